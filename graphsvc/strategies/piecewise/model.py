"""Piecewise local models (Xie 2009, "Realistic motion estimation using accelerometers",
§5–6): the knowledge base's poses reduced, clustered with their readings, and per
cluster a map from readings to the reduced pose.

Learning, from the knowledge-base frames a run may use (the graph's original nodes
with an original edge into them, `strategies.index.frame_readings`, less every frame
of a hidden clip — a model learned with a hidden clip would carry it):

1. Poses: each frame's local pose vector (`synthesis.local_pose`: the pelvis rotation
   with the frame's heading taken off, the pelvis height, the local rotation of every
   joint under the pelvis; unit quaternions on their w ≥ 0 side), D = 5 + 4·joints
   values, reduced to `dims` by PCA (r = (q − q̄)Aᵀ, Xie eq. 5.2). A pose comes back
   as q̄ + rA with each quaternion normalised. By default `dims` is the fewest
   components holding 99.9 % of the variance (VARIANCE_KEPT). Xie kept 99 % (7 did
   for his capture); on Bandai dataset 2 without its takes 004 99 % needs 31 and its
   truncation alone costs 1.5 cm of joint error on the local rotations, 99.9 % needs
   49 and costs 0.27 cm.
1b. Or by LLE (`--piecewise-reduce lle`, Roweis & Saul 2000, "Nonlinear dimensionality
   reduction by locally linear embedding"), as landmark LLE to stay small on a large
   knowledge base: sklearn's LocallyLinearEmbedding (ARPACK, LLE_NEIGHBOURS
   neighbours) over an even stride of at most LLE_LANDMARKS frames, every frame then
   placed in the embedding by the standard out-of-sample reconstruction weights from
   its nearest landmarks (sklearn's `transform`). A point of the embedding comes back
   to a pose the same way round: the weights that rebuild it from its nearest
   landmarks' embeddings, applied to their poses (`lle_pose`). The embedding is scaled
   to the poses' total variance, so that its clusters and priors weigh as a PCA's do.
2. Readings: the layout's accelerations on arriving at the frame, in g (S × 3, the
   graph's sensor-frame convention: the same features `nearest` matches).
3. Clusters: a Gaussian mixture (full covariances) over [r, readings]; with
   clusters = auto, the count of the ladder CLUSTER_LADDER (up to one per
   MIN_FRAMES_PER_CLUSTER frames, and up the ladder only until the BIC has risen
   twice running) with the smallest BIC, each candidate fitted on at most BIC_FRAMES
   frames (an even stride), the chosen count then on at most GMM_FRAMES. Every frame
   is grouped by the mixture's component of highest posterior.
4. A sample is assigned to a cluster in one of two ways (`assign`). `nearest` (the
   default): the cluster of the training frame whose readings are nearest the sample's
   (a kd-tree over the training frames' readings, built on load; the frames' clusters
   are stored with the model). `mixture`, Xie's: the component of highest posterior
   under the mixture's marginal over the readings (log πₖ + log N(c; μ_c,k, Σ_cc,k)).
   Twelve noisy readings leave that marginal ambiguous: on four dataset-2
   takes 004 it picks a cluster whose frames are far from the truth so often that the
   joint error is 6.6 cm against 3.9 with `nearest` (docs/piecewise.md).
5. RBF, Xie eq. 5.9 (`rbf-fit`): per cluster y(c) = ȳ + Σᵢ wᵢ exp(−‖c − cᵢ‖² / σ²),
   y = [r, the frame's root step on the ground (2, m, in the frame before's heading
   frame), its turn (rad), its foot contacts (2)], so one map gives the pose and the
   root's own motion. Centres: the cluster's frames, an even stride of at most
   MAX_CENTRES of them in a larger one; the weights fit every frame of the cluster by
   ridge-regularised least squares, (ΦᵀΦ + λI)w = Φᵀ(y − ȳ), λ = RIDGE · mean
   diag(ΦᵀΦ) (with all frames as centres this is the interpolation of eq. 5.9, kept
   solvable where the Gaussian kernel's matrix is near singular). σ: the `width`
   option, else the cluster's median distance from a centre to its WIDTH_NEIGHBOUR-th
   nearest centre.
5b. The default `rbf`: a normalised Gaussian RBF over the cluster's LOCAL_NEIGHBOURS
   frames nearest the sample's readings, y(c) = Σᵢ φᵢyᵢ / Σᵢ φᵢ with φᵢ = exp(−(‖c −
   cᵢ‖/σ)²) and σ the median of their distances (Moody & Darken 1989, "Fast learning
   in networks of locally-tuned processing units"): a blend of nearby examples that
   cannot leave their span, where the fitted map extrapolates off the poses' manifold
   from noisy readings. The frames' outputs y, clusters and nodes are stored with the
   model; their readings come from the frames' index.
6. Optimisation, Xie eq. 6.2–6.4, per frame over r:
       (r − μ)ᵀΛ⁻¹(r − μ) + ω_s‖r − 2r₋₁ + r₋₂‖² + ω_c‖Gr + g − c‖²
   with Λ the cluster's pose covariance (the mixture component's pose block), μ the
   sample's `rbf` estimate (Xie's is the cluster's mean, which holds the pose near the
   cluster's average: 5.7 cm of joint error against 3.7 on docs/piecewise.md's clips),
   and the readings model the component's own linear one, the conditional mean
   of the readings given the pose, E[c | r] = μ_c + Σ_cr Σ_rr⁻¹(r − μ_r) = Gr + g.
   Every term is quadratic, so the minimum is one small linear solve,
       (Λ⁻¹ + ω_s I + ω_c GᵀG) r = Λ⁻¹μ + ω_s(2r₋₁ − r₋₂) + ω_c Gᵀ(c − g),
   made with the two matrices' inverses kept per cluster (without the smoothness term
   for the first two frames), instead of Xie's Levenberg–Marquardt on an RBF reverse
   map. The root's step still comes from the cluster's RBF map.

scikit-learn does the reduction (PCA) and the clustering (GaussianMixture, with its
BIC): that is the job it is made for, and it is deterministic with a fixed
random_state. The RBF map is written here, not scipy's RBFInterpolator: eq. 5.9 has
no polynomial tail, a larger cluster is fitted on fewer centres than points (which
RBFInterpolator cannot), and a model must be flat arrays to be cached beside the graph
and memory-mapped — evaluating one sample is one kernel row against its cluster's
centres, a few microseconds of numpy.

Everything learned is a dict of flat arrays (`learn`), cached beside the graph file
(`strategies.index`) under a name keyed by the options that shape it and the frames
it was learned from (`model_key`), so another hold-out learns (and caches) its own.
"""

from __future__ import annotations

import hashlib
import math

import numpy as np

from graphsvc.blas import one_thread
from graphsvc.errors import InputError
from graphsvc.graph.model import MotionGraph
from graphsvc.graph.poses import node_rotations, node_translations
from graphsvc.strategies.index import frame_readings
from graphsvc.synthesis.local_pose import pose_layout, pose_vectors

CLUSTER_LADDER = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64)
MIN_FRAMES_PER_CLUSTER = 40
BIC_FRAMES = 6000
GMM_FRAMES = 12000
MAX_CENTRES = 800
RIDGE = 1e-6
WIDTH_NEIGHBOUR = 4
RANDOM_STATE = 0
REG_COVAR = 1e-5
CHUNK = 32768
VARIANCE_KEPT = 0.999
LLE_LANDMARKS = 3000
LLE_NEIGHBOURS = 12
LLE_REG = 1e-3
LOCAL_NEIGHBOURS = 8
MODEL_VERSION = 4


def frame_data(graph: MotionGraph) -> dict[str, np.ndarray]:
    """Every knowledge-base frame a model may learn from: nodes (F,), edges (F,) (the
    original edge into each), readings (F, 3S) float32 g, poses (F, D) float32 (module
    docstring), steps (F, 3) float32 (ground step (2) m and turn rad of the edge into
    the frame) and contacts (F, 2) float32."""
    arrays = frame_readings(graph)
    nodes, edges = arrays["nodes"], arrays["edges"]
    layout = pose_layout(graph.skeleton, graph.params.get("mapping"))
    poses = np.empty((nodes.size, layout.dims), np.float32)
    for lo in range(0, nodes.size, CHUNK):
        n = nodes[lo : lo + CHUNK]
        poses[lo : lo + n.size] = pose_vectors(
            node_rotations(graph, n),
            node_translations(graph, n),
            graph.skeleton.parents,
            layout,
            graph.node_heading[n].astype(np.float64),
        )
    steps = np.concatenate(
        [np.asarray(graph.edge_offset)[edges], np.asarray(graph.edge_heading)[edges][:, None]], axis=1
    )
    contacts = np.asarray(graph.node_contacts)[nodes].astype(np.float32)
    return {**arrays, "poses": poses, "steps": steps.astype(np.float32), "contacts": contacts}


def training_rows(data: dict, allowed: np.ndarray | None) -> np.ndarray:
    """Positions in `data` of the frames a model learns from: every frame whose node is
    allowed (all with None)."""
    if allowed is None:
        return np.arange(data["nodes"].size)
    return np.flatnonzero(np.asarray(allowed, dtype=bool)[data["nodes"]])


def check_against(own, frames: int, pose_dims: int) -> None:
    """InputError for options this knowledge base cannot take: a reduced dimension not
    below the pose's, more clusters than frames, no frames at all."""
    if frames == 0:
        raise InputError("piecewise: every knowledge-base frame is hidden: nothing to learn from")
    if own.dims is not None and own.dims >= pose_dims:
        raise InputError(f"piecewise dims ({own.dims}) must be below the pose dimension ({pose_dims})")
    if own.dims is not None and own.dims > frames:
        raise InputError(f"piecewise dims ({own.dims}) exceeds the knowledge base's {frames} frames")
    k = own.cluster_count()
    if k is not None and k > frames:
        raise InputError(f"piecewise clusters ({k}) exceeds the knowledge base's {frames} frames")


def model_key(own, data: dict, rows: np.ndarray) -> str:
    """What a learned model depends on, hashed: the options that shape it and the frames
    it learns from (their nodes), so another hold-out gets its own."""
    h = hashlib.sha256(repr((MODEL_VERSION, own.reduce, own.dims, own.clusters.strip(), own.width)).encode())
    h.update(np.ascontiguousarray(np.asarray(data["nodes"])[rows], dtype=np.int64).tobytes())
    return h.hexdigest()[:16]


@one_thread()  # (the same model however many threads BLAS has: graphsvc.blas)
def learn(data: dict, rows: np.ndarray, own) -> dict[str, np.ndarray]:
    """The model's arrays, learned from frames `rows` of `data` (module docstring)."""
    from sklearn.decomposition import PCA
    from sklearn.mixture import GaussianMixture

    poses = np.asarray(data["poses"], dtype=np.float64)[rows]
    readings = np.asarray(data["readings"], dtype=np.float64)[rows]
    check_against(own, rows.size, poses.shape[1])
    d = own.dims if own.dims is not None else kept_dims(poses)
    if own.reduce == "lle":
        reduction = _lle(poses, d)
        reduced = reduction.pop("reduced")
    else:
        pca = PCA(n_components=d, svd_solver="full", random_state=RANDOM_STATE).fit(poses)
        reduced = pca.transform(poses)
        reduction = {"pca_mean": pca.mean_, "pca_components": pca.components_}
    joint = np.concatenate([reduced, readings], axis=1)
    k = own.cluster_count()
    bic = {}
    if k is None:
        top = max(1, rows.size // MIN_FRAMES_PER_CLUSTER)
        sample = joint[:: max(1, -(-rows.size // BIC_FRAMES))]
        for count in (c for c in CLUSTER_LADDER if c <= min(top, sample.shape[0])):
            bic[count] = _mixture(GaussianMixture, count).fit(sample).bic(sample)
            values = list(bic.values())
            if len(values) >= 3 and values[-1] > values[-2] > values[-3]:
                break  # (rising twice: the larger counts only fit the sample's noise)
        k = min(bic, key=bic.get)
    gmm = _mixture(GaussianMixture, k).fit(joint[:: max(1, -(-rows.size // GMM_FRAMES))])
    label = gmm.predict(joint)
    outputs = np.concatenate(
        [reduced, np.asarray(data["steps"], np.float64)[rows], np.asarray(data["contacts"], np.float64)[rows]], axis=1
    )
    rbf = _fit_rbfs(readings, outputs, label, k, gmm.means_[:, :d], own.width)
    return {
        **reduction,
        "mix_weights": gmm.weights_,
        "mix_means": gmm.means_,
        "mix_covariances": gmm.covariances_,
        "bic_counts": np.array(list(bic), np.int64),
        "bic_values": np.array(list(bic.values()), np.float64),
        **rbf,
        "centre_nodes": np.asarray(data["nodes"])[rows][rbf["centre_rows"]].astype(np.int64),
        "row_labels": label.astype(np.int32),
        "row_outputs": outputs.astype(np.float32),
        "row_nodes": np.asarray(data["nodes"])[rows].astype(np.int64),
        "template": np.asarray(data["nodes"])[rows[:1]].astype(np.int64),
    }


def kept_dims(poses: np.ndarray) -> int:
    """The fewest principal components holding VARIANCE_KEPT of the poses' variance
    (Xie's criterion, at a higher share: his 7 held 99 % of his capture), at most one
    below the pose dimension."""
    from sklearn.decomposition import PCA

    ratio = PCA(svd_solver="full").fit(poses).explained_variance_ratio_
    d = int(np.searchsorted(np.cumsum(ratio), VARIANCE_KEPT - 1e-12) + 1)
    return max(1, min(d, poses.shape[1] - 1, poses.shape[0]))


def _lle(poses: np.ndarray, d: int) -> dict[str, np.ndarray]:
    """Landmark LLE (module docstring, 1b): the embedding of an even stride of at most
    LLE_LANDMARKS poses (sklearn's LocallyLinearEmbedding, ARPACK), every frame placed
    by its reconstruction weights from its nearest landmarks (sklearn's out-of-sample
    `transform`). Returns the landmarks' poses and embedding, and every frame's
    embedding ("reduced")."""
    from sklearn.manifold import LocallyLinearEmbedding

    marks = poses[:: max(1, -(-poses.shape[0] // LLE_LANDMARKS))]
    k = min(max(LLE_NEIGHBOURS, d + 1), marks.shape[0] - 1)
    if k <= d:
        raise InputError(f"piecewise: LLE into {d} dimensions needs more than {d + 1} frames")
    lle = LocallyLinearEmbedding(
        n_neighbors=k, n_components=d, eigen_solver="arpack", random_state=RANDOM_STATE, reg=LLE_REG
    )
    embedding = lle.fit_transform(marks)
    # (in the poses' units: its total variance theirs, as a PCA's nearly is; ARPACK's
    # unit eigenvectors put every coordinate near 1/√landmarks)
    scale = math.sqrt(float(marks.var(axis=0).sum()) / max(float(embedding.var(axis=0).sum()), 1e-300))
    return {"lle_poses": marks, "lle_embedding": embedding * scale, "reduced": lle.transform(poses) * scale}


def lle_pose(embedding: np.ndarray, poses: np.ndarray, tree, r: np.ndarray, k: int) -> np.ndarray:
    """The pose (D,) at embedding point r: its k nearest landmarks' poses weighted by
    the weights that rebuild r from their embeddings (sum 1, LLE's regularised local
    Gram system)."""
    _, near = tree.query(r, k)
    near = np.atleast_1d(near)
    Z = embedding[near] - r[None]
    C = Z @ Z.T
    C = C + np.eye(near.size) * LLE_REG * max(float(np.trace(C)), 1e-12)
    w = np.linalg.solve(C, np.ones(near.size))
    return (w / w.sum()) @ poses[near]


def _mixture(cls, count: int):
    return cls(count, covariance_type="full", reg_covar=REG_COVAR, random_state=RANDOM_STATE, n_init=1, max_iter=200)


def _fit_rbfs(X: np.ndarray, Y: np.ndarray, label: np.ndarray, K: int, pose_means: np.ndarray, width):
    """Per cluster its centres, σ, output mean and weights (module docstring, 5),
    concatenated: centres (M, F), weights (M, O), start (K + 1,) offsets, sigma (K,),
    out_mean (K, O); centre_rows (M,): each centre's position among the training rows."""
    O = Y.shape[1]
    centres, weights, rows, start, sigma, out_mean = [], [], [], [0], np.ones(K), np.zeros((K, O))
    for j in range(K):
        own = np.flatnonzero(label == j)
        if own.size == 0:  # (a component no frame prefers: its pose mean, standing still)
            out_mean[j, : pose_means.shape[1]] = pose_means[j]
            start.append(start[-1])
            continue
        c = own[:: max(1, -(-own.size // MAX_CENTRES))]
        C = X[c]
        out_mean[j] = Y[own].mean(axis=0)
        sigma[j] = float(width) if width is not None else _width(C)
        phi = _kernel(X[own], C, sigma[j])
        gram = phi.T @ phi
        ridge = RIDGE * max(float(np.mean(np.diag(gram))), 1e-12)
        w = np.linalg.solve(gram + ridge * np.eye(c.size), phi.T @ (Y[own] - out_mean[j]))
        centres.append(C)
        weights.append(w)
        rows.append(c)
        start.append(start[-1] + c.size)
    F = X.shape[1]
    return {
        "centres": np.concatenate(centres) if centres else np.zeros((0, F)),
        "weights": np.concatenate(weights) if weights else np.zeros((0, O)),
        "centre_rows": np.concatenate(rows).astype(np.int64) if rows else np.zeros(0, np.int64),
        "start": np.asarray(start, np.int64),
        "sigma": sigma,
        "out_mean": out_mean,
    }


def _width(C: np.ndarray) -> float:
    """σ of a cluster with centres C: the median distance to the WIDTH_NEIGHBOUR-th
    nearest other centre (1 g for a single centre; never below 1e-3 g)."""
    if C.shape[0] < 2:
        return 1.0
    from scipy.spatial import cKDTree

    k = min(WIDTH_NEIGHBOUR, C.shape[0] - 1)
    dist, _ = cKDTree(C).query(C, k + 1)
    return max(float(np.median(dist[:, k])), 1e-3)


def _kernel(X: np.ndarray, C: np.ndarray, sigma: float) -> np.ndarray:
    d2 = np.maximum((X * X).sum(1)[:, None] - 2.0 * X @ C.T + (C * C).sum(1)[None], 0.0)
    return np.exp(-d2 / (sigma * sigma))


class Model:
    """A learned model's arrays (`learn`) and what a sample's step reads of them, made
    once: the mixture's marginal over the readings (means, Cholesky factors of the
    precisions, log normalisers) and, for the optimisation, each cluster's prior and
    readings model folded into two inverse matrices."""

    @one_thread()
    def __init__(
        self, arrays: dict, readings: np.ndarray, w_smooth: float = 0.2, w_control: float = 0.8, assign: str = "nearest"
    ):
        from scipy.spatial import cKDTree

        self.arrays = arrays
        a = {k: np.asarray(v) for k, v in arrays.items()}
        # the training frames (the model's rows): readings, cluster, outputs, node
        self.row_readings = np.asarray(readings, dtype=np.float64)
        self.row_labels, self.row_outputs, self.row_nodes = a["row_labels"], a["row_outputs"], a["row_nodes"]
        self.tree = cKDTree(self.row_readings) if assign == "nearest" else None
        members = [np.flatnonzero(self.row_labels == k) for k in range(a["mix_means"].shape[0])]
        self.members = members
        self.member_trees = [cKDTree(self.row_readings[m]) if m.size else None for m in members]
        self.lle = "lle_embedding" in a
        if self.lle:
            self.embedding, self.landmarks = a["lle_embedding"], a["lle_poses"]
            self.lle_tree = cKDTree(self.embedding)
            d = self.d = self.embedding.shape[1]
            self.near = min(max(LLE_NEIGHBOURS, d + 1), self.embedding.shape[0])
        else:
            self.mean, self.components = a["pca_mean"], a["pca_components"]
            d = self.d = self.components.shape[0]
        means, covs = a["mix_means"], a["mix_covariances"]
        self.K = means.shape[0]
        self.read_mean = np.ascontiguousarray(means[:, d:])
        F = self.read_mean.shape[1]
        self.read_chol = np.empty((self.K, F, F))  # L with Σ_cc⁻¹ = L Lᵀ
        self.read_log = np.empty(self.K)
        self.prior_mean = np.ascontiguousarray(means[:, :d])
        self.solve = np.empty((2, self.K, d, d))  # without / with the smoothness term
        self.rhs_prior = np.empty((self.K, d))
        self.precision = np.empty((self.K, d, d))
        self.G, self.g = np.empty((self.K, F, d)), np.empty((self.K, F))
        self.control = np.empty((self.K, F, F))
        self.w_smooth, self.w_control = float(w_smooth), float(w_control)
        for k in range(self.K):
            srr, scc, scr = covs[k, :d, :d], covs[k, d:, d:], covs[k, d:, :d]
            inv_cc = np.linalg.inv(scc)
            self.read_chol[k] = np.linalg.cholesky(0.5 * (inv_cc + inv_cc.T))
            self.read_log[k] = (
                math.log(a["mix_weights"][k]) - 0.5 * np.linalg.slogdet(scc)[1] - 0.5 * F * math.log(2.0 * math.pi)
            )
            prec = np.linalg.inv(srr)
            self.G[k] = scr @ prec
            self.g[k] = self.read_mean[k] - self.G[k] @ self.prior_mean[k]
            residual = scc - self.G[k] @ scr.T  # the readings' spread about their model: Σ_cc − Σ_cr Σ_rr⁻¹ Σ_rc
            self.control[k] = np.linalg.inv(0.5 * (residual + residual.T))
            base = prec + self.w_control * self.G[k].T @ self.control[k] @ self.G[k]
            self.solve[0, k] = np.linalg.inv(base)
            self.solve[1, k] = np.linalg.inv(base + self.w_smooth * np.eye(d))
            self.rhs_prior[k] = prec @ self.prior_mean[k]
            self.precision[k] = prec
        self.centres, self.weights = a["centres"], a["weights"]
        self.start, self.sigma, self.out_mean = a["start"], a["sigma"], a["out_mean"]
        self.centre_rows, self.centre_nodes = a["centre_rows"], a["centre_nodes"]

    def cluster(self, c: np.ndarray) -> int:
        """The cluster of readings c (F,) g: with the training frames' readings given,
        the cluster of the frame whose readings are nearest (module docstring, 4);
        else the highest posterior under the mixture's marginal over the readings."""
        if self.tree is not None:
            return int(self.row_labels[self.tree.query(c)[1]])
        z = np.einsum("kf,kfg->kg", c[None] - self.read_mean, self.read_chol)
        return int(np.argmax(self.read_log - 0.5 * (z * z).sum(1)))

    def rbf(self, k: int, c: np.ndarray) -> tuple[np.ndarray, int]:
        """Cluster k's fitted map (eq. 5.9) at readings c: the outputs (O,) ([r, step
        (3), contacts (2)]) and the node of the centre nearest c (−1: none)."""
        lo, hi = int(self.start[k]), int(self.start[k + 1])
        if hi == lo:
            return self.out_mean[k].copy(), -1
        C = self.centres[lo:hi]
        d2 = ((C - c[None]) ** 2).sum(1)
        phi = np.exp(-d2 / (self.sigma[k] ** 2))
        return self.out_mean[k] + phi @ self.weights[lo:hi], int(self.centre_nodes[lo + int(np.argmin(d2))])

    def local(self, k: int, c: np.ndarray) -> tuple[np.ndarray, int]:
        """Cluster k's normalised RBF at readings c (module docstring, 5b): the outputs
        (O,) weighted over the cluster's LOCAL_NEIGHBOURS frames nearest c, and the
        nearest one's node (−1: the cluster has no frame)."""
        tree = self.member_trees[k]
        if tree is None:
            return self.out_mean[k].copy(), -1
        dist, near = tree.query(c, min(LOCAL_NEIGHBOURS, self.members[k].size))
        dist, near = np.atleast_1d(dist), self.members[k][np.atleast_1d(near)]
        sigma = max(float(np.median(dist)), 1e-9)
        w = np.exp(-((dist / sigma) ** 2))
        return (w / w.sum()) @ self.row_outputs[near].astype(np.float64), int(self.row_nodes[near[0]])

    def optimise(
        self, k: int, c: np.ndarray, r1: np.ndarray | None, r2: np.ndarray | None, mu: np.ndarray | None = None
    ) -> np.ndarray:
        """The reduced pose minimising eq. 6.2–6.4 in cluster k (module docstring, 6);
        r1, r2: the two previous frames' (None: not yet, no smoothness term); mu: the
        prior's mean (None: the cluster's)."""
        b = (self.rhs_prior[k] if mu is None else self.precision[k] @ mu) + self.w_control * self.G[k].T @ (
            self.control[k] @ (c - self.g[k])
        )
        if r1 is None or r2 is None:
            return self.solve[0, k] @ b
        return self.solve[1, k] @ (b + self.w_smooth * (2.0 * r1 - r2))

    def pose(self, r: np.ndarray) -> np.ndarray:
        """The pose vector (D,) of reduced pose r (quaternions not yet normalised)."""
        if self.lle:
            return lle_pose(self.embedding, self.landmarks, self.lle_tree, r, self.near)
        return self.mean + r @ self.components

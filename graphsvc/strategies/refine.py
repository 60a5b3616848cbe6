"""Pose refinement: a graph path's poses corrected toward a local linear model of the
knowledge base around the measured readings (`--refine`, for the strategies that name
`refine` among their shared options: those whose output is a graph path).

A strategy that outputs the graph's poses can do no better than the pose-oracle floor
(`evaluate.oracle`), and on a performer the knowledge base never saw, one frame whose
readings are nearest (`nearest`) or a path through the graph (`viterbi`) lands well
above it. The refinement keeps the path's motion — its timing, its root track and
turning, its blends and planted feet — and adds to each frame's local pose
(`synthesis.local_pose`) a slowly varying correction:

1. the query is the measured accelerations over a short window centred on the frame
   (`OFFSETS_S`: five samples over ±0.13 s, in g, each sensor's frame), so a pose is
   told by how the readings move and not by one noisy sample;
2. its `NEIGHBOURS` nearest knowledge-base frames by the same window of their virtual
   readings (only the frames a hold-out leaves usable; `nearest_rows`, below),
   weighted by a bisquare kernel out to the farthest of them, sharpened toward the
   nearest (÷ (d/h + ε)², so a frame the knowledge base holds comes back as it is);
3. the regressed pose is the neighbours' weighted mean plus a ridge regression of their
   poses on their readings' deviations from the weighted mean, evaluated at the query
   (after Chai and Hodgins 2005, "Performance animation from low-dimensional control
   signals": a local model learned at run time from the examples nearest the control
   signals); the ridge (`RIDGE` × the mean eigenvalue) keeps the move to what the
   readings support;
4. the correction is the regressed pose less the path node's own pose, smoothed over
   time by a Gaussian of σ `CORRECTION_S` (clamped at the ends), and added to the
   synthesized frame's pose. The regressed poses alone change from frame to frame as
   their neighbours do (3.4 times the truth's jitter after the poses' filter); their
   difference from the path is slow, and smoothed it keeps most of the gain with the
   path's jitter;
5. the feet the path had planted are held (`synthesis.foot_hold`): while a node's
   contact flag is on, the ankle and toe move as they did before the correction, which
   costs part of the gain (0.45 cm on the tune set) and keeps the foot skate at the
   path's.

With measured orientations (W_R > 0, a graph with the orientation cue):
6. a frame's own measured cue (`sensors.orientation`), times √(W_R · `ORIENTATION_GAIN`),
   joins its query and the regression's inputs, the neighbours' cue beside their
   windows: a limb's orientation tells a pose far better than its accelerations;
7. with the cue relative to a root sensor, each measured segment then gets its measured
   orientation (`synthesis.sensor_orientations`: trunk and shins whole, a forearm its
   direction), from the cue smoothed over time by a Gaussian of σ `CUE_S` (the devices'
   2° of white noise otherwise shows as 1.7 times the truth's jitter), before the feet
   are held.
Chosen on the same 20 clips with kelly6 and the `real` noise (its orientation output,
positions and heading): the gain 30 against 1, 4, 10 and 100 (4.60, 4.50, 4.36, 4.26 cm
against 4.22 without imposing; 10: 3.81 cm imposing, skate 1.07 times the truth's
against 1.19); imposing against not (3.77 against 4.22 cm); the cue's σ 1/30 s against
none (3.81 cm, jitter 1.74 times the truth's) and 1/15 s (3.83 cm, skate 1.28 times).

A frame whose window has a missing reading gets no correction of its own. Each step is
frame by frame (the window of the frame's samples and the correction's frames, clamped
at the recording's ends), so a live stream gives the batch's frames: the correction
reaches ⌈3σ⌉ frames ahead, less than the synthesis' look-ahead that a frame waits for
anyway, and the window's samples have arrived with the search's lag (below 0.14 s of
latency, the window is cut at the newest sample).

Chosen on the takes 002 and 003 of the held-out actor's styles with a graph without
that actor (20 clips, never the reported ones; wrists-ankles, default noise, seed 7,
positions and heading): the window ±4 samples at 30 Hz against ±0, ±6, ±8, ±10 and
every sample; 256 neighbours against 8 to 128; ridge 1 against 0.01 to 10⁶ (the plain
mean of 8: 0.6 cm worse); the correction's σ 0.1 s against 0.067 (0.04 cm worse) and
0.2 s (0.05 cm); holding the feet with the legs against not holding them (4.58 cm, skate
2.2 times the truth's) and against carrying the body on the planted foot (4.94 cm,
jitter 1.6 times the truth's). There the search's joint error goes from 5.87 to 5.03 cm
(`nearest` 5.59), jitter 0.99 and skate 1.17 times the truth's.
Docs: docs/reconstruction.md, *Refinement*.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np

from graphsvc.graph.derived import derived
from graphsvc.graph.model import EDGE_ORIGINAL, MotionGraph
from graphsvc.graph.poses import node_rotations, node_translations
from graphsvc.motion.skeleton import Motion
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.sensors.orientation import normalised_rows
from graphsvc.strategies.index import cached_arrays, frame_readings
from graphsvc.synthesis.foot_hold import FootHold
from graphsvc.synthesis.local_pose import PoseLayout, node_pose_vectors, place_local_poses, pose_layout, pose_vectors
from graphsvc.synthesis.sensor_orientations import clip_sensor_placements, impose_at_nodes, imposes
from graphsvc.synthesis.smooth import gaussian_taps, smooth_poses

INDEX_VERSION = 2
OFFSETS_S = (-2 / 15, -1 / 15, 0.0, 1 / 15, 2 / 15)  # the query window's samples (s), ±4 samples at 30 Hz
NEIGHBOURS = 256
RIDGE = 1.0
SHARPEN = 0.01  # ε of the weights' 1 / (d/h + ε)²
CORRECTION_S = 0.1  # σ (s) of the Gaussian over the corrections
ORIENTATION_GAIN = 30.0  # the query's orientation cue weighs W_R times this (module docstring)
CUE_S = 1 / 30  # σ (s) of the Gaussian over the measured orientations imposed


def window_offsets(rate_hz: float) -> np.ndarray:
    """The query window's sample offsets at rate_hz (int64)."""
    return np.array([round(s * float(rate_hz)) for s in OFFSETS_S], dtype=np.int64)


def _build_arrays(graph: MotionGraph) -> dict[str, np.ndarray]:
    """nodes (M,), windows (M, W·3S) float32 g: each frame's readings at the window's
    offsets along its own clip (clamped at the clip's ends), poses (M, D) float32."""
    fr = frame_readings(graph)
    nodes, readings = fr["nodes"], fr["readings"]
    M = nodes.size
    row = np.full(graph.num_nodes, -1, dtype=np.int64)
    row[nodes] = np.arange(M)
    e = np.flatnonzero(np.asarray(graph.edge_kind) == EDGE_ORIGINAL)
    src, dst = np.asarray(graph.edge_src)[e].astype(np.int64), np.asarray(graph.edge_dst)[e].astype(np.int64)
    nxt = np.arange(M)
    prv = np.arange(M)
    ok = (row[src] >= 0) & (row[dst] >= 0)
    nxt[row[src[ok]]] = row[dst[ok]]
    prv[row[dst[ok]]] = row[src[ok]]
    parts = []
    for d in window_offsets(graph.rate_hz):
        at = np.arange(M)
        for _ in range(abs(int(d))):
            at = (nxt if d > 0 else prv)[at]
        parts.append(readings[at])
    layout = pose_layout(graph.skeleton, graph.params.get("mapping"))
    return {
        "nodes": nodes,
        "edges": fr["edges"],
        "windows": np.ascontiguousarray(np.concatenate(parts, axis=1), dtype=np.float32),
        "poses": node_pose_vectors(graph, nodes, layout),
    }


def refine_arrays(graph: MotionGraph) -> dict[str, np.ndarray]:
    """The refinement's index arrays, cached beside the graph file (`strategies.index`)."""
    return cached_arrays(graph, "refine", INDEX_VERSION, lambda: _build_arrays(graph))


@dataclass
class RefineIndex:
    """The usable frames' windows (M, d) float64 and poses (M, D), their k-d tree, the
    pose layout, the graph rate and joint map; and the frames' orientation cue (M, W·S)
    (`graph.edge_up` of the edge into each; None where the graph has none), with the
    trees over windows and √W_R · cue made per weight on first use."""

    windows: np.ndarray
    poses: np.ndarray
    columns: np.ndarray  # the windows (d, M) float32, for `nearest_rows`
    layout: PoseLayout
    rate_hz: float
    mapping: object = None  # (the graph's joint map)
    cue: np.ndarray | None = None
    oriented: dict = field(default_factory=dict)  # weight → (features (M, d + W·S), their columns)

    def features(self, weight: float) -> tuple[np.ndarray, np.ndarray]:
        """The frames' query features (M, d) float64 and the same as columns (d, M)
        float32: the windows alone (weight 0 or no cue), else the windows and √weight ·
        the orientation cue."""
        if weight <= 0 or self.cue is None:
            return self.windows, self.columns
        if weight not in self.oriented:
            f = np.concatenate([self.windows, np.sqrt(weight) * self.cue], axis=1)
            self.oriented[weight] = (f, _columns(f))
        return self.oriented[weight]


def refine_index(graph: MotionGraph, allowed: np.ndarray | None = None) -> RefineIndex:
    """The index over the frames `allowed` (N,) leaves usable (None: all; that one is
    made once per graph object and kept while the graph is, `graph.derived`: a server's
    sessions share it)."""
    if allowed is None or bool(np.all(allowed)):
        return derived(graph, "refine.index", lambda: _make_index(graph, None))
    return _make_index(graph, allowed)


def _make_index(graph: MotionGraph, allowed: np.ndarray | None) -> RefineIndex:
    arrays = refine_arrays(graph)
    keep = slice(None) if allowed is None else np.asarray(allowed, dtype=bool)[arrays["nodes"]]
    windows = np.asarray(arrays["windows"][keep], dtype=np.float64)
    edges = np.asarray(arrays["edges"][keep], dtype=np.int64)
    # (the frames' edges gathered first: the whole edge_up in float64 is 1.2 GB on a 12.5M-edge graph)
    cue = None if graph.edge_up is None else np.asarray(graph.edge_up[edges], dtype=np.float64).reshape(edges.size, -1)
    return RefineIndex(
        windows,
        np.asarray(arrays["poses"][keep], dtype=np.float64),
        _columns(windows),
        pose_layout(graph.skeleton, graph.params.get("mapping")),
        float(graph.rate_hz),
        graph.params.get("mapping"),
        cue,
    )


def _columns(features: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(features.T, dtype=np.float32)


@numba.njit(cache=True)
def nearest_rows(features, columns, queries, near, dist):
    """For each query (n, d): its K = near.shape[1] nearest rows of features (M, d) into
    near (n, K), their distances into dist (n, K), nearest first (ties: lower row).

    A brute force: every row's squared distance in float32 over the columns (d, M)
    (one pass over the rows a column), the K smallest selected, then their
    distances in float64 from `features` and sorted. On the 60-value windows of 33,048
    frames it takes 0.5–0.6 ms of CPU a query where scipy's k-d tree took 3.9 ms (a
    tree prunes little in 60 dimensions). The selection in float32 may swap rows tied
    to within its rounding at the K-th distance, where the weights are nil."""
    d, M = columns.shape
    K = near.shape[1]
    acc = np.empty(M, np.float32)
    d2 = np.empty(K)
    for q in range(queries.shape[0]):
        acc[:] = 0.0
        for j in range(d):
            v = np.float32(queries[q, j])
            row = columns[j]
            for i in range(M):
                t = row[i] - v
                acc[i] += t * t
        picked = np.sort(np.argpartition(acc, K - 1)[:K])
        for k in range(K):
            s = 0.0
            for j in range(d):
                t = features[picked[k], j] - queries[q, j]
                s += t * t
            d2[k] = s
        order = np.argsort(d2, kind="mergesort")
        for k in range(K):
            near[q, k] = picked[order[k]]
            dist[q, k] = np.sqrt(d2[order[k]])


def regress(index: RefineIndex, queries: np.ndarray, weight: float = 0.0) -> np.ndarray:
    """Regressed poses (n, D) for queries (n, d) (module docstring, steps 2–3): windows,
    or with weight > 0 windows and √weight · the orientation cue (`RefineIndex.features`)."""
    n = queries.shape[0]
    poses = np.empty((n, index.poses.shape[1]))
    K = min(NEIGHBOURS, index.windows.shape[0])
    if n == 0:
        return poses
    features, columns = index.features(weight)
    queries = np.ascontiguousarray(queries, dtype=np.float64)
    near, dist = np.empty((n, K), np.int64), np.empty((n, K))
    nearest_rows(features, columns, queries, near, dist)
    local_regression(features, index.poses, queries, near, dist, RIDGE, SHARPEN, poses)
    return poses


@numba.njit(cache=True)
def local_regression(features, poses, queries, near, dist, ridge, sharpen, out):
    """Steps 2–3 of the module docstring for each query (n, d) from its neighbours'
    rows near (n, K) of features (M, d) and poses (M, D), at distances dist (n, K)
    (nearest first), into out (n, D).

    With dev_k = f_k − f̄ and A = Σ w_k dev_k dev_kᵀ + λI (λ = ridge × A's mean
    eigenvalue), the ridge regression's β = A⁻¹ Σ w_k dev_k (p_k − p̄)ᵀ evaluated at the
    query is p̄ + Σ_k w_k (dev_k · z)(p_k − p̄) with z = A⁻¹ (q − f̄): one Cholesky
    factorisation and a single right-hand side a query. Written out here rather than
    through BLAS: OpenBLAS's products change in the last bits with its thread count,
    and these poses must be the same bytes in the CLI, a batch worker and a server's
    thread (graphsvc.blas). About 0.5 ms of CPU a query with 256 neighbours of 60
    values and 105-value poses; numpy's batched products and solve were about 0.8 ms."""
    n, K = near.shape
    d, D = features.shape[1], poses.shape[1]
    w = np.empty(K)
    fm = np.empty(d)
    pm = np.empty(D)
    dev = np.empty((K, d))
    A = np.empty((d, d))
    z = np.empty(d)
    for q in range(n):
        h = max(dist[q, K - 1], 1e-12)
        total = 0.0
        for k in range(K):
            u = dist[q, k] / h
            a = 1.0 - u * u
            w[k] = (a * a + 1e-6) / ((u + sharpen) * (u + sharpen))
            total += w[k]
        for k in range(K):
            w[k] /= total
        fm[:] = 0.0
        pm[:] = 0.0
        for k in range(K):
            r = near[q, k]
            for j in range(d):
                fm[j] += w[k] * features[r, j]
            for j in range(D):
                pm[j] += w[k] * poses[r, j]
        for k in range(K):
            r = near[q, k]
            for j in range(d):
                dev[k, j] = features[r, j] - fm[j]
        A[:, :] = 0.0
        for k in range(K):
            for i in range(d):
                a = w[k] * dev[k, i]
                for j in range(i, d):
                    A[i, j] += a * dev[k, j]
        trace = 0.0
        for i in range(d):
            trace += A[i, i]
        lam = ridge * trace / d + 1e-12
        for i in range(d):
            A[i, i] += lam
            for j in range(i):
                A[i, j] = A[j, i]
        # Cholesky, A = L Lᵀ, L in A's lower triangle.
        for j in range(d):
            s = A[j, j]
            for m in range(j):
                s -= A[j, m] * A[j, m]
            A[j, j] = np.sqrt(s)
            for i in range(j + 1, d):
                s = A[i, j]
                for m in range(j):
                    s -= A[i, m] * A[j, m]
                A[i, j] = s / A[j, j]
        for i in range(d):  # L y = q − f̄
            s = queries[q, i] - fm[i]
            for m in range(i):
                s -= A[i, m] * z[m]
            z[i] = s / A[i, i]
        for i in range(d - 1, -1, -1):  # Lᵀ z = y
            s = z[i]
            for m in range(i + 1, d):
                s -= A[m, i] * z[m]
            z[i] = s / A[i, i]
        for j in range(D):
            out[q, j] = pm[j]
        for k in range(K):
            c = 0.0
            for j in range(d):
                c += dev[k, j] * z[j]
            c *= w[k]
            r = near[q, k]
            for j in range(D):
                out[q, j] += c * (poses[r, j] - pm[j])


def _aligned(p: np.ndarray, to: np.ndarray) -> np.ndarray:
    """Pose vectors p (n, D) with each quaternion on the side of `to`'s (n, D): the
    pelvis's at 0–3 and the joints' from 5 on, four values each."""
    n, D = p.shape
    slots = np.r_[0:4, 5:D]
    q = p[:, slots].reshape(n, -1, 4)
    sign = np.where(np.sum(q * to[:, slots].reshape(n, -1, 4), axis=2) < 0.0, -1.0, 1.0)
    out = p.copy()
    out[:, slots] = (q * sign[:, :, None]).reshape(n, -1)
    return out


class Refiner:
    """The refinement of one recording, live or in batch. `push` each sample's
    accelerations (S, 3) m/s² (NaN: missing), and its orientation cue (S, W) where
    measured, as it comes and `finish` at the end; weight: W_R, with which a frame's
    measured cue joins its query (0, or a graph without the cue: readings alone);
    `correct(first, rot, trans, nodes_of)` adds the smoothed correction to final frames
    first, first + 1, … of a path's motion, `nodes_of(lo, hi)` giving the path's nodes
    of frames lo..hi−1 (known up to `reach` frames past the last final one, or to the
    end once finished)."""

    def __init__(self, graph: MotionGraph, index: RefineIndex, weight: float = 0.0):
        self.graph = graph
        self.index = index
        self.weight = float(weight) * ORIENTATION_GAIN if index.cue is not None else 0.0
        self.cues: list = []  # each sample's normalised cue (W·S,), NaN where incomplete
        # Measured orientations relative to a root sensor are imposed on their segments
        # (`synthesis.sensor_orientations`).
        self.impose = self.weight > 0 and imposes(graph)
        self.offsets = window_offsets(index.rate_hz)
        self.taps = gaussian_taps(CORRECTION_S * index.rate_hz)
        self.h = (self.taps.size - 1) // 2
        self.samples: list = []
        self.base = 0  # the index of samples[0]
        self.ended = False
        self.deltas: list = []  # the corrections of frames dbase, dbase + 1, …
        self.node_poses: list = []  # and their path nodes' local poses
        self.frame_cues: list = []  # and, where imposed, their measured orientation cue
        self.cue_taps = gaussian_taps(CUE_S * index.rate_hz)
        self.dbase = 0
        self.hold = FootHold(graph.skeleton, index.rate_hz, index.mapping)

    @property
    def reach(self) -> int:
        """Frames past a final frame whose nodes its correction reads."""
        return self.h

    def push(self, acc, up=None) -> None:
        self.samples.append(np.asarray(acc, dtype=np.float64).reshape(-1) / GRAVITY)
        if self.weight > 0:
            row = np.full(self.index.cue.shape[1], np.nan)
            if up is not None:
                cue, valid = normalised_rows(np.asarray(up, dtype=np.float64).reshape(len(self.graph.sensor_names), -1))
                if valid.all() and cue.size == row.size:
                    row = cue.reshape(-1)
            self.cues.append(row)

    def finish(self) -> None:
        self.ended = True

    def regressed(self, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
        """(poses (n, D), refined (n,) bool) of frames lo..hi−1: each frame's window of
        samples, clamped to the first and to the newest one in; a frame whose window
        holds a missing reading is not refined."""
        n = max(0, hi - lo)
        newest = self.base + len(self.samples) - 1
        at = np.clip(np.arange(lo, hi)[:, None] + self.offsets[None, :], 0, max(newest, 0)) - self.base
        x = np.stack(self.samples) if self.samples else np.zeros((1, self.index.windows.shape[1] // self.offsets.size))
        q = x[at].reshape(n, -1)
        ok = np.all(np.isfinite(q), axis=1)
        poses = np.zeros((n, self.index.poses.shape[1]))
        if self.weight > 0:  # (a frame's own sample's cue, where complete, joins its query)
            own = np.clip(np.arange(lo, hi), 0, max(newest, 0)) - self.base
            cue = np.stack(self.cues)[own] if self.cues else np.full((n, self.index.cue.shape[1]), np.nan)
            both = ok & np.all(np.isfinite(cue), axis=1)
            poses[both] = regress(
                self.index, np.concatenate([q[both], np.sqrt(self.weight) * cue[both]], axis=1), self.weight
            )
            ok_plain = ok & ~both
            poses[ok_plain] = regress(self.index, q[ok_plain])
            return poses, ok
        poses[ok] = regress(self.index, q[ok])
        return poses, ok

    def _deltas_to(self, hi: int, nodes_of) -> None:
        """The corrections of every frame before hi, made once each."""
        lo = self.dbase + len(self.deltas)
        if hi <= lo:
            return
        node = node_pose_vectors(self.graph, nodes_of(lo, hi), self.index.layout).astype(np.float64)
        poses, ok = self.regressed(lo, hi)
        delta = np.where(ok[:, None], _aligned(poses, node) - node, 0.0)
        self.deltas.extend(delta)
        self.node_poses.extend(node)
        if self.impose:  # (each frame's measured cue, smoothed over time, kept with its correction)
            newest = self.base + len(self.samples) - 1
            rows = np.stack(self.cues)
            cue = np.zeros((hi - lo, rows.shape[1]))
            hc = (self.cue_taps.size - 1) // 2
            for k, tap in enumerate(self.cue_taps):
                cue += tap * rows[np.clip(np.arange(lo, hi) + k - hc, 0, max(newest, 0)) - self.base]
            self.frame_cues.extend(cue)
        # Forget the samples and corrections no later frame reads.
        drop = hi - self.h - 1 + int(self.offsets.min()) - self.base
        if drop > 256:
            del self.samples[:drop]
            del self.cues[:drop]
            self.base += drop

    def correct(self, first: int, rot: np.ndarray, trans: np.ndarray, nodes_of, last: int | None = None):
        """Final frames first.. (rot (K, J, 4), trans (K, J, 3)) with their corrections
        added; last: the recording's last frame once known (the correction's clamp)."""
        K = rot.shape[0]
        if K == 0:
            return rot, trans
        end = first + K - 1 + self.h if last is None else min(first + K - 1 + self.h, last)
        self._deltas_to(end + 1, nodes_of)
        top = end if last is not None else first + K - 1 + self.h
        corr = np.zeros((K, self.index.poses.shape[1]))
        rows = np.asarray(self.deltas[max(0, first - self.h - self.dbase) :], dtype=np.float64)
        row0 = max(0, first - self.h - self.dbase) + self.dbase
        for k, tap in enumerate(self.taps):  # (the same order of sums, live or not)
            at = np.clip(np.arange(first, first + K) + k - self.h, 0, top) - row0
            corr += tap * rows[at]
        node = np.asarray(self.node_poses[first - self.dbase : first + K - self.dbase])
        cue = np.asarray(self.frame_cues[first - self.dbase : first + K - self.dbase]) if self.impose else None
        drop = first + K - self.h - 1 - self.dbase
        if drop > 256:
            del self.deltas[:drop], self.node_poses[:drop], self.frame_cues[:drop]
            self.dbase += drop
        parents = self.graph.skeleton.parents
        pose = _aligned(pose_vectors(rot, trans, parents, self.index.layout), node)
        out_rot, out_trans = place_local_poses(
            rot, trans, parents, self.index.layout, pose + corr, np.ones(K, dtype=bool)
        )
        nodes = nodes_of(first, first + K)
        if cue is not None:
            out_rot = self._imposed(cue, out_rot, nodes)
        contacts = self.graph.node_contacts[nodes]
        return self.hold.apply(out_rot, out_trans, rot, trans, contacts), out_trans

    def _imposed(self, cue: np.ndarray, rot: np.ndarray, nodes: np.ndarray) -> np.ndarray:
        """rot (K, J, 4) with the measured orientation cue (K, W·S) of its frames imposed."""
        return impose_at_nodes(self.graph, rot, cue.reshape(rot.shape[0], len(self.graph.sensor_names), -1), nodes)


def refine_motion(
    graph: MotionGraph,
    motion: Motion,
    nodes: np.ndarray,
    index: RefineIndex,
    acc: np.ndarray,
    smooth_frames: float,
    up: np.ndarray | None = None,
    weight: float = 0.0,
) -> Motion:
    """A path's motion (its nodes (T,)) with its poses corrected from the accelerations
    (T, S, 3) m/s² of its T frames (and their orientation cue (T, S, W) weighed by
    weight, where given) and then filtered (`synthesis.smooth`, σ in frames): what a
    `StreamingSynthesizer` with a `Refiner` gives, all at once."""
    r = Refiner(graph, index, weight if up is not None else 0.0)
    for t, a in enumerate(acc):
        r.push(a, None if up is None else up[t])
    r.finish()
    nodes = np.asarray(nodes, dtype=np.int64)
    rot, trans = r.correct(0, motion.rotations, motion.translations, lambda lo, hi: nodes[lo:hi], nodes.size - 1)
    rot, trans = smooth_poses(rot, trans, smooth_frames)
    return Motion(motion.skeleton, rot, trans, motion.rate_hz, name=motion.name, source=motion.source)


def warm_up_refine(graph: MotionGraph) -> None:
    """The index over the whole graph made (its arrays written beside the graph file)
    and the kernels compiled or loaded, so that a session's first frames do not wait."""
    index = refine_index(graph)
    if imposes(graph):
        clip_sensor_placements(graph)  # (each clip's placement, for imposing measured orientations)
    nodes = np.arange(min(2, graph.num_nodes), dtype=np.int64)
    rot, trans = node_rotations(graph, nodes), node_translations(graph, nodes)
    pose = pose_vectors(rot, trans, graph.skeleton.parents, index.layout)
    rot2, trans2 = place_local_poses(rot, trans, graph.skeleton.parents, index.layout, pose, np.ones(nodes.size, bool))
    FootHold(graph.skeleton, index.rate_hz, index.mapping).apply(
        rot2, trans2, rot, trans, np.ones((nodes.size, 2), dtype=bool)
    )
    if index.windows.shape[0]:
        regress(index, index.windows[:1])  # (the neighbour search and the regression compiled or loaded)

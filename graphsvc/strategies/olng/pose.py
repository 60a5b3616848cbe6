"""OLNG pose synthesis (Tautges et al. 2011, §5; Tautges 2012, §3.5): the pose that
best agrees with the neighbourhood's frames and with the measured accelerations,
found in a weighted-PCA subspace of the neighbours' poses.

A pose is a vector p: the pelvis rotation with its frame's heading taken off (4), the
pelvis height (1, m), and the local rotation of each joint under the pelvis (4 each),
every quaternion on the w ≥ 0 side (aligned to the previous pose before a PCA). Its
joint positions x are taken in the frame's own heading frame, from the ground point
under the pelvis (FK with the pelvis at (0, height, 0)), so they say nothing of where
the performer stands or faces; the root's motion is made apart (`strategies.olng.
decoder`).

Energy, for the I neighbours i with weights wᵢ (Tautges et al. 2011, eq. 2–11), over
the pose x of frame t + 1 given the output poses x_t, x_{t−1}:

- E_pose   = Σ wᵢ ρ(qᵢ − q): the quaternions, all joints stacked;
- E_motion = Σ wᵢ ρ(x'ᵢ − x), x'ᵢ = x_t + vᵢΔt + ½aᵢΔt², with vᵢ the central velocity
  and aᵢ the acceleration of the neighbour's joints at its frame before, so that
  vᵢΔt + ½aᵢΔt² is exactly the neighbour's own step into its frame;
- E_smooth = Σ wᵢ Δt² ρ(aᵢ − a), a = (x − 2x_t + x_{t−1}) / Δt²: Δt², not the
  paper's Δt, so that every position term is in metres (with Δt the smoothness term is
  `rate` times stiffer than the motion term: at 30 Hz it pinned each pose to the
  previous two and cost a noise-free run of the procedural knowledge base 3.8 cm of
  joint error, 4.9 against 1.1 cm);
- E_contr  = Σ wᵢ ρ(x̃ᵢ − ⟨x⟩) on the sensors' points, x̃ᵢ = x_t + vᵢΔt + ½α̂Δt², α̂ the
  measured acceleration turned into the heading frame by the sensor's orientation in
  the previous output pose, gravity removed, less the neighbours' weighted ground
  acceleration (the positions are relative to the ground point);

E = w_prior (w_pose E_pose + w_motion E_motion + w_smooth E_smooth) + w_contr E_contr,
the paper's weights by default (`OlngOptions`). ρ(d) = √(|d|² + ε²) stands for the
paper's |d|: the same away from zero, and smooth at zero, where the norm's gradient is
undefined and a quasi-Newton method stalls (ε = 1e-4 in the terms' units).

The subspace keeps the leading principal directions of the neighbours' weighted pose
covariance until they hold 99 % of its variance; the search starts from the previous
pose projected into it (the first frame: the heaviest neighbour's) and runs L-BFGS on
the energy and its analytic gradient, all inside numba (`_minimise`, `lbfgs`: the steps
and stopping rules of scipy's L-BFGS-B, whose Python driver cost about 0.2 ms an
iteration around this energy): one pass computes FK, the four terms, and the gradient
back through the tree (each joint's rotation moves its descendants) and through the
quaternions' normalisation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from graphsvc.blas import one_thread
from graphsvc.errors import InputError
from graphsvc.graph.metadata import graph_placement
from graphsvc.graph.model import MotionGraph
from graphsvc.graph.poses import node_rotations, node_translations
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import qmul4 as _qmul
from graphsvc.motion.kinematics import qrot3 as _qrot
from graphsvc.motion.placement import joint_tables
from graphsvc.sensors.accelerometer import carried_frame
from graphsvc.strategies.olng import lbfgs
from graphsvc.synthesis.local_pose import pose_layout, pose_vectors

EPS = 1e-4  # ρ's smoothing (units of each term)
VARIANCE_KEPT = 0.99
MAX_ITERATIONS = 40
GTOL = 1e-7  # the largest gradient component at which the search stops (scipy's pgtol as it was called)
EPS_MACHINE = float(np.finfo(np.float64).eps)


@dataclass(frozen=True)
class PoseModel:
    """How a graph's poses become vectors: active (Ja,) the pelvis then the joints
    under it, in topological order; parent_slot (Ja,) each active joint's parent's
    position in `active` (−1 for the pelvis); slot (Ja,) where its quaternion starts in
    the pose vector (the height is at 4); descendant (Ja, Ja) bool: joint b moves with
    joint a's rotation; sensors: the layout's points as segment and toward slots and
    `along` (the sensors' offsets off the bone are left out: the layouts place them on
    it); pelvis and carrier joints of the skeleton."""

    active: np.ndarray
    parent_slot: np.ndarray
    slot: np.ndarray
    descendant: np.ndarray
    sensor_a: np.ndarray
    sensor_b: np.ndarray
    along: np.ndarray
    sensor_rotation: np.ndarray
    pelvis: int
    carrier: int
    sensor_carrier: np.ndarray  # (S,) slot of the joint carrying a sensor's Y, −1: rigid (`layout.Placement`)
    sensor_axis: np.ndarray  # (S, 3) that axis in the carrier's frame

    @property
    def dims(self) -> int:
        return 5 + 4 * (self.active.size - 1)


def pose_model(graph: MotionGraph) -> PoseModel:
    sk = graph.skeleton
    joints = joint_map(sk, graph.params.get("mapping"))
    below, carrier = joint_tables(sk, joints)
    pelvis = joints["pelvis"]
    active = np.concatenate([[pelvis], np.flatnonzero(below)]).astype(np.int64)
    where = {int(j): k for k, j in enumerate(active)}
    parent_slot = np.array([-1] + [where[int(sk.parents[j])] for j in active[1:]], dtype=np.int64)
    slot = np.array([0] + [5 + 4 * (k - 1) for k in range(1, active.size)], dtype=np.int64)
    Ja = active.size
    descendant = np.zeros((Ja, Ja), dtype=np.bool_)
    for b in range(1, Ja):
        a = parent_slot[b]
        while a >= 0:
            descendant[a, b] = True
            a = parent_slot[a]
    placement = graph_placement(graph)
    carried = placement.carrier[placement.carrier >= 0]
    missing = [int(j) for j in np.concatenate([placement.segment, placement.toward, carried]) if int(j) not in where]
    if missing:
        raise InputError(f"OLNG needs every sensor on the body under the pelvis; joint {sk.names[missing[0]]!r} is not")
    return PoseModel(
        active,
        parent_slot,
        slot,
        descendant,
        np.array([where[int(j)] for j in placement.segment], dtype=np.int64),
        np.array([where[int(j)] for j in placement.toward], dtype=np.int64),
        np.asarray(placement.along, dtype=np.float64),
        np.asarray(placement.rotation, dtype=np.float64),
        int(pelvis),
        int(carrier),
        np.array([where[int(j)] if j >= 0 else -1 for j in placement.carrier], dtype=np.int64),
        np.asarray(placement.axis, dtype=np.float64),
    )


def frame_poses(graph: MotionGraph, model: PoseModel, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pose vectors (F, D) and heading-frame joint positions (F, Ja, 3) of graph nodes
    (module docstring), float32."""
    nodes = np.asarray(nodes, dtype=np.int64)
    F = nodes.size
    D = model.dims
    P = np.empty((F, D), np.float32)
    X = np.empty((F, model.active.size, 3), np.float32)
    layout = pose_layout(graph.skeleton, graph.params.get("mapping"))  # (its joints: model.active[1:])
    for lo in range(0, F, 65536):
        n = nodes[lo : lo + 65536]
        rot = node_rotations(graph, n)
        trans = node_translations(graph, n)
        p = pose_vectors(rot, trans, graph.skeleton.parents, layout, graph.node_heading[n].astype(np.float64))
        P[lo : lo + n.size] = p
        offsets = np.ascontiguousarray(trans[:, model.active])
        X[lo : lo + n.size] = _positions(p, offsets, model.parent_slot, model.slot)
    return P, X


@numba.njit(cache=True, nogil=True)
def _positions(p, offsets, parent_slot, slot):
    """Heading-frame positions (F, Ja, 3) of pose vectors p (F, D) with each frame's
    local offsets (F, Ja, 3)."""
    F, Ja = p.shape[0], slot.shape[0]
    x = np.empty((F, Ja, 3))
    g = np.empty((Ja, 4))
    for f in range(F):
        for k in range(Ja):
            s = slot[k]
            n = math.sqrt(p[f, s] ** 2 + p[f, s + 1] ** 2 + p[f, s + 2] ** 2 + p[f, s + 3] ** 2)
            qw, qx, qy, qz = p[f, s] / n, p[f, s + 1] / n, p[f, s + 2] / n, p[f, s + 3] / n
            if k == 0:
                g[0] = (qw, qx, qy, qz)
                x[f, 0] = (0.0, p[f, 4], 0.0)
                continue
            a = parent_slot[k]
            o = offsets[f, k]
            vx, vy, vz = _qrot(g[a, 0], g[a, 1], g[a, 2], g[a, 3], o[0], o[1], o[2])
            x[f, k] = (x[f, a, 0] + vx, x[f, a, 1] + vy, x[f, a, 2] + vz)
            g[k] = _qmul(g[a, 0], g[a, 1], g[a, 2], g[a, 3], qw, qx, qy, qz)
    return x


# ---------------------------------------------------------------- subspace


def weighted_pca(P: np.ndarray, w: np.ndarray, kept: float = VARIANCE_KEPT) -> tuple[np.ndarray, np.ndarray, float]:
    """Mean (D,), basis (D, d) (orthonormal columns, largest variance first) and the
    share of the weighted variance it holds, for the fewest directions holding at
    least `kept` of it (none when the poses are all the same)."""
    P = np.asarray(P, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    w = w / w.sum()
    # On one BLAS thread: the same basis however many threads BLAS has, and cheaper:
    # OpenBLAS's threads on a 100-odd-square eigendecomposition cost far more than they
    # bring (one eigh of 133 × 133 on a loaded machine: 230 ms of CPU with its threads,
    # 1.7–4 ms without).
    with one_thread():
        mean = w @ P
        Y = (P - mean) * np.sqrt(w)[:, None]
        if Y.shape[0] < Y.shape[1]:  # fewer poses than dimensions: through the (I, I) Gram matrix
            values, u = np.linalg.eigh(Y @ Y.T)
            values, u = np.maximum(values[::-1], 0.0), u[:, ::-1]
            vectors = Y.T @ u / np.sqrt(np.maximum(values, 1e-300))
        else:
            values, vectors = np.linalg.eigh(Y.T @ Y)
            values, vectors = np.maximum(values[::-1], 0.0), vectors[:, ::-1]
    total = values.sum()
    if not total > 1e-18:
        return mean, np.zeros((P.shape[1], 0)), 1.0
    share = np.cumsum(values) / total
    d = int(np.searchsorted(share, kept - 1e-12) + 1)
    return mean, np.ascontiguousarray(vectors[:, :d]), float(share[d - 1])


# ---------------------------------------------------------------- energy


@dataclass
class EnergyTerms:
    """Everything the energy of one frame reads, as arrays (module docstring). Q (I, D)
    the neighbours' pose vectors; w (I,); offsets (Ja, 3) the output's bone offsets;
    motion (I, Ja, 3) x'ᵢ; accel (I, Ja, 3) aᵢ; control (I, S, 3) x̃ᵢ; x_t, x_tm1
    (Ja, 3) the previous output poses' positions (zeros when not used); weights
    (w_pose, w_motion, w_smooth, w_contr) already multiplied by w_prior where it
    applies, 0 for a term the frame has no data for; rate (Hz)."""

    Q: np.ndarray
    w: np.ndarray
    offsets: np.ndarray
    motion: np.ndarray
    accel: np.ndarray
    control: np.ndarray
    x_t: np.ndarray
    x_tm1: np.ndarray
    weights: np.ndarray
    rate: float


@numba.njit(cache=True, nogil=True)
def _energy(
    z,
    mean,
    basis,
    Q,
    w,
    offsets,
    motion,
    accel,
    control,
    x_t,
    x_tm1,
    weights,
    rate,
    parent_slot,
    slot,
    descendant,
    sensor_a,
    sensor_b,
    along,
    grad,
):
    """E at subspace point z (d,); its gradient into grad (d,)."""
    D, d = basis.shape
    Ja = slot.shape[0]
    I = Q.shape[0]
    S = sensor_a.shape[0]
    p = mean.copy()
    for c in range(d):
        for r in range(D):
            p[r] += basis[r, c] * z[c]
    qh = np.empty((Ja, 4))
    norm = np.empty(Ja)
    for k in range(Ja):
        s = slot[k]
        n = math.sqrt(p[s] ** 2 + p[s + 1] ** 2 + p[s + 2] ** 2 + p[s + 3] ** 2)
        norm[k] = n
        for c in range(4):
            qh[k, c] = p[s + c] / n
    g = np.empty((Ja, 4))
    x = np.empty((Ja, 3))
    g[0] = qh[0]
    x[0] = (0.0, p[4], 0.0)
    for k in range(1, Ja):
        a = parent_slot[k]
        vx, vy, vz = _qrot(g[a, 0], g[a, 1], g[a, 2], g[a, 3], offsets[k, 0], offsets[k, 1], offsets[k, 2])
        x[k] = (x[a, 0] + vx, x[a, 1] + vy, x[a, 2] + vz)
        g[k] = _qmul(g[a, 0], g[a, 1], g[a, 2], g[a, 3], qh[k, 0], qh[k, 1], qh[k, 2], qh[k, 3])
    gq = np.zeros((Ja, 4))
    gx = np.zeros((Ja, 3))
    E = 0.0
    eps2 = EPS * EPS
    w_pose, w_motion, w_smooth, w_contr = weights[0], weights[1], weights[2], weights[3]
    for i in range(I):
        if w_pose > 0.0:
            r2 = 0.0
            for k in range(Ja):
                s = slot[k]
                for c in range(4):
                    r2 += (qh[k, c] - Q[i, s + c]) ** 2
            rho = math.sqrt(r2 + eps2)
            E += w_pose * w[i] * rho
            f = w_pose * w[i] / rho
            for k in range(Ja):
                s = slot[k]
                for c in range(4):
                    gq[k, c] += f * (qh[k, c] - Q[i, s + c])
        if w_motion > 0.0:
            r2 = 0.0
            for k in range(Ja):
                for c in range(3):
                    r2 += (x[k, c] - motion[i, k, c]) ** 2
            rho = math.sqrt(r2 + eps2)
            E += w_motion * w[i] * rho
            f = w_motion * w[i] / rho
            for k in range(Ja):
                for c in range(3):
                    gx[k, c] += f * (x[k, c] - motion[i, k, c])
        if w_smooth > 0.0:
            r2 = 0.0
            h2 = rate * rate
            for k in range(Ja):
                for c in range(3):
                    r2 += ((x[k, c] - 2.0 * x_t[k, c] + x_tm1[k, c]) * h2 - accel[i, k, c]) ** 2
            rho = math.sqrt(r2 + eps2)
            E += w_smooth * w[i] / h2 * rho
            f = w_smooth * w[i] / rho
            for k in range(Ja):
                for c in range(3):
                    gx[k, c] += f * ((x[k, c] - 2.0 * x_t[k, c] + x_tm1[k, c]) * h2 - accel[i, k, c])
        if w_contr > 0.0 and S > 0:
            r2 = 0.0
            for m in range(S):
                a, b, al = sensor_a[m], sensor_b[m], along[m]
                for c in range(3):
                    r2 += ((1.0 - al) * x[a, c] + al * x[b, c] - control[i, m, c]) ** 2
            rho = math.sqrt(r2 + eps2)
            E += w_contr * w[i] * rho
            f = w_contr * w[i] / rho
            for m in range(S):
                a, b, al = sensor_a[m], sensor_b[m], along[m]
                for c in range(3):
                    e = (1.0 - al) * x[a, c] + al * x[b, c] - control[i, m, c]
                    gx[a, c] += f * (1.0 - al) * e
                    gx[b, c] += f * al * e
    # Back through FK: joint k's rotation turns every descendant b about x_k.
    gp = np.zeros(D)
    for k in range(Ja):
        gp[4] += gx[k, 1]  # every position rises with the pelvis
    for k in range(Ja):
        qw, ux, uy, uz = qh[k, 0], qh[k, 1], qh[k, 2], qh[k, 3]
        a = parent_slot[k]
        if a >= 0:
            pw, px, py, pz = g[a, 0], g[a, 1], g[a, 2], g[a, 3]
        else:
            pw, px, py, pz = 1.0, 0.0, 0.0, 0.0
        dw, dx, dy, dz = gq[k, 0], gq[k, 1], gq[k, 2], gq[k, 3]
        for b in range(Ja):
            if not descendant[k, b]:
                continue
            # r = x_b − x_k = G_par R(q) v; v = R(q)ᵀ G_parᵀ r, g' = G_parᵀ g_b.
            rx, ry, rz = _qrot(pw, -px, -py, -pz, x[b, 0] - x[k, 0], x[b, 1] - x[k, 1], x[b, 2] - x[k, 2])
            vx, vy, vz = _qrot(qw, -ux, -uy, -uz, rx, ry, rz)
            hx, hy, hz = _qrot(pw, -px, -py, -pz, gx[b, 0], gx[b, 1], gx[b, 2])
            # d/dw [h·R(q)v] = 2 h·(u × v); d/du = 2w (v × h) + 2 [h (u·v) + v (h·u) − 2u (h·v)]
            cx, cy, cz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
            dw += 2.0 * (hx * cx + hy * cy + hz * cz)
            uv = ux * vx + uy * vy + uz * vz
            hu = hx * ux + hy * uy + hz * uz
            hv = hx * vx + hy * vy + hz * vz
            dx += 2.0 * qw * (vy * hz - vz * hy) + 2.0 * (hx * uv + vx * hu - 2.0 * ux * hv)
            dy += 2.0 * qw * (vz * hx - vx * hz) + 2.0 * (hy * uv + vy * hu - 2.0 * uy * hv)
            dz += 2.0 * qw * (vx * hy - vy * hx) + 2.0 * (hz * uv + vz * hu - 2.0 * uz * hv)
        # Through the normalisation q̂ = p / |p|: (I − q̂q̂ᵀ) / |p|.
        dot = dw * qw + dx * ux + dy * uy + dz * uz
        s = slot[k]
        n = norm[k]
        gp[s] += (dw - dot * qw) / n
        gp[s + 1] += (dx - dot * ux) / n
        gp[s + 2] += (dy - dot * uy) / n
        gp[s + 3] += (dz - dot * uz) / n
    for c in range(d):
        acc = 0.0
        for r in range(D):
            acc += basis[r, c] * gp[r]
        grad[c] = acc
    return E


def energy(z, mean, basis, terms: EnergyTerms, model: PoseModel) -> tuple[float, np.ndarray]:
    """E (module docstring) at subspace point z and its gradient (d,)."""
    grad = np.empty(basis.shape[1])
    e = _energy(
        np.asarray(z, dtype=np.float64),
        mean,
        basis,
        terms.Q,
        terms.w,
        terms.offsets,
        terms.motion,
        terms.accel,
        terms.control,
        terms.x_t,
        terms.x_tm1,
        terms.weights,
        float(terms.rate),
        model.parent_slot,
        model.slot,
        model.descendant,
        model.sensor_a,
        model.sensor_b,
        model.along,
        grad,
    )
    return float(e), grad


@numba.njit(cache=True, nogil=True)
def _minimise(
    z0,
    max_iterations,
    gtol,
    mean,
    basis,
    Q,
    w,
    offsets,
    motion,
    accel,
    control,
    x_t,
    x_tm1,
    weights,
    rate,
    parent_slot,
    slot,
    descendant,
    sensor_a,
    sensor_b,
    along,
):
    """L-BFGS on the energy from z0 (`lbfgs`: L-BFGS-B's steps without bounds):
    (z, E, iterations, evaluations)."""
    n = z0.shape[0]
    S = np.zeros((lbfgs.MEMORY, n))
    Y = np.zeros((lbfgs.MEMORY, n))
    rho = np.zeros(lbfgs.MEMORY)
    alpha = np.zeros(lbfgs.MEMORY)
    state = np.zeros(lbfgs.STATE_SIZE)
    x = z0.copy()
    g = np.empty(n)
    trial = np.empty(n)
    g_trial = np.empty(n)
    d = np.empty(n)
    f = _energy(
        x,
        mean,
        basis,
        Q,
        w,
        offsets,
        motion,
        accel,
        control,
        x_t,
        x_tm1,
        weights,
        rate,
        parent_slot,
        slot,
        descendant,
        sensor_a,
        sensor_b,
        along,
        g,
    )
    evaluations = 1
    if np.max(np.abs(g)) <= gtol:
        return x, f, 0, evaluations
    count = 0
    head = lbfgs.MEMORY - 1
    iterations = 0
    while True:
        lbfgs.direction(g, S, Y, rho, count, head, d, alpha)
        gd = 0.0
        dd = 0.0
        for c in range(n):
            gd += g[c] * d[c]
            dd += d[c] * d[c]
        stp = min(1.0 / math.sqrt(dd), lbfgs.STEP_MAX) if iterations == 0 else 1.0
        failed = not gd < 0.0
        f_trial = f
        if not failed:
            lbfgs.search_start(f, gd, stp, state)
            trials = 0
            while True:
                for c in range(n):
                    trial[c] = x[c] + stp * d[c]
                f_trial = _energy(
                    trial,
                    mean,
                    basis,
                    Q,
                    w,
                    offsets,
                    motion,
                    accel,
                    control,
                    x_t,
                    x_tm1,
                    weights,
                    rate,
                    parent_slot,
                    slot,
                    descendant,
                    sensor_a,
                    sensor_b,
                    along,
                    g_trial,
                )
                evaluations += 1
                trials += 1
                gd_trial = 0.0
                for c in range(n):
                    gd_trial += g_trial[c] * d[c]
                verdict, stp = lbfgs.search_step(f_trial, gd_trial, stp, state)
                if verdict == lbfgs.SEARCH_DONE:
                    break
                if trials >= lbfgs.MAX_TRIALS:
                    failed = True
                    break
        if failed:  # the last point stays; restart from −g, or stop with no memory left
            if count == 0:
                return x, f, iterations, evaluations
            count = 0
            continue
        iterations += 1
        f_old = f
        # The pair s = stp·d, y = g_trial − g, kept when sᵀy > ε_mach · (−gᵀs).
        nxt = (head + 1) % lbfgs.MEMORY
        sy = 0.0
        for c in range(n):
            s_c = trial[c] - x[c]
            y_c = g_trial[c] - g[c]
            S[nxt, c] = s_c
            Y[nxt, c] = y_c
            sy += s_c * y_c
            x[c] = trial[c]
            g[c] = g_trial[c]
        f = f_trial
        if iterations >= max_iterations:
            break
        if np.max(np.abs(g)) <= gtol:
            break
        if f_old - f <= lbfgs.REL_REDUCTION * max(abs(f_old), abs(f), 1.0):
            break
        if sy > EPS_MACHINE * (-gd * stp):
            head = nxt
            rho[head] = 1.0 / sy
            count = min(count + 1, lbfgs.MEMORY)
    return x, f, iterations, evaluations


def optimise(
    mean: np.ndarray,
    basis: np.ndarray,
    start: np.ndarray,
    terms: EnergyTerms,
    model: PoseModel,
    max_iterations: int = MAX_ITERATIONS,
) -> tuple[np.ndarray, float, int]:
    """The pose vector (D,) minimising the energy in the subspace, from pose `start`
    (D,) projected into it; its energy and the iterations taken (`_minimise`)."""
    z0 = basis.T @ (np.asarray(start, dtype=np.float64) - mean)
    if basis.shape[1] == 0:
        e, _ = energy(z0, mean, basis, terms, model)
        return mean.copy(), e, 0
    z, e, iterations, _ = _minimise(
        np.ascontiguousarray(z0),
        int(max_iterations),
        GTOL,
        mean,
        np.ascontiguousarray(basis),
        terms.Q,
        terms.w,
        terms.offsets,
        terms.motion,
        terms.accel,
        terms.control,
        terms.x_t,
        terms.x_tm1,
        terms.weights,
        float(terms.rate),
        model.parent_slot,
        model.slot,
        model.descendant,
        model.sensor_a,
        model.sensor_b,
        model.along,
    )
    return mean + basis @ z, float(e), int(iterations)


def pose_positions(p: np.ndarray, offsets: np.ndarray, model: PoseModel) -> np.ndarray:
    """Heading-frame joint positions (Ja, 3) of one pose vector."""
    return _positions(
        np.asarray(p, dtype=np.float64)[None],
        np.ascontiguousarray(offsets, dtype=np.float64)[None],
        model.parent_slot,
        model.slot,
    )[0]


def sensor_orientations(p: np.ndarray, model: PoseModel) -> np.ndarray:
    """Heading-frame orientations (S, 4) of the sensors in pose p: each segment's
    global rotation times the sensor's rotation on it (a carried sensor's:
    `accelerometer.carried_frame`)."""
    Ja = model.active.size
    g = np.empty((Ja, 4))
    for k in range(Ja):
        s = model.slot[k]
        q = np.asarray(p[s : s + 4], dtype=np.float64)
        q = q / np.linalg.norm(q)
        g[k] = q if k == 0 else _qmul(*g[model.parent_slot[k]], *q)
    out = np.empty((model.sensor_a.size, 4))
    for m in range(model.sensor_a.size):
        c = model.sensor_carrier[m]
        if c < 0:
            out[m] = _qmul(*g[model.sensor_a[m]], *model.sensor_rotation[m])
        else:
            carried_frame(g[model.sensor_a[m]], model.sensor_rotation[m], g[c], model.sensor_axis[m], out[m])
    return out

"""A motion unit from its mode coefficients, its virtual sensors' readings, and the
coefficients fitted to measured readings (Tautges 2012, eq. 2.3–2.4 and 2.8).

A unit of L frames: M + m(x_S, x_R) (`model.Tensor.values`, on the tensor's F reference frames)
played at the times τ(s_k)·(F − 1), s_k = k/(L − 1), where τ is the normalised integral
of the rate exp(Σ_j w_j cos(jπs)), j = 1 … J — a smooth, monotone time warp onto the
unit's frames, uniform at w = 0, with J = 1 term for a step and WHOLE_TERMS for a whole
clip (a gesture's repeats need not keep the reference's pace), each |w_j| ≤ WARP_LIMIT
— (`model.warp_values`); its poses put on the tensor's template skeleton at the track
its own steps and turns integrate from the origin; the layout's accelerometers
simulated on it (`sensors.accelerometer.simulate_accelerations`, g). Accelerations in
each sensor's own frame do not change when the unit is turned about the vertical or
moved, so the fit needs no alignment of the unit to the recording (the thesis aligns
world accelerations by a rotation about the vertical, eq. 2.10).

The fit (`fit_unit`): scipy's `least_squares` (trust-region reflective, a numeric
Jacobian: kS + kR coefficients and the J warp weights, a few dozen residual evaluations of well under a
millisecond) of the simulated readings against the measured ones over the unit's
frames inside the recording (the first and last frame left out: their second
derivative is one-sided), plus `prior`·(x − x₀) pulling toward the starting row's
coefficients x₀ (and the warp toward uniform). The fit starts from each of the
STARTS original units (s, r) whose own readings, put on the unit's frames, are closest
to the measured ones, and keeps the cheapest result.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from graphsvc.blas import one_thread
from graphsvc.graph import metadata as meta
from graphsvc.graph.model import MotionGraph
from graphsvc.graph.poses import node_rotations, node_translations
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.motion.placement import place_poses
from graphsvc.sensors.accelerometer import GRAVITY, simulate_accelerations
from graphsvc.strategies.multilinear import tensor as tn
from graphsvc.strategies.multilinear.model import Tensor, warp_values
from graphsvc.synthesis.local_pose import PoseLayout, pose_layout

WARP_LIMIT = 1.5
WHOLE_TERMS = 4
STARTS = 3


@dataclass
class Body:
    """What a unit is put on: the skeleton's parents, the pose layout, a template
    frame's local rotations and translations (J, 4/3), the sensors' placement and rate."""

    parents: np.ndarray
    layout: PoseLayout
    rot: np.ndarray
    trans: np.ndarray
    placement: object
    rate_hz: float


def graph_body(graph: MotionGraph, node: int = 0) -> Body:
    """The graph's skeleton at node `node`'s translations, with its layout's placement."""
    parents = np.ascontiguousarray(graph.skeleton.parents, dtype=np.int64)
    return Body(
        parents,
        pose_layout(graph.skeleton, graph.params.get("mapping")),
        node_rotations(graph, node),
        node_translations(graph, node),
        meta.graph_placement(graph),
        float(graph.rate_hz),
    )


def unit_times(frames: int, length: int, warp=()) -> np.ndarray:
    """(length,) reference-frame times of a unit of `length` frames under the warp
    weights `warp` (J,) (module docstring)."""
    if length == 1:
        return np.zeros(1)
    s = np.linspace(0.0, 1.0, length)
    w = np.asarray(warp, dtype=np.float64)
    if w.size == 0 or not w.any():
        return s * (frames - 1)
    rate = np.exp(np.cos(np.pi * np.outer(s, np.arange(1, w.size + 1))) @ w)
    tau = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]))])
    return tau / tau[-1] * (frames - 1)


def unit_values(t: Tensor, x_s: np.ndarray, x_r: np.ndarray, length: int, warp, pose_dims: int) -> np.ndarray:
    """(length, V) the values of the unit M + m(x_S, x_R) on `length` frames."""
    return warp_values(t.values(x_s, x_r), unit_times(t.frames, length, warp), pose_dims)


class UnitPlayer:
    """`unit_values` of one tensor on L frames for many (x_S, x_R, warp), as the fit asks
    for them: the core as one (V·F, kS·kR) matrix (a product with x_S ⊗ x_R, where
    numpy's einsum spent most of its time planning), the warp's times kept while the
    warp stays (a numeric Jacobian moves one parameter at a time, most of them
    coefficients). (The warp as dense (L, F) interpolation matrices was tried: quicker
    for a step, three times slower for a gesture's few hundred frames.)"""

    def __init__(self, t: Tensor, length: int, pose_dims: int):
        V, F, kS, kR = t.core_t.shape
        self.core = np.ascontiguousarray(t.core_t.reshape(V * F, kS * kR), dtype=np.float64)
        self.mean = np.asarray(t.mean, dtype=np.float64)
        self.frames, self.length, self.d = F, length, pose_dims
        self.shape = (V, F)
        self._key: bytes | None = None
        self._times: np.ndarray | None = None

    def __call__(self, x_s: np.ndarray, x_r: np.ndarray, warp) -> np.ndarray:
        w = np.ascontiguousarray(warp, dtype=np.float64)
        key = w.tobytes()
        if key != self._key or self._times is None:
            self._times = unit_times(self.frames, self.length, w)
            self._key = key
        base = (self.mean + (self.core @ np.outer(x_s, x_r).reshape(-1)).reshape(self.shape)).T  # (F, V)
        return warp_values(base, self._times, self.d)


def local_frames(values: np.ndarray, body: Body) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Values (L, V) as local rotations (L, J, 4) and translations (L, J, 3) of the
    template (quaternions normalised), the pelvis' relative rotation (L, 4) and height (L,)."""
    L, lay = values.shape[0], body.layout
    rot = np.repeat(body.rot[None], L, axis=0)
    trans = np.repeat(body.trans[None], L, axis=0)
    q = values[:, 5 : lay.dims].reshape(L, -1, 4)
    rot[:, lay.joints] = q / np.maximum(np.sqrt((q * q).sum(axis=2))[:, :, None], 1e-12)
    r = values[:, 0:4]
    rel = r / np.maximum(np.sqrt((r * r).sum(axis=1))[:, None], 1e-12)
    return rot, trans, rel, values[:, 4].copy()


def placed(rot, trans, rel, height, ground, heading, body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Local frames put at ground (L, 2) m and heading (L,) rad (in place; returned)."""
    src_rot, src_pos = forward_kinematics(rot, trans, body.parents)
    place_poses(
        rot,
        trans,
        np.ascontiguousarray(rel),
        np.ascontiguousarray(height),
        np.ascontiguousarray(ground),
        np.ascontiguousarray(heading),
        src_rot,
        src_pos,
        body.parents,
        body.layout.pelvis,
        body.layout.carrier,
    )
    return rot, trans


def simulate_unit(values: np.ndarray, body: Body) -> np.ndarray:
    """(L, S, 3) the layout's readings (g) of a unit's values, on its own track."""
    d = body.layout.dims
    ground, heading = meta.integrate_path(np.zeros(2), 0.0, values[1:, d : d + 2], values[1:, d + 2])
    rot, trans = placed(*local_frames(values, body), ground, heading, body)
    world_rot, world_pos = forward_kinematics(rot, trans, body.parents)
    return simulate_accelerations(world_rot, world_pos, body.placement, body.rate_hz).astype(np.float64) / GRAVITY


@dataclass
class UnitFit:
    x_s: np.ndarray
    x_r: np.ndarray
    warp: np.ndarray  # (J,)
    values: np.ndarray  # (L, V)
    cost: float  # mean squared reading residual, g²
    start_cost: float  # the best starting row's
    start_row: int
    evaluations: int


def start_rows(t: Tensor, measured: np.ndarray, inside: np.ndarray, count: int) -> list[tuple[int, float]]:
    """The `count` original rows whose readings on the unit's frames are nearest the
    measured (L, 3S) g on frames `inside` (bool (L,)), with their mean squared distances."""
    times = unit_times(t.frames, measured.shape[0])
    costs = []
    for k in range(t.row_readings.shape[0]):
        e = tn.sample(np.asarray(t.row_readings[k], np.float64), times)[inside] - measured[inside]
        costs.append(float(np.mean(e * e)) if e.size else 0.0)
    order = np.argsort(costs, kind="stable")[:count]
    return [(int(k), costs[int(k)]) for k in order]


@one_thread()  # (the same fit however many threads BLAS has: graphsvc.blas)
def fit_unit(
    t: Tensor, measured: np.ndarray, inside: np.ndarray, body: Body, prior: float, warp: bool, evaluations: int
) -> UnitFit:
    """The coefficients (and warp) of tensor t's unit best explaining `measured` (L, S, 3)
    g on frames `inside` (L,) bool (module docstring)."""
    L = measured.shape[0]
    m = measured.reshape(L, -1)
    finite = np.all(np.isfinite(m), axis=1)
    use = inside & finite
    if L > 2:  # (one-sided second derivatives at the ends)
        use[0] = use[-1] = False
    kS, kR = t.kept
    J = (1 if t.foot >= 0 else WHOLE_TERMS) if warp else 0
    d = body.layout.dims
    count = int(use.sum()) * m.shape[1]
    scale = 1.0 / np.sqrt(max(count, 1))
    R = t.u_rep.shape[0]
    best = None
    play = UnitPlayer(t, L, d)
    for row, _ in start_rows(t, m, inside & finite, STARTS):
        p0 = np.concatenate([*t.row_coefficients(row // R, row % R), np.zeros(J)])

        def values_of(p):
            return play(p[:kS], p[kS : kS + kR], p[kS + kR :])

        def residual(p, p0=p0, values_of=values_of):
            sim = simulate_unit(values_of(p), body).reshape(L, -1)
            return np.concatenate([(sim[use] - m[use]).reshape(-1) * scale, prior * (p - p0)])

        if count == 0:
            return UnitFit(p0[:kS], p0[kS : kS + kR], np.zeros(J), values_of(p0), 0.0, 0.0, row, 0)
        start = residual(p0)
        lo, hi = np.full(p0.size, -np.inf), np.full(p0.size, np.inf)
        lo[kS + kR :], hi[kS + kR :] = -WARP_LIMIT, WARP_LIMIT
        sol = least_squares(residual, p0, bounds=(lo, hi), method="trf", max_nfev=evaluations)
        p = sol.x
        fit = UnitFit(
            p[:kS].copy(),
            p[kS : kS + kR].copy(),
            p[kS + kR :].copy(),
            values_of(p),
            float(np.mean((sol.fun[:count] / scale) ** 2)),
            float(np.mean((start[:count] / scale) ** 2)),
            row,
            int(sol.nfev),
        )
        if best is None or fit.cost < best.cost:
            best = replace(
                fit,
                evaluations=fit.evaluations + (best.evaluations if best else 0),
                start_cost=min(fit.start_cost, best.start_cost) if best else fit.start_cost,
            )
        else:
            best = replace(best, evaluations=best.evaluations + fit.evaluations)
    return best

"""A motion unit from its mode coefficients, its virtual sensors' readings, and the
coefficients fitted to measured readings (Tautges 2012, eq. 2.3–2.4 and 2.8).

A unit of L frames: M + m(x_S, x_R) (`model.Tensor.values`, on the tensor's F reference frames)
played at the times u_k·(F − 1), u_k = s + b·s(1 − s) for s = k/(L − 1) — a uniform
time warp onto the unit's frames, bent by b ∈ (−BEND, BEND) (b = 0: uniform) —
(`model.warp_values`); its poses put on the tensor's template skeleton at the track
its own steps and turns integrate from the origin; the layout's accelerometers
simulated on it (`sensors.accelerometer.simulate_accelerations`, g). Accelerations in
each sensor's own frame do not change when the unit is turned about the vertical or
moved, so the fit needs no alignment of the unit to the recording (the thesis aligns
world accelerations by a rotation about the vertical, eq. 2.10).

The fit (`fit_unit`): scipy's `least_squares` (trust-region reflective, a numeric
Jacobian: 2 + kS + kR coefficients, a few dozen residual evaluations of well under a
millisecond) of the simulated readings against the measured ones over the unit's
frames inside the recording (the first and last frame left out: their second
derivative is one-sided), plus `prior`·(x − x₀) pulling toward the starting row's
coefficients x₀. The starting row is the original unit (s, r) whose own readings, put
on the unit's frames, are closest to the measured ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from graphsvc.graph import metadata as meta
from graphsvc.graph.model import MotionGraph
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.motion.placement import place_poses
from graphsvc.sensors.accelerometer import GRAVITY, simulate_accelerations
from graphsvc.strategies.multilinear import tensor as tn
from graphsvc.strategies.multilinear.model import Tensor, warp_values
from graphsvc.synthesis.local_pose import PoseLayout, pose_layout

BEND = 0.6


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
    return Body(parents, pose_layout(graph.skeleton, graph.params.get("mapping")),
                graph.node_rotations[node].astype(np.float64), graph.node_translations[node].astype(np.float64),
                meta.graph_placement(graph), float(graph.rate_hz))  # fmt: skip


def unit_times(frames: int, length: int, bend: float = 0.0) -> np.ndarray:
    """(length,) reference-frame times of a unit of `length` frames (module docstring)."""
    if length == 1:
        return np.zeros(1)
    s = np.linspace(0.0, 1.0, length)
    return (s + bend * s * (1.0 - s)) * (frames - 1)


def unit_values(t: Tensor, x_s: np.ndarray, x_r: np.ndarray, length: int, bend: float, pose_dims: int) -> np.ndarray:
    """(length, V) the values of the unit m(x_S, x_R) on `length` frames."""
    return warp_values(t.values(x_s, x_r), unit_times(t.frames, length, bend), pose_dims)


def local_frames(values: np.ndarray, body: Body) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Values (L, V) as local rotations (L, J, 4) and translations (L, J, 3) of the
    template (quaternions normalised), the pelvis' relative rotation (L, 4) and height (L,)."""
    L, lay = values.shape[0], body.layout
    rot = np.repeat(body.rot[None], L, axis=0)
    trans = np.repeat(body.trans[None], L, axis=0)
    q = values[:, 5: lay.dims].reshape(L, -1, 4)
    rot[:, lay.joints] = q / np.maximum(np.linalg.norm(q, axis=2, keepdims=True), 1e-12)
    rel = values[:, 0:4] / np.maximum(np.linalg.norm(values[:, 0:4], axis=1, keepdims=True), 1e-12)
    return rot, trans, rel, values[:, 4].copy()


def placed(rot, trans, rel, height, ground, heading, body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Local frames put at ground (L, 2) m and heading (L,) rad (in place; returned)."""
    src_rot, src_pos = forward_kinematics(rot, trans, body.parents)
    place_poses(rot, trans, np.ascontiguousarray(rel), np.ascontiguousarray(height), np.ascontiguousarray(ground),
                np.ascontiguousarray(heading), src_rot, src_pos, body.parents, body.layout.pelvis,
                body.layout.carrier)  # fmt: skip
    return rot, trans


def simulate_unit(values: np.ndarray, body: Body) -> np.ndarray:
    """(L, S, 3) the layout's readings (g) of a unit's values, on its own track."""
    d = body.layout.dims
    ground, heading = meta.integrate_path(np.zeros(2), 0.0, values[1:, d: d + 2], values[1:, d + 2])
    rot, trans = placed(*local_frames(values, body), ground, heading, body)
    world_rot, world_pos = forward_kinematics(rot, trans, body.parents)
    return simulate_accelerations(world_rot, world_pos, body.placement, body.rate_hz).astype(np.float64) / GRAVITY


@dataclass
class UnitFit:
    x_s: np.ndarray
    x_r: np.ndarray
    bend: float
    values: np.ndarray  # (L, V)
    cost: float  # mean squared reading residual, g²
    start_cost: float
    start_row: int
    evaluations: int


def start_row(t: Tensor, measured: np.ndarray, inside: np.ndarray) -> tuple[int, float]:
    """The original row whose readings on the unit's frames are nearest the measured
    (L, 3S) g on frames `inside` (bool (L,)), and its mean squared distance."""
    times = unit_times(t.frames, measured.shape[0])
    best, cost = 0, np.inf
    for k in range(t.row_readings.shape[0]):
        r = tn.sample(np.asarray(t.row_readings[k], np.float64), times)
        e = r[inside] - measured[inside]
        c = float(np.nanmean(e * e))
        if c < cost:
            best, cost = k, c
    return best, cost


def fit_unit(t: Tensor, measured: np.ndarray, inside: np.ndarray, body: Body, prior: float, warp: bool,
             evaluations: int) -> UnitFit:  # fmt: skip
    """The coefficients (and bend) of tensor t's unit best explaining `measured` (L, S, 3)
    g on frames `inside` (L,) bool (module docstring)."""
    L = measured.shape[0]
    m = measured.reshape(L, -1)
    use = inside.copy()
    if L > 2:  # (one-sided second derivatives at the ends)
        use[0] = use[-1] = False
    use &= np.all(np.isfinite(m), axis=1)
    row, _ = start_row(t, m, inside & np.all(np.isfinite(m), axis=1))
    R = t.u_rep.shape[0]
    xs0, xr0 = t.row_coefficients(row // R, row % R)
    kS, kR = t.kept
    d = body.layout.dims
    p0 = np.concatenate([xs0, xr0, [0.0] if warp else []])
    n = max(int(use.sum()), 1)
    scale = 1.0 / np.sqrt(n * m.shape[1])
    pull = np.full(p0.size, prior)

    def values_of(p):
        return unit_values(t, p[:kS], p[kS: kS + kR], L, p[kS + kR] if warp else 0.0, d)

    def residual(p):
        sim = simulate_unit(values_of(p), body).reshape(L, -1)
        return np.concatenate([(sim[use] - m[use]).reshape(-1) * scale, pull * (p - p0)])

    if not use.any():
        return UnitFit(xs0, xr0, 0.0, values_of(p0), 0.0, 0.0, row, 0)
    lo, hi = np.full(p0.size, -np.inf), np.full(p0.size, np.inf)
    if warp:
        lo[-1], hi[-1] = -BEND, BEND
    start = residual(p0)
    sol = least_squares(residual, p0, bounds=(lo, hi), method="trf", max_nfev=evaluations)
    p = sol.x
    count = int(use.sum()) * m.shape[1]
    fit_res, start_res = sol.fun[:count] / scale, start[:count] / scale
    return UnitFit(p[:kS].copy(), p[kS: kS + kR].copy(), float(p[kS + kR]) if warp else 0.0, values_of(p),
                   float(np.mean(fit_res ** 2)), float(np.mean(start_res ** 2)), row, int(sol.nfev))  # fmt: skip

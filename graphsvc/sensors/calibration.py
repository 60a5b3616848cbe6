"""Mounting calibration: each sensor's rotation from its device frame to the layout's
sensor frame, from a calibration take (the performer stands still in a known pose,
then moves), and its application to device-frame recordings.

A device frame is D(t) = S(t) ⊗ M (S the layout's sensor frame in the world, M the
mounting), so a device reads M⁻¹·(what the layout's sensor reads). Calibration
estimates R = M: a_layout = R·a_device, and orientations q_layout = q_device ⊗ R⁻¹.

1. **Rest** (`find_rest`): the first stretch of ≥ 0.5 s where the most sensors are
   still at once (readings within their own window's noise of their mean, |a| ≈ g); a
   sensor not still there (an arm moving from the first sample) gets its whole rotation
   from the motion. The mean reading (or,
   with orientation output, the mean of the device frame's view of the world's
   vertical, D(t)⁻¹·ŷ, which the yaw drift leaves alone and the accelerometer's bias
   does not touch) is gravity's direction in the device frame; `POSE_READINGS` gives it
   in the layout's frame. The shortest rotation between the two fixes the tilt.
2. **Rotation about gravity** (`match_windows`): per sensor, a reading splits into its
   component p along the layout's gravity axis u and the perpendicular part, written
   as a complex number z over a basis (e1, e2) of u's plane. A rotation by θ about u
   multiplies z by e^{iθ}; for a window of device samples against a window of graph
   readings the best θ is arg Σ z_g·conj(z_d) and the residual Σ|z_d|² + Σ|z_g|² −
   2|Σ z_g·conj(z_d)| + Σ(p_d − p_g)². Every window of the take from the rest on (all
   sensors share it) slides over the graph's readings in clip order (original edges; a
   window never straddles two clips); the best-matching graph windows' complex sums,
   each weighted by how well its window matched, give θ (a weighted least-squares angle
   over all matched samples, outliers beyond `OUTLIER_DEG` dropped).
3. **Refinement** (`wahba`): for `stand` and sensors without a rest, all three degrees
   of freedom fitted (SVD) over the matched sample pairs and the rest's gravity pair
   (weighted `REST_WEIGHT`); for `npose`/`tpose` only the rotation about gravity, in
   closed form over every pair (the pose fixes the tilt) — but a T-pose fixes only that
   an arm's bone is level, not its roll about the bone: arm sensors get all three (SVD)
   with a light rest term keeping the bone level (`_level_fit`), and one more round. Steps 2–3 run `ITERATIONS`
   times, each from the last estimate. With orientation output the fits also pair the
   vertical each device frame saw, D(t)⁻¹·ŷ (free of the yaw drift and of linear
   acceleration), with the matched graph frames' (`Reference.verticals`, FK of the poses
   the graph stores): the relative rotations D(t0)⁻¹D(t) = M⁻¹·S(t0)⁻¹S(t)·M tie M to
   the segment's motion, seen through gravity. A sensor the motion hardly turns off its
   rest axis (`SEEN_RATIO`) cannot show its rotation about gravity and keeps none.

Without a graph the rotation about gravity cannot be determined (a single direction
fixes two of three degrees of freedom): `calibrate_against` refuses.

The graph's part — its readings in clip order and the verticals of the poses it
stores, as a `Reference` — is `graph.calibration`, whose `calibrate(rec, pose, graph)`
is what `graphsvc calibrate` runs; this module takes the arrays.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from graphsvc.errors import CalibrationQualityError, FormatError, InputError
from graphsvc.fileio import read_json_file, write_text_atomic
from graphsvc.motion import quat
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.sensors.anatomy import ANATOMICAL, CONVENTIONS
from graphsvc.sensors.grid import readings_at_rate, uniform_grid

FORMAT = "graphsvc-calibration"
VERSION = 1
POSES = ("npose", "tpose", "stand")
REST_MIN_S = 0.5
REST_NORM_TOL = 1.0  # m/s²: | |mean| − g | at rest
MEDIAN_ABS_NORMAL = 0.6744897501960817  # the median of |x| for x ~ N(0, 1)
REST_NOISE_RATIO = 1.5  # a still window's RMS deviation from its mean, at most × its own noise
REST_DEV_MIN = 0.3  # m/s²: RMS deviation from the window's mean always allowed at rest
REST_DEV_MAX = 3.0  # m/s²: … and never more (per-axis noise σ up to about 1.2 m/s²)
WINDOW_S = 1.0  # query window
STRIDE_S = 0.5
MAX_MOTION_S = 30.0  # of the take matched, from the rest's start
BEST_MATCHES = 4  # graph windows kept per query window
OUTLIER_DEG = 45.0
ITERATIONS = 2
# A sensor whose readings, during the motion, leave the rest's gravity axis by less than
# SEEN_RATIO × the noise's energy perpendicular to it (twice the rest's per-axis
# variance, at least MIN_NOISE_ENERGY (m/s²)²) — a shin while the arms wave — keeps no
# rotation about gravity (the motion does not show it): the rest's shortest tilt, or
# for `stand` the shortest rotation from its mean reading to the matched graph readings'.
SEEN_RATIO = 4.0
MIN_NOISE_ENERGY = 0.25
REST_WEIGHT = {"npose": 1.0, "tpose": 1.0, "stand": 0.05}  # × the matched pairs' total weight
LEVEL_WEIGHT = 0.1  # a T-pose arm's level bone, × the matched pairs' total weight
LEVEL_STEPS = 4
# Quality (`quality_problems`): a sensor is named when its residual exceeds MAX_RESIDUAL_DEG,
# it moved during the pose, or its gravity over the rest from the accelerometer and from
# the orientation output are more than MAX_GRAVITY_GAP_DEG apart.
MAX_RESIDUAL_DEG = 25.0
MAX_GRAVITY_GAP_DEG = 10.0

# The reading at rest (m/s², the layout's sensor frame: X along the bone from the
# segment's joint toward its `toward` joint; in the N-pose and T-pose Z points forward,
# Y = Z × X) of a sensor on each canonical segment, per pose, for a sensor whose X points
# toward the segment's canonical child (`sensor_reversed`: X and Y turn over otherwise).
_LIMBS = ("shoulder", "elbow", "wrist", "hip", "knee")
_TRUNK = ("pelvis", "spine", "chest", "neck", "head")
_FEET = ("ankle", "toe")
_ARMS = ("shoulder", "elbow", "wrist")


def _pose_table() -> dict[str, dict[str, tuple[float, float, float]]]:
    g = GRAVITY
    npose = {seg: (g, 0.0, 0.0) for seg in _TRUNK}
    for side in ("l_", "r_"):
        npose.update({side + seg: (-g, 0.0, 0.0) for seg in _LIMBS})
        npose.update({side + seg: (0.0, 0.0, g) for seg in _FEET})
    tpose = dict(npose)
    for seg in ("shoulder", "elbow", "wrist"):
        tpose["l_" + seg] = (0.0, g, 0.0)
        tpose["r_" + seg] = (0.0, -g, 0.0)
    return {"npose": npose, "tpose": tpose, "stand": dict(npose)}


POSE_READINGS = _pose_table()


# ------------------------------------------------------------------ small rotation helpers


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(3, 3) the shortest rotation taking direction u onto v."""
    return quat.to_matrix(quat.between(u, v))


def _about(axis: np.ndarray, angle: float) -> np.ndarray:
    return quat.to_matrix(quat.from_axis_angle(_unit(axis), np.float64(angle)))


def _plane_basis(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """e1, e2 with (e1, e2, u) right-handed and orthonormal."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = _unit(np.cross(helper, u))
    return e1, np.cross(u, e1)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle (degrees) of the rotation between two rotation matrices."""
    c = (np.trace(a.T @ b) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def wahba(device: np.ndarray, layout: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(3, 3) the rotation R minimising Σ w‖layout − R·device‖² (SVD), from (K, 3) pairs."""
    B = (layout * weight[:, None]).T @ device
    U, _, Vt = np.linalg.svd(B)
    d = np.sign(np.linalg.det(U @ Vt)) or 1.0
    return U @ np.diag([1.0, 1.0, d]) @ Vt


# ------------------------------------------------------------------ rest


def noise_variance(diffs: np.ndarray) -> np.ndarray:
    """(...) the white noise's variance a axis, from its sample-to-sample differences
    (..., 3, n): σ² = (median |d| / MEDIAN_ABS_NORMAL)² / 2 a axis, averaged over the
    axes — a slow drift or a single step hardly moves it, as it would a deviation."""
    return np.mean((np.median(np.abs(diffs), axis=-1) / MEDIAN_ABS_NORMAL) ** 2, axis=-1) / 2.0


def find_rest(acc: np.ndarray, rate_hz: float, min_s: float = REST_MIN_S) -> np.ndarray | None:
    """Each sensor's rest in (T, S, 3) readings: (S, 2) int [start, stop) samples, (−1,
    −1) for a sensor without one; None when no sensor is ever still.

    A sensor is still over a window of min_s seconds when its RMS deviation from the
    window's mean is within REST_NOISE_RATIO × the window's own noise (`noise_variance`
    of its sample-to-sample differences: smooth motion and a single step hardly raise
    it), clamped to [REST_DEV_MIN, REST_DEV_MAX], and the mean's norm
    within REST_NORM_TOL of g. The pose is the first window where the most sensors are
    still at once, for as long as all of them are (each judged by its own windows'
    noise); a sensor not still there has no rest (it moved during the pose, or never
    stood still)."""
    T, S = acc.shape[:2]
    W = max(3, int(round(min_s * rate_hz)))
    out = np.full((S, 2), -1, dtype=np.int64)
    if T < W:
        return None
    a = np.asarray(acc, dtype=np.float64)
    bad = ~np.isfinite(a).all(axis=2)  # (T, S)
    a = np.where(np.isfinite(a), a, 0.0)
    zero = lambda x: np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])  # noqa: E731
    c1, c2, cb = zero(a), zero(np.sum(a * a, axis=-1)), zero(bad.astype(np.float64))
    mean = (c1[W:] - c1[:-W]) / W  # (K, S, 3)
    dev = np.sqrt(np.maximum((c2[W:] - c2[:-W]) / W - np.sum(mean * mean, axis=-1), 0.0))  # (K, S)
    noise = np.empty_like(dev)
    for s in range(S):  # each window's W − 1 differences
        d = np.lib.stride_tricks.sliding_window_view(np.diff(a[:, s], axis=0), W - 1, axis=0)  # (K, 3, W−1)
        noise[:, s] = np.sqrt(3.0 * noise_variance(d))
    usable = (np.abs(np.linalg.norm(mean, axis=-1) - GRAVITY) < REST_NORM_TOL) & (cb[W:] == cb[:-W])
    still = usable & (dev <= np.clip(REST_NOISE_RATIO * noise, REST_DEV_MIN, REST_DEV_MAX))
    count = still.sum(axis=1)
    if count.max() == 0:
        return None
    k = int(np.argmax(count))  # the pose: the first window where the most sensors are still at once
    posed = still[k]
    i = j = k
    while i > 0 and still[i - 1, posed].all():
        i -= 1
    while j + 1 < still.shape[0] and still[j + 1, posed].all():
        j += 1
    out[posed] = (i, j + W)
    return out


# ------------------------------------------------------------------ matching a reference's readings


def world_vertical(q: np.ndarray) -> np.ndarray:
    """(..., 3) the world's +Y seen in frames q (..., 4): a device frame's view of the
    vertical, and a reference frame's (`Reference.verticals`), alike."""
    return quat.inv_rotate(q, np.broadcast_to([0.0, 1.0, 0.0], q.shape[:-1] + (3,)))


@numba.njit(cache=True, nogil=True)
def _slide(gp, gz, valid, qp, qz, cost, corr):
    """For every graph window start j (valid[j]) against one query window: per sensor
    the complex sum Σ_w z_g[j+w]·conj(z_q[w]) into corr[j, s] and the total residual
    (module docstring, step 2) into cost[j]; invalid starts cost +inf."""
    S = gp.shape[1]
    N, W = cost.shape[0], qp.shape[0]
    qnorm = 0.0
    for w in range(W):
        for s in range(S):
            qnorm += abs(qz[w, s]) ** 2
    for j in range(N):
        if not valid[j]:
            cost[j] = np.inf
            continue
        total = qnorm
        for s in range(S):
            c = 0j
            for w in range(W):
                g = gz[j + w, s]
                c += g * qz[w, s].conjugate()
                total += g.real * g.real + g.imag * g.imag
                d = qp[w, s] - gp[j + w, s]
                total += d * d
            corr[j, s] = c
            total -= 2.0 * abs(c)
        cost[j] = total


def _split(x: np.ndarray, axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(…, S, 3) vectors, axes (S, 3, 3) rows (e1, e2, u) → parallel (…, S), complex (…, S)."""
    c = np.einsum("...si,sji->...sj", x, axes)
    return np.ascontiguousarray(c[..., 2]), np.ascontiguousarray(c[..., 0] + 1j * c[..., 1])


def match_windows(
    device: np.ndarray,
    stream: np.ndarray,
    runs: np.ndarray,
    up_layout: np.ndarray,
    window: int,
    stride: int,
    best: int = BEST_MATCHES,
) -> list[tuple[int, int, float, np.ndarray]]:
    """Device readings (T, S, 3) already turned into the layout's frames up to a
    rotation about each sensor's gravity axis up_layout (S, 3), against the graph's
    clip-ordered readings (N, S, 3) with run ids (N,): per query window (start q,
    every `stride` samples, no missing values) its `best` graph windows, each as (q,
    j, residual, complex sums (S,))."""
    T, S = device.shape[:2]
    N = stream.shape[0]
    if N < window:
        return []
    axes = np.stack([np.stack(_plane_basis(u) + (u,)) for u in up_layout])
    gp, gz = _split(stream, axes)
    starts = np.arange(N - window + 1)
    valid = runs[starts] == runs[starts + window - 1]
    cost = np.empty(N - window + 1)
    corr = np.empty((N - window + 1, S), dtype=np.complex128)
    out = []
    for q in range(0, T - window + 1, stride):
        chunk = device[q : q + window]
        if not np.isfinite(chunk).all():
            continue
        qp, qz = _split(chunk, axes)
        _slide(gp, gz, valid, qp, qz, cost, corr)
        chosen: list[int] = []
        for j in np.argsort(cost, kind="stable"):
            if not np.isfinite(cost[j]) or len(chosen) == best:
                break
            if all(abs(int(j) - k) >= window // 2 for k in chosen):
                chosen.append(int(j))
                out.append((q, int(j), float(cost[j]), corr[j].copy()))
    return out


# ------------------------------------------------------------------ calibration


def sensor_segments(layout: dict | None, names) -> list[str]:
    """Each named sensor's canonical segment, from a layout description."""
    if not layout or not isinstance(layout.get("sensors"), list):
        raise InputError(
            "calibration needs the sensors' layout (which segment each sensor is on): the recording "
            "carries none; give --graph"
        )
    seg = {s.get("name"): s.get("segment") for s in layout["sensors"] if isinstance(s, dict)}
    missing = [n for n in names if n not in seg]
    if missing:
        raise InputError(f"layout {layout.get('name')!r} has no sensor named {', '.join(missing)}")
    return [seg[n] for n in names]


def sensor_reversed(layout: dict, names) -> np.ndarray:
    """(S,) bool: each named sensor's X points from its segment's joint toward another
    joint than the segment's canonical child (dip6's head sensor, toward the neck): the
    pose table's X and Y turn over for it (Z, forward, stays)."""
    from graphsvc.motion.joints import CANONICAL_CHILD

    spec = {s.get("name"): s for s in layout["sensors"] if isinstance(s, dict)}
    return np.array(
        [spec[n].get("toward") not in (None, CANONICAL_CHILD.get(spec[n].get("segment"))) for n in names], dtype=bool
    )


def gravity_gap_deg(acc: np.ndarray, orient: np.ndarray | None, rests: np.ndarray) -> np.ndarray:
    """(S,) degrees between gravity's direction over each sensor's rest from its mean
    reading and from its orientation output (the mean of D(t)⁻¹·ŷ); NaN without a rest
    or without orientations there."""
    out = np.full(rests.shape[0], np.nan)
    for s, (a, b) in enumerate(rests):
        if a >= 0 and orient is not None and np.isfinite(orient[a:b, s]).all():
            u = _unit(world_vertical(quat.normalize(np.asarray(orient[a:b, s], dtype=np.float64))).mean(axis=0))
            v = _unit(np.nanmean(np.asarray(acc[a:b, s], dtype=np.float64), axis=0))
            out[s] = math.degrees(math.acos(float(np.clip(u @ v, -1.0, 1.0))))
    return out


def quality_problems(names, residual_deg, has_rest, gap_deg) -> list[str]:
    """What makes a calibration untrustworthy, one phrase a sensor (module constants)."""
    out = []
    for n, r, still, gap in zip(names, residual_deg, has_rest, gap_deg):
        why = []
        if not still:
            why.append("moved during the pose")
        if r > MAX_RESIDUAL_DEG:
            why.append(f"residual {r:.1f}° > {MAX_RESIDUAL_DEG:g}°")
        if np.isfinite(gap) and gap > MAX_GRAVITY_GAP_DEG:
            why.append(f"gravity from acceleration and orientation {gap:.1f}° apart (> {MAX_GRAVITY_GAP_DEG:g}°)")
        if why:
            out.append(f"{n} ({', '.join(why)})")
    return out


def _rest_up_device(acc: np.ndarray, orient: np.ndarray | None, rests: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """(S, 3) gravity's direction in each device frame over its own rest (rests (S, 2);
    a sensor without one: zero) and where it came from, per sensor."""
    up, source = np.zeros((rests.shape[0], 3)), []
    for s, (a, b) in enumerate(rests):
        if a < 0:
            source.append("")
        elif orient is not None and np.isfinite(orient[a:b, s]).all():
            up[s] = _unit(world_vertical(quat.normalize(np.asarray(orient[a:b, s], dtype=np.float64))).mean(axis=0))
            source.append("orientation")
        else:
            up[s] = _unit(np.nanmean(np.asarray(acc[a:b, s], dtype=np.float64), axis=0))
            source.append("acceleration")
    return up, source


@dataclass(frozen=True)
class Reference:
    """What a calibration take's motion is matched against: readings of similar motion in
    the layout's sensor frames, as a graph holds them (`graph.calibration.graph_reference`).

    layout: the layout description (which segment each sensor is on); sensor_names: its
    sensors, in the readings' order; rate_hz: the readings' rate; sensor_frames: their
    frames' convention (`sensors.anatomy`); readings: (N, S, 3) float64 m/s² at normal
    speed, in order; runs: (N,) int64 a run id a reading (a new one wherever a clip
    changes or a frame is skipped: a window never straddles two); verticals: (K,)
    indices into readings and sensor names → (K, len(names), 3) the world's vertical
    in those sensors' layout frames at those readings' frames (`world_vertical`)."""

    layout: dict | None
    sensor_names: tuple
    rate_hz: float
    sensor_frames: str
    readings: np.ndarray
    runs: np.ndarray
    verticals: Callable[[np.ndarray, tuple], np.ndarray]


def calibrate_against(
    rec, pose: str, reference: Reference | None = None, start_s: float | None = None, end_s: float | None = None
) -> dict:
    """The calibration (the CAL.json document, `save_calibration`) of a recording's
    sensors from a calibration take in `pose` (POSES), against a reference's readings of
    similar motion (a graph's: `graph.calibration.calibrate`). InputError when it cannot
    be done (module docstring); CalibrationQualityError, carrying the document, when it
    was done but names sensors not to be trusted (`quality_problems`; the document's
    "problems" lists them)."""
    if pose not in POSES:
        raise InputError(f"unknown pose {pose!r} (poses: {', '.join(POSES)})")
    if rec.accelerations is None or rec.num_sensors == 0:
        raise InputError("the recording has no accelerometer readings to calibrate")
    if rec.meta.get("sensor_frame") == "layout":
        raise InputError("the recording's readings are already in the layout's sensor frames (sensor_frame=layout)")
    layout = reference.layout if reference is not None else rec.layout
    names = tuple(rec.sensor_names)
    if reference is not None:
        gnames = reference.sensor_names
        if sorted(gnames) != sorted(names):
            hint = (
                ""
                if rec.meta.get("device_sensors") is not None
                else ": give --device-map to name them as the layout does"
            )  # (mapped already: some are missing)
            raise InputError(
                f"the recording's sensors ({', '.join(names)}) are not the graph's ({', '.join(gnames)}){hint}"
            )
    segments = sensor_segments(layout, names)
    table = POSE_READINGS[pose]
    unknown = [f"{n} ({s})" for n, s in zip(names, segments) if s not in table]
    if unknown:
        raise InputError(f"pose {pose} does not say where gravity points for {', '.join(unknown)}")
    rate = float(reference.rate_hz) if reference is not None else float(rec.rate_hz)
    t_first = float(rec.timestamps_s[0])
    rec = _span(rec, start_s, end_s)
    offset = float(rec.timestamps_s[0]) - t_first  # (the span's start, from the recording's first sample)
    acc = np.asarray(readings_at_rate(rec, rate)[0], dtype=np.float64)
    orient = None
    if rec.orientations is not None:
        orient = _orientations_at(rec, rate)
    rests = find_rest(acc, rate)
    if rests is None:
        raise InputError(
            f"no still stretch of ≥ {REST_MIN_S:g} s (every sensor steady, |a| ≈ g) in the recording: "
            "a calibration take starts with the performer standing still in the pose"
        )
    has_rest = rests[:, 0] >= 0
    r0, r1 = (int(v) for v in rests[np.argmax(has_rest)])
    up_dev, rest_source = _rest_up_device(acc, orient, rests)
    up_lay = _unit(np.array([table[s] for s in segments], dtype=np.float64))
    up_lay[sensor_reversed(layout, names)] *= np.array([-1.0, -1.0, 1.0])
    if reference is None:
        raise InputError(
            f"pose {pose} fixes each sensor's tilt but not its rotation about gravity; give --graph G "
            "(the motion after the rest, matched against the graph's readings, fixes it)"
        )
    S = len(names)
    R0 = np.stack([_between(up_dev[s], up_lay[s]) if has_rest[s] else np.eye(3) for s in range(S)])
    R = R0.copy()
    # A T-pose says only that an arm's bone (the sensor's X) is level; how far it is
    # rolled about itself is the performer's: the table's Y-up is a first guess, the
    # motion fixes the rest (`_level_fit`).
    rolled = has_rest & np.array([pose == "tpose" and seg[2:] in _ARMS for seg in segments])
    noise_var = np.zeros(S)  # per axis, over each sensor's own rest
    for s in np.flatnonzero(has_rest):
        noise_var[s] = noise_variance(
            np.diff(np.asarray(acc[rests[s, 0] : rests[s, 1], s], dtype=np.float64), axis=0).T
        )
    stream, runs = reference.readings, reference.runs
    cols = [list(reference.sensor_names).index(n) for n in names]
    stream = np.ascontiguousarray(stream[:, cols])
    moving = acc[r0 : r0 + int(MAX_MOTION_S * rate)]  # (the rest and the motion after it)
    # With orientation output: the vertical each device frame saw (free of the yaw drift
    # and of linear acceleration), paired with the matched graph frames' (FK of its poses).
    dev_up = None if orient is None else world_vertical(quat.normalize(orient[r0 : r0 + moving.shape[0]]))
    window, stride = max(4, int(round(WINDOW_S * rate))), max(1, int(round(STRIDE_S * rate)))
    if moving.shape[0] < 2 * window:
        raise InputError(
            f"the recording has {moving.shape[0] / rate:.2f} s from its rest on; calibration needs "
            f"at least {2 * WINDOW_S:g} s"
        )
    # How far each reading leaves the rest's gravity axis during the motion, against the noise.
    moved = moving[np.isfinite(moving).all(axis=(1, 2))]
    along = np.einsum("tsi,si->ts", moved, up_dev)
    perp = np.mean(np.sum(moved * moved, axis=-1) - along * along, axis=0)
    seen = ~has_rest | (perp / np.maximum(2.0 * noise_var, MIN_NOISE_ENERGY) >= SEEN_RATIO)
    residual = np.zeros(S)
    pairs = 0
    for it in range(ITERATIONS + int(rolled.any())):
        if it:  # (the rolled sensors' gravity as the last fit put it)
            up_lay[rolled] = _unit(np.einsum("sij,sj->si", R[rolled], up_dev[rolled]))
        turned = np.einsum("sij,tsj->tsi", R, moving)
        matches = match_windows(turned, stream, runs, up_lay, window, stride)
        if not matches:
            raise InputError("no window of the graph's readings could be matched to the recording's motion")
        costs = np.array([m[2] for m in matches])
        weight = 1.0 / (costs / max(float(np.median(costs)), 1e-9) + 0.05)
        sums = np.stack([m[3] for m in matches])  # (K, S)
        theta = _robust_angle(sums, weight)
        R = np.stack([_about(up_lay[s], theta[s]) @ R[s] for s in range(S)])
        idx_q = np.concatenate([np.arange(m[0], m[0] + window) for m in matches])
        idx_g = np.concatenate([np.arange(m[1], m[1] + window) for m in matches])
        w_pair = np.repeat(weight, window)
        lay_up = None
        if dev_up is not None:
            used, back = np.unique(idx_g, return_inverse=True)
            lay_up = reference.verticals(used, names)[back]
        for s in range(S):
            dev, lay, w_s = moving[idx_q, s], stream[idx_g, s], w_pair
            if lay_up is not None:  # (gravity's pairs beside the readings', NaN orientations left out)
                ok = np.isfinite(dev_up[idx_q, s]).all(axis=-1)
                dev = np.vstack([dev, GRAVITY * dev_up[idx_q[ok], s]])
                lay = np.vstack([lay, GRAVITY * lay_up[ok, s]])
                w_s = np.concatenate([w_pair, w_pair[ok]])
            if not seen[s]:  # the motion barely turns it off gravity's axis: its twist is unseen,
                # its tilt the pose's, or for a natural stance the matched graph poses' (shortest arcs)
                R[s] = R0[s] if pose != "stand" else _between(w_s @ dev, w_s @ lay)
            elif rolled[s]:
                R[s] = _level_fit(R[s], dev, lay, w_s, up_dev[s], LEVEL_WEIGHT * w_s.sum())
            elif pose == "stand" or not has_rest[s]:
                rest_w = REST_WEIGHT[pose] * w_s.sum() * has_rest[s]
                R[s] = wahba(
                    np.vstack([dev, up_dev[s] * GRAVITY]), np.vstack([lay, up_lay[s] * GRAVITY]), np.append(w_s, rest_w)
                )
            else:  # the tilt is the pose's: only the angle about gravity, over every pair
                R[s] = _about_only(R0[s], dev, lay, w_s, up_lay[s])
            got = np.einsum("ij,kj->ki", R[s], dev)
            cosang = np.sum(_unit(got) * _unit(lay), axis=-1)
            residual[s] = math.degrees(math.sqrt(np.average(np.arccos(np.clip(cosang, -1, 1)) ** 2, weights=w_s)))
        pairs = idx_q.size
    rest = (r0, r1)
    gap = gravity_gap_deg(acc, orient, rests)
    problems = quality_problems(names, residual, has_rest, gap)
    method = [
        ("graph (never still)" if not has_rest[s] else f"rest ({rest_source[s]}) + graph")
        if seen[s]
        else f"rest ({rest_source[s]}) only: the motion hardly turned it, no rotation about gravity"
        for s in range(S)
    ]
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "layout": (layout or {}).get("name"),
        "pose": pose,
        # The convention of the layout frames it calibrates onto (`sensors.anatomy`): the
        # graph's, else the pose table's (anatomical).
        "sensor_frames": reference.sensor_frames if reference is not None else ANATOMICAL,
        "source": str(rec.meta.get("source", "")),
        # seconds from the recording's first sample (not from start_s)
        "rest_s": [round(offset + rest[0] / rate, 4), round(offset + rest[1] / rate, 4)],
        "matched_samples": int(pairs),
        "sensors": {
            n: {
                "rotation_wxyz": [round(float(v), 9) for v in _canonical(quat.from_matrix(R[s]))],
                "method": method[s],
                "residual_deg": round(float(residual[s]), 3),
            }
            for s, n in enumerate(names)
        },
        "problems": problems,
    }
    if problems:
        raise CalibrationQualityError(f"calibration not to be trusted: {'; '.join(problems)}", doc)
    return doc


def mounting_angle_deg(item: dict) -> float:
    """A CAL document sensor's mounting angle (degrees) from its rotation_wxyz."""
    return 2.0 * math.degrees(math.acos(min(1.0, abs(float(item["rotation_wxyz"][0])))))


def _canonical(q: np.ndarray) -> np.ndarray:
    return -q if q[0] < 0 else q


def _robust_angle(sums: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(S,) the weighted least-squares angle of complex sums (K, S), then again without
    the matches whose own angle is more than OUTLIER_DEG from it."""
    total = (sums * weight[:, None]).sum(axis=0)
    theta = np.angle(total)
    own = np.angle(sums)
    keep = np.abs(np.angle(np.exp(1j * (own - theta[None])))) <= math.radians(OUTLIER_DEG)
    kept = (sums * weight[:, None] * keep).sum(axis=0)
    return np.where(keep.any(axis=0), np.angle(kept), theta)


def _level_fit(
    R: np.ndarray, dev: np.ndarray, lay: np.ndarray, weight: np.ndarray, up: np.ndarray, rest_w: float
) -> np.ndarray:
    """All three degrees of freedom (Wahba) over the pairs, and a rest term of weight
    rest_w pairing the device's gravity `up` with the nearest direction that keeps the
    bone (the layout's X) level: alternately that direction from the last R, R from it,
    LEVEL_STEPS times from R."""
    bone = np.array([1.0, 0.0, 0.0])
    for _ in range(LEVEL_STEPS):
        target = R @ up
        target = target - (target @ bone) * bone
        if np.linalg.norm(target) < 1e-9:  # (gravity along the bone: no level direction is nearer)
            break
        R = wahba(np.vstack([dev, up * GRAVITY]), np.vstack([lay, _unit(target) * GRAVITY]), np.append(weight, rest_w))
    return R


def _about_only(R: np.ndarray, dev: np.ndarray, lay: np.ndarray, weight: np.ndarray, u: np.ndarray) -> np.ndarray:
    """R turned about u by the angle θ that best maps R·dev onto lay (closed form)."""
    e1, e2 = _plane_basis(u)
    got = dev @ R.T
    zd = got @ e1 + 1j * (got @ e2)
    zl = lay @ e1 + 1j * (lay @ e2)
    return _about(u, float(np.angle(np.sum(weight * zl * np.conj(zd))))) @ R


def _span(rec, start_s: float | None, end_s: float | None):
    """The part of a recording between start_s and end_s (seconds from its first sample)."""
    from dataclasses import replace

    if start_s is None and end_s is None:
        return rec
    t = rec.timestamps_s - rec.timestamps_s[0]
    lo = -np.inf if start_s is None else float(start_s)
    hi = np.inf if end_s is None else float(end_s)
    if not (math.isfinite(lo) or start_s is None) or not (math.isfinite(hi) or end_s is None) or hi <= lo:
        raise InputError(f"--from/--to must be finite seconds with --from < --to, got {start_s}, {end_s}")
    keep = (t >= lo - 1e-9) & (t <= hi + 1e-9)
    if keep.sum() < 2:
        raise InputError(
            f"the recording has no samples between {start_s} and {end_s} s (it lasts {rec.duration_s:.2f} s)"
        )
    pick = lambda a: None if a is None else a[keep]  # noqa: E731
    return replace(
        rec,
        timestamps_s=rec.timestamps_s[keep],
        accelerations=pick(rec.accelerations),
        orientations=pick(rec.orientations),
        ground_position=pick(rec.ground_position),
        heading=pick(rec.heading),
        marker_positions=pick(rec.marker_positions),
    )


def _orientations_at(rec, rate: float) -> np.ndarray:
    """The recording's orientations on `readings_at_rate`'s grid (nearest sample)."""
    t, grid = uniform_grid(rec, rate)
    q = np.asarray(rec.orientations, dtype=np.float64)
    if grid is None:
        return q
    idx = np.clip(np.searchsorted(t, grid), 0, t.size - 1)
    return q[idx]


# ------------------------------------------------------------------ CAL.json


def save_calibration(cal: dict, path) -> None:
    write_text_atomic(path, json.dumps(cal, indent=1, sort_keys=True) + "\n")


def load_calibration(path) -> dict:
    """A CAL.json checked: FormatError naming the file for anything malformed. Returns
    the document with each sensor's rotation as a unit (4,) array under "rotation"."""
    path = Path(path)
    return check_calibration(read_json_file(path), path)


def check_calibration(doc, path="calibration") -> dict:
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise FormatError(path, f'not a graphsvc calibration (expected "format": "{FORMAT}")')
    if doc.get("version") != VERSION:
        raise FormatError(path, f"calibration version {doc.get('version')!r} is not supported (this reads {VERSION})")
    if "sensor_frames" in doc and doc["sensor_frames"] not in CONVENTIONS:
        raise FormatError(path, f"sensor_frames must be {' or '.join(CONVENTIONS)}, got {doc['sensor_frames']!r}")
    sensors = doc.get("sensors")
    if not isinstance(sensors, dict) or not sensors:
        raise FormatError(path, '"sensors" must be an object with at least one sensor')
    out = {}
    for name, item in sensors.items():
        q = item.get("rotation_wxyz") if isinstance(item, dict) else None
        try:
            q = np.asarray(q, dtype=np.float64)
        except (TypeError, ValueError):
            q = np.zeros(0)
        if q.shape != (4,) or not np.isfinite(q).all() or abs(np.linalg.norm(q) - 1.0) > 1e-3:
            raise FormatError(path, f"sensor {name!r}: rotation_wxyz must be a unit quaternion of 4 numbers")
        out[name] = q / np.linalg.norm(q)
    return {**doc, "rotations": out, "path": str(path)}


# ------------------------------------------------------------------ applying it


def calibration_rotations(cal: dict, names) -> np.ndarray:
    """(S, 4) the rotations of sensors `names`, in that order; InputError unless the
    calibration holds exactly those sensors."""
    have = cal["rotations"]
    if sorted(have) != sorted(names):
        raise InputError(
            f"{cal.get('path', 'the calibration')} calibrates sensors {', '.join(sorted(have))}, "
            f"not the recording's {', '.join(sorted(names))}"
        )
    return np.stack([have[n] for n in names])


def calibrate_sample(rotations: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """One sample's (S, 3) device-frame readings → the layout's frames (the live form)."""
    return quat.rotate(rotations, np.asarray(acc, dtype=np.float64))


def apply_calibration(rec, cal: dict):
    """A device-frame recording turned into a layout-frame one: a_layout = R·a_device,
    q_layout = q_device ⊗ R⁻¹; meta sensor_frame becomes "layout", sensor_frames the
    calibration's convention (so a graph in another is refused), and it records the
    calibration file. InputError for a recording already in layout frames or sensors
    that do not match."""
    from dataclasses import replace

    if rec.meta.get("sensor_frame") == "layout":
        raise InputError(
            "the recording's readings are already in the layout's sensor frames (sensor_frame=layout): "
            "it needs no calibration"
        )
    if rec.accelerations is None:
        raise InputError("the recording has no accelerometer readings to calibrate")
    R = calibration_rotations(cal, rec.sensor_names)
    acc = quat.rotate(R[None], np.asarray(rec.accelerations, dtype=np.float64)).astype(np.float32)
    orient = rec.orientations
    if orient is not None:
        orient = quat.mul(np.asarray(orient, dtype=np.float64), quat.conjugate(R)[None]).astype(np.float32)
    meta = {**rec.meta, "sensor_frame": "layout", "calibration": cal.get("path", "")}
    if cal.get("sensor_frames") in CONVENTIONS:  # (files without it: unknown, not checked)
        meta["sensor_frames"] = cal["sensor_frames"]
    out = replace(rec, accelerations=acc, orientations=orient, meta=meta)
    out.validate()
    return out

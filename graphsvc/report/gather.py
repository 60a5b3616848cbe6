"""The arrays one clip of a report shows, gathered into one JSON-able dict (a "view").

A view holds, for T frames at `rate_hz`:

- `figures`: the reconstruction and, when known, the truth, each as its skeleton's
  parents and joint names, the root's (joint 0's) positions (T, 3) as int32
  millimetres and every joint's position relative to that root (T, J, 3) as int16
  millimetres — both base64, little-endian; `round(p · 1000)` exactly, so the page's
  positions are the motion's within 0.5 mm a coordinate — the feet's contacts (T, 2)
  as "0"/"1", `centre`: the joint the page follows (its trail, the grid's placement and
  the camera: `centre_joint`, the pelvis), and `drawn`: the joints drawn, every joint
  but the centre's ancestors (`drawn_joints`: no bone from a root fixed at the origin,
  such as the Bandai-Namco skeleton's `joint_Root` above `Hips`);
- `errors`: per-frame joint, root (cm) and heading (°) error, when the truth is known
  (`evaluate.metrics.truth_errors`, `error_arrays`);
- `sensors`: per sensor the measured readings on the graph's grid and the virtual
  readings of the output motion (noise-free, the same layout), (T, 3) int16 cm/s²
  (−32768: missing), base64;
- `markers`: measured optical markers (T, M, 3) as int32 mm (missing: −2³¹), for an
  input of markers;
- `timeline`: the source of every frame (`strategies.sources`: `timeline_from_nodes`,
  `timeline_from_sources`);
- `constraints`: each annotation constraint with the frames where it was met.

Small free functions over flat arrays; `clip_view` puts them together.
"""

from __future__ import annotations

import base64

import numpy as np

from graphsvc.errors import GraphsvcError, InputError
from graphsvc.evaluate.metrics import error_arrays, truth_errors
from graphsvc.motion import signals
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.skeleton import Motion
from graphsvc.sensors.grid import markers_at_rate, readings_at_rate
from graphsvc.sensors.layout import layout_from_dict
from graphsvc.sensors.noise import PRESETS
from graphsvc.sensors.simulate import simulate_recording

MISSING_I16 = -32768
MISSING_I32 = -(2**31)


def b64(a: np.ndarray, dtype) -> str:
    """The array's values as little-endian `dtype` bytes, base64."""
    return base64.b64encode(np.ascontiguousarray(a, dtype=np.dtype(dtype).newbyteorder("<")).tobytes()).decode("ascii")


def _mm(a: np.ndarray) -> np.ndarray:
    return np.rint(np.asarray(a, dtype=np.float64) * 1000.0).astype(np.int64)


def bits(flags: np.ndarray) -> str:
    """(T,) bool as a string of "0" and "1"."""
    return "".join("1" if f else "0" for f in np.asarray(flags, dtype=bool))


# A joint "moves" over a clip when its position spans more than this on some axis (m).
MOVING_M = 0.001


def centre_joint(world: np.ndarray, table=None) -> int:
    """The joint the page follows in a motion's world positions (T, J, 3) m: the pelvis
    of the skeleton's joint table (`joint_map`) when there is one, else the first joint
    (a skeleton lists parents first) whose position moves over the clip by more than
    MOVING_M on some axis, else joint 0."""
    if table is not None:
        return int(table["pelvis"])
    world = np.asarray(world, dtype=np.float64)
    world = world[np.isfinite(world).all(axis=(1, 2))]  # (frames with a non-finite joint left out)
    if world.shape[0] == 0:
        return 0
    moving = np.flatnonzero(np.ptp(world, axis=0).max(axis=-1) > MOVING_M)
    return int(moving[0]) if moving.size else 0


def drawn_joints(parents, centre: int) -> list[int]:
    """The joints to draw: all but the strict ancestors of `centre`. A root above the
    pelvis (Bandai-Namco's `joint_Root`, fixed at the origin while `Hips` carries the
    motion) is not part of the body: neither it nor a bone from it is drawn."""
    parents = np.asarray(parents, dtype=np.int64)
    keep = np.ones(parents.size, dtype=bool)
    j = int(parents[centre]) if 0 <= centre < parents.size else -1
    while j >= 0:
        keep[j] = False
        j = int(parents[j])
    return [int(k) for k in np.flatnonzero(keep)]


def figure_arrays(motion: Motion, name: str, mapping=None) -> dict:
    """One skeleton to draw: names, parents, root (T, 3) int32 mm, joints relative to
    it (T, J, 3) int16 mm, the feet's contacts and the feet's joints, the joint to
    follow and the joints to draw (module docstring)."""
    _, world = motion_fk(motion)
    mm = _mm(world)  # (T, J, 3)
    root = mm[:, 0]
    rel = mm - root[:, None, :]
    if np.abs(rel).max(initial=0) > 32767:
        raise InputError(f"{motion.name}: a joint lies more than 32 m from the root")
    out = {
        "name": name,
        "joints": list(motion.skeleton.names),
        "parents": [int(p) for p in motion.skeleton.parents],
        "root_mm": b64(root, np.int32),
        "rel_mm": b64(rel, np.int16),
        "contacts": None,
        "feet": None,
    }
    try:
        table = joint_map(motion.skeleton, mapping)
    except Exception:  # (a skeleton no joint map knows: drawn without contacts)
        table = None
    out["centre"] = centre_joint(world, table)
    out["drawn"] = drawn_joints(motion.skeleton.parents, out["centre"])
    if table is None:
        return out
    contacts = signals.foot_contacts(world, table, motion.rate_hz)
    out["contacts"] = [bits(contacts[:, 0]), bits(contacts[:, 1])]
    out["feet"] = [int(table["l_ankle"]), int(table["r_ankle"])]
    return out


def _cms2(acc: np.ndarray) -> np.ndarray:
    a = np.asarray(acc, dtype=np.float64) * 100.0
    out = np.clip(np.rint(np.nan_to_num(a, nan=0.0)), -32767, 32767).astype(np.int16)
    out[~np.isfinite(a)] = MISSING_I16
    return out


def sensor_arrays(rec, motion: Motion, mapping=None, virtual: np.ndarray | None = None) -> dict | None:
    """Per sensor, the recording's measured accelerations on the motion's frame grid
    and the path's virtual readings: `virtual` (T, S, 3) m/s² when given (a node
    path's edges, `strategies.sources.path_readings`), else those of `motion` itself
    (the same layout, no noise): {"names", "measured": [b64 (T, 3) int16 cm/s²],
    "virtual": [...]}. None for a recording without accelerations or without a layout,
    or a skeleton the layout cannot be placed on."""
    if rec is None or rec.accelerations is None or not rec.accelerations.size or not rec.layout:
        return None
    measured, _, _, _ = readings_at_rate(rec, motion.rate_hz)
    T = motion.num_frames
    if virtual is None or virtual.shape[1] != measured.shape[1]:
        try:
            virtual = simulate_recording(
                motion, layout_from_dict(rec.layout), PRESETS["none"], mapping=mapping
            ).accelerations
        except GraphsvcError:
            return None
    v = np.full((T, measured.shape[1], 3), np.nan)
    v[: min(T, len(virtual))] = virtual[:T]
    m = np.full((T, measured.shape[1], 3), np.nan)
    n = min(T, measured.shape[0])
    m[:n] = measured[:n]
    return {
        "names": list(rec.sensor_names),
        "measured": [b64(_cms2(m[:, s]), np.int16) for s in range(m.shape[1])],
        "virtual": [b64(_cms2(v[:, s]), np.int16) for s in range(v.shape[1])],
    }


def marker_arrays(rec, frames: int, rate_hz: float) -> dict | None:
    """The recording's optical markers on the frame grid, (T, M, 3) int32 mm, or None."""
    if rec is None or rec.marker_positions is None:
        return None
    points = markers_at_rate(rec, rate_hz)
    out = np.full((frames, points.shape[1], 3), MISSING_I32, dtype=np.int64)
    n = min(frames, points.shape[0])
    seen = np.isfinite(points[:n])
    out[:n][seen] = _mm(np.where(seen, points[:n], 0.0))[seen]
    return {"names": list(rec.marker_names), "mm": b64(out, np.int32)}


# ---------------------------------------------------------------- constraints


def constraint_arrays(constraints, labels, contacts: np.ndarray | None, rate_hz: float) -> list[dict]:
    """Each annotation constraint (sets in priority order) with its frames and, per
    frame of its interval, whether the output met it: {set, start_s, end_s, require,
    first_frame, met: "0"/"1" a frame}. labels: (T,) the output's per-frame labels;
    contacts: (T, 2) the output's feet contacts (left, right) or None."""
    T = len(labels)
    out = []
    want_feet = {"left": (True, False), "right": (False, True), "both": (True, True), "none": (False, False)}
    for k, cset in enumerate(constraints or []):
        for c in cset:
            a = max(0, int(np.ceil(float(c["start_s"]) * rate_hz - 1e-9)))
            b = min(T, int(np.ceil(float(c["end_s"]) * rate_hz - 1e-9)))
            req = dict(c["require"])
            if "label" in req:
                met = [str(labels[t]) == str(req["label"]) for t in range(a, b)]
            elif "contact" in req and contacts is not None:
                want = want_feet[str(req["contact"])]
                met = [bool(contacts[t, 0]) == want[0] and bool(contacts[t, 1]) == want[1] for t in range(a, b)]
            else:
                met = []
            out.append(
                {
                    "set": k,
                    "start_s": float(c["start_s"]),
                    "end_s": float(c["end_s"]),
                    "require": req,
                    "first_frame": a,
                    "met": bits(met),
                }
            )
    return out


# ---------------------------------------------------------------- one clip


def clip_view(
    name: str,
    motion: Motion,
    timeline: dict,
    rec=None,
    truth: Motion | None = None,
    per_frame: dict | None = None,
    constraints=None,
    labels=None,
    mapping=None,
    info: dict | None = None,
    virtual: np.ndarray | None = None,
    truth_mapping=None,
    notes: list | None = None,
) -> dict:
    """Everything the page shows of one reconstruction (module docstring). motion:
    the output; timeline: `strategies.sources.timeline_from_*`'s; rec: the input
    recording (or None); truth: the true motion at the same rate (or None); per_frame:
    its errors (`truth_errors`' per_frame; computed from `truth` when None);
    constraints: the sets the search was given; labels: the output's per-frame labels
    (default: from the timeline); info: a few lines shown above the viewer; virtual:
    the path's virtual readings (`sensor_arrays`); truth_mapping: the truth's joint map
    (a dict, a file or "guess"; None: a built-in one); notes: a list that collects a
    line saying why the error charts are left out, or None."""
    T = motion.num_frames
    figures = [figure_arrays(motion, "reconstruction", mapping)]
    if truth is not None:
        figures.append(figure_arrays(truth, "truth", truth_mapping))
        if per_frame is None:
            try:
                per_frame = truth_errors(motion, truth, pred_mapping=mapping, true_mapping=truth_mapping)["per_frame"]
            except GraphsvcError as exc:  # (skeletons the metrics cannot compare: shown without errors)
                per_frame = None
                if notes is not None:
                    notes.append(
                        f"{name}: the error charts are left out, the truth cannot be compared joint by joint: {exc}"
                    )
    if labels is None:
        labels = [""] * T
        for seg in timeline["segments"]:
            labels[seg["start"] : seg["start"] + seg["frames"]] = [seg["label"]] * seg["frames"]
    contacts = None
    if figures[0]["contacts"] is not None:
        contacts = np.array(
            [[c == "1" for c in figures[0]["contacts"][0]], [c == "1" for c in figures[0]["contacts"][1]]]
        ).T
    return {
        "name": name,
        "rate_hz": float(motion.rate_hz),
        "frames": int(T),
        "figures": figures,
        "errors": error_arrays(per_frame),
        "sensors": sensor_arrays(rec, motion, mapping, virtual),
        "markers": marker_arrays(rec, T, float(motion.rate_hz)),
        "timeline": timeline,
        "constraints": constraint_arrays(constraints, labels, contacts, float(motion.rate_hz)),
        "info": dict(info or {}),
    }

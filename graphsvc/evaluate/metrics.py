"""Evaluation metrics: pure functions over flat per-frame arrays.

Conventions: positions in metres, Y up, ground plane XZ; ground positions
are (x, z) pairs in metres; headings are radians about +Y, 0 facing +Z, positive
turning toward +X, so that R_y(θ) maps (x, z) to (cos θ·x + sin θ·z, −sin θ·x + cos θ·z).
Reported metrics are in centimetres and degrees.

Joint arrays hold the canonical joints only: select them with
`graphsvc.motion.joints.canonical_indices` before calling (`pos[:, idx]`). Ground
positions and headings are those of `graphsvc.motion.signals.ground_position` and
`signals.heading` (or whatever the synthesizer reports for its own frames).

Each metric returns `(per_frame, mean)`: a (T,) float array and its mean as a Python
float. Every function raises `graphsvc.errors.InputError` on empty, non-finite or
shape-mismatched input, so outputs never contain NaN.

`truth_errors` scores two motions (a reconstruction against its truth: forward
kinematics, the joints both skeletons have), and `error_arrays` rounds the per-frame
errors for a JSON document (the report page, an evaluation's kept clips).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from graphsvc.errors import InputError
from graphsvc.motion import signals
from graphsvc.motion.joints import CANONICAL, JointMapping, common_joints, joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.proportions import SEGMENTS
from graphsvc.motion.quat import wrap_angle
from graphsvc.motion.skeleton import Motion

METRICS = ("joint_err_cm", "root_err_cm", "heading_err_deg", "label_acc")
FLOORS = ("oracle_joint_err_cm",)  # (a row's bound, where asked for: `evaluate.oracle`)
SCALED = ("joint_err_scaled_cm",)  # (the pose error on the truth's bone lengths, where scored)


def _finite(name: str, a, shape_tail: tuple) -> np.ndarray:
    """`a` as a float array of shape (T, *shape_tail) with T ≥ 1 and finite values;
    None in shape_tail accepts any size."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 1 + len(shape_tail) or any(w is not None and w != n for w, n in zip(shape_tail, arr.shape[1:])):
        want = ", ".join(["T", *("P" if w is None else str(w) for w in shape_tail)])
        raise InputError(f"{name}: expected shape ({want}), got {arr.shape}")
    if arr.shape[0] == 0:
        raise InputError(f"{name}: zero frames")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: contains NaN or infinite values")
    return arr


def _same_frames(**arrays) -> int:
    lengths = {k: len(v) for k, v in arrays.items()}
    if len(set(lengths.values())) != 1:
        raise InputError("frame counts disagree: " + ", ".join(f"{k}={n}" for k, n in lengths.items()))
    return next(iter(lengths.values()))


def align_frames(pred_pos, pred_ground, pred_heading, true_ground, true_heading) -> np.ndarray:
    """(T, P, 3) metres: each predicted frame rotated about +Y by (true − pred heading)
    around its own root ground position, then translated so that ground position lands
    on the true one. Heights (Y) are untouched."""
    d = np.asarray(true_heading, dtype=np.float64) - np.asarray(pred_heading, dtype=np.float64)
    c, s = np.cos(d)[:, None], np.sin(d)[:, None]
    pred_ground = np.asarray(pred_ground, dtype=np.float64)
    true_ground = np.asarray(true_ground, dtype=np.float64)
    x = pred_pos[..., 0] - pred_ground[:, 0:1]
    z = pred_pos[..., 2] - pred_ground[:, 1:2]
    out = np.array(pred_pos, dtype=np.float64, copy=True)
    out[..., 0] = c * x + s * z + true_ground[:, 0:1]
    out[..., 2] = -s * x + c * z + true_ground[:, 1:2]
    return out


def joint_err_cm(pred_pos, true_pos, pred_ground, pred_heading, true_ground, true_heading):
    """Local pose error: ((T,) per-frame, mean) in centimetres.

    pred_pos, true_pos: (T, P, 3) metres, canonical joints, same order. pred_ground,
    true_ground: (T, 2) root (x, z) metres. pred_heading, true_heading: (T,) radians.
    Each predicted frame is aligned to the truth (`align_frames`); the per-frame value
    is the mean Euclidean distance over the P joints."""
    pred_pos = _finite("pred_pos", pred_pos, (None, 3))
    true_pos = _finite("true_pos", true_pos, (None, 3))
    if pred_pos.shape[1] != true_pos.shape[1]:
        raise InputError(f"joint counts disagree: predicted {pred_pos.shape[1]}, true {true_pos.shape[1]}")
    if pred_pos.shape[1] == 0:
        raise InputError("no joints to compare")
    pg = _finite("pred_ground", pred_ground, (2,))
    tg = _finite("true_ground", true_ground, (2,))
    ph = _finite("pred_heading", pred_heading, ())
    th = _finite("true_heading", true_heading, ())
    _same_frames(pred_pos=pred_pos, true_pos=true_pos, pred_ground=pg, true_ground=tg, pred_heading=ph, true_heading=th)
    aligned = align_frames(pred_pos, pg, ph, tg, th)
    per_frame = 100.0 * np.linalg.norm(aligned - true_pos, axis=-1).mean(axis=1)
    return per_frame, float(per_frame.mean())


# Each canonical joint's parent in the canonical tree (the segments' proximal joints).
_CANONICAL_PARENT = {b: a for a, b in SEGMENTS.values()}
# The joints whose bones (from their parents) make the legs: pelvis → hip → knee → ankle.
LEG_JOINTS = ("l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle")


def canonical_parents(names) -> np.ndarray:
    """(P,) the index in `names` (canonical joints, in CANONICAL's order) of each joint's
    nearest ancestor among them in the canonical tree, -1 for one without (the pelvis):
    a skeleton without a spine joint hangs its chest from the pelvis."""
    names = list(names)
    out = []
    for n in names:
        p = _CANONICAL_PARENT.get(n)
        while p is not None and p not in names:
            p = _CANONICAL_PARENT.get(p)
        out.append(-1 if p is None else names.index(p))
    return np.array(out, dtype=np.int64)


def bone_lengths(pos, parents) -> np.ndarray:
    """(T, P) each joint's distance from its parent (`parents`: (P,) indices, -1 for a
    root, whose length is 0) in every frame of (T, P, 3) positions."""
    p = _finite("pos", pos, (None, 3))
    parents = np.asarray(parents, dtype=np.int64)
    if parents.shape != (p.shape[1],):
        raise InputError(f"parents: expected {p.shape[1]} entries, got {parents.shape}")
    out = np.linalg.norm(p - p[:, np.maximum(parents, 0)], axis=-1)
    out[:, parents < 0] = 0.0
    return out


def bone_scaled_positions(pos, lengths, parents) -> np.ndarray:
    """(T, P, 3) metres: the pose of `pos` (T, P, 3) with the bone lengths `lengths`
    ((T, P) per frame, or (P,): each joint's distance from its parent, as `bone_lengths`
    gives a truth's): every root where it is, every other joint its parent's scaled
    position plus the unit direction from its parent in `pos` times its length. A bone
    of zero length in `pos` has no direction and stays zero. parents: (P,) indices, each
    before its joint, -1 for a root (`canonical_parents` of the canonical joints).

    What the pose error on the truth's proportions compares (`joint_err_scaled_cm`): a
    knowledge base whose trunk is shorter than the performer's is scored on the
    directions of its bones, not on their lengths."""
    p = _finite("pos", pos, (None, 3))
    parents = np.asarray(parents, dtype=np.int64)
    T, P = p.shape[:2]
    if parents.shape != (P,) or np.any(parents >= np.arange(P)):
        raise InputError(f"parents: expected {P} entries, each before its joint or -1")
    L = np.asarray(lengths, dtype=np.float64)
    if L.shape == (P,):
        L = np.broadcast_to(L, (T, P))
    L = _finite("lengths", L, (P,))
    if L.shape[0] != T:
        raise InputError(f"frame counts disagree: pos={T}, lengths={L.shape[0]}")
    if np.any(L < 0):
        raise InputError("lengths: a bone length is negative")
    out = p.copy()
    for j in range(P):
        a = parents[j]
        if a < 0:
            continue
        d = p[:, j] - p[:, a]
        n = np.linalg.norm(d, axis=-1, keepdims=True)
        unit = np.divide(d, n, out=np.zeros_like(d), where=n > 0)
        out[:, j] = out[:, a] + unit * L[:, j : j + 1]
    return out


def joint_err_scaled_cm(pred_pos, true_pos, parents, pred_ground, pred_heading, true_ground, true_heading, legs=None):
    """`joint_err_cm` of the prediction on the truth's bone lengths: ((T,) per-frame,
    mean) in centimetres. The predicted pose keeps its root and bone directions, each
    bone the truth's length in that frame (`bone_scaled_positions` with `bone_lengths`
    of true_pos); parents as there. legs: the indices of the joints whose bones make the
    legs (hips, knees, ankles: `LEG_JOINTS`); given, the root's height is scaled by the
    ratio of the truth's legs to the prediction's in each frame, as a performer's longer
    legs lift the pelvis (`motion.proportions.on_performer`). Shapes as in `joint_err_cm`."""
    pred_pos = _finite("pred_pos", pred_pos, (None, 3))
    true_pos = _finite("true_pos", true_pos, (None, 3))
    if pred_pos.shape[1] != true_pos.shape[1]:
        raise InputError(f"joint counts disagree: predicted {pred_pos.shape[1]}, true {true_pos.shape[1]}")
    _same_frames(pred_pos=pred_pos, true_pos=true_pos)
    true_lengths = bone_lengths(true_pos, parents)
    scaled = bone_scaled_positions(pred_pos, true_lengths, parents)
    if legs is not None and len(legs) > 0:
        legs = list(legs)
        have = bone_lengths(pred_pos, parents)[:, legs].sum(axis=1)
        want = true_lengths[:, legs].sum(axis=1)
        k = np.divide(want, have, out=np.ones_like(want), where=have > 0)
        root = int(np.flatnonzero(np.asarray(parents) < 0)[0])
        scaled[..., 1] += ((k - 1.0) * pred_pos[:, root, 1])[:, None]
    return joint_err_cm(scaled, true_pos, pred_ground, pred_heading, true_ground, true_heading)


def root_err_cm(pred_ground, true_ground):
    """Ground-plane root distance: ((T,) per-frame, mean) in centimetres.
    pred_ground, true_ground: (T, 2) (x, z) metres."""
    pg = _finite("pred_ground", pred_ground, (2,))
    tg = _finite("true_ground", true_ground, (2,))
    _same_frames(pred_ground=pg, true_ground=tg)
    per_frame = 100.0 * np.linalg.norm(pg - tg, axis=-1)
    return per_frame, float(per_frame.mean())


def heading_err_deg(pred_heading, true_heading):
    """Absolute heading difference wrapped to [0°, 180°]: ((T,) per-frame, mean) in degrees.
    pred_heading, true_heading: (T,) radians (any range)."""
    ph = _finite("pred_heading", pred_heading, ())
    th = _finite("true_heading", true_heading, ())
    _same_frames(pred_heading=ph, true_heading=th)
    per_frame = np.degrees(np.abs(wrap_angle(ph - th)))
    return per_frame, float(per_frame.mean())


def label_acc(pred_labels, true_label):
    """Content-label accuracy: ((T,) per-frame 0/1 floats, fraction of frames).

    pred_labels: (T,) the content label (str or int) of the source clip each
    synthesized frame was taken from; None marks an unlabelled source and counts as a
    miss. true_label: the test clip's label, or a (T,) sequence of per-frame labels
    (a performance that changes activity, like the demo's); frames whose true label
    is None are not scored (0 in the per-frame array, left out of the fraction).
    Labels compare as strings, so 3 and "3" match."""
    labels = list(np.asarray(pred_labels, dtype=object).reshape(-1)) if np.ndim(pred_labels) <= 1 else None
    if labels is None:
        raise InputError(f"pred_labels: expected shape (T,), got {np.shape(pred_labels)}")
    if not labels:
        raise InputError("pred_labels: zero frames")
    if true_label is None:
        raise InputError("true_label: the test clip has no content label")
    if isinstance(true_label, (str, bytes, int, np.integer, np.str_)):
        want = [str(true_label)] * len(labels)
    else:
        want = [None if w is None else str(w) for w in np.asarray(true_label, dtype=object).reshape(-1)]
        if len(want) != len(labels):
            raise InputError(f"per-frame true labels: {len(want)} frames, predicted {len(labels)}")
    scored = np.array([w is not None for w in want])
    if not scored.any():
        raise InputError("true_label: no frame has a label")
    per_frame = np.array(
        [lab is not None and w is not None and str(lab) == w for lab, w in zip(labels, want)], dtype=np.float64
    )
    return per_frame, float(per_frame[scored].mean())


# ---------------------------------------------------------------- what a viewer sees

# A foot this high above its lowest (5th-percentile) height counts half as planted for
# the skate (Zhang et al. 2018, "Mode-Adaptive Neural Networks for Quadruped Motion
# Control": weight clip(2 − 2^(h / H), 0, 1), H = 2.5 cm: 1 on the floor, 0 from 2.5 cm up).
SKATE_HEIGHT_M = 0.025
PLAUSIBILITY = ("jitter_km_s3", "skate_cm_s", "penetration_cm")


def jitter_km_s3(pos, rate_hz: float):
    """Jitter, as sparse-IMU posers report it: the norm of the third time difference of
    the joints' global positions (T, P, 3) m, times rate³, mean over joints: ((T−3,)
    per-frame, mean) in km/s³; (empty, None) for fewer than four frames."""
    p = _finite("pos", pos, (None, 3))
    if p.shape[0] < 4:
        return np.zeros(0), None
    jerk = np.diff(p, n=3, axis=0) * float(rate_hz) ** 3  # (T−3, P, 3) m/s³
    per_frame = np.linalg.norm(jerk, axis=-1).mean(axis=1) / 1000.0
    return per_frame, float(per_frame.mean())


def skate_cm_s(pos, rate_hz: float, feet):
    """Foot skate: each foot joint's horizontal speed weighted by its nearness to the
    floor, clip(2 − 2^(h / 2.5 cm), 0, 1), h its height above its own 5th-percentile
    height over the clip (Zhang et al. 2018), mean over the feet: ((T−1,) per step,
    mean) in cm/s; (empty, None) for a single frame. pos: (T, P, 3) m; feet: the foot
    joints' indices in P (the ankles)."""
    p = _finite("pos", pos, (None, 3))
    if p.shape[0] < 2:
        return np.zeros(0), None
    f = p[:, list(feet)]  # (T, F, 3)
    h = f[..., 1] - np.percentile(f[..., 1], 5, axis=0)
    h = 0.5 * (h[1:] + h[:-1])  # (each step's height: its two frames')
    w = np.clip(2.0 - np.power(2.0, h / SKATE_HEIGHT_M), 0.0, 1.0)
    v = np.linalg.norm(np.diff(f[..., [0, 2]], axis=0), axis=-1) * float(rate_hz)  # (T−1, F) m/s
    per_frame = 100.0 * (w * v).mean(axis=1)
    return per_frame, float(per_frame.mean())


def penetration_cm(pos, floor_m: float = 0.0):
    """Ground penetration: how far the lowest joint of each frame is below the floor
    (Y = floor_m): ((T,) per-frame, mean) in centimetres, 0 where none is."""
    p = _finite("pos", pos, (None, 3))
    per_frame = 100.0 * np.maximum(0.0, floor_m - p[..., 1].min(axis=1))
    return per_frame, float(per_frame.mean())


def plausibility(pos, rate_hz: float, feet) -> tuple[dict, dict]:
    """({"jitter_km_s3", "skate_cm_s", "penetration_cm": mean or None}, their per-frame
    arrays) of a motion's global joint positions (T, P, 3) m at rate_hz."""
    out, per_frame = {}, {}
    for key, (values, mean) in (
        ("jitter_km_s3", jitter_km_s3(pos, rate_hz)),
        ("skate_cm_s", skate_cm_s(pos, rate_hz, feet)),
        ("penetration_cm", penetration_cm(pos)),
    ):
        out[key], per_frame[key] = mean, values
    return out, per_frame


def motion_plausibility(motion: Motion, mapping=None) -> dict:
    """`plausibility` of a motion's canonical joints (its skeleton's joint map, or
    `mapping`): {"jitter_km_s3", "skate_cm_s", "penetration_cm"}, means or None."""
    table = joint_map(motion.skeleton, mapping)
    names = [c for c in CANONICAL if c in table]
    pos = motion_fk(motion)[1][:, [table[c] for c in names]]
    values, _ = plausibility(pos, float(motion.rate_hz), [names.index("l_ankle"), names.index("r_ankle")])
    return values


def evaluate_frames(
    pred_pos,
    true_pos,
    pred_ground,
    pred_heading,
    true_ground,
    true_heading,
    pred_labels=None,
    true_label=None,
    name: str | None = None,
    joints=None,
) -> dict:
    """All §9 metrics for one clip.

    Shapes as in `joint_err_cm`; pred_labels (Tp,) and true_label as in `label_acc`
    (one label, or (Tt,) per-frame labels). joints: the P joints' canonical names, which
    adds `joint_err_scaled_cm` (their `canonical_parents` and `LEG_JOINTS`; None: not
    scored).
    Within each side the arrays must agree on frame count (pred_*: Tp, true_*: Tt),
    else InputError. Length rule: when Tp ≠ Tt both sides are aligned at frame 0 and
    truncated to T = min(Tp, Tt); the dropped count is reported as `frames_dropped`.
    When pred_labels or true_label is None, `label_acc` is None (JSON null).

    Returns {"name", "frames": T, "frames_dropped", "joint_err_cm", "root_err_cm",
    "heading_err_deg", "label_acc", "per_frame": {metric: (T,) array}} (and
    "joint_err_scaled_cm" with joints) with Python floats for the scalars."""
    pred_pos = np.asarray(pred_pos, dtype=np.float64)
    true_pos = np.asarray(true_pos, dtype=np.float64)
    if pred_pos.ndim != 3 or true_pos.ndim != 3:
        raise InputError(f"joint positions must be (T, P, 3); got {pred_pos.shape} and {true_pos.shape}")
    if pred_pos.shape[1] != true_pos.shape[1]:
        raise InputError(f"joint counts disagree: predicted {pred_pos.shape[1]}, true {true_pos.shape[1]}")
    pred = {"pred_pos": pred_pos, "pred_ground": np.asarray(pred_ground), "pred_heading": np.asarray(pred_heading)}
    if pred_labels is not None:
        pred["pred_labels"] = np.asarray(pred_labels, dtype=object)
    true = {"true_pos": true_pos, "true_ground": np.asarray(true_ground), "true_heading": np.asarray(true_heading)}
    tp = _same_frames(**pred)
    tt = _same_frames(**true)
    n = min(tp, tt)
    if n == 0:
        raise InputError(f"zero frames to evaluate (predicted {tp}, true {tt})")
    pred = {k: v[:n] for k, v in pred.items()}
    true = {k: v[:n] for k, v in true.items()}

    joint, joint_mean = joint_err_cm(
        pred["pred_pos"],
        true["true_pos"],
        pred["pred_ground"],
        pred["pred_heading"],
        true["true_ground"],
        true["true_heading"],
    )
    root, root_mean = root_err_cm(pred["pred_ground"], true["true_ground"])
    head, head_mean = heading_err_deg(pred["pred_heading"], true["true_heading"])
    per_frame = {"joint_err_cm": joint, "root_err_cm": root, "heading_err_deg": head, "label_acc": None}
    acc_mean = None
    if pred_labels is not None and true_label is not None:
        if not isinstance(true_label, (str, bytes, int, np.integer, np.str_)):
            # Per-frame truth: same length rule as the other true_* arrays.
            true_label = list(np.asarray(true_label, dtype=object).reshape(-1))
            if len(true_label) != tt:
                raise InputError(f"frame counts disagree: true_label={len(true_label)}, true_pos={tt}")
            true_label = true_label[:n]
        per_frame["label_acc"], acc_mean = label_acc(pred["pred_labels"], true_label)
    scaled = {}
    if joints is not None:
        joints = list(joints)
        if len(joints) != pred_pos.shape[1]:
            raise InputError(f"joints: {len(joints)} names for {pred_pos.shape[1]} joints")
        per_frame["joint_err_scaled_cm"], scaled["joint_err_scaled_cm"] = joint_err_scaled_cm(
            pred["pred_pos"],
            true["true_pos"],
            canonical_parents(joints),
            pred["pred_ground"],
            pred["pred_heading"],
            true["true_ground"],
            true["true_heading"],
            legs=[joints.index(n) for n in LEG_JOINTS if n in joints],
        )
    return {
        "name": name,
        "frames": int(n),
        "frames_dropped": int(max(tp, tt) - n),
        "joint_err_cm": joint_mean,
        **scaled,
        "root_err_cm": root_mean,
        "heading_err_deg": head_mean,
        "label_acc": acc_mean,
        "per_frame": per_frame,
    }


def summarize(results: list[dict]) -> dict:
    """JSON-ready summary of `evaluate_frames` results (what `graphsvc evaluate --json`
    prints): {"clips": [row, ...], "mean": {...}}.

    Each row is the result without `per_frame` (other extra keys, e.g. runtime, pass
    through). `mean` holds `clips`, total `frames` and, per metric, the frame-weighted
    mean over clips, Σ frames_i·m_i / Σ frames_i, which equals the mean over all frames;
    label_acc is averaged only over clips that have it and is None when none do. The
    plausibility figures (`PLAUSIBILITY`, the output's and the truth's `truth_…`) are
    averaged the same way where rows have them, and so are the pose-oracle floor
    (`FLOORS`, `evaluate.oracle`) and the pose error on the truth's bone lengths
    (`SCALED`)."""
    rows = []
    for r in results:
        row = {k: v for k, v in r.items() if k != "per_frame"}
        for k in METRICS:
            if row.get(k) is not None:
                row[k] = float(row[k])
        rows.append(row)
    mean: dict = {"clips": len(rows), "frames": int(sum(int(r["frames"]) for r in rows))}
    plausible = [
        k for k in (*PLAUSIBILITY, *(f"truth_{p}" for p in PLAUSIBILITY), *FLOORS, *SCALED) if any(k in r for r in rows)
    ]
    for k in (*METRICS, *plausible):
        have = [r for r in rows if r.get(k) is not None]
        weight = sum(int(r["frames"]) for r in have)
        mean[k] = float(sum(int(r["frames"]) * r[k] for r in have) / weight) if weight > 0 else None
    return {"clips": rows, "mean": mean}


# ---------------------------------------------------------------- two motions, and for a JSON document


def truth_errors(
    predicted: Motion,
    truth: Motion,
    pred_labels: ArrayLike | None = None,
    true_labels: str | ArrayLike | None = None,
    pred_mapping: JointMapping = None,
    true_mapping: JointMapping = None,
) -> dict:
    """`evaluate_frames` of a reconstruction against its truth (both at one rate; the
    shorter length counts): the scalar metrics and `per_frame` arrays."""
    pt, tt = joint_map(predicted.skeleton, pred_mapping), joint_map(truth.skeleton, true_mapping)
    names = common_joints(tt, pt)
    _, pw = motion_fk(predicted)
    _, tw = motion_fk(truth)
    return evaluate_frames(
        pw[:, [pt[c] for c in names]],
        tw[:, [tt[c] for c in names]],
        signals.ground_position(pw, pt["pelvis"]),
        signals.heading(pw, pt),
        signals.ground_position(tw, tt["pelvis"]),
        signals.heading(tw, tt),
        pred_labels=pred_labels,
        true_label=true_labels,
        name=predicted.name,
        joints=names,
    )


def error_arrays(per_frame: dict | None) -> dict | None:
    """Per-frame joint, root (cm) and heading (°) errors rounded to 0.01, or None."""
    if not per_frame:
        return None
    keys = ("joint_err_cm", "root_err_cm", "heading_err_deg")
    return {
        k: [round(float(v), 2) if np.isfinite(v) else None for v in np.asarray(per_frame[k], dtype=np.float64)]
        for k in keys
        if per_frame.get(k) is not None
    }

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
- `errors`: per-frame joint, root (cm) and heading (°) error, when the truth is known;
- `sensors`: per sensor the measured readings on the graph's grid and the virtual
  readings of the output motion (noise-free, the same layout), (T, 3) int16 cm/s²
  (−32768: missing), base64;
- `markers`: measured optical markers (T, M, 3) as int32 mm (missing: −2³¹), for an
  input of markers;
- `timeline`: the source of every frame (`timeline_from_nodes`,
  `timeline_from_sources`);
- `constraints`: each annotation constraint with the frames where it was met.

Small free functions over flat arrays; `clip_view` puts them together.
"""

from __future__ import annotations

import base64

import numpy as np

from graphsvc.motion import signals
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.skeleton import Motion
from graphsvc.sensors.grid import markers_at_rate, readings_at_rate

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
        from graphsvc.errors import InputError

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


def truth_errors(predicted: Motion, truth: Motion, pred_labels=None, true_labels=None,
                 pred_mapping=None, true_mapping=None) -> dict:  # fmt: skip
    """`evaluate_frames` of a reconstruction against its truth (both at one rate; the
    shorter length counts): the scalar metrics and `per_frame` arrays."""
    from graphsvc.evaluate.metrics import evaluate_frames
    from graphsvc.motion.joints import common_joints

    pt, tt = joint_map(predicted.skeleton, pred_mapping), joint_map(truth.skeleton, true_mapping)
    names = common_joints(tt, pt)
    _, pw = motion_fk(predicted)
    _, tw = motion_fk(truth)
    return evaluate_frames(
        pw[:, [pt[c] for c in names]], tw[:, [tt[c] for c in names]],
        signals.ground_position(pw, pt["pelvis"]), signals.heading(pw, pt),
        signals.ground_position(tw, tt["pelvis"]), signals.heading(tw, tt),
        pred_labels=pred_labels, true_label=true_labels, name=predicted.name,
    )  # fmt: skip


def error_arrays(per_frame: dict | None) -> dict | None:
    """Per-frame joint, root (cm) and heading (°) errors rounded to 0.01, or None."""
    if not per_frame:
        return None
    keys = ("joint_err_cm", "root_err_cm", "heading_err_deg")
    return {k: [round(float(v), 2) if np.isfinite(v) else None for v in np.asarray(per_frame[k], dtype=np.float64)]
            for k in keys if per_frame.get(k) is not None}  # fmt: skip


def _cms2(acc: np.ndarray) -> np.ndarray:
    a = np.asarray(acc, dtype=np.float64) * 100.0
    out = np.clip(np.rint(np.nan_to_num(a, nan=0.0)), -32767, 32767).astype(np.int16)
    out[~np.isfinite(a)] = MISSING_I16
    return out


def sensor_arrays(rec, motion: Motion, mapping=None, virtual: np.ndarray | None = None) -> dict | None:
    """Per sensor, the recording's measured accelerations on the motion's frame grid
    and the path's virtual readings: `virtual` (T, S, 3) m/s² when given (a node
    path's edges, `path_readings`), else those of `motion` itself (the same layout, no
    noise): {"names", "measured": [b64 (T, 3) int16 cm/s²], "virtual": [...]}. None
    for a recording without accelerations or without a layout, or a skeleton the
    layout cannot be placed on."""
    if rec is None or rec.accelerations is None or not rec.accelerations.size or not rec.layout:
        return None
    from graphsvc.errors import GraphsvcError
    from graphsvc.sensors.layout import layout_from_dict
    from graphsvc.sensors.noise import PRESETS
    from graphsvc.sensors.simulate import simulate_recording
    measured, _, _, _ = readings_at_rate(rec, motion.rate_hz)
    T = motion.num_frames
    if virtual is None or virtual.shape[1] != measured.shape[1]:
        try:
            virtual = simulate_recording(motion, layout_from_dict(rec.layout), PRESETS["none"],
                                         mapping=mapping).accelerations  # fmt: skip
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


# ---------------------------------------------------------------- where each frame comes from

# A frame's kind on the timeline: the source clip played as captured, at another speed,
# through an interpolated (blended) segment, over a bridge between actions, or a blend of
# several sources (OLNG, SSG).
KINDS = ("original", "speed", "interpolated", "bridge", "blend")


def path_edges(graph, nodes) -> np.ndarray:
    """(T,) the graph edge entering each frame of a node path (−1: none — the first
    frame, or a jump no edge makes)."""
    nodes = np.asarray(nodes, dtype=np.int64)
    out = np.full(nodes.size, -1, dtype=np.int64)
    for t in range(1, nodes.size):
        a, b = int(nodes[t - 1]), int(nodes[t])
        lo, hi = int(graph.incoming[b]), int(graph.incoming[b + 1])
        k = lo + int(np.searchsorted(np.asarray(graph.edge_src[lo:hi]), a))
        if k < hi and int(graph.edge_src[k]) == a:
            out[t] = k
    return out


def path_readings(graph, nodes) -> np.ndarray:
    """(T, S, 3) m/s² the virtual readings a node path was scored against: each
    entering edge's metadata (NaN where no edge enters)."""
    edges = path_edges(graph, nodes)
    acc = np.asarray(graph.edge_acc, dtype=np.float64)[np.maximum(edges, 0)]
    acc[edges < 0] = np.nan
    return acc


def source_readings(graph, clip: np.ndarray, frame: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(T, S, 3) m/s² the virtual readings of frames made of several knowledge-base
    sources (OLNG, SSG): per frame the weighted mean of its sources' readings — each
    source frame's original node's entering edge in its clip (NaN where none)."""
    from graphsvc.graph.model import EDGE_ORIGINAL, NODE_ORIGINAL

    clip = np.asarray(clip, dtype=np.int64)
    weight = np.where(clip >= 0, np.asarray(weight, dtype=np.float64), 0.0)
    frame = np.rint(np.asarray(frame, dtype=np.float64)).astype(np.int64)
    original = np.flatnonzero(np.asarray(graph.edge_kind) == EDGE_ORIGINAL)
    dst = np.asarray(graph.edge_dst)[original].astype(np.int64)
    keep = np.asarray(graph.node_kind)[dst] == NODE_ORIGINAL
    original, dst = original[keep], dst[keep]
    span = int(np.asarray(graph.node_frame).max(initial=0)) + 2
    keys = np.asarray(graph.node_clip)[dst].astype(np.int64) * span + np.rint(np.asarray(graph.node_frame)[dst]).astype(np.int64)
    order = np.argsort(keys, kind="stable")
    keys, original = keys[order], original[order]
    want = np.maximum(clip, 0) * span + frame
    at = np.clip(np.searchsorted(keys, want), 0, max(len(keys) - 1, 0))
    found = (len(keys) > 0) & (keys[at] == want) & (weight > 0) if len(keys) else np.zeros(want.shape, bool)
    S = np.asarray(graph.edge_acc).shape[1]
    acc = np.asarray(graph.edge_acc, dtype=np.float64)[original[at]] if len(keys) else np.zeros(want.shape + (S, 3))
    w = np.where(found, weight, 0.0)
    total = w.sum(axis=1)
    out = np.einsum("tk,tksc->tsc", w, np.where(found[..., None, None], acc, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        out = out / total[:, None, None]
    out[total <= 0] = np.nan
    return out


def timeline_from_nodes(graph, nodes) -> dict:
    """The timeline of a path of graph nodes: runs of one source clip and kind
    ({start, frames, clip, label, kind, from_frame}), the frames entered by a
    transition (another clip, or a jump within one), and the labels as runs."""
    from graphsvc.graph.model import EDGE_BRIDGE, EDGE_INTERP, EDGE_SLOW, EDGE_SPEEDUP, EDGE_TRANSITION
    from graphsvc.graph.model import NODE_BRIDGE, NODE_INTERP, NODE_SLOW

    nodes = np.asarray(nodes, dtype=np.int64)
    T = nodes.size
    clip = np.asarray(graph.node_clip)[nodes].astype(np.int64)
    src = np.asarray(graph.node_frame)[nodes].astype(np.float64)
    nkind = np.asarray(graph.node_kind)[nodes]
    edges = path_edges(graph, nodes)
    ekind = np.where(edges >= 0, np.asarray(graph.edge_kind)[np.maximum(edges, 0)], 255).astype(np.int64)
    kind = np.zeros(T, dtype=np.int64)
    kind[(nkind == NODE_SLOW) | (ekind == EDGE_SLOW) | (ekind == EDGE_SPEEDUP)] = 1
    kind[(nkind == NODE_INTERP) | (ekind == EDGE_INTERP)] = 2
    kind[(nkind == NODE_BRIDGE) | (ekind == EDGE_BRIDGE)] = 3
    jump = np.zeros(T, dtype=bool)
    jump[1:] = (ekind[1:] == EDGE_TRANSITION) | (ekind[1:] == 255) | (clip[1:] != clip[:-1])
    labels = [str(graph.labels[int(k)]) for k in np.asarray(graph.node_label)[nodes]]
    names = [str(c["name"]) for c in graph.clips]
    segments = []
    start = 0
    for t in range(1, T + 1):
        if t == T or jump[t] or kind[t] != kind[start] or clip[t] != clip[start]:
            segments.append({"start": start, "frames": t - start, "clip": names[clip[start]], "label": labels[start],
                             "kind": KINDS[kind[start]], "from_frame": round(float(src[start]), 1)})  # fmt: skip
            start = t
    from graphsvc.strategies.results import label_runs

    return {"segments": segments, "transitions": [int(t) for t in np.flatnonzero(jump)], "labels": label_runs(labels),
            "neighbours": None}  # fmt: skip


def timeline_from_sources(clip_names, labels, clip: np.ndarray, frame: np.ndarray, weight: np.ndarray,
                          rows: int = 8) -> dict:  # fmt: skip
    """The timeline of frames made of several knowledge-base sources (OLNG's
    neighbourhood, SSG's cross-fades): runs of the heaviest source's clip (kind
    "blend" where a frame has more than one source), the frames where that clip
    changes, the labels as runs, and `neighbours`: the `rows` clips of most total
    weight, each with its weight in every frame as one digit 0–9 a frame."""
    from graphsvc.strategies.results import label_runs

    clip = np.asarray(clip, dtype=np.int64)
    weight = np.where(clip >= 0, np.asarray(weight, dtype=np.float64), 0.0)
    T = clip.shape[0]
    top = np.argmax(weight, axis=1)
    lead = clip[np.arange(T), top]
    lead_frame = np.asarray(frame, dtype=np.float64)[np.arange(T), top]
    blended = (weight > 0).sum(axis=1) > 1
    labels = [str(v) for v in labels]
    segments = []
    start = 0
    for t in range(1, T + 1):
        if t == T or lead[t] != lead[start] or blended[t] != blended[start]:
            segments.append({"start": start, "frames": t - start,
                             "clip": clip_names[lead[start]] if lead[start] >= 0 else "",
                             "label": labels[start], "kind": "blend" if blended[start] else "original",
                             "from_frame": round(float(lead_frame[start]), 1)})  # fmt: skip
            start = t
    changes = [int(t) for t in range(1, T) if lead[t] != lead[t - 1]]
    totals: dict[int, float] = {}
    for c, w in zip(clip.ravel(), weight.ravel()):
        if c >= 0 and w > 0:
            totals[int(c)] = totals.get(int(c), 0.0) + float(w)
    chosen = sorted(totals, key=lambda c: (-totals[c], c))[:rows]
    neighbours = {"clips": [clip_names[c] for c in chosen], "weights": []}
    for c in chosen:
        w = np.where(clip == c, weight, 0.0).sum(axis=1)
        neighbours["weights"].append("".join(str(int(v)) for v in np.clip(np.rint(w * 9.0), 0, 9)))
    return {"segments": segments, "transitions": changes, "labels": label_runs(labels), "neighbours": neighbours}


def timeline_from_labels(runs: list[dict]) -> dict:
    """A timeline from label runs alone (no graph to name the sources)."""
    segments = [{"start": int(r["start_frame"]), "frames": int(r["frames"]), "clip": "", "label": str(r["label"]),
                 "kind": "original", "from_frame": 0.0} for r in runs]  # fmt: skip
    return {"segments": segments, "transitions": [s["start"] for s in segments[1:]], "labels": runs,
            "neighbours": None}  # fmt: skip


def compact_sources(provenance, top: int = 4) -> dict:
    """A reconstruction's provenance for a report JSON: per frame its `top` heaviest
    sources' clip, frame (0.1) and weight (0.001), heaviest first (clip −1: none)."""
    w = np.where(provenance.clip >= 0, provenance.weight, -1.0)
    order = np.argsort(-w, axis=1, kind="stable")[:, :top]
    rows = np.arange(w.shape[0])[:, None]
    clip = np.where(w[rows, order] > 0, provenance.clip[rows, order], -1)
    return {"clip": clip.astype(int).tolist(),
            "frame": np.round(provenance.frame[rows, order].astype(float), 1).tolist(),
            "weight": np.round(np.clip(w[rows, order], 0.0, None), 3).tolist()}  # fmt: skip


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
            out.append({"set": k, "start_s": float(c["start_s"]), "end_s": float(c["end_s"]), "require": req,
                        "first_frame": a, "met": bits(met)})  # fmt: skip
    return out


# ---------------------------------------------------------------- one clip


def clip_view(name: str, motion: Motion, timeline: dict, rec=None, truth: Motion | None = None,
              per_frame: dict | None = None, constraints=None, labels=None, mapping=None,
              info: dict | None = None, virtual: np.ndarray | None = None) -> dict:  # fmt: skip
    """Everything the page shows of one reconstruction (module docstring). motion:
    the output; timeline: `timeline_from_*`'s; rec: the input recording (or None);
    truth: the true motion at the same rate (or None); per_frame: its errors
    (`truth_errors`' per_frame; computed from `truth` when None); constraints: the
    sets the search was given; labels: the output's per-frame labels (default: from
    the timeline); info: a few lines shown above the viewer; virtual: the path's
    virtual readings (`sensor_arrays`)."""
    T = motion.num_frames
    figures = [figure_arrays(motion, "reconstruction", mapping)]
    if truth is not None:
        figures.append(figure_arrays(truth, "truth"))
        if per_frame is None:
            try:
                per_frame = truth_errors(motion, truth, pred_mapping=mapping)["per_frame"]
            except Exception:  # (skeletons the metrics cannot compare: shown without errors)
                per_frame = None
    if labels is None:
        labels = [""] * T
        for seg in timeline["segments"]:
            labels[seg["start"]: seg["start"] + seg["frames"]] = [seg["label"]] * seg["frames"]
    contacts = None
    if figures[0]["contacts"] is not None:
        contacts = np.array([[c == "1" for c in figures[0]["contacts"][0]],
                             [c == "1" for c in figures[0]["contacts"][1]]]).T  # fmt: skip
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

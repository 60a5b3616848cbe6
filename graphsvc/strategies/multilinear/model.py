"""The multilinear model of a knowledge base: its motion units, one tensor a class (and
foot), truncated by the HOSVD (`tensor`), as flat arrays cached beside the graph.

Learning, from the graph's recorded clips (not their mirrored or reversed copies) that
a run may use (a hidden clip — every node of it disallowed — is left out):

1. A clip enters when its name carries a take number of three or more digits at the
   end: `<stem>_<take>`; its style is the stem's last `_` part (Bandai-Namco's
   `dataset-2_walk_normal_004`: style `normal`, take 004), its class the clip's
   content label. A class (a foot for steps) whose clips give fewer than two units is
   left without a tensor; a knowledge base with no tensor at all is refused.
2. Units. A class is locomotion when its clips' median ground speed is at least
   LOCOMOTION_SPEED: its units are steps, cut at the touchdowns of the graph's foot
   contacts (`node_contacts`; a touchdown is kept only MIN_STEP_S after the previous
   kept one and on the other foot), each unit from a touchdown to the next, in the
   tensor of the foot that touched down (left and right apart, as Tautges 2012 does
   after Golla 2009); units longer than MAX_STEP_S (a stop) are left out. Other
   classes' units are their whole clips.
3. A frame of a unit is V values: the local pose (`synthesis.local_pose`: the pelvis
   rotation without the heading, its height, every joint's local rotation under the
   pelvis; each quaternion on the side of its joint's principal direction over the
   knowledge base, `align_hemispheres`, not w ≥ 0), the root's step into the frame (2, m, in the previous frame's heading
   frame) and turn (rad), and the two feet's contacts (0/1).
4. Rows: per style its units in take and time order, R = the most any style has, at
   most `max_reps` (an even choice among them); a style with fewer repeats its own
   units in turn. The tensor's reference is the unit of median length (F frames);
   every unit is put on its F frames by a uniform time scaling (`align` linear; by
   default for steps: a step runs touchdown to touchdown, so its phases already
   agree), or by DTW on the pose values (`tensor.dtw_path`, `align` dtw, by default
   for whole clips, whose repeats keep no common pace; the time map smoothed over
   DTW_SIGMA·F frames) — poses resampled linearly, the root's steps as differences of
   the resampled cumulative track (`warp_values`). The fit compares accelerations,
   and a warp's curvature adds its own (the joint's velocity times the warp's second
   derivative): on the procedural walk of the tests, a step put on its reference by
   DTW smoothed over 2 frames then simulated differs from its own recorded readings by
   0.4 g² (mean square), smoothed over F/4 frames 0.25 g², uniformly scaled 0.04 g².
5. HOSVD: every mode's SVD; the style and repetition modes truncated to the fewest
   vectors holding `variance` of their unfolding's squared singular values, the
   technical modes (values, frames) kept whole. Stored: Φ_t (V, F, kS, kR), the full
   U_S, U_R and singular values of each mode, each row's clip and the clip frame at
   each reference frame (for the provenance), and each row's layout readings on the
   reference frames (g; the fit's starting row). The tensor is centred first (its mean
   unit M taken off every row, as Vasilescu & Terzopoulos 2002 do): uncentred, the first
   vector of each mode is the mean and holds nearly all the energy, so a share of the
   "variance" would keep that one alone; a motion is M + m(x_S, x_R).

Everything is a dict of arrays (`learn`), per tensor under the prefix `t<i>.`,
cached beside the graph file (`strategies.index`) under a name keyed by the options
that shape it and the clips it learned from (`model_key`).
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass

import numpy as np

from graphsvc.blas import one_thread
from graphsvc.errors import InputError
from graphsvc.graph.holdout import is_augmented
from graphsvc.graph.model import EDGE_ORIGINAL, MotionGraph
from graphsvc.graph.poses import node_rotations, node_translations
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.strategies.multilinear import tensor as tn
from graphsvc.synthesis.local_pose import pose_layout, pose_vectors

LOCOMOTION_SPEED = 0.4  # m/s, a class's median clip ground speed
MIN_STEP_S = 0.15
MAX_STEP_S = 1.2
MODEL_VERSION = 2
DTW_SIGMA = 0.25  # the DTW time map's smoothing, a share of the reference's frames
_TAKE = re.compile(r"^(?P<stem>.*[A-Za-z].*)_(?P<take>\d{3,})$")
EXTRA = 5  # values after the pose: step x, step z, turn, left contact, right contact


def clip_style_take(name: str) -> tuple[str, int] | None:
    """(style, take) of a clip name `<stem>_<take>` (module docstring), or None."""
    m = _TAKE.match(str(name))
    if not m:
        return None
    stem = m.group("stem")
    return (stem.rsplit("_", 1)[1] if "_" in stem else ""), int(m.group("take"))


def frame_data(graph: MotionGraph) -> dict[str, np.ndarray]:
    """Every recorded clip's frames (the graph's index, cached beside it): clip_start
    (C + 1,) rows of each clip, values (N, V) float32 (module docstring, 3), readings
    (N, 3S) float32 g (of the original edge into the frame; a clip's first frame
    repeats its second's), speed (C,) the clip's mean ground speed m/s."""
    layout = pose_layout(graph.skeleton, graph.params.get("mapping"))
    C = len(graph.clips)
    sizes = np.array([int(c["frames"]) for c in graph.clips], np.int64)
    start = np.concatenate([[0], np.cumsum(sizes)])
    nodes = np.concatenate([int(c["first_node"]) + np.arange(int(c["frames"])) for c in graph.clips]).astype(np.int64)
    N = nodes.size
    values = np.zeros((N, layout.dims + EXTRA), np.float32)
    parents = graph.skeleton.parents
    for c in range(C):
        n = nodes[start[c] : start[c + 1]]
        values[start[c] : start[c + 1], : layout.dims] = pose_vectors(
            node_rotations(graph, n),
            node_translations(graph, n),
            parents,
            layout,
            graph.node_heading[n].astype(np.float64),
        )
    refs = hemisphere_refs(values[:, : layout.dims], layout.slot)
    align_hemispheres(values, refs, layout.slot)
    e = np.flatnonzero(np.asarray(graph.edge_kind) == EDGE_ORIGINAL)
    into = np.full(graph.num_nodes, -1, np.int64)
    into[np.asarray(graph.edge_dst)[e]] = e
    edge = into[nodes]
    has = edge >= 0
    S = len(graph.sensor_names)
    readings = np.zeros((N, 3 * S), np.float32)
    readings[has] = np.asarray(graph.edge_acc, np.float64)[edge[has]].reshape(-1, 3 * S) / GRAVITY
    d = layout.dims
    values[has, d : d + 2] = np.asarray(graph.edge_offset)[edge[has]]
    values[has, d + 2] = np.asarray(graph.edge_heading)[edge[has]]
    values[:, d + 3 : d + 5] = np.asarray(graph.node_contacts)[nodes]
    for c in range(C):  # (a clip's first frame: its second's readings, a step of zero)
        if sizes[c] > 1 and not has[start[c]]:
            readings[start[c]] = readings[start[c] + 1]
    ground = np.asarray(graph.node_ground, dtype=np.float64)[nodes]
    speed = np.zeros(C)
    for c in range(C):
        g = ground[start[c] : start[c + 1]]
        if g.shape[0] > 1:
            speed[c] = float(np.linalg.norm(np.diff(g, axis=0), axis=1).sum()) * graph.rate_hz / (g.shape[0] - 1)
    return {
        "clip_start": start,
        "nodes": nodes,
        "values": values,
        "readings": readings,
        "speed": speed,
        "pose_dims": np.array([d], np.int64),
        "hemispheres": refs,
    }


def hemisphere_refs(poses: np.ndarray, slot: np.ndarray) -> np.ndarray:
    """(K, 4) per quaternion of the pose vectors (F, D) its principal direction: the top
    eigenvector of Σ q qᵀ over the frames."""
    refs = np.empty((slot.size, 4))
    for k, s in enumerate(slot):
        q = np.asarray(poses[:, s : s + 4], dtype=np.float64)
        refs[k] = np.linalg.eigh(q.T @ q)[1][:, -1]
    return refs


def align_hemispheres(values: np.ndarray, refs: np.ndarray, slot: np.ndarray) -> None:
    """Each quaternion of values (F, ≥ D) onto the side of its slot's principal
    direction, in place. (The local pose's w ≥ 0 side is discontinuous for a joint
    whose rotation stays near 180°: Bandai's skeleton has two such, whose w is within
    0.3 of zero in every frame, and a mix of units across the flip is no rotation.)"""
    for k, s in enumerate(slot):
        flip = values[:, s : s + 4] @ refs[k] < 0.0
        values[flip, s : s + 4] *= -1.0


def touchdowns(contacts: np.ndarray, min_gap: int) -> list[tuple[int, int]]:
    """(frame, foot) of each kept touchdown (module docstring, 2) of contacts (T, 2)."""
    c = np.asarray(contacts) > 0.5
    events = []
    for foot in range(2):
        rise = np.flatnonzero(c[1:, foot] & ~c[:-1, foot]) + 1
        events += [(int(t), foot) for t in rise]
    kept: list[tuple[int, int]] = []
    for t, foot in sorted(events):
        if kept and (t - kept[-1][0] < min_gap or foot == kept[-1][1]):
            continue
        kept.append((t, foot))
    return kept


def step_units(contacts: np.ndarray, rate_hz: float) -> list[tuple[int, int, int]]:
    """(start, end, foot) of the steps of contacts (T, 2): touchdown to touchdown."""
    kept = touchdowns(contacts, max(1, round(MIN_STEP_S * rate_hz)))
    longest = MAX_STEP_S * rate_hz
    return [(a, b, foot) for (a, foot), (b, _) in zip(kept, kept[1:]) if b - a <= longest]


@dataclass
class ClassUnits:
    label: str
    foot: int  # −1: whole clips; 0 left, 1 right
    units: dict  # style → [(clip, start, end)]


def gather_units(graph: MotionGraph, data: dict, clips: np.ndarray) -> tuple[list[ClassUnits], dict[str, bool]]:
    """The units of every class among `clips` (graph clip indices), and which classes
    are locomotion."""
    by_class: dict[str, list[int]] = {}
    for c in clips:
        info = graph.clips[int(c)]
        if is_augmented(info["name"]) or clip_style_take(info["name"]) is None or not info.get("labels"):
            continue
        by_class.setdefault(str(info["labels"][0]), []).append(int(c))
    start = np.asarray(data["clip_start"])
    d = int(np.asarray(data["pose_dims"])[0])
    speed = np.asarray(data["speed"])
    out, locomotion = [], {}
    for label in sorted(by_class):
        members = sorted(by_class[label], key=lambda c: (clip_style_take(graph.clips[c]["name"])[::-1], c))
        moving = bool(np.median(speed[members]) >= LOCOMOTION_SPEED)
        locomotion[label] = moving
        groups = {0: {}, 1: {}} if moving else {-1: {}}
        for c in sorted(members, key=lambda c: (clip_style_take(graph.clips[c]["name"])[1], c)):
            style = clip_style_take(graph.clips[c]["name"])[0]
            if moving:
                contacts = np.asarray(data["values"])[start[c] : start[c + 1], d + 3 : d + 5]
                for a, b, foot in step_units(contacts, graph.rate_hz):
                    groups[foot].setdefault(style, []).append((c, a, b))
            else:
                groups[-1].setdefault(style, []).append((c, 0, int(start[c + 1] - start[c])))
        for foot, units in groups.items():
            out.append(ClassUnits(label, foot, units))
    return out, locomotion


def unit_values(data: dict, clip: int, a: int, b: int) -> np.ndarray:
    s = int(np.asarray(data["clip_start"])[clip])
    return np.asarray(data["values"], dtype=np.float64)[s + a : s + b]


def warp_values(values: np.ndarray, times: np.ndarray, pose_dims: int) -> np.ndarray:
    """A unit's values (L, V) at fractional frame times (K,): the pose and contacts
    interpolated, the root's steps and turn as differences of the interpolated
    cumulative track (a unit played faster takes longer steps a frame)."""
    out = tn.sample(values, times)
    d = pose_dims
    cum = np.concatenate(
        [np.zeros((1, 3)), np.cumsum(values[:, d : d + 3], axis=0)]
    )  # cum[k + 1]: the track at frame k
    t = np.asarray(times, dtype=np.float64)
    previous = np.concatenate([[t[0] - 1.0], t[:-1]])
    out[:, d : d + 3] = tn.sample(cum, t + 1.0) - tn.sample(cum, previous + 1.0)
    return out


def build_tensor(
    data: dict, group: ClassUnits, max_reps: int, variance: float, align: str = "auto"
) -> dict[str, np.ndarray] | None:
    """One class's (and foot's) tensor and its truncated HOSVD (module docstring, 4–5),
    or None with fewer than two units."""
    styles = sorted(s for s, u in group.units.items() if u)
    if sum(len(group.units[s]) for s in styles) < 2:
        return None
    R = min(max_reps, max(len(group.units[s]) for s in styles))
    rows = []
    for s in styles:
        units = group.units[s]
        pick = np.linspace(0, len(units) - 1, R).round().astype(int) if len(units) >= R else np.arange(R) % len(units)
        rows += [units[k] for k in pick]
    lengths = np.array([b - a for _, a, b in rows])
    ref = int(np.flatnonzero(lengths == np.sort(lengths)[(lengths.size - 1) // 2])[0])
    d = int(np.asarray(data["pose_dims"])[0])
    reference = unit_values(data, *rows[ref])
    F = reference.shape[0]
    S = len(styles)
    X = np.empty((reference.shape[1], F, S, R))
    S3 = np.asarray(data["readings"]).shape[1]
    row_readings = np.empty((S * R, F, S3), np.float32)
    row_frame = np.empty((S * R, F))
    start = np.asarray(data["clip_start"])
    for k, (c, a, b) in enumerate(rows):
        v = unit_values(data, c, a, b)
        if align == "dtw" or (align == "auto" and group.foot < 0):
            ia, ib, _ = tn.dtw_path(reference[:, :d], v[:, :d])
            times = tn.warp_onto(ia, ib, F, b - a, DTW_SIGMA * F)
        else:
            times = np.linspace(0.0, b - a - 1.0, F)
        X[:, :, k // R, k % R] = warp_values(v, times, d).T
        row_frame[k] = a + times
        row_readings[k] = tn.sample(np.asarray(data["readings"], np.float64)[start[c] + a : start[c] + b], times)
    return {
        **decompose(X, variance),
        "row_clip": np.array([c for c, _, _ in rows], np.int64),
        "row_frame": row_frame,
        "row_readings": row_readings,
    }


def decompose(X: np.ndarray, variance: float) -> dict[str, np.ndarray]:
    """A tensor X (V, F, S, R) centred and decomposed (module docstring, 5): its mean
    unit (V, F), Φ_t (V, F, kS, kR), the full U_S, U_R, each mode's singular values,
    the kept counts (2,) and the centred tensor."""
    mean = X.mean(axis=(2, 3))
    X = X - mean[:, :, None, None]
    Us, ss = zip(*(tn.mode_svd(X, mode) for mode in range(4)))
    kS, kR = tn.kept_count(ss[2], variance), tn.kept_count(ss[3], variance)
    return {
        "mean": mean,
        "core_t": tn.natural_core(X, Us[2][:, :kS], Us[3][:, :kR]),
        "u_style": Us[2],
        "u_rep": Us[3],
        "sv_style": ss[2],
        "sv_rep": ss[3],
        "sv_values": ss[0],
        "sv_frames": ss[1],
        "kept": np.array([kS, kR], np.int64),
        "tensor": X,
    }


def usable_clips(graph: MotionGraph, allowed: np.ndarray | None) -> np.ndarray:
    """Graph clips a model may learn from: every one with none of its frames hidden."""
    C = len(graph.clips)
    if allowed is None:
        return np.arange(C)
    allowed = np.asarray(allowed, dtype=bool)
    return np.array(
        [
            c
            for c in range(C)
            if allowed[
                int(graph.clips[c]["first_node"]) : int(graph.clips[c]["first_node"]) + int(graph.clips[c]["frames"])
            ].all()
        ],
        dtype=np.int64,
    )


def model_key(own, clips: np.ndarray) -> str:
    """What a learned model depends on, hashed: the options that shape it and its clips."""
    h = hashlib.sha256(repr((MODEL_VERSION, own.variance, own.max_reps, own.align)).encode())
    h.update(np.ascontiguousarray(clips, dtype=np.int64).tobytes())
    return h.hexdigest()[:16]


@one_thread()  # (the same tensors however many threads BLAS has: graphsvc.blas)
def learn(graph: MotionGraph, data: dict, clips: np.ndarray, own) -> dict[str, np.ndarray]:
    """The model's arrays (module docstring) from graph clips `clips`. InputError when no
    class of them has two units."""
    groups, locomotion = gather_units(graph, data, clips)
    labels = list(graph.labels)
    out: dict[str, np.ndarray] = {}
    table = []
    for group in groups:
        t = build_tensor(data, group, own.max_reps, own.variance, own.align)
        if t is None:
            continue
        i = len(table)
        table.append([labels.index(group.label), group.foot, t["core_t"].shape[1]])
        out.update({f"t{i}.{k}": v for k, v in t.items()})
    if not table:
        raise InputError(
            "multilinear: no class of the knowledge base has two takes (clips named <content>_<style>_<take>, "
            "the take three digits or more) to make a tensor of"
        )
    out["tensors"] = np.array(table, np.int64).reshape(-1, 3)
    out["locomotion"] = np.array([labels.index(k) for k, v in sorted(locomotion.items()) if v], np.int64)
    out["clips"] = np.asarray(clips, np.int64)
    return out


@dataclass
class Tensor:
    """One learned tensor, read from the model's arrays."""

    label: int
    foot: int
    frames: int
    mean: np.ndarray  # (V, F)
    core_t: np.ndarray  # (V, F, kS, kR)
    u_style: np.ndarray  # (S, S)
    u_rep: np.ndarray  # (R, R)
    row_clip: np.ndarray
    row_frame: np.ndarray
    row_readings: np.ndarray

    @property
    def kept(self) -> tuple[int, int]:
        return int(self.core_t.shape[2]), int(self.core_t.shape[3])

    def row_coefficients(self, s: int, r: int) -> tuple[np.ndarray, np.ndarray]:
        """x_S, x_R of row (s, r) under the kept vectors."""
        kS, kR = self.kept
        return np.array(self.u_style[s, :kS]), np.array(self.u_rep[r, :kR])

    def row_weights(self, x_s: np.ndarray, x_r: np.ndarray) -> np.ndarray:
        """(S·R,) how much of each original row a motion of coefficients x_S, x_R holds."""
        kS, kR = self.kept
        ab = np.outer(self.u_style[:, :kS] @ x_s, self.u_rep[:, :kR] @ x_r).reshape(-1)
        # (M + Σ ab·(X_sr − M), M the rows' mean: each row's weight ab + (1 − Σ ab) / rows, summing to 1)
        return ab + (1.0 - ab.sum()) / ab.size

    def values(self, x_s: np.ndarray, x_r: np.ndarray) -> np.ndarray:
        """(F, V) the unit M + m(x_S, x_R) on the reference frames."""
        return (self.mean + tn.synthesize(self.core_t, x_s, x_r)).T


def tensor_of(t: dict, label: int = 0, foot: int = -1) -> Tensor:
    """A Tensor from one tensor's arrays (`decompose`'s, with the rows' clip, frames and readings)."""
    return Tensor(
        label,
        foot,
        int(np.asarray(t["core_t"]).shape[1]),
        *(np.asarray(t[k]) for k in ("mean", "core_t", "u_style", "u_rep", "row_clip", "row_frame", "row_readings")),
    )


def tensors_of(arrays: dict) -> list[Tensor]:
    table = np.asarray(arrays["tensors"])
    return [
        tensor_of(
            {k.split(".", 1)[1]: v for k, v in arrays.items() if k.startswith(f"t{i}.")}, int(row[0]), int(row[1])
        )
        for i, row in enumerate(table)
    ]

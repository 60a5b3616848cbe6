"""Offline motion-graph builder (Kelly et al. 2013, §4).

Stages, each over flat arrays: prepare clips (resample to the graph rate, FK,
contacts, pose features, sensor readings at three speeds) → transitions (kd-tree
indexed, contact-constrained) → speed variations → edges with metadata →
interpolation segments → bridges between actions (`bridges.py`) → sort.
"""

from __future__ import annotations

import hashlib
import re
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from pathlib import Path

import numpy as np
from tqdm import tqdm

from graphsvc.errors import InputError, SkeletonError
from graphsvc.graph import bridges as br
from graphsvc.graph import interpolation as interp
from graphsvc.graph import metadata as meta
from graphsvc.graph import partners, records
from graphsvc.graph.connectivity import label_reach
from graphsvc.graph.distance import (
    DEFAULT_WINDOW_S,
    PoseFeatures,
    concat_features,
    distance_block,
    pose_features,
    take,
    window_frames,
)
from graphsvc.graph.labels import AUGMENTED_SUFFIX, clip_frame_labels, content_label, node_labels
from graphsvc.graph.model import (
    EDGE_BRIDGE,
    EDGE_INTERP,
    EDGE_ORIGINAL,
    EDGE_SLOW,
    EDGE_SPEEDUP,
    EDGE_TRANSITION,
    NODE_BRIDGE,
    NODE_INTERP,
    NODE_ORIGINAL,
    NODE_SLOW,
    READING_DTYPE,
    MotionGraph,
    incoming_offsets,
)
from graphsvc.graph.poses import PosePacker, moving_joints, rotating_joints
from graphsvc.graph.records import BRIDGE_FIELDS, Records
from graphsvc.graph.rows import drain
from graphsvc.graph.transitions import DEFAULT_THRESHOLD_M, find_transitions
from graphsvc.heap import release_free_memory
from graphsvc.motion import augment as aug
from graphsvc.motion import quat, signals
from graphsvc.motion.joints import CANONICAL, joint_map
from graphsvc.motion.kinematics import forward_kinematics, motion_fk
from graphsvc.motion.library import find_motion_files, load_motion
from graphsvc.motion.resample import resample
from graphsvc.motion.retarget import pool_skeletons
from graphsvc.motion.skeleton import Motion, Skeleton, check_finite
from graphsvc.sensors.accelerometer import simulate_accelerations
from graphsvc.sensors.anatomy import ANATOMICAL
from graphsvc.sensors.layout import PRESETS, Layout, Placement, anatomical_placement, place


@dataclass(frozen=True)
class BuildOptions:
    """rate_hz: graph rate. transition_threshold_m: RMS point-cloud distance (m).
    window_s: distance window. max_transitions_per_frame: cap on a frame's
    transitions (None: all local minima). transition_candidates: each contact-change
    frame's candidate partners, its this many nearest by the distance's lower bound
    within the threshold (`transitions.indexed_pairs`; None: every frame within it,
    which grows with the square of a label's near-identical clips). still_clip_step_s: clips without any
    contact change (gestures with both feet planted) offer a transition candidate
    every this many seconds, or they could never be entered or left. bridges:
    blended transitions between actions and out of / into clip ends (`bridges.py`),
    at most bridge_threshold_m (bridge_end_threshold_m for clip ends) apart, one
    per other label every bridge_spacing_s of a clip. jobs: threads for clip
    preparation (does not change the result)."""

    rate_hz: float = 30.0
    layout: Layout | None = None
    msv: bool = True
    interp: bool = True
    transition_threshold_m: float = DEFAULT_THRESHOLD_M
    interp_threshold_m: float = 0.08
    interp_min_s: float = 0.5
    interp_partners: int = 2
    window_s: float = DEFAULT_WINDOW_S
    max_transitions_per_frame: int | None = 8
    transition_candidates: int | None = 128
    still_clip_step_s: float = 0.2
    bridges: bool = True
    bridge_threshold_m: float = br.DEFAULT_THRESHOLD_M
    bridge_end_threshold_m: float = br.DEFAULT_END_THRESHOLD_M
    bridge_spacing_s: float = br.DEFAULT_SPACING_S
    augment: tuple[str, ...] = ()
    mapping: dict | None = None  # canonical joint → skeleton joint, for unknown skeletons
    jobs: int = 1
    progress: bool | None = None  # None: only on a terminal


@dataclass
class PreparedClip:
    """One KB clip at the graph rate, with everything the graph needs (F frames);
    `build_graph` empties its features and midpoints once they are spent (`_spent`)."""

    motion: Motion
    contacts: np.ndarray  # (F, 2) bool
    changes: np.ndarray  # (F,) bool
    ground: np.ndarray  # (F, 2)
    heading: np.ndarray  # (F,)
    features: PoseFeatures
    readings: meta.SpeedReadings
    half_ground: np.ndarray  # (2F−1, 2)
    half_heading: np.ndarray  # (2F−1,)
    mid_rotations: np.ndarray  # (F−1, J, 4) float32: the half-speed poses between frames
    mid_translations: np.ndarray  # (F−1, J, 3) float32
    placement: Placement  # the layout on this clip, its sensor frames estimated from the clip's motion
    digest: str = ""


def _spent(clip: PreparedClip) -> PreparedClip:
    """The clip without what only the transitions, the speed variations and the
    interpolation use: its window clouds (1.6 KB a frame) and half-speed midpoints
    (0.6 KB), left with zero rows."""
    f = clip.features
    none = lambda a: a[:0].copy()  # noqa: E731  (a copy: a view would keep the rows alive)
    return replace(
        clip,
        features=PoseFeatures(none(f.x), none(f.z), none(f.y), none(f.norm2), none(f.mean_xz)),
        mid_rotations=none(clip.mid_rotations),
        mid_translations=none(clip.mid_translations),
    )


@dataclass
class BuildReport:
    timings: dict = field(default_factory=dict)
    still_clips: list = field(default_factory=list)
    transitions: int = 0
    bridges: int = 0


def content_digest(motion: Motion) -> str:
    """sha256 of the source file when there is one, else of the motion's arrays."""
    h = hashlib.sha256()
    src = Path(motion.source) if motion.source else None
    if src is not None and src.is_file():
        h.update(src.read_bytes())
    else:
        h.update(np.ascontiguousarray(motion.rotations).tobytes())
        h.update(np.ascontiguousarray(motion.translations).tobytes())
    return h.hexdigest()


def check_knowledge_base(motions: list[Motion], window: int, rate_hz: float) -> None:
    """One topology, finite values, every clip at least one distance window long."""
    if not motions:
        raise InputError("the knowledge base is empty: no motion files given or found")
    first = motions[0]
    for m in motions:
        check_finite(m)
        if m.skeleton.names != first.skeleton.names or not np.array_equal(m.skeleton.parents, first.skeleton.parents):
            raise SkeletonError(
                f"the knowledge base mixes skeleton topologies: {first.source or first.name} and "
                f"{m.source or m.name} differ (one topology per graph)"
            )
        frames = int(np.floor((m.num_frames - 1) * rate_hz / m.rate_hz + 1e-9)) + 1
        if frames < max(window, 3):
            raise InputError(
                f"{m.source or m.name}: {frames} frames at {rate_hz:g} Hz, shorter than the "
                f"distance window of {window} frames"
            )


def prepare_clip(motion: Motion, rate_hz: float, layout: Layout, window: int, mapping=None) -> PreparedClip:
    motion = resample(motion, rate_hz)
    sk = motion.skeleton
    table = joint_map(sk, mapping)
    world_rot, world_pos = motion_fk(motion)
    contacts = signals.foot_contacts(world_pos, table, rate_hz)
    ground, heading = meta.ground_and_heading(world_pos, table)
    canon = world_pos[:, [table[c] for c in CANONICAL]]
    half_rot, half_trans = meta.half_speed_poses(motion.rotations, motion.translations)
    half_world_rot, half_pos = forward_kinematics(half_rot, half_trans, sk.parents)
    half_ground, half_heading = meta.ground_and_heading(half_pos, table)
    placement = anatomical_placement(layout, sk, mapping, world_rot, world_pos)
    readings = meta.speed_readings(world_rot, world_pos, half_world_rot, half_pos, placement, rate_hz)
    return PreparedClip(
        motion=motion,
        contacts=contacts,
        changes=signals.contact_changes(contacts),
        ground=ground,
        heading=heading,
        features=pose_features(canon, window),
        readings=readings,
        half_ground=half_ground,
        half_heading=half_heading,
        mid_rotations=half_rot[1::2].astype(np.float32),
        mid_translations=half_trans[1::2].astype(np.float32),
        placement=placement,
        digest=content_digest(motion),
    )


def standard_skeleton(motions: list[Motion]) -> Skeleton:
    """The KB topology with bone offsets averaged over clips (Tautges et al. 2011, §3)."""
    sk = motions[0].skeleton
    offsets = np.mean([m.skeleton.offsets for m in motions], axis=0)
    return Skeleton(sk.names, sk.parents, offsets, sk.channels, sk.end_site)


class _Edges:
    """Edge lists gathered per kind, concatenated once at the end: src, dst (int64),
    kind (uint8), readings (in the graph's READING_DTYPE, rounded through float32 as
    ever), offset and heading change (float32), a list of parts each."""

    def __init__(self) -> None:
        self.src: list[np.ndarray] = []
        self.dst: list[np.ndarray] = []
        self.kind: list[np.ndarray] = []
        self.acc: list[np.ndarray] = []
        self.offset: list[np.ndarray] = []
        self.dheading: list[np.ndarray] = []

    def add(self, src, dst, kind, acc, offset, dheading):
        n = len(src)
        if n:
            self.src.append(np.asarray(src, np.int64))
            self.dst.append(np.asarray(dst, np.int64))
            self.kind.append(np.full(n, kind, np.uint8))
            self.acc.append(acc.astype(np.float32).astype(READING_DTYPE))
            self.offset.append(offset.astype(np.float32))
            self.dheading.append(dheading.astype(np.float32))

    def arrays(self, S: int):
        """(src, dst, kind, readings, offset, heading change), each part freed as it is
        copied (call once)."""
        return (
            drain(self.src, (0,), np.int64),
            drain(self.dst, (0,), np.int64),
            drain(self.kind, (0,), np.uint8),
            drain(self.acc, (0, S, 3), READING_DTYPE),
            drain(self.offset, (0, 2), np.float32),
            drain(self.dheading, (0,), np.float32),
        )


def thread_map(jobs: int) -> Callable:
    """A `ClipMap` over `jobs` threads of this process."""

    def run(fn, items, desc: str = "", progress: bool | None = None) -> list:
        with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
            return list(
                tqdm(
                    pool.map(fn, items),
                    total=len(items),
                    desc=desc,
                    unit="clip",
                    disable=None if progress is None else not progress,
                )
            )

    return run


# ClipMap: (fn, items, desc, progress) → [fn(item) for item in items], in order, however
# it runs them: `thread_map` here, Dask tasks on a cluster (`graphsvc build --scheduler`).
# fn and items are picklable (module-level functions, `functools.partial` of them).
ClipMap = Callable[..., list]


def build_graph(
    motions: list[Motion], options: BuildOptions, frame_labels: dict | None = None, clip_map: ClipMap | None = None
) -> tuple[MotionGraph, BuildReport]:
    """Build the motion graph of a knowledge base (already loaded and augmented).
    frame_labels: clip name → (F,) per-frame content labels, for knowledge bases
    whose clips hold more than one action (the procedural one's stop clips walk first);
    a node then carries the label of the frame it comes from (`_node_labels`), else its
    clip's. Mirrored and reversed copies take their original's, mirrored or reversed.
    clip_map: where the per-clip stage (resampling, kinematics, contacts, features,
    readings) runs (`ClipMap`; default `options.jobs` threads): the graph is the same."""
    layout = options.layout or PRESETS["wrists-ankles"]
    rate = float(options.rate_hz)
    if not (np.isfinite(rate) and rate > 0):
        raise InputError(f"graph rate must be positive, got {rate}")
    window = window_frames(rate, options.window_s)
    check_knowledge_base(motions, window, rate)
    joint_map(motions[0].skeleton, options.mapping)  # unknown skeleton: fail before any work
    place(layout, motions[0].skeleton, options.mapping)  # layout naming missing joints: same
    report = BuildReport()
    bar = lambda it, **kw: tqdm(it, disable=None if options.progress is None else not options.progress, **kw)  # noqa: E731

    t0 = time.perf_counter()
    prepare = partial(prepare_clip, rate_hz=rate, layout=layout, window=window, mapping=options.mapping)
    clips = (clip_map or thread_map(options.jobs))(prepare, motions, desc="clips", progress=options.progress)
    report.timings["prepare_s"] = time.perf_counter() - t0

    C = len(clips)
    lengths = np.array([c.motion.num_frames for c in clips], dtype=np.int64)
    start = np.zeros(C + 1, dtype=np.int64)
    np.cumsum(lengths, out=start[1:])
    N0 = int(start[-1])
    clip_of_frame = np.repeat(np.arange(C), lengths)
    frame_in_clip = np.arange(N0) - start[clip_of_frame]
    contacts = np.concatenate([c.contacts for c in clips])
    changes = np.concatenate([c.changes for c in clips])
    ground = np.concatenate([c.ground for c in clips])
    heading = np.concatenate([c.heading for c in clips])
    normal = np.concatenate([c.readings.normal for c in clips])
    S = normal.shape[1]

    # Clips where the feet never change contact (waving, bowing) would be islands:
    # offer regularly spaced candidates there instead of contact changes.
    candidates = changes.copy()
    step = max(1, int(round(options.still_clip_step_s * rate)))
    for c, clip in enumerate(clips):
        if not clip.changes[1:].any():
            report.still_clips.append(clip.motion.name)
            frames = np.arange(step, lengths[c] - 1, step)
            candidates[start[c] + frames] = True
    if not candidates.any():
        raise InputError("no clip of the knowledge base has a foot-contact change: no transitions possible")

    t0 = time.perf_counter()
    scale = rate / 30.0  # the transition search's frame radii are tuned at 30 Hz
    trans = find_transitions(
        concat_features([c.features for c in clips]),
        contacts,
        candidates,
        clip_of_frame,
        frame_in_clip,
        lengths,
        threshold_m=options.transition_threshold_m,
        exclude_same_clip_within=max(1, int(round(10 * scale))),
        local_min_radius=max(1, int(round(5 * scale))),
        max_per_source=options.max_transitions_per_frame,
        k=options.transition_candidates,
    )
    report.transitions = len(trans)
    report.timings["transitions_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    edges = _Edges()
    # Original edges: f → f+1 within each clip, reading the clip's own stream.
    has_next = frame_in_clip < lengths[clip_of_frame] - 1
    src = np.nonzero(has_next)[0]
    off, dh = meta.local_offsets(ground[src], heading[src], ground[src + 1], heading[src + 1])
    edges.add(src, src + 1, EDGE_ORIGINAL, normal[src + 1], off, dh)

    # Transitions i → j+1: continue as j's clip continues, placed by the alignment
    # that takes j's window onto i's.
    i, j = trans.src, trans.dst
    dst_ground = meta.rotate_ground(ground[j + 1], trans.theta, trans.translation)
    off, dh = meta.local_offsets(ground[i], heading[i], dst_ground, heading[j + 1] + trans.theta)
    edges.add(i, j + 1, EDGE_TRANSITION, normal[j + 1], off, dh)

    node_parts: dict[str, list[np.ndarray]] = {
        "kind": [np.full(N0, NODE_ORIGINAL, np.uint8)],
        "clip": [clip_of_frame.astype(np.int32)],
        "frame": [frame_in_clip.astype(np.float32)],
        "contacts": [contacts],
        "ground": [ground.astype(np.float32)],
        "heading": [heading.astype(np.float32)],
    }
    poses = PosePacker(
        rotating_joints([c.motion.rotations for c in clips]),
        moving_joints([c.motion.translations for c in clips]),
        clips[0].motion.skeleton.num_joints,
    )
    for c in clips:
        poses.add(c.motion.rotations, c.motion.translations)
    next_node = N0
    if options.msv:
        for c, clip in enumerate(clips):
            next_node = _add_speed_variations(clip, int(start[c]), c, next_node, edges, node_parts, poses)
    report.timings["edges_s"] = time.perf_counter() - t0
    segments = []
    if options.interp:
        t0 = time.perf_counter()
        segments = _add_interpolations(clips, start, options, layout, next_node, edges, node_parts, poses, bar)
        next_node = sum(len(k) for k in node_parts["kind"])
        report.timings["interpolation_s"] = time.perf_counter() - t0
    clips = [_spent(c) for c in clips]  # (before the bridges, the build's memory peak)
    release_free_memory()
    per_frame = [clip_frame_labels(c.motion, frame_labels, int(lengths[k])) for k, c in enumerate(clips)]
    labels = sorted({content_label(m.motion) for m in clips} | {x for f in per_frame if f is not None for x in f})
    label_of_clip = np.array([labels.index(content_label(c.motion)) for c in clips], dtype=np.int32)
    bridges = records.bridges()
    if options.bridges:
        t0 = time.perf_counter()
        bridges = _add_bridges(
            clips, start, label_of_clip, window, options, layout, next_node, edges, node_parts, poses
        )
        report.bridges = len(bridges)
        report.timings["bridges_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    e_src, e_dst, e_kind, e_acc, e_off, e_dh = edges.arrays(S)
    # Sort by destination, then source, then kind; drop duplicate (src, dst) pairs
    # (a transition onto the next frame duplicates the original edge) keeping the
    # lowest kind, so the order never depends on how edges were gathered.
    order = np.lexsort((e_kind, e_src, e_dst))
    src_sorted, dst_sorted = e_src[order], e_dst[order]
    keep = np.ones(len(order), dtype=bool)
    keep[1:] = (src_sorted[1:] != src_sorted[:-1]) | (dst_sorted[1:] != dst_sorted[:-1])
    order = order[keep]  # every edge array below is indexed by this one order
    del src_sorted, dst_sorted, keep
    # Each array put in order as the gathered one is dropped, the node parts freed as they
    # are joined: the graph's arrays are never held twice.
    edge_src = e_src[order].astype(np.int32)
    del e_src
    edge_dst = e_dst[order]
    del e_dst
    edge_kind = e_kind[order]
    del e_kind
    edge_acc = e_acc[order]
    del e_acc
    edge_offset = e_off[order]
    del e_off
    edge_heading = e_dh[order]
    del e_dh, order
    N = sum(len(k) for k in node_parts["kind"])
    incoming = incoming_offsets(edge_dst, N)
    node_clip = drain(node_parts["clip"], (0,), np.int32)
    node_frame = drain(node_parts["frame"], (0,), np.float32)
    graph = MotionGraph(
        rate_hz=rate,
        skeleton=standard_skeleton([c.motion for c in clips]),
        layout=layout.to_dict(),
        clips=[_clip_record(c, int(lengths[k]), int(start[k])) for k, c in enumerate(clips)],
        labels=tuple(labels),
        params={k: v for k, v in _params(options, layout, window).items()},
        clip_offsets=np.stack([c.motion.skeleton.offsets for c in clips]),
        node_kind=drain(node_parts["kind"], (0,), np.uint8),
        node_clip=node_clip,
        node_frame=node_frame,
        node_contacts=drain(node_parts["contacts"], (0, 2), bool),
        node_label=node_labels(per_frame, labels, label_of_clip, start, lengths, node_clip, node_frame),
        **poses.arrays(),
        node_ground=drain(node_parts["ground"], (0, 2), np.float32),
        node_heading=drain(node_parts["heading"], (0,), np.float32),
        edge_src=edge_src,
        edge_dst=edge_dst.astype(np.int32),
        edge_kind=edge_kind,
        edge_acc=edge_acc,
        edge_offset=edge_offset,
        edge_heading=edge_heading,
        incoming=incoming,
        segments=records.segments(segments),
        bridges=bridges,
    )
    del clips, edge_dst  # (what the prepared clips still hold: readings, placements)
    release_free_memory()
    report.timings["assemble_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    graph.edge_up = meta.edge_up_vectors(graph, layout)  # (from the stored poses, as `relayout` computes it)
    report.timings["orientations_s"] = time.perf_counter() - t0
    return graph, report


def _clip_record(clip: PreparedClip, frames: int, first_node: int) -> dict:
    """A clip's entry in the graph (`MotionGraph.clips`): where it came from, its
    content hash, frames and labels; `retargeted_from`, the skeleton family it was
    captured on, when it was put on the graph's skeleton from another."""
    m = clip.motion
    out = {
        "name": m.name,
        "source": m.source,
        "sha256": clip.digest,
        "frames": frames,
        "first_node": first_node,
        "labels": list(m.labels) or [m.name],
    }
    if m.retargeted_from:
        out["retargeted_from"] = m.retargeted_from
    return out


def _performance(motion: Motion) -> tuple[str, str]:
    """What identifies one recorded performance across its augmented copies."""
    return motion.source, re.sub(AUGMENTED_SUFFIX, "", motion.name)


def _params(options: BuildOptions, layout: Layout, window: int) -> dict:
    d = asdict(options)
    d["layout"] = layout.name
    d["window_frames"] = window
    d["sensor_frames"] = ANATOMICAL
    d["augment"] = list(options.augment)
    for k in ("jobs", "progress"):  # do not change the graph: keep them out of the file
        d.pop(k)
    return d


def _add_speed_variations(
    clip: PreparedClip, first: int, clip_index: int, next_node: int, edges: _Edges, parts, poses: PosePacker
) -> int:
    """Slow-down nodes between frames f and f+1 and speed-up edges f → f+2 (Kelly et al. 2013, §4.1),
    never where a frame involved has both feet off the ground (gravity would play
    at half or double strength). Returns the next free node index."""
    F = clip.motion.num_frames
    grounded = np.asarray(clip.contacts.any(axis=1))
    r = clip.readings
    # Slow-down: o_f → s_f → o_{f+1}, along the half-speed timeline.
    f = np.nonzero(grounded[:-1] & grounded[1:])[0]
    s = next_node + np.arange(len(f))
    hg, hh = clip.half_ground, clip.half_heading
    off_in, dh_in = meta.local_offsets(hg[2 * f], hh[2 * f], hg[2 * f + 1], hh[2 * f + 1])
    off_out, dh_out = meta.local_offsets(hg[2 * f + 1], hh[2 * f + 1], hg[2 * f + 2], hh[2 * f + 2])
    edges.add(first + f, s, EDGE_SLOW, r.half[2 * f + 1], off_in, dh_in)
    edges.add(s, first + f + 1, EDGE_SLOW, r.half[2 * f + 2], off_out, dh_out)
    parts["kind"].append(np.full(len(f), NODE_SLOW, np.uint8))
    parts["clip"].append(np.full(len(f), clip_index, np.int32))
    parts["frame"].append((f + 0.5).astype(np.float32))
    parts["contacts"].append(clip.contacts[f] & clip.contacts[f + 1])
    poses.add(clip.mid_rotations[f], clip.mid_translations[f])
    parts["ground"].append(hg[2 * f + 1].astype(np.float32))
    parts["heading"].append(hh[2 * f + 1].astype(np.float32))
    # Speed-up: o_f → o_{f+2}, reading the double-speed playback.
    if F >= 3:
        g = np.nonzero(grounded[:-2] & grounded[1:-1] & grounded[2:])[0]
        off, dh = meta.local_offsets(clip.ground[g], clip.heading[g], clip.ground[g + 2], clip.heading[g + 2])
        edges.add(first + g, first + g + 2, EDGE_SPEEDUP, r.double[g + 2], off, dh)
    return next_node + len(f)


def _add_interpolations(clips, start, options, layout, next_node, edges, parts, poses, bar) -> list[dict]:
    """Interpolation nodes (Kelly et al. 2013, §4.2). For every pair of clips with the same content
    label — K blends only similar actions, and restricting the pairs keeps the
    similarity matrices few — find regions of similar frames with equal contact
    state, align each with slope-bounded DTW, and blend segments longer than
    `interp_min_s` with even weights into new nodes, expressed in clip a's frame.
    Each segment is entered from the frames before it in both clips and left
    toward the frames after it in both; a segment that reaches a clip's first or
    last frames on both sides is trimmed so that it can be entered and left
    (`interpolation.trim_to_reachable`).

    Blending every pair grows the graph with the square of the clips per label
    (Bandai: 13× the data); each clip instead blends with its `interp_partners` best
    partners, ranked by the fraction of its frames that have a close match in the
    partner (`partners.choose_partners`: all pairs of a label's clips, or a clip-level
    index where a label has many), so growth stays linear in the data."""
    rate = options.rate_hz
    by_label: dict[str, list[int]] = {}
    for c, clip in enumerate(clips):
        by_label.setdefault(content_label(clip.motion), []).append(c)
    # Ranking looks at every `step`-th frame only (0.1 s apart): a ninth of the cells,
    # enough to tell which clips share long similar stretches.
    step = max(1, int(round(rate / 10.0)))
    sampled = [(take(c.features, np.arange(0, c.motion.num_frames, step)), c.contacts[::step]) for c in clips]
    chosen = partners.choose_partners(
        sampled,
        list(by_label.values()),
        [_performance(c.motion) for c in clips],
        options.interp_threshold_m,
        options.interp_partners,
        bar=bar,
    )
    segments = []
    first_reached, last_grounded = br.reachable_span(np.concatenate([c.contacts for c in clips]), start)
    for a, b in bar(sorted(chosen), desc="interpolation", unit="pair"):
        A, B = clips[a], clips[b]
        # Recomputed rather than kept from the ranking pass: storing every pair's
        # matrix costs gigabytes on large KBs, computing one costs a millisecond.
        distance = distance_block(A.features, B.features)
        same = interp.same_contact_matrix(A.contacts, B.contacts)
        for aligned in interp.aligned_segments(distance, same, options.interp_threshold_m, rate, options.interp_min_s):
            path = interp.trim_to_reachable(
                aligned,
                (first_reached[a], last_grounded[a]),
                (first_reached[b], last_grounded[b]),
                rate,
                options.interp_min_s,
            )
            if path is None:
                continue
            seg = _blend_segment(A, B, path, layout, rate, options.mapping)
            if seg is None:
                continue
            rot, trans, ground, heading, contacts, coords_a, readings, theta, shift = seg
            K = rot.shape[0]
            nodes = next_node + np.arange(K)
            next_node += K
            parts["kind"].append(np.full(K, NODE_INTERP, np.uint8))
            parts["clip"].append(np.full(K, a, np.int32))
            parts["frame"].append(coords_a.astype(np.float32))
            parts["contacts"].append(contacts)
            poses.add(rot, trans)
            parts["ground"].append(ground.astype(np.float32))
            parts["heading"].append(heading.astype(np.float32))
            off, dh = meta.local_offsets(ground[:-1], heading[:-1], ground[1:], heading[1:])
            edges.add(nodes[:-1], nodes[1:], EDGE_INTERP, readings[1:], off, dh)
            (a0, b0), (a1, b1) = path[0], path[-1]
            # b's frames, moved into a's frame by the segment's alignment.
            b_ground = meta.rotate_ground(
                B.ground, np.full(B.ground.shape[0], theta), np.broadcast_to(shift, B.ground.shape)
            )
            b_heading = B.heading + theta
            for clip_index, g, h, first, last, clip in (
                (a, A.ground, A.heading, a0, a1, A),
                (b, b_ground, b_heading, b0, b1, B),
            ):
                base = int(start[clip_index])
                if first >= 1:  # enter from the frame before the segment
                    off, dh = meta.local_offsets(g[first - 1 : first], h[first - 1 : first], ground[:1], heading[:1])
                    edges.add([base + first - 1], nodes[:1], EDGE_INTERP, readings[:1], off, dh)
                if last + 1 < clip.motion.num_frames:  # leave toward the frame after it
                    off, dh = meta.local_offsets(
                        ground[-1:], heading[-1:], g[last + 1 : last + 2], h[last + 1 : last + 2]
                    )
                    edges.add(
                        nodes[-1:], [base + last + 1], EDGE_INTERP, clip.readings.normal[last + 1 : last + 2], off, dh
                    )
            segments.append(
                {
                    "first_node": int(nodes[0]),
                    "count": int(K),
                    "clip_a": int(a),
                    "clip_b": int(b),
                    "a_start": int(a0),
                    "a_end": int(a1),
                    "b_start": int(b0),
                    "b_end": int(b1),
                    "theta": float(theta),
                    "translation": [float(v) for v in shift],
                }
            )
    return segments


def _add_bridges(clips, start, label_of_clip, window, options, layout, next_node, edges, parts, poses) -> Records:
    """Bridges between actions and out of / into every clip's ends (`bridges.py`):
    their nodes and edges appended to the graph under construction. Returns the
    bridge records (graph.bridges)."""
    rate = options.rate_hz
    sk = clips[0].motion.skeleton
    joints = joint_map(sk, options.mapping)
    performances: dict = {}
    performance = np.array([performances.setdefault(_performance(c.motion), len(performances)) for c in clips])
    performers: dict = {}
    performer = np.array(
        [performers.setdefault(np.round(c.motion.skeleton.offsets, 6).tobytes(), len(performers)) for c in clips]
    )
    rotations = np.concatenate([c.motion.rotations for c in clips])
    translations = np.concatenate([c.motion.translations for c in clips])
    heading = np.concatenate([c.heading for c in clips])
    # (the positions prepare_clip computed, the same numbers: not kept clip by clip)
    canon, pelvis_rel, pelvis_height = br.world_summaries(
        rotations, translations, heading, sk.parents, joints["pelvis"], [joints[c] for c in CANONICAL]
    )
    kb = br.KBFrames(
        rotations=rotations,
        translations=translations,
        pelvis_rel=pelvis_rel,
        pelvis_height=pelvis_height,
        ground=np.concatenate([c.ground for c in clips]),
        heading=heading,
        contacts=np.concatenate([c.contacts for c in clips]),
        window=window,
        canon=canon,
        start=start,
        label=np.asarray(label_of_clip),
        performance=performance,
        performer=performer,
    )
    # Bridges between labels only where the graph so far is slow to get from one to the
    # other: where plain transitions already connect two actions (a walk and a walk
    # that turns), bridges measured no better on mixed performances, at 11 % more nodes.
    node_label = np.asarray(label_of_clip)[np.concatenate(parts["clip"])]
    e_src, e_dst = np.concatenate(edges.src), np.concatenate(edges.dst)
    typical = label_reach(e_src, e_dst, node_label, int(np.max(label_of_clip)) + 1)[1] / rate
    needed = ~(typical <= options.bridge_spacing_s / 2.0)
    np.fill_diagonal(needed, False)
    matches = br.select_matches(
        kb,
        rate,
        options.bridge_threshold_m,
        options.bridge_end_threshold_m,
        options.bridge_spacing_s,
        needed,
        options.jobs,
    )
    if not len(matches):
        return records.bridges()
    nodes = br.blend_bridges(kb, matches, sk, joints, lambda c: clips[c].placement, rate, poses.add)
    B, M = len(matches), nodes.ground.shape[0]
    parts["kind"].append(np.full(M, NODE_BRIDGE, np.uint8))
    parts["clip"].append(nodes.source_clip.astype(np.int32))
    parts["frame"].append(nodes.source_frame.astype(np.float32))
    parts["contacts"].append(nodes.contacts)
    parts["ground"].append(nodes.ground.astype(np.float32))
    parts["heading"].append(nodes.heading.astype(np.float32))
    # Edges bridge by bridge: entry → node 1 → … → node L → exit (the order of nodes.readings).
    ids = next_node + np.arange(M)
    bridge = np.repeat(np.arange(B), nodes.count)
    first = nodes.first[bridge] == np.arange(M)
    entry = start[matches.clip_a] + matches.entry
    exit_frame = start[matches.clip_b] + matches.exit
    src_in = np.where(first, entry[bridge], ids - 1)
    last_ids = ids[nodes.first + nodes.count - 1]
    src = np.empty(M + B, np.int64)
    dst = np.empty(M + B, np.int64)
    inner = np.ones(M + B, dtype=bool)
    inner[nodes.first + np.arange(B) + nodes.count] = False
    src[inner], dst[inner] = src_in, ids
    src[~inner], dst[~inner] = last_ids, exit_frame
    edges.add(src, dst, EDGE_BRIDGE, nodes.readings, nodes.step_offset, nodes.step_heading)
    columns = {
        "first_node": next_node + nodes.first,
        "count": nodes.count,
        "clip_a": matches.clip_a,
        "clip_b": matches.clip_b,
        "a_entry": matches.entry,
        "b_exit": matches.exit,
        "a_match": matches.i,
        "b_match": matches.j,
        "distance_m": np.round(np.asarray(matches.distance, np.float64), 5),
        "kind": matches.kind,
    }
    return Records(BRIDGE_FIELDS, {f.name: np.asarray(columns[f.name], dtype=f.dtype) for f in BRIDGE_FIELDS})


def _blend_segment(A: PreparedClip, B: PreparedClip, path: np.ndarray, layout: Layout, rate: float, mapping=None):
    """Even-weight blend of clips A and B along a DTW path, in A's frame."""
    theta, shift = interp.path_alignment(A.features, B.features, path)
    rot_b = B.motion.rotations.copy()
    trans_b = B.motion.translations.copy()
    # Move all of B rigidly: turn and shift its root, the rest of the body follows.
    rot_b[:, 0] = quat.mul(quat.about_y(np.full(rot_b.shape[0], theta)), rot_b[:, 0])
    root_xz = meta.rotate_ground(
        trans_b[:, 0, [0, 2]], np.full(rot_b.shape[0], theta), np.broadcast_to(shift, (rot_b.shape[0], 2))
    )
    trans_b[:, 0, 0], trans_b[:, 0, 2] = root_xz[:, 0], root_xz[:, 1]
    rot = interp.blend_along_path(A.motion.rotations, rot_b, path)
    trans = interp.blend_arrays_along_path(A.motion.translations, trans_b, path)
    if rot.shape[0] < 2:
        return None
    coords_a, _ = interp.blend_timeline(path)
    sk = A.motion.skeleton
    world_rot, world_pos = forward_kinematics(rot, trans, sk.parents)
    ground, heading = meta.ground_and_heading(world_pos, joint_map(sk, mapping))
    readings = simulate_accelerations(world_rot, world_pos, A.placement, rate)
    contacts = A.contacts[np.clip(np.rint(coords_a).astype(np.int64), 0, A.motion.num_frames - 1)]
    return rot, trans, ground, heading, contacts, coords_a, readings, theta, np.asarray(shift, dtype=np.float64)


def load_knowledge_base(
    paths: Sequence[str],
    exclude: Sequence[str] = (),
    augment: tuple[str, ...] = (),
    jobs: int = 1,
    progress: bool | None = None,
    skeleton: Motion | None = None,
    mapping=None,
    clip_map: ClipMap | None = None,
) -> list[Motion]:
    """Load KB files/folders/globs, put every clip on one skeleton (`retarget.pool_skeletons`:
    `skeleton`'s, else that of the first file of the first path), then add the requested
    augmented copies (`mirror`: left/right mirror images, `reverse`: time-reversed clips;
    OLNG paper). mapping: the joint map of a skeleton no built-in map fits. clip_map:
    where the files are read and clips retargeted (`ClipMap`; default `jobs` threads)."""
    unknown = sorted(set(augment) - {"mirror", "reverse"})
    if unknown:
        raise InputError(f"unknown augmentation {', '.join(unknown)} (choose from mirror, reverse)")
    files = find_motion_files(list(paths), exclude=list(exclude))
    if not files:
        raise InputError("the knowledge base is empty: no .bvh, .amc or DeepMimic .txt files matched")
    motions = (clip_map or thread_map(jobs))(load_motion, files, desc="loading", progress=progress)
    first = next(iter(find_motion_files(list(paths)[:1], exclude=list(exclude))), files[0])
    motions = pool_skeletons(
        motions, skeleton, mapping, first=files.index(first), clip_map=clip_map or thread_map(jobs), progress=progress
    )
    if augment:
        extra = []
        if "mirror" in augment:
            extra += [aug.mirror_motion(m) for m in motions]
        if "reverse" in augment:
            extra += [aug.reverse_motion(m) for m in motions + extra]
        motions = motions + extra
    return motions

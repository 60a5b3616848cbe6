"""The motion graph as flat arrays.

Nodes are poses: every knowledge-base frame (original), half-way frames for playing
slower (slow-down), blends of similar segments (interpolated), and the blended frames
of bridges that carry one clip into another of a different action (`bridges.py`).
Each node keeps its full local pose (packed, `graph/poses.py`), so sensor metadata for
any layout can be recomputed from the graph alone (`graph.metadata.recompute_accelerations`).

An edge m → n says "after pose m, pose n may follow, one sample later". Its metadata
(Kelly et al. 2013, §4.3): the accelerations the layout's sensors read on arriving at n that way
(S × 3, m/s², sensor frames), the root's ground displacement expressed in m's local
frame (metres; local frame: facing +Z, left +X), and the heading change (radians).
Edges are sorted by destination then source, so a node's incoming edges are one
contiguous run (`incoming`, CSR offsets) — the access pattern of the Viterbi search.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from graphsvc.graph import records
from graphsvc.graph.poses import pack_poses
from graphsvc.graph.records import Records
from graphsvc.graph.rows import ranges
from graphsvc.motion.skeleton import Skeleton

NODE_ORIGINAL, NODE_SLOW, NODE_INTERP, NODE_BRIDGE = 0, 1, 2, 3
NODE_KINDS = ("original", "slow-down", "interpolated", "bridge")
EDGE_ORIGINAL, EDGE_SLOW, EDGE_SPEEDUP, EDGE_TRANSITION, EDGE_INTERP, EDGE_BRIDGE = 0, 1, 2, 3, 4, 5
EDGE_KINDS = ("original", "slow-down", "speed-up", "transition", "interpolated", "bridge")
# Edge readings as a graph stores them: float16 keeps 11 significant bits, 0.004 m/s²
# at 10 m/s² (0.03 at 100), under any accelerometer's noise; the search reads them
# through float32 tables. Half the bytes of float32: 24 a 4-sensor edge.
READING_DTYPE = np.float16
_AUGMENTED = re.compile(r"_(mirror|reverse)$")


@dataclass(eq=False)
class MotionGraph:
    """Node arrays have N rows, edge arrays E rows; J joints, S sensors, C clips.

    node_kind (N,) uint8; node_clip (N,) int32 source clip; node_frame (N,) float32
    source frame (x.5 for slow-down nodes); node_contacts (N, 2) bool (left, right);
    node_label (N,) int32 into `labels` (a file holds node_clip and node_bones as
    uint16 and node_label as int16 where their counts allow, `file.narrow_index`); the
    local poses, read through `graph.poses.node_poses` (float64), stored as
    `graph.poses` packs them:
    node_rot64 (N, R) uint64 quaternions in 64 bits of the joints `rotating_joints` (R,)
    int32 (the others hold the identity); node_moving (N, V, 3) float32
    local translations (m) of the joints `moving_joints` (V,) int32 (the root and any
    joint animated in translation); node_bones (N,) int32 into bone_sets (B, J, 3)
    float32, the distinct local translations of the other joints;
    node_ground (N, 2) float32 root ground position (x, z) in its source clip (m);
    node_heading (N,) float32 (rad).
    edge_src, edge_dst (E,) int32; edge_kind (E,) uint8; edge_acc (E, S, 3) float16
    (m/s², READING_DTYPE; float32 in files before format 3); edge_offset (E, 2) float32 (m, in the source node's local frame);
    edge_heading (E,) float32 (rad); incoming (N + 1,) int64 CSR offsets by destination
    (not stored: `incoming_offsets` of edge_dst).
    clip_offsets (C, J, 3) float64: each clip's skeleton offsets (sensor placement).
    edge_up (E, S, W) float16 or None: each edge's sensor orientation cue
    (`metadata.edge_up_vectors`, `sensors.orientation`): W = 3, the sensors' "up" (world
    +Y in the sensor frame), or W = 9, their rotations relative to the root sensor's
    heading (layouts with a sensor on the pelvis); None in graph files written before
    it, which then cannot weigh measured orientations.
    """

    rate_hz: float
    skeleton: Skeleton
    layout: dict
    clips: list[dict]
    labels: tuple[str, ...]
    params: dict
    clip_offsets: np.ndarray
    node_kind: np.ndarray
    node_clip: np.ndarray
    node_frame: np.ndarray
    node_contacts: np.ndarray
    node_label: np.ndarray
    node_rot64: np.ndarray
    node_moving: np.ndarray
    node_bones: np.ndarray
    bone_sets: np.ndarray
    moving_joints: np.ndarray
    rotating_joints: np.ndarray
    node_ground: np.ndarray
    node_heading: np.ndarray
    edge_src: np.ndarray
    edge_dst: np.ndarray
    edge_kind: np.ndarray
    edge_acc: np.ndarray
    edge_offset: np.ndarray
    edge_heading: np.ndarray
    incoming: np.ndarray
    # Interpolated segments and bridges (`bridges.py`): one record each of the nodes it
    # made, from which clips and frames (`records.SEGMENT_FIELDS`, `records.BRIDGE_FIELDS`).
    segments: Records = field(default_factory=records.segments)
    bridges: Records = field(default_factory=records.bridges)
    # Where the graph was loaded from and that file's SHA-256 (`store.file_checksum`),
    # or None for a graph built in memory: what a strategy's cached index is keyed by.
    source_path: str | None = None
    checksum: str | None = None
    edge_up: np.ndarray | None = None

    @property
    def num_nodes(self) -> int:
        return int(self.node_kind.shape[0])

    @property
    def num_edges(self) -> int:
        return int(self.edge_src.shape[0])

    @property
    def sensor_names(self) -> tuple[str, ...]:
        return tuple(s["name"] for s in self.layout["sensors"])

    def out_degree(self) -> np.ndarray:
        return np.bincount(self.edge_src, minlength=self.num_nodes)


# A graph's arrays of one row a node and one row an edge (`MotionGraph`), as stored.
NODE_ARRAYS = (
    "node_kind",
    "node_clip",
    "node_frame",
    "node_contacts",
    "node_label",
    "node_rot64",
    "node_moving",
    "node_bones",
    "node_ground",
    "node_heading",
)
EDGE_ARRAYS = ("edge_src", "edge_dst", "edge_kind", "edge_acc", "edge_offset", "edge_heading")


def incoming_offsets(edge_dst: np.ndarray, num_nodes: int) -> np.ndarray:
    """CSR offsets (N + 1,) of edges sorted by destination."""
    out = np.zeros(num_nodes + 1, dtype=np.int64)
    np.cumsum(np.bincount(edge_dst, minlength=num_nodes), out=out[1:])
    return out


def node_subgraph(graph: MotionGraph, nodes) -> MotionGraph:
    """The graph's nodes `nodes` (ids, any order; renumbered in increasing order) and the
    edges among them, with its skeleton, layout, clips, labels and bone sets, and the
    segments and bridges whose nodes are all kept: a graph whose arrays have the whole
    one's types at a fraction of its size (what a warm-up runs on,
    `strategies.viterbi.strategy.warm_up`). Not loaded from a file: no source path or
    checksum."""
    nodes = np.unique(np.asarray(nodes, dtype=np.int64))
    if nodes.size == 0 or nodes[0] < 0 or nodes[-1] >= graph.num_nodes:
        raise ValueError(f"node_subgraph: node ids must lie in 0..{graph.num_nodes - 1}")
    new_id = np.full(graph.num_nodes, -1, dtype=np.int64)
    new_id[nodes] = np.arange(nodes.size)
    # the edges into the kept nodes (edges are numbered by destination), then those from kept nodes
    starts, counts = graph.incoming[nodes], np.diff(graph.incoming)[nodes]
    into = ranges(starts, counts)
    keep = into[new_id[np.asarray(graph.edge_src)[into]] >= 0]
    edges = {name: np.ascontiguousarray(getattr(graph, name)[keep]) for name in EDGE_ARRAYS[2:]}  # (ends: below)
    edge_dst = new_id[np.asarray(graph.edge_dst)[keep]].astype(np.int32)

    def kept(parts: Records) -> Records:
        first = parts.column("first_node").astype(np.int64)
        last = first + parts.column("count") - 1
        whole = (new_id[first] >= 0) & (new_id[last] - new_id[first] == last - first)
        return parts.select(whole).replaced("first_node", new_id[first[whole]])

    fields: dict[str, Any] = {name: np.ascontiguousarray(getattr(graph, name)[nodes]) for name in NODE_ARRAYS}
    fields.update(
        edges,
        edge_src=new_id[np.asarray(graph.edge_src)[keep]].astype(np.int32),
        edge_dst=edge_dst,
        incoming=incoming_offsets(edge_dst, nodes.size),
        edge_up=None if graph.edge_up is None else np.ascontiguousarray(graph.edge_up[keep]),
        segments=kept(graph.segments),
        bridges=kept(graph.bridges),
        source_path=None,
        checksum=None,
    )
    return replace(graph, **fields)


def summary(graph: MotionGraph, file_size: int | None = None) -> dict:
    """What `graphsvc info` reports (the columns of Table 2 of Kelly et al. 2013, and more)."""
    nodes = {k: int(np.sum(graph.node_kind == i)) for i, k in enumerate(NODE_KINDS)}
    edges = {k: int(np.sum(graph.edge_kind == i)) for i, k in enumerate(EDGE_KINDS)}
    # Every frame the graph was built from, augmented copies included (their clips are
    # named "<name>_mirror" / "<name>_reverse", `motion.augment`); the recorded ones beside.
    if graph.clips:
        kb_frames = sum(int(c["frames"]) for c in graph.clips)
        recorded = sum(int(c["frames"]) for c in graph.clips if not _AUGMENTED.search(str(c["name"])))
    else:  # (a bare graph of edges: `graph_from_edges`)
        kb_frames = recorded = nodes["original"]
    out = {
        "nodes": graph.num_nodes,
        "edges": graph.num_edges,
        "nodes_by_kind": nodes,
        "edges_by_kind": edges,
        "dead_ends": int(np.sum(graph.out_degree() == 0)),
        "clips": len(graph.clips),
        "kb_frames": kb_frames,
        "kb_frames_original": recorded,
        "kb_minutes": round(kb_frames / graph.rate_hz / 60.0, 3),
        "labels": list(graph.labels),
        "layout": graph.layout["name"],
        "sensors": list(graph.sensor_names),
        "rate_hz": graph.rate_hz,
        "joints": graph.skeleton.num_joints_excluding_end_sites,
        "interpolated_segments": len(graph.segments),
        "bridges": len(graph.bridges),
        "sensor_orientations": graph.edge_up is not None,
    }
    if file_size is not None:
        out["file_bytes"] = int(file_size)
    return out


def format_summary(s: dict) -> str:
    kinds = lambda d: ", ".join(f"{k} {v:,}" for k, v in d.items() if v or k != "bridge")  # noqa: E731
    lines = [
        f"nodes {s['nodes']:,} ({kinds(s['nodes_by_kind'])})",
        f"edges {s['edges']:,} ({kinds(s['edges_by_kind'])})",
        f"dead ends {s['dead_ends']:,}; clips {s['clips']}, {s['kb_frames']:,} frames"
        + (
            f" ({s['kb_frames_original']:,} recorded, the rest augmented copies)"
            if s.get("kb_frames_original", s["kb_frames"]) != s["kb_frames"]
            else ""
        )
        + f" ({s['kb_minutes']:.1f} min) at {s['rate_hz']:g} Hz, {s['joints']} joints",
        f"layout {s['layout']} ({', '.join(s['sensors'])})"
        + (
            "; sensor orientations"
            if s.get("sensor_orientations")
            else "; no sensor orientations (`graphsvc relayout` adds them)"
        ),
        f"labels: {', '.join(s['labels'])}",
    ]
    if "file_bytes" in s:
        lines.append(f"file size {s['file_bytes'] / 2**20:.1f} MiB")
    return "\n".join(lines)


def graph_from_edges(
    src, dst, acc, offsets=None, dheading=None, contacts=None, labels=None, kinds=None, rate_hz: float = 30.0, up=None
) -> MotionGraph:
    """A MotionGraph of bare edges, for synthetic studies (benchmarks, tests): N nodes
    (the largest index + 1) on a one-joint skeleton, without poses or clips. src, dst
    (E,) node indices; acc (E, S, 3) readings (m/s²); up (E, S, 3 or 9) the orientation cue
    (None: no orientation metadata); offsets (E, 2) m, dheading (E,)
    rad (default 0); contacts (N, 2) bool (default all planted); labels (N,) int into
    ("a", "b") (default 0); kinds (E,) edge kinds (default original). Edges are
    sorted by destination, as a built graph's."""
    src, dst = np.asarray(src), np.asarray(dst)
    N = int(max(src.max(), dst.max())) + 1
    order = np.lexsort((src, dst))
    E = len(src)
    sk = Skeleton(("root",), np.array([-1]), np.zeros((1, 3)), (("Xposition",),), np.zeros(1, bool))
    offsets = np.zeros((E, 2)) if offsets is None else np.asarray(offsets)
    dheading = np.zeros(E) if dheading is None else np.asarray(dheading)
    contacts = np.ones((N, 2), bool) if contacts is None else np.asarray(contacts)
    labels = np.zeros(N, np.int32) if labels is None else np.asarray(labels, np.int32)
    kinds = np.zeros(E, np.uint8) if kinds is None else np.asarray(kinds, np.uint8)
    S = acc.shape[1]
    return MotionGraph(
        rate_hz=rate_hz,
        skeleton=sk,
        layout={"name": "t", "sensors": [{"name": f"s{i}"} for i in range(S)]},
        clips=[],
        labels=("a", "b"),
        params={},
        clip_offsets=np.zeros((1, 1, 3)),
        node_kind=np.zeros(N, np.uint8),
        node_clip=np.zeros(N, np.int32),
        node_frame=np.zeros(N, np.float32),
        node_contacts=contacts,
        node_label=labels,
        **pack_poses(np.tile([1.0, 0.0, 0.0, 0.0], (N, 1, 1)), np.zeros((N, 1, 3))),
        node_ground=np.zeros((N, 2), np.float32),
        node_heading=np.zeros(N, np.float32),
        edge_src=src[order].astype(np.int32),
        edge_dst=dst[order].astype(np.int32),
        edge_kind=kinds[order],
        edge_acc=np.asarray(acc, np.float32)[order],
        edge_offset=offsets[order].astype(np.float32),
        edge_heading=dheading[order].astype(np.float32),
        incoming=incoming_offsets(dst[order], N),
        edge_up=None if up is None else np.asarray(up, np.float16)[order],
    )

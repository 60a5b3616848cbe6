"""The graph file: one checksummed, versioned container (graphsvc/store.py) of kind
"graph". Meta holds the format version, skeleton, rate, layout, build parameters and
the source clips with content hashes; arrays are the MotionGraph's, memory-mapped
on load so a large graph is not copied.

Format 4 stores what the arrays of format 3 held in fewer bytes, losing nothing
(9.3M nodes: 3,153 → 2,9xx MB): the interpolated segments' and bridges' records as
columns (`records.py`; 65 MB of JSON in the header before), node clips and bone sets
as uint16 where fewer than 65,536 of them and labels as int16 (int32 before), and no
`incoming`: the CSR offsets follow from the destinations (edges are sorted by them),
one bincount on load (45 ms and N × 8 bytes a process at 9.3M nodes)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from graphsvc.errors import FormatError
from graphsvc.fileio import StrPath
from graphsvc.graph.model import EDGE_ARRAYS, NODE_ARRAYS, MotionGraph, incoming_offsets
from graphsvc.graph.poses import pack_poses
from graphsvc.graph.records import BRIDGE_FIELDS, SEGMENT_FIELDS, Records, node_ranges_inside
from graphsvc.motion.skeleton import Skeleton
from graphsvc.sensors.layout import ROOT_SEGMENT
from graphsvc.sensors.orientation import RELATIVE_WIDTH, WIDTHS
from graphsvc.store import file_checksum, read_container, read_header, write_container

KIND = "graph"
# 2: bridge nodes and edges (kind 3 / 5) and their records; 3: packed poses; 4: records
# as columns, narrow index types, no stored offsets
FORMAT_VERSION = 4
READABLE_VERSIONS = (1, 2, 3, 4)  # 1 and 2 store float32 poses, packed on load
ARRAYS = (
    "clip_offsets",
    *NODE_ARRAYS,
    "bone_sets",
    "moving_joints",
    "rotating_joints",
    *EDGE_ARRAYS,
)
OPTIONAL = ("edge_up",)  # absent from files written before it (loaded as None)
RECORDS = {"segments": ("segment_", SEGMENT_FIELDS), "bridges": ("bridge_", BRIDGE_FIELDS)}


def narrow_index(values: np.ndarray, count: int, signed: bool = False) -> np.ndarray:
    """An index array (values in 0..count − 1, or −1 too when signed) as uint16 /
    int16 when `count` allows it, else int32: what a graph file stores."""
    small, bound = (np.int16, 1 << 15) if signed else (np.uint16, 1 << 16)
    return np.ascontiguousarray(values, dtype=small if count <= bound else np.int32)


def save_graph(graph: MotionGraph, path: StrPath) -> None:
    """Write atomically; equal graphs give byte-identical files."""
    sk = graph.skeleton
    meta = {
        "rate_hz": graph.rate_hz,
        "skeleton": {
            "names": list(sk.names),
            "parents": sk.parents.tolist(),
            "offsets": sk.offsets.tolist(),
            "channels": [list(c) for c in sk.channels],
            "end_site": sk.end_site.tolist(),
        },
        "layout": graph.layout,
        "clips": graph.clips,
        "labels": list(graph.labels),
        "params": graph.params,
        "counts": {"nodes": graph.num_nodes, "edges": graph.num_edges},
    }
    arrays = {name: getattr(graph, name) for name in ARRAYS}
    arrays.update({name: getattr(graph, name) for name in OPTIONAL if getattr(graph, name) is not None})
    arrays["node_clip"] = narrow_index(graph.node_clip, len(graph.clips))
    arrays["node_bones"] = narrow_index(graph.node_bones, len(graph.bone_sets))
    arrays["node_label"] = narrow_index(graph.node_label, len(graph.labels), signed=True)
    for name, (prefix, _) in RECORDS.items():
        arrays.update(getattr(graph, name).arrays(prefix))
    write_container(path, KIND, meta, arrays, FORMAT_VERSION)


def load_graph(path: StrPath, mmap: bool = True, verify: bool = True) -> MotionGraph:
    """Load a graph file; refuses truncated, corrupted or foreign files (FormatError)."""
    meta, arrays, version = read_container(path, kind=KIND, mmap=mmap, verify=verify)
    if version not in READABLE_VERSIONS:
        raise FormatError(
            path,
            f"graph format version {version} is not supported (this graphsvc reads "
            f"{', '.join(map(str, READABLE_VERSIONS))})",
        )
    if version < 3 and "node_rotations" in arrays and "node_translations" in arrays:
        arrays = dict(arrays)
        arrays.update(_packed(arrays.pop("node_rotations"), arrays.pop("node_translations"), path))
    missing = [a for a in ARRAYS if a not in arrays]
    if missing:
        raise FormatError(path, f"graph file lacks arrays: {', '.join(missing)}")
    try:
        s = meta["skeleton"]
        skeleton = Skeleton(
            tuple(s["names"]),
            np.array(s["parents"]),
            np.array(s["offsets"]),
            tuple(tuple(c) for c in s["channels"]),
            np.array(s["end_site"]),
        )
        stored: dict[str, Any] = {name: arrays.get(name) for name in (*ARRAYS, *OPTIONAL)}  # (ARRAYS: all there)
        stored.update(_records(meta, arrays, version))
        graph = MotionGraph(
            rate_hz=float(meta["rate_hz"]),
            skeleton=skeleton,
            layout=meta["layout"],
            clips=meta["clips"],
            labels=tuple(meta["labels"]),
            params=meta["params"],
            incoming=np.zeros(0, np.int64),  # (the offsets follow from the edges, once checked: below)
            **stored,
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise FormatError(path, f"graph metadata is incomplete: {exc}") from None
    N, E = graph.num_nodes, graph.num_edges
    if meta.get("counts") != {"nodes": N, "edges": E}:
        raise FormatError(path, "graph arrays disagree with its header counts")
    check_graph_arrays(graph, path)
    graph.incoming = incoming_offsets(graph.edge_dst, N)
    graph.source_path, graph.checksum = str(Path(path).resolve()), file_checksum(path)
    return graph


def check_graph_arrays(graph: MotionGraph, path) -> None:
    """FormatError unless every array has the shape the graph's counts, skeleton,
    layout and clips give it, and every index (edges' nodes, sorted by destination;
    nodes' clips, labels and bone sets; the records' nodes and clips) is in range: the
    search's compiled loops index without bounds checks, so a file checksummed after
    it was altered must not reach them."""
    N, E, J, C = graph.num_nodes, graph.num_edges, graph.skeleton.num_joints, len(graph.clips)
    V, B, R = graph.moving_joints.shape[0], graph.bone_sets.shape[0], graph.rotating_joints.shape[0]
    layout = graph.layout
    if (
        not isinstance(layout, dict)
        or not isinstance(layout.get("sensors"), list)
        or not all(isinstance(s, dict) and isinstance(s.get("name"), str) for s in layout["sensors"])
    ):
        raise FormatError(path, "graph metadata: the layout has no list of named sensors")
    S = len(layout["sensors"])
    shapes = {
        "node_kind": (N,),
        "node_clip": (N,),
        "node_frame": (N,),
        "node_contacts": (N, 2),
        "node_label": (N,),
        "node_rot64": (N, R),
        "node_moving": (N, V, 3),
        "node_bones": (N,),
        "bone_sets": (B, J, 3),
        "moving_joints": (V,),
        "rotating_joints": (R,),
        "node_ground": (N, 2),
        "node_heading": (N,),
        "edge_src": (E,),
        "edge_dst": (E,),
        "edge_kind": (E,),
        "edge_acc": (E, S, 3),
        "edge_offset": (E, 2),
        "edge_heading": (E,),
        "clip_offsets": (C, J, 3),
    }
    for name, shape in shapes.items():
        a = getattr(graph, name)
        if a is not None and (a.shape != shape or a.dtype.kind not in "biuf"):
            raise FormatError(
                path, f"graph array {name} is {a.dtype}{list(a.shape)}, expected numbers of shape {list(shape)}"
            )
    up = graph.edge_up
    if up is not None:
        # The orientation cue: tilt (3) or relative to the root sensor (9, `sensors.orientation`).
        width = up.shape[-1] if up.ndim == 3 else None
        if up.shape[:2] != (E, S) or width not in WIDTHS or up.dtype.kind not in "f":
            raise FormatError(
                path, f"graph array edge_up is {up.dtype}{list(up.shape)}, expected numbers of shape [{E}, {S}, 3 or 9]"
            )
        if width == RELATIVE_WIDTH and not any(s.get("segment") == ROOT_SEGMENT for s in layout["sensors"]):
            raise FormatError(
                path,
                "graph metadata: orientations relative to a root sensor, and the layout has no "
                f"sensor on the {ROOT_SEGMENT}",
            )
    if graph.node_rot64.dtype != np.uint64:
        raise FormatError(path, f"graph array node_rot64 holds {graph.node_rot64.dtype}, expected uint64")
    for name in (
        "edge_src",
        "edge_dst",
        "node_clip",
        "node_label",
        "node_kind",
        "edge_kind",
        "node_bones",
        "moving_joints",
        "rotating_joints",
    ):
        if getattr(graph, name).dtype.kind not in "iu":
            raise FormatError(path, f"graph array {name} holds {getattr(graph, name).dtype}, expected integers")

    def outside(a, low, high) -> bool:
        return a.size > 0 and (int(a.min()) < low or int(a.max()) >= high)

    if outside(graph.edge_src, 0, N) or outside(graph.edge_dst, 0, N):
        raise FormatError(path, f"graph edges name nodes outside 0..{N - 1}")
    if E > 1 and bool(np.any(graph.edge_dst[1:] < graph.edge_dst[:-1])):
        raise FormatError(path, "graph edges are not sorted by destination (their offsets would not hold)")
    if outside(graph.node_clip, 0, C) or outside(graph.node_label, -1, len(graph.labels)):
        raise FormatError(path, "graph nodes name clips or labels the graph does not have")
    if outside(graph.node_bones, 0, B):
        raise FormatError(path, "graph nodes name bone sets the graph does not have")
    for name in RECORDS:
        if not node_ranges_inside(getattr(graph, name), N, C):
            raise FormatError(path, f"graph {name} name nodes or clips the graph does not have")
    for name in ("moving_joints", "rotating_joints"):
        joints = getattr(graph, name)
        if len(joints) == 0 or int(joints[0]) != 0 or outside(joints, 0, J) or bool(np.any(np.diff(joints) <= 0)):
            raise FormatError(path, f"graph array {name} is not the root and then increasing joint indices")


def _records(meta: dict, arrays: dict, version: int) -> dict[str, Records]:
    """The segments' and bridges' records: columns in a format 4 file, JSON in the
    header before (KeyError / ValueError when incomplete)."""
    if version >= 4:
        return {name: Records.from_arrays(fields, arrays, prefix) for name, (prefix, fields) in RECORDS.items()}
    return {name: Records.from_dicts(fields, meta.get(name, [])) for name, (_, fields) in RECORDS.items()}


def _packed(rotations: np.ndarray, translations: np.ndarray, path) -> dict:
    """A version 1 or 2 file's float32 poses, packed as a version 3 file holds them."""
    if rotations.ndim != 3 or rotations.shape[-1] != 4 or translations.shape != rotations.shape[:2] + (3,):
        raise FormatError(path, f"graph poses are {list(rotations.shape)} and {list(translations.shape)}")
    return pack_poses(rotations, translations)


def graph_file_meta(path) -> dict:
    """The header of a graph file without loading its arrays."""
    return read_header(Path(path))

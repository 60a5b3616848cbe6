"""The graph file: one checksummed, versioned container (graphsvc/store.py) of kind
"graph". Meta holds the format version, skeleton, rate, layout, build parameters and
the source clips with content hashes; arrays are the MotionGraph's, memory-mapped
on load so a large graph is not copied."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graphsvc.errors import FormatError
from graphsvc.graph.model import MotionGraph
from graphsvc.motion.skeleton import Skeleton
from graphsvc.store import file_checksum, read_container, read_header, write_container

KIND = "graph"
FORMAT_VERSION = 2  # 2: bridge nodes and edges (kind 3 / 5) and their records
READABLE_VERSIONS = (1, 2)
ARRAYS = ("clip_offsets", "node_kind", "node_clip", "node_frame", "node_contacts", "node_label", "node_rotations",
          "node_translations", "node_ground", "node_heading", "edge_src", "edge_dst", "edge_kind", "edge_acc",
          "edge_offset", "edge_heading", "incoming")  # fmt: skip
OPTIONAL = ("edge_up",)  # absent from files written before it (loaded as None)


def save_graph(graph: MotionGraph, path) -> None:
    """Write atomically; equal graphs give byte-identical files."""
    sk = graph.skeleton
    meta = {
        "rate_hz": graph.rate_hz,
        "skeleton": {"names": list(sk.names), "parents": sk.parents.tolist(), "offsets": sk.offsets.tolist(),
                     "channels": [list(c) for c in sk.channels], "end_site": sk.end_site.tolist()},  # fmt: skip
        "layout": graph.layout,
        "clips": graph.clips,
        "labels": list(graph.labels),
        "params": graph.params,
        "segments": graph.segments,
        "bridges": graph.bridges,
        "counts": {"nodes": graph.num_nodes, "edges": graph.num_edges},
    }
    arrays = {name: getattr(graph, name) for name in ARRAYS}
    arrays.update({name: getattr(graph, name) for name in OPTIONAL if getattr(graph, name) is not None})
    write_container(path, KIND, meta, arrays, FORMAT_VERSION)


def load_graph(path, mmap: bool = True, verify: bool = True) -> MotionGraph:
    """Load a graph file; refuses truncated, corrupted or foreign files (FormatError)."""
    meta, arrays, version = read_container(path, kind=KIND, mmap=mmap, verify=verify)
    if version not in READABLE_VERSIONS:
        raise FormatError(path, f"graph format version {version} is not supported (this graphsvc reads "
                                f"{', '.join(map(str, READABLE_VERSIONS))})")  # fmt: skip
    missing = [a for a in ARRAYS if a not in arrays]
    if missing:
        raise FormatError(path, f"graph file lacks arrays: {', '.join(missing)}")
    try:
        s = meta["skeleton"]
        skeleton = Skeleton(tuple(s["names"]), np.array(s["parents"]), np.array(s["offsets"]),
                            tuple(tuple(c) for c in s["channels"]), np.array(s["end_site"]))  # fmt: skip
        graph = MotionGraph(rate_hz=float(meta["rate_hz"]), skeleton=skeleton, layout=meta["layout"],
                            clips=meta["clips"], labels=tuple(meta["labels"]), params=meta["params"],
                            segments=meta.get("segments", []), bridges=meta.get("bridges", []),
                            **{name: arrays[name] for name in ARRAYS},
                            **{name: arrays.get(name) for name in OPTIONAL})  # fmt: skip
    except (KeyError, TypeError, ValueError) as exc:
        raise FormatError(path, f"graph metadata is incomplete: {exc}") from None
    N, E = graph.num_nodes, graph.num_edges
    up = graph.edge_up
    if meta.get("counts") != {"nodes": N, "edges": E} or graph.incoming.shape != (N + 1,) or (
            up is not None and up.shape != graph.edge_acc.shape):
        raise FormatError(path, "graph arrays disagree with its header counts")
    graph.source_path, graph.checksum = str(Path(path).resolve()), file_checksum(path)
    return graph


def graph_file_meta(path) -> dict:
    """The header of a graph file without loading its arrays."""
    return read_header(Path(path))

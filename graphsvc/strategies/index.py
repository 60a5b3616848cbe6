"""A strategy's index cached beside its graph file.

An index that costs time to build (a kd-tree's points, per-frame arrays) is written
once next to the graph, as `GRAPH.<strategy>.index` — a graphsvc container (kind
"index") whose meta records the graph file's SHA-256 (`store.file_checksum`), the
strategy and its index version — and memory-mapped on every later load. A cache whose
checksum or version does not match (the graph was rebuilt, the strategy changed), or
that is damaged, is built again; one that cannot be written (a read-only folder) is
kept in memory for the process only. A graph built in memory, never saved, has no
file to key by: its index is built and held in memory. So every command still takes
the graph file alone.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graphsvc.errors import FormatError
from graphsvc.graph.model import EDGE_ORIGINAL, NODE_ORIGINAL
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.store import read_container, write_container

KIND = "index"


def index_path(graph_path, strategy: str) -> Path:
    p = Path(graph_path)
    return p.with_name(f"{p.name}.{strategy}.index")


def cached_arrays(graph, strategy: str, version: int, build) -> dict[str, np.ndarray]:
    """The arrays of `strategy`'s index for `graph` (module docstring). build() → dict
    of arrays, called when no valid cache exists."""
    if graph.source_path is None or graph.checksum is None:
        return build()
    path = index_path(graph.source_path, strategy)
    want = {"graph_sha256": graph.checksum, "strategy": strategy, "version": int(version)}
    if path.is_file():
        try:
            meta, arrays, _ = read_container(path, kind=KIND, mmap=True, verify=False)
            if all(meta.get(k) == v for k, v in want.items()):
                return dict(arrays)
        except FormatError:
            pass  # damaged or foreign: built again below
    arrays = build()
    try:
        write_container(path, KIND, want, arrays, 1)
    except OSError:
        return arrays
    return dict(read_container(path, kind=KIND, mmap=True, verify=False).arrays)


def frame_readings(graph) -> dict[str, np.ndarray]:
    """The knowledge-base frames a per-frame index holds: the original nodes with an
    original edge into them (the readings on arriving at a frame are that edge's), in
    node order — nodes (F,) int64, edges (F,) int64, readings (F, 3S) float32 in g."""
    e = np.flatnonzero(np.asarray(graph.edge_kind) == EDGE_ORIGINAL)
    dst = np.asarray(graph.edge_dst)[e].astype(np.int64)
    keep = np.asarray(graph.node_kind)[dst] == NODE_ORIGINAL
    e, dst = e[keep], dst[keep]
    order = np.argsort(dst, kind="stable")
    e, dst = e[order], dst[order]
    readings = (np.asarray(graph.edge_acc, np.float64)[e].reshape(e.size, -1) / GRAVITY).astype(np.float32)
    return {"nodes": dst, "edges": e.astype(np.int64), "readings": readings}

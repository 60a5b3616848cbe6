"""The graphs a server serves: `--graph NAME=FILE` read (`parse_graph_spec`), each
graph loaded once (`load_graphs`: memory-mapped, checksum verified, every strategy's
index and kernels warmed up) as a `LoadedGraph` with its GraphInfo, shared read-only
by every call.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from graphsvc.errors import InputError
from graphsvc.graph.file import load_graph
from graphsvc.pipeline import warm_up
from graphsvc.service._generated import graphsvc_pb2 as pb
from graphsvc.service.convert_graph import graph_info


@dataclass(frozen=True)
class LoadedGraph:
    """A graph the server serves. info: its GraphInfo, computed once."""

    name: str
    path: Path
    graph: object  # graphsvc.graph.model.MotionGraph
    info: pb.GraphInfo
    load_s: float = 0.0  # mapping, checking and warming it up in this process, seconds


def parse_graph_spec(text: str) -> tuple[str, Path]:
    """ "NAME=FILE" → (name, path)."""
    name, sep, path = text.partition("=")
    name = name.strip()
    if not sep or not name or not path:
        raise InputError(f"--graph takes NAME=FILE, got {text!r}")
    return name, Path(path)


def load_graphs(specs: list[str]) -> dict[str, LoadedGraph]:
    """Load each "NAME=FILE" graph once (memory-mapped, checksum verified)."""
    if not specs:
        raise InputError("no graphs to serve (give --graph NAME=FILE at least once)")
    graphs: dict[str, LoadedGraph] = {}
    for spec in specs:
        name, path = parse_graph_spec(spec)
        if name in graphs:
            raise InputError(f"graph name {name!r} given twice")
        start = time.perf_counter()
        graph = load_graph(path)
        # Every strategy's index, and its kernels compiled or loaded (serial, and
        # threaded for a stream running alone), now, not in the first client's call.
        warm_up(graph, threads=False)
        warm_up(graph, threads=True)
        graphs[name] = LoadedGraph(
            name, path, graph, graph_info(name, graph, path.stat().st_size), time.perf_counter() - start
        )
    return graphs

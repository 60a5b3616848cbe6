"""What a reconstruction returns: the motion, the graph path where there is one, the
report, and where every frame comes from (`Provenance`, which fits blended frames too);
a live session's output frame (`Frame`); label runs for the report."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from graphsvc.graph.model import MotionGraph
from graphsvc.motion.skeleton import Motion


@dataclass
class Provenance:
    """Where each of T output frames comes from: up to K knowledge-base sources, as
    clip (T, K) int (−1: none), frame (T, K) float (fractional for slow-down and blended
    frames) and weight (T, K) float (summing to 1 over a frame's sources), and the
    frame's content label (T,). A graph node is one source; a blend is several."""

    clip: np.ndarray
    frame: np.ndarray
    weight: np.ndarray
    label: np.ndarray

    @staticmethod
    def of_nodes(graph: MotionGraph, nodes: np.ndarray) -> Provenance:
        """One source a frame: each node's clip and frame (a blended node's dominant one)."""
        nodes = np.asarray(nodes, dtype=np.int64)
        return Provenance(
            np.asarray(graph.node_clip)[nodes][:, None].astype(np.int64),
            np.asarray(graph.node_frame)[nodes][:, None].astype(np.float64),
            np.ones((nodes.size, 1)),
            np.asarray(graph.labels, dtype=object)[np.asarray(graph.node_label)[nodes]],
        )

    def sources(self, t: int) -> list[tuple[int, float, float]]:
        """Frame t's sources as (clip, frame, weight), heaviest first."""
        keep = self.clip[t] >= 0
        order = np.argsort(-self.weight[t][keep], kind="stable")
        return [
            (int(c), float(f), float(w))
            for c, f, w in zip(self.clip[t][keep][order], self.frame[t][keep][order], self.weight[t][keep][order])
        ]


@dataclass
class Reconstruction:
    """motion: on graph.skeleton at graph.rate_hz; node_path (T,), edge_path (T−1,) (the
    edges entering node_path[1:]) for strategies that walk graph nodes, else None;
    provenance: per-frame sources and labels; report: JSON-able summary (see the
    README's *Report*)."""

    motion: Motion
    node_path: np.ndarray | None
    edge_path: np.ndarray | None
    report: dict = field(default_factory=dict)
    provenance: Provenance | None = None


def label_runs(labels) -> list[dict]:
    """Per-frame labels as runs: [{label, start_frame, frames}]."""
    runs = []
    start = 0
    for t in range(1, len(labels) + 1):
        if t == len(labels) or labels[t] != labels[start]:
            runs.append({"label": str(labels[start]), "start_frame": start, "frames": t - start})
            start = t
    return runs


def path_labels(graph: MotionGraph, nodes: np.ndarray) -> list[dict]:
    """The content labels along a path as runs: [{label, start_frame, frames}]."""
    return label_runs([graph.labels[int(k)] for k in graph.node_label[nodes]])


@dataclass
class Frame:
    """One output pose. index: frame number at the graph rate; time_s: stream time;
    node: the graph node it plays (−1 for a strategy whose frames are not nodes);
    label: its content label; rotations (J, 4) float32 local wxyz; translations (J, 3)
    float32 local, metres; sources: (clip, frame, weight) of the knowledge-base frames
    it is made of, heaviest first."""

    index: int
    time_s: float
    node: int
    label: str
    rotations: np.ndarray
    translations: np.ndarray
    sources: list = field(default_factory=list)

"""The OLNG index: every knowledge-base frame's simulated readings in a kd-tree, and the
neighbour query a stream makes each sample.

Frames are the graph's original nodes that have an original edge into them (the
readings on arriving at a frame are that edge's), in node order, so a clip's frames
are consecutive; `run_of` numbers the runs of consecutive frames (a clip, or the part
of one between frames the graph left out), so frame p − k is k frames before p exactly
when `run_of` agrees — the rule `lattice.Lattice` steps by. Readings are in g, S × 3
values a frame, at the graph rate and in its layout, so `graphsvc relayout` serves OLNG
as it serves the search; and each frame's pose vector and heading-frame joint
positions (`pose.frame_poses`), which the pose energy reads for the neighbours. The
arrays are cached beside the graph file (`strategies.index`, memory-mapped on later
loads); the tree is built on load (scipy's cKDTree).

With measured sensor orientations (a recording that has them, a graph with their
metadata, W_R > 0) the query runs on a second tree whose features are each frame's
readings and its sensors' orientation cue times √W_R (`graph.edge_up` of the edge into
the frame: "up" vectors, or rotations relative to the root sensor, `sensors.orientation`), so a neighbour's squared distance is ‖Δa‖² (g²) + W_R·Σ chord² — the
Viterbi search's weighing of C_R against C_A, summed over the sensors. It is built
on first use for each weight.

Hiding clips (leave-out evaluation) never rebuilds the tree: the query asks for more
neighbours and drops the hidden ones (`Neighbours.dropped` says how many).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from graphsvc.errors import InputError
from graphsvc.graph.model import MotionGraph
from graphsvc.strategies.index import cached_arrays, frame_readings
from graphsvc.strategies.olng.pose import frame_poses, pose_model

INDEX_VERSION = 2


def build_arrays(graph: MotionGraph) -> dict[str, np.ndarray]:
    """The index's arrays: nodes (F,) int64, edges (F,) int64 (the original edge into
    each), readings (F, 3S) float32 g, run_of (F,) int64, and what the pose energy reads
    of each frame (`pose`): poses (F, D) and positions (F, Ja, 3) float32."""
    arrays = frame_readings(graph)
    dst = arrays["nodes"]
    poses, positions = frame_poses(graph, pose_model(graph), dst)
    clip = np.asarray(graph.node_clip)[dst].astype(np.int64)
    frame = np.asarray(graph.node_frame)[dst].astype(np.float64)
    # A new run where the clip changes or a frame is not the one after the previous.
    new_run = np.ones(dst.size, dtype=bool)
    new_run[1:] = (clip[1:] != clip[:-1]) | (frame[1:] - frame[:-1] != 1.0)
    return {**arrays, "run_of": np.cumsum(new_run) - 1, "poses": poses, "positions": positions}


def load_index(graph: MotionGraph, allowed: np.ndarray | None = None) -> OlngIndex:
    """The graph's OLNG index: its arrays from the cache beside the graph file (built and
    written there the first time), the tree built on them."""
    return OlngIndex(graph, cached_arrays(graph, "olng", INDEX_VERSION, lambda: build_arrays(graph)), allowed)


@dataclass
class Neighbours:
    """One sample's neighbours, nearest first: frames (k,) positions in the index,
    distances (k,) in g; dropped: hidden frames the query passed over."""

    frames: np.ndarray
    distances: np.ndarray
    dropped: int


class OlngIndex:
    """The arrays of `build_arrays` and their kd-tree. allowed (N,) bool over graph
    nodes: the frames a query may return (None: all)."""

    def __init__(self, graph: MotionGraph, arrays: dict, allowed: np.ndarray | None = None):
        self.graph = graph
        self.nodes = np.asarray(arrays["nodes"])
        self.edges = np.asarray(arrays["edges"])
        self.readings = np.asarray(arrays["readings"])
        self.run_of = np.ascontiguousarray(arrays["run_of"], dtype=np.int64)
        self.poses = arrays.get("poses")
        self.positions = arrays.get("positions")
        if self.nodes.size == 0:
            raise InputError("the graph has no original frames with readings for OLNG")
        self.tree = cKDTree(self.readings)
        self.up = (
            None
            if graph.edge_up is None
            else np.asarray(graph.edge_up, np.float32)[self.edges].reshape(self.nodes.size, -1)
        )
        self._oriented: dict = {}  # weight → the tree over readings and √weight · up
        self.hidden = None if allowed is None else ~np.asarray(allowed, dtype=bool)[self.nodes]
        if self.hidden is not None and not self.hidden.any():
            self.hidden = None

    @property
    def frames(self) -> int:
        return int(self.nodes.size)

    @property
    def searchable(self) -> int:
        return self.frames if self.hidden is None else int(self.frames - self.hidden.sum())

    def with_allowed(self, allowed: np.ndarray | None) -> OlngIndex:
        """The same tree, another set of hidden frames."""
        other = object.__new__(OlngIndex)
        other.__dict__.update(self.__dict__)
        other.hidden = None if allowed is None else ~np.asarray(allowed, dtype=bool)[self.nodes]
        if other.hidden is not None and not other.hidden.any():
            other.hidden = None
        return other

    def oriented_tree(self, weight: float) -> cKDTree:
        """The tree over each frame's readings and √weight · its sensors' "up" vectors
        (made once per weight; shared by `with_allowed` copies)."""
        if self.up is None:
            raise InputError("the graph has no sensor orientation metadata (rebuild it or run `graphsvc relayout`)")
        if weight not in self._oriented:
            self._oriented[weight] = cKDTree(np.concatenate([self.readings, np.sqrt(weight) * self.up], axis=1))
        return self._oriented[weight]

    def query(self, reading: np.ndarray, k: int, up: np.ndarray | None = None, weight: float = 0.0) -> Neighbours:
        """The k searchable frames nearest `reading` ((3S,) g, every sensor present: a
        kd-tree cannot leave a missing axis out of its distance); with up ((W·S,), the
        sensors' measured orientation cue, `sensors.orientation.normalised_rows`, all finite) and weight > 0, nearest in
        readings and √weight · up (`oriented_tree`)."""
        reading = np.asarray(reading, dtype=np.float64).reshape(-1)
        if reading.size != self.readings.shape[1]:
            raise InputError(f"a reading of {reading.size} values for an index of {self.readings.shape[1]}")
        if not np.all(np.isfinite(reading)):
            raise InputError("an OLNG query needs every sensor's reading (NaN or inf given)")
        tree = self.tree
        if up is not None and weight > 0:
            tree = self.oriented_tree(float(weight))
            reading = np.concatenate([reading, np.sqrt(weight) * np.asarray(up, dtype=np.float64).reshape(-1)])
        if not 1 <= k <= self.searchable:
            raise InputError(f"K must be between 1 and the {self.searchable} searchable frames, got {k}")
        if self.hidden is None:
            d, p = tree.query(reading, k=k)
            return Neighbours(np.atleast_1d(p).astype(np.int64), np.atleast_1d(d).astype(np.float64), 0)
        share = self.searchable / self.frames
        ask = min(self.frames, int(np.ceil(k / share * 1.1)) + 8)
        while True:
            d, p = tree.query(reading, k=ask)
            p, d = np.atleast_1d(p).astype(np.int64), np.atleast_1d(d)
            keep = ~self.hidden[p]
            if keep.sum() >= k or ask == self.frames:
                kept = np.flatnonzero(keep)[:k]
                return Neighbours(p[kept], d[kept].astype(np.float64), int(kept[-1] + 1 - kept.size))
            ask = min(self.frames, 2 * ask)

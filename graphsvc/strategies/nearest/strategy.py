"""The baseline strategy: per sample, the knowledge-base frame whose simulated readings
are nearest the measured ones.

No search over time, no track, no constraints: each sample is matched on its own by a
kd-tree (scipy's cKDTree) over every original graph frame's readings on arrival (the
layout's accelerations in g, S × 3 values; with measured orientations and W_R > 0,
also the sensors' orientation cue times √W_R, `sensors.orientation`, so a frame's
squared distance is S·(C_A + W_R·C_R), the Viterbi search's weighing; a sample whose
cue is incomplete is matched on its readings alone), and the chosen frames are synthesized with
the same clean-up as a graph path (`synthesis.path`: blends at every jump, each
frame's own root step, foot clean-up). A sample with a missing sensor continues the
previous frame's clip. It is the floor a search has to beat in every accuracy table,
and the smallest strategy to show the interface end to end.

Index: the frames (original nodes with an incoming original edge), that edge, and
their readings, cached beside the graph (`strategies.index`); the tree is built on
load (tens of milliseconds). Held-out clips are left out by building the tree over the
allowed frames only.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from graphsvc.graph.model import EDGE_ORIGINAL, MotionGraph
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.sensors.orientation import normalised_rows
from graphsvc.strategies.base import Strategy, frame_by_frame_ignored, prepared_index
from graphsvc.strategies.index import cached_arrays, frame_readings
from graphsvc.strategies.inputs import PreparedInput
from graphsvc.strategies.live import LiveSession
from graphsvc.strategies.options import Options
from graphsvc.strategies.results import Provenance, Reconstruction, path_labels
from graphsvc.strategies.start import first_measured
from graphsvc.synthesis.path import synthesize_motion, warm_up_synthesis
from graphsvc.synthesis.stream import StreamingSynthesizer

INDEX_VERSION = 1


@dataclass
class NearestIndex:
    """nodes (M,): the frames a sample can match; edges (M,): the original edge into
    each; readings (M, S·3) float32 g; tree: their kd-tree; next_of (N,): each node's
    position in `nodes` of its clip's next frame (−1: none)."""

    nodes: np.ndarray
    edges: np.ndarray
    readings: np.ndarray
    tree: cKDTree
    next_of: np.ndarray
    cue: np.ndarray | None = None  # (M, W·S) float32: the frames' orientation cue (None: the graph has none)
    oriented: dict = field(default_factory=dict)  # weight → the tree over readings and √weight · cue

    def oriented_tree(self, weight: float) -> cKDTree:
        """The tree over the readings and √weight · the orientation cue (made once per weight)."""
        if weight not in self.oriented:
            self.oriented[weight] = cKDTree(np.concatenate([self.readings, np.sqrt(weight) * self.cue], axis=1))
        return self.oriented[weight]


def _build_arrays(graph: MotionGraph) -> dict[str, np.ndarray]:
    return frame_readings(graph)


def _index(graph: MotionGraph, arrays: dict, allowed: np.ndarray | None = None) -> NearestIndex:
    nodes, edges, readings = arrays["nodes"], arrays["edges"], arrays["readings"]
    if allowed is not None:
        ok = np.asarray(allowed, dtype=bool)[nodes]
        nodes, edges, readings = nodes[ok], edges[ok], readings[ok]
    position = np.full(graph.num_nodes, -1, dtype=np.int64)
    position[nodes] = np.arange(nodes.size)
    # The next frame of a node's clip: the original edge out of it, if that frame can be matched.
    e = np.flatnonzero(np.asarray(graph.edge_kind) == EDGE_ORIGINAL)
    next_of = np.full(graph.num_nodes, -1, dtype=np.int64)
    next_of[np.asarray(graph.edge_src)[e]] = position[np.asarray(graph.edge_dst)[e]]
    cue = (
        None
        if graph.edge_up is None
        else np.asarray(graph.edge_up, np.float32)[np.asarray(edges)].reshape(nodes.size, -1)
    )
    return NearestIndex(np.asarray(nodes), np.asarray(edges), np.asarray(readings), cKDTree(readings), next_of, cue)


class NearestStrategy(Strategy):
    name = "nearest"
    needs = frozenset({"accelerations"})
    uses = frozenset({"accelerations", "orientations", "ground_position", "heading"})  # the track only places the start
    summary = "per sample the knowledge-base frame with the nearest readings: the floor a search must beat"

    def describe_lag(self, rate_hz: float) -> str:
        return f"{NearestSession.synthesis_lag_frames(rate_hz)} frames (the synthesis' blend), whatever S"

    def prepare(self, graph: MotionGraph):
        return cached_arrays(graph, self.name, INDEX_VERSION, lambda: _build_arrays(graph))

    def warm_up(self, index, graph: MotionGraph, threads: bool = False) -> None:
        warm_up_synthesis(graph)

    def ignored_options(self, options: Options) -> list[str]:
        # each frame is decided from its own sample; the track only places its start, no
        # path follows it (the shared track pull is not among what it reads)
        return sorted(frame_by_frame_ignored(options) + super().ignored_options(options))

    def reconstruct(
        self,
        index,
        graph: MotionGraph,
        inp: PreparedInput,
        options: Options,
        allowed: np.ndarray | None = None,
        threads: bool = True,
        should_stop=None,
    ) -> Reconstruction:
        t0 = time.perf_counter()
        idx = _index(graph, index, allowed)
        warm_up_synthesis(graph)
        weight = float(options.weights.orientation)
        up = inp.up if weight > 0 and idx.cue is not None else None
        if up is not None:
            idx.oriented_tree(weight)  # (made once per weight, with the warm-up's time)
        warm_up_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        picks, cost = choose(idx, inp.acc, up=up, weight=weight)
        nodes = idx.nodes[picks]
        edges = idx.edges[picks[1:]]
        search_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        motion = synthesize_motion(graph, nodes, edges, *first_measured(inp.position, inp.heading), allow_jumps=True)
        synth_s = time.perf_counter() - t0
        T = nodes.size
        report = {
            "cost": options.weights.acc * cost,
            "terms": {"acc_g2": cost},
            "candidate_frames": int(idx.nodes.size),
            "labels": path_labels(graph, nodes),
            "node_path": nodes.tolist(),
            "timings_s": {"warm_up": round(warm_up_s, 4), "search": round(search_s, 4), "synthesis": round(synth_s, 4)},
            "samples_per_s": round(T / max(search_s, 1e-9), 1),
        }
        return Reconstruction(motion, nodes, edges, report, Provenance.of_nodes(graph, nodes))


def choose(
    idx: NearestIndex, acc: np.ndarray, previous: int = -1, up: np.ndarray | None = None, weight: float = 0.0
) -> tuple[np.ndarray, float]:
    """(T,) positions in idx.nodes of each sample's frame, and the summed cost (mean over
    sensors of the squared reading difference, g², as the Viterbi search's C_A, plus
    W_R·C_R where the orientation cue counted). acc (T, S, 3) m/s²; up (T, S, W) the
    measured orientation cue or None, weighed by weight (W_R; the index must hold the
    graph's cue). A sample with a missing sensor plays on from the previous
    frame (its clip's next frame when it can be matched, else the same frame; with none
    before it, the first complete sample's frame). previous: the frame before acc[0]
    (−1: none)."""
    T = acc.shape[0]
    x = (np.asarray(acc, dtype=np.float64) / GRAVITY).reshape(T, -1)
    complete = np.all(np.isfinite(x), axis=1)
    picks = np.empty(T, dtype=np.int64)
    dist = np.zeros(T)
    oriented = np.zeros(T, dtype=bool)
    if up is not None and weight > 0:
        cue, valid = normalised_rows(np.asarray(up, dtype=np.float64).reshape(T, acc.shape[1], -1))
        oriented = complete & valid.all(axis=1)
        if oriented.any():
            q = np.concatenate([x[oriented], np.sqrt(weight) * cue[oriented].reshape(int(oriented.sum()), -1)], axis=1)
            d, k = idx.oriented_tree(weight).query(q)
            picks[oriented], dist[oriented] = k, d
    plain = complete & ~oriented
    if plain.any():
        d, k = idx.tree.query(x[plain])
        picks[plain] = k
        dist[plain] = d
    S = acc.shape[1]
    for t in np.flatnonzero(~complete):  # in order: each follows the one before
        last = picks[t - 1] if t else previous
        if last < 0:  # nothing before it: the first complete sample's frame, or the first frame
            last = int(picks[np.argmax(complete)]) if complete.any() else 0
            picks[t] = last
            continue
        nxt = idx.next_of[idx.nodes[last]]
        picks[t] = nxt if nxt >= 0 else last
    return picks, float(np.sum(dist[complete] ** 2) / S)


class NearestSession(LiveSession):
    """`nearest` live: each sample's frame at once, synthesized a few frames behind
    (the blend at a jump reaches half its window forward)."""

    def _open(self, allowed, threads: bool) -> None:
        graph = self.graph
        self.index = _index(graph, prepared_index(self.strategy, graph), allowed)
        self.synth: StreamingSynthesizer | None = None
        self.start_position: np.ndarray | None = None
        self.start_heading: float | None = None
        self.previous = -1
        self.lag_frames = self.synthesis_lag_frames(self.rate)

    def _decode(self, acc, position, heading, markers=None, up=None):
        weight = float(self.options.weights.orientation)
        up = None if up is None or self.index.cue is None else np.asarray(up)[None]
        if self.start_position is None and position is not None and np.all(np.isfinite(position)):
            self.start_position = np.asarray(position, dtype=np.float64)
        if self.start_heading is None and heading is not None and np.isfinite(heading):
            self.start_heading = float(heading)
        picks, _ = choose(self.index, np.asarray(acc, dtype=np.float64)[None], self.previous, up, weight)
        first = self.previous < 0
        self.previous = int(picks[0])
        node = self.index.nodes[picks]
        edge = np.array([-1]) if first else self.index.edges[picks]
        if self.synth is None:
            g = np.zeros(2) if self.start_position is None else self.start_position
            h = 0.0 if self.start_heading is None else self.start_heading
            self.synth = StreamingSynthesizer(self.graph, g, h, batch=self.SYNTH_BATCH)
        return self._frames(self.synth.add(node, edge))

    def _frames(self, synthesized):
        return self._emit_synthesized(self.synth, synthesized)

    def _finish(self):
        return self._frames(self.synth.finish()) if self.synth is not None else []


NearestStrategy.session_class = NearestSession
STRATEGY = NearestStrategy()

"""The Viterbi strategy: batch reconstruction and the live session.

Batch (`ViterbiStrategy.reconstruct`): the whole recording in one search (`batch`), or,
with a latency, the fixed-lag decoder a live stream runs (`stream`), then synthesis
(`synthesis.path`, `synthesis.stream`). Live (`ViterbiSession`): the fixed-lag decoder
and the streaming synthesizer, one sample at a time. Its index is the graph's search
index (`tables.SearchIndex`), made at load by the warm-up.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections import deque
from pathlib import Path

import numpy as np

from graphsvc.errors import SearchCancelled
from graphsvc.graph.file import load_graph, save_graph
from graphsvc.graph.model import MotionGraph, node_subgraph
from graphsvc.motion.skeleton import Motion
from graphsvc.sensors.noise import CausalTrackHeading
from graphsvc.strategies.base import Strategy
from graphsvc.strategies.inputs import PreparedInput
from graphsvc.strategies.live import LiveSession
from graphsvc.strategies.options import SMOOTH_S, Options, Weights, check_constraints
from graphsvc.strategies.refine import Refiner, refine_index, refine_motion, warm_up_refine
from graphsvc.strategies.results import Provenance, Reconstruction, path_labels
from graphsvc.strategies.start import start_placement, start_samples, start_state
from graphsvc.strategies.viterbi.batch import (
    needs_placement,
    orientation_counts,
    viterbi_search,
    warm_up_search,
    warm_up_search_once,
)
from graphsvc.strategies.viterbi.beam import _immortal
from graphsvc.strategies.viterbi.options import ViterbiOptions
from graphsvc.strategies.viterbi.stream import FixedLagDecoder
from graphsvc.strategies.viterbi.tables import SearchIndex, search_index
from graphsvc.synthesis.path import synthesize_motion, warm_up_synthesis
from graphsvc.synthesis.smooth import smooth_poses
from graphsvc.synthesis.stream import StreamingSynthesizer
from graphsvc.synthesis.track import TrackModel, fused_track


class ViterbiStrategy(Strategy):
    name = "viterbi"
    needs = frozenset({"accelerations"})
    uses = frozenset({"accelerations", "orientations", "ground_position", "heading", "constraints"})
    summary = "the motion-graph path that best explains the readings, the track and the constraints"
    options_class = ViterbiOptions
    shared = frozenset({"track_pull_s", "track_sigma_m", "track_drift", "smooth_s", "refine"})

    def describe_lag(self, rate_hz: float) -> str:
        s = ViterbiSession
        tail, total = s.synthesis_lag_frames(rate_hz, SMOOTH_S), s.output_lag_frames(rate_hz)
        return (
            f"at most round(S × rate) + {tail} frames after its sample at {rate_hz:g} Hz ({tail} for the synthesis' "
            f"blend look-ahead, its batches of {s.SYNTH_BATCH} frames and the poses' smoothing): {total} frames "
            f"({total / rate_hz:.2f} s) by default (and none before the search starts, 1 s in)"
        )

    def prepare(self, graph: MotionGraph) -> SearchIndex:
        return search_index(graph)  # (its tables are made on first use: by the warm-up at load)

    def warm_up(self, index, graph: MotionGraph, threads: bool = False) -> None:
        warm_up(graph, threads)
        warm_up_refine(graph)  # (its arrays on disk, its tree in memory: a session opens at once)

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
        acc, position, heading, constraints = inp.acc, inp.position, inp.heading, inp.constraints
        rate = float(graph.rate_hz)
        T = acc.shape[0]
        w = options.weights
        beam, pull_s = self.own(options).beam, options.shared.track_pull_s
        use_pos = position if w.position else None
        use_head = heading if w.heading else None
        # numba compiles (or loads) the search and synthesis kernels and the graph's tables
        # are made once per process, timed apart: the search time is the search's own.
        t0 = time.perf_counter()
        warm_up_search_once(graph, threads)
        warm_up_synthesis(graph)
        if orientation_counts(
            graph, w, inp.up
        ):  # (the oriented index's tables, once per graph, not in the search's time)
            oriented = search_index(graph, True)
            _ = oriented.slots if constraints else (oriented.tables, oriented.float32)
        refining = refine_index(graph, allowed) if options.shared.refine else None
        refine_weight = float(w.orientation) if inp.up is not None else 0.0
        if refining is not None and refine_weight > 0:
            refining.features(refine_weight)  # (the oriented tree, once per weight)
        warm_up_s = time.perf_counter() - t0

        t0 = time.perf_counter()
        # Every path starts where the first second's measurements put it (start_placement),
        # and the motion is synthesized from there.
        start = start_placement(position, heading, rate)
        start_ground, start_heading = start_state(position, heading, rate)
        # The positions the search pulls its paths toward, with which synthesis fuses the
        # path's own root track (`synthesis.track`).
        targets = pull_targets(use_pos, T)
        model = track_model(options, rate) if np.isfinite(targets).all(axis=1).any() else None
        if options.latency_s is None:
            result = viterbi_search(
                graph,
                acc,
                use_pos,
                use_head,
                w,
                constraints,
                allowed=allowed,
                threads=threads,
                should_stop=should_stop,
                beam=beam,
                start=start,
                pull_s=pull_s,
                up=inp.up,
            )
            nodes, edges = result.node_path, result.edge_path
            search_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            track = fused_track(graph, nodes, edges, start_ground, start_heading, targets, model) if model else None
            motion = synthesize_motion(graph, nodes, edges, start_ground, start_heading, track=track)
            motion = (
                refine_motion(
                    graph, motion, nodes, refining, acc, options.shared.smooth_s * rate, inp.up, refine_weight
                )
                if refining is not None
                else smoothed(motion, options)
            )
            synth_s = time.perf_counter() - t0
            extra = {
                "cost": result.cost,
                "terms": result.terms,
                "broken_constraints": result.broken,
                "compression": round(result.compression, 2),
                "peak_survivor_entries": result.peak_entries,
            }
        else:
            lag = int(round(options.latency_s * rate))
            decoder = FixedLagDecoder(
                graph,
                w,
                lag,
                constraints,
                allowed,
                rate,
                threads,
                needs_placement(w, use_pos, use_head),
                beam=beam,
                start_samples=start_samples(rate),
                pull_s=pull_s,
                oriented=orientation_counts(graph, w, inp.up),
                max_live=self.own(options).live_paths,
            )
            synth = StreamingSynthesizer(
                graph,
                start_ground,
                start_heading,
                batch=LiveSession.SYNTH_BATCH,
                track_model=track_model(options, rate) if use_pos is not None else None,
                smooth_frames=options.shared.smooth_s * rate,
                refiner=None if refining is None else Refiner(graph, refining, refine_weight),
            )
            emitted = 0
            node_parts, edge_parts, rot_parts, trans_parts = [], [], [], []
            synth_s = 0.0
            for t in range(T + 1):
                if should_stop is not None and t % 32 == 31 and should_stop():
                    raise SearchCancelled(f"search stopped at sample {t} of {T}")
                if t < T and synth.refiner is not None:
                    synth.refiner.push(acc[t], None if inp.up is None else inp.up[t])
                elif synth.refiner is not None:
                    synth.refiner.finish()
                if t < T:  # (the raw streams: the search scores only what its weights count)
                    n, e = decoder.push(
                        acc[t],
                        None if position is None else position[t],
                        None if heading is None else heading[t],
                        None if inp.up is None else inp.up[t],
                    )
                else:
                    n, e = decoder.flush()
                node_parts.append(n)
                edge_parts.append(e)
                ts = time.perf_counter()
                part = synth.add(n, e, targets[emitted : emitted + len(n)])
                emitted += len(n)
                _, rot, trans = part if t < T else _join(part, synth.finish())
                synth_s += time.perf_counter() - ts
                rot_parts.append(rot)
                trans_parts.append(trans)
            nodes = np.concatenate(node_parts)
            edges = np.concatenate(edge_parts)[1:]
            motion = Motion(
                graph.skeleton,
                np.concatenate(rot_parts),
                np.concatenate(trans_parts),
                rate,
                name="synthesized",
                source="graph path",
            )
            search_s = time.perf_counter() - t0 - synth_s
            s = decoder.search
            extra = {
                "lag_samples": lag,
                "revisions": decoder.revisions,
                "converged_early_frames": decoder.converged_frames,
                "compression": round(s.compression, 2),
                "peak_survivor_entries": int(s.peak_entries),
            }
        if model is not None:  # (the paths were placed toward the tracker, the root fused with it)
            extra["track"] = {"pull_s": float(pull_s), "sigma_m": model.sigma_m, "drift": model.drift}
        report = {
            **extra,
            "labels": path_labels(graph, nodes),
            "node_path": nodes.tolist(),
            "timings_s": {"warm_up": round(warm_up_s, 4), "search": round(search_s, 4), "synthesis": round(synth_s, 4)},
            "samples_per_s": round(T / max(search_s, 1e-9), 1),
        }
        return Reconstruction(motion, nodes, edges, report, Provenance.of_nodes(graph, nodes))


def smoothed(motion: Motion, options: Options) -> Motion:
    """The motion with its poses filtered (`synthesis.smooth`, the shared smooth_s)."""
    rot, trans = smooth_poses(motion.rotations, motion.translations, options.shared.smooth_s * motion.rate_hz)
    return (
        motion
        if rot is motion.rotations
        else Motion(motion.skeleton, rot, trans, motion.rate_hz, name=motion.name, source=motion.source)
    )


def track_model(options: Options, rate_hz: float) -> TrackModel:
    """How the synthesized root is fused with the tracker (the shared options)."""
    return TrackModel(options.shared.track_sigma_m, options.shared.track_drift, rate_hz)


def pull_targets(position, T: int) -> np.ndarray:
    """(T, 2) the positions the search's pull counts (NaN where none)."""
    if position is None:
        return np.full((T, 2), np.nan)
    out = np.asarray(position, dtype=np.float64).reshape(T, 2).copy()
    out[~np.isfinite(out).all(axis=1)] = np.nan
    return out


def _join(a, b):
    return a[0], np.concatenate([a[1], b[1]]), np.concatenate([a[2], b[2]])


class ViterbiSession(LiveSession):
    """A live stream through the Viterbi search: samples decoded by the fixed-lag
    decoder (lag = options.latency_s, default 1 s) and synthesized a few frames behind
    it, SYNTH_BATCH frames at a time. threads: numba threads per step — off by
    default, since a live server runs many sessions side by side (it turns them on
    while a session runs alone: `threads`)."""

    def _open(self, allowed, threads: bool) -> None:
        graph, options = self.graph, self.options
        constraints = check_constraints(options.constraints or [], graph)
        self.decoder = FixedLagDecoder(
            graph,
            options.weights,
            self.decoder_lag(self.rate, options.latency_s),
            constraints,
            allowed,
            self.rate,
            threads,
            beam=self.own.beam,
            start_samples=start_samples(self.rate),
            pull_s=options.shared.track_pull_s,
            oriented=self.reads_up,
            max_live=self.own.live_paths,
        )
        self.synth: StreamingSynthesizer | None = None
        self.counts_position = options.weights.position != 0
        self._targets: deque = deque()  # measured positions of the samples not yet synthesized
        self.track = (
            CausalTrackHeading(self.rate, options.speed_threshold, math.radians(options.rest_heading_deg))
            if options.heading_from_track
            else None
        )
        self.lag_frames = self.decoder.lag + self.synthesis_lag_frames(self.rate, options.shared.smooth_s)
        self.refiner = (
            Refiner(graph, refine_index(graph, allowed), options.weights.orientation if self.reads_up else 0.0)
            if options.shared.refine
            else None
        )

    @classmethod
    def decoder_lag(cls, rate_hz: float, latency_s: float | None = None) -> int:
        """The fixed-lag decoder's lag, samples at the graph rate: latency_s (default
        DEFAULT_LATENCY_S) of them."""
        return int(round((cls.DEFAULT_LATENCY_S if latency_s is None else latency_s) * rate_hz))

    @classmethod
    def output_lag_frames(cls, rate_hz: float, latency_s: float | None = None, smooth_s: float = SMOOTH_S) -> int:
        """A session's `lag_frames`: the decoder's lag plus the synthesis' (47 frames at
        30 Hz with the defaults: 30 + 12 + 2 + 3)."""
        return cls.decoder_lag(rate_hz, latency_s) + cls.synthesis_lag_frames(rate_hz, smooth_s)

    @property
    def threads(self) -> bool:
        """Whether the search steps use numba's threads; may change between pushes
        (same frames either way — see `graphsvc.strategies.threads`)."""
        return self.decoder.search.threads

    @threads.setter
    def threads(self, on: bool) -> None:
        self.decoder.search.threads = on

    def _decode(self, acc, position, heading, markers=None, up=None):
        if self.refiner is not None:
            self.refiner.push(acc, up)
        if self.track is not None:
            heading = self.track.push(position)
        nodes, edges = self.decoder.push(acc, position, heading, up)  # (the search scores what its weights count)
        self._targets.append(position if self.counts_position and position is not None else None)
        if self.synth is None and not len(nodes):
            return []
        return self._frames(self._synthesizer().add(nodes, edges, self._take_targets(len(nodes))))

    def _take_targets(self, count: int) -> np.ndarray:
        """The measured positions of the next `count` frames (NaN where none), as the
        search pulled its paths toward them."""
        out = np.full((count, 2), np.nan)
        for k in range(count):
            p = self._targets.popleft()
            if p is not None:
                out[k] = p
        return out

    def _synthesizer(self) -> StreamingSynthesizer:
        """Made when the first frames are final, starting where the search starts its
        paths (`strategies.base.start_placement` over the first second; a position or
        heading measured only later moves the search's paths, not frames already out)."""
        if self.synth is None:
            g, h = self.decoder.search.start_placement
            model = track_model(self.options, self.rate) if self.counts_position else None
            self.synth = StreamingSynthesizer(
                self.graph,
                g,
                h,
                batch=self.SYNTH_BATCH,
                track_model=model,
                smooth_frames=self.options.shared.smooth_s * self.rate,
                refiner=self.refiner,
            )
        return self.synth

    def _frames(self, synthesized):
        return self._emit_synthesized(self.synth, synthesized)

    def _finish(self):
        nodes, edges = self.decoder.flush()
        if self.refiner is not None:
            self.refiner.finish()
        synth = self._synthesizer()
        return self._frames(_join(synth.add(nodes, edges, self._take_targets(len(nodes))), synth.finish()))


ViterbiStrategy.session_class = ViterbiSession
STRATEGY = ViterbiStrategy()


# Above this many nodes the warm-up's searches run on a subgraph of about this many
# (`warm_up`): dense steps cost in proportion to the nodes, and on a 9.3M-node graph
# the whole graph's warm-up took 306 s of a server's start.
WARM_UP_NODES = 50_000


def warm_up(graph: MotionGraph, threads: bool = False) -> float:
    """Run a few samples through a live session and a batch search, so numba's
    compilation (or loading from its cache) and the graph's search tables are paid at
    load, not by the first client. Returns the seconds it took.

    On a graph of a file with more than WARM_UP_NODES nodes the tables are made (or
    mapped from their cache) for the graph, and the samples run on a subgraph of it
    saved to a temporary file and mapped as the graph is, so every kernel sees the
    argument types a search of the graph passes (read-only mapped arrays, the same
    dtypes: the subgraph keeps the node with the most incoming edges and its
    predecessors, which set the width of the arrivals' type). Graphs built in memory,
    small ones, and those whose subgraph has no cycle (every search on it would run
    into a dead end) warm up on themselves."""
    t0 = time.perf_counter()
    if graph.source_path is None or graph.num_nodes <= WARM_UP_NODES:
        _warm_up_on(graph, threads)
        return time.perf_counter() - t0
    index = search_index(graph)
    _ = index.tables, index.float32, index.beam  # (mapped from the cache beside the graph, made once)
    degree = np.diff(graph.incoming)
    busiest = int(np.argmax(degree))
    nodes = np.concatenate(
        [np.arange(WARM_UP_NODES), [busiest], graph.edge_src[graph.incoming[busiest] : graph.incoming[busiest + 1]]]
    )
    small = node_subgraph(graph, nodes)
    if not _immortal(small.incoming, small.edge_src, np.ones(small.num_nodes, dtype=bool)).any():
        _warm_up_on(graph, threads)  # (no path goes on forever there: the searches would find none)
        return time.perf_counter() - t0
    with tempfile.TemporaryDirectory(prefix="graphsvc-warm-up-", ignore_cleanup_errors=True) as folder:
        path = Path(folder) / "warm-up.graph"
        save_graph(small, path)
        del small
        _warm_up_on(load_graph(path, verify=False), threads)
    index.warmed.update((True, False) if threads else (False,))
    warm_up_synthesis(graph)
    return time.perf_counter() - t0


def _warm_up_on(graph: MotionGraph, threads: bool) -> None:
    S = len(graph.sensor_names)
    rng = np.random.default_rng(0)
    T = 48
    acc = rng.normal(0.0, 1.0, (T, S, 3))
    acc[:, :, 1] += 9.81
    position = np.cumsum(rng.normal(0.0, 0.02, (T, 2)), axis=0)
    heading = np.zeros(T)
    session = ViterbiSession(
        STRATEGY, graph, Options(weights=Weights(0.5, 1, 1), latency_s=0.2, own=ViterbiOptions()), threads=threads
    )
    for t in range(T):
        session.push(t / graph.rate_hz, acc[t], position[t], heading[t])
    session.flush()
    warm_up_search(graph, threads)  # (batch searches too)
    warm_up_synthesis(graph)

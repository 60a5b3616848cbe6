"""Recording → motion: the one path the CLI, the evaluation and the gRPC service share.

`reconstruct` takes a whole recording (batch); `LiveSession` takes samples one at a
time and returns pose frames as they become final. Both check the recording against
the graph (layout, rate), derive heading from the overhead track when asked, decode
with the chosen strategy and synthesize on the knowledge-base skeleton.

With `latency_s` set, batch decoding runs the very same fixed-lag decoder and streaming
synthesis as a live session, so `reconstruct` predicts what a live client gets.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from graphsvc.errors import FormatError, InputError, SearchCancelled, StrategyNotImplementedError
from graphsvc.graph.model import MotionGraph
from graphsvc.motion import quat
from graphsvc.motion.skeleton import Motion
from graphsvc.search.stream import FixedLagDecoder
from graphsvc.search.viterbi import (Weights, compile_constraints, needs_placement, viterbi_search, warm_up_search,
                                     warm_up_search_once)  # fmt: skip
from graphsvc.sensors.noise import CausalTrackHeading, heading_from_track
from graphsvc.sensors.recording import Recording, validate_constraints
from graphsvc.synthesis.path import synthesize_motion, warm_up_synthesis
from graphsvc.synthesis.stream import StreamingSynthesizer, lookahead_frames

STRATEGIES = ("viterbi", "olng", "ssg")


@dataclass(frozen=True)
class Options:
    """How to decode. weights: K eq. 6 (per g², per m, per rad). latency_s: fixed lag
    (s) of the streaming decoder; None in batch = search the whole input at once.
    heading_from_track: derive heading from the ground positions (K §6: direction of
    travel above `speed_threshold` m/s, else `rest_heading_deg`). constraints:
    annotation constraint sets in priority order (None: the recording's own). beam: a
    cost; after each sample only the paths within it of the best one go on (faster
    on built graphs, no longer always the cheapest path; None: the exact search; see
    `ViterbiSearch`)."""

    strategy: str = "viterbi"
    weights: Weights = Weights()
    latency_s: float | None = None
    heading_from_track: bool = False
    rest_heading_deg: float = 0.0
    speed_threshold: float = 2.0
    constraints: tuple | None = None
    beam: float | None = None

    def to_dict(self) -> dict:
        d = asdict(self)
        d["constraints"] = None if self.constraints is None else list(self.constraints)
        return d


def check_options(options: Options) -> None:
    """InputError for values no strategy accepts; StrategyNotImplementedError for a
    strategy that is specified but not built."""
    if options.strategy not in STRATEGIES:
        raise InputError(f"unknown strategy {options.strategy!r} (choose from {', '.join(STRATEGIES)})")
    if options.strategy != "viterbi":
        raise StrategyNotImplementedError(f"strategy {options.strategy!r} is not implemented yet (use viterbi)")
    w = options.weights
    for name in ("acc", "position", "heading"):
        v = getattr(w, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise InputError(f"weight {name} must be a finite number ≥ 0, got {v!r}")
    if options.latency_s is not None and (not math.isfinite(options.latency_s) or options.latency_s < 0):
        raise InputError(f"latency must be a finite number of seconds ≥ 0, got {options.latency_s}")
    if options.beam is not None and (isinstance(options.beam, bool) or not isinstance(options.beam, (int, float))
                                     or not math.isfinite(options.beam) or options.beam <= 0):
        raise InputError(f"beam must be a finite cost > 0, got {options.beam!r}")
    if not math.isfinite(options.rest_heading_deg):
        raise InputError(f"rest heading must be finite, got {options.rest_heading_deg}")
    if not (math.isfinite(options.speed_threshold) and options.speed_threshold >= 0):
        raise InputError(f"speed threshold must be finite and ≥ 0, got {options.speed_threshold}")


def parse_weights(text: str) -> Weights:
    """'A,P,O' (three non-negative numbers) → Weights."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise InputError(f"weights must be three numbers A,P,O, got {text!r}") from None
    if len(values) != 3 or not all(math.isfinite(v) and v >= 0 for v in values):
        raise InputError(f"weights must be three finite numbers ≥ 0 as A,P,O, got {text!r}")
    return Weights(*values)


def check_constraints(constraints, graph: MotionGraph | None = None) -> list:
    """Validate constraint sets (see `Recording`): structure, 0 ≤ start < end, no two
    intervals of one set overlapping (they would ask for two things at once), and —
    given a graph — labels it has."""
    constraints = list(constraints)
    validate_constraints(constraints)
    for i, cset in enumerate(constraints):
        spans = sorted((float(c["start_s"]), float(c["end_s"]), j) for j, c in enumerate(cset))
        for (s0, e0, j0), (s1, e1, j1) in zip(spans, spans[1:]):
            if s1 <= e0:
                raise InputError(f"constraint set {i}: constraints {j0} ({s0:g}–{e0:g} s) and {j1} ({s1:g}–{e1:g} s) overlap")
    if graph is not None:
        compile_constraints(graph, constraints, np.zeros(0))
    return constraints


def load_constraints(path) -> list:
    """A constraint file: a JSON list of sets in priority order (see `Recording`)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise FormatError(path, "not UTF-8 text") from None
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"not valid JSON: {exc.msg}", exc.lineno) from None
    try:
        return check_constraints(data)
    except InputError as exc:
        raise FormatError(path, str(exc)) from None


# ---------------------------------------------------------------- input checks


def check_layout(graph: MotionGraph, sensor_names) -> None:
    """InputError unless the stream's sensors are the graph's, in the same order."""
    mine, theirs = tuple(graph.sensor_names), tuple(sensor_names)
    if mine == theirs:
        return
    missing = [n for n in mine if n not in theirs]
    extra = [n for n in theirs if n not in mine]
    parts = []
    if missing:
        parts.append(f"missing {', '.join(missing)}")
    if extra:
        parts.append(f"not in the graph: {', '.join(extra)}")
    if not parts:
        parts.append(f"order {', '.join(theirs)} instead of {', '.join(mine)}")
    raise InputError(f"the recording's sensors do not match the graph's layout {graph.layout.get('name', '?')!r}: "
                     + "; ".join(parts) + " (rebuild the graph or run `graphsvc relayout`)")  # fmt: skip


def _interp_linear(times: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Linear interpolation along axis 0; NaN at either neighbour gives NaN (a gap
    stays a gap)."""
    i = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(times) - 2)
    w = ((at - times[i]) / (times[i + 1] - times[i])).reshape((-1,) + (1,) * (values.ndim - 1))
    return values[i] * (1.0 - w) + values[i + 1] * w


def _interp_angle(times: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    i = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(times) - 2)
    w = (at - times[i]) / (times[i + 1] - times[i])
    return quat.wrap_angle(values[i] + w * quat.wrap_angle(values[i + 1] - values[i]))


def to_graph_rate(rec: Recording, rate_hz: float) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, bool]:
    """The recording's accelerations (T', S, 3), positions (T', 2) and headings (T',)
    on a uniform grid at `rate_hz` from its first timestamp, linearly interpolated
    (headings the short way round). Untouched when already uniform at that rate.
    Returns (acc, position, heading, resampled)."""
    t = np.asarray(rec.timestamps_s, dtype=np.float64)
    acc = np.asarray(rec.accelerations, dtype=np.float64)
    period = 1.0 / rate_hz
    uniform = abs(rec.rate_hz - rate_hz) < 1e-9 * rate_hz and (
        t.size < 2 or np.max(np.abs(np.diff(t) - period)) < 0.01 * period
    )
    if uniform:
        return acc, rec.ground_position, rec.heading, False
    if t.size < 2:
        return acc, rec.ground_position, rec.heading, False
    n = int(math.floor((t[-1] - t[0]) * rate_hz + 1e-6)) + 1
    grid = t[0] + np.arange(n) * period
    position = None if rec.ground_position is None else _interp_linear(t, np.asarray(rec.ground_position, float), grid)
    heading = None if rec.heading is None else _interp_angle(t, np.asarray(rec.heading, float), grid)
    return _interp_linear(t, acc, grid), position, heading, True


# ---------------------------------------------------------------- batch


@dataclass
class Reconstruction:
    """motion: on graph.skeleton at graph.rate_hz; node_path (T,), edge_path (T−1,)
    (the edges entering node_path[1:]); report: JSON-able summary."""

    motion: Motion
    node_path: np.ndarray
    edge_path: np.ndarray
    report: dict = field(default_factory=dict)


def _start_state(position, heading) -> tuple[np.ndarray, float]:
    """Where the search starts every path (`ViterbiSearch._anchor`): the first measured
    ground position (T, 2) m and heading (T,) rad, else the origin facing +Z."""
    g = np.zeros(2)
    if position is not None:
        measured = np.nonzero(np.isfinite(position).all(axis=1))[0]
        if len(measured):
            g = np.asarray(position[measured[0]], dtype=np.float64)
    h = 0.0
    if heading is not None:
        measured = np.nonzero(np.isfinite(heading))[0]
        if len(measured):
            h = float(heading[measured[0]])
    return g, h


def reconstruct(graph: MotionGraph, rec: Recording, options: Options = Options(), allowed: np.ndarray | None = None,
                threads: bool = True, should_stop=None) -> Reconstruction:  # fmt: skip
    """The motion a recording's measurements describe. allowed: (N,) bool node mask
    (leave-one-out evaluation) or None; threads: numba threads inside the search
    (False where many searches run side by side); should_stop: callable polled during
    the search, raising SearchCancelled when it returns true. Raises InputError for
    recordings that do not fit the graph, StrategyNotImplementedError for strategies
    not built yet."""
    check_options(options)
    rec.validate()
    check_layout(graph, rec.sensor_names)
    constraints = check_constraints(rec.constraints if options.constraints is None else options.constraints, graph)
    t_start = time.perf_counter()
    acc, position, heading, resampled = to_graph_rate(rec, graph.rate_hz)
    rate = float(graph.rate_hz)
    T = acc.shape[0]
    heading_source = "recording" if heading is not None else "none"
    if options.heading_from_track:
        if position is None:
            raise InputError("--heading-from-track needs ground positions, and the recording has none")
        rest = math.radians(options.rest_heading_deg)
        if options.latency_s is None:
            heading = heading_from_track(position, rate, options.speed_threshold, rest)
        else:
            track = CausalTrackHeading(rate, options.speed_threshold, rest)
            heading = np.array([track.push(p) for p in position])
        heading_source = "track"
    w = options.weights
    use_pos = position if w.position else None
    use_head = heading if w.heading else None
    prepare_s = time.perf_counter() - t_start
    # numba compiles (or loads) the search and synthesis kernels and the graph's tables
    # are made once per process, timed apart: the search time is the search's own.
    t0 = time.perf_counter()
    warm_up_search_once(graph, threads)
    warm_up_synthesis(graph)
    warm_up_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    start_ground, start_heading = _start_state(position, heading)
    extra = {}
    if options.latency_s is None:
        result = viterbi_search(graph, acc, use_pos, use_head, w, constraints, allowed=allowed, threads=threads,
                                should_stop=should_stop, beam=options.beam)  # fmt: skip
        nodes, edges = result.node_path, result.edge_path
        search_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        motion = synthesize_motion(graph, nodes, edges, start_ground, start_heading)
        synth_s = time.perf_counter() - t0
        extra = {"cost": result.cost, "terms": result.terms, "broken_constraints": result.broken,
                 "compression": round(result.compression, 2), "peak_survivor_entries": result.peak_entries}  # fmt: skip
    else:
        lag = int(round(options.latency_s * rate))
        decoder = FixedLagDecoder(graph, w, lag, constraints, allowed, rate, threads,
                                  needs_placement(w, use_pos, use_head), beam=options.beam)  # fmt: skip
        synth = StreamingSynthesizer(graph, start_ground, start_heading, batch=LiveSession.SYNTH_BATCH)
        node_parts, edge_parts, rot_parts, trans_parts = [], [], [], []
        synth_s = 0.0
        for t in range(T + 1):
            if should_stop is not None and t % 32 == 31 and should_stop():
                raise SearchCancelled(f"search stopped at sample {t} of {T}")
            if t < T:
                n, e = decoder.push(acc[t], None if use_pos is None else use_pos[t], None if use_head is None else use_head[t])
            else:
                n, e = decoder.flush()
            node_parts.append(n)
            edge_parts.append(e)
            ts = time.perf_counter()
            _, rot, trans = synth.add(n, e) if t < T else _join(synth.add(n, e), synth.finish())
            synth_s += time.perf_counter() - ts
            rot_parts.append(rot)
            trans_parts.append(trans)
        nodes = np.concatenate(node_parts)
        edges = np.concatenate(edge_parts)[1:]
        motion = Motion(graph.skeleton, np.concatenate(rot_parts), np.concatenate(trans_parts), rate,
                        name="synthesized", source="graph path")  # fmt: skip
        search_s = time.perf_counter() - t0 - synth_s
        s = decoder.search
        extra = {"lag_samples": lag, "revisions": decoder.revisions, "converged_early_frames": decoder.converged_frames,
                 "compression": round(s.compression, 2),
                 "peak_survivor_entries": int(s.peak_entries)}  # fmt: skip
    report = {
        "strategy": options.strategy,
        "options": options.to_dict(),
        "graph": {"nodes": graph.num_nodes, "edges": graph.num_edges, "rate_hz": rate, "layout": graph.layout.get("name")},
        "samples": T,
        "input_rate_hz": float(rec.rate_hz),
        "resampled": resampled,
        "heading_source": heading_source,
        "constraint_sets": len(constraints),
        **extra,
        "labels": path_labels(graph, nodes),
        "node_path": nodes.tolist(),
        "timings_s": {"warm_up": round(warm_up_s, 4), "prepare": round(prepare_s, 4), "search": round(search_s, 4),
                      "synthesis": round(synth_s, 4)},  # fmt: skip
        "samples_per_s": round(T / max(search_s, 1e-9), 1),
    }
    return Reconstruction(motion, nodes, edges, report)


def _join(a, b):
    return a[0], np.concatenate([a[1], b[1]]), np.concatenate([a[2], b[2]])


def path_labels(graph: MotionGraph, nodes: np.ndarray) -> list[dict]:
    """The content labels along a path as runs: [{label, start_frame, frames}]."""
    labels = graph.node_label[nodes]
    runs = []
    start = 0
    for t in range(1, len(labels) + 1):
        if t == len(labels) or labels[t] != labels[start]:
            runs.append({"label": graph.labels[int(labels[start])], "start_frame": start, "frames": t - start})
            start = t
    return runs


# ---------------------------------------------------------------- live


@dataclass
class Frame:
    """One output pose. index: frame number at the graph rate; time_s: stream time;
    rotations (J, 4) float32 local wxyz; translations (J, 3) float32 local, metres."""

    index: int
    time_s: float
    node: int
    label: str
    rotations: np.ndarray
    translations: np.ndarray


class LiveSession:
    """A live stream: `push` sensor samples (any rate, strictly increasing times),
    receive the pose frames that became final; `flush` at the end.

    Samples are linearly resampled to the graph rate on arrival, decoded by the
    fixed-lag decoder (lag = options.latency_s, default 1 s) and synthesized a few
    frames behind it, SYNTH_BATCH frames at a time. `lag_frames` is the most a frame
    waits, in graph frames, between its sample arriving and its pose coming out.
    threads: numba threads per step — off by default, since a live server runs many
    sessions side by side (it turns them on while a session runs alone: `threads`).
    keep_motion: keep every frame emitted, for `motion()`; that grows by J × 56 bytes a
    frame (190 MB an hour at 31 joints and 30 Hz), so a server streaming whole matches
    passes False and keeps only what later frames need."""

    DEFAULT_LATENCY_S = 1.0
    SYNTH_BATCH = 3  # 0.1 s at 30 Hz

    def __init__(self, graph: MotionGraph, options: Options = Options(), sensor_names=None, allowed=None,
                 threads: bool = False, keep_motion: bool = True):  # fmt: skip
        check_options(options)
        check_layout(graph, graph.sensor_names if sensor_names is None else sensor_names)
        self.graph = graph
        self.options = options
        self.rate = float(graph.rate_hz)
        latency = self.DEFAULT_LATENCY_S if options.latency_s is None else options.latency_s
        constraints = check_constraints(options.constraints or [], graph)
        self.decoder = FixedLagDecoder(graph, options.weights, int(round(latency * self.rate)), constraints, allowed,
                                       self.rate, threads, beam=options.beam)  # fmt: skip
        self.synth: StreamingSynthesizer | None = None
        self.start_position: np.ndarray | None = None  # first measured, (2,) m
        self.start_heading: float | None = None  # first measured (or from the track), rad
        self.track = (CausalTrackHeading(self.rate, options.speed_threshold, math.radians(options.rest_heading_deg))
                      if options.heading_from_track else None)  # fmt: skip
        self.lag_frames = self.decoder.lag + lookahead_frames(self.rate) + self.SYNTH_BATCH - 1
        self.S = len(graph.sensor_names)
        self.t0: float | None = None
        self.prev: tuple | None = None  # last raw sample (t, acc, position, heading)
        self.next_tick = 0  # index of the next graph-rate sample to produce
        self.samples_in = 0
        self.keep_motion = keep_motion
        self._rot: list[np.ndarray] = []
        self._trans: list[np.ndarray] = []
        self.flushed = False

    @property
    def threads(self) -> bool:
        """Whether the search steps use numba's threads; may change between pushes
        (same frames either way — see `graphsvc.search.threads`)."""
        return self.decoder.search.threads

    @threads.setter
    def threads(self, on: bool) -> None:
        self.decoder.search.threads = on

    def _check(self, t_s, acc, position, heading):
        if isinstance(t_s, bool) or not isinstance(t_s, (int, float, np.integer, np.floating)) or not math.isfinite(t_s):
            raise InputError(f"timestamp must be a finite number of seconds, got {t_s!r}")
        if self.prev is not None and not t_s > self.prev[0]:
            raise InputError(f"timestamps must increase: {t_s} after {self.prev[0]}")
        acc = np.asarray(acc, dtype=np.float64)
        if acc.shape != (self.S, 3):
            raise InputError(f"accelerations must be ({self.S}, 3) for the graph's sensors, got {acc.shape}")
        if np.isinf(acc).any():
            raise InputError("accelerations contain infinite values (use NaN for missing)")
        if position is not None:
            position = np.asarray(position, dtype=np.float64)
            if position.shape != (2,) or np.isinf(position).any():
                raise InputError("position must be two finite numbers (x, z) in metres, or NaN for missing")
        if heading is not None:
            heading = float(heading)
            if math.isinf(heading):
                raise InputError("heading must be finite (NaN for missing)")
        return float(t_s), acc, position, heading

    def push(self, t_s: float, acc, position=None, heading=None) -> list[Frame]:
        """One sensor sample at time t_s (s): acc (S, 3) m/s² (NaN = missing), position
        (2,) m or None, heading rad or None. Returns the frames now final."""
        if self.flushed:
            raise InputError("the stream was already flushed")
        t_s, acc, position, heading = self._check(t_s, acc, position, heading)
        self.samples_in += 1
        cur = (t_s, acc, position, heading)
        frames: list[Frame] = []
        if self.prev is None:
            self.t0 = t_s
            frames += self._decode(acc, position, heading)
        else:
            t_prev = self.prev[0]
            while True:
                tick = self.t0 + self.next_tick / self.rate
                if tick > t_s + 1e-9:
                    break
                if abs(tick - t_s) < 1e-9:  # on the grid already: exact values, as in batch
                    frames += self._decode(acc, position, heading)
                else:
                    frames += self._decode(*_blend(self.prev, cur, (tick - t_prev) / (t_s - t_prev)))
        self.prev = cur
        return frames

    def _decode(self, acc, position, heading) -> list[Frame]:
        self.next_tick += 1
        if self.track is not None:
            heading = self.track.push(position)
        if self.start_position is None and position is not None and np.all(np.isfinite(position)):
            self.start_position = np.asarray(position, dtype=np.float64)
        if self.start_heading is None and heading is not None and math.isfinite(heading):
            self.start_heading = float(heading)
        w = self.options.weights
        nodes, edges = self.decoder.push(acc, position if w.position else None, heading if w.heading else None)
        if self.synth is None and not len(nodes):
            return []
        return self._frames(self._synthesizer().add(nodes, edges))

    def _synthesizer(self) -> StreamingSynthesizer:
        """Made when the first frames are final, starting where the search starts its
        paths (`_start_state`): the first position and heading measured so far (one
        measured only later moves the search's paths, not frames already out)."""
        if self.synth is None:
            g = np.zeros(2) if self.start_position is None else self.start_position
            h = 0.0 if self.start_heading is None else self.start_heading
            self.synth = StreamingSynthesizer(self.graph, g, h, batch=self.SYNTH_BATCH)
        return self.synth

    def _frames(self, synthesized) -> list[Frame]:
        first, rot, trans = synthesized
        if not len(rot):
            return []
        if self.keep_motion:
            self._rot.append(rot)
            self._trans.append(trans)
        out = []
        for k in range(rot.shape[0]):
            f = first + k
            node = self._node_at(f)
            out.append(Frame(f, self.t0 + f / self.rate, node, self.graph.labels[int(self.graph.node_label[node])],
                             rot[k].astype(np.float32), trans[k].astype(np.float32)))  # fmt: skip
        return out

    def _node_at(self, f: int) -> int:
        synth = self.synth
        return int(synth.nodes[f - synth.base])

    def flush(self) -> list[Frame]:
        """The frames still held back, at the end of the stream."""
        if self.flushed or self.next_tick == 0:
            self.flushed = True
            return []
        self.flushed = True
        nodes, edges = self.decoder.flush()
        synth = self._synthesizer()
        first, rot, trans = _join(synth.add(nodes, edges), synth.finish())
        return self._frames((first, rot, trans))

    def motion(self) -> Motion:
        """Everything emitted so far as one motion (a session made with keep_motion)."""
        if not self.keep_motion:
            raise InputError("this live session was made with keep_motion=False: it keeps no frames for motion()")
        J = self.graph.skeleton.num_joints
        rot = np.concatenate(self._rot) if self._rot else np.zeros((0, J, 4))
        trans = np.concatenate(self._trans) if self._trans else np.zeros((0, J, 3))
        return Motion(self.graph.skeleton, rot, trans, self.rate, name="synthesized", source="live stream")


def _blend(a: tuple, b: tuple, w: float):
    """Sample between raw samples a and b at fraction w: (acc, position, heading)."""
    acc = a[1] * (1.0 - w) + b[1] * w
    pos = None
    if a[2] is not None and b[2] is not None:
        pos = a[2] * (1.0 - w) + b[2] * w
    elif w >= 0.5 and b[2] is not None or w < 0.5 and a[2] is not None:
        pos = b[2] if w >= 0.5 else a[2]
    head = None
    if a[3] is not None and b[3] is not None:
        head = float(quat.wrap_angle(a[3] + w * quat.wrap_angle(b[3] - a[3])))
    elif w >= 0.5 and b[3] is not None or w < 0.5 and a[3] is not None:
        head = b[3] if w >= 0.5 else a[3]
    return acc, pos, head


def warm_up(graph: MotionGraph, threads: bool = False) -> float:
    """Run a few samples through a live session and a batch search, so numba's
    compilation (or loading from its cache) and the graph's search tables are paid at
    load, not by the first client. Returns the seconds it took."""
    t0 = time.perf_counter()
    S = len(graph.sensor_names)
    rng = np.random.default_rng(0)
    T = 48
    acc = rng.normal(0.0, 1.0, (T, S, 3))
    acc[:, :, 1] += 9.81
    position = np.cumsum(rng.normal(0.0, 0.02, (T, 2)), axis=0)
    heading = np.zeros(T)
    session = LiveSession(graph, Options(weights=Weights(0.5, 1, 1), latency_s=0.2), threads=threads)
    for t in range(T):
        session.push(t / graph.rate_hz, acc[t], position[t], heading[t])
    session.flush()
    warm_up_search(graph, threads)  # (batch searches too)
    warm_up_synthesis(graph)
    return time.perf_counter() - t0

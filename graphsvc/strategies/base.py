"""The interface every reconstruction strategy implements, and what they share.

A strategy (`Strategy`) turns a recording into motion on a graph's skeleton. It:

- declares the inputs it needs (`needs`: a recording without one is refused, naming
  it) and those it can use (`uses`: the others are ignored and the report lists them
  under `ignored_inputs`), from INPUTS;
- prepares an index from a graph (`prepare`: built on first use, held for the graph
  object; a strategy whose index is costly caches it beside the graph file, keyed by
  the file's checksum — `strategies.index`);
- reconstructs a whole recording (`reconstruct`), given the recording already
  checked and put on the graph's sample grid (`prepare_input`);
- opens a live session (`session_class`, a `LiveSession`: `push(sample) -> frames`,
  `flush()`);
- hides clips for leave-one-out evaluation (`allowed_mask`: for the graph strategies a
  node mask, `graph.holdout.held_out_mask`).

What they share lives here: the checks and resampling of a recording
(`prepare_input`), the result type (`Reconstruction`, with per-frame provenance that
also fits blended frames), the live frame (`Frame`) and the live session's sample
handling (resampling raw samples onto the graph's grid), so a strategy writes only
its own decoding.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from graphsvc.errors import InputError
from graphsvc.graph.derived import derived
from graphsvc.graph.model import MotionGraph
from graphsvc.sensors.anatomy import check_frames
from graphsvc.motion import quat
from graphsvc.motion.skeleton import Motion
from graphsvc.sensors.noise import CausalTrackHeading, heading_from_track
from graphsvc.sensors.recording import Recording, check_gap
from graphsvc.strategies.options import Options, check_constraints

INPUTS = ("accelerations", "orientations", "markers", "ground_position", "heading", "constraints")


class Strategy:
    """One way to reconstruct motion (module docstring). Subclasses set `name`, `needs`,
    `uses` and `summary`, and implement `prepare`, `reconstruct` and `session_class`."""

    name: str = ""
    needs: frozenset = frozenset()
    uses: frozenset = frozenset()
    summary: str = ""
    session_class: type = None  # a LiveSession subclass

    def prepare(self, graph: MotionGraph):
        """The strategy's index for `graph`, made once per graph object."""
        raise NotImplementedError

    def reconstruct(self, index, graph: MotionGraph, inp: "PreparedInput", options: Options,
                    allowed: np.ndarray | None = None, threads: bool = True, should_stop=None) -> "Reconstruction":  # fmt: skip
        raise NotImplementedError

    def warm_up(self, index, graph: MotionGraph, threads: bool = False) -> None:
        """Load compiled code and make tables now, not on a client's first sample."""

    def allowed_mask(self, graph: MotionGraph, clips) -> np.ndarray:
        """(N,) bool: the nodes a search may use when graph clips `clips` (their
        performances) are held out."""
        from graphsvc.graph.holdout import held_out_mask

        return held_out_mask(graph, clips)

    def ignored_options(self, options: Options) -> list[str]:
        """Options set to something this strategy does not use (for the report)."""
        return []


def frame_by_frame_ignored(options: Options) -> list[str]:
    """The options a strategy that decides each frame from its own sample ignores:
    the beam and the latency (no search over time to prune or to delay)."""
    return [name for name, v in (("beam", options.beam), ("latency_s", options.latency_s)) if v is not None]


def prepared_index(strategy: Strategy, graph: MotionGraph):
    """`strategy.prepare(graph)`, once per graph object and strategy (`graph.derived`:
    an index must not refer to its graph but weakly)."""
    return derived(graph, ("strategy index", strategy.name), lambda: strategy.prepare(graph))


# ---------------------------------------------------------------- input checks


def recording_inputs(rec: Recording) -> set[str]:
    """Which of INPUTS a recording carries."""
    have = set()
    if rec.accelerations is not None and rec.accelerations.size:
        have.add("accelerations")
    if getattr(rec, "orientations", None) is not None:
        have.add("orientations")
    if getattr(rec, "marker_positions", None) is not None:
        have.add("markers")
    if rec.ground_position is not None:
        have.add("ground_position")
    if rec.heading is not None:
        have.add("heading")
    if rec.constraints:
        have.add("constraints")
    return have


def check_inputs(strategy: Strategy, have: set[str]) -> list[str]:
    """InputError naming the first input `strategy` needs that `have` lacks; else the
    inputs present that it cannot use (sorted)."""
    for name in INPUTS:
        if name in strategy.needs and name not in have:
            raise InputError(f"strategy {strategy.name!r} needs {name.replace('_', ' ')}, and the recording has none")
    return sorted(have - set(strategy.uses))


def layout_mismatch(mine, theirs, order_matters: bool = True) -> str | None:
    """What separates a stream's sensor names `theirs` from a layout's `mine`: the
    missing sensors, those not in the layout, duplicates or (order_matters) the
    order; None when they agree. One wording for the CLI and the service."""
    mine, theirs = tuple(mine), tuple(theirs)
    if mine == theirs:
        return None
    missing = [n for n in mine if n not in theirs]
    extra = [n for n in dict.fromkeys(theirs) if n not in mine]
    dup = [n for n in dict.fromkeys(theirs) if theirs.count(n) > 1]
    parts = []
    if missing:
        parts.append(f"missing {', '.join(missing)}")
    if extra:
        parts.append(f"not in the graph: {', '.join(extra)}")
    if dup:
        parts.append(f"named twice: {', '.join(dup)}")
    if not parts:
        if not order_matters:
            return None
        parts.append(f"order {', '.join(theirs)} instead of {', '.join(mine)}")
    return "; ".join(parts)


def layout_mismatch_message(layout_name: str, mine, theirs, order_matters: bool = True) -> str | None:
    """The line that refuses sensors `theirs` for a graph whose layout `layout_name`
    has sensors `mine`, or None when they fit."""
    what = layout_mismatch(mine, theirs, order_matters)
    if what is None:
        return None
    return (f"the recording's sensors do not match the graph's layout {layout_name!r}: "
            f"{what} (rebuild the graph or run `graphsvc relayout`)")  # fmt: skip


def check_layout(graph: MotionGraph, sensor_names) -> None:
    """InputError unless the stream's sensors are the graph's, in the same order."""
    message = layout_mismatch_message(graph.layout.get("name", "?"), graph.sensor_names, sensor_names)
    if message is not None:
        raise InputError(message)


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
    Returns (acc, position, heading, resampled); a recording without accelerations
    gives (T', 0, 3) (`markers_to_graph_rate` puts its markers on the same grid)."""
    t, grid = _grid(rec, rate_hz)
    acc = np.asarray(rec.accelerations, dtype=np.float64) if rec.accelerations is not None else np.zeros((t.size, 0, 3))
    if grid is None:
        return acc, rec.ground_position, rec.heading, False
    position = None if rec.ground_position is None else _interp_linear(t, np.asarray(rec.ground_position, float), grid)
    heading = None if rec.heading is None else _interp_angle(t, np.asarray(rec.heading, float), grid)
    return _interp_linear(t, acc, grid), position, heading, True


def _grid(rec: Recording, rate_hz: float) -> tuple[np.ndarray, np.ndarray | None]:
    """The recording's timestamps and the uniform grid at `rate_hz` from its first
    (None: already uniform at that rate, or a single sample)."""
    t = np.asarray(rec.timestamps_s, dtype=np.float64)
    period = 1.0 / rate_hz
    uniform = abs(rec.rate_hz - rate_hz) < 1e-9 * rate_hz and (
        t.size < 2 or np.max(np.abs(np.diff(t) - period)) < 0.01 * period
    )
    if uniform or t.size < 2:
        return t, None
    n = int(math.floor((t[-1] - t[0]) * rate_hz + 1e-6)) + 1
    return t, t[0] + np.arange(n) * period


def orientations_to_graph_rate(rec: Recording, rate_hz: float) -> np.ndarray:
    """The sensors' measured "up" vectors (T', S, 3) (`graph.metadata.sensor_up` of the
    recording's orientations) on `to_graph_rate`'s grid, interpolated linearly (the
    search normalises them; NaN stays a gap)."""
    from graphsvc.graph.metadata import sensor_up

    t, grid = _grid(rec, rate_hz)
    up = sensor_up(np.asarray(rec.orientations, dtype=np.float64))
    return up if grid is None else _interp_linear(t, up, grid)


def markers_to_graph_rate(rec: Recording, rate_hz: float) -> np.ndarray | None:
    """The recording's marker positions (T', M, 3) on `to_graph_rate`'s grid (a marker
    unseen at either neighbouring sample is unseen between them), or None."""
    if rec.marker_positions is None:
        return None
    t, grid = _grid(rec, rate_hz)
    points = np.asarray(rec.marker_positions, dtype=np.float64)
    return points if grid is None else _interp_linear(t, points, grid)


@dataclass
class PreparedInput:
    """A recording checked against a graph and put on its sample grid: T samples of
    accelerations (T, S, 3) m/s² (S = 0 for a strategy that reads none), ground
    positions (T, 2) m and headings (T,) rad (or None), labelled marker positions (T, M,
    3) m (or None), the constraint sets, and what the report says about them."""

    acc: np.ndarray
    position: np.ndarray | None
    heading: np.ndarray | None
    constraints: list
    resampled: bool
    heading_source: str
    input_rate_hz: float
    ignored_inputs: list = field(default_factory=list)
    markers: np.ndarray | None = None  # (T, M, 3) m, NaN = not seen
    marker_names: tuple = ()
    meta: dict = field(default_factory=dict)  # the recording's provenance
    # (T, S, 3) the sensors' measured "up" vectors (world +Y in each sensor's frame,
    # `graph.metadata.sensor_up`; NaN = missing), where the strategy uses orientations
    # and the graph has their metadata; else None
    up: np.ndarray | None = None

    @property
    def num_samples(self) -> int:
        return int(self.acc.shape[0])


def check_constraint_times(constraints, duration_s: float) -> None:
    """InputError for a constraint interval that starts at or after the recording's
    end (it could never hold); one that only ends past it is kept."""
    for k, cset in enumerate(constraints):
        for j, c in enumerate(cset):
            start, end = float(c["start_s"]), float(c["end_s"])
            if start >= duration_s:
                raise InputError(f"constraint set {k}: constraint {j} ({start:g}–{end:g} s) starts after the "
                                 f"recording ends ({duration_s:g} s)")  # fmt: skip


def prepare_input(strategy: Strategy, graph: MotionGraph, rec: Recording, options: Options) -> PreparedInput:
    """Check `rec` for `strategy` on `graph` and resample it to the graph rate (module
    docstring). Raises InputError naming what does not fit."""
    rec.validate()
    constraints = rec.constraints if options.constraints is None else options.constraints
    have = recording_inputs(rec) | ({"constraints"} if constraints else set())
    ignored = check_inputs(strategy, have)
    if "accelerations" in strategy.uses:
        check_layout(graph, rec.sensor_names)
        check_frames(graph.params, rec.meta)
    constraints = check_constraints(constraints, graph) if "constraints" in strategy.uses else []
    check_constraint_times(constraints, rec.num_samples / rec.rate_hz)
    acc, position, heading, resampled = to_graph_rate(rec, graph.rate_hz)
    if "accelerations" not in strategy.uses:
        acc = np.zeros((acc.shape[0], 0, 3))
    markers = markers_to_graph_rate(rec, graph.rate_hz) if "markers" in strategy.uses else None
    up = None
    if getattr(rec, "orientations", None) is not None and "orientations" in strategy.uses:
        if graph.edge_up is None:  # (a graph file written before orientation metadata)
            ignored = sorted(set(ignored) | {"orientations"})
        else:
            up = orientations_to_graph_rate(rec, graph.rate_hz)
    heading_source = "recording" if heading is not None else "none"
    if options.heading_from_track:
        if position is None:
            raise InputError("--heading-from-track needs ground positions, and the recording has none")
        rate = float(graph.rate_hz)
        rest = math.radians(options.rest_heading_deg)
        if options.latency_s is None:
            heading = heading_from_track(position, rate, options.speed_threshold, rest)
        else:
            track = CausalTrackHeading(rate, options.speed_threshold, rest)
            heading = np.array([track.push(p) for p in position])
        heading_source = "track"
    return PreparedInput(acc, position, heading, constraints, resampled, heading_source, float(rec.rate_hz), ignored,
                         markers, tuple(rec.marker_names) if markers is not None else (), dict(rec.meta), up)  # fmt: skip


# Where a reconstruction starts is estimated from the measurements of its first second:
# anchoring it to the first sample alone carried that sample's tracker noise (σ 10 cm,
# 10° by default) into the whole path.
START_WINDOW_S = 1.0
# Without a measured heading, a reconstruction starts facing its track's direction of
# travel when the track moves at least this far (m) over the first second (a standing
# performer keeps facing +Z: the track says nothing of the facing).
START_TRAVEL_M = 0.3


def start_samples(rate_hz: float) -> int:
    """How many samples `start_placement` reads at the graph rate (a live decoder waits
    for them before its search starts)."""
    return max(1, int(round(START_WINDOW_S * float(rate_hz))))


# Below these white-noise levels (estimated from the measurements' second differences)
# the first measurement is the start: a line cannot follow a walk's sway, so its
# intercept is off by a centimetre or two where the measurements themselves are not.
EXACT_POSITION_M = 0.02
EXACT_HEADING_RAD = np.radians(2.0)


def _white_noise(values: np.ndarray) -> float:
    """The white noise σ of samples of a smooth signal (n, ...): from the median
    absolute second difference (σ·√6 for white noise; a smooth motion's own second
    differences at 30 Hz are millimetres)."""
    if len(values) < 3:
        return 0.0
    d2 = values[2:] - 2.0 * values[1:-1] + values[:-2]
    return float(np.median(np.abs(d2)) / 0.6745 / np.sqrt(6.0))


def start_placement(position, heading, rate_hz: float) -> tuple[np.ndarray | None, float | None]:
    """Where a reconstruction starts, from the measurements of its first
    `start_samples(rate_hz)` samples (a live decoder has them all before it starts):
    ground position (2,) m and heading rad, None for what they do not tell (the search
    then anchors to the first later measurement: `ViterbiSearch._anchor`).

    - Position: the value at sample 0 of a straight line fitted to the window's
      measured positions — its intercept, where one sample's noise shrinks by about
      2 / √n — unless they are exact (white noise below EXACT_POSITION_M) and
      sample 0 is measured: then that sample; with fewer than three measured, the
      first measured position.
    - Heading measured: the same with the window's unwrapped headings
      (EXACT_HEADING_RAD).
    - Only positions measured: the direction of travel of the fitted line, when the
      track moves at least START_TRAVEL_M over the window.
    position (T, 2) or None, heading (T,) or None (only the window is read)."""
    W = start_samples(rate_hz)
    p0 = velocity = None
    if position is not None:
        pos = np.asarray(position, dtype=np.float64)[:W]
        t = np.flatnonzero(np.isfinite(pos).all(axis=1))
        if len(t) >= 3:
            slope, p0 = np.polyfit(t.astype(np.float64), pos[t], 1)  # (2,) each
            velocity = slope * float(rate_hz)
            if _white_noise(pos[t]) < EXACT_POSITION_M and t[0] == 0:
                p0 = pos[0].copy()  # (exact: the first sample, unless it is missing)
        elif len(t):
            p0 = pos[t[0]].copy()
    h0 = None
    if heading is not None:
        head = np.asarray(heading, dtype=np.float64)[:W]
        t = np.flatnonzero(np.isfinite(head))
        if len(t) >= 3 and (t[0] > 0 or _white_noise(np.unwrap(head[t])) >= EXACT_HEADING_RAD):
            h0 = float(np.polyfit(t.astype(np.float64), np.unwrap(head[t]), 1)[1])
        elif len(t):
            h0 = float(head[t[0]])
    if h0 is None and velocity is not None and float(np.hypot(*velocity)) * (W - 1) / rate_hz >= START_TRAVEL_M:
        h0 = float(np.arctan2(velocity[0], velocity[1]))  # (0 faces +Z, positive toward +X)
    if h0 is not None:
        h0 = float(h0 - 2.0 * np.pi * np.floor((h0 + np.pi) / (2.0 * np.pi)))  # [−π, π)
    return p0, h0


def first_measured(position, heading) -> tuple[np.ndarray, float]:
    """The first measured ground position (T, 2) m and heading (T,) rad, else the
    origin facing +Z: where a strategy that decides each frame at once (a live
    `nearest` session cannot wait for `start_placement`'s second) places its start."""
    g = np.zeros(2)
    if position is not None:
        measured = np.flatnonzero(np.isfinite(position).all(axis=1))
        if len(measured):
            g = np.asarray(position[measured[0]], dtype=np.float64)
    h = 0.0
    if heading is not None:
        measured = np.flatnonzero(np.isfinite(heading))
        if len(measured):
            h = float(heading[measured[0]])
    return g, h


def start_state(position, heading, rate_hz: float) -> tuple[np.ndarray, float]:
    """`start_placement` with what it cannot tell filled in: the first measured position
    and heading, else the origin, facing +Z (where the search's paths start)."""
    p0, h0 = start_placement(position, heading, rate_hz)
    g, h = first_measured(position, heading)
    return (g if p0 is None else np.asarray(p0, dtype=np.float64)), (h if h0 is None else h0)


# ---------------------------------------------------------------- results


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
    def of_nodes(graph: MotionGraph, nodes: np.ndarray) -> "Provenance":
        """One source a frame: each node's clip and frame (a blended node's dominant one)."""
        nodes = np.asarray(nodes, dtype=np.int64)
        return Provenance(np.asarray(graph.node_clip)[nodes][:, None].astype(np.int64),
                          np.asarray(graph.node_frame)[nodes][:, None].astype(np.float64),
                          np.ones((nodes.size, 1)),
                          np.asarray(graph.labels, dtype=object)[np.asarray(graph.node_label)[nodes]])  # fmt: skip

    def sources(self, t: int) -> list[tuple[int, float, float]]:
        """Frame t's sources as (clip, frame, weight), heaviest first."""
        keep = self.clip[t] >= 0
        order = np.argsort(-self.weight[t][keep], kind="stable")
        return [(int(c), float(f), float(w)) for c, f, w in
                zip(self.clip[t][keep][order], self.frame[t][keep][order], self.weight[t][keep][order])]  # fmt: skip


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


# ---------------------------------------------------------------- live


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


class LiveSession:
    """A live stream: `push` sensor samples (any rate, strictly increasing times),
    receive the pose frames that became final; `flush` at the end.

    `LiveSession(graph, options, ...)` opens the session of `options.strategy` (its
    `session_class`, a subclass). Samples are checked and linearly resampled to the
    graph rate on arrival (headings the short way round); each grid sample goes to the
    strategy's `_decode`. `lag_frames` is the most a frame waits, in graph frames,
    between its sample arriving and its pose coming out. keep_motion: keep every frame
    emitted, for `motion()`; that grows by J × 56 bytes a frame (190 MB an hour at 31
    joints and 30 Hz), so a server streaming whole matches passes False."""

    DEFAULT_LATENCY_S = 1.0
    SYNTH_BATCH = 3  # 0.1 s at 30 Hz

    @classmethod
    def synthesis_lag_frames(cls, rate_hz: float) -> int:
        """Frames a streamed pose can come out after its frame of the path is final:
        the streaming synthesis' look-ahead (half its blend window, plus one) and up to
        SYNTH_BATCH − 1 frames waiting for its batch to fill; 12 + 2 at 30 Hz."""
        from graphsvc.synthesis.stream import lookahead_frames

        return lookahead_frames(rate_hz) + cls.SYNTH_BATCH - 1

    def __new__(cls, graph: MotionGraph, options: Options = Options(), *args, **kwargs):
        if cls is LiveSession:
            from graphsvc.strategies import get

            cls = get(options.strategy).session_class
        return super().__new__(cls)

    def __init__(self, graph: MotionGraph, options: Options = Options(), sensor_names=None, allowed=None,
                 threads: bool = False, keep_motion: bool = True, marker_names=None,
                 orientations: bool = False):  # fmt: skip
        from graphsvc.strategies import get
        from graphsvc.strategies.options import check_options

        check_options(options)
        self.strategy = get(options.strategy)
        self.reads_acc = "accelerations" in self.strategy.uses
        if self.reads_acc:
            check_layout(graph, graph.sensor_names if sensor_names is None else sensor_names)
        self.marker_names = tuple(marker_names or ()) if "markers" in self.strategy.uses else ()
        if "markers" in self.strategy.needs and not self.marker_names:
            raise InputError(f"strategy {self.strategy.name!r} needs the names of the markers the stream carries")
        self.graph = graph
        self.options = options
        self.rate = float(graph.rate_hz)
        self.S = len(graph.sensor_names) if self.reads_acc else 0
        # orientations: the stream's samples carry each sensor's orientation; they count
        # where the strategy uses them, the graph has their metadata and W_R > 0
        self.reads_up = bool(orientations) and "orientations" in self.strategy.uses and graph.edge_up is not None \
            and options.weights.orientation > 0
        self.M = len(self.marker_names)
        self.lag_frames = 0
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
        """Whether the strategy's kernels use numba's threads (may change between pushes)."""
        return False

    @threads.setter
    def threads(self, on: bool) -> None:
        pass

    def _check(self, t_s, acc, position, heading, markers=None, orientations=None):
        if isinstance(t_s, bool) or not isinstance(t_s, (int, float, np.integer, np.floating)) or not math.isfinite(t_s):
            raise InputError(f"timestamp must be a finite number of seconds, got {t_s!r}")
        if self.prev is not None and not t_s > self.prev[0]:
            raise InputError(f"timestamps must increase: {t_s} after {self.prev[0]}")
        if self.prev is not None:
            check_gap(float(self.prev[0]), float(t_s))
        acc = np.asarray(acc, dtype=np.float64) if self.reads_acc else np.zeros((0, 3))  # (else ignored)
        if acc.shape != (self.S, 3):
            raise InputError(f"accelerations must be ({self.S}, 3) for the graph's sensors, got {acc.shape}")
        if np.isinf(acc).any():
            raise InputError("accelerations contain infinite values (use NaN for missing)")
        if self.M:
            markers = np.full((self.M, 3), np.nan) if markers is None else np.asarray(markers, dtype=np.float64)
            if markers.shape != (self.M, 3):
                raise InputError(f"marker positions must be ({self.M}, 3) for the stream's markers, got {markers.shape}")
            if np.isinf(markers).any():
                raise InputError("marker positions contain infinite values (use NaN for not seen)")
        else:
            markers = None
        if position is not None:
            position = np.asarray(position, dtype=np.float64)
            if position.shape != (2,) or np.isinf(position).any():
                raise InputError("position must be two finite numbers (x, z) in metres, or NaN for missing")
        if heading is not None:
            heading = float(heading)
            if math.isinf(heading):
                raise InputError("heading must be finite (NaN for missing)")
        up = None
        if orientations is not None:
            q = np.asarray(orientations, dtype=np.float64)
            S = len(self.graph.sensor_names)
            if q.shape != (S, 4) or np.isinf(q).any():
                raise InputError(f"orientations must be ({S}, 4) finite quaternions w, x, y, z (NaN for missing), "
                                 f"got shape {q.shape}")  # fmt: skip
            if self.reads_up:
                from graphsvc.graph.metadata import sensor_up

                with np.errstate(invalid="ignore", divide="ignore"):
                    up = sensor_up(q)  # (a zero or NaN quaternion gives NaN: missing)
        return float(t_s), acc, position, heading, markers, up

    def push(self, t_s: float, acc=None, position=None, heading=None, markers=None,
             orientations=None) -> list[Frame]:  # fmt: skip
        """One sample at time t_s (s): acc (S, 3) m/s² (NaN = missing; None for a
        strategy that reads no accelerations), position (2,) m or None, heading rad or
        None, markers (M, 3) m for the session's marker names (NaN = not seen) or None,
        orientations (S, 4) each sensor's (w, x, y, z; NaN = missing) or None — used by
        a session opened with `orientations` (see __init__). Returns the frames now final."""
        if self.flushed:
            raise InputError("the stream was already flushed")
        t_s, acc, position, heading, markers, up = self._check(t_s, acc, position, heading, markers, orientations)
        self.samples_in += 1
        cur = (t_s, acc, position, heading, markers, up)
        frames: list[Frame] = []
        if self.prev is None:
            self.t0 = t_s
            self.next_tick += 1
            frames += self._decode(acc, position, heading, markers, up)
        else:
            t_prev = self.prev[0]
            while True:
                tick = self.t0 + self.next_tick / self.rate
                if tick > t_s + 1e-9:
                    break
                self.next_tick += 1
                if abs(tick - t_s) < 1e-9:  # on the grid already: exact values, as in batch
                    frames += self._decode(acc, position, heading, markers, up)
                else:
                    frames += self._decode(*_blend(self.prev, cur, (tick - t_prev) / (t_s - t_prev)))
        self.prev = cur
        return frames

    def flush(self) -> list[Frame]:
        """The frames still held back, at the end of the stream."""
        if self.flushed or self.next_tick == 0:
            self.flushed = True
            return []
        self.flushed = True
        return self._finish()

    def _decode(self, acc, position, heading, markers=None, up=None) -> list[Frame]:
        """One sample on the graph's grid → the frames now final. up: (S, 3) the
        sensors' "up" vectors (`graph.metadata.sensor_up`), or None."""
        raise NotImplementedError

    def _finish(self) -> list[Frame]:
        """The frames still held back, once, at the end."""
        raise NotImplementedError

    def _emit_synthesized(self, synth, synthesized):
        """The frames a StreamingSynthesizer made final, `synth.add`'s or `finish`'s
        (first, rotations, translations), with the nodes it played."""
        first, rot, trans = synthesized
        nodes = synth.nodes[first - synth.base: first - synth.base + len(rot)] if len(rot) else []
        return self._emit(first, rot, trans, nodes)

    def _emit(self, first: int, rot: np.ndarray, trans: np.ndarray, nodes=None, provenance: Provenance | None = None):
        """Frames first … first + K − 1 from their poses (K, J, 4/3), and either their
        graph nodes (K,) or their provenance."""
        if not len(rot):
            return []
        if self.keep_motion:
            self._rot.append(rot)
            self._trans.append(trans)
        if provenance is None:
            provenance = Provenance.of_nodes(self.graph, nodes)
        out = []
        for k in range(rot.shape[0]):
            f = first + k
            out.append(Frame(f, self.t0 + f / self.rate, -1 if nodes is None else int(nodes[k]),
                             str(provenance.label[k]), rot[k].astype(np.float32), trans[k].astype(np.float32),
                             provenance.sources(k)))  # fmt: skip
        return out

    def motion(self) -> Motion:
        """Everything emitted so far as one motion (a session made with keep_motion)."""
        if not self.keep_motion:
            raise InputError("this live session was made with keep_motion=False: it keeps no frames for motion()")
        J = self.graph.skeleton.num_joints
        rot = np.concatenate(self._rot) if self._rot else np.zeros((0, J, 4))
        trans = np.concatenate(self._trans) if self._trans else np.zeros((0, J, 3))
        return Motion(self.graph.skeleton, rot, trans, self.rate, name="synthesized", source="live stream")


def _blend(a: tuple, b: tuple, w: float):
    """Sample between raw samples a and b at fraction w: (acc, position, heading,
    markers, up); a marker unseen at either is unseen between them; the sensors' "up"
    vectors blend linearly (the search normalises them), or the nearer sample's."""
    acc = a[1] * (1.0 - w) + b[1] * w
    markers = None if a[4] is None else a[4] * (1.0 - w) + b[4] * w
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
    up = None
    if a[5] is not None and b[5] is not None:
        up = a[5] * (1.0 - w) + b[5] * w
    elif w >= 0.5 and b[5] is not None or w < 0.5 and a[5] is not None:
        up = b[5] if w >= 0.5 else a[5]
    return acc, pos, head, markers, up

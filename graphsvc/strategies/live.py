"""A live stream's session: samples in at any rate, pose frames out as they become final.

`LiveSession` checks each sample, resamples the stream onto the graph's grid as samples
arrive (headings the short way round, markers unseen at either neighbour unseen
between them) and hands each grid sample to its strategy's `_decode`; a strategy's
session subclasses it and writes only its own decoding. Sessions are opened through
the registry (`graphsvc.strategies.open_session`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from graphsvc.errors import InputError
from graphsvc.graph.model import MotionGraph
from graphsvc.motion import quat
from graphsvc.motion.skeleton import Motion
from graphsvc.sensors.recording import check_gap
from graphsvc.strategies.inputs import check_layout, graph_cue
from graphsvc.strategies.options import Options
from graphsvc.strategies.results import Frame, Provenance
from graphsvc.synthesis.smooth import half_width
from graphsvc.synthesis.stream import lookahead_frames


class LiveSession:
    """A live stream: `push` sensor samples (any rate, strictly increasing times),
    receive the pose frames that became final; `flush` at the end.

    A strategy's session is its `session_class`, a subclass, opened through the registry
    (`graphsvc.strategies.open_session`). Samples are checked and linearly resampled to the
    graph rate on arrival (headings the short way round); each grid sample goes to the
    strategy's `_decode`. `lag_frames` is the most a frame waits, in graph frames,
    between its sample arriving and its pose coming out. keep_motion: keep every frame
    emitted, for `motion()`; that grows by J × 56 bytes a frame (190 MB an hour at 31
    joints and 30 Hz), so a server streaming whole matches passes False."""

    DEFAULT_LATENCY_S = 1.0
    SYNTH_BATCH = 3  # 0.1 s at 30 Hz

    @classmethod
    def synthesis_lag_frames(cls, rate_hz: float, smooth_s: float = 0.0) -> int:
        """Frames a streamed pose can come out after its frame of the path is final:
        the streaming synthesis' look-ahead (half its blend window, plus one), up to
        SYNTH_BATCH − 1 frames waiting for its batch to fill, and the frames the poses'
        filter waits for (`synthesis.smooth`, σ = smooth_s); 12 + 2 + 3 at 30 Hz with
        the default σ."""
        return lookahead_frames(rate_hz) + cls.SYNTH_BATCH - 1 + half_width(smooth_s * rate_hz)

    def __init__(
        self,
        strategy,
        graph: MotionGraph,
        options: Options,
        sensor_names=None,
        allowed=None,
        threads: bool = False,
        keep_motion: bool = True,
        marker_names=None,
        orientations: bool = False,
    ):
        """strategy: the `base.Strategy` whose session this is; options: checked
        (`strategies.check_options`). Opened by `strategies.open_session`, which says
        what the rest are. A strategy's session sets itself up in `_open`."""
        self.strategy = strategy
        self.own = strategy.own(options)
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
        self.reads_up = (
            bool(orientations)
            and "orientations" in self.strategy.uses
            and graph.edge_up is not None
            and options.weights.orientation > 0
        )
        self.M = len(self.marker_names)
        self.lag_frames = 0
        self.t0 = 0.0  # the first sample's time (set by the first push)
        self.prev: tuple | None = None  # last raw sample (t, acc, position, heading)
        self.next_tick = 0  # index of the next graph-rate sample to produce
        self.samples_in = 0
        self.keep_motion = keep_motion
        self._rot: list[np.ndarray] = []
        self._trans: list[np.ndarray] = []
        self.flushed = False
        self._open(allowed, threads)

    def _open(self, allowed, threads: bool) -> None:
        """The strategy's own set-up (its decoder, `lag_frames`), after the common one:
        allowed, the node mask of a leave-out run (or None); threads, numba's threads."""

    @property
    def threads(self) -> bool:
        """Whether the strategy's kernels use numba's threads (may change between pushes)."""
        return False

    @threads.setter
    def threads(self, on: bool) -> None:
        pass

    def _check(self, t_s, acc, position, heading, markers=None, orientations=None):
        if (
            isinstance(t_s, bool)
            or not isinstance(t_s, (int, float, np.integer, np.floating))
            or not math.isfinite(t_s)
        ):
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
                raise InputError(
                    f"marker positions must be ({self.M}, 3) for the stream's markers, got {markers.shape}"
                )
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
                raise InputError(
                    f"orientations must be ({S}, 4) finite quaternions w, x, y, z (NaN for missing), "
                    f"got shape {q.shape}"
                )
            if self.reads_up:
                with np.errstate(invalid="ignore", divide="ignore"):
                    up = graph_cue(self.graph, q)  # (a zero or NaN quaternion gives NaN: missing)
        return float(t_s), acc, position, heading, markers, up

    def push(
        self,
        t_s: float,
        acc: ArrayLike | None = None,
        position: ArrayLike | None = None,
        heading: float | None = None,
        markers: ArrayLike | None = None,
        orientations: ArrayLike | None = None,
    ) -> list[Frame]:
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
        sensors' orientation cue (`strategies.inputs.graph_cue`), or None."""
        raise NotImplementedError

    def _finish(self) -> list[Frame]:
        """The frames still held back, once, at the end."""
        raise NotImplementedError

    def _emit_synthesized(self, synth, synthesized):
        """The frames a StreamingSynthesizer made final, `synth.add`'s or `finish`'s
        (first, rotations, translations), with the nodes it played."""
        first, rot, trans = synthesized
        nodes = synth.nodes[first - synth.base : first - synth.base + len(rot)] if len(rot) else []
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
            out.append(
                Frame(
                    f,
                    self.t0 + f / self.rate,
                    -1 if nodes is None else int(nodes[k]),
                    str(provenance.label[k]),
                    rot[k].astype(np.float32),
                    trans[k].astype(np.float32),
                    provenance.sources(k),
                )
            )
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

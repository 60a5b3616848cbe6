"""What a live stream needs beside its session: a slot among the server's
`max_streams` (`StreamSlots`), its first message, the StreamConfig, read within
`config_timeout_s` of connecting (`first_message`), and what that config announces
(`StreamInput`: the sensors, their order, the marker names), by which each sample is
read into the graph's order, and a calibration from the stream's own start when the
config asks for one (`StartCalibration`).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import grpc
import numpy as np

from graphsvc.errors import FieldError, InputError
from graphsvc.service.convert_recording import (
    marker_names_from_proto,
    sample_from_proto,
    sample_markers_from_proto,
    sample_orientations_from_proto,
    sensor_order,
)
from graphsvc.service.status import RpcStatus

# A stream that sends no StreamConfig within this many seconds of connecting is ended
# with DEADLINE_EXCEEDED and its slot freed (the server's --config-timeout-s).
CONFIG_TIMEOUT_S = 10.0


class StreamSlots:
    """At most `limit` live streams at once. A slot is released exactly once, by the
    handler finishing or by gRPC's termination callback, whichever comes first."""

    def __init__(self, limit: int):
        self.limit = limit
        self._active = 0
        self._lock = threading.Lock()

    @property
    def active(self) -> int:
        return self._active

    def try_acquire(self):
        """A release function, or None when all slots are taken."""
        with self._lock:
            if self._active >= self.limit:
                return None
            self._active += 1
        released = threading.Event()

        def release():
            with self._lock:
                if not released.is_set():
                    released.set()
                    self._active -= 1

        return release


def first_message(request_iterator, timeout_s: float):
    """The first request of a stream, or None when the client half-closed before
    sending one; RpcStatus DEADLINE_EXCEEDED when none came within timeout_s.

    gRPC's request iterator has no timed read, so a short-lived thread reads the one
    message while the handler waits. On a timeout the handler ends the call, which
    ends the reader's wait too (its read raises, and the thread exits)."""
    box: list = []
    done = threading.Event()

    def read():
        try:
            box.append(next(request_iterator, None))
        except BaseException as exc:  # noqa: BLE001 — grpc.RpcError when the call ends first; handed over
            box.append(exc)
        done.set()

    threading.Thread(target=read, name="graphsvc-config", daemon=True).start()
    if not done.wait(timeout_s):
        raise RpcStatus(
            grpc.StatusCode.DEADLINE_EXCEEDED,
            f"config: no StreamConfig within {timeout_s:g} s of "
            "connecting (the server's --config-timeout-s); the stream's slot is freed",
        )
    if isinstance(box[0], BaseException):
        raise box[0]
    return box[0]


@dataclass(frozen=True)
class StreamInput:
    """What a stream's config announces, checked against its graph and strategy.
    names: the sensors the samples carry, in the graph's order (a strategy that reads
    no accelerations: whatever the config names, else the graph's); order: indices
    that put a sample's sensors into that order (None: they are); reads_acc: whether
    the strategy reads accelerations (else a sample may carry none); marker_names:
    the markers each sample places; orientations: whether samples carry them."""

    names: tuple[str, ...]
    order: np.ndarray | None
    reads_acc: bool
    marker_names: tuple[str, ...]
    orientations: bool

    @classmethod
    def of(cls, config, graph, strategy) -> StreamInput:
        """A StreamConfig's sensors and marker names read for `graph` (a MotionGraph)
        and `strategy`; FieldError naming the config's field."""
        names = graph.sensor_names
        reads_acc = "accelerations" in strategy.uses
        if reads_acc:
            order = sensor_order(config.sensor_names, names, "config.sensor_names", graph.layout.get("name", "?"))
        else:  # whatever sensors the samples carry (the strategy reads none): the lengths still checked
            order, names = None, tuple(config.sensor_names) or names
        marker_names = marker_names_from_proto(config.marker_names, "config.marker_names")
        return cls(names, order, reads_acc, marker_names, config.orientations)

    def sample(self, msg, previous_time_s: float | None, field: str) -> tuple:
        """A SensorSample read in the graph's sensor order: (time_s, acc, position,
        heading, markers, orientations), each checked (`convert_recording`)."""
        t, acc, position, heading = sample_from_proto(
            msg, len(self.names), self.order, previous_time_s, field, self.reads_acc
        )
        markers = sample_markers_from_proto(msg, len(self.marker_names), field)
        orientations = sample_orientations_from_proto(msg, len(self.names), self.order, self.orientations, field)
        return t, acc, position, heading, markers, orientations


class StartCalibration:
    """A stream calibrated from its own start (StreamConfig.calibrate_from_start): the
    samples of its first `seconds` (from the first sample's time) are held, the devices'
    mountings calibrated from them against the graph (`pipeline.calibrated_from_start`'s
    calibration), and they and every later sample are searched in the layout's frames."""

    FIELD = "config.calibrate_from_start"

    def __init__(self, graph, names: tuple[str, ...], seconds: float, pose: str):
        from graphsvc.graph.calibration import MAX_FROM_START_S
        from graphsvc.sensors.calibration import POSES

        if not (np.isfinite(seconds) and 0 < seconds <= MAX_FROM_START_S):
            raise FieldError(
                f"{self.FIELD}.seconds",
                f"must be a finite number of seconds > 0 and at most {MAX_FROM_START_S:g}, got {seconds}",
            )
        if pose not in POSES:
            raise FieldError(f"{self.FIELD}.pose", f"unknown pose {pose!r} (poses: {', '.join(POSES)})")
        self.graph, self.names, self.seconds, self.pose = graph, tuple(names), float(seconds), pose
        self.held: list[tuple] = []
        self.rotations: np.ndarray | None = None  # (S, 4) once calibrated

    @classmethod
    def of(cls, config, graph, names) -> StartCalibration | None:
        if not config.HasField("calibrate_from_start"):
            return None
        c = config.calibrate_from_start
        return cls(graph, names, c.seconds, c.pose)

    def add(self, sample: tuple) -> list[tuple]:
        """One sample (`StreamInput.sample`'s tuple) in; the samples ready to search out:
        none while the first seconds are held, then those and this one, calibrated."""
        if self.rotations is None:
            if not self.held or sample[0] - self.held[0][0] <= self.seconds + 1e-9:
                self.held.append(sample)
                return []
            self._calibrate()
        return self._ready([sample])

    def finish(self) -> list[tuple]:
        """The held samples of a stream that ended within its first seconds, calibrated
        from what it sent."""
        if self.rotations is None and self.held:
            self._calibrate()
        return self._ready([])

    def _calibrate(self) -> None:
        from graphsvc.graph.calibration import calibrate_from_start
        from graphsvc.sensors.calibration import calibration_rotations, check_calibration
        from graphsvc.sensors.recording import Recording

        t = np.array([s[0] for s in self.held], dtype=np.float64)
        if any(s[1] is None for s in self.held):
            raise FieldError(self.FIELD, "a calibration needs every sample's accelerations")
        acc = np.stack([s[1] for s in self.held]).astype(np.float32)
        orient = (
            None if any(s[5] is None for s in self.held) else np.stack([s[5] for s in self.held]).astype(np.float32)
        )
        rate = round(1.0 / float(np.median(np.diff(t))), 6) if t.size > 1 else float(self.graph.rate_hz)
        rec = Recording(
            rate_hz=rate,
            timestamps_s=t,
            sensor_names=self.names,
            accelerations=acc,
            orientations=orient,
            meta={"source": "stream", "sensor_frame": "device"},
        )
        try:
            cal = check_calibration(calibrate_from_start(rec, self.graph, self.seconds, self.pose), self.FIELD)
        except InputError as exc:
            raise FieldError(self.FIELD, str(exc)) from None
        self.rotations = calibration_rotations(cal, self.names)

    def _ready(self, new: list[tuple]) -> list[tuple]:
        from graphsvc.motion import quat
        from graphsvc.sensors.calibration import calibrate_sample

        out = []
        for t, acc, position, heading, markers, orient in self.held + new:
            if acc is not None:
                acc = calibrate_sample(self.rotations, acc).astype(np.float32)
            if orient is not None:
                orient = quat.mul(np.asarray(orient, dtype=np.float64), quat.conjugate(self.rotations)).astype(
                    np.float32
                )
            out.append((t, acc, position, heading, markers, orient))
        self.held = []
        return out

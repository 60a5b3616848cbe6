"""What a live stream needs beside its session: a slot among the server's
`max_streams` (`StreamSlots`), its first message, the StreamConfig, read within
`config_timeout_s` of connecting (`first_message`), and what that config announces
(`StreamInput`: the sensors, their order, the marker names), by which each sample is
read into the graph's order.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import grpc
import numpy as np

from graphsvc.service.convert_recording import (marker_names_from_proto, sample_from_proto, sample_markers_from_proto,
                                                sample_orientations_from_proto, sensor_order)  # fmt: skip
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
        raise RpcStatus(grpc.StatusCode.DEADLINE_EXCEEDED, f"config: no StreamConfig within {timeout_s:g} s of "
                        "connecting (the server's --config-timeout-s); the stream's slot is freed")  # fmt: skip
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
        t, acc, position, heading = sample_from_proto(msg, len(self.names), self.order, previous_time_s, field,
                                                      self.reads_acc)  # fmt: skip
        markers = sample_markers_from_proto(msg, len(self.marker_names), field)
        orientations = sample_orientations_from_proto(msg, len(self.names), self.order, self.orientations, field)
        return t, acc, position, heading, markers, orientations

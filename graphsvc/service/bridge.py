"""Serial sensor bridge: accelerometer lines from a serial device → live stream to a
graphsvc server → the synthesized motion.

Line protocol (ASCII, one reading of one sensor per line, `\\n` or `\\r\\n`)::

    t_ms,sensor_id,ax,ay,az

- ``t_ms``: the device clock in milliseconds (any origin; integer or decimal).
  All sensors read in one sampling round carry the same ``t_ms``; rounds increase.
- ``sensor_id``: index into the graph's layout sensors (0-based, the order of
  `graphsvc info`) or the sensor's name.
- ``ax,ay,az``: acceleration in the sensor's own frame, m/s² (``--units m/s2``) or g
  (``--units g``, × 9.81).
- Blank lines and lines starting with ``#`` (banners, comments) are ignored.

Lines with the same ``t_ms`` form one sample; a sample is complete when every sensor
has reported or a later ``t_ms`` arrives (sensors that did not report are missing:
NaN). Anything else — wrong field count, non-numbers, NaN or ±inf, an unknown
sensor, a time earlier than the current round, a sensor twice in one round, a line
over 256 bytes, bytes that are not ASCII — is counted and skipped, never fatal.

Samples are resampled to the graph's rate (linear interpolation on the grid t0 +
k/rate from the first streamed sample; gaps longer than 0.5 s stay missing instead
of being bridged) and streamed to the server.

Static calibration (``--calibrate-seconds S``): for the first S seconds the subject
stands still in the graph skeleton's rest pose (a T-pose for the procedural and CMU
skeletons). Each sensor's constant bias is estimated as its mean reading over that
window minus the reading the graph expects in the rest pose, gravity only
(GraphInfo.rest_pose_accelerations_m_s2), and subtracted from every later reading.
Why a bias and not a rotation: from one static pose, a constant offset and a small
mounting misalignment cannot be told apart (both move the mean gravity vector);
a per-axis offset is the simplest correction that makes the still reading exact, it
is what cheap MEMS accelerometers drift by, and it needs no assumption about the
mounting. The calibration window itself is not streamed. A sensor that moved during
the window (per-axis σ above 0.5 m/s²), or whose mean is far from 1 g (wrong
``--units``?), is reported; one without readings in the window is left uncorrected.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.sensors.calibration import calibrate_sample
from graphsvc.service import client
from graphsvc.service.convert_recording import sample_to_proto

LINE_MAX_BYTES = 256  # longer without a newline: noise or a wrong baud rate
MAX_GAP_S = 0.5  # resampling does not interpolate across a longer silence
STILL_SIGMA_M_S2 = 0.5  # per-axis σ above which a sensor was not still during calibration
ONE_G_TOLERANCE_M_S2 = 1.5  # |mean| farther than this from 1 g: not gravity alone
UNITS = {"m/s2": 1.0, "g": GRAVITY}


class CorruptLine(ValueError):
    """A line the protocol cannot use; the message is the reason (counted per reason)."""


def parse_line(text: str, sensor_ids: dict[str, int], num_sensors: int, scale: float) -> tuple[float, int, np.ndarray]:
    """ "t_ms,sensor_id,ax,ay,az" → (t_ms, sensor index, (3,) m/s²). scale: m/s² per
    input unit. Raises CorruptLine."""
    fields = [f.strip() for f in text.split(",")]
    if len(fields) != 5:
        raise CorruptLine("wrong field count")
    try:
        values = [float(fields[0]), float(fields[2]), float(fields[3]), float(fields[4])]
    except ValueError:
        raise CorruptLine("not a number") from None
    if not all(math.isfinite(v) for v in values):
        raise CorruptLine("NaN or infinite value")
    ident = fields[1]
    if ident in sensor_ids:
        sensor = sensor_ids[ident]
    else:
        try:
            sensor = int(ident)
        except ValueError:
            raise CorruptLine("unknown sensor") from None
        if not 0 <= sensor < num_sensors:
            raise CorruptLine("unknown sensor")
    return values[0], sensor, np.array(values[1:], np.float64) * scale


class SampleAssembler:
    """Groups per-sensor readings of one t_ms into (t_s, acc (S, 3) m/s², NaN for
    sensors that did not report)."""

    def __init__(self, num_sensors: int):
        self.S = num_sensors
        self.t_ms: float | None = None
        self.acc = np.full((num_sensors, 3), np.nan)
        self.seen = np.zeros(num_sensors, bool)
        self.last_emitted_ms = -math.inf
        self.incomplete = 0  # samples emitted with sensors missing

    def add(self, t_ms: float, sensor: int, xyz: np.ndarray) -> list[tuple[float, np.ndarray]]:
        if t_ms <= self.last_emitted_ms or (self.t_ms is not None and t_ms < self.t_ms):
            raise CorruptLine("time out of order")
        out = []
        if self.t_ms is not None and t_ms > self.t_ms:
            out.append(self._emit())
        if self.t_ms is None:
            self.t_ms = t_ms
        if self.seen[sensor]:
            raise CorruptLine("sensor twice in one sample")
        self.acc[sensor] = xyz
        self.seen[sensor] = True
        if self.seen.all():
            out.append(self._emit())
        return out

    def finish(self) -> list[tuple[float, np.ndarray]]:
        return [self._emit()] if self.t_ms is not None else []

    def _emit(self) -> tuple[float, np.ndarray]:
        sample = (self.t_ms / 1000.0, self.acc)
        if not self.seen.all():
            self.incomplete += 1
        self.last_emitted_ms = self.t_ms
        self.t_ms = None
        self.acc = np.full((self.S, 3), np.nan)
        self.seen[:] = False
        return sample


class Resampler:
    """Samples at any times → samples on the grid t0 + k/rate_hz (t0: the first
    sample's time), linearly interpolated; NaN at either neighbour stays NaN; ticks
    inside a gap longer than MAX_GAP_S are all-NaN (missing), not interpolated."""

    def __init__(self, rate_hz: float):
        self.rate = float(rate_hz)
        self.t0: float | None = None
        self.k = 0
        self.prev: tuple[float, np.ndarray] | None = None

    def add(self, t: float, acc: np.ndarray) -> list[tuple[float, np.ndarray]]:
        out = []
        if self.t0 is None:
            self.t0, self.k = t, 1
            out.append((t, acc))
        else:
            t_prev, acc_prev = self.prev
            while True:
                # The same expression LiveSession uses for its grid, so these samples
                # land on it exactly and are not resampled a second time.
                tick = self.t0 + self.k / self.rate
                if tick > t + 1e-9:
                    break
                if abs(tick - t) < 1e-9:
                    out.append((tick, acc))
                elif t - t_prev > MAX_GAP_S:
                    out.append((tick, np.full_like(acc, np.nan)))
                else:
                    w = (tick - t_prev) / (t - t_prev)
                    out.append((tick, acc_prev * (1.0 - w) + acc * w))
                self.k += 1
        self.prev = (t, acc)
        return out


class StaticCalibration:
    """Per-sensor constant bias from a still rest pose held for `seconds` (see the
    module docstring). expected: (S, 3) m/s², the graph's rest-pose readings."""

    def __init__(self, seconds: float, expected: np.ndarray, sensor_names: tuple[str, ...]):
        self.seconds = float(seconds)
        self.expected = np.asarray(expected, np.float64).reshape(-1, 3)
        self.names = sensor_names
        S = self.expected.shape[0]
        self.t0: float | None = None
        self.sum = np.zeros((S, 3))
        self.sum_sq = np.zeros((S, 3))
        self.count = np.zeros((S, 1))
        self.bias = np.zeros((S, 3))
        self.done = self.seconds <= 0
        self.warnings: list[str] = []
        self.samples = 0

    def add(self, t: float, acc: np.ndarray) -> bool:
        """Take a raw sample; True while it belongs to the calibration window."""
        if self.done:
            return False
        if self.t0 is None:
            self.t0 = t
        if t - self.t0 >= self.seconds:
            self.finish()
            return False
        ok = np.isfinite(acc).all(axis=1)
        self.sum[ok] += acc[ok]
        self.sum_sq[ok] += acc[ok] ** 2
        self.count[ok] += 1
        self.samples += 1
        return True

    def finish(self) -> None:
        if self.done:
            return
        self.done = True
        n = np.maximum(self.count, 1)
        mean = self.sum / n
        sigma = np.sqrt(np.maximum(self.sum_sq / n - mean**2, 0.0))
        for s, name in enumerate(self.names):
            if self.count[s, 0] < 3:
                self.warnings.append(f"{name}: too few readings in the calibration window; left uncorrected")
                continue
            if not np.isfinite(self.expected[s]).all():
                self.warnings.append(f"{name}: the graph gives no rest-pose reading; left uncorrected")
                continue
            if sigma[s].max() > STILL_SIGMA_M_S2:
                self.warnings.append(f"{name}: moved during calibration (σ {sigma[s].max():.2f} m/s²)")
            if abs(np.linalg.norm(mean[s]) - GRAVITY) > ONE_G_TOLERANCE_M_S2:
                self.warnings.append(f"{name}: mean reading {np.linalg.norm(mean[s]):.2f} m/s² is not 1 g (--units?)")
            self.bias[s] = mean[s] - self.expected[s]

    def apply(self, acc: np.ndarray) -> np.ndarray:
        return acc - self.bias


@dataclass
class BridgeStats:
    lines: int = 0
    corrupt: dict = field(default_factory=dict)  # reason → count
    device_samples: int = 0  # assembled from lines
    incomplete_samples: int = 0  # ... with at least one sensor missing
    calibration_samples: int = 0
    samples_streamed: int = 0  # at the graph rate
    first_device_t_s: float | None = None
    last_device_t_s: float | None = None

    @property
    def corrupt_lines(self) -> int:
        return sum(self.corrupt.values())


class LineProtocol:
    """Bytes from the device → graph-rate samples (t_s, acc (S, 3) m/s²) ready to
    stream: line splitting, parsing, grouping, calibration, resampling."""

    def __init__(
        self,
        sensor_names: tuple[str, ...],
        rate_hz: float,
        units: str = "m/s2",
        calibration: StaticCalibration | None = None,
        mounting: np.ndarray | None = None,
    ):
        if units not in UNITS:
            raise ValueError(f"units must be one of {', '.join(UNITS)}, got {units!r}")
        self.names = tuple(sensor_names)
        self.ids = {n: i for i, n in enumerate(self.names)}
        self.scale = UNITS[units]
        self.assembler = SampleAssembler(len(self.names))
        self.resampler = Resampler(rate_hz)
        self.calibration = calibration
        self.mounting = mounting  # (S, 4): device frame → the layout's (`sensors.calibration`), or None
        self.stats = BridgeStats()
        self._buffer = bytearray()
        self._skipping = False  # inside an over-long line: drop bytes up to its newline

    def _corrupt(self, reason: str) -> None:
        self.stats.corrupt[reason] = self.stats.corrupt.get(reason, 0) + 1

    def push_bytes(self, data: bytes) -> list[tuple[float, np.ndarray]]:
        self._buffer += data
        out = []
        while True:
            i = self._buffer.find(b"\n")
            if i < 0:
                if len(self._buffer) > LINE_MAX_BYTES:
                    if not self._skipping:
                        self.stats.lines += 1
                        self._corrupt("line too long")
                    self._skipping = True
                    self._buffer.clear()
                return out
            line = bytes(self._buffer[:i])
            del self._buffer[: i + 1]
            if self._skipping:
                self._skipping = False
                continue
            if len(line) > LINE_MAX_BYTES:
                self.stats.lines += 1
                self._corrupt("line too long")
                continue
            out += self.push_line(line)

    def push_line(self, raw: bytes) -> list[tuple[float, np.ndarray]]:
        try:
            text = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            self.stats.lines += 1
            self._corrupt("not ASCII")
            return []
        if not text or text.startswith("#"):
            return []
        self.stats.lines += 1
        try:
            t_ms, sensor, xyz = parse_line(text, self.ids, len(self.names), self.scale)
            samples = self.assembler.add(t_ms, sensor, xyz)
        except CorruptLine as exc:
            self._corrupt(str(exc))
            return []
        return self._process(samples)

    def finish(self) -> list[tuple[float, np.ndarray]]:
        """The samples still held at the end of input (a trailing partial line is
        dropped as corrupt)."""
        if self._buffer.strip() and not self._skipping:
            self.stats.lines += 1
            self._corrupt("unterminated last line")
        self._buffer.clear()
        out = self._process(self.assembler.finish())
        if self.calibration is not None:
            self.calibration.finish()
        return out

    def _process(self, samples) -> list[tuple[float, np.ndarray]]:
        out = []
        for t, acc in samples:
            st = self.stats
            st.device_samples += 1
            st.incomplete_samples = self.assembler.incomplete
            st.first_device_t_s = t if st.first_device_t_s is None else st.first_device_t_s
            st.last_device_t_s = t
            if self.mounting is not None:
                acc = calibrate_sample(self.mounting, acc)
            if self.calibration is not None:
                if self.calibration.add(t, acc):
                    st.calibration_samples += 1
                    continue
                acc = self.calibration.apply(acc)
            resampled = self.resampler.add(t, acc)
            st.samples_streamed += len(resampled)
            out += resampled
        return out


# ---------------------------------------------------------------- running


@dataclass
class BridgeResult:
    stats: BridgeStats
    stream: object  # client.StreamResult
    calibration: StaticCalibration | None
    end_reason: str


def read_device(port, protocol: LineProtocol, feed, stop: threading.Event, duration_s: float | None = None) -> str:
    """Read `port` (a pyserial Serial or anything with read(n) and in_waiting) until
    the device goes away, `stop` is set or `duration_s` passes; put each graph-rate
    sample into `feed`, then close it. Returns why it ended."""

    def send(samples):
        for t, acc in samples:
            feed.put(sample_to_proto(t, acc))

    start = time.monotonic()
    reason = "stopped"
    try:
        while not stop.is_set():
            if duration_s is not None and time.monotonic() - start >= duration_s:
                reason = "duration reached"
                break
            try:
                data = port.read(max(1, getattr(port, "in_waiting", 0) or 1))
            except Exception as exc:  # noqa: BLE001 — pyserial raises SerialException/OSError on unplug
                reason = f"device closed ({type(exc).__name__})"
                break
            if data:
                send(protocol.push_bytes(data))
        send(protocol.finish())
    finally:
        feed.close()
    return reason


def run_bridge(
    port,
    conn,
    graph_info,
    options,
    units: str = "m/s2",
    calibrate_s: float = 0.0,
    stop: threading.Event | None = None,
    duration_s: float | None = None,
    on_frame=None,
    mounting: np.ndarray | None = None,
) -> BridgeResult:
    """Stream what `port` reports to graph `graph_info` (a GraphInfo) on `conn`
    with SynthesisOptions `options`; returns when the device closes, `stop` is set,
    or `duration_s` passes, after the server has sent the last frames. `mounting` (S,
    4): each sensor's rotation from its device frame into the layout's
    (`sensors.calibration`), applied to every reading first."""
    names = tuple(graph_info.sensor_names)
    calibration = None
    if calibrate_s > 0:
        calibration = StaticCalibration(calibrate_s, np.array(graph_info.rest_pose_accelerations_m_s2), names)
    protocol = LineProtocol(names, graph_info.rate_hz, units, calibration, mounting)
    feed = client.SampleFeed(client.stream_config(graph_info.name, options, names))
    stop = stop or threading.Event()
    ended = {"reason": "stream ended"}

    def reader():
        ended["reason"] = read_device(port, protocol, feed, stop, duration_s)

    thread = threading.Thread(target=reader, name="graphsvc-bridge-reader", daemon=True)
    thread.start()
    try:
        stream = client.run_stream(conn, feed, on_frame)
    finally:
        stop.set()  # the stream failed or ended: stop reading
        thread.join(timeout=5.0)
    return BridgeResult(protocol.stats, stream, calibration, ended["reason"])

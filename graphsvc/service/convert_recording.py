"""Recordings and live samples ↔ protocol buffers: a `Recording` (Synthesize), a
stream's `SensorSample`s and marker names, and the order that puts a request's
sensors into the graph's.

Every `*_from_proto` checks what it reads and raises FieldError naming the field (its
path in the request, e.g. "recording.timestamps_s[12]"), which the server turns into
INVALID_ARGUMENT. Arrays travel flattened row-major in packed repeated fields; their
shapes are in the proto's comments.
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from graphsvc.errors import FieldError, InputError
from graphsvc.sensors.recording import Recording, check_gap, check_rate
from graphsvc.service._generated import graphsvc_pb2 as pb
from graphsvc.strategies.inputs import layout_mismatch_message


def sensor_order(
    given: list[str], graph_names: tuple[str, ...], field: str, layout_name: str = "?"
) -> np.ndarray | None:
    """Indices that put the request's sensor triplets into the graph's order, or None
    when they already are (or no names were given: the graph's order is implied).
    Sensors that are not the layout's are refused with the CLI's line naming them."""
    given = list(given)
    if not given or tuple(given) == tuple(graph_names):
        return None
    message = layout_mismatch_message(layout_name, graph_names, given, order_matters=False)
    if message is not None:
        raise FieldError(field, message)
    return np.array([given.index(n) for n in graph_names], np.int64)


def _check_no_inf(field: str, values: np.ndarray, per_item: int) -> None:
    bad = np.isinf(values)
    if bad.any():
        k = int(np.argmax(bad))
        raise FieldError(f"{field}[{k}]", f"infinite value (sample {k // per_item}; use NaN for missing)")


def recording_to_proto(rec: Recording) -> pb.Recording:
    msg = pb.Recording(rate_hz=float(rec.rate_hz), sensor_names=list(rec.sensor_names))
    msg.timestamps_s.extend(np.asarray(rec.timestamps_s, np.float64).tolist())
    if rec.accelerations is not None:
        msg.accelerations_m_s2.extend(np.asarray(rec.accelerations, np.float32).ravel().tolist())
    if rec.orientations is not None:
        msg.orientations_wxyz.extend(np.asarray(rec.orientations, np.float32).ravel().tolist())
    if rec.marker_positions is not None:
        msg.marker_names.extend(rec.marker_names)
        msg.marker_positions_m.extend(np.asarray(rec.marker_positions, np.float64).ravel().tolist())
    if rec.ground_position is not None:
        msg.ground_positions_m.extend(np.asarray(rec.ground_position, np.float64).ravel().tolist())
    if rec.heading is not None:
        msg.headings_rad.extend(np.asarray(rec.heading, np.float64).tolist())
    return msg


def recording_from_proto(
    msg: pb.Recording,
    graph_names: tuple[str, ...],
    field: str = "recording",
    match_layout: bool = True,
    layout_name: str = "?",
) -> Recording:
    """A validated Recording with the sensors in the graph's order. Checks shapes,
    finiteness (NaN = missing is allowed in readings, never in times) and order.
    match_layout False (a strategy that reads no accelerations): the sensors are
    whatever the recording names (the graph's when it names none), in its order."""
    rate = msg.rate_hz
    try:
        check_rate(rate, "rate")
    except InputError as exc:
        raise FieldError(f"{field}.rate_hz", str(exc)) from None
    t = np.array(msg.timestamps_s, np.float64)
    T = t.shape[0]
    if T == 0:
        raise FieldError(f"{field}.timestamps_s", "no samples")
    _check_times(t, f"{field}.timestamps_s")
    if match_layout:
        order = sensor_order(msg.sensor_names, graph_names, f"{field}.sensor_names", layout_name)
    else:
        order, graph_names = None, tuple(msg.sensor_names) or tuple(graph_names)
    S = len(graph_names)
    acc = _per_sensor(msg.accelerations_m_s2, T, S, 3, f"{field}.accelerations_m_s2", order, graph_names)
    orientations = _per_sensor(msg.orientations_wxyz, T, S, 4, f"{field}.orientations_wxyz", order, graph_names)
    marker_names, markers = tuple(msg.marker_names), None
    if len(msg.marker_positions_m) or marker_names:
        M = len(marker_names)
        markers = np.array(msg.marker_positions_m, np.float64)
        if markers.shape[0] != T * M * 3:
            raise FieldError(
                f"{field}.marker_positions_m",
                f"expected T×M×3 = {T}×{M}×3 = {T * M * 3} values "
                f"({T} timestamps, {M} marker names), got {markers.shape[0]}",
            )
        _check_no_inf(f"{field}.marker_positions_m", markers, 3)
        markers = markers.reshape(T, M, 3)
    position = heading = None
    if len(msg.ground_positions_m):
        position = np.array(msg.ground_positions_m, np.float64)
        if position.shape[0] != 2 * T:
            raise FieldError(
                f"{field}.ground_positions_m", f"expected 0 or T×2 = {2 * T} values, got {position.shape[0]}"
            )
        _check_no_inf(f"{field}.ground_positions_m", position, 2)
        position = position.reshape(T, 2)
    if len(msg.headings_rad):
        heading = np.array(msg.headings_rad, np.float64)
        if heading.shape[0] != T:
            raise FieldError(f"{field}.headings_rad", f"expected 0 or T = {T} values, got {heading.shape[0]}")
        _check_no_inf(f"{field}.headings_rad", heading, 1)
    rec = Recording(
        rate_hz=float(rate),
        timestamps_s=t,
        sensor_names=tuple(graph_names),
        accelerations=acc,
        ground_position=position,
        heading=heading,
        meta={"source": "grpc"},
        orientations=orientations,
        marker_names=marker_names,
        marker_positions=markers,
    )
    try:
        rec.validate()
    except InputError as exc:  # anything the checks above missed still names the message
        raise FieldError(field, str(exc)) from None
    return rec


def _per_sensor(values, T: int, S: int, width: int, field: str, order, names=()) -> np.ndarray | None:
    """(T, S, width) float32 in the graph's sensor order from a flat proto field, None
    when it is empty."""
    a = np.array(values, np.float32)
    if a.shape[0] == 0:
        return None
    if a.shape[0] != T * S * width:
        raise FieldError(
            field,
            f"expected T×S×{width} = {T}×{S}×{width} = {T * S * width} values "
            f"({T} timestamps, {S} sensors{': ' if names else ''}{', '.join(names)}), got {a.shape[0]}",
        )
    _check_no_inf(field, a, S * width)
    a = a.reshape(T, S, width)
    return np.ascontiguousarray(a[:, order]) if order is not None else a


def _check_times(t: np.ndarray, field: str) -> None:
    bad = ~np.isfinite(t)
    if bad.any():
        k = int(np.argmax(bad))
        raise FieldError(f"{field}[{k}]", f"not a finite number of seconds ({t[k]})")
    steps = np.diff(t)
    if (steps <= 0).any():
        k = int(np.argmax(steps <= 0)) + 1
        raise FieldError(
            f"{field}[{k}]",
            f"{t[k]!r} s is not after the previous timestamp {t[k - 1]!r} s (timestamps must strictly increase)",
        )


def sample_to_proto(
    time_s: float, acc: np.ndarray | None, position=None, heading=None, markers=None, orientations=None
) -> pb.SensorSample:
    """acc (S, 3) m/s² NaN = missing, or None (a marker-only sample); position (2,) m
    or None; heading rad or None; markers (M, 3) m for the stream's marker names, NaN =
    not seen, or None; orientations (S, 4) w, x, y, z, NaN = missing, or None."""
    msg = pb.SensorSample(time_s=float(time_s))
    if acc is not None:
        msg.accelerations_m_s2.extend(np.asarray(acc, np.float32).ravel().tolist())
    if position is not None:
        msg.ground_position.x_m, msg.ground_position.z_m = (float(position[0]), float(position[1]))
    if heading is not None:
        msg.heading_rad = float(heading)
    if markers is not None:
        msg.marker_positions_m.extend(np.asarray(markers, np.float64).ravel().tolist())
    if orientations is not None:
        msg.orientations_wxyz.extend(np.asarray(orientations, np.float32).ravel().tolist())
    return msg


def sample_orientations_from_proto(
    msg: pb.SensorSample, num_sensors: int, order: np.ndarray | None, expected: bool, field: str
) -> np.ndarray | None:
    """The sample's orientations (S, 4) float64 (w, x, y, z; NaN = missing) in the
    graph's sensor order when the stream's config says samples carry them, else None;
    checked: S×4 values, no ±inf, none where the config announced none."""
    values = np.array(msg.orientations_wxyz, np.float64)
    name = f"{field}.orientations_wxyz"
    if not expected:
        if values.size:
            raise FieldError(name, "the stream's config.orientations is not set: samples carry no orientations")
        return None
    if values.shape[0] != 4 * num_sensors:
        raise FieldError(
            name,
            f"expected S×4 = {4 * num_sensors} values for the graph's {num_sensors} sensors, got {values.shape[0]}",
        )
    if np.isinf(values).any():
        raise FieldError(f"{name}[{int(np.argmax(np.isinf(values)))}]", "infinite value (use NaN for missing)")
    q = values.reshape(num_sensors, 4)
    return q if order is None else q[order]


def sample_from_proto(
    msg: pb.SensorSample,
    num_sensors: int,
    order: np.ndarray | None,
    previous_time_s: float | None,
    field: str,
    reads_acc: bool = True,
) -> tuple[float, np.ndarray | None, np.ndarray | None, float | None]:
    """(time_s, acc (S, 3) float64 m/s², position (2,) m or None, heading rad or
    None) in the graph's sensor order, checked: finite time after the previous one,
    S×3 readings with no ±inf, finite-or-NaN position and heading. reads_acc False (a
    strategy that reads no accelerations): the readings may be absent (acc None)."""
    t = msg.time_s
    if not math.isfinite(t):
        raise FieldError(f"{field}.time_s", f"not a finite number of seconds ({t})")
    if previous_time_s is not None and not t > previous_time_s:
        raise FieldError(
            f"{field}.time_s",
            f"{t!r} s is not after the previous sample's {previous_time_s!r} s (times must strictly increase)",
        )
    if previous_time_s is not None:
        try:
            check_gap(previous_time_s, t)
        except InputError as exc:
            raise FieldError(f"{field}.time_s", str(exc)) from None
    acc = np.array(msg.accelerations_m_s2, np.float64)
    if acc.shape[0] == 0 and not reads_acc:
        acc = None
    else:
        acc = _triplets(
            acc,
            num_sensors,
            f"{field}.accelerations_m_s2",
            f"S×3 = {3 * num_sensors} values for the graph's {num_sensors} sensors{'' if reads_acc else ' (or none)'}",
            "missing",
        )
        if order is not None:
            acc = acc[order]
    position = None
    if msg.HasField("ground_position"):
        position = np.array([msg.ground_position.x_m, msg.ground_position.z_m], np.float64)
        if np.isinf(position).any():
            raise FieldError(f"{field}.ground_position", "infinite value (use NaN for missing)")
    heading = None
    if msg.HasField("heading_rad"):
        heading = float(msg.heading_rad)
        if math.isinf(heading):
            raise FieldError(f"{field}.heading_rad", "infinite value (use NaN for missing)")
    return float(t), acc, position, heading


def sample_markers_from_proto(msg: pb.SensorSample, num_markers: int, field: str) -> np.ndarray | None:
    """The sample's marker positions (M, 3) float64 m (NaN = not seen) for the stream's
    M marker names, None when it names none; checked: M×3 values, no ±inf."""
    markers = _triplets(
        np.array(msg.marker_positions_m, np.float64),
        num_markers,
        f"{field}.marker_positions_m",
        f"M×3 = {3 * num_markers} values for the {num_markers} markers of config.marker_names",
        "not seen",
    )
    return markers if num_markers else None


def _triplets(values: np.ndarray, count: int, field: str, expected: str, unseen: str) -> np.ndarray:
    """(count, 3) from a sample's flat values, checked: `count` triplets (else the error
    says `expected`), no ±inf (NaN is `unseen`)."""
    if values.shape[0] != 3 * count:
        raise FieldError(field, f"expected {expected}, got {values.shape[0]}")
    if np.isinf(values).any():
        k = int(np.argmax(np.isinf(values)))
        raise FieldError(f"{field}[{k}]", f"infinite value (use NaN for {unseen})")
    return values.reshape(count, 3)


def marker_names_from_proto(names, field: str) -> tuple[str, ...]:
    """A stream's marker names, checked as a Recording's: non-empty, no commas, quotes,
    newlines or edge spaces, distinct."""
    names = tuple(names)
    for i, n in enumerate(names):
        if not n or n != n.strip() or set(n) & set(',"\r\n'):
            raise FieldError(
                f"{field}[{i}]", f"bad marker name {n!r} (non-empty, no commas, quotes, newlines or edge spaces)"
            )
    if len(set(names)) != len(names):
        dup = sorted(n for n, c in Counter(names).items() if c > 1)
        raise FieldError(
            field, f"duplicate marker names: {', '.join(dup[:8])}" + (f" … (+{len(dup) - 8})" if len(dup) > 8 else "")
        )
    return names

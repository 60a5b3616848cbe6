"""Protocol buffers ↔ numpy arrays, Recordings, Motions (and, from
`service.options_proto`, the options).

Every `*_from_proto` checks what it reads and raises FieldError naming the field
(its path in the request, e.g. "recording.timestamps_s[12]"), which the server turns
into INVALID_ARGUMENT. Arrays travel flattened row-major in packed repeated fields;
their shapes are in the proto's comments.
"""

from __future__ import annotations

import json
import math
from collections import Counter

import numpy as np

from graphsvc.errors import FieldError, InputError
from graphsvc.graph.model import MotionGraph, summary
from graphsvc.motion.skeleton import Motion, Skeleton
from graphsvc.sensors.recording import Recording, check_gap, check_rate
from graphsvc.service._generated import graphsvc_pb2 as pb
from graphsvc.service.options_proto import (  # noqa: F401  (the options' conversions, named here too)
    constraints_from_proto, constraints_to_proto, for_recording, options_from_proto, options_to_proto)



# ---------------------------------------------------------------- skeleton and graph


def skeleton_to_proto(sk: Skeleton) -> pb.Skeleton:
    return pb.Skeleton(
        joint_names=list(sk.names),
        parent_indices=[int(p) for p in sk.parents],
        offsets_m=np.asarray(sk.offsets, np.float64).ravel().tolist(),
        channels=[pb.JointChannels(names=list(c)) for c in sk.channels],
        end_sites=[bool(e) for e in sk.end_site],
    )


def skeleton_from_proto(msg: pb.Skeleton) -> Skeleton:
    J = len(msg.joint_names)
    if not (len(msg.parent_indices) == len(msg.channels) == len(msg.end_sites) == J and len(msg.offsets_m) == 3 * J):
        raise FieldError("skeleton", f"arrays disagree with {J} joint names")
    return Skeleton(tuple(msg.joint_names), np.array(msg.parent_indices, np.int64),
                    np.array(msg.offsets_m, np.float64).reshape(J, 3), tuple(tuple(c.names) for c in msg.channels),
                    np.array(msg.end_sites, bool))  # fmt: skip


def rest_pose_readings(graph: MotionGraph) -> np.ndarray:
    """(S, 3) float32 m/s²: each layout sensor's reading while graph.skeleton stands
    still in its rest pose (all local rotations identity) — gravity only. NaN when
    the layout cannot be placed on the skeleton (an unknown skeleton without the
    mapping it was built with)."""
    from graphsvc.errors import GraphsvcError
    from graphsvc.motion.kinematics import forward_kinematics
    from graphsvc.sensors.accelerometer import simulate_accelerations
    from graphsvc.graph.metadata import graph_placement

    sk = graph.skeleton
    S = len(graph.sensor_names)
    try:
        placement = graph_placement(graph)
    except GraphsvcError:
        return np.full((S, 3), np.nan, np.float32)
    frames = 5  # the derivative stencil needs a few frames; a held pose has p̈ = 0
    rot = np.zeros((frames, sk.num_joints, 4))
    rot[..., 0] = 1.0
    trans = np.broadcast_to(sk.offsets, (frames, sk.num_joints, 3)).copy()
    world_rot, world_pos = forward_kinematics(rot, trans, sk.parents)
    return simulate_accelerations(world_rot, world_pos, placement, graph.rate_hz)[frames // 2].astype(np.float32)


def graph_info(name: str, graph: MotionGraph, file_bytes: int | None) -> pb.GraphInfo:
    """GraphInfo: graphsvc.graph.model.summary plus params, skeleton and rest readings."""
    s = summary(graph, file_bytes)
    info = pb.GraphInfo(
        name=name,
        node_count=s["nodes"],
        edge_count=s["edges"],
        node_counts_by_kind=s["nodes_by_kind"],
        edge_counts_by_kind=s["edges_by_kind"],
        dead_end_count=s["dead_ends"],
        clip_count=s["clips"],
        kb_frame_count=s["kb_frames"],
        kb_minutes=s["kb_minutes"],
        labels=s["labels"],
        layout=str(s["layout"]),
        sensor_names=s["sensors"],
        rate_hz=s["rate_hz"],
        joint_count=s["joints"],
        interpolated_segment_count=s["interpolated_segments"],
        bridge_count=s["bridges"],
        sensor_orientations=s["sensor_orientations"],
        file_bytes=s.get("file_bytes", 0),
        skeleton=skeleton_to_proto(graph.skeleton),
        rest_pose_accelerations_m_s2=rest_pose_readings(graph).ravel().tolist(),
    )
    info.params.update(json_safe(graph.params))
    return info


def graph_info_dict(info: pb.GraphInfo) -> dict:
    """GraphInfo → the dict `graphsvc info --json` prints (keys of model.summary plus
    "params"), for `graphsvc client graphs` to print the same way."""
    from google.protobuf.json_format import MessageToDict

    return {
        "nodes": info.node_count,
        "edges": info.edge_count,
        "nodes_by_kind": dict(info.node_counts_by_kind),
        "edges_by_kind": dict(info.edge_counts_by_kind),
        "dead_ends": info.dead_end_count,
        "clips": info.clip_count,
        "kb_frames": info.kb_frame_count,
        "kb_minutes": info.kb_minutes,
        "labels": list(info.labels),
        "layout": info.layout,
        "sensors": list(info.sensor_names),
        "rate_hz": info.rate_hz,
        "joints": info.joint_count,
        "interpolated_segments": info.interpolated_segment_count,
        "bridges": info.bridge_count,
        "sensor_orientations": info.sensor_orientations,
        "file_bytes": info.file_bytes,
        "params": MessageToDict(info.params),
    }


def json_safe(value):
    """A JSON-able copy for google.protobuf.Struct: numpy scalars and arrays become
    Python numbers and lists, NaN and ±inf become None (Struct cannot print them)."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if value is None or isinstance(value, str):
        return value
    return str(value)


# ---------------------------------------------------------------- sensors


def sensor_order(given: list[str], graph_names: tuple[str, ...], field: str, layout_name: str = "?") -> np.ndarray | None:
    """Indices that put the request's sensor triplets into the graph's order, or None
    when they already are (or no names were given: the graph's order is implied).
    Sensors that are not the layout's are refused with the CLI's line naming them."""
    from graphsvc.strategies.inputs import layout_mismatch_message

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


def recording_from_proto(msg: pb.Recording, graph_names: tuple[str, ...], field: str = "recording",
                         match_layout: bool = True, layout_name: str = "?") -> Recording:  # fmt: skip
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
            raise FieldError(f"{field}.marker_positions_m", f"expected T×M×3 = {T}×{M}×3 = {T * M * 3} values "
                             f"({T} timestamps, {M} marker names), got {markers.shape[0]}")  # fmt: skip
        _check_no_inf(f"{field}.marker_positions_m", markers, 3)
        markers = markers.reshape(T, M, 3)
    position = heading = None
    if len(msg.ground_positions_m):
        position = np.array(msg.ground_positions_m, np.float64)
        if position.shape[0] != 2 * T:
            raise FieldError(f"{field}.ground_positions_m", f"expected 0 or T×2 = {2 * T} values, got {position.shape[0]}")
        _check_no_inf(f"{field}.ground_positions_m", position, 2)
        position = position.reshape(T, 2)
    if len(msg.headings_rad):
        heading = np.array(msg.headings_rad, np.float64)
        if heading.shape[0] != T:
            raise FieldError(f"{field}.headings_rad", f"expected 0 or T = {T} values, got {heading.shape[0]}")
        _check_no_inf(f"{field}.headings_rad", heading, 1)
    rec = Recording(rate_hz=float(rate), timestamps_s=t, sensor_names=tuple(graph_names), accelerations=acc,
                    ground_position=position, heading=heading, meta={"source": "grpc"}, orientations=orientations,
                    marker_names=marker_names, marker_positions=markers)  # fmt: skip
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
        raise FieldError(field, f"expected T×S×{width} = {T}×{S}×{width} = {T * S * width} values "
                         f"({T} timestamps, {S} sensors{': ' if names else ''}{', '.join(names)}), got {a.shape[0]}")  # fmt: skip
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
        raise FieldError(f"{field}[{k}]", f"{t[k]!r} s is not after the previous timestamp {t[k - 1]!r} s "
                         "(timestamps must strictly increase)")  # fmt: skip


def sample_to_proto(time_s: float, acc: np.ndarray | None, position=None, heading=None,
                    markers=None, orientations=None) -> pb.SensorSample:  # fmt: skip
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


def sample_orientations_from_proto(msg: pb.SensorSample, num_sensors: int, order: np.ndarray | None, expected: bool,
                                   field: str) -> np.ndarray | None:  # fmt: skip
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
        raise FieldError(name, f"expected S×4 = {4 * num_sensors} values for the graph's {num_sensors} sensors, "
                               f"got {values.shape[0]}")  # fmt: skip
    if np.isinf(values).any():
        raise FieldError(f"{name}[{int(np.argmax(np.isinf(values)))}]", "infinite value (use NaN for missing)")
    q = values.reshape(num_sensors, 4)
    return q if order is None else q[order]


def sample_from_proto(msg: pb.SensorSample, num_sensors: int, order: np.ndarray | None, previous_time_s: float | None,
                      field: str, reads_acc: bool = True,
                      ) -> tuple[float, np.ndarray | None, np.ndarray | None, float | None]:  # fmt: skip
    """(time_s, acc (S, 3) float64 m/s², position (2,) m or None, heading rad or
    None) in the graph's sensor order, checked: finite time after the previous one,
    S×3 readings with no ±inf, finite-or-NaN position and heading. reads_acc False (a
    strategy that reads no accelerations): the readings may be absent (acc None)."""
    t = msg.time_s
    if not math.isfinite(t):
        raise FieldError(f"{field}.time_s", f"not a finite number of seconds ({t})")
    if previous_time_s is not None and not t > previous_time_s:
        raise FieldError(f"{field}.time_s", f"{t!r} s is not after the previous sample's {previous_time_s!r} s "
                         "(times must strictly increase)")  # fmt: skip
    if previous_time_s is not None:
        try:
            check_gap(previous_time_s, t)
        except InputError as exc:
            raise FieldError(f"{field}.time_s", str(exc)) from None
    acc = np.array(msg.accelerations_m_s2, np.float64)
    if acc.shape[0] == 0 and not reads_acc:
        acc = None
    else:
        acc = _triplets(acc, num_sensors, f"{field}.accelerations_m_s2", f"S×3 = {3 * num_sensors} values for the "
                        f"graph's {num_sensors} sensors{'' if reads_acc else ' (or none)'}", "missing")  # fmt: skip
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
    markers = _triplets(np.array(msg.marker_positions_m, np.float64), num_markers, f"{field}.marker_positions_m",
                        f"M×3 = {3 * num_markers} values for the {num_markers} markers of config.marker_names",
                        "not seen")  # fmt: skip
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
            raise FieldError(f"{field}[{i}]", f"bad marker name {n!r} (non-empty, no commas, quotes, newlines or "
                             "edge spaces)")  # fmt: skip
    if len(set(names)) != len(names):
        dup = sorted(n for n, c in Counter(names).items() if c > 1)
        raise FieldError(field, f"duplicate marker names: {', '.join(dup[:8])}" + (f" … (+{len(dup) - 8})" if len(dup) > 8 else ""))
    return names


# ---------------------------------------------------------------- motion and frames


def motion_to_proto(motion: Motion) -> pb.Motion:
    msg = pb.Motion(rate_hz=float(motion.rate_hz), frame_count=motion.num_frames, joint_count=motion.skeleton.num_joints)
    msg.rotations_wxyz.extend(np.asarray(motion.rotations, np.float32).ravel().tolist())
    msg.translations_m.extend(np.asarray(motion.translations, np.float32).ravel().tolist())
    return msg


def motion_from_proto(msg: pb.Motion, skeleton: Skeleton, name: str = "synthesized") -> Motion:
    F, J = msg.frame_count, msg.joint_count
    if J != skeleton.num_joints or len(msg.rotations_wxyz) != F * J * 4 or len(msg.translations_m) != F * J * 3:
        raise FieldError("motion", f"arrays disagree with {F} frames of {J} joints on a {skeleton.num_joints}-joint skeleton")
    rot = np.array(msg.rotations_wxyz, np.float32).reshape(F, J, 4)
    trans = np.array(msg.translations_m, np.float32).reshape(F, J, 3)
    return Motion(skeleton, rot, trans, msg.rate_hz, name=name, source="graphsvc service")


def frame_to_proto(frame, input_sample_index: int) -> pb.PoseFrame:
    """A pipeline.Frame → PoseFrame."""
    msg = pb.PoseFrame(index=int(frame.index), time_s=float(frame.time_s), node=int(frame.node), label=frame.label,
                       input_sample_index=int(input_sample_index))  # fmt: skip
    msg.rotations_wxyz.extend(np.asarray(frame.rotations, np.float32).ravel().tolist())
    msg.translations_m.extend(np.asarray(frame.translations, np.float32).ravel().tolist())
    msg.sources.extend(pb.FrameSource(clip=c, frame=f, weight=w) for c, f, w in frame.sources)
    return msg


def provenance_to_proto(prov) -> pb.Provenance:
    """A strategies.base.Provenance → Provenance."""
    msg = pb.Provenance(sources_per_frame=int(prov.clip.shape[1]))
    msg.clips.extend(np.asarray(prov.clip, np.int64).ravel().tolist())
    msg.frames.extend(np.asarray(prov.frame, np.float64).ravel().tolist())
    msg.weights.extend(np.asarray(prov.weight, np.float64).ravel().tolist())
    msg.labels.extend(str(x) for x in prov.label)
    return msg


def frames_to_motion(frames: list[pb.PoseFrame], skeleton: Skeleton, rate_hz: float, name: str = "synthesized") -> Motion:
    """PoseFrames (any order, consecutive indices) → one Motion."""
    J = skeleton.num_joints
    frames = sorted(frames, key=lambda f: f.index)
    if frames and [f.index for f in frames] != list(range(frames[0].index, frames[0].index + len(frames))):
        raise InputError("pose frames are not consecutive")
    rot = np.array([f.rotations_wxyz for f in frames], np.float32).reshape(len(frames), J, 4)
    trans = np.array([f.translations_m for f in frames], np.float32).reshape(len(frames), J, 3)
    return Motion(skeleton, rot, trans, rate_hz, name=name, source="graphsvc live stream")


def report_to_proto(report: dict, response: pb.SynthesizeResponse) -> None:
    """The report into a SynthesizeResponse: JSON text (report_json, types kept) and
    the Struct (report, every number a double) for clients that read that."""
    safe = json_safe(report)
    response.report_json = json.dumps(safe, sort_keys=True, allow_nan=False)
    response.report.update(safe)


def report_from_proto(response: pb.SynthesizeResponse) -> dict:
    """The report of a SynthesizeResponse with its integers as integers (from
    report_json; a server that sends only the Struct gives its doubles)."""
    if response.report_json:
        try:
            report = json.loads(response.report_json)
        except json.JSONDecodeError as exc:
            raise InputError(f"report_json: not valid JSON ({exc.msg})") from None
        if isinstance(report, dict):
            return report
    return struct_to_dict(response.report)


def struct_to_dict(msg) -> dict:
    from google.protobuf.json_format import MessageToDict

    return MessageToDict(msg)


def batch_status_to_proto(status: dict) -> pb.BatchStatus:
    """A BatchManager status (batch.service) as a BatchStatus."""
    msg = pb.BatchStatus(batch_id=status["batch_id"], state=status["state"], items=status["items"],
                         queued=status["queued"], running=status["running"], done=status["done"],
                         failed=status["failed"], error=status["error"], submitted_unix_s=status["submitted"],
                         folder=status["folder"])  # fmt: skip
    for r in status.get("item_rows", ()):
        res = r["result"] or {}
        msg.item_status.append(pb.BatchItem(output=r["output"], line=r["line"] or 0, state=r["state"],
                                            attempts=r["attempts"] or 0, reason=r["reason"] or "",
                                            seconds=res.get("seconds", 0.0), output_path=r["output_path"] or "",
                                            checksum=r["checksum"] or ""))  # fmt: skip
    return msg

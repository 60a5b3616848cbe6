"""Skeletons and graphs ↔ protocol buffers: `Skeleton`, `GraphInfo` (what ListGraphs
and GetGraph answer, with the rest pose's sensor readings) and the dict
`graphsvc client graphs` prints from it.
"""

from __future__ import annotations

import numpy as np

from graphsvc.errors import FieldError, GraphsvcError
from graphsvc.graph.metadata import graph_placement
from graphsvc.graph.model import MotionGraph, summary
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.motion.skeleton import Skeleton
from graphsvc.sensors.accelerometer import simulate_accelerations
from graphsvc.service._generated import graphsvc_pb2 as pb
from graphsvc.service.convert_report import json_safe


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
    return Skeleton(
        tuple(msg.joint_names),
        np.array(msg.parent_indices, np.int64),
        np.array(msg.offsets_m, np.float64).reshape(J, 3),
        tuple(tuple(c.names) for c in msg.channels),
        np.array(msg.end_sites, bool),
    )


def rest_pose_readings(graph: MotionGraph) -> np.ndarray:
    """(S, 3) float32 m/s²: each layout sensor's reading while graph.skeleton stands
    still in its rest pose (all local rotations identity) — gravity only. NaN when
    the layout cannot be placed on the skeleton (an unknown skeleton without the
    mapping it was built with)."""
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
        kb_original_frame_count=s["kb_frames_original"],
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
        "kb_frames_original": info.kb_original_frame_count,
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

"""Mounting calibration against a graph (`graphsvc calibrate --graph G`): the graph's
readings at normal speed in clip order and the world's vertical in its sensors' frames at
its stored poses, as the `sensors.calibration.Reference` a calibration take's motion is
matched against; the method is `sensors.calibration`'s (module docstring there)."""

from __future__ import annotations

import math

import numpy as np

from graphsvc.errors import InputError
from graphsvc.graph.metadata import clip_placement
from graphsvc.graph.model import EDGE_ORIGINAL
from graphsvc.graph.poses import node_rotations, node_translations
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.sensors.accelerometer import sensor_poses
from graphsvc.sensors.anatomy import REST_POSE
from graphsvc.sensors.calibration import POSES, Reference, calibrate_against, world_vertical
from graphsvc.sensors.layout import layout_from_dict


def calibrate(rec, pose: str, graph=None, start_s: float | None = None, end_s: float | None = None) -> dict:
    """The calibration (the CAL.json document, `sensors.calibration.save_calibration`) of
    a recording's sensors from a calibration take in `pose` (`sensors.calibration.POSES`),
    against `graph`'s readings of similar motion (None: refused, the rotation about
    gravity unknown). InputError when it cannot be done."""
    return calibrate_against(rec, pose, None if graph is None else graph_reference(graph), start_s, end_s)


MAX_FROM_START_S = 3600.0  # (a stream holds its samples until then: bounded; `flags.add_calibrate_from_start_flags`)


def calibrate_from_start(rec, graph, seconds: float, pose: str, hidden_clips=()) -> dict:
    """The calibration (the CAL.json document) of a recording from its own first `seconds`
    — the performer holds `pose` at the start of the take, then moves — against `graph`,
    so that a take needs no separate calibration take (`synthesize
    --calibrate-from-start`). The samples in [0, seconds] stay part of the take: the
    caller reconstructs them unless it cuts them. hidden_clips: names of the graph's
    clips left out of the readings matched (an evaluation that hides clips must not
    calibrate against them). InputError (CalibrationQualityError among them) as
    `calibrate`."""
    if not (isinstance(seconds, (int, float)) and math.isfinite(seconds) and 0 < seconds <= MAX_FROM_START_S):
        raise InputError(
            f"--calibrate-from-start must be a finite number of seconds > 0 and at most "
            f"{MAX_FROM_START_S:g}, got {seconds}"
        )
    if pose not in POSES:
        raise InputError(f"unknown pose {pose!r} (poses: {', '.join(POSES)})")
    return calibrate_against(rec, pose, graph_reference(graph, hidden_clips), None, float(seconds))


def graph_reference(graph, hidden_clips=()) -> Reference:
    """The graph as a calibration's reference: its layout, sensors, rate and sensor-frame
    convention, its readings in clip order (`graph_stream`, without the clips named in
    hidden_clips) and the verticals of the poses it stores (`graph_verticals`)."""
    stream, runs, stream_nodes = graph_stream(graph)
    hidden = {str(n) for n in hidden_clips}
    if hidden:
        names = np.array([str(c.get("name", "")) for c in graph.clips] + [""])
        keep = ~np.isin(names[np.minimum(graph.node_clip[stream_nodes], len(graph.clips))], list(hidden))
        stream, runs, stream_nodes = stream[keep], runs[keep], stream_nodes[keep]
    return Reference(
        layout=graph.layout,
        sensor_names=graph.sensor_names,
        rate_hz=graph.rate_hz,
        sensor_frames=graph.params.get("sensor_frames", REST_POSE),
        readings=stream,
        runs=runs,
        verticals=lambda rows, names: graph_verticals(graph, stream_nodes[rows], names),
    )


def graph_stream(graph) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The graph's readings at normal speed in clip order: (N, S, 3) float64 (the
    original edges, by clip then frame), (N,) int64 run ids (a new id wherever the
    clip changes or a frame is skipped) and (N,) the edges' destination nodes."""
    edges = np.flatnonzero(graph.edge_kind == EDGE_ORIGINAL)
    dst = graph.edge_dst[edges]
    clip = graph.node_clip[dst].astype(np.int64)
    frame = graph.node_frame[dst].astype(np.float64)
    order = np.lexsort((frame, clip))
    edges, clip, frame = edges[order], clip[order], frame[order]
    brk = np.ones(edges.size, dtype=bool)
    brk[1:] = (clip[1:] != clip[:-1]) | (np.abs(frame[1:] - frame[:-1] - 1.0) > 1e-3)
    return np.asarray(graph.edge_acc[edges], dtype=np.float64), np.cumsum(brk) - 1, graph.edge_dst[edges]


def graph_verticals(graph, nodes: np.ndarray, names) -> np.ndarray:
    """(len(nodes), S, 3) the world's vertical (a unit vector) in the layout's frame of
    sensors `names` at original nodes `nodes`, from the poses the graph stores (each
    clip's skeleton placing the sensors, as `graph.metadata.recompute_accelerations`)."""
    layout = layout_from_dict(graph.layout)
    sk = graph.skeleton
    cols = [layout.sensor_names.index(n) for n in names]
    out = np.zeros((nodes.size, len(names), 3))
    clips = graph.node_clip[nodes]
    for c in np.unique(clips):
        pick = np.flatnonzero(clips == c)
        world_rot, world_pos = forward_kinematics(
            node_rotations(graph, nodes[pick]),
            node_translations(graph, nodes[pick]),
            sk.parents,
        )
        placement = clip_placement(graph, layout, int(c))
        _, orientation = sensor_poses(world_rot, world_pos, placement)
        out[pick] = world_vertical(orientation)[:, cols]
    return out

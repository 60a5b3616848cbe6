"""Measured orientations in the refinement: the cue joins its query, and each segment
whose sensor's orientation relative to the root is measured gets it
(`synthesis.sensor_orientations`)."""

from __future__ import annotations

import numpy as np
import pytest

from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.motion import quat
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.pipeline import Options, reconstruct
from graphsvc.sensors.accelerometer import sensor_poses
from graphsvc.sensors.layout import PRESETS, layout_from_dict, root_sensor
from graphsvc.sensors.noise import parse_noise
from graphsvc.sensors.orientation import relative_orientations
from graphsvc.sensors.simulate import simulate_recording
from graphsvc.strategies.options import Weights
from graphsvc.synthesis.sensor_orientations import cue_rotations, impose_sensor_orientations, world_rotations


def _angle_deg(a, b):
    return np.degrees(2.0 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=-1)), 0.0, 1.0)))


def test_cue_rotations_give_back_the_relative_rotation():
    rng = np.random.default_rng(4)
    q = quat.normalize(rng.normal(size=(20, 3, 4)))
    rel = relative_orientations(q, 0)
    back = cue_rotations(rel)
    # H⁻¹·R_s by another route: quaternions, the twist undone by its conjugate
    from graphsvc.sensors.orientation import heading_twist

    want = quat.mul(quat.conjugate(heading_twist(q[:, :1])), q)
    assert np.all(_angle_deg(back, want) < 1e-4)
    rel[3, 1] = np.nan
    assert np.isnan(cue_rotations(rel)[3, 1]).all() and np.isfinite(cue_rotations(rel)[3, 2]).all()


def test_a_rigid_sensor_gets_its_measured_orientation_and_its_parent_stays():
    # A chain root → 1 → 2; the root sensor on joint 0, a rigid sensor on joint 1.
    rng = np.random.default_rng(7)
    K = 12
    parents = np.array([-1, 0, 1])
    local = quat.normalize(rng.normal(size=(K, 3, 4)))
    rotation = np.broadcast_to(quat.normalize(rng.normal(size=(2, 4))), (K, 2, 4)).copy()
    segment, carrier = np.array([0, 1]), np.array([-1, -1])
    want = quat.normalize(rng.normal(size=(K, 2, 4)))  # the devices' orientations, any common heading
    cue = relative_orientations(want, 0)
    out = impose_sensor_orientations(local, parents, cue, rotation, segment, carrier, 0, np.ones((K, 2), bool))
    world = world_rotations(out, parents)
    sensors = quat.mul(world[:, segment], rotation)
    np.testing.assert_allclose(relative_orientations(sensors, 0), cue, atol=1e-9)
    # the root keeps the pose's heading: only its tilt changed
    from graphsvc.sensors.orientation import heading_twist

    before = heading_twist(quat.mul(world_rotations(local, parents)[:, 0], rotation[:, 0]))
    assert np.all(_angle_deg(heading_twist(sensors[:, 0]), before) < 1e-4)
    # a frame without the root's measurement, or a sensor not measured, is left alone
    present = np.ones((K, 2), bool)
    present[2, 0] = False
    present[5, 1] = False
    part = impose_sensor_orientations(local, parents, cue, rotation, segment, carrier, 0, present)
    np.testing.assert_array_equal(part[2], local[2])
    assert np.all(_angle_deg(part[5, 1], local[5, 1]) < 1e-4)


@pytest.fixture(scope="module")
def built6():
    kb = generate_knowledge_base(seed=5, minutes=0.6)
    graph, _ = build_graph(kb, BuildOptions(interp=False, progress=False, layout=PRESETS["kelly6"]))
    return kb, graph


def test_a_measured_orientation_is_reproduced_within_a_degree_by_the_refinement(built6):
    kb, graph = built6
    layout = layout_from_dict(graph.layout)
    clip = kb[3]
    rec = simulate_recording(clip, layout, parse_noise("none,orientations=1"), seed=0, rate_hz=graph.rate_hz)
    # the performer's arms held 25° off what the clip did: no knowledge-base frame has it
    turn = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.radians(25.0))
    arms = [layout.sensor_names.index(n) for n in ("l_forearm", "r_forearm")]
    q = np.array(rec.orientations, dtype=np.float64)
    q[:, arms] = quat.mul(turn, q[:, arms])
    from dataclasses import replace

    rec = replace(rec, orientations=q.astype(np.float32))
    out = reconstruct(graph, rec, Options(weights=Weights(0.5, 1, 1, 1.0), smooth_s=0.0)).motion
    from graphsvc.graph.metadata import clip_placement

    placement = clip_placement(graph, layout, 3)
    from graphsvc.motion.kinematics import forward_kinematics

    got = relative_orientations(
        sensor_poses(*forward_kinematics(out.rotations, out.translations, graph.skeleton.parents), placement)[1],
        root_sensor(layout),
    )
    measured = relative_orientations(q, root_sensor(layout))
    trunk = [layout.sensor_names.index(n) for n in ("lower_back", "chest")]
    err = _angle_deg(cue_rotations(got[:, trunk]), cue_rotations(measured[:, trunk]))
    assert np.percentile(err, 95) < 1.0, np.percentile(err, [50, 95, 100])
    # a forearm's frame is carried by the upper arm: its direction (the sensor's X) is imposed
    x = np.array([1.0, 0.0, 0.0])
    got_x, want_x = quat.rotate(cue_rotations(got[:, arms]), x), quat.rotate(cue_rotations(measured[:, arms]), x)
    err = np.degrees(np.arccos(np.clip(np.sum(got_x * want_x, axis=-1), -1.0, 1.0)))
    assert np.percentile(err, 95) < 1.0, np.percentile(err, [50, 95, 100])
    # and the arms moved: without the orientations the forearms stay about 25° off
    plain = reconstruct(
        graph, replace(rec, orientations=None), Options(weights=Weights(0.5, 1, 1), smooth_s=0.0)
    ).motion
    off = relative_orientations(
        sensor_poses(*forward_kinematics(plain.rotations, plain.translations, graph.skeleton.parents), placement)[1],
        root_sensor(layout),
    )
    off_x = quat.rotate(cue_rotations(off[:, arms]), x)
    assert np.median(np.degrees(np.arccos(np.clip(np.sum(off_x * want_x, axis=-1), -1.0, 1.0)))) > 10.0

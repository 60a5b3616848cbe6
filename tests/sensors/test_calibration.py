"""Mounting calibration: rest detection, the closed forms, recovering simulated
mountings against a small procedural graph, applying a calibration, CAL.json checks."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from graphsvc.errors import FormatError, InputError
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.calibration import calibrate
from graphsvc.motion import quat
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.motion.skeleton import Motion
from graphsvc.sensors import calibration as cal_mod
from graphsvc.sensors.calibration import (
    POSE_READINGS,
    angle_deg,
    apply_calibration,
    calibrate_sample,
    check_calibration,
    find_rest,
    load_calibration,
    match_windows,
    wahba,
)
from graphsvc.sensors.device_model import mounting
from graphsvc.sensors.layout import load_layout
from graphsvc.sensors.noise import corrupt_accelerations, parse_noise
from graphsvc.sensors.simulate import simulate_recording

LAYOUT = load_layout("wrists-ankles")


def pose_take(clip: Motion, pose: np.ndarray, hold_s: float = 1.5, blend_s: float = 0.6) -> Motion:
    """A calibration take: local rotations `pose` (J, 4) held (the root where `clip`
    starts), eased into `clip`'s first frame, then the clip."""
    sk, rate = clip.skeleton, clip.rate_hz
    trans = sk.offsets.copy()
    trans[0] = clip.translations[0, 0]
    hold, blend = int(hold_s * rate), int(blend_s * rate)
    t = (1.0 - np.cos(np.pi * (np.arange(1, blend + 1) / (blend + 1)))) / 2.0  # (eased: still at both ends)
    rot_b = quat.slerp(
        np.broadcast_to(pose, (blend, *pose.shape)),
        np.broadcast_to(clip.rotations[0], (blend, *pose.shape)),
        t[:, None],
    )
    trans_b = trans[None] + t[:, None, None] * (clip.translations[0][None] - trans[None])
    rot = np.concatenate([np.broadcast_to(pose, (hold, *pose.shape)), rot_b, clip.rotations])
    tr = np.concatenate([np.broadcast_to(trans, (hold, *trans.shape)), trans_b, clip.translations])
    return Motion(sk, np.ascontiguousarray(rot), np.ascontiguousarray(tr), rate, name="calibration-take")


def npose_take(clip: Motion) -> Motion:
    """`pose_take` of the procedural skeleton's N-pose: its T-pose rest (identity
    rotations) with the arms turned down, legs straight."""
    sk = clip.skeleton
    pose = quat.identity((sk.num_joints,))
    for name, sign in (("l_shoulder", -1.0), ("r_shoulder", 1.0)):
        pose[sk.names.index(name)] = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.float64(sign * np.pi / 2))
    return pose_take(clip, pose)


@pytest.fixture(scope="module")
def kb():
    return generate_knowledge_base(seed=3, minutes=1.0)


@pytest.fixture(scope="module")
def graph(kb):
    g, _ = build_graph(kb, BuildOptions(layout=LAYOUT, progress=False))
    return g


def _clip(kb, name):
    return next(m for m in kb if m.name.startswith(name))


def _errors(cal: dict, seed: int, names, degrees: float, misalign=None) -> np.ndarray:
    true = mounting(seed, names, degrees)
    if misalign is not None:
        true = quat.mul(true, misalign)
    doc = check_calibration(cal)
    return np.array(
        [angle_deg(quat.to_matrix(doc["rotations"][n]), quat.to_matrix(true[k])) for k, n in enumerate(names)]
    )


# ---------------------------------------------------------------- pieces


def test_the_pose_table_reads_plus_one_g_and_holds_every_canonical_segment():
    for pose, table in POSE_READINGS.items():
        for seg, v in table.items():
            assert np.linalg.norm(v) == pytest.approx(9.81), (pose, seg)
    assert POSE_READINGS["npose"]["l_elbow"] == (-9.81, 0.0, 0.0)
    assert POSE_READINGS["npose"]["chest"] == (9.81, 0.0, 0.0)
    assert POSE_READINGS["npose"]["r_ankle"] == (0.0, 0.0, 9.81)
    assert POSE_READINGS["tpose"]["l_wrist"] == (0.0, 9.81, 0.0)
    assert POSE_READINGS["tpose"]["r_shoulder"] == (0.0, -9.81, 0.0)
    assert POSE_READINGS["tpose"]["l_knee"] == POSE_READINGS["npose"]["l_knee"]


def test_find_rest_finds_the_pose_and_the_sensors_not_still_in_it():
    rng = np.random.default_rng(0)
    rate, T = 30.0, 150
    acc = np.zeros((T, 3, 3))
    acc[:] = (0.0, 9.81, 0.0)
    acc += rng.normal(0.0, 0.05, acc.shape)
    t = np.arange(T) / rate
    acc[:12, 0, 0] += 3.0  # moved off for 0.4 s
    acc[60:, 0, 0] += 4.0 * np.sin(7 * t[60:])  # still 0.4–2.0 s, then moving
    acc[:, 1, 2] += 5.0 * np.sin(12 * t)  # never still
    acc[:30, 2, 0] += 4.0 * np.sin(7 * t[:30])  # still from 1.0 s on
    # The pose: sensors 0 and 2 both still over samples 30–60 (0 alone is still before).
    rests = find_rest(acc, rate)
    assert rests[1].tolist() == [-1, -1]
    assert rests[0].tolist() == rests[2].tolist() and 30 <= rests[0, 0] <= 32 and 58 <= rests[0, 1] <= 61
    assert find_rest(acc[:, 1:2], rate) is None
    late = acc[:, [0, 2]].copy()
    late[:46, 1, 0] += 4.0 * np.sin(7 * t[:46])  # still from 46 on: never with sensor 0 for 0.5 s
    rests = find_rest(late, rate)
    assert 12 <= rests[0, 0] <= 14 and rests[1].tolist() == [-1, -1]  # (the first of the most still at once)
    acc[:, 0] *= 1.5  # not 1 g: not at rest
    assert find_rest(acc[:, :1], rate) is None


def test_each_window_is_judged_by_its_own_noise():
    """A sensor noisy while held still (σ = 0.9 m/s² a axis: RMS deviation 1.56 m/s²),
    then moving, then holding one value (a device repeating its last reading): its rest
    is the still start, not the frozen stretch — the frozen stretch's zero noise does not
    set the tolerance elsewhere, nor does a fixed bound refuse the noisy rest."""
    rng = np.random.default_rng(4)
    rate, T = 30.0, 150
    t = np.arange(T) / rate
    acc = np.zeros((T, 1, 3))
    acc[:] = (0.0, 9.81, 0.0)
    acc[:90] += rng.normal(0.0, 0.9, (90, 1, 3))
    acc[36:90, 0, 0] += 6.0 * np.sin(5 * t[36:90])
    acc[90:] = (0.2, 9.8, 0.1)  # frozen from 3 s
    rests = find_rest(acc, rate)
    assert rests[0, 0] == 0 and 36 <= rests[0, 1] <= 45, rests  # (moving from sample 36)


def test_wahba_matches_scipy_align_vectors():
    rng = np.random.default_rng(1)
    R = Rotation.random(random_state=2).as_matrix()
    dev = rng.normal(size=(40, 3))
    lay = dev @ R.T + rng.normal(0, 0.05, (40, 3))
    w = rng.uniform(0.5, 2.0, 40)
    ref, _ = Rotation.align_vectors(lay, dev, weights=w)
    assert angle_deg(wahba(dev, lay, w), ref.as_matrix()) < 1e-4
    assert angle_deg(wahba(dev, dev @ R.T, np.ones(40)), R) < 1e-4


def test_the_complex_sum_gives_the_rotation_about_gravity_and_the_best_window():
    rng = np.random.default_rng(3)
    N, S, W = 200, 2, 20
    stream = rng.normal(0.0, 3.0, (N, S, 3)) + np.array([0.0, 9.81, 0.0])
    runs = np.zeros(N, dtype=np.int64)
    runs[100:] = 1
    up = np.array([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    theta = np.array([0.4, -1.1])
    # The device window is graph window 130 turned by −θ about gravity: the graph = R(θ)·device.
    device = np.stack(
        [Rotation.from_rotvec(-theta[s] * up[s]).apply(stream[130 : 130 + W, s]) for s in range(S)], axis=1
    )
    matches = match_windows(device, stream, runs, up, W, W)
    q, j, cost, sums = matches[0]
    assert (q, j) == (0, 130) and cost == pytest.approx(0.0, abs=1e-6)
    e1, e2 = cal_mod._plane_basis(up[0])
    assert np.cross(e1, e2) == pytest.approx(up[0])
    np.testing.assert_allclose(np.angle(sums), theta, atol=1e-9)
    assert all(runs[m[1]] == runs[m[1] + W - 1] for m in matches)  # (no window across two clips)


# ---------------------------------------------------------------- recovering a mounting


@pytest.mark.parametrize("seed", [11, 12])
def test_calibration_recovers_a_mounting_from_exact_readings(kb, graph, seed):
    take = npose_take(_clip(kb, "stop"))
    rec = simulate_recording(take, LAYOUT, parse_noise("none,mount=90"), seed=seed)
    assert rec.meta["sensor_frame"] == "device"
    cal = calibrate(rec, "npose", graph)
    assert cal["rest_s"][0] < 0.1 and cal["rest_s"][1] >= 1.0
    err = _errors(cal, seed, LAYOUT.sensor_names, 90.0)
    assert err.max() < 2.0, err


@pytest.mark.parametrize("orientations", [False, True])
def test_calibration_recovers_a_mounting_at_the_default_noise(kb, graph, orientations):
    seed = 21
    spec = "default,misalign=0,mount=90" + (",orientations=1,orient_sigma=2,yaw_drift=0.5" if orientations else "")
    rec = simulate_recording(npose_take(_clip(kb, "stop")), LAYOUT, parse_noise(spec), seed=seed)
    assert (rec.orientations is not None) == orientations
    cal = calibrate(rec, "npose", graph)
    err = _errors(cal, seed, LAYOUT.sensor_names, 90.0)
    assert err.max() < 5.0, err
    assert all(("orientation" in s["method"]) == orientations for s in cal["sensors"].values())


def test_a_t_pose_take_calibrates_sensors_in_anatomical_frames(kb):
    """Sensor frames given explicitly (the procedural skeleton's rest is the T-pose with
    identity rotations, so a frame's rotation is its world axes there): the left arm X
    to the body's left (+X), Y up; the right arm X to its right, Y down; the shins X
    down, Z forward — the frames `POSE_READINGS` is written for."""
    from graphsvc.sensors.layout import layout_from_dict

    c = float(np.sqrt(0.5))
    layout = layout_from_dict(
        {
            "name": "anatomical",
            "sensors": [
                {"name": "l_wrist", "segment": "l_elbow", "along": 0.9, "rotation_wxyz": [1, 0, 0, 0]},
                {"name": "r_wrist", "segment": "r_elbow", "along": 0.9, "rotation_wxyz": [0, 0, 0, 1]},
                {"name": "l_ankle", "segment": "l_knee", "along": 0.9, "rotation_wxyz": [c, 0, 0, -c]},
                {"name": "r_ankle", "segment": "r_knee", "along": 0.9, "rotation_wxyz": [c, 0, 0, -c]},
            ],
        }
    )
    g, _ = build_graph(kb, BuildOptions(layout=layout, progress=False))
    seed = 8
    take = pose_take(_clip(kb, "stop"), quat.identity((kb[0].skeleton.num_joints,)))
    rec = simulate_recording(take, layout, parse_noise("none,mount=90"), seed=seed)
    rest = rec.accelerations[5].astype(float)  # (the T-pose's readings without the mounting:)
    np.testing.assert_allclose(
        quat.rotate(mounting(seed, layout.sensor_names, 90.0), rest),
        [POSE_READINGS["tpose"][s.segment] for s in layout.sensors],
        atol=1e-3,
    )
    # (The arms' roll about their bone comes from the motion, not the table, even here
    # where the table's is the truth: 2.0° and 1.4°, the shins 0.03°.)
    err = _errors(calibrate(rec, "tpose", g), seed, layout.sensor_names, 90.0)
    assert err.max() < 3.0 and err[2:].max() < 0.1, err


def test_orientation_output_pairs_gravity_free_of_linear_acceleration(kb, graph):
    """The `real` preset (soft tissue on the legs, foot-strike jolts, orientation output
    with noise and yaw drift): the verticals the orientation output gives, paired with
    the graph frames', make the fit better than the readings alone (over seeds 30–35 the
    largest error 5.8° with them, 8.4° without)."""
    seed = 33
    take = npose_take(_clip(kb, "stop"))
    err = {}
    for spec in ("real,mount=60", "real,mount=60,orientations=0"):
        noise = parse_noise(spec)
        rec = simulate_recording(take, LAYOUT, noise, seed=seed)
        _, misalign = corrupt_accelerations(np.zeros((1, 4, 3)), noise, np.random.default_rng(seed), True)
        err[spec] = _errors(calibrate(rec, "npose", graph), seed, LAYOUT.sensor_names, 60.0, misalign)
    with_o, without = err.values()
    assert with_o.max() < 4.0 and with_o.mean() < without.mean(), (with_o, without)


def test_a_natural_stance_is_calibrated_from_the_motion(kb, graph):
    """`stand`: the procedural clips' own standing start (arms hanging bent, not an
    N-pose), the default noise; the misalignment drawn for this take is part of what
    its devices' frames are turned by."""
    seed = 5
    noise = parse_noise("default,mount=60")
    clip = _clip(kb, "punch")
    rec = simulate_recording(clip, LAYOUT, noise, seed=seed)
    _, misalign = corrupt_accelerations(np.zeros((1, 4, 3)), noise, np.random.default_rng(seed), True)
    err = _errors(calibrate(rec, "stand", graph), seed, LAYOUT.sensor_names, 60.0, misalign)
    assert err.max() < 6.0, err  # (over seeds 30–37: 0.5–5.1°, the shins' the largest)


def test_calibration_refuses_what_it_cannot_do(kb, graph):
    rec = simulate_recording(npose_take(_clip(kb, "stop")), LAYOUT, parse_noise("none,mount=30"), seed=1)
    with pytest.raises(InputError, match="rotation about gravity"):
        calibrate(rec, "npose", None)
    with pytest.raises(InputError, match="unknown pose"):
        calibrate(rec, "sitting", graph)
    plain = simulate_recording(_clip(kb, "stop"), LAYOUT, parse_noise("none"), seed=1)
    with pytest.raises(InputError, match="already in the layout"):
        calibrate(plain, "npose", graph)
    moving = replace(rec, accelerations=rec.accelerations * 1.6)  # nowhere near 1 g
    with pytest.raises(InputError, match="no still stretch"):
        calibrate(moving, "npose", graph)
    with pytest.raises(InputError, match="not the graph's"):
        calibrate(replace(rec, sensor_names=("a", "b", "c", "d")), "npose", graph)


# ---------------------------------------------------------------- applying it


def test_apply_calibration_with_the_true_mounting_gives_the_mount_free_recording(kb):
    clip = _clip(kb, "stop")
    spec = "none,orientations=1"
    mounted = simulate_recording(clip, LAYOUT, parse_noise(spec + ",mount=70"), seed=4)
    free = simulate_recording(clip, LAYOUT, parse_noise(spec), seed=4)
    true = mounting(4, LAYOUT.sensor_names, 70.0)
    doc = check_calibration(
        {
            "format": "graphsvc-calibration",
            "version": 1,
            "sensors": {n: {"rotation_wxyz": true[k].tolist()} for k, n in enumerate(LAYOUT.sensor_names)},
        },
        "cal.json",
    )
    out = apply_calibration(mounted, doc)
    np.testing.assert_allclose(out.accelerations, free.accelerations, atol=2e-4)
    dots = np.abs(np.sum(out.orientations.astype(float) * free.orientations.astype(float), axis=-1))
    assert dots.min() > 1 - 1e-6
    assert out.meta["sensor_frame"] == "layout" and out.meta["calibration"] == "cal.json"
    # The live form turns one sample the same way.
    np.testing.assert_allclose(
        calibrate_sample(
            doc["rotations"] and np.stack([doc["rotations"][n] for n in LAYOUT.sensor_names]), mounted.accelerations[7]
        ),
        free.accelerations[7],
        atol=2e-4,
    )
    with pytest.raises(InputError, match="already in the layout"):
        apply_calibration(out, doc)
    wrong = {**doc, "rotations": {**doc["rotations"], "extra": np.array([1.0, 0, 0, 0])}}
    with pytest.raises(InputError, match="not the recording's"):
        apply_calibration(mounted, wrong)


def test_cal_json_round_trips_and_malformed_files_are_refused(tmp_path, kb, graph):
    rec = simulate_recording(npose_take(_clip(kb, "stop")), LAYOUT, parse_noise("none,mount=30"), seed=2)
    cal = calibrate(rec, "npose", graph)
    path = tmp_path / "cal.json"
    cal_mod.save_calibration(cal, path)
    doc = load_calibration(path)
    assert doc["format"] == "graphsvc-calibration" and doc["version"] == 1 and doc["layout"] == "wrists-ankles"
    assert set(doc["rotations"]) == set(LAYOUT.sensor_names)
    for n, item in doc["sensors"].items():
        assert set(item) == {"rotation_wxyz", "method", "residual_deg"}
    bad = {
        "not json": "{",
        "another format": json.dumps({"format": "x", "version": 1, "sensors": {}}),
        "a newer version": json.dumps({**cal, "version": 2}),
        "no sensors": json.dumps({**cal, "sensors": {}}),
        "not a rotation": json.dumps({**cal, "sensors": {"l_wrist": {"rotation_wxyz": [1, 2, 3, 4]}}}),
        "three numbers": json.dumps({**cal, "sensors": {"l_wrist": {"rotation_wxyz": [1, 0, 0]}}}),
        "words": json.dumps({**cal, "sensors": {"l_wrist": {"rotation_wxyz": "identity"}}}),
        "an unknown convention": json.dumps({**cal, "sensor_frames": "sideways"}),
    }
    for what, text in bad.items():
        path.write_text(text)
        with pytest.raises(FormatError):
            load_calibration(path)


def test_a_calibration_carries_its_graphs_sensor_frame_convention(kb, graph):
    """Calibrated against a graph, a recording's readings are in that graph's frames: the
    calibration says which, and a graph in another convention refuses them."""
    from graphsvc.sensors.anatomy import check_frames

    rec = simulate_recording(npose_take(_clip(kb, "stop")), LAYOUT, parse_noise("none,mount=30"), seed=2)
    rec = replace(rec, meta={k: v for k, v in rec.meta.items() if k != "sensor_frames"})  # (as a device's)
    cal = calibrate(rec, "npose", graph)
    assert cal["sensor_frames"] == graph.params["sensor_frames"] == "anatomical"
    out = apply_calibration(rec, check_calibration(json.loads(json.dumps(cal))))
    assert out.meta["sensor_frames"] == "anatomical"
    check_frames(graph.params, out.meta)
    with pytest.raises(InputError, match="rest-pose"):
        check_frames({}, out.meta)  # a graph built before anatomical frames


# ---------------------------------------------------------------- a calibration pose before a clip

KELLY6 = load_layout("kelly6")


@pytest.fixture(scope="module")
def graph6(kb):
    g, _ = build_graph(kb, BuildOptions(layout=KELLY6, progress=False))
    return g


def _arms_lowered(monkeypatch, degrees: float) -> None:
    """`with_calibration_pose`'s T-pose with both upper arms turned `degrees` down about
    the performer's forward axis (negative: up)."""
    import graphsvc.motion.calibration_pose as cp
    from graphsvc.motion.joints import joint_map
    from graphsvc.motion.kinematics import forward_kinematics

    made = cp.calibration_frame

    def frame(motion, pose, mapping=None):
        rot, trans = made(motion, pose, mapping)
        table, parents = joint_map(motion.skeleton, mapping), motion.skeleton.parents
        world = forward_kinematics(rot[None], trans[None], parents)
        left = world[1][0, table["l_hip"]] - world[1][0, table["r_hip"]]
        left[1] = 0.0
        forward = np.cross(left / np.linalg.norm(left), [0.0, 1.0, 0.0])
        for side, sign in (("l_", -1.0), ("r_", 1.0)):
            j = table[side + "shoulder"]
            turn = quat.from_axis_angle(forward, np.float64(np.radians(sign * degrees)))
            rot[j] = quat.mul(quat.conjugate(world[0][0, parents[j]]), quat.mul(turn, world[0][0, j]))
        return rot, trans

    monkeypatch.setattr(cp, "calibration_frame", frame)


@pytest.mark.parametrize("pose, lowered, bound", [("npose", 0.0, 2.0), ("tpose", 0.0, 3.0), ("tpose", 15.0, 3.0)])
def test_a_pose_before_the_clip_calibrates_every_sensor(kb, graph6, monkeypatch, pose, lowered, bound):
    """`with_calibration_pose` before the punch clip, every sensor mounted up to 30° off,
    the default noise without its misalignment. A T-pose says only that the arms are
    level: the forearms' roll about their bone is the first frame's (about 27° from the
    table's Y-up here), which the motion fixes — as it does when the arms are 15° below
    level (the table's assumption gave 27° and 30° of error; measured: 1.8° and 1.8° the
    largest (the shins'; the forearms 0.9° and 1.5°), the N-pose 1.3°)."""
    from graphsvc.motion.calibration_pose import with_calibration_pose

    if lowered:
        _arms_lowered(monkeypatch, lowered)
    seed = 1
    take = with_calibration_pose(_clip(kb, "punch"), pose, 2.0)
    rec = simulate_recording(take, KELLY6, parse_noise("default,misalign=0,mount=30"), seed=seed)
    cal = calibrate(rec, pose, graph6)
    err = _errors(cal, seed, KELLY6.sensor_names, 30.0)
    assert err.max() < bound, dict(zip(KELLY6.sensor_names, err.round(2)))


# ---------------------------------------------------------------- quality


def test_quality_problems_name_each_sensor_in_one_phrase():
    got = cal_mod.quality_problems(
        ("a", "b", "c", "d"), [25.5, 3.0, 24.9, 40.0], [True, False, True, True], [np.nan, np.nan, 10.5, 9.9]
    )
    assert got == [
        "a (residual 25.5° > 25°)",
        "b (moved during the pose)",
        "c (gravity from acceleration and orientation 10.5° apart (> 10°))",
        "d (residual 40.0° > 25°)",
    ]


def _wobbled(rec, sensor: int):
    """`rec` with one sensor shaken throughout (2 m/s² at 2 Hz along its X): never
    still, so not in the pose the others hold."""
    acc = rec.accelerations.astype(np.float64)
    t = rec.timestamps_s - rec.timestamps_s[0]
    acc[:, sensor, 0] += 2.0 * np.sin(2 * np.pi * 2.0 * t)
    return replace(rec, accelerations=acc.astype(np.float32))


def test_a_sensor_that_moved_during_the_pose_is_named(kb, graph):
    rec = simulate_recording(npose_take(_clip(kb, "stop")), LAYOUT, parse_noise("none,mount=30"), seed=3)
    with pytest.raises(cal_mod.CalibrationQualityError) as info:
        calibrate(_wobbled(rec, 1), "npose", graph)
    assert isinstance(info.value, InputError)
    assert str(info.value) == "calibration not to be trusted: r_wrist (moved during the pose)"
    doc = info.value.calibration
    assert doc["problems"] == ["r_wrist (moved during the pose)"] and set(doc["sensors"]) == set(LAYOUT.sensor_names)
    assert doc["sensors"]["r_wrist"]["method"] == "graph (never still)"
    assert calibrate(rec, "npose", graph)["problems"] == []


def test_gravity_from_acceleration_and_orientation_that_disagree_is_named(kb, graph):
    """The accelerometer's frame turned 15° off the orientation output's (about an axis
    across gravity): the two views of gravity over the rest are 15° apart."""
    rec = simulate_recording(npose_take(_clip(kb, "stop")), LAYOUT, parse_noise("none,orientations=1,mount=30"), seed=3)
    acc = rec.accelerations.astype(np.float64)
    down = acc[:10, 2].mean(axis=0)
    axis = np.cross(down, [1.0, 0.0, 0.0])
    turn = quat.from_axis_angle(axis / np.linalg.norm(axis), np.float64(np.radians(15.0)))
    acc[:, 2] = quat.rotate(turn[None], acc[:, 2])
    gap = cal_mod.gravity_gap_deg(acc, rec.orientations.astype(np.float64), np.array([[0, 30]] * 4))
    assert gap[2] == pytest.approx(15.0, abs=1e-3) and np.abs(gap[[0, 1, 3]]).max() < 1e-3
    with pytest.raises(
        cal_mod.CalibrationQualityError, match=r"l_ankle \(gravity from acceleration and orientation 15\.0°"
    ):
        calibrate(replace(rec, accelerations=acc.astype(np.float32)), "npose", graph)


# ---------------------------------------------------------------- calibrating a take from its own start


def test_hidden_clips_are_left_out_of_the_reference(kb, graph):
    """An evaluation that hides a clip must not calibrate against it: its readings (and
    only its) leave the reference, in the graph's clip order."""
    from graphsvc.graph.calibration import calibrate_from_start, graph_reference, graph_stream

    names = [c["name"] for c in graph.clips]
    full, runs, nodes = graph_stream(graph)
    ref = graph_reference(graph, hidden_clips=("stop_01", "not-a-clip"))
    keep = graph.node_clip[nodes] != names.index("stop_01")
    assert 0 < keep.sum() < keep.size
    np.testing.assert_array_equal(ref.readings, full[keep])
    np.testing.assert_array_equal(ref.runs, runs[keep])
    np.testing.assert_array_equal(graph_reference(graph).readings, full)
    # The verticals follow the kept rows: row k of the reference is row keep[k] of the whole.
    rows = np.array([0, 7, int(keep.sum()) - 1])
    np.testing.assert_allclose(
        ref.verticals(rows, LAYOUT.sensor_names),
        graph_reference(graph).verticals(np.flatnonzero(keep)[rows], LAYOUT.sensor_names),
    )
    rec = simulate_recording(npose_take(_clip(kb, "stop")), LAYOUT, parse_noise("none,mount=30"), seed=2)
    assert calibrate_from_start(rec, graph, 5.0, "npose") == calibrate(rec, "npose", graph, None, 5.0)
    with pytest.raises(InputError, match="no window of the graph's readings"):
        calibrate_from_start(rec, graph, 5.0, "npose", hidden_clips=names)
    with pytest.raises(InputError, match="unknown pose"):
        calibrate_from_start(rec, graph, 5.0, "sitting")


@pytest.fixture(scope="module")
def graph_dip6(kb):
    g, _ = build_graph(kb, BuildOptions(layout=load_layout("dip6"), progress=False))
    return g


@pytest.mark.parametrize("pose", ["npose", "tpose"])
def test_dip6_head_sensor_pointing_down_its_segment_is_calibrated_as_the_others(kb, graph_dip6, pose):
    """dip6's head sensor has its X toward the neck (no joint above the head): the pose
    table's X and Y turn over for it (`sensor_reversed`); without that its tilt came out
    upside down (residuals of 130–150° on every simulated clip)."""
    from graphsvc.motion.calibration_pose import with_calibration_pose
    from graphsvc.sensors.calibration import sensor_reversed

    dip6 = load_layout("dip6")
    assert sensor_reversed(dip6.to_dict(), dip6.sensor_names).tolist() == [False] * 4 + [True, False]
    take = with_calibration_pose(_clip(kb, "punch"), pose, 2.0)
    rec = simulate_recording(take, dip6, parse_noise("default,misalign=0,mount=30"), seed=1)
    cal = calibrate(rec, pose, graph_dip6)
    err = _errors(cal, 1, dip6.sensor_names, 30.0)
    assert err.max() < 3.0, dict(zip(dip6.sensor_names, err.round(2)))
    assert cal["sensors"]["head"]["residual_deg"] < 10.0

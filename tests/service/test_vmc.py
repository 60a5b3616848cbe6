"""Pose frames out over VMC (`--vmc`): received on loopback with python-osc's own
server, the bones' local rotations and the skeleton's bone offsets (mirrored into
Unity's left-handed axes here, by hand) rebuild every frame's joint positions within
1 mm; a bad address is one line, exit 2."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from graphsvc.service import client as C
from tests.service.conftest import wait_for

# Unity's humanoid bone of each of the procedural skeleton's joints, and its parent bone
# (the procedural skeleton's own parent joint: it has no joint between two bones).
BONES = {
    "pelvis": "Hips",
    "spine": "Spine",
    "chest": "Chest",
    "neck": "Neck",
    "head": "Head",
    "l_shoulder": "LeftUpperArm",
    "l_elbow": "LeftLowerArm",
    "l_wrist": "LeftHand",
    "r_shoulder": "RightUpperArm",
    "r_elbow": "RightLowerArm",
    "r_wrist": "RightHand",
    "l_hip": "LeftUpperLeg",
    "l_knee": "LeftLowerLeg",
    "l_ankle": "LeftFoot",
    "l_toe": "LeftToes",
    "r_hip": "RightUpperLeg",
    "r_knee": "RightLowerLeg",
    "r_ankle": "RightFoot",
    "r_toe": "RightToes",
}


def _rebuild(received: dict, skeleton) -> dict[str, np.ndarray]:
    """Joint positions in graphsvc's axes from one received frame: the root, the Hips'
    local position, every bone's local rotation, and the skeleton's own offsets with X
    negated (graphsvc right-handed → Unity left-handed); then X negated back."""
    name, root, root_q = received["root"]
    assert name == "root" and np.allclose(root_q, [0, 0, 0, 1]) and root[1] == 0.0
    world_pos, world_rot = {}, {}
    for joint in BONES:  # (parents before children)
        j = skeleton.index(joint)
        position, rotation = received["bones"][BONES[joint]]
        local = Rotation.from_quat(rotation)  # (x, y, z, w): Unity's order, scipy's too
        if joint == "pelvis":
            world_pos[joint], world_rot[joint] = root + position, local
            continue
        parent = skeleton.names[skeleton.parents[j]]
        offset = skeleton.offsets[j] * [-1.0, 1.0, 1.0]
        np.testing.assert_allclose(position, offset, atol=1e-6)  # a T-pose's offsets, as sent
        world_pos[joint] = world_pos[parent] + world_rot[parent].apply(offset)
        world_rot[joint] = world_rot[parent] * local
    return {j: p * [-1.0, 1.0, 1.0] for j, p in world_pos.items()}


def test_the_bones_rebuild_every_frame_within_a_millimetre(server, recording, vmc_receiver):
    from graphsvc.motion.kinematics import motion_fk
    from graphsvc.service.convert_graph import skeleton_from_proto
    from graphsvc.service.vmc import VmcSender

    with C.connect(f"127.0.0.1:{server.port}") as conn:
        info = C.resolve_graph(conn, "small")
        skeleton = skeleton_from_proto(info.skeleton)
        sender = VmcSender(f"127.0.0.1:{vmc_receiver.port}", skeleton)
        result = C.stream_recording(conn, "small", recording, speed=100.0, on_frame=sender.send)
    wait_for(lambda: len(vmc_receiver.frames) == len(result.frames), timeout_s=10)
    assert sender.sent == len(result.frames) > 30 and sender.failed == 0
    _, truth = motion_fk(result.motion())
    worst = 0.0
    for k, (frame, received) in enumerate(zip(result.frames, vmc_receiver.frames)):
        assert received["t"] == pytest.approx(frame.time_s, abs=1e-5) and received["ok"] == (1,)
        assert sorted(received["bones"]) == sorted(BONES.values())
        rebuilt = _rebuild(received, skeleton)
        for joint, p in rebuilt.items():
            worst = max(worst, float(np.abs(p - truth[k, skeleton.index(joint)]).max()))
    assert worst < 1e-3, worst


def test_client_stream_sends_vmc_and_refuses_a_bad_address(server, rec_file, vmc_receiver, capsys):
    from graphsvc.cli import main

    common = ["client", "stream", str(rec_file), "--server", f"127.0.0.1:{server.port}"]
    vmc = f"127.0.0.1:{vmc_receiver.port}"
    assert main([*common, "--speed", "100", "--quiet", "--vmc", vmc, "--strategy", "nearest"]) == 0
    out = capsys.readouterr().out
    frames = int(out.split(" frames from", 1)[0])
    assert f"vmc: {frames} frames sent to {vmc}" in out
    wait_for(lambda: len(vmc_receiver.frames) == frames, timeout_s=10)
    for bad, said in [
        ("127.0.0.1", "expected HOST:PORT"),
        ("127.0.0.1:0", "port 1–65535"),
        ("no-such-host.invalid:39539", "cannot resolve no-such-host.invalid"),
    ]:
        assert main([*common, "--vmc", bad]) == 2
        printed = capsys.readouterr()
        assert printed.out == "" and len(printed.err.splitlines()) == 1, printed.err
        assert printed.err.startswith("graphsvc: error: --vmc") and said in printed.err, printed.err


def test_a_rest_that_is_no_t_pose_is_sent_as_one():
    """Arms hanging and the body turned a quarter (facing +X) at rest: the bones' offsets
    are a T-pose's facing +Z all the same, and any pose still rebuilds exactly."""
    from graphsvc.motion import quat
    from graphsvc.motion.kinematics import forward_kinematics
    from graphsvc.motion.procedural import generate_performance
    from graphsvc.motion.skeleton import Skeleton
    from graphsvc.service.vmc import pose_to_vmc, vmc_rig

    sk = generate_performance(seed=1)[0].skeleton
    offsets = sk.offsets.astype(np.float64).copy()
    for side in "lr":
        for joint, length in (("elbow", 0.29), ("wrist", 0.26), ("wrist_End", 0.18)):
            offsets[sk.index(f"{side}_{joint}")] = (0.0, -length, 0.0)
    offsets = quat.rotate(quat.about_y(np.full(len(offsets), np.pi / 2)), offsets)
    hanging = Skeleton(sk.names, sk.parents, offsets, sk.channels, sk.end_site)
    rig = vmc_rig(hanging)
    sent = dict(zip(rig.names, rig.offsets))
    for bone, expected in {
        "LeftLowerArm": (0.29, 0, 0),
        "LeftHand": (0.26, 0, 0),
        "RightLowerArm": (-0.29, 0, 0),
        "LeftUpperArm": (0.17, 0.19, 0),
        "LeftUpperLeg": (0.09, -0.07, 0),
        "Spine": (0, 0.1, 0),
        "LeftToes": (0, -0.06, 0.13),
    }.items():
        np.testing.assert_allclose(sent[bone], expected, atol=1e-9, err_msg=bone)
    rng = np.random.default_rng(3)
    rotations = quat.normalize(rng.normal(size=(hanging.num_joints, 4)))
    translations = offsets.copy()
    translations[0] += (0.3, 0.1, -0.2)  # (the root somewhere else)
    _, truth = forward_kinematics(rotations[None], translations[None], hanging.parents)
    root, positions, local = pose_to_vmc(rig, rotations, translations)
    world_pos, world_rot = {}, {}
    for k, bone in enumerate(rig.names):
        parent = rig.parent[k]
        if parent < 0:
            world_pos[k], world_rot[k] = root + positions[k], Rotation.from_quat(local[k])
        else:
            world_pos[k] = world_pos[parent] + world_rot[parent].apply(positions[k])
            world_rot[k] = world_rot[parent] * Rotation.from_quat(local[k])
        np.testing.assert_allclose(world_pos[k] * [-1, 1, 1], truth[0, rig.joints[k]], atol=1e-9, err_msg=bone)

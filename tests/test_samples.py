"""The sample clips that install with pybullet: the humanoid read from its URDF is the
reader's, poses agree with pybullet's own forward kinematics, the walk is a plausible
walk, `graphsvc samples` writes BVH that reads back as the same motion with the
licence beside it; without pybullet the commands say how to install it."""

import importlib.util
import json

import numpy as np
import pytest

from graphsvc.cli import main

HAS_PYBULLET = importlib.util.find_spec("pybullet_data") is not None
needs_pybullet = pytest.mark.skipif(not HAS_PYBULLET, reason="pybullet is not installed (the [samples] extra)")


def run(argv, capsys):
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_without_pybullet_the_commands_say_how_to_install_it(tmp_path, capsys, monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "pybullet_data" else real(name, *a)
    )
    for argv in (["samples", "-o", str(tmp_path / "s")], ["demo", "--kb", "pybullet", "-o", str(tmp_path / "d")]):
        code, _, err = run(argv, capsys)
        assert code == 2 and len(err.strip().splitlines()) == 1 and "pip install 'graphsvc[samples]'" in err, err
    assert list(tmp_path.iterdir()) == []


def test_demo_flags_that_do_not_fit_the_knowledge_base(tmp_path, capsys):
    for argv, needle in (
        (["demo", "--kb", "pybullet", "--minutes", "1"], "--minutes"),
        (["demo", "--held-out", "walk"], "--kb pybullet"),
    ):
        code, _, err = run(argv + ["-o", str(tmp_path / "d")], capsys)
        assert code == 2 and needle in err
    assert list(tmp_path.iterdir()) == []


@needs_pybullet
def test_urdf_humanoid_is_the_readers_and_pybullet_poses_it_alike():
    import pybullet
    import pybullet_data

    from graphsvc.motion import quat
    from graphsvc.motion.deepmimic import TO_GRAPHSVC, character_from_urdf, humanoid_character, read_deepmimic
    from graphsvc.motion.kinematics import motion_fk

    data = pybullet_data.getDataPath()
    urdf = character_from_urdf(f"{data}/humanoid/humanoid.urdf")
    ours = humanoid_character()
    assert urdf.names == ours.names and urdf.kinds == ours.kinds and np.array_equal(urdf.parents, ours.parents)
    np.testing.assert_allclose(urdf.offsets, ours.offsets, atol=1e-12)
    np.testing.assert_allclose(urdf.axes, ours.axes, atol=1e-12)

    # Frame 20 of the kick (30 Hz in the file and once read), posed by pybullet from the same values.
    path = f"{data}/data/motions/humanoid3d_kick.txt"
    row = json.loads(open(path).read())["Frames"][20]
    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(
            f"{data}/humanoid/humanoid.urdf", [0, 0, 0], globalScaling=0.25, physicsClientId=client
        )
        w, x, y, z = row[4:8]
        pybullet.resetBasePositionAndOrientation(body, row[1:4], [x, y, z, w], physicsClientId=client)
        index = {
            pybullet.getJointInfo(body, j, physicsClientId=client)[1].decode(): j
            for j in range(pybullet.getNumJoints(body, physicsClientId=client))
        }
        c = 8
        for name, kind in zip(ours.names[1:], ours.kinds[1:]):
            if kind == "spherical":
                w, x, y, z = row[c : c + 4]
                pybullet.resetJointStateMultiDof(body, index[name], [x, y, z, w], physicsClientId=client)
                c += 4
            elif kind == "revolute":
                pybullet.resetJointState(body, index[name], row[c], physicsClientId=client)
                c += 1
        theirs = {
            n: pybullet.getLinkState(body, index[n], computeForwardKinematics=True, physicsClientId=client)[4]
            for n in ours.names[1:]
        }
    finally:
        pybullet.disconnect(client)
    m = read_deepmimic(path)
    assert m.rate_hz == 30.0
    frame = 20
    _, p = motion_fk(m)
    back = quat.rotate(quat.conjugate(TO_GRAPHSVC), p[frame])  # graphsvc's frame → DeepMimic's
    for name, position in theirs.items():
        np.testing.assert_allclose(back[m.skeleton.names.index(name)], position, atol=1e-5, err_msg=name)


@needs_pybullet
def test_walk_is_a_plausible_walk():
    import pybullet_data

    from graphsvc.motion import signals
    from graphsvc.motion.joints import joint_map
    from graphsvc.motion.kinematics import motion_fk
    from graphsvc.motion.library import load_motion

    m = load_motion(f"{pybullet_data.getDataPath()}/data/motions/humanoid3d_walk.txt")
    assert (m.labels, m.rate_hz, m.num_frames) == (("walk",), 30.0, 39)
    t = joint_map(m.skeleton)
    _, p = motion_fk(m)
    stature = p[:, t["head"], 1].max() - p[:, [t["l_toe"], t["r_toe"]], 1].min()
    assert 1.45 < stature < 1.65  # a 1.6 m humanoid, head centre to sole
    assert np.all(p[:, [t["l_ankle"], t["r_ankle"], t["l_toe"], t["r_toe"]], 1] > -0.01)  # never in the floor
    travel = p[-1, t["pelvis"]] - p[0, t["pelvis"]]
    speed = np.linalg.norm(travel[[0, 2]]) / ((m.num_frames - 1) / m.rate_hz)
    assert 0.7 < speed < 1.3 and travel[2] > abs(travel[0])  # walking pace, forward (+Z)
    contacts = signals.foot_contacts(p, t, m.rate_hz)
    assert 0.3 < contacts.mean() < 0.8 and contacts.any(axis=1).mean() > 0.9  # feet take turns


@needs_pybullet
def test_samples_write_bvh_that_reads_back_as_the_clips(tmp_path, capsys):
    from graphsvc.motion.kinematics import motion_fk
    from graphsvc.motion.library import load_motion
    from graphsvc.samples import load_samples

    code, out, _ = run(["samples", "-o", str(tmp_path / "s")], capsys)
    assert code == 0 and "20 clips as BVH" in out
    clips = {m.name: m for m in load_samples()}
    names = sorted(p.stem for p in (tmp_path / "s").glob("*.bvh"))
    assert names == sorted(clips) and {"walk", "crawl", "getup_faceup", "turn_left_0", "backflip"} <= set(names)
    licence = (tmp_path / "s" / "LICENSE.txt").read_text()
    assert "zlib" in licence and "pybullet_data/data/motions" in licence and "Erwin Coumans" in licence
    for name in ("walk", "turn_left_0", "roll"):
        back, clip = load_motion(tmp_path / "s" / f"{name}.bvh"), clips[name]
        assert back.skeleton.same_topology(clip.skeleton) and back.labels == clip.labels
        assert back.rate_hz == clip.rate_hz and back.num_frames == clip.num_frames
        np.testing.assert_allclose(motion_fk(back)[1], motion_fk(clip)[1], atol=1e-5)


@needs_pybullet
def test_demo_knowledge_base_leaves_one_clip_out(tmp_path, capsys):
    from graphsvc.demo import PYBULLET_RATE_HZ, pybullet_knowledge_base

    kb, held, labels = pybullet_knowledge_base("turn_left_1")
    assert len(kb) == 19 and "turn_left_1" not in {c.name for c in kb} and "turn_left_0" in {c.name for c in kb}
    assert held.name == "turn_left_1" and held.rate_hz == PYBULLET_RATE_HZ
    assert labels.shape == (held.num_frames,) and set(labels) == {"turn_left"}
    code, _, err = run(["demo", "--kb", "pybullet", "--held-out", "moonwalk", "-o", str(tmp_path / "d")], capsys)
    assert code == 2 and "no sample clip named 'moonwalk'" in err and "turn_right_1" in err
    assert list(tmp_path.iterdir()) == []

"""Retargeting between skeletons of other joints: canonical bone directions carried
over exactly, twist and the placement on the floor; one knowledge base of two
families; `graphsvc build` with mixed sources and `--skeleton`."""

from __future__ import annotations

import numpy as np
import pytest

from graphsvc.cli import main
from graphsvc.errors import SkeletonError
from graphsvc.motion import quat
from graphsvc.motion.joints import CANONICAL_CHILD, joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.procedural import make_clip
from graphsvc.motion.procedural.body import standard_skeleton
from graphsvc.motion.proportions import leg_length, rest_positions, segment_lengths
from graphsvc.motion.retarget import Side, make_side, pool_skeletons, rest_heights, retarget
from graphsvc.motion.skeleton import Motion, Skeleton

ALL = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
ROT = ("Zrotation", "Xrotation", "Yrotation")


def _other_skeleton(seed: int = 3) -> Motion:
    """A one-frame standing motion on a skeleton of another family than the procedural
    one: Bandai-Namco's joint names, a root joint on the floor that alone has position
    channels (the pelvis is moved through it), clavicle joints, zero-length end sites,
    the procedural body stretched (taller, narrower), and every joint's local axes
    turned at random, so that no local rotation means what it means on the procedural
    skeleton."""
    proc = standard_skeleton()
    p = {n: x for n, x in zip(proc.names, rest_positions(proc) * np.array([0.92, 1.08, 1.0]))}
    p["l_arm"] = (p["chest"] + p["l_shoulder"]) / 2.0
    p["r_arm"] = (p["chest"] + p["r_shoulder"]) / 2.0
    joints = [  # name, parent, world position of the standing pose
        ("joint_Root", None, p["pelvis"] * np.array([1.0, 0.0, 1.0])),
        ("Hips", "joint_Root", p["pelvis"]),
        ("Spine", "Hips", p["spine"]),
        ("Chest", "Spine", p["chest"]),
        ("Neck", "Chest", p["neck"]),
        ("Head", "Neck", p["head"]),
        ("Head_End", "Head", p["head"]),
        ("Shoulder_L", "Chest", p["l_arm"]),
        ("UpperArm_L", "Shoulder_L", p["l_shoulder"]),
        ("LowerArm_L", "UpperArm_L", p["l_elbow"]),
        ("Hand_L", "LowerArm_L", p["l_wrist"]),
        ("Hand_L_End", "Hand_L", p["l_wrist"]),
        ("Shoulder_R", "Chest", p["r_arm"]),
        ("UpperArm_R", "Shoulder_R", p["r_shoulder"]),
        ("LowerArm_R", "UpperArm_R", p["r_elbow"]),
        ("Hand_R", "LowerArm_R", p["r_wrist"]),
        ("Hand_R_End", "Hand_R", p["r_wrist"]),
        ("UpperLeg_L", "Hips", p["l_hip"]),
        ("LowerLeg_L", "UpperLeg_L", p["l_knee"]),
        ("Foot_L", "LowerLeg_L", p["l_ankle"]),
        ("Toes_L", "Foot_L", p["l_toe"]),
        ("Toes_L_End", "Toes_L", p["l_toe"]),
        ("UpperLeg_R", "Hips", p["r_hip"]),
        ("LowerLeg_R", "UpperLeg_R", p["r_knee"]),
        ("Foot_R", "LowerLeg_R", p["r_ankle"]),
        ("Toes_R", "Foot_R", p["r_toe"]),
        ("Toes_R_End", "Toes_R", p["r_toe"]),
    ]
    names = tuple(n for n, _, _ in joints)
    parents = np.array([-1 if q is None else names.index(q) for _, q, _ in joints])
    frames = quat.normalize(np.random.default_rng(seed).normal(size=(len(names), 4)))  # each joint's world axes
    end = np.array([n.endswith("_End") for n in names])
    offsets, local = np.zeros((len(names), 3)), np.empty((len(names), 4))
    for j, (_, _, pos) in enumerate(joints):
        if parents[j] < 0:
            offsets[j], local[j] = pos, frames[j]
        else:
            q = frames[parents[j]]
            offsets[j] = quat.inv_rotate(q, pos - joints[parents[j]][2])
            local[j] = quat.mul(quat.conjugate(q), frames[j])
    local[end] = quat.IDENTITY
    channels = tuple(ALL if parents[j] < 0 else () if end[j] else ROT for j in range(len(names)))
    sk = Skeleton(names, parents, offsets, channels, end)
    return Motion(sk, local[None], offsets[None].copy(), 30.0, name="stand")


def _walk(seconds: float = 3.0, kind: str = "walk") -> Motion:
    return make_clip(kind, np.random.default_rng(11), standard_skeleton(), 30.0, seconds, f"{kind}_001")


def _directions(motion: Motion) -> dict[str, np.ndarray]:
    """Each canonical bone's world direction, (F, 3) unit vectors."""
    table = joint_map(motion.skeleton)
    _, pos = motion_fk(motion)
    out = {}
    for c, child in CANONICAL_CHILD.items():
        v = pos[:, table[child]] - pos[:, table[c]]
        out[c] = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return out


def _worst_angle_deg(a: dict, b: dict) -> float:
    return max(float(np.degrees(np.arccos(np.clip(np.sum(a[k] * b[k], axis=-1), -1.0, 1.0))).max()) for k in a)


def _on(side: Side, motion: Motion) -> Side:
    """`side`'s family with `motion`'s own skeleton (bone lengths)."""
    return Side(motion.skeleton, side.table, side.mapping, side.reference, side.foot_rest)


def test_procedural_round_trip_keeps_directions_and_rotations():
    walk, stand = _walk(kind="punch"), _other_skeleton()
    source, target = make_side(walk.skeleton, [walk]), make_side(stand.skeleton, [stand])
    there = retarget(walk, source, target)
    assert there.skeleton is stand.skeleton and there.num_frames == walk.num_frames
    assert there.name == walk.name and there.labels == walk.labels and there.retargeted_from == "procedural"
    assert _worst_angle_deg(_directions(walk), _directions(there)) < 2.0
    back = retarget(there, _on(target, there), source)
    assert back.retargeted_from == "bandai"
    assert _worst_angle_deg(_directions(walk), _directions(back)) < 2.0
    # The twist comes back too: every canonical joint's world rotation, the hands' and
    # the head's (which have no bone direction) included.
    table = joint_map(walk.skeleton)
    (r0, p0), (r1, p1) = motion_fk(walk), motion_fk(back)
    for c in table.present():
        q = quat.mul(quat.conjugate(r0[:, table[c]]), r1[:, table[c]])
        assert np.degrees(2.0 * np.arccos(np.clip(np.abs(q[:, 0]), 0.0, 1.0))).max() < 2.0, c
    # The way back puts the pelvis path where it was (scaled there and back by the legs' ratio).
    assert np.abs(p1[:, table["pelvis"]] - p0[:, table["pelvis"]]).max() < 0.01


def test_pelvis_scaled_by_legs_and_feet_on_the_floor():
    walk, stand = _walk(), _other_skeleton()
    there = retarget(walk, make_side(walk.skeleton, [walk]), make_side(stand.skeleton, [stand]))
    k = leg_length(segment_lengths(stand.skeleton)) / leg_length(segment_lengths(walk.skeleton))
    assert k > 1.03  # (the other skeleton is 8 % taller)
    _, p0 = motion_fk(walk)
    _, p1 = motion_fk(there)
    pelvis0, pelvis1 = p0[:, joint_map(walk.skeleton)["pelvis"]], p1[:, joint_map(stand.skeleton)["pelvis"]]
    # the stride scales with the legs: the ground path, relative to its start
    travel0, travel1 = pelvis0[:, [0, 2]] - pelvis0[0, [0, 2]], pelvis1[:, [0, 2]] - pelvis1[0, [0, 2]]
    assert np.allclose(travel1, travel0 * k, atol=1e-6)
    # the walking feet rest where the standing pose's stand (ankles, toes), within 1.5 cm
    table = joint_map(stand.skeleton)
    _, stand_pos = motion_fk(stand)
    assert np.abs(rest_heights(p1, table) - rest_heights(stand_pos, table)).max() < 0.015
    # the pelvis height follows the legs: the walk's mean pelvis height times k, within the feet's shift
    assert abs(pelvis1[:, 1].mean() - k * pelvis0[:, 1].mean()) < 0.03


def test_pool_skeletons_puts_a_mixed_knowledge_base_on_the_first_family():
    walk, run, stand = _walk(), _walk(kind="run"), _other_skeleton()
    assert pool_skeletons([walk, run]) == [walk, run]  # one family: unchanged
    pooled = pool_skeletons([stand, walk, run])
    assert [m.name for m in pooled] == ["stand", "walk_001", "run_001"]
    assert pooled[0] is stand and all(m.skeleton.same_topology(stand.skeleton) for m in pooled)
    assert [m.retargeted_from for m in pooled] == ["", "procedural", "procedural"]
    # `first` names the target's family; a given skeleton wins over both
    assert all(m.skeleton.names == walk.skeleton.names for m in pool_skeletons([stand, walk], first=1))
    onto = pool_skeletons([walk], skeleton=stand)
    assert onto[0].skeleton is stand.skeleton and onto[0].retargeted_from == "procedural"


def test_a_skeleton_without_canonical_joints_is_refused_or_mapped():
    sk = Skeleton(("a", "b"), np.array([-1, 0]), np.array([[0, 0, 0], [0, 1, 0]]), (ALL, ROT), np.zeros(2, bool))
    odd = Motion(sk, quat.identity((2, 2)), np.zeros((2, 2, 3)), 30.0)
    with pytest.raises(SkeletonError):
        pool_skeletons([_walk(1.0), odd])
    # a family no built-in map fits, through a joint map: the procedural joints renamed
    walk = _walk(1.0)
    sk = walk.skeleton
    renamed = Skeleton(tuple("p_" + n for n in sk.names), sk.parents, sk.offsets, sk.channels, sk.end_site)
    foreign = walk.copy(skeleton=renamed)
    with pytest.raises(SkeletonError, match="unknown skeleton"):
        pool_skeletons([_other_skeleton(), foreign])
    mapping = {c: "p_" + c for c in joint_map(walk.skeleton)}
    stand, there = pool_skeletons([_other_skeleton(), foreign], mapping=mapping)
    assert there.retargeted_from == "given" and np.array_equal(there.skeleton.offsets, stand.skeleton.offsets)
    assert _worst_angle_deg(_directions(walk), _directions(there)) < 2.0


def test_cmu_onto_bandai_and_back_within_2_degrees(data_dir):
    from graphsvc.motion.library import load_motion

    cmu = load_motion(data_dir / "cmu" / "02" / "02_01.amc").slice(0, 600)
    bandai = load_motion(data_dir / "bandai" / "dataset-2" / "data" / "dataset-2_walk_normal_001.bvh")
    source, target = make_side(cmu.skeleton, [cmu]), make_side(bandai.skeleton, [bandai])
    there = retarget(cmu, source, target)
    back = retarget(there, _on(target, there), source)
    assert there.retargeted_from == "cmu" and back.skeleton is cmu.skeleton
    assert _worst_angle_deg(_directions(cmu), _directions(there)) < 2.0
    assert _worst_angle_deg(_directions(cmu), _directions(back)) < 2.0
    _, pos = motion_fk(there)
    assert np.abs(rest_heights(pos, target.table).mean() - target.foot_rest.mean()) < 1e-6  # feet on the floor


def test_build_mixed_sources_and_skeleton_flag(tmp_path, capsys):
    from graphsvc.graph.file import load_graph
    from graphsvc.motion.bvh import write_bvh

    kb = tmp_path / "kb"
    (kb / "a").mkdir(parents=True)
    (kb / "b").mkdir()
    for kind in ("walk", "run"):
        write_bvh(kb / "a" / f"{kind}_001.bvh", _walk(2.5, kind), scale=100.0)
    stand = _other_skeleton()
    held = stand.copy(
        rotations=np.repeat(stand.rotations, 40, axis=0), translations=np.repeat(stand.translations, 40, axis=0)
    )
    write_bvh(kb / "b" / "idle_001.bvh", held, scale=100.0)
    out = tmp_path / "mixed.graph"
    flags = ["--no-interp", "--no-bridges", "--no-msv", "--quiet"]
    assert main(["build", str(kb / "b"), str(kb / "a"), "-o", str(out), *flags]) == 0
    assert "2 clips retargeted onto the graph's skeleton from procedural" in capsys.readouterr().out
    graph = load_graph(out)
    assert graph.skeleton.names == stand.skeleton.names
    assert {c["name"]: c.get("retargeted_from") for c in graph.clips} == {
        "idle_001": None,
        "run_001": "procedural",
        "walk_001": "procedural",
    }
    # --skeleton: onto the procedural family's, the clip of the other family retargeted
    out2 = tmp_path / "onto.graph"
    assert main(["build", str(kb), "-o", str(out2), "--skeleton", str(kb / "a" / "walk_001.bvh"), *flags]) == 0
    capsys.readouterr()
    graph = load_graph(out2)
    assert graph.skeleton.names == standard_skeleton().names
    assert [c["name"] for c in graph.clips if c.get("retargeted_from")] == ["idle_001"]


@pytest.mark.parametrize("case, needle", [("missing", "no such file"), ("no-joints", "no canonical joints")])
def test_bad_skeleton_flag_exit_2(tmp_path, capsys, case, needle):
    from graphsvc.motion.bvh import write_bvh

    write_bvh(tmp_path / "walk_001.bvh", _walk(2.0), scale=100.0)
    target = tmp_path / "target.bvh"
    if case == "no-joints":
        sk = Skeleton(("a", "b"), np.array([-1, 0]), np.array([[0, 0, 0], [0, 1, 0]]), (ALL, ROT), np.zeros(2, bool))
        write_bvh(target, Motion(sk, quat.identity((2, 2)), np.zeros((2, 2, 3)), 30.0), scale=100.0)
    out = tmp_path / "g.graph"
    assert main(["build", str(tmp_path / "walk_001.bvh"), "-o", str(out), "--skeleton", str(target), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0] and str(target) in err[0]
    assert not out.exists()

import numpy as np
import pytest

from graphsvc.errors import SkeletonError
from graphsvc.motion import quat
from graphsvc.motion.augment import (
    WORLD_MIRROR,
    mirror_frames,
    mirror_motion,
    mirror_pairs,
    reverse_motion,
)
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.skeleton import Motion, Skeleton
from tests.conftest import still_motion, tpose_skeleton

ROT = ("Zrotation", "Xrotation", "Yrotation")
POS = ("Xposition", "Yposition", "Zposition")


def _skeleton(table, positions=()) -> Skeleton:
    """table: (name, parent name or None, offset); `positions` names joints with
    position channels (the root always has them)."""
    names = tuple(n for n, _, _ in table)
    parents = np.array([-1 if p is None else names.index(p) for _, p, _ in table])
    end = np.array([n.endswith("_End") for n in names])
    channels = tuple(
        () if e else (POS + ROT if p is None or n in positions else ROT) for (n, p, _), e in zip(table, end)
    )
    return Skeleton(names, parents, np.array([o for _, _, o in table], dtype=float), channels, end)


def _random_motion(sk: Skeleton, frames=40, seed=0) -> Motion:
    rng = np.random.default_rng(seed)
    J = sk.num_joints
    rot = quat.normalize(rng.standard_normal((frames, J, 4)))
    trans = np.broadcast_to(sk.offsets, (frames, J, 3)).copy()
    animated = np.array([bool(c) and c[0] == "Xposition" for c in sk.channels])
    trans[:, animated] += 0.05 * rng.standard_normal((frames, int(animated.sum()), 3))
    return Motion(sk, rot, trans, 30.0, name="clip", source="clip.bvh", labels=("walk", "tag"))


def _partner_names(names, pairs):
    return {names[i]: names[p] for i, p in enumerate(pairs)}


# Bandai-like: rest pose lying along +X, hips frame has the legs at ∓Y, chest
# frame the shoulders at ±Z, right-side limb frames negated ("behaviour" mirror).
BANDAI_LIKE = [
    ("joint_Root", None, (0.0, 0.0, 0.0)),
    ("Hips", "joint_Root", (0.0, 0.9, 0.0)),
    ("Spine", "Hips", (0.15, 0.0, 0.0)),
    ("Chest", "Spine", (0.09, 0.0, 0.0)),
    ("Neck", "Chest", (0.16, 0.0, 0.0)),
    ("Head", "Neck", (0.07, 0.0, 0.0)),
    ("Head_End", "Head", (0.0, 0.0, 0.0)),
    ("Shoulder_L", "Chest", (0.13, -0.002, 0.05)),
    ("UpperArm_L", "Shoulder_L", (0.05, 0.0, 0.0)),
    ("LowerArm_L", "UpperArm_L", (0.24, 0.0, 0.0)),
    ("Hand_L", "LowerArm_L", (0.22, 0.0, 0.0)),
    ("Hand_L_End", "Hand_L", (0.0, 0.0, 0.0)),
    ("Shoulder_R", "Chest", (0.13, -0.002, -0.05)),
    ("UpperArm_R", "Shoulder_R", (-0.05, 0.0, 0.0)),
    ("LowerArm_R", "UpperArm_R", (-0.24, 0.0, 0.0)),
    ("Hand_R", "LowerArm_R", (-0.22, 0.0, 0.0)),
    ("Hand_R_End", "Hand_R", (0.0, 0.0, 0.0)),
    ("UpperLeg_L", "Hips", (-0.02, -0.065, 0.0)),
    ("LowerLeg_L", "UpperLeg_L", (0.39, 0.0, 0.0)),
    ("Foot_L", "LowerLeg_L", (0.41, 0.0, 0.0)),
    ("Toes_L", "Foot_L", (0.12, 0.0, 0.0)),
    ("UpperLeg_R", "Hips", (-0.02, 0.065, 0.0)),
    ("LowerLeg_R", "UpperLeg_R", (-0.39, 0.0, 0.0)),
    ("Foot_R", "LowerLeg_R", (-0.41, 0.0, 0.0)),
    ("Toes_R", "Foot_R", (-0.12, 0.0, 0.0)),
]

CMU_LIKE = [  # left and right bones differ by millimetres, as in CMU subjects
    ("root", None, (0.0, 0.0, 0.0)),
    ("lhipjoint", "root", (0.0, 0.0, 0.0)),
    ("lfemur", "lhipjoint", (0.094, -0.102, 0.035)),
    ("ltibia", "lfemur", (0.147, -0.403, 0.0)),
    ("ltoes", "ltibia", (0.011, -0.031, 0.121)),
    ("ltoes_End", "ltoes", (0.0, 0.0, 0.063)),
    ("rhipjoint", "root", (0.0, 0.0, 0.0)),
    ("rfemur", "rhipjoint", (-0.091, -0.102, 0.035)),
    ("rtibia", "rfemur", (-0.146, -0.402, 0.0)),
    ("rtoes", "rtibia", (-0.013, -0.036, 0.12)),
    ("rtoes_End", "rtoes", (0.0, 0.0, 0.063)),
    ("lowerback", "root", (0.0, 0.0, 0.0)),
    ("thorax", "lowerback", (0.001, 0.117, -0.003)),
    ("lclavicle", "thorax", (0.0, 0.117, 0.0)),
    ("lhumerus", "lclavicle", (0.2, 0.051, -0.01)),
    ("lradius", "lhumerus", (0.275, 0.0, 0.0)),
    ("rclavicle", "thorax", (0.0, 0.117, 0.0)),
    ("rhumerus", "rclavicle", (-0.197, 0.043, -0.018)),
    ("rradius", "rhumerus", (-0.284, 0.0, 0.0)),
]


def test_pairs_on_canonical_tpose(skeleton):
    pairs = mirror_pairs(skeleton.names, skeleton.parents)
    got = _partner_names(skeleton.names, pairs)
    assert got["l_wrist"] == "r_wrist" and got["r_toe"] == "l_toe"
    assert all(got[n] == n for n in ("pelvis", "spine", "chest", "neck", "head"))
    assert np.array_equal(pairs[pairs], np.arange(skeleton.num_joints))


def test_pairs_on_cmu_names():
    names = tuple(n for n, _, _ in CMU_LIKE)
    got = _partner_names(names, mirror_pairs(names, _skeleton(CMU_LIKE).parents))
    assert got["lhipjoint"] == "rhipjoint" and got["rfemur"] == "lfemur" and got["ltoes_End"] == "rtoes_End"
    assert got["lclavicle"] == "rclavicle" and got["rradius"] == "lradius"
    # l/r initials without a partner are midline joints, not sides.
    assert got["root"] == "root" and got["lowerback"] == "lowerback"


def test_pairs_on_bandai_names():
    names = tuple(n for n, _, _ in BANDAI_LIKE)
    got = _partner_names(names, mirror_pairs(names, _skeleton(BANDAI_LIKE).parents))
    assert got["joint_Root"] == "joint_Root" and got["Head_End"] == "Head_End"
    assert got["UpperLeg_L"] == "UpperLeg_R" and got["Hand_R_End"] == "Hand_L_End"


def test_pairs_on_other_conventions():
    names = (
        "Hips",
        "LeftUpLeg",
        "RightUpLeg",
        "mixamorig:LeftHand",
        "mixamorig:RightHand",
        "hand.L",
        "hand.R",
        "thigh_l",
        "thigh_r",
    )
    got = _partner_names(names, mirror_pairs(names))
    assert got == {
        "Hips": "Hips",
        "LeftUpLeg": "RightUpLeg",
        "RightUpLeg": "LeftUpLeg",
        "mixamorig:LeftHand": "mixamorig:RightHand",
        "mixamorig:RightHand": "mixamorig:LeftHand",
        "hand.L": "hand.R",
        "hand.R": "hand.L",
        "thigh_l": "thigh_r",
        "thigh_r": "thigh_l",
    }


def test_unpaired_and_inconsistent_names_raise():
    with pytest.raises(SkeletonError, match="no mirror partner"):
        mirror_pairs(("Hips", "UpperLeg_L", "LowerLeg_L", "UpperLeg_R"))
    with pytest.raises(SkeletonError, match="not partners"):
        # l_knee hangs from the right hip.
        mirror_pairs(("pelvis", "l_hip", "r_hip", "l_knee", "r_knee"), np.array([-1, 0, 0, 2, 2]))
    with pytest.raises(SkeletonError, match="root"):
        mirror_pairs(("l_root", "r_root"), np.array([-1, 0]))


def test_no_fitting_reflection_raises():
    # The right hip sits in front where the left one sits to the side.
    sk = _skeleton([("pelvis", None, (0, 1, 0)), ("l_hip", "pelvis", (0.1, 0, 0)), ("r_hip", "pelvis", (0, 0, 0.1))])
    with pytest.raises(SkeletonError, match="reflection"):
        mirror_motion(_random_motion(sk, frames=2))


@pytest.mark.parametrize("table", [None, BANDAI_LIKE, CMU_LIKE], ids=["tpose", "bandai_like", "cmu_like"])
def test_mirror_matches_reflected_partners_in_world(table):
    sk = tpose_skeleton() if table is None else _skeleton(table, positions={"Hips"})
    motion = _random_motion(sk)
    mirrored = mirror_motion(motion)
    pairs = mirror_pairs(sk.names, sk.parents)
    world_rot, pos = motion_fk(motion)
    m_rot, m_pos = motion_fk(mirrored)
    np.testing.assert_allclose(m_pos, pos[:, pairs] @ WORLD_MIRROR.T, atol=1e-9)
    frames = mirror_frames(sk, pairs)
    expect = WORLD_MIRROR @ quat.to_matrix(world_rot[:, pairs]) @ frames
    np.testing.assert_allclose(quat.to_matrix(m_rot), expect, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(mirrored.rotations, axis=-1), 1.0, atol=1e-12)
    # Joints without position channels still carry their (mirrored) skeleton's offsets.
    fixed = np.array([not c or c[0] != "Xposition" for c in sk.channels])
    diff = mirrored.translations[:, fixed] - mirrored.skeleton.offsets[fixed]
    assert np.abs(diff).max() < 1e-12


@pytest.mark.parametrize("table", [None, BANDAI_LIKE, CMU_LIKE], ids=["tpose", "bandai_like", "cmu_like"])
def test_mirror_twice_is_identity(table):
    sk = tpose_skeleton() if table is None else _skeleton(table, positions={"Hips"})
    motion = _random_motion(sk, seed=1)
    twice = mirror_motion(mirror_motion(motion))
    dots = np.abs(np.sum(twice.rotations * motion.rotations, axis=-1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-12)
    np.testing.assert_allclose(twice.translations, motion.translations, atol=1e-9)
    np.testing.assert_allclose(twice.skeleton.offsets, sk.offsets, atol=1e-12)
    np.testing.assert_allclose(motion_fk(twice)[1], motion_fk(motion)[1], atol=1e-9)


def test_bandai_like_frames_follow_the_rig_conventions():
    sk = _skeleton(BANDAI_LIKE, positions={"Hips"})
    frames = mirror_frames(sk)
    diag = {n: tuple(np.diag(frames[i]).astype(int)) for i, n in enumerate(sk.names)}
    assert diag["joint_Root"] == (-1, 1, 1)  # the static root stays put under W
    assert diag["Hips"] == (1, -1, 1)  # legs at ∓Y
    assert diag["Spine"] == diag["Chest"] == diag["Head_End"] == (1, 1, -1)  # shoulders at ±Z
    assert diag["UpperArm_L"] == diag["Toes_R"] == (-1, -1, -1)  # negated limb frames
    assert np.allclose(frames @ frames, np.eye(3)) and np.allclose(np.linalg.det(frames), -1.0)


def test_symmetric_pose_mirrors_onto_itself():
    motion = still_motion(3)
    motion.translations[:, 0] += [0.0, 0.02, 0.3]  # moving along the mirror plane
    mirrored = mirror_motion(motion)
    assert mirrored.skeleton is motion.skeleton
    np.testing.assert_allclose(np.abs(mirrored.rotations[..., 0]), 1.0)
    np.testing.assert_allclose(mirrored.translations, motion.translations, atol=1e-15)


def test_asymmetric_bones_give_a_mirrored_skeleton():
    sk = _skeleton(CMU_LIKE)
    mirrored = mirror_motion(_random_motion(sk, frames=3))
    assert mirrored.skeleton is not sk and mirrored.skeleton.same_topology(sk)
    lf, rf = sk.index("lfemur"), sk.index("rfemur")
    np.testing.assert_allclose(mirrored.skeleton.offsets[lf], sk.offsets[rf] * [-1, 1, 1])


def test_mirror_keeps_metadata():
    motion = _random_motion(tpose_skeleton(), frames=5)
    mirrored = mirror_motion(motion)
    assert (mirrored.name, mirrored.source, mirrored.labels) == ("clip_mirror", "clip.bvh", ("walk", "tag"))
    assert mirrored.rate_hz == 30.0
    assert mirrored.rotations.shape == motion.rotations.shape


def test_reverse():
    motion = _random_motion(tpose_skeleton(), frames=7)
    rev = reverse_motion(motion)
    assert rev.name == "clip_reverse" and rev.labels == motion.labels and rev.source == motion.source
    np.testing.assert_array_equal(rev.rotations[0], motion.rotations[-1])
    np.testing.assert_array_equal(rev.translations[2], motion.translations[4])
    twice = reverse_motion(rev)
    np.testing.assert_array_equal(twice.rotations, motion.rotations)
    np.testing.assert_array_equal(twice.translations, motion.translations)
    rev.rotations[0] = 0.0  # a copy, not a view
    assert np.all(np.linalg.norm(motion.rotations, axis=-1) > 0.5)


def test_mirror_swaps_side_words_in_labels():
    from graphsvc.motion.augment import mirror_label

    assert mirror_label("walk-turn-left") == "walk-turn-right"
    assert mirror_label("raise-up-right-hand") == "raise-up-left-hand"
    assert mirror_label("wave-both-hands") == "wave-both-hands"
    assert mirror_label("LeftHandWave") == "RightHandWave"
    assert mirror_label("upright") == "upright"  # a word that merely contains "right"
    m = still_motion(3)
    m.labels = ("wave-left-hand", "left-handed-player")
    assert mirror_motion(m).labels == ("wave-right-hand", "right-handed-player")

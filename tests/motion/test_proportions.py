"""Segment lengths of a skeleton, a performer's from a file or a height, and a motion
put on them (graphsvc.motion.proportions)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from graphsvc.errors import FormatError, InputError, MissingFileError
from graphsvc.motion.bvh import read_bvh, write_bvh
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.procedural import make_clip
from graphsvc.motion.procedural.body import standard_skeleton
from graphsvc.motion.proportions import (
    SEGMENTS,
    complete_lengths,
    leg_length,
    lengths_for_height,
    load_performer_file,
    on_performer,
    performer_lengths,
    performer_skeleton,
    segment_lengths,
    skeleton_height,
)
from graphsvc.motion.skeleton import Skeleton

BANDAI = Path("/work/shared/data/bandai/dataset-1/data")

# The procedural skeleton's segments, from its offsets (procedural/body.py) by hand.
PROCEDURAL = {
    "lower_spine": 0.10,
    "upper_spine": 0.14,
    "chest": 0.22,
    "neck": 0.10,
    "l_clavicle": math.sqrt(0.17**2 + 0.19**2),
    "l_upper_arm": 0.29,
    "l_forearm": 0.26,
    "r_clavicle": math.sqrt(0.17**2 + 0.19**2),
    "r_upper_arm": 0.29,
    "r_forearm": 0.26,
    "l_pelvis": math.sqrt(0.09**2 + 0.07**2),
    "l_thigh": 0.42,
    "l_shin": 0.42,
    "l_foot": math.sqrt(0.06**2 + 0.13**2),
    "r_pelvis": math.sqrt(0.09**2 + 0.07**2),
    "r_thigh": 0.42,
    "r_shin": 0.42,
    "r_foot": math.sqrt(0.06**2 + 0.13**2),
}


def _walk():
    return make_clip("walk", np.random.default_rng(4), standard_skeleton(), 30.0, 3.0, "walk_t")


def _with_collar(sk: Skeleton) -> Skeleton:
    """The procedural skeleton with a collar joint between chest and left shoulder:
    chest → l_collar (0.05, 0.19, 0) → l_shoulder (0.12, 0, 0)."""
    i = sk.index("l_shoulder")
    names = list(sk.names[:i]) + ["l_collar"] + list(sk.names[i:])
    old = list(sk.names)
    parents = [-1]
    for n in names[1:]:
        if n == "l_collar":
            parents.append(names.index("chest"))
        elif n == "l_shoulder":
            parents.append(names.index("l_collar"))
        else:
            parents.append(names.index(old[sk.parents[old.index(n)]]))
    offsets = [sk.offsets[old.index(n)] if n not in ("l_collar", "l_shoulder") else None for n in names]
    offsets[names.index("l_collar")] = np.array([0.05, 0.19, 0.0])
    offsets[names.index("l_shoulder")] = np.array([0.12, 0.0, 0.0])
    channels = [sk.channels[old.index(n)] if n != "l_collar" else sk.channels[i] for n in names]
    end = [n.endswith("_End") for n in names]
    return Skeleton(tuple(names), np.array(parents), np.array(offsets), tuple(channels), np.array(end))


def test_segment_lengths_of_the_procedural_skeleton_by_hand():
    got = segment_lengths(standard_skeleton())
    assert list(got) == list(SEGMENTS)
    for name, want in PROCEDURAL.items():
        assert got[name] == pytest.approx(want, abs=1e-12), name
    # (0.42 + 0.42) + 0.10 + 0.14 + 0.22 + 0.10 = 1.40 m over 0.80: the 1.75 m adult
    assert skeleton_height(got) == pytest.approx(1.75, abs=1e-12)
    # pelvis → hip → knee → ankle: √(0.09² + 0.07²) + 0.84
    assert leg_length(got) == pytest.approx(math.sqrt(0.013) + 0.84, abs=1e-12)


def test_a_segment_spans_the_bones_between_its_joints():
    sk = _with_collar(standard_skeleton())
    lengths = segment_lengths(sk)
    assert lengths["l_clavicle"] == pytest.approx(math.sqrt(0.05**2 + 0.19**2) + 0.12, abs=1e-12)  # its two bones
    assert lengths["r_clavicle"] == pytest.approx(math.sqrt(0.17**2 + 0.19**2), abs=1e-12)
    out = performer_skeleton(sk, {**lengths, "l_clavicle": 2 * lengths["l_clavicle"]})
    for n in ("l_collar", "l_shoulder"):  # both bones of the segment, doubled
        np.testing.assert_allclose(out.offsets[sk.index(n)], 2 * sk.offsets[sk.index(n)], atol=1e-15)
    for n in ("r_shoulder", "l_elbow", "neck", "l_knee"):  # the rest kept
        np.testing.assert_allclose(out.offsets[sk.index(n)], sk.offsets[sk.index(n)], atol=1e-15)


def test_performer_skeleton_takes_each_segment_and_scales_end_sites_with_their_segment():
    sk = standard_skeleton()
    want = {name: v * (1.0 + 0.01 * i) for i, (name, v) in enumerate(PROCEDURAL.items())}
    out = performer_skeleton(sk, want)
    got = segment_lengths(out)
    for name in SEGMENTS:
        assert got[name] == pytest.approx(want[name], abs=1e-12), name
    # head_End by the neck's ratio (1.03), a hand tip by the forearm's, a toe tip by the foot's
    np.testing.assert_allclose(out.offsets[sk.index("head_End")], [0.0, 0.18 * 1.03, 0.0], atol=1e-15)
    np.testing.assert_allclose(out.offsets[sk.index("l_wrist_End")], [0.18 * 1.06, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(out.offsets[sk.index("r_toe_End")], [0.0, 0.0, 0.05 * 1.17], atol=1e-15)
    assert out.same_topology(sk)


def test_height_175_to_196_scales_every_bone_by_112():
    sk = standard_skeleton()
    kb = segment_lengths(sk)
    tall = lengths_for_height(kb, 1.96)
    for name in SEGMENTS:
        assert tall[name] == pytest.approx(1.12 * kb[name], rel=1e-12)
    assert skeleton_height(tall) == pytest.approx(1.96, rel=1e-12)
    out = performer_skeleton(sk, tall)
    np.testing.assert_allclose(out.offsets, 1.12 * sk.offsets, rtol=1e-12, atol=1e-15)
    assert performer_lengths(sk, height=1.96) == pytest.approx(tall, rel=1e-12)


@pytest.mark.parametrize("height", [-1.75, 0.0, float("nan"), float("inf"), 175.0, "tall"])
def test_a_height_not_in_metres_is_refused(height):
    with pytest.raises(InputError, match="height"):
        lengths_for_height(segment_lengths(standard_skeleton()), height)


def test_on_performer_of_a_uniform_scale_scales_every_position():
    walk = _walk()
    out = on_performer(walk, performer_skeleton(walk.skeleton, performer_lengths(walk.skeleton, height=1.96)))
    np.testing.assert_array_equal(out.rotations, walk.rotations)
    np.testing.assert_allclose(motion_fk(out)[1], 1.12 * motion_fk(walk)[1], rtol=1e-9, atol=1e-12)


def test_on_performer_keeps_the_feet_on_the_floor_and_scales_the_stride_with_the_legs():
    walk = _walk()
    sk = walk.skeleton
    kb = segment_lengths(sk)
    # longer legs (thigh and shin × 1.15), the rest as it was
    long_legs = {**kb, **{f"{s}_{b}": 1.15 * kb[f"{s}_{b}"] for s in "lr" for b in ("thigh", "shin")}}
    out = on_performer(walk, performer_skeleton(sk, long_legs))
    k = leg_length(long_legs) / leg_length(kb)
    assert k == pytest.approx((math.sqrt(0.013) + 1.15 * 0.84) / (math.sqrt(0.013) + 0.84), rel=1e-12)
    before, after = motion_fk(walk)[1], motion_fk(out)[1]
    feet = [sk.index(n) for n in ("l_ankle", "r_ankle", "l_toe", "r_toe")]
    low_before = before[:, feet, 1].min(axis=1)
    low_after = after[:, feet, 1].min(axis=1)
    # a foot on the floor stays there (the ankle's height above it scales with k,
    # the hip's drop below the pelvis does not: within a centimetre)
    assert abs(np.median(low_after) - np.median(low_before)) < 0.01
    assert low_after.min() > -0.01
    # the ground track is the original's times k
    pelvis = sk.index("pelvis")
    np.testing.assert_allclose(after[:, pelvis, [0, 2]], k * before[:, pelvis, [0, 2]], rtol=1e-12, atol=1e-12)


def test_on_performer_refuses_another_topology():
    walk = _walk()
    with pytest.raises(InputError, match="not the motion's"):
        on_performer(walk, _with_collar(walk.skeleton))


def test_a_bvh_s_proportions_round_trip(tmp_path):
    walk = _walk()
    want = {name: v * (1.2 - 0.02 * i) for i, (name, v) in enumerate(PROCEDURAL.items())}
    write_bvh(tmp_path / "performer.bvh", on_performer(walk, performer_skeleton(walk.skeleton, want)), scale=100.0)
    read = read_bvh(tmp_path / "performer.bvh")
    got = segment_lengths(read.skeleton)
    for name in SEGMENTS:
        assert got[name] == pytest.approx(want[name], abs=1e-6), name
    from_file = performer_lengths(walk.skeleton, performer=tmp_path / "performer.bvh")
    for name in SEGMENTS:
        assert from_file[name] == pytest.approx(want[name], abs=1e-6), name


def _performer_json(path: Path, segments, **extra) -> Path:
    path.write_text(json.dumps({"format": "graphsvc-performer", "version": 1, "segments_m": segments, **extra}))
    return path


def test_a_json_performer_fills_the_segments_it_leaves_out(tmp_path):
    sk = standard_skeleton()
    # l_thigh × 1.2, r_thigh × 1.1: the others × 1.15, their mean ratio
    path = _performer_json(tmp_path / "p.json", {"l_thigh": 0.504, "r_thigh": 0.462})
    assert load_performer_file(path) == {"l_thigh": 0.504, "r_thigh": 0.462}
    got = performer_lengths(sk, performer=path)
    assert got["l_thigh"] == 0.504 and got["r_thigh"] == 0.462
    for name in SEGMENTS:
        if name not in ("l_thigh", "r_thigh"):
            assert got[name] == pytest.approx(1.15 * PROCEDURAL[name], rel=1e-12), name
    assert segment_lengths(performer_skeleton(sk, got)) == pytest.approx(got, abs=1e-12)


@pytest.mark.parametrize(
    "text, match",
    [
        ("{", "not valid JSON"),
        ('{"format": "other", "version": 1, "segments_m": {"l_thigh": 0.4}}', "graphsvc-performer"),
        ('{"format": "graphsvc-performer", "version": 2, "segments_m": {"l_thigh": 0.4}}', "version 2"),
        ('{"format": "graphsvc-performer", "version": 1, "segments_m": {}}', "non-empty"),
        ('{"format": "graphsvc-performer", "version": 1, "segments_m": {"l_thigh": -0.4}}', "l_thigh must be"),
        ('{"format": "graphsvc-performer", "version": 1, "segments_m": {"l_thigh": "long"}}', "l_thigh must be"),
        ('{"format": "graphsvc-performer", "version": 1, "segments_m": {"l_thigh": 46}}', "at most 3"),
        ('{"format": "graphsvc-performer", "version": 1, "segments_m": {"l_thigh": 1e308}}', "at most 3"),
        (
            '{"format": "graphsvc-performer", "version": 1, "segments_m": {"tail": 0.3, "l_thig": 0.4, "l_shin": 0.4}}',
            "unknown segments: l_thig, tail",
        ),
        (
            '{"format": "graphsvc-performer", "version": 1, "segments_m": {"l_shin": 0.4}, "mass": 70}',
            "unknown keys: mass",
        ),
    ],
)
def test_a_bad_performer_file_is_a_format_error_naming_it(tmp_path, text, match):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(FormatError, match=match) as err:
        performer_lengths(standard_skeleton(), performer=path)
    assert str(path) in str(err.value)


def test_a_missing_performer_file_and_a_missing_choice_are_refused(tmp_path):
    with pytest.raises(MissingFileError, match="no such file"):
        performer_lengths(standard_skeleton(), performer=tmp_path / "absent.json")
    with pytest.raises(InputError, match="one of the two"):
        performer_lengths(standard_skeleton(), performer=tmp_path / "p.json", height=1.8)
    with pytest.raises(InputError, match="one of the two"):
        performer_lengths(standard_skeleton())


def test_complete_lengths_refuses_what_it_cannot_use():
    kb = segment_lengths(standard_skeleton())
    with pytest.raises(InputError, match="unknown segments: wing"):
        complete_lengths(kb, {"wing": 0.3})
    with pytest.raises(InputError, match="must be a number of metres"):
        complete_lengths(kb, {"l_shin": float("nan")})
    with pytest.raises(InputError, match="at most 3"):
        complete_lengths(kb, {"l_shin": 42.0})
    with pytest.raises(InputError, match="no segment given"):
        complete_lengths({**kb, "l_shin": 0.0}, {"l_shin": 0.4})


def _bandai_file():
    files = sorted(BANDAI.glob("*.bvh"))[:1] if BANDAI.is_dir() else []
    if not files:
        pytest.skip("no Bandai-Namco data")
    return files[0]


def test_a_bandai_skeleton_s_height_and_proportions_on_the_procedural_skeleton():
    bandai = read_bvh(_bandai_file()).skeleton
    lengths = segment_lengths(bandai)
    assert 1.45 < skeleton_height(lengths) < 1.95  # an adult actor
    for s in "lr":  # a thigh and a shin of 35–50 cm, a forearm of 20–30
        assert 0.35 < lengths[f"{s}_thigh"] < 0.5 and 0.35 < lengths[f"{s}_shin"] < 0.5
        assert 0.2 < lengths[f"{s}_forearm"] < 0.3
    # its clavicle is two bones (Chest → Shoulder → UpperArm) whose rest offsets point
    # differently on the two sides; their lengths do not
    assert lengths["l_clavicle"] == pytest.approx(lengths["r_clavicle"], abs=1e-3)
    on_procedural = segment_lengths(performer_skeleton(standard_skeleton(), lengths))
    for name in SEGMENTS:
        assert on_procedural[name] == pytest.approx(lengths[name], abs=1e-9), name
    # and the other way round: the procedural proportions on the Bandai skeleton
    back = segment_lengths(performer_skeleton(bandai, PROCEDURAL))
    for name in SEGMENTS:
        assert back[name] == pytest.approx(PROCEDURAL[name], abs=1e-9), name


def test_a_foreign_skeleton_s_segments_through_a_guessed_mapping():
    from graphsvc.errors import SkeletonError
    from tests.motion.test_joints import SCHEMES, _skeleton

    sk = _skeleton(**SCHEMES["LeftForeArm"])  # Hips, Spine, Spine2, LeftShoulder → LeftArm → LeftForeArm, LeftUpLeg …
    sk = Skeleton(sk.names, sk.parents, np.tile([0.0, 0.1, 0.0], (sk.num_joints, 1)), sk.channels, sk.end_site)
    with pytest.raises(SkeletonError, match="unknown skeleton"):
        segment_lengths(sk)
    got = segment_lengths(sk, "guess")
    # every segment one bone of 0.1 m but the clavicles: Spine2 → LeftShoulder → LeftArm
    for name in SEGMENTS:
        assert got[name] == pytest.approx(0.2 if name.endswith("clavicle") else 0.1, abs=1e-12), name


def test_a_skeleton_without_length_is_refused_not_divided_by():
    sk = standard_skeleton()
    flat = Skeleton(sk.names, sk.parents, np.zeros_like(sk.offsets), sk.channels, sk.end_site)
    with pytest.raises(InputError, match="no height"):
        performer_lengths(flat, height=1.8)
    with pytest.raises(InputError, match="no segment given that the knowledge base's skeleton has"):
        performer_skeleton(flat, PROCEDURAL)
    # legs of no length: a motion put on them stands at the floor (its translations × 0);
    # put back from them, nothing scales its translations (not a division by zero)
    walk = _walk()
    legless = dict(PROCEDURAL, l_pelvis=0.0, r_pelvis=0.0, l_thigh=0.0, r_thigh=0.0, l_shin=0.0, r_shin=0.0)
    on_legless = on_performer(walk, performer_skeleton(walk.skeleton, legless))
    np.testing.assert_array_equal(on_legless.translations[:, 0], 0.0)
    back = on_performer(on_legless, walk.skeleton)
    np.testing.assert_array_equal(back.translations[:, 0], 0.0)
    np.testing.assert_array_equal(back.translations[:, 1:], walk.translations[:, 1:])

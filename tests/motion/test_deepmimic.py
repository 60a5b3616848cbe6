"""DeepMimic motion files: hand-made files with known rotations give the joint
positions worked out by hand, uneven durations are resampled, and bad files give one
line naming the file and the problem (exit 2)."""

import json
import math

import numpy as np
import pytest

from graphsvc.cli import main
from graphsvc.errors import FormatError
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.library import find_motion_files, load_motion

H = math.sqrt(0.5)
IDENTITY = [1.0, 0.0, 0.0, 0.0]


def frame(duration=1 / 30, root=(0.0, 0.9, 0.0), root_rot=IDENTITY, knee_r=0.0, shoulder_l=IDENTITY):
    """A frame of the humanoid: duration, root position and rotation, then chest, neck,
    right hip, right knee, right ankle, right shoulder, right elbow, left hip, left knee,
    left ankle, left shoulder, left elbow."""
    return (
        [duration, *root, *root_rot]
        + IDENTITY * 3
        + [knee_r]
        + IDENTITY * 2
        + [0.0]
        + IDENTITY
        + [0.0]
        + IDENTITY
        + list(shoulder_l)
        + [0.0]
    )


def write(path, data) -> str:
    path.write_text(json.dumps(data) if not isinstance(data, str) else data)
    return str(path)


def test_known_rotations_give_hand_worked_positions(tmp_path):
    # Frame 0: the right knee bent -90° about its axis (+Z), the left shoulder 90° about
    # +X. Frame 1: the root at (1, 0.9, 2), turned 90° about +Y. Offsets: humanoid.urdf
    # times 0.25. In DeepMimic's frame (facing +X, right at +Z), frame 0:
    #   right knee = (0, 0.9, 0) + (0, 0, 0.084887) + (0, -0.421546, 0) = (0, 0.478454, 0.084887)
    #   right ankle = knee + Rz(-90°)(0, -0.40987, 0) = knee + (-0.40987, 0, 0)
    #   left shoulder = (0, 0.9, 0) + (0, 0.236151, 0) + (-0.02405, 0.2435, -0.18311)
    #   left elbow = shoulder + Rx(90°)(0, -0.274788, 0) = shoulder + (0, 0, -0.274788)
    # frame 1 (a quarter turn about Y maps (x, y, z) to (z, y, -x)):
    #   head = root + (0, 0.236151 + 0.223894 + 0.175, 0) = (1, 1.535045, 2)
    #   right toe: (0, 0, 0.084887) + (0, -0.421546, 0) + (0, -0.40987, 0) + (0.1335, -0.05, 0)
    #     = (0.1335, -0.881416, 0.084887), turned (0.084887, -0.881416, -0.1335), + root
    # graphsvc's frame (facing +Z, left at +X) is DeepMimic's turned: (x, y, z) → (-z, y, x).
    path = write(
        tmp_path / "pose.txt",
        {
            "Loop": "none",
            "Frames": [
                frame(knee_r=-math.pi / 2, shoulder_l=[H, H, 0.0, 0.0]),
                frame(duration=0.0, root=(1.0, 0.9, 2.0), root_rot=[H, 0.0, H, 0.0]),
            ],
        },
    )
    m = load_motion(path)
    assert (m.num_frames, m.rate_hz, m.labels) == (2, 30.0, ("pose",))
    t = joint_map(m.skeleton)
    assert t.family == "deepmimic" and t.missing == {"spine"} and t["spine"] == t["chest"]
    _, p = motion_fk(m)

    def dm(x, y, z):
        return [-z, y, x]

    np.testing.assert_allclose(p[0, t["r_knee"]], dm(0.0, 0.478454, 0.084887), atol=1e-9)
    np.testing.assert_allclose(p[0, t["r_ankle"]], dm(-0.40987, 0.478454, 0.084887), atol=1e-9)
    np.testing.assert_allclose(p[0, t["l_shoulder"]], dm(-0.02405, 1.379651, -0.18311), atol=1e-9)
    np.testing.assert_allclose(p[0, t["l_elbow"]], dm(-0.02405, 1.379651, -0.457898), atol=1e-9)
    np.testing.assert_allclose(p[1, t["head"]], dm(1.0, 1.535045, 2.0), atol=1e-9)
    np.testing.assert_allclose(p[1, t["r_toe"]], dm(1.084887, 0.018584, 1.8665), atol=1e-9)
    np.testing.assert_allclose(p[1, t["pelvis"]], dm(1.0, 0.9, 2.0), atol=1e-12)


def test_uneven_durations_resampled_to_the_median_rate(tmp_path):
    # Frames at 0, 0.1 and 0.4 s with the root at x = 0, 1 and 4: the median duration
    # 0.2 s gives 5 Hz, samples at 0, 0.2, 0.4 s, x = 0, 1 + 3·(0.1 / 0.3) = 2, 4
    # (DeepMimic's +X is graphsvc's +Z).
    frames = [frame(0.1, root=(0.0, 0.9, 0.0)), frame(0.3, root=(1.0, 0.9, 0.0)), frame(0.0, root=(4.0, 0.9, 0.0))]
    path = write(tmp_path / "humanoid3d_glide.txt", {"Frames": frames})
    m = load_motion(path)
    assert m.rate_hz == 5.0 and m.labels == ("glide",)
    np.testing.assert_allclose(m.translations[:, 0, 2], [0.0, 2.0, 4.0], atol=1e-12)
    m = load_motion(path, rate_hz=10.0)
    np.testing.assert_allclose(m.translations[:, 0, 2], [0.0, 1.0, 2.0, 3.0, 4.0], atol=1e-12)


def test_folder_scan_collects_deepmimic_txt_only(tmp_path):
    write(tmp_path / "turn_left0.txt", {"Loop": "wrap", "Frames": [frame(), frame(0.0)]})
    write(tmp_path / "content_label.txt", "walk\nrun\n")
    write(tmp_path / "notes.txt", {"other": 1})
    assert [p.name for p in find_motion_files([str(tmp_path)])] == ["turn_left0.txt"]
    assert load_motion(tmp_path / "turn_left0.txt").labels == ("turn_left",)


BAD = {
    "missing key": ({"Loop": "wrap"}, 'missing key "Frames"'),
    "non-finite": (
        '{"Frames": [' + json.dumps(frame()).replace("0.9", "NaN", 1) + "]}",
        "frame 0: non-finite value (nan) for root position y",
    ),
    "extra joint": ({"Frames": [frame() + IDENTITY]}, "values for a joint the skeleton lacks"),
    "too few": ({"Frames": [frame()[:-5]]}, "from left_shoulder rotation w on missing"),
    "mirror joint": ({"Frames": [frame()], "RightJoints": [3, 20]}, "names joint 20, which the skeleton lacks"),
    "zero frames": ({"Loop": "none", "Frames": []}, "zero frames"),
    "no duration": ({"Frames": [frame(0.0), frame(0.0)]}, "every frame lasts 0 s"),
    "zero quaternion": ({"Frames": [frame(shoulder_l=[0.0] * 4)]}, "left_shoulder's rotation quaternion has zero"),
    "not json": ("{Frames: oops", "not valid JSON"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_file_one_line_naming_file_and_problem(tmp_path, capsys, case):
    data, needle = BAD[case]
    path = write(tmp_path / "bad.txt", data)
    with pytest.raises(FormatError, match="bad.txt"):
        load_motion(path)
    for argv in (["inspect", path], ["build", path, "-o", str(tmp_path / "g.graph")]):
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert path in err and needle in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.txt"]

import json

import numpy as np
import pytest

from graphsvc.errors import LayoutError, SkeletonError
from graphsvc.motion import quat
from graphsvc.motion.skeleton import Skeleton
from graphsvc.sensors.layout import PRESETS, load_layout, place


def test_presets_have_expected_sensors():
    assert PRESETS["wrists-ankles"].sensor_names == ("l_wrist", "r_wrist", "l_ankle", "r_ankle")
    assert len(PRESETS["kelly6"].sensors) == 6
    assert PRESETS["right-wrist"].sensor_names == ("r_wrist",)
    assert load_layout("kelly6") is PRESETS["kelly6"]


def test_default_frames_follow_spec_in_tpose(skeleton):
    p = place(PRESETS["kelly6"], skeleton)
    m = quat.to_matrix(p.rotation)  # columns: sensor X, Y, Z in segment (= world, rest) coordinates
    np.testing.assert_allclose(m[0][:, 0], [1, 0, 0], atol=1e-12)  # left forearm: X away from body
    np.testing.assert_allclose(m[0][:, 2], [0, 1, 0], atol=1e-12)  # Z up
    np.testing.assert_allclose(m[1][:, 0], [-1, 0, 0], atol=1e-12)  # right forearm
    np.testing.assert_allclose(m[2][:, 0], [0, -1, 0], atol=1e-12)  # shin: X down the leg
    np.testing.assert_allclose(m[2][:, 2], [0, 0, 1], atol=1e-12)  # Z forward
    for r in m:
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)


def test_custom_layout_file_json_and_toml(tmp_path, skeleton):
    j = tmp_path / "one.json"
    j.write_text(
        json.dumps({"sensors": [{"name": "hand", "segment": "r_elbow", "along": 1.0, "rotation_wxyz": [0, 0, 0, 1]}]})
    )
    layout = load_layout(str(j))
    assert layout.name == "one" and layout.sensors[0].toward == "r_wrist"
    p = place(layout, skeleton)
    np.testing.assert_allclose(p.rotation[0], [0, 0, 0, 1])
    t = tmp_path / "two.toml"
    t.write_text(
        'name = "shins"\n[[sensors]]\nname = "l"\nsegment = "l_knee"\n[[sensors]]\nname = "r"\nsegment = "r_knee"\nalong = 0.8\n'
    )
    assert load_layout(str(t)).sensor_names == ("l", "r")


@pytest.mark.parametrize(
    "content",
    [
        '{"sensors": []}',
        '{"sensors": [{"segment": "tail"}]}',
        '{"sensors": [{"segment": "l_knee", "along": "x"}]}',
        '{"sensors": [{"segment": "l_knee", "colour": 1}]}',
        '{"sensors": [{"segment": "l_knee"}, {"segment": "l_knee"}]}',
        "not json",
    ],
)
def test_bad_layout_files_raise_layout_error(tmp_path, content):
    f = tmp_path / "bad.json"
    f.write_text(content)
    with pytest.raises(LayoutError):
        load_layout(str(f))


def test_unknown_layout_name():
    with pytest.raises(LayoutError, match="not a preset"):
        load_layout("elbows")


def test_layout_on_skeleton_lacking_joints_is_refused(skeleton):
    keep = [i for i, n in enumerate(skeleton.names) if not n.startswith("r_")]
    names = tuple(skeleton.names[i] for i in keep)
    parents = [-1] + [keep.index(skeleton.parents[i]) for i in keep[1:]]
    small = Skeleton(
        names,
        np.array(parents),
        skeleton.offsets[keep],
        tuple(skeleton.channels[i] for i in keep),
        np.zeros(len(keep), bool),
    )
    with pytest.raises(SkeletonError):
        place(PRESETS["right-wrist"], small)


def test_dip6_places_six_sensors_on_the_tpose(skeleton):
    """DIP-IMU's six: forearms near the wrists, shins just below the knees, head and
    pelvis. Positions worked out from tests/conftest.py's T-pose offsets: the left
    elbow at (0.46, 1.46, 0), wrist (0.71, 1.46, 0); the left knee at (0.10, 0.49, 0),
    ankle (0.10, 0.07, 0); the head at (0, 1.61, 0); the pelvis at (0, 0.96, 0)."""
    from graphsvc.motion.kinematics import forward_kinematics
    from graphsvc.sensors.accelerometer import sensor_poses
    from tests.conftest import still_motion

    layout = PRESETS["dip6"]
    assert layout.sensor_names == ("l_wrist", "r_wrist", "l_knee", "r_knee", "head", "pelvis")
    assert load_layout("dip6") is layout
    m = still_motion(1)
    world_rot, world_pos = forward_kinematics(m.rotations, m.translations, skeleton.parents)
    position, _ = sensor_poses(world_rot, world_pos, place(layout, skeleton))
    expected = [
        (0.685, 1.46, 0.0),
        (-0.685, 1.46, 0.0),
        (0.10, 0.448, 0.0),
        (-0.10, 0.448, 0.0),
        (0.0, 1.61, 0.0),
        (0.0, 0.96, 0.0),
    ]
    np.testing.assert_allclose(position[0], expected, atol=1e-12)
    p = place(layout, skeleton)
    assert [skeleton.names[j] for j in p.segment] == ["l_elbow", "r_elbow", "l_knee", "r_knee", "head", "pelvis"]
    assert [skeleton.names[j] for j in p.toward] == ["l_wrist", "r_wrist", "l_ankle", "r_ankle", "neck", "spine"]


def test_dip6_root_sensor_is_the_pelvis():
    from graphsvc.sensors.layout import root_sensor

    assert root_sensor(PRESETS["dip6"]) == 5 == PRESETS["dip6"].sensor_names.index("pelvis")


def test_every_layout_help_lists_the_presets():
    """--layout's help, wherever a command takes it, names every preset (from PRESETS)."""
    import argparse

    from graphsvc.cli import build_parser

    def parsers(parser):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    yield sub
                    yield from parsers(sub)

    helps = [a.help for p in parsers(build_parser()) for a in p._actions if "--layout" in a.option_strings]
    assert len(helps) >= 5  # build, simulate, evaluate, relayout, demo
    for text in helps:
        assert all(name in text for name in PRESETS), text

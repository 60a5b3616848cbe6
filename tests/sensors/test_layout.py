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
    j.write_text(json.dumps({"sensors": [{"name": "hand", "segment": "r_elbow", "along": 1.0,
                                          "rotation_wxyz": [0, 0, 0, 1]}]}))
    layout = load_layout(str(j))
    assert layout.name == "one" and layout.sensors[0].toward == "r_wrist"
    p = place(layout, skeleton)
    np.testing.assert_allclose(p.rotation[0], [0, 0, 0, 1])
    t = tmp_path / "two.toml"
    t.write_text('name = "shins"\n[[sensors]]\nname = "l"\nsegment = "l_knee"\n[[sensors]]\nname = "r"\nsegment = "r_knee"\nalong = 0.8\n')
    assert load_layout(str(t)).sensor_names == ("l", "r")


@pytest.mark.parametrize("content", [
    '{"sensors": []}',
    '{"sensors": [{"segment": "tail"}]}',
    '{"sensors": [{"segment": "l_knee", "along": "x"}]}',
    '{"sensors": [{"segment": "l_knee", "colour": 1}]}',
    '{"sensors": [{"segment": "l_knee"}, {"segment": "l_knee"}]}',
    'not json',
])
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
    small = Skeleton(names, np.array(parents), skeleton.offsets[keep], tuple(skeleton.channels[i] for i in keep), np.zeros(len(keep), bool))
    with pytest.raises(SkeletonError):
        place(PRESETS["right-wrist"], small)

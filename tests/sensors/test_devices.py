"""Device input: Xsens MVNX files (real exports and small synthetic ones with values
worked out by hand), device name maps, the device CSV's comments, and the CLI."""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from graphsvc.cli import main
from graphsvc.errors import FormatError, InputError
from graphsvc.motion import quat
from graphsvc.sensors.devices import DEVICE_MAPS, apply_device_map, device_map, generic_key, read_mvnx
from graphsvc.sensors.files import read_recording
from graphsvc.sensors.layout import PRESETS
from graphsvc.sensors.recording import Recording, export_csv, import_csv
from tests.conftest import still_motion

G = 9.81
NS = "http://www.xsens.com/mvn/mvnx"
C45 = math.sqrt(0.5)  # cos 45° = sin 45°
FREE_FILE = "blender-mvnx-io_test_mocap.mvnx"
RAW_FILE = "robotology_Meri-020.mvnx"
XSENS_UPPER = (
    "Pelvis",
    "T8",
    "Head",
    "RightShoulder",
    "RightUpperArm",
    "RightForeArm",
    "RightHand",
    "LeftShoulder",
    "LeftUpperArm",
    "LeftForeArm",
    "LeftHand",
)
XSENS_FULL = XSENS_UPPER + ("RightUpperLeg", "RightLowerLeg", "RightFoot", "LeftUpperLeg", "LeftLowerLeg", "LeftFoot")


def mvnx_text(labels, frames, rate=60, version="3", namespace=True, sensor_count=None) -> str:
    """An MVNX document: `frames` is a list of (attributes, {element: values}), values
    written as given (a string) or joined with spaces (a sequence of numbers)."""
    ns = f' xmlns="{NS}"' if namespace else ""
    out = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<mvnx{ns} version="{version}">',
        '  <mvn version="2019.0.0" build="test"/>',
        f'  <subject label="s" frameRate="{rate}" segmentCount="23" configuration="FullBody">',
        '    <segments><segment label="Pelvis" id="1"/></segments>',
        "    <sensors>",
    ]
    out += [f'      <sensor label="{n}"/>' for n in labels]
    count = len(labels) if sensor_count is None else sensor_count
    out += ["    </sensors>", f'    <frames segmentCount="23" sensorCount="{count}" jointCount="22">']
    for attrs, fields in frames:
        a = " ".join(f'{k}="{v}"' for k, v in attrs.items())
        out.append(f"      <frame {a}>")
        for name, values in fields.items():
            text = values if isinstance(values, str) else " ".join(f"{v:.6f}" for v in np.ravel(values))
            out.append(f"        <{name}>{text}</{name}>")
        out.append("      </frame>")
    out += ["    </frames>", "  </subject>", '  <securityCode code="0"/>', "</mvnx>", ""]
    return "\n".join(out)


def write_mvnx(path, *args, **kwargs):
    path.write_text(mvnx_text(*args, **kwargs))
    return path


def normal(k, rate=60, **fields):
    return {"time": str(round(1000 * k / rate)), "index": str(k), "type": "normal"}, fields


# ---------------------------------------------------------------- axes


def test_xsens_axes_onto_graphsvc_axes():
    """A sensor whose Xsens orientation is the identity has its X (Xsens forward) along
    graphsvc +Z, its Y (Xsens left) along +X and its Z (up) along +Y."""
    from graphsvc.sensors.axes import Q_Z_UP_TO_Y_UP, z_up_to_y_up

    q = z_up_to_y_up(quat.identity())
    for local, world in (((1, 0, 0), (0, 0, 1)), ((0, 1, 0), (1, 0, 0)), ((0, 0, 1), (0, 1, 0))):
        np.testing.assert_allclose(quat.rotate(q, np.array(local, float)), world, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(Q_Z_UP_TO_Y_UP), 1.0)
    # The same change as optical.to_y_up for points: (x, y, z) → (y, z, x).
    from graphsvc.sensors.optical import to_y_up

    v = np.array([0.3, -1.2, 2.5])
    np.testing.assert_allclose(quat.rotate(Q_Z_UP_TO_Y_UP, v), to_y_up(v, "z"), atol=1e-12)
    assert np.isnan(z_up_to_y_up(np.full(4, np.nan))).all()


# ---------------------------------------------------------------- synthetic MVNX


@pytest.mark.parametrize("namespace", [True, False])
def test_free_acceleration_hand_checked(tmp_path, namespace):
    # Sensor a: identity orientation, free acceleration (1, 0, 0) → reads (1, 0, 9.81).
    # Sensor b: turned 90° about Xsens Z (its X points left, its Y backward), free (0, 2, 0)
    #   (leftward) → its X reads 2, Y 0, Z 9.81.
    # Sensor c: turned 90° about Xsens Y (its X points down, its Z forward), at rest →
    #   its X reads −9.81.
    q = [[1, 0, 0, 0], [C45, 0, 0, C45], [C45, 0, C45, 0]]
    free = [[1, 0, 0], [0, 2, 0], [0, 0, 0]]
    frames = [
        ({"time": "0", "tc": "00", "ms": "0", "type": "identity"}, {"orientation": [1, 0, 0, 0]}),
        ({"time": "0", "tc": "00", "ms": "0", "type": "tpose"}, {"sensorOrientation": q}),
        normal(0, sensorFreeAcceleration=free, sensorOrientation=q, sensorMagneticField=np.zeros(9)),
        normal(1, sensorFreeAcceleration=np.zeros(9), sensorOrientation=q),
    ]
    rec = read_mvnx(write_mvnx(tmp_path / "t.mvnx", ("a", "b", "c"), frames, version="4", namespace=namespace))
    assert rec.sensor_names == ("a", "b", "c") and rec.num_samples == 2 and rec.rate_hz == 60.0
    np.testing.assert_allclose(rec.timestamps_s, [0.0, 0.017])  # the frames' time, ms
    np.testing.assert_allclose(rec.accelerations[0], [[1, 0, G], [2, 0, G], [-G, 0, 0]], atol=1e-5)
    np.testing.assert_allclose(rec.accelerations[1], [[0, 0, G], [0, 0, G], [-G, 0, 0]], atol=1e-5)
    assert rec.accelerations.dtype == np.float32 and rec.orientations.dtype == np.float32
    # Orientations in graphsvc's world: a's X along +Z; b's X along +X (Xsens left), its
    # Y along −Z (backward); c's X along −Y (down), its Z along +Z (forward).
    o = rec.orientations[0].astype(np.float64)
    ex, ey, ez = np.eye(3)
    np.testing.assert_allclose(quat.rotate(o[0], ex), [0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(quat.rotate(o[0], ez), [0, 1, 0], atol=1e-6)
    np.testing.assert_allclose(quat.rotate(o[1], ex), [1, 0, 0], atol=1e-6)
    np.testing.assert_allclose(quat.rotate(o[1], ey), [0, 0, -1], atol=1e-6)
    np.testing.assert_allclose(quat.rotate(o[2], ex), [0, -1, 0], atol=1e-6)
    np.testing.assert_allclose(quat.rotate(o[2], ez), [0, 0, 1], atol=1e-6)
    m = rec.meta
    assert m["imported_from"] == "mvnx" and m["sensor_frame"] == "device"
    assert m["acceleration"] == "sensorFreeAcceleration" and m["timestamps_from"] == "time"
    assert m["frame_rate_hz"] == 60.0 and m["configuration"] == "FullBody" and m["mvnx_version"] == "4"
    assert m["calibration_frames"] == ["identity", "tpose"]
    assert set(m["poses"]) == {"tpose"}
    np.testing.assert_allclose(m["poses"]["tpose"], o, atol=1e-6)  # the same conversion as the samples
    json.dumps(m, allow_nan=False)  # JSON-able, as .rec meta must be


def test_raw_acceleration_read_as_is(tmp_path):
    acc = [[-9.026212, 0.558642, 3.671129], [0.1, 9.8, -0.2]]
    q = [[C45, 0, 0, C45], [1, 0, 0, 0]]
    frames = [
        ({"time": "0", "index": "-2", "type": "tpose"}, {"orientation": np.zeros(4)}),
        normal(0, 240, sensorAcceleration=acc, sensorOrientation=q, sensorFreeAcceleration=np.ones(6)),
        normal(1, 240, sensorAcceleration=acc, sensorOrientation=q, sensorFreeAcceleration=np.ones(6)),
    ]
    rec = read_mvnx(write_mvnx(tmp_path / "r.mvnx", ("LeftForeArm", "Pelvis"), frames, rate=240))
    np.testing.assert_array_equal(rec.accelerations[0], np.float32(acc))  # not rotated, not re-gravitated
    assert rec.meta["acceleration"] == "sensorAcceleration" and "poses" not in rec.meta
    assert rec.meta["calibration_frames"] == ["tpose"] and rec.rate_hz == 240.0
    np.testing.assert_allclose(rec.timestamps_s, [0.0, 0.004])
    np.testing.assert_allclose(quat.rotate(rec.orientations[0, 0].astype(float), [1.0, 0, 0]), [1, 0, 0], atol=1e-6)


def test_raw_acceleration_without_orientations(tmp_path):
    frames = [normal(k, sensorAcceleration=[0, 0, G]) for k in range(3)]
    rec = read_mvnx(write_mvnx(tmp_path / "r.mvnx", ("Pelvis",), frames))
    assert rec.orientations is None and rec.accelerations.shape == (3, 1, 3)


def test_timestamps_from_index_without_time(tmp_path):
    frames = [({"index": str(k), "type": "normal"}, {"sensorAcceleration": [0, 0, G]}) for k in (0, 1, 2, 4)]
    rec = read_mvnx(write_mvnx(tmp_path / "r.mvnx", ("Pelvis",), frames, rate=100))
    np.testing.assert_allclose(rec.timestamps_s, [0.0, 0.01, 0.02, 0.04])  # a dropped frame stays a gap
    assert rec.meta["timestamps_from"] == "index"


def test_many_frames_and_missing_sensor(tmp_path):
    """Beyond the readers' first buffer (64 rows); an all-zero quaternion is a sensor
    without data: NaN orientation and (free acceleration) NaN reading."""
    rng = np.random.default_rng(1)
    T = 200
    q = rng.normal(size=(T, 2, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.round(q, 6)
    q[7, 1] = 0.0
    free = np.round(rng.normal(size=(T, 2, 3)), 6)
    frames = [normal(k, sensorFreeAcceleration=free[k], sensorOrientation=q[k]) for k in range(T)]
    rec = read_mvnx(write_mvnx(tmp_path / "m.mvnx", ("a", "b"), frames))
    assert rec.num_samples == T
    ok = np.ones((T, 2), bool)
    ok[7, 1] = False
    assert np.isnan(rec.orientations[7, 1]).all() and np.isnan(rec.accelerations[7, 1]).all()
    assert np.isfinite(rec.accelerations[ok]).all()
    # Independently: R (a_sensor) − g_up = the free acceleration, in Xsens axes.
    qn = q[ok] / np.linalg.norm(q[ok], axis=-1, keepdims=True)
    back = quat.rotate(qn, rec.accelerations[ok].astype(float)) - [0, 0, G]
    np.testing.assert_allclose(back, free[ok], atol=2e-5)


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda t: t[: len(t) // 2], "ends early"),
        (lambda t: t.replace("</mvnx>", ""), "ends early"),
        (lambda t: t.replace("<frames ", "<frames <", 1), "not a well-formed"),
        (lambda t: t.replace("0.000000", "zero", 1), "not a number"),
        (
            lambda t: t.replace(" 0.707107</sensorOrientation>", "</sensorOrientation>", 1),
            "has 7 values, expected 8 \\(4 for each of 2 sensors\\)",
        ),
        (lambda t: t.replace("9.810000", "inf", 1), "infinite"),
        (lambda t: t.replace('sensorCount="2"', 'sensorCount="3"'), "sensorCount"),
        (lambda t: t.replace('label="b"', 'label="a"'), "duplicate sensor labels: a"),
        (lambda t: t.replace('<sensor label="a"/>', "").replace('<sensor label="b"/>', ""), "no sensors"),
        (lambda t: t.replace('type="normal"', 'type="tpose"'), "no normal frames"),
        (lambda t: t.replace("sensorOrientation", "sensorMagneticField"), "needs sensorOrientation"),
        (lambda t: t.replace("sensorFreeAcceleration", "acceleration"), "no sensor accelerations"),
        (lambda t: t.replace('time="17"', 'time="0"'), "does not follow"),
        (lambda t: t.replace("<mvnx", "<mvnz").replace("</mvnx", "</mvnz"), "not an MVNX file"),
        (
            lambda t: t.replace("0.707107 0.000000 0.000000 0.707107", "0.5 0 0 0.5"),
            "the sensorOrientation of b is not a unit quaternion",
        ),
    ],
)
def test_malformed_mvnx_refused(tmp_path, edit, message):
    q = [[1, 0, 0, 0], [C45, 0, 0, C45]]
    frames = [normal(k, sensorFreeAcceleration=[0, 0, 0, 0, 0, 9.81 * k], sensorOrientation=q) for k in range(3)]
    text = mvnx_text(("a", "b"), frames)
    path = tmp_path / "bad.mvnx"
    path.write_text(edit(text))
    assert path.read_text() != text
    with pytest.raises(FormatError, match=message) as info:
        read_mvnx(path)
    assert "bad.mvnx" in str(info.value)


def test_mvnx_other_errors(tmp_path):
    with pytest.raises(FormatError, match="no such file"):
        read_mvnx(tmp_path / "absent.mvnx")
    (tmp_path / "empty.mvnx").write_bytes(b"")
    with pytest.raises(FormatError, match="empty.mvnx:1"):
        read_mvnx(tmp_path / "empty.mvnx")
    path = write_mvnx(tmp_path / "ok.mvnx", ("a",), [normal(0, sensorAcceleration=[0, 0, G])])
    with pytest.raises(InputError, match="do not apply"):
        read_recording(path, up="z")
    assert read_recording(path).sensor_names == ("a",)  # by suffix


def test_truncated_mvnx_names_the_line(tmp_path):
    frames = [normal(k, sensorAcceleration=[0, 0, G]) for k in range(5)]
    text = mvnx_text(("a",), frames)
    path = tmp_path / "cut.mvnx"
    path.write_text(text[: text.index("<frame ", text.index('index="3"') - 20)])
    with pytest.raises(FormatError, match="ends early") as info:
        read_mvnx(path)
    assert info.value.line == path.read_text().count("\n") + 1  # where the text stopped


# ---------------------------------------------------------------- real MVNX exports


def _file_fields(path, name):
    """(T, values) of one field in the normal frames, parsed independently."""
    rows = []
    for frame in ET.parse(path).getroot().iter(f"{{{NS}}}frame"):
        if frame.get("type") == "normal":
            rows.append([float(v) for v in frame.find(f"{{{NS}}}{name}").text.split()])
    return np.array(rows)


def test_real_mvnx_free_acceleration(data_dir):
    path = data_dir / "mvnx" / FREE_FILE
    rec = read_mvnx(path)
    assert rec.num_samples == 112 and rec.rate_hz == 60.0 and rec.sensor_names == XSENS_UPPER
    assert rec.meta["acceleration"] == "sensorFreeAcceleration" and rec.meta["configuration"] == "UpperBody"
    assert rec.meta["calibration_frames"] == ["identity", "tpose", "tpose-isb"]
    assert "poses" not in rec.meta  # its calibration frames carry segment, not sensor, orientations
    assert rec.timestamps_s[-1] == pytest.approx(111 / 60, abs=1e-3)
    np.testing.assert_allclose(np.linalg.norm(rec.orientations, axis=-1), 1.0, atol=1e-6)
    # The pelvis barely moves: it reads about 1 g.
    assert np.median(np.linalg.norm(rec.accelerations[:, 0], axis=-1)) == pytest.approx(G, abs=0.3)
    # Gravity was added back in each sensor's frame consistently with its orientation:
    # R·a_sensor − g_up is the file's free acceleration (Xsens axes → graphsvc's).
    free = _file_fields(path, "sensorFreeAcceleration").reshape(112, 11, 3)
    world = quat.rotate(rec.orientations.astype(float), rec.accelerations.astype(float)) - [0, G, 0]
    np.testing.assert_allclose(world, free[..., [1, 2, 0]], atol=1e-4)


def test_real_mvnx_raw_acceleration(data_dir):
    path = data_dir / "mvnx" / RAW_FILE
    rec = read_mvnx(path)
    assert rec.num_samples == 4 and rec.rate_hz == 240.0 and rec.sensor_names == XSENS_FULL
    assert rec.meta["acceleration"] == "sensorAcceleration" and rec.meta["mvnx_version"] == "3"
    assert rec.meta["calibration_frames"] == ["npose", "tpose"]
    np.testing.assert_allclose(rec.timestamps_s, [0, 0.004, 0.008, 0.012])
    raw = _file_fields(path, "sensorAcceleration").reshape(4, 17, 3)
    np.testing.assert_array_equal(rec.accelerations, raw.astype(np.float32))
    np.testing.assert_allclose(rec.accelerations[0, 0], [-9.026212, 0.558642, 3.671129], rtol=1e-6)
    # A performer standing still: every sensor reads about 1 g, pointing up in the world.
    np.testing.assert_allclose(np.linalg.norm(rec.accelerations, axis=-1), G, atol=0.3)
    np.testing.assert_allclose(np.linalg.norm(rec.orientations, axis=-1), 1.0, atol=1e-6)
    up = quat.rotate(rec.orientations.astype(float), rec.accelerations.astype(float))
    assert np.abs(up[..., [0, 2]]).max() < 0.5 and (up[..., 1] > 9.3).all()


def test_real_mvnx_truncated(data_dir, tmp_path):
    data = (data_dir / "mvnx" / RAW_FILE).read_bytes()
    path = tmp_path / "cut.mvnx"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(FormatError, match="ends early") as info:
        read_mvnx(path)
    assert info.value.line is not None and "cut.mvnx" in str(info.value)


# ---------------------------------------------------------------- device maps


def test_builtin_xsens_maps_follow_the_presets():
    assert device_map("xsens", "kelly6") == {
        "LeftForeArm": "l_forearm",
        "RightForeArm": "r_forearm",
        "LeftLowerLeg": "l_shin",
        "RightLowerLeg": "r_shin",
        "Pelvis": "lower_back",
        "T8": "chest",
    }
    assert device_map("xsens", "wrists-ankles") == {
        "LeftForeArm": "l_wrist",
        "RightForeArm": "r_wrist",
        "LeftLowerLeg": "l_ankle",
        "RightLowerLeg": "r_ankle",
    }
    assert device_map("xsens", "right-wrist") == {"RightForeArm": "r_wrist"}
    for layout, mapping in DEVICE_MAPS["xsens"].items():
        assert tuple(mapping.values()) == PRESETS[layout].sensor_names  # in the layout's order
        assert set(mapping) <= set(XSENS_FULL)
    with pytest.raises(InputError, match="wrists-ankles, kelly6, right-wrist, dip6"):
        device_map("xsens", "my-layout")
    with pytest.raises(InputError, match="not a built-in device"):
        device_map("vicon-imu", "kelly6")


XSENS_SKELETON = (
    "Hips",
    "Spine",
    "Spine1",
    "Spine2",
    "Spine3",
    "Neck",
    "Head",
    "RightShoulder",
    "RightArm",
    "RightForeArm",
    "RightHand",
    "LeftShoulder",
    "LeftArm",
    "LeftForeArm",
    "LeftHand",
    "RightUpLeg",
    "RightLeg",
    "RightFoot",
    "LeftUpLeg",
    "LeftLeg",
    "LeftFoot",
)
XSENS_SEGMENTS_ALL = ("Pelvis", "L5", "L3", "T12", "T8", "Neck", "Head") + XSENS_FULL[3:]


def test_builtin_maps_for_dip6():
    assert device_map("xsens", "dip6") == {
        "LeftForeArm": "l_wrist",
        "RightForeArm": "r_wrist",
        "LeftLowerLeg": "l_knee",
        "RightLowerLeg": "r_knee",
        "Head": "head",
        "Pelvis": "pelvis",
    }
    assert device_map("mvn", "dip6") == {
        "LeftForeArm": "l_wrist",
        "RightForeArm": "r_wrist",
        "LeftLeg": "l_knee",
        "RightLeg": "r_knee",
        "Head": "head",
        "Hips": "pelvis",
    }
    assert device_map("generic", "dip6") == {
        "left_wrist": "l_wrist",
        "right_wrist": "r_wrist",
        "left_knee": "l_knee",
        "right_knee": "r_knee",
        "head": "head",
        "pelvis": "pelvis",
    }
    for device in DEVICE_MAPS:
        for layout, mapping in DEVICE_MAPS[device].items():
            assert tuple(mapping.values()) == PRESETS[layout].sensor_names


def test_xsens_takes_the_naming_that_names_more_sensors():
    # MVN segment names (an MVNX's sensors): Pelvis, T8, LowerLeg.
    assert device_map("xsens", "kelly6", XSENS_SEGMENTS_ALL) == DEVICE_MAPS["xsens"]["kelly6"]
    # MVN skeleton names (a BVH export's): Hips, Spine3, Leg; Head and LeftForeArm are in both.
    assert device_map("xsens", "kelly6", XSENS_SKELETON) == {
        "LeftForeArm": "l_forearm",
        "RightForeArm": "r_forearm",
        "LeftLeg": "l_shin",
        "RightLeg": "r_shin",
        "Hips": "lower_back",
        "Spine3": "chest",
    }
    assert device_map("xsens", "dip6", XSENS_SKELETON) == device_map("mvn", "dip6")
    # An upper-body take in skeleton names: the skeleton naming still names more (Hips, Spine3 against none).
    upper = ("Hips", "Spine3", "Head", "LeftForeArm", "RightForeArm")
    assert device_map("xsens", "kelly6", upper) == {
        "LeftForeArm": "l_forearm",
        "RightForeArm": "r_forearm",
        "Hips": "lower_back",
        "Spine3": "chest",
    }
    with pytest.raises(
        InputError,
        match=re.escape(
            "the mvn device map names none of the recording's sensors (S1, S2) "
            "for layout 'right-wrist' (it takes RightForeArm)"
        ),
    ):
        device_map("mvn", "right-wrist", ("S1", "S2"))
    # mvn never reads segment names.
    assert device_map("mvn", "dip6", XSENS_SEGMENTS_ALL) == {
        "LeftForeArm": "l_wrist",
        "RightForeArm": "r_wrist",
        "Head": "head",
    }


@pytest.mark.parametrize(
    "name, key",
    [
        ("left_wrist", "lwrist"),
        ("LeftWrist", "lwrist"),
        ("l-wrist", "lwrist"),
        ("lwrist", "lwrist"),
        ("wrist_L", "lwrist"),
        ("wrist_left", "lwrist"),
        ("Right Knee", "rknee"),
        ("RIGHT_LOWER_LEG", "rlowerleg"),
        ("Lower-Back", "lowerback"),
        ("head", "head"),
    ],
)
def test_generic_key(name, key):
    assert generic_key(name) == key


def test_generic_map_on_a_device_csv(tmp_path):
    """A device CSV in everyday spellings through the generic map: each dip6 sensor takes
    the first of its names the recording has (the knee sensor before a shin one), and a
    sensor the layout has no place for stays unmapped."""
    from graphsvc.pipeline import read_recording_file

    names = ["Pelvis", "LWrist", "wrist_r", "left_shin", "Left_Knee", "right-knee", "HEAD", "chest"]
    cols = ",".join(f"{n}_a{c}" for n in names for c in "xyz")
    row = lambda t: ",".join([f"{t:g}"] + [f"{k + 0.5 * t:g}" for k in range(3 * len(names))])  # noqa: E731
    path = tmp_path / "dev.csv"
    path.write_text(f"# rate_hz=10\nt_s,{cols}\n" + "\n".join(row(t / 10) for t in range(4)) + "\n")
    notes = []
    rec = read_recording_file(
        path, device_map="generic", notes=notes, layout_name="dip6", sensor_names=PRESETS["dip6"].sensor_names
    )
    assert rec.sensor_names == PRESETS["dip6"].sensor_names
    assert rec.meta["device_sensors"] == {
        "l_wrist": "LWrist",
        "r_wrist": "wrist_r",
        "l_knee": "Left_Knee",
        "r_knee": "right-knee",
        "head": "HEAD",
        "pelvis": "Pelvis",
    }
    assert rec.meta["unmapped_sensors"] == ["left_shin", "chest"]
    # columns follow their sensors: Left_Knee is the 5th device sensor, its x the 13th number
    np.testing.assert_allclose(rec.accelerations[1, 2], [12.05, 13.05, 14.05], rtol=1e-6)
    assert len(notes) == 1 and "own frame" in notes[0]  # all six found: no note of unmapped ones
    # kelly6 from the same file: the shin sensor for l_shin, the knee for r_shin (no right shin), chest
    notes = []
    rec = read_recording_file(
        path, device_map="generic", notes=notes, layout_name="kelly6", sensor_names=PRESETS["kelly6"].sensor_names
    )
    assert rec.meta["device_sensors"] == {
        "l_forearm": "LWrist",
        "r_forearm": "wrist_r",
        "l_shin": "left_shin",
        "r_shin": "right-knee",
        "lower_back": "Pelvis",
        "chest": "chest",
    }


@pytest.mark.parametrize("device", ["xsens", "mvn"])
def test_xsens_and_mvn_maps_on_a_device_csv_in_skeleton_names(tmp_path, device):
    """A CSV named as MVN's skeleton (a BVH export's joints): both maps take dip6's six
    from it, each column following its sensor."""
    from graphsvc.pipeline import read_recording_file

    names = ["Hips", "Spine3", "Head", "LeftForeArm", "RightForeArm", "LeftLeg", "RightLeg", "LeftUpLeg"]
    cols = ",".join(f"{n}_a{c}" for n in names for c in "xyz")
    path = tmp_path / "mvn.csv"
    path.write_text(
        f"t_s,{cols}\n"
        + "\n".join(",".join([f"{t / 10:g}"] + [str(k + 100 * t) for k in range(24)]) for t in range(3))
        + "\n"
    )
    rec = read_recording_file(path, device_map=device, layout_name="dip6", sensor_names=PRESETS["dip6"].sensor_names)
    assert rec.meta["device_sensors"] == {
        "l_wrist": "LeftForeArm",
        "r_wrist": "RightForeArm",
        "l_knee": "LeftLeg",
        "r_knee": "RightLeg",
        "head": "Head",
        "pelvis": "Hips",
    }
    assert rec.meta["unmapped_sensors"] == ["Spine3", "LeftUpLeg"]
    # l_knee is LeftLeg, the 6th sensor: columns 15–17; at t = 0.2 s each value is k + 200
    np.testing.assert_array_equal(rec.accelerations[2, 2], np.float32([215, 216, 217]))


def test_one_note_names_the_layout_sensors_left_unmapped(tmp_path):
    from graphsvc.pipeline import read_recording_file

    path = write_mvnx(
        tmp_path / "upper.mvnx", XSENS_UPPER, [normal(k, sensorAcceleration=np.zeros(33)) for k in range(3)]
    )
    notes = []
    rec = read_recording_file(
        path, device_map="xsens", notes=notes, layout_name="dip6", sensor_names=PRESETS["dip6"].sensor_names
    )
    assert rec.sensor_names == ("l_wrist", "r_wrist", "head", "pelvis")
    mapped = [n for n in notes if n.startswith("device map")]
    assert mapped == [
        "device map xsens: no sensor of the recording for l_knee, r_knee (unmapped: T8, RightShoulder, "
        "RightUpperArm, RightHand, LeftShoulder, LeftUpperArm, LeftHand)"
    ]


def test_map_files(tmp_path):
    wrapped = tmp_path / "w.json"
    wrapped.write_text(json.dumps({"device": "mine", "sensors": {"S2": "r_wrist", "S1": "l_wrist"}}))
    assert device_map(str(wrapped), "kelly6") == {"S2": "r_wrist", "S1": "l_wrist"}
    bare = tmp_path / "b.json"
    bare.write_text('{"S1": "l_wrist"}')
    assert device_map(str(bare), None) == {"S1": "l_wrist"}


@pytest.mark.parametrize(
    "text, message",
    [
        ('{"S1": "l_wrist", "S1": "r_wrist"}', "'S1' more than once"),
        ('{"S1": "l_wrist", "S2": "l_wrist"}', "l_wrist more than once"),
        ('{"S1": "l_wrist",\n "S2": }', "not valid JSON"),
        ("{}", "non-empty"),
        ('["S1", "l_wrist"]', "non-empty object"),
        ('{"S1": 3}', "non-empty strings"),
        ('{"S1": ""}', "non-empty strings"),
        ('{"device": "x", "sensors": {"S1": "a"}, "layout": "kelly6"}', "unknown keys layout"),
    ],
)
def test_bad_map_files(tmp_path, text, message):
    path = tmp_path / "m.json"
    path.write_text(text)
    with pytest.raises(FormatError, match=message) as info:
        device_map(str(path), "kelly6")
    assert "m.json" in str(info.value)


def _device_recording(names=("Pelvis", "LeftForeArm", "Head", "RightForeArm")) -> Recording:
    T, S = 5, len(names)
    acc = np.arange(T * S * 3, dtype=np.float32).reshape(T, S, 3)
    q = np.zeros((T, S, 4), np.float32)
    q[..., 0] = 1.0
    return Recording(
        rate_hz=60.0,
        timestamps_s=np.arange(T) / 60.0,
        sensor_names=tuple(names),
        accelerations=acc,
        orientations=q,
        meta={"imported_from": "mvnx"},
    )


def test_apply_device_map():
    rec = _device_recording()
    out = apply_device_map(rec, {"RightForeArm": "r_wrist", "LeftForeArm": "l_wrist", "LeftLowerLeg": "l_ankle"})
    assert out.sensor_names == ("r_wrist", "l_wrist")  # the map's order; the absent LeftLowerLeg left out
    np.testing.assert_array_equal(out.accelerations[:, 0], rec.accelerations[:, 3])
    np.testing.assert_array_equal(out.accelerations[:, 1], rec.accelerations[:, 1])
    np.testing.assert_array_equal(out.orientations, rec.orientations[:, [3, 1]])
    assert out.meta["unmapped_sensors"] == ["Pelvis", "Head"]
    assert out.meta["device_sensors"] == {"r_wrist": "RightForeArm", "l_wrist": "LeftForeArm"}
    assert out.meta["imported_from"] == "mvnx" and "unmapped_sensors" not in rec.meta  # rec untouched
    ordered = apply_device_map(rec, {"RightForeArm": "r_wrist", "LeftForeArm": "l_wrist"}, order=("l_wrist", "r_wrist"))
    assert ordered.sensor_names == ("l_wrist", "r_wrist")
    np.testing.assert_array_equal(ordered.accelerations[:, 0], rec.accelerations[:, 1])
    with pytest.raises(InputError, match="none of the recording's sensors"):
        apply_device_map(rec, {"LeftLowerLeg": "l_ankle"})
    with pytest.raises(InputError, match="more than once"):
        apply_device_map(rec, {"RightForeArm": "r_wrist", "LeftForeArm": "r_wrist"})
    with pytest.raises(InputError, match="non-empty object"):
        apply_device_map(rec, {})


def test_real_mvnx_through_the_xsens_maps(data_dir):
    rec = read_mvnx(data_dir / "mvnx" / RAW_FILE)
    out = apply_device_map(rec, device_map("xsens", "wrists-ankles"))
    assert out.sensor_names == PRESETS["wrists-ankles"].sensor_names
    for new, old in (("l_wrist", "LeftForeArm"), ("r_ankle", "RightLowerLeg")):
        np.testing.assert_array_equal(
            out.accelerations[:, out.sensor_names.index(new)], rec.accelerations[:, rec.sensor_names.index(old)]
        )
    assert len(out.meta["unmapped_sensors"]) == 13
    upper = apply_device_map(read_mvnx(data_dir / "mvnx" / FREE_FILE), device_map("xsens", "kelly6"))
    assert upper.sensor_names == ("l_forearm", "r_forearm", "lower_back", "chest")  # no legs in an upper-body take


# ---------------------------------------------------------------- device CSV comments


def test_csv_units_comment(tmp_path):
    path = tmp_path / "d.csv"
    path.write_text("# units=g\nt_s,s_ax,s_ay,s_az\n0,1,0.5,-2\n0.01,0,0,1\n")
    rec = import_csv(path)
    np.testing.assert_array_equal(rec.accelerations[0, 0], np.float32([9.81, 4.905, -19.62]))
    assert rec.meta["units"] == "g"
    assert import_csv(path, units="m/s2").accelerations[0, 0, 0] == 1.0  # the argument wins
    path.write_text("# Units=M/S2\nt_s,s_ax,s_ay,s_az\n0,1,0.5,-2\n0.01,0,0,1\n")
    assert import_csv(path).accelerations[0, 0, 0] == 1.0
    assert read_recording(path, units="g").accelerations[0, 0, 0] == np.float32(9.81)
    with pytest.raises(InputError, match="acceleration unit"):
        read_recording(path, units="mm")


def test_csv_up_z_turns_orientations_onto_y_up(tmp_path):
    # Sample 0: identity in the Z-up device world → the sensor's X along graphsvc +Z, its Z
    # along +Y. Sample 1: 90° about the device's Z → its X along the device's Y (left),
    # graphsvc +X; its Z still up (+Y).
    path = tmp_path / "d.csv"
    text = f"# up=z\nt_s,s_ax,s_ay,s_az,s_qw,s_qx,s_qy,s_qz\n0,0,0,9.81,1,0,0,0\n0.01,0,0,9.81,{C45!r},0,0,{C45!r}\n"
    path.write_text(text)
    rec = import_csv(path)
    o = rec.orientations[:, 0].astype(np.float64)
    ex, ez = np.array([1.0, 0, 0]), np.array([0, 0, 1.0])
    np.testing.assert_allclose(quat.rotate(o[0], ex), [0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(quat.rotate(o[0], ez), [0, 1, 0], atol=1e-6)
    np.testing.assert_allclose(quat.rotate(o[1], ex), [1, 0, 0], atol=1e-6)
    np.testing.assert_allclose(quat.rotate(o[1], ez), [0, 1, 0], atol=1e-6)
    np.testing.assert_array_equal(rec.accelerations[0, 0], np.float32([0, 0, 9.81]))  # readings untouched
    assert rec.meta["up"] == "z"
    same = import_csv(path, up="y")  # the argument wins: as written
    np.testing.assert_array_equal(same.orientations[1, 0], np.float32([C45, 0, 0, C45]))
    # A world orientation then reads gravity up: R·a = (0, 9.81, 0).
    np.testing.assert_allclose(quat.rotate(o[0], [0, 0, 9.81]), [0, 9.81, 0], atol=1e-5)


def test_csv_sensor_frame(tmp_path):
    rec = _device_recording(("a", "b"))
    export_csv(rec, tmp_path / "ours.csv")
    back = import_csv(tmp_path / "ours.csv")
    assert back.meta["sensor_frame"] == "layout" and back.meta["up"] == "y" and back.meta["units"] == "m/s2"
    np.testing.assert_array_equal(back.accelerations, rec.accelerations)
    np.testing.assert_array_equal(back.orientations, rec.orientations)  # up=y: untouched
    body = "t_s,s_ax,s_ay,s_az\n0,1,2,3\n0.1,1,2,3\n"
    (tmp_path / "dev.csv").write_text(body)
    assert import_csv(tmp_path / "dev.csv").meta["sensor_frame"] == "device"
    (tmp_path / "dev.csv").write_text("# sensor_frame=layout\n" + body)
    assert import_csv(tmp_path / "dev.csv").meta["sensor_frame"] == "layout"
    (tmp_path / "dev.csv").write_text("# graphsvc recording v1\n# sensor_frame=device\n" + body)
    assert import_csv(tmp_path / "dev.csv").meta["sensor_frame"] == "device"


@pytest.mark.parametrize(
    "comment, message",
    [
        ("# units=mg", "bad units comment 'mg' (expected m/s2 or g)"),
        ("# up=x", "bad up comment 'x' (expected y or z)"),
        ("# sensor_frame=body", "bad sensor_frame comment 'body' (expected device or layout)"),
    ],
)
def test_csv_bad_comments_have_line_numbers(tmp_path, comment, message):
    path = tmp_path / "bad.csv"
    path.write_text(f"# rate_hz=100\n{comment}\nt_s,s_ax,s_ay,s_az\n0,1,2,3\n")
    with pytest.raises(FormatError, match=re.escape(message)) as info:
        import_csv(path)
    assert info.value.line == 2


def test_marker_file_refuses_acceleration_units(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("time,A_x,A_y,A_z\n0,1,2,3\n0.1,1,2,3\n")
    with pytest.raises(InputError, match="acceleration unit"):
        read_recording(path, units="g")
    assert read_recording(path, units="mm").marker_positions[0, 0, 0] == pytest.approx(0.001)


# ---------------------------------------------------------------- CLI


def run(argv, capsys):
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_cli_truncated_mvnx_one_line_exit_2(tmp_path, capsys):
    text = mvnx_text(("a",), [normal(k, sensorAcceleration=[0, 0, G]) for k in range(3)])
    path = tmp_path / "cut.mvnx"
    path.write_text(text[: len(text) // 2])
    code, out, err = run(["inspect", str(path)], capsys)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and "cut.mvnx" in err and "ends early" in err
    assert "Traceback" not in err


def test_cli_inspect_mvnx(tmp_path, capsys):
    path = write_mvnx(
        tmp_path / "t.mvnx", ("Pelvis", "RightForeArm"), [normal(k, sensorAcceleration=np.zeros(6)) for k in range(6)]
    )
    code, out, _ = run(["inspect", str(path), "--json"], capsys)
    info = json.loads(out)["recordings"][0]
    assert code == 0 and info["samples"] == 6 and info["sensors"] == ["Pelvis", "RightForeArm"]


def gliding_graph(folder, capsys, layout: str, *flags: str):
    """A graph of the T-pose gliding 1 m over 60 frames, built for `layout`."""
    from graphsvc.motion.bvh import write_bvh

    m = still_motion(60)
    m.translations[:, 0, 2] = np.linspace(0, 1.0, 60)
    write_bvh(folder / "walk_demo_001.bvh", m, scale=100.0)
    graph = folder / f"{layout}.graph"
    assert (
        run(
            ["build", str(folder / "walk_demo_001.bvh"), "-o", str(graph), "--layout", layout, "--quiet", *flags],
            capsys,
        )[0]
        == 0
    )
    return graph


@pytest.fixture
def wrist_graph(tmp_path, capsys):
    return gliding_graph(tmp_path, capsys, "right-wrist")


def test_cli_synthesize_mvnx_with_device_map(tmp_path, wrist_graph, capsys):
    q = [[1, 0, 0, 0], [C45, 0, C45, 0]]
    frames = [normal(k, sensorFreeAcceleration=np.zeros(6), sensorOrientation=q) for k in range(60)]
    rec = write_mvnx(tmp_path / "take.mvnx", ("Pelvis", "RightForeArm"), frames)
    out = tmp_path / "out.bvh"
    code, _, err = run(["synthesize", str(wrist_graph), str(rec), "-o", str(out)], capsys)
    assert code == 2 and "--device-map xsens" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
    code, stdout, err = run(["synthesize", str(wrist_graph), str(rec), "-o", str(out), "--device-map", "xsens"], capsys)
    assert code == 0, err
    assert out.exists() and "wrote" in stdout and "own frame" in err
    mapfile = tmp_path / "map.json"
    mapfile.write_text('{"device": "xsens", "sensors": {"RightForeArm": "r_wrist"}}')
    code, _, err = run(["synthesize", str(wrist_graph), str(rec), "-o", str(out), "--device-map", str(mapfile)], capsys)
    assert code == 0, err
    code, _, err = run(["synthesize", str(wrist_graph), str(rec), "-o", str(out), "--device-map", "nope"], capsys)
    assert code == 2 and "unknown device map" in err and len(err.strip().splitlines()) == 1


@pytest.fixture
def dip6_graph(tmp_path, capsys):
    return gliding_graph(tmp_path, capsys, "dip6", "--rate", "240")


def test_real_mvnx_mapped_and_reconstructed_on_dip6(data_dir, dip6_graph, tmp_path, capsys):
    """A real full-body MVNX take → the xsens map → dip6 → a reconstruction on a graph at
    the take's 240 Hz: its 4 samples, at 0, 4, 8 and 12 ms (whole milliseconds), span
    0.012 s, which holds the grid's 0, 1/240 and 2/240 s (3/240 s is past the end)."""
    take = data_dir / "mvnx" / RAW_FILE
    out, report = tmp_path / "take.bvh", tmp_path / "take.json"
    code, stdout, err = run(
        ["synthesize", str(dip6_graph), str(take), "--device-map", "xsens", "-o", str(out), "--report", str(report)],
        capsys,
    )
    assert code == 0, err
    assert "from 3 samples (resampled from 240 Hz)" in stdout and "no sensor of the recording" not in err
    r = json.loads(report.read_text())
    assert r["samples"] == 3 and r["files"]["read"] == {"device_map": "xsens"}
    rec = read_mvnx(take)
    mapped = apply_device_map(rec, device_map("xsens", "dip6", rec.sensor_names))
    assert mapped.sensor_names == PRESETS["dip6"].sensor_names
    np.testing.assert_array_equal(
        mapped.accelerations[:, 2], rec.accelerations[:, rec.sensor_names.index("LeftLowerLeg")]
    )
    assert len(mapped.meta["unmapped_sensors"]) == 11


def test_export_csv_keeps_a_device_recordings_frame(tmp_path):
    """A recording still in its devices' frames says so in the CSV it is exported to."""
    from graphsvc.sensors.recording import Recording, export_csv, import_csv

    rec = Recording(
        rate_hz=10.0,
        timestamps_s=np.arange(3) / 10.0,
        sensor_names=("a",),
        accelerations=np.zeros((3, 1, 3), np.float32),
        meta={"sensor_frame": "device"},
    )
    export_csv(rec, tmp_path / "d.csv")
    assert import_csv(tmp_path / "d.csv").meta["sensor_frame"] == "device"
    export_csv(
        Recording(
            rate_hz=10.0,
            timestamps_s=np.arange(3) / 10.0,
            sensor_names=("a",),
            accelerations=np.zeros((3, 1, 3), np.float32),
        ),
        tmp_path / "l.csv",
    )
    assert import_csv(tmp_path / "l.csv").meta["sensor_frame"] == "layout"


@pytest.fixture
def kelly6_csv(tmp_path, capsys):
    """(a kelly6 graph of the gliding T-pose, a CSV of its clip's kelly6 readings)."""
    graph = gliding_graph(tmp_path, capsys, "kelly6")
    rec = tmp_path / "rec.csv"
    assert (
        run(
            [
                "simulate",
                str(tmp_path / "walk_demo_001.bvh"),
                "--layout",
                "kelly6",
                "--noise",
                "default",
                "-o",
                str(rec),
            ],
            capsys,
        )[0]
        == 0
    )
    return graph, rec


def _with_sensors(rec: Recording, names, cols) -> Recording:
    from dataclasses import replace

    return replace(rec, sensor_names=tuple(names), accelerations=np.ascontiguousarray(rec.accelerations[:, cols]))


def test_cli_csv_with_the_graphs_sensors_in_another_order(tmp_path, kelly6_csv, capsys):
    """The same readings with their columns in another order reconstruct to the same
    bytes: the recording is put in the graph's order."""
    graph, ordered = kelly6_csv
    rec = import_csv(ordered)
    cols = [5, 3, 1, 0, 2, 4]
    shuffled = tmp_path / "shuffled.csv"
    export_csv(_with_sensors(rec, [rec.sensor_names[c] for c in cols], cols), shuffled)
    assert import_csv(shuffled).sensor_names == ("chest", "r_shin", "r_forearm", "l_forearm", "l_shin", "lower_back")
    outputs = []
    for name, path in (("a", ordered), ("b", shuffled)):
        out, report = tmp_path / f"{name}.bvh", tmp_path / f"{name}.json"
        code, _, err = run(["synthesize", str(graph), str(path), "-o", str(out), "--report", str(report)], capsys)
        assert code == 0, err
        r = json.loads(report.read_text())
        r.pop("files"), r.pop("timings_s"), r.pop("samples_per_s")
        outputs.append((out.read_bytes(), r))
    assert outputs[0][0] == outputs[1][0] and outputs[0][1] == outputs[1][1]


def test_cli_csv_with_foreign_sensor_names_is_advised_a_device_map(tmp_path, kelly6_csv, capsys):
    graph, ordered = kelly6_csv
    rec = import_csv(ordered)
    foreign = tmp_path / "foreign.csv"
    export_csv(_with_sensors(rec, ["S1", "S2", "S3", "S4", "S5", "S6"], list(range(6))), foreign)
    code, _, err = run(["synthesize", str(graph), str(foreign), "-o", str(tmp_path / "o.bvh")], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "not in the graph: S1, S2" in err and "--device-map (xsens, mvn, generic or a map file)" in err
    assert "relayout" not in err
    # A recording of another preset's sensors: another graph is the fix.
    other = tmp_path / "other.csv"
    export_csv(_with_sensors(rec, PRESETS["dip6"].sensor_names, list(range(6))), other)
    code, _, err = run(["synthesize", str(graph), str(other), "-o", str(tmp_path / "o.bvh")], capsys)
    assert code == 2 and "rebuild the graph or run `graphsvc relayout`" in err and "--device-map" not in err


def test_cli_inspect_says_how_a_device_csv_was_read(tmp_path, capsys):
    """The sensor frame, up axis and units, each with where it came from: a flag, the
    file's header comment, or the default (MVNX: its format)."""
    path = tmp_path / "d.csv"
    path.write_text("# units=g\nt_s,LWrist_ax,LWrist_ay,LWrist_az\n0,0,0,1\n0.01,0,0,1\n")
    code, out, _ = run(["inspect", str(path), "--up", "z"], capsys)
    assert code == 0
    assert out.splitlines()[-1] == "  read: sensor frame device (default), up z (--up), units g (file header)"
    code, out, _ = run(["inspect", str(path), "--units", "m/s2", "--json"], capsys)
    reading = json.loads(out)["recordings"][0]["reading"]
    assert reading == {
        "sensor_frame": {"value": "device", "from": "default"},
        "up": {"value": "y", "from": "default"},
        "units": {"value": "m/s2", "from": "argument"},
    }
    path.write_text("# sensor_frame=layout\n# up=Z\nt_s,s_ax,s_ay,s_az\n0,0,0,1\n0.01,0,0,1\n")
    code, out, _ = run(["inspect", str(path)], capsys)
    assert out.splitlines()[-1] == "  read: sensor frame layout (file header), up z (file header), units m/s2 (default)"
    mvnx = write_mvnx(tmp_path / "t.mvnx", ("Pelvis",), [normal(k, sensorAcceleration=[0, 0, G]) for k in range(3)])
    code, out, _ = run(["inspect", str(mvnx)], capsys)
    assert out.splitlines()[-1] == (
        "  read: sensor frame device (MVNX format), up z (MVNX format), units m/s2 (MVNX format)"
    )
    rec = tmp_path / "r.rec"
    from dataclasses import replace

    from graphsvc.sensors.recording import save_recording

    for meta in (
        {"simulated": True},  # a layout's recording
        {"imported_from": "csv", "units": "g", "up": "y", "sensor_frame": "device"},
    ):  # not saying whence
        save_recording(replace(_device_recording(("a",)), meta=meta), rec)
        code, out, _ = run(["inspect", str(rec)], capsys)
        assert code == 0 and "read:" not in out

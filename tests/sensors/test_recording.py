"""Recordings: validation, .rec and CSV round trips, CSV import of device files,
error reporting, describe_recording."""

from __future__ import annotations

import numpy as np
import pytest

from graphsvc.errors import FormatError, InputError
from graphsvc.sensors.recording import (
    Recording,
    describe_recording,
    export_csv,
    import_csv,
    load_recording,
    save_recording,
)
from graphsvc.store import read_container, write_container

CONSTRAINTS = [
    [{"start_s": 0.0, "end_s": 0.1, "require": {"contact": "left"}}],
    [
        {"start_s": 0.05, "end_s": 0.2, "require": {"label": "walk"}},
        {"start_s": 0, "end_s": 1, "require": {"contact": "none"}},
    ],
]


def make_recording(T: int = 12, optional: bool = True, rate: float = 30.0) -> Recording:
    rng = np.random.default_rng(3)
    acc = rng.normal(0, 5, size=(T, 2, 3)).astype(np.float32)
    acc[2, 1, 0] = np.nan
    acc[5, 0, :] = np.nan
    pos = rng.normal(size=(T, 2)) if optional else None
    heading = rng.uniform(-np.pi, np.pi, T) if optional else None
    if optional:
        pos[4] = np.nan
        heading[7] = np.nan
    return Recording(
        rate_hz=rate,
        timestamps_s=np.arange(T) / rate,
        sensor_names=("l_wrist", "r_ankle"),
        accelerations=acc,
        ground_position=pos,
        heading=heading,
        constraints=CONSTRAINTS if optional else [],
        layout={"name": "two", "sensors": [{"name": "l_wrist"}, {"name": "r_ankle"}]} if optional else None,
        meta={"source": "clip.bvh", "seed": 4, "noise": {"sigma": 0.5}},
    )


def assert_same(a: Recording, b: Recording, exact: bool = True) -> None:
    assert a.rate_hz == b.rate_hz
    assert a.sensor_names == b.sensor_names
    np.testing.assert_array_equal(a.accelerations, b.accelerations)  # float32: exact even via '%.9g'
    assert b.accelerations.dtype == np.float32
    close = np.testing.assert_array_equal if exact else (lambda x, y: np.testing.assert_allclose(x, y, rtol=1e-8))
    close(a.timestamps_s, b.timestamps_s)
    for name in ("ground_position", "heading"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            close(x, y)


# ---------------------------------------------------------------- validation


def test_properties():
    rec = make_recording(T=12)
    rec.validate()
    assert rec.num_samples == 12 and rec.num_sensors == 2
    assert rec.duration_s == pytest.approx(12 / 30)


@pytest.mark.parametrize(
    "change",
    [
        {"rate_hz": 0.0},
        {"rate_hz": float("inf")},
        {
            "timestamps_s": np.zeros(0),
            "accelerations": np.zeros((0, 2, 3), np.float32),
            "ground_position": None,
            "heading": None,
        },
        {"timestamps_s": np.r_[0.0, 0.1, 0.1, *np.arange(3, 12) / 10]},
        {"timestamps_s": np.r_[np.nan, np.arange(1, 12) / 30]},
        {"sensor_names": ("a", "a")},
        {"sensor_names": ("a,b", "c")},
        {"sensor_names": ("a",)},
        {"accelerations": np.full((12, 2, 3), np.inf, np.float32)},
        {"ground_position": np.zeros((12, 3))},
        {"heading": np.r_[np.inf, np.zeros(11)]},
        {"constraints": [[{"start_s": 0.5, "end_s": 0.5, "require": {"contact": "left"}}]]},
        {"constraints": [[{"start_s": -1, "end_s": 0.5, "require": {"contact": "left"}}]]},
        {"constraints": [[{"start_s": 0, "end_s": 0.5, "require": {"contact": "middle"}}]]},
        {"constraints": [[{"start_s": 0, "end_s": 0.5, "require": {"speed": 2}}]]},
        {"constraints": [[{"start_s": 0, "end_s": 0.5, "require": {"label": "x"}, "extra": 1}]]},
        {"constraints": [{"start_s": 0, "end_s": 0.5, "require": {"label": "x"}}]},
        {"layout": "two"},
    ],
)
def test_validate_refuses(change):
    rec = make_recording()
    for k, v in change.items():
        setattr(rec, k, v)
    with pytest.raises(InputError):
        rec.validate()


# ---------------------------------------------------------------- .rec


@pytest.mark.parametrize("optional", [True, False])
def test_rec_round_trip(tmp_path, optional):
    rec = make_recording(optional=optional)
    path = tmp_path / "r.rec"
    save_recording(rec, path)
    back = load_recording(path)
    assert_same(rec, back)
    assert back.constraints == rec.constraints
    assert back.layout == rec.layout and back.meta == rec.meta
    assert back.accelerations.flags.writeable  # copied out of the file, not mapped


def test_rec_deterministic(tmp_path):
    save_recording(make_recording(), tmp_path / "a.rec")
    save_recording(make_recording(), tmp_path / "b.rec")
    assert (tmp_path / "a.rec").read_bytes() == (tmp_path / "b.rec").read_bytes()


def test_rec_refuses_other_kind_and_versions(tmp_path):
    path = tmp_path / "g.rec"
    write_container(path, "graph", {}, {"a": np.zeros(2)}, 1)
    with pytest.raises(FormatError, match="expected a recording, got a graph"):
        load_recording(path)
    save_recording(make_recording(), path)
    meta, arrays, _ = read_container(path, mmap=False)
    write_container(path, "recording", meta, arrays, 2)
    with pytest.raises(FormatError, match="format version 2"):
        load_recording(path)
    del arrays["timestamps_s"]
    write_container(path, "recording", meta, arrays, 1)
    with pytest.raises(FormatError, match="timestamps_s"):
        load_recording(path)


def test_rec_corrupted(tmp_path):
    path = tmp_path / "r.rec"
    save_recording(make_recording(), path)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x10
    path.write_bytes(bytes(data))
    with pytest.raises(FormatError, match="corrupted"):
        load_recording(path)


def test_save_invalid_leaves_nothing(tmp_path):
    rec = make_recording()
    rec.sensor_names = ("a", "a")
    with pytest.raises(InputError):
        save_recording(rec, tmp_path / "r.rec")
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------- CSV


@pytest.mark.parametrize("optional", [True, False])
def test_csv_round_trip(tmp_path, optional):
    rec = make_recording(optional=optional, rate=29.97)
    path = tmp_path / "r.csv"
    export_csv(rec, path)
    back = import_csv(path)
    assert_same(rec, back, exact=False)
    assert back.rate_hz == 29.97  # from the comment line, not re-estimated
    assert back.constraints == [] and back.layout is None


def test_csv_format(tmp_path):
    rec = make_recording(T=8)
    rec.accelerations[1, 1, 0] = 9.81
    export_csv(rec, tmp_path / "r.csv")
    lines = (tmp_path / "r.csv").read_text().splitlines()
    assert lines[0] == "# graphsvc recording v1"
    assert lines[1] == "# rate_hz=30"
    assert lines[2] == (
        "t_s,l_wrist_ax,l_wrist_ay,l_wrist_az,r_ankle_ax,r_ankle_ay,r_ankle_az,pos_x_m,pos_z_m,heading_rad"
    )
    row = lines[4].split(",")
    assert row[0] == "0.0333333333"
    assert row[4] == "9.81000042"  # float32(9.81) with '%.9g'
    assert lines[5].split(",")[4] == ""  # the NaN at [2, 1, 0]
    assert lines[8].split(",")[1:4] == ["", "", ""]  # sensor 0 lost at sample 5
    assert len(lines) == 3 + 8


def test_csv_deterministic(tmp_path):
    export_csv(make_recording(), tmp_path / "a.csv")
    export_csv(make_recording(), tmp_path / "b.csv")
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()


def test_device_csv_any_order_and_g_units(tmp_path):
    path = tmp_path / "device.csv"
    path.write_text(
        "\ufeffhip_az,t_s,hip_ax, hip_ay ,heading_rad\r\n"
        "0.5,0.00,1,-1,0.1\r\n"
        ",0.02,NaN,2,nan\r\n"
        "0,0.04,0.25,0,0.3\r\n"
        "\r\n"
        "0,0.07,0,0,\r\n"
    )
    rec = import_csv(path, units="g")
    assert rec.sensor_names == ("hip",)
    assert rec.rate_hz == pytest.approx(50.0)  # median step 0.02 s
    assert rec.ground_position is None
    np.testing.assert_array_equal(rec.heading[[0, 2]], [0.1, 0.3])
    assert np.isnan(rec.heading[1]) and np.isnan(rec.heading[3])
    # Hand-computed: 1 g → 9.81 m/s², -1 g → -9.81, 0.5 g → 4.905, 0.25 g → 2.4525.
    np.testing.assert_array_equal(rec.accelerations[0, 0], np.float32([9.81, -9.81, 4.905]))
    assert rec.accelerations[2, 0, 0] == np.float32(2.4525)
    assert np.isnan(rec.accelerations[1, 0, 0]) and np.isnan(rec.accelerations[1, 0, 2])
    assert rec.accelerations[1, 0, 1] == np.float32(19.62)
    assert import_csv(path, rate_hz=60.0).rate_hz == 60.0
    assert import_csv(path).accelerations[0, 0, 0] == 1.0  # m/s² by default


def test_csv_layout_attached(tmp_path):
    export_csv(make_recording(), tmp_path / "r.csv")
    layout = {"name": "two", "sensors": []}
    assert import_csv(tmp_path / "r.csv", layout=layout).layout == layout


@pytest.mark.parametrize(
    "text,line,message",
    [
        ("t_s,a_ax,a_ay,a_az\n0,1,2,3\n0.1,1,2\n", 3, "expected 4 columns, got 3"),
        ("t_s,a_ax,a_ay,a_az\n0,1,2,3\n0.1,1,x2,3\n", 3, "non-numeric value 'x2' in column a_ay"),
        ("# note\na_ax,a_ay,a_az\n0,1,2\n", 2, "missing t_s column"),
        ("t_s,a_ax,a_az\n0,1,2\n", 1, "lacks column"),
        ("t_s,a_ax,a_ay,a_az\n0,1,2,3\n0.1,1,2,3\n0.1,1,2,3\n", 4, "strictly increasing"),
        ("t_s,a_ax,a_ay,a_az\n0.2,1,2,3\n0.1,1,2,3\n", 3, "strictly increasing"),
        ("t_s,a_ax,a_ay,a_az\n0,1,2,3\n,1,2,3\n", 3, "t_s is empty"),
        ("t_s,a_ax,a_ay,a_az\n0,inf,2,3\n", 2, "infinite"),
        ("t_s,a_ax,a_ay,a_az,battery\n0,1,2,3,4\n", 1, "unknown column 'battery'"),
        ("t_s,a_ax,a_ay,a_az,a_ax\n0,1,2,3,4\n", 1, "duplicate column"),
        ("t_s,pos_x_m\n0,1\n", 1, "pos_x_m and pos_z_m"),
        ("t_s,a_ax,a_ay,a_az\n", 1, "no samples"),
    ],
)
def test_csv_errors_have_line_numbers(tmp_path, text, line, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(FormatError, match=message) as info:
        import_csv(path, rate_hz=10)
    assert info.value.line == line
    assert f"bad.csv:{line}:" in str(info.value)


def test_csv_other_errors(tmp_path):
    path = tmp_path / "x.csv"
    path.write_text("# only comments\n")
    with pytest.raises(FormatError, match="no header"):
        import_csv(path)
    path.write_text("t_s,a_ax,a_ay,a_az\n0,1,2,3\n")
    with pytest.raises(InputError, match="rate"):
        import_csv(path)  # one sample: no step to take the rate from
    with pytest.raises(InputError, match="units"):
        import_csv(path, units="mg")
    with pytest.raises(FormatError, match="no such file"):
        import_csv(tmp_path / "absent.csv")
    assert import_csv(path, rate_hz=100).num_samples == 1


def test_csv_export_missing_folder(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        export_csv(make_recording(), tmp_path / "no" / "r.csv")
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------- describe


def test_describe():
    info = describe_recording(make_recording(T=30))
    assert info == {
        "samples": 30,
        "sensors": ["l_wrist", "r_ankle"],
        "channels": [
            "l_wrist.ax",
            "l_wrist.ay",
            "l_wrist.az",
            "r_ankle.ax",
            "r_ankle.ay",
            "r_ankle.az",
            "ground_position.x",
            "ground_position.z",
            "heading",
        ],
        "rate_hz": 30.0,
        "duration_s": 1.0,
        "has_ground_position": True,
        "has_heading": True,
        "constraint_sets": 2,
    }
    bare = describe_recording(make_recording(optional=False))
    assert bare["channels"][-1] == "r_ankle.az" and not bare["has_heading"] and bare["constraint_sets"] == 0


# ---------------------------------------------------------------- orientations and markers


def with_orientations_and_markers(rec: Recording, accelerations: bool = True) -> Recording:
    from dataclasses import replace

    rng = np.random.default_rng(8)
    T, S = rec.num_samples, rec.num_sensors
    q = rng.normal(size=(T, S, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q = q.astype(np.float32)
    q[3, 1] = np.nan
    markers = rng.normal(size=(T, 3, 3))
    markers[[1, 2, 6], 2] = np.nan  # a marker flickering out
    return replace(
        rec,
        accelerations=rec.accelerations if accelerations else None,
        orientations=q,
        marker_names=("LFHD", "RWRA", "LTOE"),
        marker_positions=markers,
    )


@pytest.mark.parametrize("accelerations", [True, False])
def test_orientations_and_markers_round_trip_through_rec_and_csv(tmp_path, accelerations):
    rec = with_orientations_and_markers(make_recording(), accelerations)
    for path, read, write, exact in (
        (tmp_path / "r.rec", load_recording, save_recording, True),
        (tmp_path / "r.csv", import_csv, export_csv, False),
    ):
        write(rec, path)
        back = read(path)
        assert back.marker_names == rec.marker_names and back.sensor_names == rec.sensor_names
        np.testing.assert_array_equal(back.orientations, rec.orientations)  # float32: exact even via '%.9g'
        assert back.orientations.dtype == np.float32
        if exact:
            np.testing.assert_array_equal(back.marker_positions, rec.marker_positions)
        else:
            np.testing.assert_allclose(back.marker_positions, rec.marker_positions, rtol=1e-8)
        assert np.isnan(back.marker_positions[[1, 2, 6], 2]).all()
        if accelerations:
            np.testing.assert_array_equal(back.accelerations, rec.accelerations)
        else:
            assert back.accelerations is None
    d = describe_recording(rec)
    assert "LFHD.px" in d["channels"] and "l_wrist.qw" in d["channels"]
    # A recording made before orientations and markers reads as it did: none of either.
    plain = make_recording()
    save_recording(plain, tmp_path / "plain.rec")
    back = load_recording(tmp_path / "plain.rec")
    assert back.orientations is None and back.marker_positions is None and back.marker_names == ()


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda r: r.orientations.__setitem__((0, 0), [2.0, 0, 0, 0]), "unit quaternions"),
        (lambda r: r.orientations.__setitem__((0, 0, 0), np.inf), "infinite"),
        (lambda r: setattr(r, "marker_names", ("A", "A", "B")), "duplicate marker names"),
        (lambda r: setattr(r, "marker_positions", r.marker_positions[:, :2]), "marker_positions has shape"),
    ],
)
def test_orientation_and_marker_checks(change, message):
    rec = with_orientations_and_markers(make_recording())
    change(rec)
    with pytest.raises(InputError, match=message):
        rec.validate()

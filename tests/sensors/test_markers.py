"""Optical markers: marker sets and where they sit, simulated gaps and flicker, and the
C3D and marker-CSV readers (units, up axis, labels, gaps, bad files)."""

import json

import numpy as np
import pytest

from graphsvc.errors import FormatError, InputError, LayoutError
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.sensors.files import read_recording
from graphsvc.sensors.markers import PRESETS, keep_markers, load_marker_set, marker_positions, place_markers
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.sensors.noise import parse_noise
from graphsvc.sensors.optical import export_marker_csv, read_c3d, read_marker_csv, to_y_up
from graphsvc.sensors.recording import load_recording, save_recording
from graphsvc.sensors.simulate import MarkerPattern, marker_visibility, parse_gaps, simulate_marker_recording


@pytest.fixture(scope="module")
def clip():
    return generate_knowledge_base(seed=1, minutes=0.1)[0]


def test_built_in_sets():
    assert [len(PRESETS[n].markers) for n in ("hands-feet", "left-foot", "head-back", "vicon")] == [4, 1, 4, 41]
    vicon = PRESETS["vicon"].marker_names
    for name in "LFHD RFHD LBHD RBHD C7 T10 CLAV STRN RBAC LWRA LWRB LFIN LHEE LTOE LMT5 RTOE RMT5".split():
        assert name in vicon
    assert keep_markers(PRESETS["vicon"], ("RTOE", "LFHD")).marker_names == ("LFHD", "RTOE")  # (the set's order)


def test_markers_sit_where_their_definition_says(clip):
    """In the rest pose a marker is at its joint, along its bone, plus its offset; it
    moves rigidly with its segment; left and right mirror each other."""
    sk = clip.skeleton
    table = joint_map(sk)
    rest = np.zeros((sk.num_joints, 3))
    for j in range(1, sk.num_joints):
        rest[j] = rest[sk.parents[j]] + sk.offsets[j]
    p = place_markers(PRESETS["vicon"], sk)
    names = PRESETS["vicon"].marker_names
    lthi = names.index("LTHI")
    want = rest[table["l_hip"]] + 0.6 * (rest[table["l_knee"]] - rest[table["l_hip"]]) + np.array([0.07, 0, 0])
    np.testing.assert_allclose(rest[p.carrier[lthi]] + p.local[lthi], want, atol=1e-12)
    for left in ("LTHI", "LWRA", "LHEE", "LFHD"):
        a, b = names.index(left), names.index("R" + left[1:])
        pa, pb = rest[p.carrier[a]] + p.local[a], rest[p.carrier[b]] + p.local[b]
        np.testing.assert_allclose(pa * [-1, 1, 1], pb, atol=1e-9)  # (the procedural skeleton is symmetric)
    world_rot, world_pos = motion_fk(clip)
    pts = marker_positions(world_rot, world_pos, p)
    # Rigid: a marker keeps its distance to its carrier joint and to that joint's child.
    d = np.linalg.norm(pts[:, lthi] - world_pos[:, table["l_hip"]], axis=-1)
    assert np.ptp(d) < 1e-9 and d[0] > 0.1


def test_marker_set_files_and_bad_definitions(tmp_path):
    f = tmp_path / "mine.json"
    f.write_text(json.dumps({"markers": [{"name": "nose", "segment": "head", "offset_m": [0, 0.05, 0.1]}]}))
    s = load_marker_set(str(f))
    assert s.name == "mine" and s.markers[0].offset_m == (0.0, 0.05, 0.1)
    toml = tmp_path / "m.toml"
    toml.write_text('name = "t"\n[[markers]]\nname = "a"\nsegment = "l_knee"\ntoward = "l_ankle"\nalong = 0.5\n')
    assert load_marker_set(str(toml)).markers[0].toward == "l_ankle"
    for bad, needle in (
        ({"markers": [{"name": "a", "segment": "l_paw"}]}, "segment must be a canonical joint"),
        ({"markers": [{"name": "a", "segment": "head", "along": 0.5}]}, "'along' needs 'toward'"),
        ({"markers": [{"name": "a", "segment": "head"}, {"name": "a", "segment": "chest"}]}, "duplicate marker names"),
        ({"markers": [{"name": "a", "segment": "head", "offset_m": [1, 2]}]}, "offset_m"),
        ({"markers": []}, "at least one marker"),
    ):
        f.write_text(json.dumps(bad))
        with pytest.raises(LayoutError, match=needle):
            load_marker_set(str(f))
    with pytest.raises(LayoutError, match="unknown marker set"):
        load_marker_set("elbows")
    with pytest.raises(InputError, match="defines no marker XYZ"):
        keep_markers(PRESETS["hands-feet"], ("XYZ",))


def test_gaps_and_flicker_patterns():
    assert parse_gaps("20:30, 90:25") == ((20, 30), (90, 25))
    for bad in ("20", "a:3", "5:0", "-1:4"):
        with pytest.raises(InputError):
            parse_gaps(bad)
    T, M = 3000, 4
    times = np.arange(T) / 30.0
    seen = marker_visibility(times, M, MarkerPattern(gaps=((20, 30),)), 60.0, np.random.default_rng(0))
    # Frames 20–49 of a 60 Hz clip are 0.333–0.833 s: samples 10–24 at 30 Hz.
    assert np.flatnonzero(~seen.any(axis=1)).tolist() == list(range(10, 25))
    seen = marker_visibility(times, M, MarkerPattern(flicker=0.1), 30.0, np.random.default_rng(1))
    assert (~seen).mean() == pytest.approx(0.1, abs=0.02)
    runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[1], seen[:, 0].astype(int), [1]])) != 0))[::2]
    assert np.mean(runs) == pytest.approx(3.0, abs=0.6)  # (dropouts of 3 samples on average)
    seen = marker_visibility(times, M, MarkerPattern(gap_fraction=0.3), 30.0, np.random.default_rng(2))
    gap = ~seen.any(axis=1)
    assert 0.3 <= gap.mean() < 0.33 and (gap == ~seen.all(axis=1)).all()
    with pytest.raises(InputError, match="flicker"):
        marker_visibility(times, M, MarkerPattern(flicker=1.0), 30.0, np.random.default_rng(0))


def test_simulated_marker_recordings(clip, tmp_path):
    exact = simulate_marker_recording(clip, "hands-feet", NOISE["none"], seed=4)
    world_rot, world_pos = motion_fk(clip)
    np.testing.assert_array_equal(
        exact.marker_positions,
        marker_positions(world_rot, world_pos, place_markers(PRESETS["hands-feet"], clip.skeleton)),
    )
    assert exact.accelerations is None and exact.sensor_names == () and exact.meta["simulated"]
    noisy = simulate_marker_recording(
        clip, "hands-feet", parse_noise("none,marker=2"), seed=4, pattern=MarkerPattern(flicker=0.2)
    )
    again = simulate_marker_recording(
        clip, "hands-feet", parse_noise("none,marker=2"), seed=4, pattern=MarkerPattern(flicker=0.2)
    )
    np.testing.assert_array_equal(noisy.marker_positions, again.marker_positions)  # same seed, same bytes
    seen = np.isfinite(noisy.marker_positions[..., 0])
    err = (noisy.marker_positions - exact.marker_positions)[seen]
    assert err.std() * 1000 == pytest.approx(2.0, rel=0.15)
    path = tmp_path / "m.rec"
    save_recording(noisy, path)
    back = load_recording(path)
    np.testing.assert_array_equal(back.marker_positions, noisy.marker_positions)
    assert back.meta["marker_set"]["name"] == "hands-feet"


def test_marker_csv_round_trip_units_and_up_axis(clip, tmp_path):
    rec = simulate_marker_recording(clip, "head-back", NOISE["none"], pattern=MarkerPattern(flicker=0.3))
    path = tmp_path / "m.csv"
    export_marker_csv(rec, path)
    back = read_recording(path)
    np.testing.assert_allclose(back.marker_positions, rec.marker_positions, atol=1e-8, equal_nan=True)
    assert back.marker_names == rec.marker_names and back.rate_hz == rec.rate_hz
    # A Z-up file in millimetres: (x, y, z) → (y, z, x), / 1000.
    lines = ["# units=mm", "# up=z", "time,A_x,A_y,A_z", "0,100,200,1700", "0.01,,,", "0.02,110,210,1690"]
    (tmp_path / "z.csv").write_text("\n".join(lines) + "\n")
    z = read_marker_csv(tmp_path / "z.csv")
    np.testing.assert_allclose(z.marker_positions[0, 0], [0.2, 1.7, 0.1])
    assert np.isnan(z.marker_positions[1, 0]).all() and z.rate_hz == pytest.approx(100.0)
    np.testing.assert_allclose(
        read_marker_csv(tmp_path / "z.csv", up="y", units="cm").marker_positions[0, 0], [1.0, 2.0, 17.0]
    )  # (flags override the file)
    for text, needle in (
        ("time,A_x,A_y\n0,1,2\n", "lacks column"),
        ("time,A_x,A_y,A_z\n0,1,2,3\n0.1,1,2\n", ":3: expected 4 columns"),
        ("time,A_x,A_y,A_z\n0,1,2,3\n0,1,2,3\n", "strictly increasing"),
        ("time,A_x,A_y,A_z\n0,1,two,3\n", "non-numeric"),
        ("time,A_w,A_y,A_z\n0,1,2,3\n", "not NAME_x"),
        ("# units=furlongs\ntime,A_x,A_y,A_z\n0,1,2,3\n", "unknown length unit"),
        ("time,A_x,A_y,A_z\n", "no samples"),
    ):
        (tmp_path / "bad.csv").write_text(text)
        with pytest.raises(FormatError, match=needle):
            read_marker_csv(tmp_path / "bad.csv")


def _write_c3d(path, points_mm, labels, rate=100.0, residual=None):
    """A C3D file written with ezc3d: points (F, M, 3) mm."""
    import ezc3d

    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c["parameters"]["POINT"]["LABELS"]["value"] = list(labels)
    c["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    data = np.ones((4, len(labels), points_mm.shape[0]))
    data[:3] = np.transpose(points_mm, (2, 1, 0))
    c["data"]["points"] = data
    if residual is not None:
        c["data"]["meta_points"] = {
            "residuals": residual.T[None].astype(float),
            "camera_masks": np.zeros((7, len(labels), points_mm.shape[0]), bool),
        }
    c.write(str(path))


def test_c3d_units_axes_labels_and_gaps(clip, tmp_path):
    """A Z-up millimetre C3D of a simulated performance reads back as the simulation:
    subject prefixes dropped, unlabelled points skipped, negative residuals unseen,
    the vertical found from the markers' spread."""
    rec = simulate_marker_recording(clip, "vicon", NOISE["none"], keep=("LFHD", "RFHD", "LWRA", "RWRA", "LTOE", "RTOE"))
    y_up = rec.marker_positions
    z_up = y_up[..., [2, 0, 1]]  # the inverse of (x, y, z) → (y, z, x)
    np.testing.assert_allclose(to_y_up(z_up, "z"), y_up)
    F, M = y_up.shape[:2]
    pts = np.concatenate([z_up, np.zeros((F, 1, 3))], axis=1) * 1000.0
    residual = np.zeros((F, M + 1))
    residual[5:9, 2] = -1.0
    path = tmp_path / "take.c3d"
    _write_c3d(path, pts, [f"Jo:{n}" for n in rec.marker_names] + ["*6"], rate=rec.rate_hz, residual=residual)
    back = read_c3d(path)
    assert back.marker_names == rec.marker_names and back.meta["up"] == "z" and back.rate_hz == rec.rate_hz
    want = y_up.copy()
    want[5:9, 2] = np.nan
    np.testing.assert_allclose(back.marker_positions, want, atol=1e-5, equal_nan=True)
    assert read_c3d(path, up="y").meta["up_from"] == "given"
    # Truncated, empty or garbage files: one FormatError.
    data = path.read_bytes()
    for n in (100, len(data) - 300):
        (tmp_path / "cut.c3d").write_bytes(data[:n])
        with pytest.raises(FormatError):
            read_c3d(tmp_path / "cut.c3d")
    (tmp_path / "junk.c3d").write_bytes(b"\x00" * 2000)
    with pytest.raises(FormatError):
        read_c3d(tmp_path / "junk.c3d")
    only_unlabelled = tmp_path / "u.c3d"
    _write_c3d(only_unlabelled, pts[:, :2], ["*0", "*1"])
    with pytest.raises(FormatError, match="no labelled markers"):
        read_c3d(only_unlabelled)
    with pytest.raises(FormatError, match="no such file"):
        read_c3d(tmp_path / "none.c3d")

"""BVH reading and writing: hand-made files, round trips, malformed input, real data."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from graphsvc.errors import FormatError, InputError
from graphsvc.motion import quat
from graphsvc.motion.bvh import bvh_text, read_bvh, write_bvh
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.skeleton import Motion, Skeleton

# A small cm file: root with position channels, a joint whose position channels
# replace its OFFSET (Bandai style), XYZ and ZXY rotation orders, End Sites.
SIMPLE = """\
HIERARCHY
ROOT Hips
{
  OFFSET 0 90 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 6 Xposition Yposition Zposition Xrotation Yrotation Zrotation
    JOINT Head
    {
      OFFSET 0 50 0
      CHANNELS 3 Zrotation Xrotation Yrotation
      End Site
      {
        OFFSET 0 15 0
      }
    }
  }
  JOINT Leg
  {
    OFFSET 10 -5 0
    CHANNELS 1 Xrotation
    End Site Toe
    {
      OFFSET 0 -85 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0333333
1 90 2 10 20 30 0 10 0 5 6 7 0 0 90 45
-1 91 -2 0 0 0 0 12 0 0 0 0 0 0 0 -30
"""


def write(tmp_path: Path, text: str, name: str = "clip.bvh") -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode("utf-8") if isinstance(text, str) else text)
    return path


def same_rotation(a: np.ndarray, b: np.ndarray, atol: float) -> bool:
    """Unit quaternions a and b describe the same rotations (q and -q are equal)."""
    return bool(np.allclose(np.abs(np.sum(a * b, axis=-1)), 1.0, atol=atol))


def test_reads_hierarchy_channels_and_end_sites(tmp_path):
    m = read_bvh(write(tmp_path, SIMPLE))
    sk = m.skeleton
    assert sk.names == ("Hips", "Spine", "Head", "Head_End", "Leg", "Toe")
    assert list(sk.parents) == [-1, 0, 1, 2, 0, 4]
    assert list(sk.end_site) == [False, False, False, True, False, True]
    assert sk.channels[1] == ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
    assert sk.channels[3] == () and sk.channels[4] == ("Xrotation",)
    np.testing.assert_allclose(sk.offsets[5], [0, -0.85, 0])  # auto-detected centimetres
    assert m.rate_hz == 30.0 and m.num_frames == 2


def test_position_channels_replace_offset_and_rotations_follow_channel_order(tmp_path):
    m = read_bvh(write(tmp_path, SIMPLE))
    # Spine: position channels (0, 10, 0) cm replace the OFFSET, they do not add to it.
    np.testing.assert_allclose(m.translations[:, 1], [[0, 0.10, 0], [0, 0.12, 0]])
    np.testing.assert_allclose(m.translations[0, 0], [0.01, 0.90, 0.02])
    # Joints without position channels carry their offset every frame.
    np.testing.assert_allclose(m.translations[:, 2], [[0, 0.5, 0]] * 2)
    expect = {
        0: quat.from_euler([[10, 20, 30], [0, 0, 0]], "ZXY", degrees=True),
        1: quat.from_euler([[5, 6, 7], [0, 0, 0]], "XYZ", degrees=True),
        2: quat.from_euler([[0, 0, 90], [0, 0, 0]], "ZXY", degrees=True),
        4: quat.from_euler([[45], [-30]], "X", degrees=True),
    }
    for j, q in expect.items():
        assert same_rotation(m.rotations[:, j], q, 1e-12), j
    assert same_rotation(m.rotations[:, 3], quat.identity((2,)), 1e-12)


def test_zxy_means_rz_rx_ry(tmp_path):
    """A 90° Z then 90° X intrinsic rotation takes the +Y bone to +Z... checked via FK."""
    text = SIMPLE.replace("1 90 2 10 20 30", "0 90 0 90 90 0").replace("-1 91 -2 0 0 0", "0 90 0 0 0 0")
    m = read_bvh(write(tmp_path, text), scale=0.01)
    _, pos = motion_fk(m)
    spine = pos[0, 1] - pos[0, 0]  # local (0, 0.1, 0) rotated by Rz(90)·Rx(90)
    r = quat.to_matrix(quat.from_euler(np.array([90.0, 90.0, 0.0]), "ZXY", degrees=True))
    expected = r @ np.array([0, 0.1, 0])
    np.testing.assert_allclose(spine, expected, atol=1e-12)
    rz = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])
    rx = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0.0]])
    np.testing.assert_allclose(spine, rz @ rx @ np.array([0, 0.1, 0]), atol=1e-12)


@pytest.mark.parametrize(
    "factor, expected",
    [(0.01, 1.0), (1.0, 0.01), (10.0, 0.001)],
)
def test_unit_auto_detection(tmp_path, factor, expected):
    text = (
        SIMPLE.replace("OFFSET 0 50 0", f"OFFSET 0 {50 * factor} 0")
        .replace("OFFSET 0 -85 0", f"OFFSET 0 {-85 * factor} 0")
        .replace("OFFSET 0 15 0", f"OFFSET 0 {15 * factor} 0")
        .replace("OFFSET 10 -5 0", f"OFFSET {10 * factor} {-5 * factor} 0")
    )
    text = text.replace("0 10 0 5 6 7", f"0 {10 * factor} 0 5 6 7").replace("0 12 0 0 0 0", f"0 {12 * factor} 0 0 0 0")
    m = read_bvh(write(tmp_path, text))
    np.testing.assert_allclose(m.skeleton.offsets[5], [0, -85 * factor * expected, 0], rtol=1e-9)


def test_a_tall_figure_in_centimetres_is_read_in_centimetres(tmp_path):
    from graphsvc.motion.procedural.body import standard_skeleton

    sk = standard_skeleton()
    # the procedural 1.75 m adult scaled to 2.3 m: its hand tip to the other side's toe
    # tip spans 2.37 m × 2.3 / 1.75 = 3.1 m, 311 file units
    tall = Skeleton(sk.names, sk.parents, sk.offsets * (2.3 / 1.75), sk.channels, sk.end_site)
    rot = np.zeros((2, sk.num_joints, 4))
    rot[..., 0] = 1.0
    m = Motion(tall, rot, np.broadcast_to(tall.offsets, (2, sk.num_joints, 3)), 30.0)
    write_bvh(tmp_path / "tall.bvh", m, scale=100.0)
    np.testing.assert_allclose(read_bvh(tmp_path / "tall.bvh").skeleton.offsets, tall.offsets, atol=1e-9)


def test_explicit_scale_and_rate(tmp_path):
    m = read_bvh(write(tmp_path, SIMPLE.replace("0.0333333", "0.01")), scale=1.0)
    assert m.rate_hz == 100.0
    np.testing.assert_allclose(m.skeleton.offsets[2], [0, 50, 0])
    m = read_bvh(write(tmp_path, SIMPLE.replace("0.0333333", "0.03")))
    assert m.rate_hz == pytest.approx(1 / 0.03)


def test_crlf_and_tabs(tmp_path):
    text = SIMPLE.replace("\n", "\r\n").replace("  ", "\t")
    a = read_bvh(write(tmp_path, text, "crlf.bvh"))
    b = read_bvh(write(tmp_path, SIMPLE))
    np.testing.assert_array_equal(a.rotations, b.rotations)
    np.testing.assert_array_equal(a.translations, b.translations)


# ---------------------------------------------------------------------------
# Writing
# ---------------------------------------------------------------------------


def test_write_read_round_trip_and_determinism(tmp_path):
    m = read_bvh(write(tmp_path, SIMPLE))
    out = tmp_path / "out.bvh"
    write_bvh(out, m, scale=100.0)
    first = out.read_bytes()
    write_bvh(out, m, scale=100.0)
    assert out.read_bytes() == first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.bvh", "out.bvh"]  # no temp files left
    back = read_bvh(out)
    assert back.skeleton.topology() == m.skeleton.topology()
    assert same_rotation(back.rotations, m.rotations, 1e-9)
    np.testing.assert_allclose(back.translations, m.translations, atol=1e-9)
    assert back.rate_hz == 30.0


def test_failed_write_leaves_existing_file(tmp_path):
    m = read_bvh(write(tmp_path, SIMPLE))
    out = write(tmp_path, "old", "out.bvh")
    bad = m.copy(rate_hz=30.0)
    bad.rotations = bad.rotations[:, :3]  # wrong shape: fails while formatting
    with pytest.raises(Exception):  # noqa: B017 (whatever the failure, the old file stays)
        write_bvh(out, bad)
    assert out.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.bvh", "out.bvh"]


_POS = ("Xposition", "Yposition", "Zposition")
_ROT = ("Xrotation", "Yrotation", "Zrotation")


@st.composite
def motions(draw):
    """Random hierarchy, channel sets/orders (interleaved), offsets and values."""
    J = draw(st.integers(1, 7))
    # Depth-first order, as in any BVH file: a new joint hangs from the previous
    # joint or one of its ancestors.
    parents = [-1]
    for j in range(1, J):
        chain = [j - 1]
        while parents[chain[-1]] >= 0:
            chain.append(parents[chain[-1]])
        parents.append(draw(st.sampled_from(chain)))
    has_child = {p for p in parents[1:]}
    end_site = [j > 0 and j not in has_child and draw(st.booleans()) for j in range(J)]
    channels = []
    for j in range(J):
        if end_site[j]:
            channels.append(())
            continue
        pos = draw(st.lists(st.sampled_from(_POS), unique=True, max_size=3))
        rot = draw(st.sampled_from([(), ("X",), ("Y",), ("Z",), "XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"]))
        rot = [a + "rotation" for a in rot]
        chans = draw(st.permutations(pos + rot))
        channels.append(tuple(chans))
    F = draw(st.integers(1, 4))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    offsets = rng.uniform(-1, 1, (J, 3))
    rotations = quat.identity((F, J))
    translations = np.broadcast_to(offsets, (F, J, 3)).copy()
    for j, ch in enumerate(channels):
        order = "".join(c[0] for c in ch if c.endswith("rotation"))
        if len(order) == 3:
            rotations[:, j] = quat.normalize(rng.standard_normal((F, 4)))
        elif order:
            rotations[:, j] = quat.from_euler(rng.uniform(-179, 179, (F, 1)), order, degrees=True)
        for c in ch:
            if c.endswith("position"):
                translations[:, j, "XYZ".index(c[0])] = rng.uniform(-2, 2, F)
    names = tuple(f"J{j}" if not end_site[j] else f"J{parents[j]}_End" for j in range(J))
    if len(set(names)) != J:  # two end sites under one parent: give one its own name
        names = tuple(f"J{j}" for j in range(J))
    rate = draw(st.sampled_from([30.0, 60.0, 120.0, 24.5]))
    sk = Skeleton(names, np.array(parents), offsets, tuple(channels), np.array(end_site))
    return Motion(sk, rotations, translations, rate)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(motions(), st.sampled_from([1.0, 100.0]))
def test_round_trip_property(motion, scale):
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "m.bvh"
        write_bvh(path, motion, scale=scale)
        back = read_bvh(path, scale=1.0 / scale)
    sk, bk = motion.skeleton, back.skeleton
    assert bk.names == sk.names and bk.channels == sk.channels
    assert list(bk.parents) == list(sk.parents) and list(bk.end_site) == list(sk.end_site)
    np.testing.assert_allclose(bk.offsets, sk.offsets, atol=1e-6)
    np.testing.assert_allclose(back.translations, motion.translations, atol=1e-6)
    dots = np.abs(np.sum(back.rotations * motion.rotations, axis=-1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-6)
    wr0, wp0 = motion_fk(motion)
    wr1, wp1 = motion_fk(back)
    np.testing.assert_allclose(wp1, wp0, atol=1e-6)
    assert back.rate_hz == pytest.approx(motion.rate_hz, rel=1e-6)


@settings(max_examples=25, deadline=None)
@given(motions())
def test_fk_preserves_bone_lengths(motion):
    """Joints without position channels keep their distance to the parent."""
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "m.bvh"
        write_bvh(path, motion)
        back = read_bvh(path, scale=1.0)
    _, pos = motion_fk(back)
    sk = back.skeleton
    for j in range(1, sk.num_joints):
        if not any(c.endswith("position") for c in sk.channels[j]):
            d = np.linalg.norm(pos[:, j] - pos[:, sk.parents[j]], axis=-1)
            np.testing.assert_allclose(d, np.linalg.norm(sk.offsets[j]), atol=1e-9)


# ---------------------------------------------------------------------------
# Malformed input
# ---------------------------------------------------------------------------


MALFORMED = [
    ("no hierarchy", lambda t: t.replace("HIERARCHY\n", ""), "expected HIERARCHY", 1),
    ("no motion", lambda t: t.split("MOTION")[0], "MOTION", None),
    (
        "channel count",
        lambda t: t.replace("CHANNELS 3 Zrotation", "CHANNELS 4 Zrotation"),
        "declares 4 channels but lists 3",
        13,
    ),
    (
        "channel count low",
        lambda t: t.replace("CHANNELS 3 Zrotation", "CHANNELS 2 Zrotation"),
        "declares 2 channels but lists 3",
        13,
    ),
    (
        "channel name",
        lambda t: t.replace("CHANNELS 1 Xrotation", "CHANNELS 1 Wrotation"),
        "unknown channel name 'Wrotation'",
        23,
    ),
    (
        "missing close",
        lambda t: t.replace("      }\n    }\n  }\n", "      }\n    }\n", 1),
        "expected '}' closing joint",
        None,
    ),
    ("extra close", lambda t: t.replace("}\nMOTION", "}\n}\nMOTION"), "expected MOTION", 30),
    ("frames mismatch", lambda t: t.replace("Frames: 2", "Frames: 3"), "truncated", None),
    ("too many rows", lambda t: t.replace("Frames: 2", "Frames: 1"), "more data rows", 34),
    ("short row", lambda t: t.replace(" 90 45\n", " 90\n"), "frame 0: expected 16 values, found 15", 33),
    ("long row", lambda t: t.replace(" 0 -30\n", " 0 -30 7\n"), "frame 1: expected 16 values, found 17", 34),
    ("non numeric", lambda t: t.replace(" 5 6 7 ", " 5 six 7 "), "expected a number, found 'six'", 33),
    ("glued junk", lambda t: t.replace(" 5 6 7 ", " 5 6x 7 "), "found '6x'", 33),
    ("bad frame count", lambda t: t.replace("Frames: 2", "Frames: two"), "integer frame count", 31),
    ("bad frame time", lambda t: t.replace("Frame Time: 0.0333333", "Frame Time: 0"), "positive Frame Time", 32),
    ("no frame time", lambda t: t.replace("Frame Time: 0.0333333\n", ""), "Frame Time", 32),
    ("no offset", lambda t: t.replace("    OFFSET 0 -85 0\n", ""), "has no OFFSET", None),
    ("short offset", lambda t: t.replace("OFFSET 0 50 0", "OFFSET 0 50"), "OFFSET followed by 3 numbers", 12),
    ("duplicate name", lambda t: t.replace("JOINT Leg", "JOINT Spine"), "duplicate joint name 'Spine'", 20),
    ("two roots", lambda t: t.replace("MOTION", "ROOT X\n{\n}\nMOTION"), "only one ROOT", 30),
    ("binary header", lambda t: t.replace("Spine", "Sp\udcffine"), "not UTF-8", None),
    ("binary data", lambda t: t.replace(" 5 6 7 ", " 5 \x00 7 "), "expected a number", 33),
]


@pytest.mark.parametrize("label, mutate, message, line", MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_files_raise_format_error(tmp_path, label, mutate, message, line):
    text = mutate(SIMPLE)
    path = tmp_path / "bad.bvh"
    path.write_bytes(text.encode("utf-8", "surrogateescape"))
    with pytest.raises(FormatError) as err:
        read_bvh(path)
    assert message in str(err.value)
    assert str(path) in str(err.value)
    if line is not None:
        assert err.value.line == line, str(err.value)


@pytest.mark.parametrize("value", ["nan", "inf", "-Infinity", "1e999"])
def test_non_finite_values_name_the_frame(tmp_path, value):
    with pytest.raises(InputError, match="frame 1"):
        read_bvh(write(tmp_path, SIMPLE.replace(" 0 -30\n", f" 0 {value}\n")))


def test_zero_frames_and_missing_file(tmp_path):
    text = SIMPLE.split("Frames:")[0] + "Frames: 0\nFrame Time: 0.0333333\n"
    with pytest.raises(InputError, match="zero frames"):
        read_bvh(write(tmp_path, text))
    with pytest.raises(FormatError, match="no such file"):
        read_bvh(tmp_path / "nope.bvh")


def test_huge_declared_frame_count_is_truncation_not_memory_error(tmp_path):
    with pytest.raises(FormatError, match="truncated"):
        read_bvh(write(tmp_path, SIMPLE.replace("Frames: 2", "Frames: 99999999999999")))


_JUNK = st.sampled_from(list("0123456789 .-+eE{}\n\tXYZabc#:") + ["\x00", "\xff", "nan", "MOTION", "End Site"])


@settings(max_examples=150, deadline=None)
@given(
    kind=st.sampled_from(["truncate", "replace", "insert", "delete_line", "duplicate_line"]),
    where=st.floats(0.0, 1.0),
    junk=_JUNK,
)
def test_corruption_raises_only_graphsvc_errors(kind, where, junk):
    data = SIMPLE.encode()
    lines = data.split(b"\n")
    k = int(where * (len(data) - 1))
    n = int(where * (len(lines) - 1))
    raw = junk.encode("latin-1")
    if kind == "truncate":
        data = data[:k]
    elif kind == "replace":
        data = data[:k] + raw + data[k + 1 :]
    elif kind == "insert":
        data = data[:k] + raw + data[k:]
    elif kind == "delete_line":
        data = b"\n".join(lines[:n] + lines[n + 1 :])
    else:
        data = b"\n".join(lines[: n + 1] + lines[n:])
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "c.bvh"
        path.write_bytes(data)
        try:
            m = read_bvh(path)
        except (FormatError, InputError):
            return
        assert np.all(np.isfinite(m.rotations)) and np.all(np.isfinite(m.translations))


# ---------------------------------------------------------------------------
# Real data (../shared/data)
# ---------------------------------------------------------------------------


def test_bandai_totals_rate_and_speed(data_dir):
    root = data_dir / "bandai"
    if not root.is_dir():
        pytest.skip(f"../shared/data not found: {root} missing")
    totals = {}
    frames = 0
    start = time.perf_counter()
    for ds in ("dataset-1", "dataset-2"):
        files = sorted((root / ds / "data").glob("*.bvh"))
        total = 0
        for f in files:
            m = read_bvh(f)
            assert m.rate_hz == 30.0
            total += m.num_frames
        totals[ds] = total
        frames += total
    elapsed = time.perf_counter() - start
    assert totals == {"dataset-1": 31914, "dataset-2": 44595}
    print(f"bandai: {frames} frames in {elapsed:.2f} s = {frames / elapsed:,.0f} frames/s")


def test_bandai_walk_feet_near_ground_and_units(data_dir):
    path = data_dir / "bandai" / "dataset-2" / "data" / "dataset-2_walk_normal_001.bvh"
    if not path.is_file():
        pytest.skip(f"../shared/data not found: {path} missing")
    m = read_bvh(path)
    sk = m.skeleton
    _, pos = motion_fk(m)
    for foot in ("Toes_L", "Toes_R"):
        y = pos[:, sk.index(foot), 1]
        assert 0.0 < y.min() < 0.08  # toes touch down each step (metres, Y up)
    head = pos[:, sk.index("Head"), 1]
    assert 1.3 < head.mean() < 1.8  # a standing adult, so centimetres were detected
    bones = np.linalg.norm(pos[:, 2:] - pos[:, sk.parents[2:]], axis=-1)
    np.testing.assert_allclose(bones, np.broadcast_to(bones[0], bones.shape), atol=1e-9)


def test_bandai_write_read_round_trip(data_dir, tmp_path):
    path = data_dir / "bandai" / "dataset-1" / "data" / "dataset-1_walk_normal_001.bvh"
    if not path.is_file():
        pytest.skip(f"../shared/data not found: {path} missing")
    m = read_bvh(path)
    write_bvh(tmp_path / "w.bvh", m, scale=100.0)
    back = read_bvh(tmp_path / "w.bvh")
    _, p0 = motion_fk(m)
    _, p1 = motion_fk(back)
    np.testing.assert_allclose(p1, p0, atol=1e-6)
    assert "\n" in bvh_text(m.slice(0, 1), 100.0)

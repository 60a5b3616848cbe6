"""ASF/AMC reading: hand-made files checked against a direct implementation of the
Acclaim transform stack, malformed input, and the CMU data."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from graphsvc.errors import FormatError, InputError
from graphsvc.motion.asfamc import find_asf, read_asf, read_asf_amc
from graphsvc.motion.kinematics import motion_fk

# Non-trivial axes, mixed axis orders and dof subsets/orders, a root order with
# rotations before translations, comments, limits spanning lines.
ASF = """\
# test skeleton
:version 1.10
:name test
:units
  mass 1.0
  length 0.5
  angle deg
:documentation
   anything here
:root
   order RZ TX TY TZ RX RY
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name lhip
     direction 1 -1 0
     length 2
     axis 0 0 45 XYZ
  end
  begin
     id 2
     name lleg
     direction 0 -1 0
     length 8
     axis 10 20 30 ZYX
     dof rz rx
     limits (-160.0 20.0)
            (-70.0 70.0)
  end
  begin
     id 3
     name spine
     direction 0.1 1 0
     length 5
     axis -90 0 20 YXZ
     dof ry rx rz
     limits (-1 1)
            (-1 1)
            (-1 1)
  end
  begin
     id 4
     name arm
     direction 1 0 0
     length 6
     axis 0 0 -20 XYZ
     dof rx
  end
:hierarchy
  begin
    root lhip spine
    lhip lleg
    spine arm
  end
"""

AMC = """\
#!OML:ASF test.asf
:FULLY-SPECIFIED
:DEGREES
1
root 30 1 2 3 10 20
lleg 15 -40
spine 5 6 7
arm 80
2
root -10 1.5 2 3.5 0 -20
lleg 0 90
spine -5 0 3
arm -45
3
root 0 2 2 4 5 5
lleg 30 30
spine 1 2 3
arm 10
"""

INCH = 0.0254


def write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_bytes(text.encode("utf-8", "surrogateescape") if isinstance(text, str) else text)
    return path


@pytest.fixture
def clip(tmp_path) -> tuple[Path, Path]:
    return write(tmp_path, "t.asf", ASF), write(tmp_path, "t_01.amc", AMC)


def fixed(angles_deg, order: str) -> np.ndarray:
    """Rotation matrix about fixed axes, first listed applied first (scipy lower case)."""
    return Rotation.from_euler(order.lower(), angles_deg, degrees=True).as_matrix()


def acclaim_positions(frame: dict[str, list[float]], unit: float) -> dict[str, np.ndarray]:
    """World positions of every bone's start and each leaf's end, straight from the
    Acclaim definition W_b = W_parent·C·M·C⁻¹, end = start + W_b·direction·length."""
    bones = {
        "lhip": dict(parent="root", d=[1, -1, 0], L=2, axis=([0, 0, 45], "XYZ"), dof=()),
        "lleg": dict(parent="lhip", d=[0, -1, 0], L=8, axis=([10, 20, 30], "ZYX"), dof=("z", "x")),
        "spine": dict(parent="root", d=[0.1, 1, 0], L=5, axis=([-90, 0, 20], "YXZ"), dof=("y", "x", "z")),
        "arm": dict(parent="spine", d=[1, 0, 0], L=6, axis=([0, 0, -20], "XYZ"), dof=("x",)),
    }
    rz, tx, ty, tz, rx, ry = frame["root"]
    world = {"root": fixed([rz, rx, ry], "ZXY")}
    start = {"root": np.array([tx, ty, tz]) * unit}
    end = {"root": start["root"]}
    out = {"root": start["root"]}
    for name in ("lhip", "lleg", "spine", "arm"):
        b = bones[name]
        c = fixed(*b["axis"])
        m = fixed(frame[name], "".join(b["dof"]).upper()) if b["dof"] else np.eye(3)
        world[name] = world[b["parent"]] @ c @ m @ c.T
        start[name] = end[b["parent"]]
        d = np.array(b["d"], float) / np.linalg.norm(b["d"])
        end[name] = start[name] + world[name] @ d * b["L"] * unit
        out[name] = start[name]
    out["lleg_End"] = end["lleg"]
    out["arm_End"] = end["arm"]
    return out


def amc_frames(text: str) -> list[dict[str, list[float]]]:
    frames = []
    for line in text.splitlines():
        w = line.split()
        if not w or w[0].startswith(("#", ":")):
            continue
        if w[0].isdigit():
            frames.append({})
        else:
            frames[-1][w[0]] = [float(x) for x in w[1:]]
    return frames


def test_read_asf_structure(clip):
    asf = read_asf(clip[0])
    assert asf.metres_per_unit == pytest.approx(INCH / 0.5)
    assert asf.root_order == ("rz", "tx", "ty", "tz", "rx", "ry")
    assert list(asf.bones) == ["lhip", "lleg", "spine", "arm"]
    assert asf.bones["lleg"].dof == ("rz", "rx") and asf.bones["lleg"].axis_order == "ZYX"
    np.testing.assert_allclose(asf.bones["lleg"].axis, np.radians([10, 20, 30]))
    assert asf.children["root"] == ("lhip", "spine")


def test_amc_matches_acclaim_definition(clip):
    m = read_asf_amc(clip[1])
    sk = m.skeleton
    assert sk.names == ("root", "lhip", "lleg", "lleg_End", "spine", "arm", "arm_End")
    assert list(sk.end_site) == [False, False, False, True, False, False, True]
    assert m.rate_hz == 120.0 and m.num_frames == 3
    _, pos = motion_fk(m)
    unit = INCH / 0.5
    for f, frame in enumerate(amc_frames(AMC)):
        ref = acclaim_positions(frame, unit)
        for name, p in ref.items():
            np.testing.assert_allclose(pos[f, sk.index(name)], p, atol=1e-12, err_msg=f"{name} frame {f}")


def test_bone_lengths_constant_and_channels(clip):
    m = read_asf_amc(clip[1], rate_hz=60.0)
    assert m.rate_hz == 60.0
    _, pos = motion_fk(m)
    sk = m.skeleton
    lengths = np.linalg.norm(pos[:, 1:] - pos[:, sk.parents[1:]], axis=-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(lengths[0], lengths.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(sk.offsets[sk.index("lleg")]), 2 * INCH / 0.5)
    assert sk.channels[sk.index("lhip")] == ()  # no dof: never rotates
    assert sk.channels[0][:3] == ("Xposition", "Yposition", "Zposition")


def test_crlf_and_radians(tmp_path):
    rad_lines = []
    for line in ASF.replace("angle deg", "angle rad").splitlines():
        w = line.split()
        if w and w[0] == "axis" and len(w) == 5:  # bone axis angles to radians
            line = "axis " + " ".join(repr(float(np.radians(float(x)))) for x in w[1:4]) + " " + w[4]
        rad_lines.append(line)
    asf = write(tmp_path, "r.asf", "\r\n".join(rad_lines))
    deg = read_asf_amc(write(tmp_path, "a.amc", AMC), write(tmp_path, "d.asf", ASF))
    rad_text = AMC.replace(":DEGREES", ":RADIANS").replace("\n", "\r\n")
    r = lambda *a: " ".join(repr(float(np.radians(x))) for x in a)  # noqa: E731
    rad_text = (
        rad_text.replace("root 30 1 2 3 10 20", f"root {r(30)} 1 2 3 {r(10, 20)}")
        .replace("lleg 15 -40", f"lleg {r(15, -40)}")
        .replace("spine 5 6 7", f"spine {r(5, 6, 7)}")
        .replace("arm 80", f"arm {r(80)}")
    )
    rad = read_asf_amc(write(tmp_path, "r_01.amc", rad_text), asf)
    i = deg.skeleton.index("lleg")
    np.testing.assert_allclose(np.abs(np.sum(rad.rotations[0, i] * deg.rotations[0, i])), 1.0, atol=1e-12)
    np.testing.assert_allclose(motion_fk(rad)[1][0], motion_fk(deg)[1][0], atol=1e-12)


def test_find_asf(tmp_path):
    a = tmp_path / "a"
    a.mkdir()
    write(a, "01.asf", ASF)
    write(a, "010.asf", ASF)
    amc = write(a, "01_01.amc", AMC)
    assert find_asf(amc).name == "01.asf"
    assert find_asf(write(a, "010_02.amc", AMC)).name == "010.asf"
    with pytest.raises(FormatError, match="no ASF skeleton"):
        find_asf(write(a, "99_01.amc", AMC))
    b = tmp_path / "b"
    b.mkdir()
    write(b, "anything.asf", ASF)
    assert find_asf(write(b, "x.amc", AMC)).name == "anything.asf"


BAD_AMC = [
    ("unknown bone", lambda t: t.replace("arm 80", "wing 80"), "unknown bone 'wing'", 8),
    ("wrong dof count", lambda t: t.replace("lleg 0 90", "lleg 0 90 1"), "bone 'lleg' expected 2 values, found 3", 11),
    ("too few values", lambda t: t.replace("spine 1 2 3", "spine 1 2"), "bone 'spine' expected 3 values, found 2", 17),
    ("truncated frame", lambda t: t.rsplit("arm 10", 1)[0], "frame 3 is truncated: expected bone 'arm'", None),
    ("missing bone", lambda t: t.replace("lleg 0 90\n", ""), "frame 2 is truncated: expected bone 'lleg'", None),
    ("non numeric", lambda t: t.replace("arm -45", "arm x45"), "bone 'arm' expected 1 numbers", 13),
    ("frame numbers", lambda t: t.replace("\n3\n", "\n5\n"), "expected frame number 3, found 5", 14),
    ("duplicate bone", lambda t: t.replace("arm 80", "arm 80\narm 80"), "listed twice", 9),
    ("junk before frames", lambda t: t.replace(":DEGREES\n", ":DEGREES\nhello\n"), "expected a frame number", 4),
    ("binary", lambda t: t.replace("arm 80", "arm \udcff80"), "not UTF-8", 8),
]


@pytest.mark.parametrize("label, mutate, message, line", BAD_AMC, ids=[b[0] for b in BAD_AMC])
def test_malformed_amc(clip, label, mutate, message, line):
    path = write(clip[1].parent, "bad.amc", mutate(AMC))
    with pytest.raises(FormatError) as err:
        read_asf_amc(path, clip[0])
    assert message in str(err.value)
    assert str(path) in str(err.value)
    if line is not None:
        assert err.value.line == line, str(err.value)


BAD_ASF = [
    ("no bonedata", lambda t: t.split(":bonedata")[0] + ":hierarchy\n begin\n end\n", "expected a :bonedata section"),
    ("no hierarchy", lambda t: t.split(":hierarchy")[0], "expected a :hierarchy section"),
    ("unknown bone", lambda t: t.replace("spine arm", "spine wing"), "unknown bone 'wing' in :hierarchy"),
    ("unconnected", lambda t: t.replace("    spine arm\n", ""), "not connected to root"),
    ("bad dof", lambda t: t.replace("dof rx\n", "dof rw\n"), "expected dof tokens"),
    ("bad direction", lambda t: t.replace("direction 1 0 0", "direction 1 0"), "expected 3 numbers for direction"),
    ("bad axis order", lambda t: t.replace("-20 XYZ", "-20 XXZ"), "axis order"),
    ("no end", lambda t: t.replace("     dof rx\n  end\n", "     dof rx\n"), "lacks 'end'"),
    ("no name", lambda t: t.replace("     name arm\n", ""), "lacks 'name'"),
    ("bad units", lambda t: t.replace("angle deg", "angle grad"), "angle deg"),
    ("two parents", lambda t: t.replace("spine arm", "spine arm lleg"), "two parents"),
]


@pytest.mark.parametrize("label, mutate, message", BAD_ASF, ids=[b[0] for b in BAD_ASF])
def test_malformed_asf(tmp_path, label, mutate, message):
    path = write(tmp_path, "bad.asf", mutate(ASF))
    with pytest.raises(FormatError) as err:
        read_asf(path)
    assert message in str(err.value)
    assert err.value.line is not None


def test_zero_frames_nan_and_missing_files(clip):
    folder = clip[0].parent
    with pytest.raises(InputError, match="zero frames"):
        read_asf_amc(write(folder, "e.amc", ":FULLY-SPECIFIED\n:DEGREES\n"), clip[0])
    with pytest.raises(InputError, match="frame 1"):
        read_asf_amc(write(folder, "n.amc", AMC.replace("arm -45", "arm nan")), clip[0])
    with pytest.raises(FormatError, match="no such file"):
        read_asf_amc(folder / "missing.amc", clip[0])
    with pytest.raises(FormatError, match="no such file"):
        read_asf(folder / "missing.asf")


def test_general_parser_accepts_reordered_bones_and_blank_lines(clip):
    text = AMC.replace("lleg 0 90\nspine -5 0 3\n", "\nspine -5 0 3\n\nlleg 0 90\n")
    a = read_asf_amc(write(clip[1].parent, "r.amc", text), clip[0])
    b = read_asf_amc(clip[1])
    np.testing.assert_array_equal(a.rotations, b.rotations)
    np.testing.assert_array_equal(a.translations, b.translations)


_JUNK = st.sampled_from(list("0123456789 .-+e\n\tabcr:#()") + ["\x00", "\xff", "nan", "root", "begin", "end"])


@settings(max_examples=120, deadline=None)
@given(
    target=st.sampled_from(["asf", "amc"]),
    kind=st.sampled_from(["truncate", "replace", "insert", "delete_line", "duplicate_line"]),
    where=st.floats(0.0, 1.0),
    junk=_JUNK,
)
def test_corruption_raises_only_graphsvc_errors(target, kind, where, junk):
    data = (ASF if target == "asf" else AMC).encode()
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
        d = Path(d)
        asf = write(d, "t.asf", data if target == "asf" else ASF)
        amc = write(d, "t_01.amc", data if target == "amc" else AMC)
        try:
            m = read_asf_amc(amc, asf)
        except (FormatError, InputError):
            return
        assert np.all(np.isfinite(m.rotations)) and np.all(np.isfinite(m.translations))


# ---------------------------------------------------------------------------
# CMU data (../shared/data/cmu)
# ---------------------------------------------------------------------------


def _cmu(data_dir: Path) -> Path:
    root = data_dir / "cmu"
    if not root.is_dir():
        pytest.skip(f"../shared/data not found: {root} missing")
    return root


def test_cmu_totals(data_dir):
    root = _cmu(data_dir)
    files = sorted(root.glob("*/*.amc"))
    motions = [read_asf_amc(f) for f in files]
    assert len(files) == 24
    assert sum(m.num_frames for m in motions) == 67672
    assert all(m.rate_hz == 120.0 for m in motions)


def test_cmu_walk_feet_on_ground(data_dir):
    m = read_asf_amc(_cmu(data_dir) / "02" / "02_01.amc")
    sk = m.skeleton
    _, pos = motion_fk(m)
    ankles = pos[:, [sk.index("lfoot"), sk.index("rfoot")], 1]  # joint at the start of lfoot = ankle
    lowest = ankles.min(axis=1)
    # Per second of walking the lower ankle touches down at about the same small height.
    per_second = lowest[: len(lowest) // 120 * 120].reshape(-1, 120).min(axis=1)
    assert np.all((per_second > 0.0) & (per_second < 0.12)), per_second
    assert np.ptp(per_second) < 0.03
    head = pos[:, sk.index("head"), 1]
    assert 1.3 < head.mean() < 1.9  # metres: the unit conversion is right
    travel = np.linalg.norm(pos[-1, 0, [0, 2]] - pos[0, 0, [0, 2]])
    assert travel > 1.5  # it is a walk
    bones = np.linalg.norm(pos[:, 1:] - pos[:, sk.parents[1:]], axis=-1)
    np.testing.assert_allclose(bones, np.broadcast_to(bones[0], bones.shape), atol=1e-9)

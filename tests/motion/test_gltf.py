"""glTF output (`motion.gltf`, `motion.output`): the files pass Khronos's glTF validator
with no errors, and the joints' world positions read back from them — the file parsed
here, its node hierarchy and animation samplers evaluated by forward kinematics of the
test's own (4×4 matrices from glTF's x, y, z, w quaternions) — equal graphsvc's forward
kinematics of the BVH written beside them within 0.1 mm; the skinned capsules follow
their bones."""

from __future__ import annotations

import base64
import json
import os
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest

from graphsvc.cli import main
from graphsvc.errors import InputError
from graphsvc.motion.bvh import read_bvh
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.output import motion_file_bytes, write_motion
from graphsvc.motion.procedural import generate_performance
from tests.conftest import still_motion

# Where the validator is looked for: $GLTF_VALIDATOR (the package's folder), else the
# folder `.ci/run` installs it into (npm install --prefix ~/.cache/graphsvc/node).
VALIDATOR = Path(
    os.environ.get("GLTF_VALIDATOR", Path.home() / ".cache" / "graphsvc" / "node" / "node_modules" / "gltf-validator")
)
_VALIDATE_JS = """
const fs = require('fs'), path = require('path');
const validator = require(process.argv[1]);
(async () => {
  const out = [];
  for (const f of process.argv.slice(2)) {
    const r = await validator.validateBytes(new Uint8Array(fs.readFileSync(f)), {uri: path.basename(f), maxIssues: 50});
    out.push({file: f, errors: r.issues.numErrors, warnings: r.issues.numWarnings,
              messages: r.issues.messages.map(m => m.severity + ' ' + m.code + ' ' + m.message + ' ' + (m.pointer || ''))});
  }
  console.log(JSON.stringify(out));
})().catch((e) => { console.error(String(e)); process.exit(1); });
"""
TOLERANCE_M = 1e-4


def validate(paths) -> list[dict]:
    """Khronos's gltf-validator's verdict on each file (one node process for all)."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed: the glTF validator (npm gltf-validator) cannot run")
    if not (VALIDATOR / "package.json").is_file():
        pytest.skip(
            f"the npm package gltf-validator is not at {VALIDATOR} (`.ci/run` installs it; or set GLTF_VALIDATOR)"
        )
    done = subprocess.run(
        [node, "-e", _VALIDATE_JS, str(VALIDATOR), *map(str, paths)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


# ------------------------------------------------------------------ reading glTF back


def parse(path: Path) -> tuple[dict, bytes]:
    """(the JSON document, the buffer's bytes) of a .glb or a .gltf with an embedded buffer."""
    data = path.read_bytes()
    if path.suffix == ".glb":
        magic, version, length = struct.unpack_from("<4sII", data, 0)
        assert magic == b"glTF" and version == 2 and length == len(data)
        n, kind = struct.unpack_from("<II", data, 12)
        assert kind == 0x4E4F534A and n % 4 == 0
        doc = json.loads(data[20 : 20 + n])
        m, kind = struct.unpack_from("<II", data, 20 + n)
        assert kind == 0x004E4942 and m % 4 == 0 and 28 + n + m == len(data)
        return doc, data[28 + n : 28 + n + m]
    doc = json.loads(data)
    uri = doc["buffers"][0]["uri"]
    head, payload = uri.split(",", 1)
    assert head == "data:application/octet-stream;base64"
    return doc, base64.b64decode(payload)


_COMPONENTS = {5126: "<f4", 5121: "u1", 5123: "<u2", 5125: "<u4"}
_WIDTH = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def accessor(doc: dict, blob: bytes, k: int) -> np.ndarray:
    a = doc["accessors"][k]
    view = doc["bufferViews"][a["bufferView"]]
    dtype = np.dtype(_COMPONENTS[a["componentType"]])
    width = _WIDTH[a["type"]]
    start = view.get("byteOffset", 0) + a.get("byteOffset", 0)
    values = np.frombuffer(blob, dtype, a["count"] * width, start).astype(np.float64)
    return values.reshape(a["count"], width) if width > 1 else values


def sample(times: np.ndarray, values: np.ndarray, t: float, rotation: bool) -> np.ndarray:
    """A LINEAR sampler at time t (glTF 2.0 appendix: lerp, or slerp for rotations)."""
    if t <= times[0]:
        return values[0]
    if t >= times[-1]:
        return values[-1]
    k = int(np.searchsorted(times, t, side="right")) - 1
    u = (t - times[k]) / (times[k + 1] - times[k])
    a, b = values[k], values[k + 1]
    if not rotation:
        return (1 - u) * a + u * b
    d = float(a @ b)
    if d < 0:
        b, d = -b, -d
    if d > 0.9995:
        q = (1 - u) * a + u * b
    else:
        theta = np.arccos(d)
        q = (np.sin((1 - u) * theta) * a + np.sin(u * theta) * b) / np.sin(theta)
    return q / np.linalg.norm(q)


def matrix(translation, rotation) -> np.ndarray:
    """T·R of a glTF node: rotation as x, y, z, w."""
    x, y, z, w = rotation
    m = np.eye(4)
    m[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    m[:3, 3] = translation
    return m


def world_matrices(doc: dict, blob: bytes, t: float) -> dict[int, np.ndarray]:
    """Every node's world matrix at time t of the first animation."""
    trs = {
        k: {
            "translation": np.array(n.get("translation", [0.0, 0, 0])),
            "rotation": np.array(n.get("rotation", [0.0, 0, 0, 1])),
        }
        for k, n in enumerate(doc["nodes"])
    }
    anim = doc["animations"][0]
    for ch in anim["channels"]:
        s = anim["samplers"][ch["sampler"]]
        assert s["interpolation"] == "LINEAR"
        path = ch["target"]["path"]
        trs[ch["target"]["node"]][path] = sample(
            accessor(doc, blob, s["input"]), accessor(doc, blob, s["output"]), t, path == "rotation"
        )
    world = {}

    def visit(k, parent):
        world[k] = parent @ matrix(trs[k]["translation"], trs[k]["rotation"])
        for c in doc["nodes"][k].get("children", []):
            visit(c, world[k])

    for k in doc["scenes"][doc.get("scene", 0)]["nodes"]:
        visit(k, np.eye(4))
    return world


def gltf_positions(path: Path, rate_hz: float, frames: int) -> tuple[list[str], np.ndarray]:
    """(joint names, (F, J, 3) world positions) at frame times k / rate_hz of the nodes
    that hold no mesh (the skin's joints, where there is a mesh)."""
    doc, blob = parse(path)
    joints = [k for k, n in enumerate(doc["nodes"]) if "mesh" not in n]
    assert "skins" not in doc or doc["skins"][0]["joints"] == joints
    out = np.empty((frames, len(joints), 3))
    for f in range(frames):
        world = world_matrices(doc, blob, f / rate_hz)
        out[f] = [world[j][:3, 3] for j in joints]
    return [doc["nodes"][j]["name"] for j in joints], out


# ------------------------------------------------------------------ the tests


@pytest.fixture(scope="module")
def clip():
    """2 s of a procedural performance: root translation, every joint turning, end sites."""
    return generate_performance(seed=1)[0].slice(60, 120)


def _moved_far(motion):
    """`motion` 40 m away, every joint turned at random each frame."""
    m = motion.copy()
    m.translations[:, 0] += (40.0, 0.0, -25.0)
    rng = np.random.default_rng(0)
    q = rng.normal(size=m.rotations.shape)
    m.rotations = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return m


def _check_same_positions(tmp_path: Path, motion, stem: str) -> None:
    bvh = tmp_path / f"{stem}.bvh"
    write_motion(bvh, motion)
    back = read_bvh(bvh)
    _, want = motion_fk(back)
    for suffix in (".glb", ".gltf"):
        path = tmp_path / f"{stem}{suffix}"
        write_motion(path, motion)
        names, got = gltf_positions(path, motion.rate_hz, motion.num_frames)
        assert tuple(names) == back.skeleton.names
        err = np.abs(got - want).max()
        assert err < TOLERANCE_M, (suffix, err)


def test_world_positions_equal_the_bvh_s_and_files_validate(tmp_path, clip):
    far = _moved_far(clip.slice(0, 12))
    still = still_motion(1)
    _check_same_positions(tmp_path, clip, "walk")
    _check_same_positions(tmp_path, far, "far")
    _check_same_positions(tmp_path, still, "still")
    reports = validate(sorted(tmp_path.glob("*.gl*")))
    assert len(reports) == 6
    for r in reports:
        assert r["errors"] == 0 and r["warnings"] == 0, r


def test_a_wrong_rate_or_joint_would_be_caught(tmp_path, clip):
    """The comparison can fail: the glTF read at another rate, or with a joint's rotation
    replaced, is off by far more than the tolerance."""
    path = tmp_path / "walk.glb"
    write_motion(path, clip)
    _, want = motion_fk(clip)
    _, slow = gltf_positions(path, clip.rate_hz * 1.25, clip.num_frames)
    assert np.abs(slow - want).max() > 100 * TOLERANCE_M
    bent = clip.copy()
    bent.rotations[:, bent.skeleton.index("l_knee")] = (np.cos(0.2), np.sin(0.2), 0.0, 0.0)
    write_motion(path, bent)
    _, got = gltf_positions(path, clip.rate_hz, clip.num_frames)
    assert np.abs(got - want).max() > 100 * TOLERANCE_M


def test_the_capsules_follow_their_bones(tmp_path, clip):
    path = tmp_path / "walk.glb"
    write_motion(path, clip)
    check_capsules(path, clip)


def check_capsules(path: Path, clip) -> None:
    """Every vertex, skinned (joint world matrix × inverse bind matrix), lies within the
    largest radius of a bone from its joint to one of the joint's children, in every
    frame looked at; and each triangle faces the way its vertices' normals do."""
    from graphsvc.motion.gltf import MAX_RADIUS_M

    doc, blob = parse(path)
    prim = doc["meshes"][0]["primitives"][0]
    pos = accessor(doc, blob, prim["attributes"]["POSITION"])
    normal = accessor(doc, blob, prim["attributes"]["NORMAL"])
    joint = accessor(doc, blob, prim["attributes"]["JOINTS_0"])[:, 0].astype(int)
    weights = accessor(doc, blob, prim["attributes"]["WEIGHTS_0"])
    assert np.allclose(weights, [1, 0, 0, 0])
    tri = accessor(doc, blob, prim["indices"]).astype(int).reshape(-1, 3)
    face = np.cross(pos[tri[:, 1]] - pos[tri[:, 0]], pos[tri[:, 2]] - pos[tri[:, 0]])
    assert ((face * normal[tri].sum(axis=1)).sum(axis=1) > 0).all()
    skin = doc["skins"][0]
    ibm = accessor(doc, blob, skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
    children = {j: n.get("children", []) for j, n in enumerate(doc["nodes"])}
    for f in (0, clip.num_frames // 2, clip.num_frames - 1):
        world = world_matrices(doc, blob, f / clip.rate_hz)
        at = np.array([world[skin["joints"][j]] for j in range(len(skin["joints"]))])
        skinned = np.einsum("vab,vb->va", at[joint] @ ibm[joint], np.c_[pos, np.ones(len(pos))])[:, :3]
        for v in range(0, len(pos), 7):
            a = at[joint[v]][:3, 3]
            dist = []
            for c in children[skin["joints"][joint[v]]]:
                b = world[c][:3, 3]
                s = np.clip((skinned[v] - a) @ (b - a) / max((b - a) @ (b - a), 1e-12), 0, 1)
                dist.append(np.linalg.norm(skinned[v] - (a + s * (b - a))))
            assert min(dist) <= MAX_RADIUS_M + 1e-4, (f, v, min(dist))


def test_joints_whose_translations_change_are_animated(tmp_path, clip):
    """A skeleton whose joints carry changing translations (position channels on every
    joint): the glTF's positions equal graphsvc's forward kinematics of the motion."""
    m = clip.copy()
    m.translations[:, 1:] *= 1.0 + 0.2 * np.sin(np.arange(m.num_frames) / 5.0)[:, None, None]
    path = tmp_path / "stretch.glb"
    write_motion(path, m)
    _, got = gltf_positions(path, m.rate_hz, m.num_frames)
    assert np.abs(got - motion_fk(m)[1]).max() < TOLERANCE_M
    doc, _ = parse(path)
    moved = {c["target"]["node"] for c in doc["animations"][0]["channels"] if c["target"]["path"] == "translation"}
    assert moved == set(range(m.skeleton.num_joints))
    assert "meshes" not in doc and "skins" not in doc  # (no rigid bone: no capsule)
    assert all(r["errors"] == 0 and r["warnings"] == 0 for r in validate([path]))


def test_same_motion_same_bytes_and_the_layout(tmp_path, clip):
    data = motion_file_bytes(tmp_path / "a.glb", clip)
    assert data == motion_file_bytes(tmp_path / "b.glb", clip.copy())
    (tmp_path / "a.glb").write_bytes(data)
    doc, _ = parse(tmp_path / "a.glb")
    assert doc["asset"]["version"] == "2.0"
    assert doc["scenes"][0]["extras"] == {"rate_hz": clip.rate_hz, "frames": clip.num_frames}
    channels = doc["animations"][0]["channels"]
    turned = {c["target"]["node"] for c in channels if c["target"]["path"] == "rotation"}
    moved = {c["target"]["node"] for c in channels if c["target"]["path"] == "translation"}
    sk = clip.skeleton
    assert turned == {j for j in range(sk.num_joints) if not sk.end_site[j]} and moved == {0}


def test_a_motion_glTF_cannot_hold_is_refused_and_nothing_written(tmp_path, clip):
    empty = clip.slice(0, 0)
    out = tmp_path / "x.glb"
    with pytest.raises(InputError, match="no frames"):
        write_motion(out, empty)
    bad = clip.copy()
    bad.translations[5, 0, 1] = np.nan
    with pytest.raises(InputError, match="non-finite translations at frame 5"):
        write_motion(out, bad)
    assert not out.exists()
    with pytest.raises(InputError, match="not .obj"):
        write_motion(tmp_path / "x.obj", clip)


def test_read_back_the_same_motion(tmp_path, clip):
    """`read_gltf` (what `graphsvc report` reads): the skeleton, rate and every joint's
    world position of the motion written, the end sites where they were."""
    from graphsvc.motion.gltf_read import read_gltf

    far = _moved_far(clip)
    for name, motion in (("a.glb", far), ("a.gltf", clip), ("one.glb", still_motion(1, rate_hz=24.0))):
        write_motion(tmp_path / name, motion)
        back = read_gltf(tmp_path / name)
        sk = motion.skeleton
        assert back.skeleton.names == sk.names and (back.skeleton.parents == sk.parents).all()
        assert (back.skeleton.end_site == sk.end_site).all() and back.rate_hz == motion.rate_hz
        assert back.num_frames == motion.num_frames
        assert np.abs(motion_fk(back)[1] - motion_fk(motion)[1]).max() < TOLERANCE_M


@pytest.mark.parametrize(
    "case, needle",
    [
        ("not glTF", "not glTF JSON"),
        ("truncated", "GLB version 2, length"),
        ("external buffer", "external file"),
        ("accessor past its view", "runs past its buffer view"),
        ("nan", "non-finite"),
        ("no animation", "no animation"),
        ("uneven keyframes", "not at a uniform rate"),
        ("bad index", "is not an index"),
    ],
)
def test_a_malformed_glTF_is_one_line_naming_the_file(tmp_path, clip, case, needle):
    from graphsvc.errors import FormatError
    from graphsvc.motion.gltf_read import read_gltf

    path = tmp_path / "x.gltf"
    write_motion(path, clip.slice(0, 4))
    doc = json.loads(path.read_text())
    if case == "not glTF":
        path.write_text("{")
    elif case == "truncated":
        write_motion(tmp_path / "x.glb", clip.slice(0, 4))
        path = tmp_path / "x.glb"
        path.write_bytes(path.read_bytes()[:-8])
    else:
        if case == "external buffer":
            doc["buffers"][0]["uri"] = "x.bin"
        elif case == "accessor past its view":
            doc["accessors"][-1]["count"] *= 50
        elif case == "nan":
            blob = bytearray(base64.b64decode(doc["buffers"][0]["uri"].split(",", 1)[1]))
            a = doc["accessors"][doc["animations"][0]["samplers"][0]["output"]]
            o = doc["bufferViews"][a["bufferView"]]["byteOffset"]
            blob[o : o + 4] = struct.pack("<f", np.nan)
            doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(bytes(blob)).decode()
        elif case == "no animation":
            del doc["animations"]
        elif case == "uneven keyframes":
            blob = bytearray(base64.b64decode(doc["buffers"][0]["uri"].split(",", 1)[1]))
            a = doc["accessors"][doc["animations"][0]["samplers"][0]["input"]]
            o = doc["bufferViews"][a["bufferView"]]["byteOffset"] + 4
            blob[o : o + 4] = struct.pack("<f", 0.01)
            doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(bytes(blob)).decode()
        elif case == "bad index":
            doc["animations"][0]["samplers"][0]["input"] = -1
        path.write_text(json.dumps(doc))
    with pytest.raises(FormatError) as err:
        read_gltf(path)
    assert str(err.value).startswith(str(path)) and needle in str(err.value) and "\n" not in str(err.value)


def test_real_bandai_clip(tmp_path, data_dir):
    """A Bandai BVH (its own skeleton, end sites, centimetres) through both writers."""
    path = sorted((data_dir / "bandai" / "dataset-2" / "data").glob("*walk*_001.bvh"))[0]
    motion = read_bvh(path).slice(0, 40)
    _check_same_positions(tmp_path, motion, "bandai")
    check_capsules(tmp_path / "bandai.glb", motion)  # (its hips move under the root: no capsule between them)
    reports = validate(sorted(tmp_path.glob("*.gl*")))
    assert all(r["errors"] == 0 and r["warnings"] == 0 for r in reports), reports


def test_commands_that_write_no_motion_refuse_glTF_in_one_line(tmp_path, capsys):
    from tests.conftest import write_gliding_clip

    clip = write_gliding_clip(tmp_path)
    for argv in (
        ["simulate", clip, "--markers", "hands-feet", "-o", tmp_path / "m.glb"],
        ["simulate", clip, "--layout", "kelly6", "-o", tmp_path / "m.gltf"],
        ["mapping", clip, "-o", tmp_path / "map.glb"],
        ["build", clip, "-o", tmp_path / "g.glb"],
    ):
        assert main([str(a) for a in argv]) == 2
        err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
        assert len(err) == 1 and err[0].startswith("graphsvc: error:") and ".gl" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk_demo_001.bvh"]

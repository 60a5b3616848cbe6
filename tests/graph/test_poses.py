"""The graph's packed node poses (`graph.poses`): what goes in comes back — the
translations exactly, the rotations to the packing's bound — in built graphs, in files
of every format version, and nothing out of range reaches the readers."""

import numpy as np
import pytest

from graphsvc.errors import FormatError
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.file import ARRAYS, FORMAT_VERSION, KIND, load_graph, save_graph
from graphsvc.graph.model import NODE_ORIGINAL
from graphsvc.graph.poses import (
    PosePacker,
    moving_joints,
    node_poses,
    node_rotations,
    node_translations,
    pack_rotations,
    rotating_joints,
    unpack_rotations,
)
from graphsvc.motion import quat
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.sensors.layout import PRESETS
from graphsvc.store import read_container, write_container
from tests.graph.test_records import as_format_3

# A kept component is stored as 2^19 + round(c·√2·(2^19 − 1)): off by at most half a
# step, (1/√2)/(2^19 − 1)/2 = 6.74e-7; the rotation between q and its copy is then
# 2·asin of the error's norm (the dropped component adds its own), under 4 of those.
COMPONENT = 0.7071067811865476 / (2**19 - 1) / 2
ANGLE = 2 * np.arcsin(4 * COMPONENT)


def _angle(a, b):
    return 2 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=-1)), 0.0, 1.0))


def test_rotations_round_trip_within_the_packing_bound_and_keep_their_sign():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(50_000, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    back = unpack_rotations(pack_rotations(q))
    assert np.abs(np.linalg.norm(back, axis=1) - 1).max() < 1e-12
    assert _angle(q, back).max() < ANGLE
    assert np.abs(back - q).max() < 4 * COMPONENT  # the same hemisphere, component by component
    # The identity, the axes, both signs and the components' bound are exact.
    h = np.sqrt(0.5)
    exact = np.array([[1, 0, 0, 0], [-1, 0, 0, 0], [0, 0, 0, -1], [0, 1, 0, 0], [h, h, 0, 0], [h, 0, -h, 0]], float)
    np.testing.assert_allclose(unpack_rotations(pack_rotations(exact)), exact, atol=1e-15)
    # Any leading shape; an unnormalised quaternion is normalised first.
    assert unpack_rotations(pack_rotations(2 * q[:12].reshape(3, 4, 4))).shape == (3, 4, 4)
    np.testing.assert_allclose(unpack_rotations(pack_rotations(2 * q[:12])), q[:12], atol=4 * COMPONENT)


def test_packer_keeps_translations_and_counts_bone_sets():
    rng = np.random.default_rng(2)
    M, J = 40, 5
    bones = rng.normal(size=(J, 3))
    t = np.repeat(bones[None], M, axis=0)
    t[:, 0] = rng.normal(size=(M, 3))  # the root moves
    t[:, 2] = rng.normal(size=(M, 3))  # and one joint below it
    t[::2, 1] += 1e-14  # an export's float noise on a constant channel: not moving
    q = rng.normal(size=(M, J, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q[:, 4] = [1, 0, 0, 0]  # an end site
    other = t.copy()
    other[:, 3] += 0.01  # a clip of another performer: other bone lengths
    moving, rotating = moving_joints([t, other]), rotating_joints([q])
    q[1::3, 4, 2] = 1e-16  # (a retargeted clip's end site: rounding, not a rotation)
    assert moving.tolist() == [0, 2] and rotating.tolist() == [0, 1, 2, 3]
    packer = PosePacker(rotating, moving, J)
    packer.add(q, t)
    packer.add(q[:7], other[:7])
    packer.add(q[:0], t[:0])  # (a part without nodes)
    packer.add(q[7:9], t[7:9])
    a = packer.arrays()
    assert a["bone_sets"].shape == (2, J, 3) and a["node_bones"].tolist() == [0] * M + [1] * 7 + [0] * 2
    assert a["node_rot64"].shape == (M + 9, 4) and a["node_moving"].shape == (M + 9, 2, 3)

    class G:  # the arrays as a graph holds them
        pass

    g = G()
    g.__dict__.update(a)
    rot, trans = node_poses(g, np.arange(M + 9))
    want = np.concatenate([t, other[:7], t[7:9]]).astype(np.float64)
    assert np.array_equal(trans[:, moving], want[:, moving].astype(np.float32))  # the moving joints in float32
    assert np.abs(trans - want).max() <= 2e-7  # the others on the bone grid (and the noise gone)
    assert np.array_equal(trans[0, 1], trans[1, 1])
    assert _angle(rot, np.concatenate([q, q[:7], q[7:9]])).max() < ANGLE
    assert np.array_equal(rot[:, 4], np.tile([1.0, 0, 0, 0], (M + 9, 1)))
    # One node, a slice: the shapes numpy indexing gives.
    assert node_rotations(g, 3).shape == (J, 4) and node_translations(g, slice(2, 5)).shape == (3, J, 3)
    # A made node that turns a joint no clip turns: the build is wrong, not silently lossy.
    turned = q[:1].copy()
    turned[0, 4] = quat.about_y(0.1)
    with pytest.raises(ValueError, match="without rotation"):
        packer.add(turned, t[:1])


@pytest.fixture(scope="module")
def built():
    kb = generate_knowledge_base(seed=5, minutes=0.5)
    graph, _ = build_graph(kb, BuildOptions(layout=PRESETS["wrists-ankles"], progress=False))
    return kb, graph


def test_a_built_graph_gives_back_its_clips_frames(built):
    kb, g = built
    for c, motion in enumerate(kb[:3]):
        nodes = np.flatnonzero((g.node_kind == NODE_ORIGINAL) & (g.node_clip == c))
        rot, trans = node_poses(g, nodes)
        assert np.array_equal(trans[:, g.moving_joints], motion.translations[:, g.moving_joints].astype(np.float32))
        assert np.abs(trans - motion.translations).max() < 1e-6
        assert _angle(rot, motion.rotations).max() < ANGLE
    # Every stored bone set is used, and the moving joints are few.
    assert np.array_equal(np.unique(g.node_bones), np.arange(len(g.bone_sets)))
    assert len(g.moving_joints) <= 2 and len(g.rotating_joints) < g.skeleton.num_joints


def _as_version_2(g, path):
    """The file graphsvc wrote before packed poses: float32 rotations and translations."""
    as_format_3(g, path)
    meta, arrays, _ = read_container(path, kind=KIND, mmap=False)
    old = {k: v for k, v in arrays.items() if k not in ("node_rot64", "node_moving", "node_bones", "bone_sets")}
    old.pop("moving_joints"), old.pop("rotating_joints")
    rot, trans = node_poses(g, slice(None))
    old["node_rotations"], old["node_translations"] = rot.astype(np.float32), trans.astype(np.float32)
    write_container(path, KIND, meta, old, 2)
    return rot, trans


def test_a_version_2_file_loads_packed_and_writes_as_the_current_version(built, tmp_path):
    _, g = built
    rot, trans = _as_version_2(g, tmp_path / "old.graph")
    old = load_graph(tmp_path / "old.graph")
    r2, t2 = node_poses(old, slice(None))
    assert np.abs(t2 - trans).max() < 1e-7
    assert _angle(r2, rot).max() < ANGLE + 1e-7  # (and float32's rounding on the way)
    save_graph(old, tmp_path / "new.graph")
    assert read_container(tmp_path / "new.graph")[2] == FORMAT_VERSION and set(ARRAYS) <= set(
        read_container(tmp_path / "new.graph")[1]
    )


@pytest.mark.parametrize(
    "name, value, says",
    [
        ("node_bones", lambda a: np.where(np.arange(len(a)) == 3, 99, a).astype(np.int32), "bone sets"),
        ("moving_joints", lambda a: np.array([1], np.int32), "moving_joints"),
        ("rotating_joints", lambda a: a[::-1].copy(), "rotating_joints"),
        ("node_rot64", lambda a: a.astype(np.int64), "uint64"),
    ],
)
def test_altered_pose_arrays_are_refused(built, tmp_path, name, value, says):
    _, g = built
    path = tmp_path / "g.graph"
    save_graph(g, path)
    meta, arrays, version = read_container(path, kind=KIND, mmap=False)
    arrays = dict(arrays)
    arrays[name] = value(arrays[name])
    if name == "moving_joints":  # (its shape must agree: one moving joint a node)
        arrays["node_moving"] = np.ascontiguousarray(arrays["node_moving"][:, :1])
    write_container(path, KIND, meta, arrays, version)
    with pytest.raises(FormatError, match=says):
        load_graph(path)


def test_drain_concatenates_and_frees_the_parts():
    from graphsvc.graph.rows import drain

    parts = [np.arange(6).reshape(3, 2), np.zeros((0, 2), int), np.arange(4).reshape(2, 2) + 10]
    want = np.concatenate(parts)
    got = drain(parts, (0, 2), int)
    np.testing.assert_array_equal(got, want)
    assert parts == []
    assert drain([], (0, 3), np.float32).shape == (0, 3)


def test_ranges_join_runs_of_consecutive_ids():
    from graphsvc.graph.rows import ranges

    starts, counts = [7, 0, 3, 9], [3, 0, 2, 1]
    assert ranges(starts, counts).tolist() == [7, 8, 9, 3, 4, 9]  # (by hand)
    assert ranges([], []).tolist() == []

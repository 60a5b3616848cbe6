"""Builder and graph file on the procedural knowledge base."""

import numpy as np
import pytest

from graphsvc.errors import FormatError, InputError, SkeletonError
from graphsvc.graph import metadata as meta
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.file import load_graph, save_graph
from graphsvc.graph.model import (
    EDGE_INTERP,
    EDGE_ORIGINAL,
    EDGE_SLOW,
    EDGE_SPEEDUP,
    EDGE_TRANSITION,
    NODE_INTERP,
    NODE_ORIGINAL,
    NODE_SLOW,
    READING_DTYPE,
    summary,
)
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.sensors.layout import PRESETS
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.sensors.simulate import simulate_recording


@pytest.fixture(scope="module")
def kb():
    return generate_knowledge_base(seed=3, minutes=1.2)


@pytest.fixture(scope="module")
def built(kb):
    return build_graph(kb, BuildOptions(layout=PRESETS["kelly6"], progress=False))


def test_counts_and_csr(built):
    g, report = built
    s = summary(g)
    assert s["nodes_by_kind"]["original"] == sum(c["frames"] for c in g.clips)
    assert s["edges_by_kind"]["transition"] > 0 and s["edges_by_kind"]["speed-up"] > 0
    assert np.all(np.diff(g.edge_dst) >= 0)  # sorted by destination
    for n in (0, g.num_nodes // 2, g.num_nodes - 1):
        run = slice(g.incoming[n], g.incoming[n + 1])
        assert np.all(g.edge_dst[run] == n)
    assert len(np.unique(g.edge_src.astype(np.int64) * g.num_nodes + g.edge_dst)) == g.num_edges


def test_transitions_join_equal_contact_states_at_contact_changes(built, kb):
    g, _ = built
    t = g.edge_kind == EDGE_TRANSITION
    src, dst = g.edge_src[t], g.edge_dst[t]
    assert np.all(g.node_kind[src] == NODE_ORIGINAL) and np.all(g.node_kind[dst] == NODE_ORIGINAL)
    j = dst - 1  # the edge i → j+1 continues after frame j, which matched i
    assert np.all(g.node_clip[j] == g.node_clip[dst])
    np.testing.assert_array_equal(g.node_contacts[src], g.node_contacts[j])
    # A contact change (against the previous frame of the same clip) at both ends.
    for node in (src, j):
        prev_same_clip = (node > 0) & (g.node_clip[node - 1] == g.node_clip[node])
        changed = np.any(g.node_contacts[node] != g.node_contacts[node - 1], axis=1) & prev_same_clip
        still = np.array([g.clips[c]["name"] for c in g.node_clip[node]])
        still_clip = np.isin(still, [n for n in (c["name"] for c in g.clips) if n.startswith("idle")])
        assert np.all(changed | still_clip)


def test_no_speed_variation_in_flight(built):
    g, _ = built
    airborne = ~g.node_contacts.any(axis=1)
    assert not np.any(airborne[g.node_kind == NODE_SLOW])
    for kind in (EDGE_SLOW, EDGE_SPEEDUP):
        e = g.edge_kind == kind
        assert not np.any(airborne[g.edge_src[e]]) and not np.any(airborne[g.edge_dst[e]])
    # Speed-up edges also skip only grounded frames.
    e = g.edge_kind == EDGE_SPEEDUP
    assert not np.any(airborne[g.edge_src[e] + 1])
    # Running clips do have flight frames, so the rule was exercised.
    assert airborne.any()


def test_original_edges_reproduce_the_clip_stream_and_root_path(built, kb):
    g, _ = built
    for c in (0, len(kb) // 2, len(kb) - 1):
        clip = kb[c]
        first, F = g.clips[c]["first_node"], g.clips[c]["frames"]
        rec = simulate_recording(clip, PRESETS["kelly6"], NOISE["none"])
        e = (g.edge_kind == EDGE_ORIGINAL) & (g.edge_src >= first) & (g.edge_src < first + F - 1)
        order = np.argsort(g.edge_src[e])
        acc = g.edge_acc[e][order]
        assert acc.shape[0] == F - 1
        assert acc.dtype == READING_DTYPE
        np.testing.assert_array_equal(acc, rec.accelerations[1:].astype(READING_DTYPE))  # exact to its bits
        ground, heading = meta.integrate_path(
            rec.ground_position[0],
            rec.heading[0],
            g.edge_offset[e][order].astype(float),
            g.edge_heading[e][order].astype(float),
        )
        assert np.max(np.linalg.norm(ground - rec.ground_position, axis=-1)) < 1e-3
        assert np.max(np.abs(np.angle(np.exp(1j * (heading - rec.heading))))) < 1e-4


def test_slow_down_path_plays_at_half_speed(built, kb):
    g, _ = built
    # Walk o_f → s_f → o_{f+1} through a slow-down node: two edges, one frame of travel.
    s = np.nonzero(g.node_kind == NODE_SLOW)[0][10]
    into = np.nonzero((g.edge_dst == s) & (g.edge_kind == EDGE_SLOW))[0][0]
    out = np.nonzero((g.edge_src == s) & (g.edge_kind == EDGE_SLOW))[0][0]
    f = g.edge_src[into]
    direct = np.nonzero((g.edge_src == f) & (g.edge_dst == g.edge_dst[out]))[0][0]
    g0, h0 = np.zeros(2), 0.0
    a, ha = meta.apply_offsets(g0, h0, g.edge_offset[into], g.edge_heading[into])
    b, hb = meta.apply_offsets(a, ha, g.edge_offset[out], g.edge_heading[out])
    c, hc = meta.apply_offsets(g0, h0, g.edge_offset[direct], g.edge_heading[direct])
    assert np.linalg.norm(b - c) < 1e-5 and abs(hb - hc) < 1e-5
    assert g.node_frame[s] == g.node_frame[f] + 0.5


def test_build_is_deterministic_byte_for_byte(kb, built, tmp_path):
    g, _ = built
    save_graph(g, tmp_path / "a.graph")
    again, _ = build_graph(kb, BuildOptions(layout=PRESETS["kelly6"], progress=False, jobs=2))
    save_graph(again, tmp_path / "b.graph")
    assert (tmp_path / "a.graph").read_bytes() == (tmp_path / "b.graph").read_bytes()


def test_file_round_trip_memory_mapped(built, tmp_path):
    g, _ = built
    path = tmp_path / "g.graph"
    save_graph(g, path)
    back = load_graph(path)
    assert back.num_nodes == g.num_nodes and back.params == g.params and back.labels == g.labels
    np.testing.assert_array_equal(back.edge_acc, g.edge_acc)
    assert not back.edge_acc.flags.writeable  # a view of the mapped file, not a copy


def test_corrupted_and_truncated_files_refused(built, tmp_path):
    g, _ = built
    path = tmp_path / "g.graph"
    save_graph(g, path)
    data = bytearray(path.read_bytes())
    for where in (100, len(data) // 2, len(data) - 60):
        bad = bytearray(data)
        bad[where] ^= 0x5A
        (tmp_path / "bad.graph").write_bytes(bad)
        with pytest.raises(FormatError):
            load_graph(tmp_path / "bad.graph")
    for size in (0, 10, len(data) // 3, len(data) - 1):
        (tmp_path / "cut.graph").write_bytes(data[:size])
        with pytest.raises(FormatError):
            load_graph(tmp_path / "cut.graph")


def test_no_msv_option_and_rate(kb):
    g, _ = build_graph(kb[:4], BuildOptions(msv=False, rate_hz=15.0, progress=False))
    assert not np.any(g.node_kind == NODE_SLOW) and not np.any(g.edge_kind == EDGE_SPEEDUP)
    assert g.rate_hz == 15.0 and g.clips[0]["frames"] < kb[0].num_frames


def test_bad_knowledge_bases(kb):
    with pytest.raises(InputError, match="empty"):
        build_graph([], BuildOptions(progress=False))
    short = kb[0].slice(0, 4)
    short.name = "tiny"
    with pytest.raises(InputError, match="shorter than the distance window"):
        build_graph([kb[1], short], BuildOptions(progress=False))
    still = kb[0].copy()
    still.rotations[:] = still.rotations[:1]
    still.translations[:] = still.translations[:1]
    with pytest.raises(InputError, match="no clip"):
        build_graph([still], BuildOptions(progress=False, still_clip_step_s=1e9))
    from graphsvc.motion.skeleton import Skeleton

    sk = kb[0].skeleton
    renamed = (sk.names[0], "renamed") + sk.names[2:]
    other = kb[1].copy(skeleton=Skeleton(renamed, sk.parents, sk.offsets, sk.channels, sk.end_site))
    with pytest.raises(SkeletonError, match="mix"):
        build_graph([kb[0], other], BuildOptions(progress=False))


def test_interpolated_segments_are_long_enough_and_slope_bounded(built):
    g, _ = built
    assert g.segments, "the procedural KB has similar clips of one label: expect blends"
    rate = g.rate_hz
    for seg in g.segments:
        a_span = seg["a_end"] - seg["a_start"]
        b_span = seg["b_end"] - seg["b_start"]
        assert a_span / rate >= 0.5 - 1e-9 and b_span / rate >= 0.5 - 1e-9
        assert 0.5 <= b_span / a_span <= 2.0
        nodes = np.arange(seg["first_node"], seg["first_node"] + seg["count"])
        assert np.all(g.node_kind[nodes] == NODE_INTERP)
        # Chained one after the other, and entered/left through the source clips.
        chain = (g.edge_kind == EDGE_INTERP) & np.isin(g.edge_src, nodes[:-1])
        assert chain.sum() == len(nodes) - 1
        frames = g.node_frame[nodes]
        assert frames[0] == seg["a_start"] and np.all(np.diff(frames) > 0)
        assert g.clips[seg["clip_a"]]["labels"][0] == g.clips[seg["clip_b"]]["labels"][0]


def test_interpolation_can_be_switched_off(kb):
    g, _ = build_graph(kb[:6], BuildOptions(interp=False, progress=False))
    assert not g.segments and not np.any(g.node_kind == NODE_INTERP)


def test_metadata_recomputed_for_another_layout_without_the_kb(built, kb):
    g, _ = built
    again = meta.recompute_accelerations(g, PRESETS["kelly6"])
    assert again.shape == g.edge_acc.shape
    # Stored poses are packed (rotations to ~4e-6 rad, `graph.poses`), the build used
    # float64; a reading is a second difference at 30 Hz: 0.08 m/s² is 0.008 g. The
    # stored readings are float16: off by up to 4.9e-4 of a value (0.03 m/s² at 100).
    np.testing.assert_allclose(again, g.edge_acc.astype(np.float64), atol=0.08, rtol=2.5e-4)
    assert np.median(np.abs(again - g.edge_acc)) < 1e-3
    other = meta.recompute_accelerations(g, PRESETS["right-wrist"])
    rebuilt, _ = build_graph(kb, BuildOptions(layout=PRESETS["right-wrist"], progress=False))
    np.testing.assert_allclose(other, rebuilt.edge_acc.astype(np.float64), atol=0.08, rtol=2.5e-4)


def test_augmented_copies_are_never_blended_with_their_original(kb):
    from graphsvc.motion.augment import mirror_motion

    clips = [c.copy(source=f"/kb/{c.name}.bvh") for c in kb[:4]]
    clips += [mirror_motion(c) for c in clips]
    g, _ = build_graph(clips, BuildOptions(progress=False, msv=False))
    for seg in g.segments:
        assert g.clips[seg["clip_a"]]["source"] != g.clips[seg["clip_b"]]["source"]
    assert any(c["name"].endswith("_mirror") for c in g.clips)


def test_per_frame_labels_label_each_node_by_its_frame():
    # A procedural stop clip walks, then stops and stands: its nodes carry those phases'
    # labels, its copies the mirrored and reversed ones, other clips their own label.
    from graphsvc.graph.model import NODE_ORIGINAL
    from graphsvc.motion.augment import mirror_motion, reverse_motion

    phases: dict = {}
    kb = generate_knowledge_base(seed=3, minutes=0.8, frame_labels=phases)
    stop = next(m for m in kb if m.labels[0] == "stop")
    assert {"walk", "stop"} <= set(phases[stop.name]) or {"run", "stop"} <= set(phases[stop.name])
    del phases[kb[0].name]  # (a clip without per-frame labels keeps its clip's)
    motions = kb + [mirror_motion(stop), reverse_motion(stop)]
    g, _ = build_graph(motions, BuildOptions(layout=PRESETS["wrists-ankles"], progress=False), phases)
    names = [c["name"] for c in g.clips]
    labels = np.asarray(g.labels)

    def original(name):
        k = names.index(name)
        return labels[g.node_label[g.clips[k]["first_node"] + np.arange(g.clips[k]["frames"])]]

    np.testing.assert_array_equal(original(stop.name), phases[stop.name])
    np.testing.assert_array_equal(original(stop.name + "_reverse"), phases[stop.name][::-1])
    assert set(original(stop.name + "_mirror")) == set(phases[stop.name])  # (no left/right in these labels)
    assert set(original(kb[0].name)) == {kb[0].labels[0]}
    # Every other node (slow-downs, interpolations, bridges) takes its source frame's.
    slow = (g.node_kind != NODE_ORIGINAL) & (np.asarray(g.node_clip) == names.index(stop.name))
    frames = np.floor(g.node_frame[slow]).astype(int)
    np.testing.assert_array_equal(labels[g.node_label[slow]], phases[stop.name][frames])
    # Without per-frame labels the graph is the one the clip labels give, byte for byte.
    plain, _ = build_graph(kb, BuildOptions(layout=PRESETS["wrists-ankles"], progress=False))
    again, _ = build_graph(kb, BuildOptions(layout=PRESETS["wrists-ankles"], progress=False), {})
    np.testing.assert_array_equal(plain.node_label, again.node_label)
    assert plain.labels == again.labels


def test_build_is_the_same_however_many_threads_blas_has(kb, built, tmp_path):
    # A Dask worker's BLAS has one thread and the CLI's as many as there are cores: the
    # bridges' candidates (float32 products) and the transitions' axes (eigh) must not
    # depend on it (graphsvc.blas).
    from threadpoolctl import threadpool_limits

    g, _ = built  # (built with BLAS's own thread count: the cores')
    save_graph(g, tmp_path / "a.graph")
    with threadpool_limits(1, user_api="blas"):
        again, _ = build_graph(kb, BuildOptions(layout=PRESETS["kelly6"], progress=False))
    save_graph(again, tmp_path / "b.graph")
    assert (tmp_path / "a.graph").read_bytes() == (tmp_path / "b.graph").read_bytes()

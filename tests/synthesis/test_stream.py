"""Streaming synthesis (a path arriving a few frames at a time) on a small procedural graph."""

import numpy as np
import pytest

from graphsvc.graph import metadata as meta
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.model import EDGE_TRANSITION
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.synthesis.path import synthesize_motion
from graphsvc.synthesis.smooth import smooth_poses
from graphsvc.synthesis.stream import StreamingSynthesizer
from graphsvc.synthesis.track import TrackModel, free_steps, fused_track, smooth_offsets


@pytest.fixture(scope="module")
def graph():
    g, _ = build_graph(generate_knowledge_base(seed=3, minutes=0.6), BuildOptions(interp=False, progress=False))
    return g


def _walk(g, steps, rng):
    """A path along random outgoing edges (transitions preferred), from node 0."""
    nodes, edges = [0], []
    for _ in range(steps):
        out = np.flatnonzero(g.edge_src == nodes[-1])
        jumps = out[g.edge_kind[out] == EDGE_TRANSITION]
        e = int(rng.choice(jumps if jumps.size and rng.random() < 0.3 else out))
        edges.append(e)
        nodes.append(int(g.edge_dst[e]))
    return np.array(nodes), np.array(edges)


def _fixed_lag_track(g, nodes, edges, start, positions, model, lag):
    """The fused track a stream with `lag` frames of look-ahead makes: frame t's offset
    smoothed over the frames up to t + lag (all of them for the last lag frames)."""
    own, _ = meta.integrate_path(
        np.asarray(start[0]),
        start[1],
        g.edge_offset[edges].astype(np.float64),
        g.edge_heading[edges].astype(np.float64),
    )
    z, free = positions - own, free_steps(g.node_contacts[nodes])
    T = nodes.size
    offsets = np.array([smooth_offsets(z[: t + lag + 1], model, free[: t + lag + 1])[t] for t in range(T)])
    return own + offsets


@pytest.mark.parametrize(
    "fused, smooth", [(False, 0.0), (True, 0.0), (True, 1.0)], ids=["placed-once", "fused", "fused-smoothed"]
)
def test_frames_in_pieces_equal_the_whole_path_and_own_their_memory(graph, fused, smooth):
    g = graph
    rng = np.random.default_rng(2)
    nodes, edges = _walk(g, 150, rng)
    start = np.array([0.5, -1.0]), 0.3
    # A tracker's positions (some missing) the root is fused with, when it is.
    positions = np.cumsum(rng.normal(0, 0.05, (nodes.size, 2)), axis=0)
    positions[rng.random(nodes.size) < 0.2] = np.nan
    model = TrackModel(0.1, 0.3, float(g.rate_hz)) if fused else None
    synth = StreamingSynthesizer(g, *start, batch=3, track_model=model, smooth_frames=smooth)
    assert synth.smooth_lag == (3 if smooth else 0)
    track = _fixed_lag_track(g, nodes, edges, start, positions, model, synth.lookahead) if fused else None
    whole = synthesize_motion(g, nodes, edges, *start, track=track)
    if smooth:  # (the poses' filter over the whole path, as a batch run applies it)
        r, t = smooth_poses(whole.rotations, whole.translations, smooth)
        whole = whole.copy(rotations=r, translations=t)
    if fused:
        placed_once = synthesize_motion(g, nodes, edges, *start)
        assert np.abs(whole.translations[:, 0] - placed_once.translations[:, 0]).max() > 0.05
        # Where the look-ahead reaches the end, the whole path's smoother.
        batch = fused_track(g, nodes, edges, *start, positions, model)
        np.testing.assert_allclose(track[-synth.lookahead :], batch[-synth.lookahead :], atol=1e-12)
    arrival = np.concatenate([[-1], edges])
    rot, trans = [], []
    for a in range(0, nodes.size, 7):
        first, r, t = synth.add(nodes[a : a + 7], arrival[a : a + 7], positions[a : a + 7])
        assert first == sum(len(x) for x in rot)  # in order, each frame once
        rot.append(r)
        trans.append(t)
    _, r, t = synth.finish()
    rot.append(r)
    trans.append(t)
    for r, t in zip(rot, trans):
        # A view would keep the synthesis window's whole arrays alive with the frames.
        assert r.base is None and t.base is None
    assert np.concatenate(rot).shape == whole.rotations.shape
    # A frame's pose depends only on the path within its window, so the trailing
    # re-syntheses give the whole path's poses.
    np.testing.assert_allclose(np.concatenate(rot), whole.rotations, atol=1e-9)
    np.testing.assert_allclose(np.concatenate(trans), whole.translations, atol=1e-9)

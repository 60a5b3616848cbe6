"""The refinement (`strategies.refine`): a knowledge-base clip's own readings give back
its own poses, a noise-free clip in the graph is left as it is, a missing reading leaves
its frames to the path, and a strategy that does not read it says so."""

from __future__ import annotations

import numpy as np
import pytest

from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.pipeline import Options, reconstruct
from graphsvc.sensors.layout import layout_from_dict
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.sensors.simulate import simulate_recording
from graphsvc.strategies.options import Weights
from graphsvc.strategies.refine import Refiner, refine_index, window_offsets
from graphsvc.synthesis.local_pose import place_local_poses


@pytest.fixture(scope="module")
def built():
    kb = generate_knowledge_base(seed=5, minutes=0.6)
    graph, _ = build_graph(kb, BuildOptions(interp=False, progress=False))
    return kb, graph


def _joints_cm(rot, trans, other_rot, other_trans, parents) -> float:
    a, b = forward_kinematics(rot, trans, parents)[1], forward_kinematics(other_rot, other_trans, parents)[1]
    return float(100.0 * np.linalg.norm(a - b, axis=-1).mean())


def test_the_window_is_five_samples_over_a_quarter_second():
    assert window_offsets(30.0).tolist() == [-4, -2, 0, 2, 4]
    assert window_offsets(60.0).tolist() == [-8, -4, 0, 4, 8]


def test_a_clips_own_noise_free_readings_regress_to_its_own_poses(built):
    kb, graph = built
    clip = kb[2]
    rec = simulate_recording(clip, layout_from_dict(graph.layout), NOISE["none"], seed=0, rate_hz=graph.rate_hz)
    r = Refiner(graph, refine_index(graph))
    for a in rec.accelerations:
        r.push(a)
    r.finish()
    poses, ok = r.regressed(0, rec.num_samples)
    assert ok.all()
    rot, trans = clip.rotations.astype(np.float64), clip.translations.astype(np.float64)
    placed = place_local_poses(rot, trans, clip.skeleton.parents, r.index.layout, poses, ok)
    assert _joints_cm(*placed, rot, trans, clip.skeleton.parents) < 0.5


def test_a_noise_free_clip_in_the_graph_comes_back_within_half_a_centimetre(built):
    kb, graph = built
    rec = simulate_recording(kb[1], layout_from_dict(graph.layout), NOISE["none"], seed=0, rate_hz=graph.rate_hz)
    opts = Options(weights=Weights(0.5, 1, 1), smooth_s=0.0)
    plain = reconstruct(graph, rec, Options(weights=Weights(0.5, 1, 1), smooth_s=0.0, refine=False)).motion
    refined = reconstruct(graph, rec, opts).motion
    assert (
        _joints_cm(refined.rotations, refined.translations, plain.rotations, plain.translations, graph.skeleton.parents)
        < 0.5
    )


def test_a_missing_reading_leaves_the_frames_whose_window_holds_it_unrefined(built):
    kb, graph = built
    rec = simulate_recording(kb[0], layout_from_dict(graph.layout), NOISE["default"], seed=1, rate_hz=graph.rate_hz)
    acc = np.array(rec.accelerations, dtype=np.float64)
    acc[20, 1, 0] = np.nan
    r = Refiner(graph, refine_index(graph))
    for a in acc:
        r.push(a)
    r.finish()
    _, ok = r.regressed(0, acc.shape[0])
    assert np.flatnonzero(~ok).tolist() == [16, 18, 20, 22, 24]  # (the frames whose window reads sample 20)


def test_refine_is_the_default_of_the_search_and_nearest_stays_unrefined(built):
    kb, graph = built
    rec = simulate_recording(kb[0], layout_from_dict(graph.layout), NOISE["default"], seed=2, rate_hz=graph.rate_hz)
    assert Options().shared.refine
    near = reconstruct(graph, rec, Options(strategy="nearest", refine=False))  # (set, and not read: said so)
    assert "refine" in near.report["ignored_options"]
    a = reconstruct(graph, rec, Options(weights=Weights(0.5, 1, 1)))
    b = reconstruct(graph, rec, Options(weights=Weights(0.5, 1, 1), refine=False))
    assert np.array_equal(a.node_path, b.node_path) and not np.allclose(a.motion.rotations, b.motion.rotations)


def test_the_regressed_poses_are_the_same_however_many_threads_blas_has():
    # (a batch worker's BLAS has one thread, the CLI's two: graphsvc.blas)
    from threadpoolctl import threadpool_limits

    from graphsvc.sensors.layout import PRESETS
    from graphsvc.strategies.refine import regress

    # (six sensors: products large enough for OpenBLAS to split over its threads)
    graph, _ = build_graph(generate_knowledge_base(seed=0, minutes=0.5), BuildOptions(layout=PRESETS["kelly6"]))
    index = refine_index(graph)
    rng = np.random.default_rng(1)
    queries = index.windows[::7] + 0.05 * rng.standard_normal(index.windows[::7].shape)  # (near, not on, its rows)
    got = []
    for threads in (1, 2):
        with threadpool_limits(threads, user_api="blas"):
            got.append(regress(index, queries))
    assert got[0].tobytes() == got[1].tobytes()

"""Mixed-action performances: joining clips, grouping them, and reconstructing a
joined procedural performance with its actions in order."""

import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.evaluate import loo
from graphsvc.evaluate.mixed import join_clips, mixed_groups, mixed_items
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.motion import signals
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.resample import resample
from graphsvc.pipeline import Options
from graphsvc.sensors.layout import PRESETS
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.strategies.options import Weights
from tests.graph.test_connectivity import mixed_kb


def _ground_heading(motion):
    pos = motion_fk(motion)[1]
    table = joint_map(motion.skeleton)
    return signals.ground_position(pos, table["pelvis"]), signals.heading(pos, table)


def test_join_shifts_each_clip_to_start_where_the_last_ended():
    clips = mixed_kb(11, clips_per_kind=1, seconds=3.0)
    joined, labels = join_clips(clips, 30.0)
    assert joined.num_frames == sum(resample(c, 30.0).num_frames for c in clips) == labels.shape[0]
    ground, heading = _ground_heading(joined)
    at = 0
    for k, clip in enumerate(clips):
        own_ground, own_heading = _ground_heading(resample(clip, 30.0))
        n = own_ground.shape[0]
        assert list(labels[at : at + n]) == [clip.labels[0]] * n
        # Pose and heading as recorded; the track moved rigidly by a shift only.
        np.testing.assert_allclose(heading[at : at + n], own_heading, atol=1e-9)
        shift = ground[at] - own_ground[0]
        np.testing.assert_allclose(ground[at : at + n], own_ground + shift, atol=1e-9)
        if k:
            np.testing.assert_allclose(ground[at], ground[at - 1], atol=1e-9)  # starts where the last ended
        np.testing.assert_array_equal(joined.rotations[at : at + n], resample(clip, 30.0).rotations)
        at += n


def test_join_with_turn_continues_the_facing():
    clips = mixed_kb(11, clips_per_kind=1, seconds=3.0)
    joined, labels = join_clips(clips, 30.0, turn=True)
    ground, heading = _ground_heading(joined)
    seams = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    step = np.abs(np.angle(np.exp(1j * np.diff(heading))))
    for k in seams:
        # No jump at the seam beyond a frame's own turning, and the track continues.
        assert step[k - 1] <= 3 * np.median(step) + 0.05
        assert np.hypot(*(ground[k] - ground[k - 1])) < 0.2
    plain, _ = join_clips(clips, 30.0)
    np.testing.assert_array_equal(plain.rotations[: seams[0]], joined.rotations[: seams[0]])  # the first clip stays


def test_groups_have_distinct_labels_and_one_performer():
    clips = mixed_kb(12, clips_per_kind=3, seconds=2.0)
    groups = mixed_groups(clips, 3, seed=1)
    assert len(groups) == 4  # 12 clips of 4 labels, dealt three different labels at a time
    used = [k for g in groups for k in g]
    assert len(used) == len(set(used))
    for g in groups:
        assert len({clips[k].labels[0] for k in g}) == 3
    assert mixed_groups(clips, 3, seed=1) == groups  # deterministic by seed
    with pytest.raises(InputError):
        mixed_groups(clips, 1)


def test_groups_keep_performers_apart():
    clips = mixed_kb(13, clips_per_kind=1, seconds=2.0)
    taller = [
        c.copy(
            skeleton=type(c.skeleton)(
                c.skeleton.names, c.skeleton.parents, c.skeleton.offsets * 1.1, c.skeleton.channels, c.skeleton.end_site
            )
        )
        for c in clips
    ]
    groups = mixed_groups(clips + taller, 4, seed=0)
    assert sorted(sorted(g) for g in groups) == [[0, 1, 2, 3], [4, 5, 6, 7]]


def test_joined_procedural_performance_reconstructs_its_actions_in_order():
    kb = mixed_kb(5)
    graph, _ = build_graph(kb, BuildOptions(layout=PRESETS["wrists-ankles"], progress=False))
    # Held out: another seed's walk → run → stand → punch, none of it in the graph.
    rng_clips = {c.labels[0]: c for c in mixed_kb(21, clips_per_kind=1, seconds=4.0)}
    performance = [rng_clips[k] for k in ("walk", "run", "idle", "punch")]
    # (facing continued across the seams, as one performer would: with each clip's own
    # heading the measured heading jumps at every seam, and which label wins the run
    # then hangs on where the start is anchored)
    truth, labels = join_clips(performance, graph.rate_hz, turn=True)
    setup = loo.EvalSetup(NOISE["default"], positions=True, options=Options(weights=Weights(0.5, 1, 1)))
    row = loo.evaluate_clip(graph, truth, [], setup, labels)
    pred = row["pred_labels"]
    seams = np.r_[0, np.flatnonzero(labels[1:] != labels[:-1]) + 1, labels.shape[0]]
    majority = []
    for a, b in zip(seams[:-1], seams[1:]):
        names, counts = np.unique(pred[a:b].astype(str), return_counts=True)
        majority.append(str(names[np.argmax(counts)]))
    assert majority == ["walk", "run", "idle", "punch"]
    assert row["label_acc"] > 0.6


def test_mixed_items_hide_every_joined_clip():
    kb = mixed_kb(5, clips_per_kind=1, seconds=3.0)
    items = mixed_items(kb, list(range(len(kb))), 4, 30.0, seed=2)
    assert len(items) == 1
    motion, hidden, labels = items[0]
    assert sorted(hidden) == [0, 1, 2, 3] and motion.name == "mixed_01"
    assert motion.source == " + ".join(kb[k].name for k in mixed_groups(kb, 4, seed=2)[0])
    assert labels.shape == (motion.num_frames,)

"""Hold-out protocols: which clips a test clip hides (graphsvc/evaluate/protocols.py)."""

import json

import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.evaluate import protocols as P


def _clips():
    a, b, c = (np.full((3, 3), v) for v in (1.0, 2.0, 3.0))  # three skeletons
    spec = [
        ("dataset-2_walk_normal_001", "walk", c),
        ("dataset-2_walk_normal_004", "walk", c),
        ("dataset-2_walk_masculine_002", "walk", c),
        ("dataset-2_run_normal_001", "run", c),
        ("dataset-2_walk_youthful_001", "walk", b),
        ("dataset-2_wave-left-hand_feminine_003", "wave-left-hand", b),
        ("dataset-2_walk_active_001", "walk", a),
        ("dataset-1_walk_normal_001", "walk", c),
        ("dataset-1_bow_sad_001", "bow", None),
        ("walk_01", "walk", None),
        ("02_05", "", None),
    ]
    return [P.Clip(n, label, o) for n, label, o in spec]


def test_take_keys_and_builtin_actors():
    assert P.take_key("dataset-2_walk_normal_004") == "dataset-2_walk_normal"
    assert P.take_key("walk_01") == "walk_01"  # (two digits: a procedural clip, not a take)
    assert P.take_key("02_05") == "02_05"  # (CMU subject_trial: no take structure)
    assert P.builtin_actor("dataset-2_walk_elderly_003") == P.builtin_actor("dataset-2_run_exhausted_001")
    assert P.builtin_actor("dataset-2_walk_normal_001") != P.builtin_actor("dataset-2_walk_youthful_001")
    assert P.builtin_actor("dataset-1_walk_normal_001") is None  # (dataset 1's actors: by skeleton)
    assert P.builtin_actor("02_05") == "cmu:02"


def test_each_protocol_hides_its_set():
    clips = _clips()
    names = [c.name for c in clips]
    test = clips[1]  # walk, normal, take 004
    hide = {
        p: sorted(
            names[k]
            for k in P.hidden_clips(
                p, test, clips, *((P.actor_groups(clips), P.actor_groups(clips)[1]) if p == "actor" else ())
            )
        )
        for p in P.PROTOCOLS
    }
    assert hide["clip"] == ["dataset-2_walk_normal_004"]
    assert hide["takes"] == ["dataset-2_walk_normal_001", "dataset-2_walk_normal_004"]
    # normal and masculine are one actor (built-in), and dataset 1's walk_normal has
    # the same skeleton: the same person, found by the offsets.
    assert hide["actor"] == sorted(
        [
            "dataset-2_walk_normal_001",
            "dataset-2_walk_normal_004",
            "dataset-2_walk_masculine_002",
            "dataset-2_run_normal_001",
            "dataset-1_walk_normal_001",
        ]
    )
    assert hide["content"] == sorted(n for n, c in zip(names, clips) if c.label == "walk")
    with pytest.raises(InputError, match="unknown hold-out protocol"):
        P.hidden_clips("performer", test, clips)


def test_actor_map_file_joins_and_checks(tmp_path):
    clips = _clips()
    path = tmp_path / "actors.json"
    path.write_text(json.dumps({"dataset-1_bow_*": "sad-actor", "02_05": "sad-actor"}))
    groups = P.actor_groups(clips, P.load_actor_map(path))
    assert groups[8] == groups[10] != groups[9]
    assert groups[0] == groups[1] == groups[7] and groups[4] == groups[5] and groups[6] not in (groups[0], groups[4])
    assert P.check_actor_map(clips) == []  # the built-in map agrees with these skeletons
    wrong = clips[:4] + [P.Clip("dataset-2_walk_feminine_001", "walk", np.full((3, 3), 1.0))]
    wrong += [P.Clip("dataset-2_walk_youthful_002", "walk", np.full((3, 3), 2.0))]
    problems = P.check_actor_map(wrong)
    assert len(problems) == 1 and "2 different skeletons" in problems[0]
    bad = tmp_path / "bad.json"
    bad.write_text("[1, 2]")
    with pytest.raises(InputError, match="object of clip name"):
        P.load_actor_map(bad)


def test_activity_groups():
    assert [P.activity(x) for x in ("walk", "walk-turn-left", "run", "stop", "dash")] == ["locomotion"] * 5
    assert [P.activity(x) for x in ("wave-left-hand", "raise-up-both-hands", "bow", "idle", "forehand")] == [
        "gestures"
    ] * 5


def test_builtin_bandai_actors_agree_with_the_skeletons(data_dir):
    # The style groups of dataset 2 are one actor each: every clip of a group has the
    # same skeleton, and no two groups share one.
    from graphsvc.motion.library import find_motion_files, load_motion

    root = data_dir / "bandai" / "dataset-2" / "data"
    if not root.is_dir():
        pytest.skip(f"../shared/data not found: {root} missing")
    files = find_motion_files([str(root)])[::3]
    clips = [P.Clip(m.name, m.labels[0], m.skeleton.offsets) for m in map(load_motion, files)]
    assert P.check_actor_map(clips) == []
    assert len(set(P.actor_groups(clips).tolist())) == 3

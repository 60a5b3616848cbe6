"""Joint maps: built-in families, mappings that leave out joints a skeleton lacks (their
stand-ins, what is missing), and the guesser for common naming schemes."""

import json

import numpy as np
import pytest

from graphsvc.errors import SkeletonError
from graphsvc.evaluate.loo import _global_signals
from graphsvc.evaluate.metrics import joint_err_cm
from graphsvc.motion.joints import CANONICAL, OPTIONAL, common_joints, guess_mapping, joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.motion.skeleton import Motion, Skeleton
from graphsvc.sensors.layout import PRESETS, place
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.sensors.simulate import simulate_recording

# (parent, name) in topological order, with "{s}" for the side's spelling.
BODY = [
    (None, "{hips}"),
    ("{hips}", "{spine}"),
    ("{spine}", "{chest}"),
    ("{chest}", "{neck}"),
    ("{neck}", "{head}"),
    ("{chest}", "{L}{collar}"),
    ("{L}{collar}", "{L}{upper}"),
    ("{L}{upper}", "{L}{fore}"),
    ("{L}{fore}", "{L}{hand}"),
    ("{chest}", "{R}{collar}"),
    ("{R}{collar}", "{R}{upper}"),
    ("{R}{upper}", "{R}{fore}"),
    ("{R}{fore}", "{R}{hand}"),
    ("{hips}", "{L}{thigh}"),
    ("{L}{thigh}", "{L}{shin}"),
    ("{L}{shin}", "{L}{foot}"),
    ("{L}{foot}", "{L}{toe}"),
    ("{hips}", "{R}{thigh}"),
    ("{R}{thigh}", "{R}{shin}"),
    ("{R}{shin}", "{R}{foot}"),
    ("{R}{foot}", "{R}{toe}"),
]


def _skeleton(**words) -> Skeleton:
    fill = lambda t: None if t is None else t.format(**words)  # noqa: E731
    names = [fill(n) for _, n in BODY]
    parents = [-1 if p is None else names.index(fill(p)) for p, _ in BODY]
    return Skeleton(
        tuple(names), np.array(parents), np.zeros((len(names), 3)), tuple(() for _ in names), np.zeros(len(names), bool)
    )


SCHEMES = {
    "LeftElbow": dict(
        hips="Hips",
        spine="Spine",
        chest="Chest",
        neck="Neck",
        head="Head",
        L="Left",
        R="Right",
        collar="Collar",
        upper="Shoulder",
        fore="Elbow",
        hand="Wrist",
        thigh="Hip",
        shin="Knee",
        foot="Ankle",
        toe="Toe",
    ),
    "l_elbow": dict(
        hips="pelvis",
        spine="spine",
        chest="chest",
        neck="neck",
        head="head",
        L="l_",
        R="r_",
        collar="clavicle",
        upper="shoulder",
        fore="elbow",
        hand="wrist",
        thigh="hip",
        shin="knee",
        foot="ankle",
        toe="toe",
    ),
    "LeftForeArm": dict(
        hips="Hips",
        spine="Spine",
        chest="Spine2",
        neck="Neck",
        head="Head",
        L="Left",
        R="Right",
        collar="Shoulder",
        upper="Arm",
        fore="ForeArm",
        hand="Hand",
        thigh="UpLeg",
        shin="Leg",
        foot="Foot",
        toe="ToeBase",
    ),
    "mixamorig:LeftForeArm": dict(
        hips="mixamorig:Hips",
        spine="mixamorig:Spine",
        chest="mixamorig:Spine2",
        neck="mixamorig:Neck",
        head="mixamorig:Head",
        L="mixamorig:Left",
        R="mixamorig:Right",
        collar="Shoulder",
        upper="Arm",
        fore="ForeArm",
        hand="Hand",
        thigh="UpLeg",
        shin="Leg",
        foot="Foot",
        toe="ToeBase",
    ),
}
# Which body word each canonical joint takes: the shoulder is the upper arm's start.
ROLE = {
    "pelvis": "hips",
    "spine": "spine",
    "chest": "chest",
    "neck": "neck",
    "head": "head",
    "shoulder": "upper",
    "elbow": "fore",
    "wrist": "hand",
    "hip": "thigh",
    "knee": "shin",
    "ankle": "foot",
    "toe": "toe",
}


@pytest.mark.parametrize("scheme", sorted(SCHEMES))
def test_guess_mapping_for_common_naming_schemes(scheme):
    w = SCHEMES[scheme]
    sk = _skeleton(**w)
    guess, missing = guess_mapping(sk)
    assert missing == []
    for c in CANONICAL:
        side, part = (c[0], c[2:]) if c[1] == "_" else ("", c)
        prefix = {"l": w["L"], "r": w["R"], "": ""}[side]
        assert guess[c] == prefix + w[ROLE[part]], (c, guess[c])
    table = joint_map(sk, "guess")
    assert table.family == "guessed" and not table.missing


def test_a_mapping_may_leave_out_joints_the_skeleton_lacks():
    """The mocapbank-style skeleton: no spine joint of that name, no toes. They map to
    their stand-ins and are listed as missing; a required joint may not be left out."""
    words = dict(SCHEMES["LeftElbow"])
    sk = _skeleton(**words)
    keep = [k for k, n in enumerate(sk.names) if not n.endswith("Toe")]
    lean = Skeleton(
        tuple(sk.names[k] for k in keep),
        np.array([keep.index(sk.parents[k]) if sk.parents[k] >= 0 else -1 for k in keep]),
        np.zeros((len(keep), 3)),
        tuple(() for _ in keep),
        np.zeros(len(keep), bool),
    )
    mapping, missing = guess_mapping(lean)
    assert missing == ["l_toe", "r_toe"]
    table = joint_map(lean, mapping)
    assert table.missing == {"l_toe", "r_toe"} and table["l_toe"] == table["l_ankle"] == lean.index("LeftAnkle")
    assert "l_toe" not in table.present() and len(table.present()) == 17
    with pytest.raises(SkeletonError, match="l_elbow"):
        joint_map(lean, {k: v for k, v in mapping.items() if k != "l_elbow"} | {"l_elbow": "Nope"})
    with pytest.raises(SkeletonError, match="unknown skeleton.*--mapping guess.*l_wrist=LeftWrist"):
        joint_map(lean)
    assert set(OPTIONAL) == {"spine", "chest", "neck", "l_toe", "r_toe"}


def _without_toes(motion: Motion) -> Motion:
    """The same motion on its skeleton with the toe joints (and their end sites) removed."""
    sk = motion.skeleton
    drop = {j for j, n in enumerate(sk.names) if "toe" in n.lower()}
    keep = [j for j in range(sk.num_joints) if j not in drop]
    parents = np.array([keep.index(sk.parents[j]) if sk.parents[j] >= 0 else -1 for j in keep])
    lean = Skeleton(
        tuple(sk.names[j] for j in keep),
        parents,
        sk.offsets[keep],
        tuple(sk.channels[j] for j in keep),
        sk.end_site[keep],
    )
    return Motion(lean, motion.rotations[:, keep], motion.translations[:, keep], motion.rate_hz, name="lean")


def test_metrics_compare_what_both_skeletons_have_and_sensors_use_what_exists(tmp_path):
    clip = generate_knowledge_base(seed=2, minutes=0.1)[0]
    lean = _without_toes(clip)
    mapping = tmp_path / "map.json"
    mapping.write_text(json.dumps({c: c for c in CANONICAL if "toe" not in c}))
    full_t, lean_t = joint_map(clip.skeleton), joint_map(lean.skeleton, str(mapping))
    names = common_joints(full_t, lean_t)
    assert names == [c for c in CANONICAL if "toe" not in c]
    a = _global_signals(motion_fk(clip)[1], full_t, names)
    b = _global_signals(motion_fk(lean)[1], lean_t, names)
    assert joint_err_cm(a[0], b[0], a[1], a[2], b[1], b[2])[1] == pytest.approx(0.0, abs=1e-9)
    # Sensors away from the toes read as on the full skeleton; the recording says what was missing.
    full = simulate_recording(clip, PRESETS["kelly6"], NOISE["none"])
    rec = simulate_recording(lean, PRESETS["kelly6"], NOISE["none"], mapping=str(mapping))
    np.testing.assert_allclose(rec.accelerations, full.accelerations, atol=1e-4)
    assert rec.meta["missing_joints"] == ["l_toe", "r_toe"] and "missing_joints" not in full.meta
    from graphsvc.sensors.layout import layout_from_dict

    foot = layout_from_dict({"name": "f", "sensors": [{"name": "foot", "segment": "l_ankle", "toward": "l_toe"}]})
    with pytest.raises(SkeletonError, match="coincide.*has no l_toe"):
        place(foot, lean.skeleton, str(mapping))


def test_cli_mapping_and_a_test_clip_on_another_skeleton(tmp_path, capsys):
    """`graphsvc mapping` proposes the map; `evaluate --mapping` scores a clip whose
    skeleton lacks the toes on a graph of the full skeleton, over the joints both have."""
    from graphsvc.cli import main
    from graphsvc.graph.build import BuildOptions, build_graph
    from graphsvc.graph.file import save_graph
    from graphsvc.motion.bvh import write_bvh

    kb = generate_knowledge_base(seed=2, minutes=0.3)
    graph, _ = build_graph(kb, BuildOptions(progress=False))
    save_graph(graph, tmp_path / "g.graph")
    lean = _without_toes(kb[0])
    lean.name = "lean_clip"
    write_bvh(tmp_path / "lean_clip.bvh", lean)
    assert main(["mapping", str(tmp_path / "lean_clip.bvh"), "-o", str(tmp_path / "map.json")]) == 0
    err = capsys.readouterr().err
    assert "not found: l_toe, r_toe (a skeleton may lack these)" in err
    assert json.loads((tmp_path / "map.json").read_text())["l_wrist"] == "l_wrist"
    out = tmp_path / "e.json"
    assert (
        main(
            [
                "evaluate",
                str(tmp_path / "lean_clip.bvh"),
                "--graph",
                str(tmp_path / "g.graph"),
                "--test",
                "*.bvh",
                "--mapping",
                str(tmp_path / "map.json"),
                "--noise",
                "none",
                "--quiet",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    row = json.loads(out.read_text())["clips"][0]
    assert row["missing_joints"] == ["l_toe", "r_toe"] and row["in_graph"] is False
    assert row["joint_err_cm"] < 1.0  # (the clip is in the graph's knowledge base, on the full skeleton)
    capsys.readouterr()
    assert (
        main(
            [
                "evaluate",
                str(tmp_path / "lean_clip.bvh"),
                "--graph",
                str(tmp_path / "g.graph"),
                "--test",
                "*.bvh",
                "--quiet",
            ]
        )
        == 2
    )
    assert "--mapping guess" in capsys.readouterr().err

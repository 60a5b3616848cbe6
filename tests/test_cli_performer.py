"""`graphsvc synthesize --performer FILE | --height M`: the output on the performer's
proportions; bad, missing or conflicting inputs refused with one line and exit 2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from graphsvc.cli import main
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.file import save_graph
from graphsvc.motion.bvh import read_bvh, write_bvh
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.motion.procedural.body import standard_skeleton
from graphsvc.motion.proportions import SEGMENTS, on_performer, performer_skeleton, segment_lengths
from graphsvc.sensors.layout import load_layout
from graphsvc.sensors.noise import parse_noise
from graphsvc.sensors.recording import save_recording
from graphsvc.sensors.simulate import simulate_recording

LAYOUT = load_layout("wrists-ankles")
KB = segment_lengths(standard_skeleton())


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A graph of a procedural knowledge base, a recording of one of its clips, and the
    plain reconstruction of it (on the knowledge base's skeleton)."""
    d = tmp_path_factory.mktemp("performer")
    kb = generate_knowledge_base(seed=3, minutes=1.0)
    graph, _ = build_graph(kb, BuildOptions(layout=LAYOUT, progress=False))
    save_graph(graph, d / "g.graph")
    walk = next(m for m in kb if m.name.startswith("run"))
    save_recording(simulate_recording(walk, LAYOUT, parse_noise("none"), seed=9), d / "walk.rec")
    assert main(["synthesize", str(d / "g.graph"), str(d / "walk.rec"), "-o", str(d / "plain.bvh")]) == 0
    return d


def run(argv, capsys):
    try:
        code = main(argv)
    except SystemExit as exc:  # (argparse's refusals)
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


def _synthesize(d, out, extra, capsys):
    return run(
        [
            "synthesize",
            str(d / "g.graph"),
            str(d / "walk.rec"),
            "-o",
            str(out),
            "--report",
            str(out.with_suffix(".json")),
            *extra,
        ],
        capsys,
    )


def _same_rotations(a, b):
    """The BVH rotation channels of two motions agree (the same local rotations)."""
    ra, rb = read_bvh(a).rotations, read_bvh(b).rotations
    np.testing.assert_allclose(np.abs(np.sum(ra * rb, axis=-1)), 1.0, atol=1e-7)


def test_height_puts_the_output_on_proportions_scaled_by_height(files, capsys):
    d = files
    out = d / "tall.bvh"
    code, printed, err = _synthesize(d, out, ["--height", "1.96"], capsys)
    assert code == 0, err
    assert "on a performer 1.96 m tall" in printed
    got = segment_lengths(read_bvh(out).skeleton)
    for name in SEGMENTS:  # 1.96 / 1.75 = 1.12
        assert got[name] == pytest.approx(1.12 * KB[name], abs=1e-6), name
    _same_rotations(out, d / "plain.bvh")
    # uniform: every position the plain output's times 1.12 (the feet on the floor)
    np.testing.assert_allclose(motion_fk(read_bvh(out))[1], 1.12 * motion_fk(read_bvh(d / "plain.bvh"))[1], atol=1e-6)
    report = json.loads(out.with_suffix(".json").read_text())["performer"]
    assert report["height_m"] == pytest.approx(1.96, abs=1e-4)
    assert report["segments_m"]["l_thigh"] == pytest.approx(1.12 * 0.42, abs=1e-6)


def test_a_performer_json_gives_its_segments_and_scales_the_others(files, capsys):
    d = files
    spec = d / "spec.json"
    spec.write_text(
        json.dumps(
            {
                "format": "graphsvc-performer",
                "version": 1,
                "segments_m": {"l_thigh": 0.504, "r_thigh": 0.462, "chest": 0.253},
            }
        )
    )
    out = d / "actor.bvh"
    code, _, err = _synthesize(d, out, ["--performer", str(spec)], capsys)
    assert code == 0, err
    got = segment_lengths(read_bvh(out).skeleton)
    # given: as given; the others × (1.2 + 1.1 + 1.15) / 3 = 1.15
    want = {name: 1.15 * v for name, v in KB.items()} | {"l_thigh": 0.504, "r_thigh": 0.462, "chest": 0.253}
    for name in SEGMENTS:
        assert got[name] == pytest.approx(want[name], abs=1e-6), name
    _same_rotations(out, d / "plain.bvh")


def test_a_performer_bvh_gives_its_skeleton_s_proportions(files, capsys):
    d = files
    plain = read_bvh(d / "plain.bvh")
    want = {name: v * (1.2 - 0.02 * i) for i, (name, v) in enumerate(KB.items())}
    write_bvh(d / "someone.bvh", on_performer(plain, performer_skeleton(plain.skeleton, want)), scale=100.0)
    out = d / "as_someone.bvh"
    code, _, err = _synthesize(d, out, ["--performer", str(d / "someone.bvh")], capsys)
    assert code == 0, err
    got = segment_lengths(read_bvh(out).skeleton)
    for name in SEGMENTS:
        assert got[name] == pytest.approx(want[name], abs=1e-6), name


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--height", "1.8", "--performer", "p.json"], "not allowed with argument"),
        (["--height", "-1.75"], "--height"),
        (["--height", "175"], "at most 3"),
        (["--height", "tall"], "not a number"),
        (["--performer-mapping", "guess"], "--performer-mapping applies to a --performer"),
    ],
)
def test_conflicting_or_bad_flags_one_line_exit_2(files, capsys, extra, needle):
    d = files
    out = d / "never.bvh"
    code, _, err = _synthesize(d, out, extra, capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and needle in err, err
    assert not out.exists()


@pytest.mark.parametrize(
    "content, needle",
    [
        (None, "no such file"),
        ("{", "not valid JSON"),
        (
            json.dumps({"format": "graphsvc-performer", "version": 1, "segments_m": {"tail": 0.3}}),
            "unknown segments: tail",
        ),
        (json.dumps({"format": "graphsvc-performer", "version": 1, "segments_m": {"l_shin": -1}}), "l_shin must be"),
    ],
)
def test_a_bad_or_missing_performer_file_one_line_exit_2(files, capsys, content, needle):
    d = files
    spec = d / "bad_performer.json"
    spec.unlink(missing_ok=True)
    if content is not None:
        spec.write_text(content)
    out = d / "never.bvh"
    code, _, err = _synthesize(d, out, ["--performer", str(spec)], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and needle in err and str(spec) in err, err
    assert not out.exists()


def test_the_output_may_not_replace_the_performer_file(files, capsys):
    d = files
    target = d / "me.bvh"
    write_bvh(target, read_bvh(d / "plain.bvh"), scale=100.0)
    before = target.read_bytes()
    code, _, err = run(
        ["synthesize", str(d / "g.graph"), str(d / "walk.rec"), "-o", str(target), "--performer", str(target)], capsys
    )
    assert code == 2 and len(err.strip().splitlines()) == 1 and "performer" in err, err
    assert target.read_bytes() == before


def test_a_performer_motion_of_an_unknown_skeleton_names_the_performer_mapping(files, capsys):
    d = files
    odd = d / "odd.bvh"
    odd.write_text(
        "HIERARCHY\nROOT Torso\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation "
        "Xrotation Yrotation\n JOINT Noggin\n {\n  OFFSET 0 10 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n"
        "  End Site\n  {\n   OFFSET 0 10 0\n  }\n }\n}\nMOTION\nFrames: 1\nFrame Time: 0.0333333\n"
        "0 90 0 0 0 0 0 0 0\n"
    )
    out = d / "never.bvh"
    code, _, err = _synthesize(d, out, ["--performer", str(odd)], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert f"performer {odd}: unknown skeleton" in err and "--performer-mapping guess" in err
    assert not out.exists()

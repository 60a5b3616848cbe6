"""The manifest (CSV and JSON forms, paths, options as synthesize flags, fingerprints)
and the job store's re-run rules, without a cluster."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from graphsvc.batch import store
from graphsvc.batch.manifest import Plan, option_argv, parse_item_options, plan_item, read_manifest
from graphsvc.errors import FormatError, InputError


def test_csv_and_json_forms_read_the_same_items(tmp_path):
    csv_text = (
        "# a match\n\nrecording,graph,strategy,output,weights,options\n"
        'p1.rec,g,viterbi,p1,"0.5,1,1","{""beam"": 10}"\n'
        "p2.rec,g,olng,p2,,\n"
    )
    (tmp_path / "m.csv").write_text(csv_text)
    rows = [
        {
            "recording": "p1.rec",
            "graph": "g",
            "strategy": "viterbi",
            "output": "p1",
            "weights": [0.5, 1, 1],
            "options": {"beam": 10},
        },
        {"recording": "p2.rec", "graph": "g", "strategy": "olng", "output": "p2"},
    ]
    (tmp_path / "m.json").write_text(json.dumps({"items": rows}))
    a, b = read_manifest(tmp_path / "m.csv"), read_manifest(tmp_path / "m.json")
    assert [i.line for i in a] == [4, 5] and [i.line for i in b] == [1, 2]
    strip = lambda items: [(i.output, i.recording, i.strategy, i.weights, i.options) for i in items]  # noqa: E731
    assert (
        strip(a)
        == strip(b)
        == [("p1", "p1.rec", "viterbi", "0.5,1,1", {"beam": 10}), ("p2", "p2.rec", "olng", None, {})]
    )


def test_options_become_synthesize_flags(tmp_path):
    (tmp_path / "map.json").write_text("{}")
    (tmp_path / "m.json").write_text(
        json.dumps(
            [
                {
                    "recording": "r.rec",
                    "graph": "g",
                    "strategy": "viterbi",
                    "output": "o",
                    "weights": "0.5,1,1",
                    "options": {
                        "latency": 0.5,
                        "heading_from_track": True,
                        "olng-basic-steps": False,
                        "keep": ["A", "B"],
                        "device-map": "map.json",
                    },
                }
            ]
        )
    )
    (item,) = read_manifest(tmp_path / "m.json")
    argv = option_argv(item, tmp_path)
    assert argv == [
        "--strategy",
        "viterbi",
        "--weights",
        "0.5,1,1",
        "--device-map",
        str((tmp_path / "map.json").resolve()),
        "--heading-from-track",
        "--keep",
        "A,B",
        "--latency",
        "0.5",
    ]
    options, args = parse_item_options(argv)
    assert options.latency_s == 0.5 and options.heading_from_track and options.weights.acc == 0.5
    assert options.ssg.keep == ("A", "B") and args.scale == 100.0
    with pytest.raises(InputError, match="strategy, weights, constraints and calibration are columns"):
        option_argv(read_manifest(_one(tmp_path, {"strategy": "olng"}))[0], tmp_path)
    with pytest.raises(InputError, match="must be a number, text, a list or true"):
        option_argv(read_manifest(_one(tmp_path, {"beam": {"x": 1}}))[0], tmp_path)


def _one(folder: Path, options: dict) -> Path:
    path = folder / "one.json"
    path.write_text(
        json.dumps([{"recording": "r.rec", "graph": "g", "strategy": "viterbi", "output": "o", "options": options}])
    )
    return path


def test_bad_json_manifests_name_the_item(tmp_path):
    for body, needle in [
        ('{"a": 1}', "a JSON manifest is a list"),
        ("[1]", "item 1 is not an object"),
        ('[{"recording": "r", "graph": "g", "strategy": "s"}]', "no output"),
        ('[{"recording": "r", "graph": "g", "strategy": "s", "output": "o", "colour": 1}]', "unknown field 'colour'"),
        ("[]", "lists no items"),
        ("[", "not valid JSON"),
    ]:
        (tmp_path / "m.json").write_text(body)
        with pytest.raises(FormatError, match=needle):
            read_manifest(tmp_path / "m.json")


def test_fingerprint_follows_the_recording_and_options(tmp_path):
    graph = tmp_path / "g.graph"
    _small_graph(graph)
    (tmp_path / "r.rec").write_bytes(b"not a recording yet")
    items = lambda opts: read_manifest(_one(tmp_path, opts))[0]  # noqa: E731
    p1 = plan_item(items({}), tmp_path, {"g": graph}, tmp_path, "v")
    assert (
        p1.error is None and p1.task["graph_checksum"] and p1.task["recording"] == str((tmp_path / "r.rec").resolve())
    )
    assert plan_item(items({}), tmp_path, {"g": graph}, tmp_path, "v").fingerprint == p1.fingerprint
    assert plan_item(items({"beam": 10}), tmp_path, {"g": graph}, tmp_path, "v").fingerprint != p1.fingerprint
    assert plan_item(items({}), tmp_path, {"g": graph}, tmp_path, "v2").fingerprint != p1.fingerprint
    (tmp_path / "r.rec").write_bytes(b"another recording")
    assert plan_item(items({}), tmp_path, {"g": graph}, tmp_path, "v").fingerprint != p1.fingerprint
    bad = plan_item(items({"olng-k": 0}), tmp_path, {"g": graph}, tmp_path, "v")
    assert bad.task is None and "OLNG K must be ≥ 1" in bad.error


def test_the_format_column_chooses_the_output_s_file(tmp_path):
    """`format`: bvh (the default), glb or gltf, in the task and (when not bvh) the
    fingerprint; another value, or an output name with the suffix, fails the manifest."""
    graph = tmp_path / "g.graph"
    _small_graph(graph)
    (tmp_path / "r.rec").write_bytes(b"a recording")
    rows = [
        {"recording": "r.rec", "graph": "g", "strategy": "viterbi", "output": f"o{k}", "format": fmt}
        for k, fmt in enumerate(("bvh", "GLB", ".gltf", ""))
    ]
    (tmp_path / "m.json").write_text(json.dumps(rows))
    plans = [plan_item(i, tmp_path, {"g": graph}, tmp_path, "v") for i in read_manifest(tmp_path / "m.json")]
    assert [p.task["format"] for p in plans] == ["bvh", "glb", "gltf", "bvh"]
    fingerprints = [p.fingerprint for p in plans]
    same = plan_item(read_manifest(_one(tmp_path, {}))[0], tmp_path, {"g": graph}, tmp_path, "v").fingerprint
    assert len(set(fingerprints[:3])) == 3 and same == fingerprints[0] == fingerprints[3]  # (a bvh item's unchanged)
    for row, needle in (
        ({"format": "fbx"}, "format 'fbx' is not one of bvh, glb, gltf"),
        ({"output": "o.glb"}, "no extension"),
    ):
        (tmp_path / "m.json").write_text(json.dumps([{**rows[0], "output": "o", **row}]))
        with pytest.raises(FormatError, match=needle):
            read_manifest(tmp_path / "m.json")


def _small_graph(path: Path) -> None:
    import numpy as np

    from graphsvc.graph.file import save_graph
    from graphsvc.graph.model import graph_from_edges

    rng = np.random.default_rng(0)
    src = np.repeat(np.arange(20), 2)
    g = graph_from_edges(
        src,
        rng.integers(0, 20, src.size),
        rng.normal(0, 9.81, (src.size, 2, 3)),
        offsets=rng.normal(0, 0.05, (src.size, 2)),
        dheading=rng.normal(0, 0.05, src.size),
    )
    save_graph(g, path)


def test_store_skips_done_items_and_requeues_the_rest(tmp_path):
    from graphsvc.batch.manifest import Item

    def plan(name, fp):
        return Plan(Item(line=1, output=name, recording="r", graph="g", strategy="viterbi"), {}, fp)

    out = tmp_path / "a.bvh"
    out.write_bytes(b"motion")
    con = store.open_store(tmp_path)
    plans = [plan("a", "f1"), plan("b", "f1"), plan("c", "f1")]
    assert [p.item.output for p in store.sync(con, plans, lambda p: "sum")] == ["a", "b", "c"]
    for name in "abc":
        assert store.mark_running(con, name) == 1
    store.mark_done(con, "a", {"output": str(out), "checksum": "sum", "seconds": 1.0})
    store.mark_failed(con, "b", "worker died\nat line 3", final=True)  # c: left running (its client died)
    rows = {r["output"]: r for r in store.rows(con)}
    assert rows["b"]["reason"] == "worker died at line 3" and rows["c"]["state"] == "running"
    # Same fingerprints: a skipped; b and c queued, their attempts kept.
    todo = store.sync(con, plans, lambda p: "sum")
    assert [p.item.output for p in todo] == ["b", "c"]
    rows = {r["output"]: r for r in store.rows(con)}
    assert (rows["a"]["state"], rows["b"]["state"], rows["c"]["state"]) == ("done", "queued", "queued")
    assert rows["b"]["attempts"] == rows["c"]["attempts"] == 1
    # A changed fingerprint, or an output whose bytes changed: run again, attempts from 0.
    assert [p.item.output for p in store.sync(con, [plan("a", "f2")], lambda p: "sum")] == ["a"]
    assert store.rows(con)[0]["attempts"] == 0
    store.mark_running(con, "a")
    store.mark_done(con, "a", {"output": str(out), "checksum": "sum", "seconds": 1.0})
    assert [p.item.output for p in store.sync(con, [plan("a", "f2")], lambda p: "edited")] == ["a"]
    assert store.counts(con) == {"queued": 3, "running": 0, "done": 0, "failed": 0}
    con.close()
    with store.folder_lock(tmp_path), pytest.raises(InputError, match="another batch is running"):
        with store.folder_lock(tmp_path):
            pass


def test_an_item_calibrates_from_its_own_start_through_its_options(tmp_path):
    (item,) = read_manifest(_one(tmp_path, {"calibrate-from-start": 6, "pose": "tpose"}))
    argv = option_argv(item, tmp_path)
    assert argv == ["--strategy", "viterbi", "--calibrate-from-start", "6", "--pose", "tpose"]
    _, args = parse_item_options(argv)
    assert (args.calibrate_from_start, args.pose, args.calibration) == (6.0, "tpose", None)
    (tmp_path / "cal.json").write_text("{}")
    path = tmp_path / "both.json"
    path.write_text(
        json.dumps(
            [
                {
                    "recording": "r.rec",
                    "graph": "g",
                    "strategy": "viterbi",
                    "output": "o",
                    "calibration": "cal.json",
                    "options": {"calibrate-from-start": 6, "pose": "npose"},
                }
            ]
        )
    )
    with pytest.raises(InputError, match="two ways to calibrate"):
        parse_item_options(option_argv(read_manifest(path)[0], tmp_path))
    with pytest.raises(InputError, match="needs --pose"):
        parse_item_options(option_argv(read_manifest(_one(tmp_path, {"calibrate-from-start": 6}))[0], tmp_path))


def _performer_json(path: Path, l_thigh: float) -> Path:
    path.write_text(json.dumps({"format": "graphsvc-performer", "version": 1, "segments_m": {"l_thigh": l_thigh}}))
    return path


def test_a_performer_or_a_height_is_an_item_option(tmp_path):
    graph = tmp_path / "g.graph"
    _small_graph(graph)
    (tmp_path / "r.rec").write_bytes(b"not a recording yet")
    _performer_json(tmp_path / "actor.json", 0.46)
    items = lambda opts: read_manifest(_one(tmp_path, opts))[0]  # noqa: E731
    plan = lambda opts: plan_item(items(opts), tmp_path, {"g": graph}, tmp_path, "v")  # noqa: E731
    tall = plan({"height": 1.9})
    assert tall.error is None and tall.task["argv"][-2:] == ["--height", "1.9"]
    actor = plan({"performer": "actor.json"})  # (from the manifest's folder)
    assert actor.error is None and actor.task["argv"][-2:] == ["--performer", str((tmp_path / "actor.json").resolve())]
    assert len({plan({}).fingerprint, tall.fingerprint, actor.fingerprint}) == 3
    _performer_json(tmp_path / "actor.json", 0.48)  # another performer in the same file: another fingerprint
    assert plan({"performer": "actor.json"}).fingerprint != actor.fingerprint
    for opts, needle in [
        ({"height": 1.9, "performer": "actor.json"}, "not allowed with argument"),
        ({"height": -1}, "--height"),
        ({"performer": "nobody.json"}, "no such file"),
        ({"performer-mapping": "guess"}, "performer-mapping applies"),
    ]:
        bad = plan(opts)
        assert bad.task is None and needle in bad.error, (opts, bad.error)
    (tmp_path / "bad.json").write_text('{"format": "graphsvc-performer", "version": 1, "segments_m": {"tail": 1}}')
    bad = plan({"performer": "bad.json"})
    assert bad.task is None and "unknown segments: tail" in bad.error


def test_an_item_on_a_performer_writes_its_proportions(tmp_path, batch_files):
    from graphsvc.batch.work import run_item
    from graphsvc.motion.bvh import read_bvh
    from graphsvc.motion.procedural.body import standard_skeleton
    from graphsvc.motion.proportions import SEGMENTS, segment_lengths

    (tmp_path / "m.json").write_text(
        json.dumps(
            [
                {
                    "recording": str(batch_files / "perf0.rec"),
                    "graph": "g",
                    "strategy": "nearest",
                    "output": "tall",
                    "options": {"height": 1.96},
                }
            ]
        )
    )
    (item,) = read_manifest(tmp_path / "m.json")
    p = plan_item(item, tmp_path, {"g": batch_files / "small.graph"}, tmp_path, "v")
    assert p.error is None, p.error
    done = run_item(p.task)
    assert "error" not in done, done
    got = segment_lengths(read_bvh(tmp_path / "tall.bvh").skeleton)
    kb = segment_lengths(standard_skeleton())
    for name in SEGMENTS:  # 1.96 / 1.75 = 1.12
        assert got[name] == pytest.approx(1.12 * kb[name], abs=1e-6), name
    assert json.loads((tmp_path / "tall.json").read_text())["performer"]["height_m"] == pytest.approx(1.96, abs=1e-4)

"""`graphsvc batch` end to end on a real two-worker LocalCluster: outputs equal to
`graphsvc synthesize`'s, a worker killed mid-item, a client killed mid-batch and
restarted, items that fail on their input, and bad input refused in one line."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
from distributed.diagnostics.plugin import WorkerPlugin

from graphsvc.cli import main
from tests.batch.conftest import write_manifest

ROOT = Path(__file__).resolve().parents[2]
VOLATILE = ("timings_s", "samples_per_s", "files")  # report fields that differ run to run or by path


def link_inputs(folder: Path, batch_files: Path) -> None:
    """The recordings beside the manifest (relative paths are the manifest folder's)."""
    for f in batch_files.glob("*.rec"):
        (folder / f.name).symlink_to(f)


def store_rows(out: Path) -> dict:
    con = sqlite3.connect(out / "batch.sqlite")
    con.row_factory = sqlite3.Row
    rows = {r["output"]: dict(r) for r in con.execute("SELECT * FROM items")}
    con.close()
    return rows


def leftovers(out: Path) -> list[str]:
    return sorted(p.name for p in out.iterdir() if p.name.endswith(".tmp"))


SIX = [  # every registered strategy, with the columns and options a manifest takes
    {"recording": "perf0.rec", "graph": "small", "strategy": "viterbi", "output": "v-weights", "weights": "0.5,1,1"},
    {
        "recording": "perf1.rec",
        "graph": "small",
        "strategy": "viterbi",
        "output": "v-beam-lag",
        "options": {"beam": 10, "latency": 0.5},
    },
    {
        "recording": "perf2.rec",
        "graph": "small",
        "strategy": "viterbi",
        "output": "v-track",
        "options": {"heading-from-track": True, "track_pull": 0},
    },
    {"recording": "perf0.rec", "graph": "small", "strategy": "nearest", "output": "nearest"},
    {"recording": "perf1.rec", "graph": "small", "strategy": "olng", "output": "olng", "options": {"olng-k": 32}},
    {"recording": "markers.rec", "graph": "small", "strategy": "ssg", "output": "ssg", "format": "glb"},
]


def output_name(row: dict) -> str:
    return f"{row['output']}.{row.get('format', 'bvh')}"


def synthesize_argv(row: dict, graph: Path, folder: Path, out: Path) -> list[str]:
    argv = [
        "synthesize",
        str(graph),
        str(folder / row["recording"]),
        "-o",
        str(out / output_name(row)),
        "--report",
        str(out / f"{row['output']}.json"),
        "--strategy",
        row["strategy"],
    ]
    if row.get("weights"):
        argv += ["--weights", row["weights"]]
    for k, v in row.get("options", {}).items():
        argv += [f"--{k.replace('_', '-')}"] + ([] if v is True else [str(v)])
    return argv


def test_six_items_on_two_workers_equal_synthesize_byte_for_byte(tmp_path, batch_files, cluster, capsys):
    link_inputs(tmp_path, batch_files)
    manifest = write_manifest(tmp_path / "match.csv", SIX)
    out = tmp_path / "out"
    graph = batch_files / "small.graph"
    code = main(
        [
            "batch",
            str(manifest),
            "--out",
            str(out),
            "--scheduler",
            cluster.scheduler_address,
            "--graph",
            f"small={graph}",
            "--quiet",
        ]
    )
    printed = capsys.readouterr().out
    assert code == 0, printed
    summary = json.loads((out / "summary.json").read_text())
    assert summary["totals"]["done"] == 6 and summary["failures"] == []
    assert [e["output"] for e in summary["items"]] == [r["output"] for r in SIX]
    assert summary["totals"]["samples"] == sum(e["samples"] for e in summary["items"])
    assert all(e["jitter_km_s3"] > 0 and e["skate_cm_s"] >= 0 for e in summary["items"])  # (what a viewer sees)
    ref = tmp_path / "ref"
    ref.mkdir()
    for row in SIX:
        assert main(synthesize_argv(row, graph, tmp_path, ref)) == 0
        name = row["output"]
        assert (out / output_name(row)).read_bytes() == (ref / output_name(row)).read_bytes(), name
        got, want = (json.loads((d / f"{name}.json").read_text()) for d in (out, ref))
        assert got["files"]["output"] == str((out / output_name(row)).resolve())
        assert {k: v for k, v in got.items() if k not in VOLATILE} == {
            k: v for k, v in want.items() if k not in VOLATILE
        }
    capsys.readouterr()
    rows = store_rows(out)
    assert {r["state"] for r in rows.values()} == {"done"} and {r["attempts"] for r in rows.values()} == {1}
    from graphsvc.fileio import file_sha256

    assert all(r["checksum"] == file_sha256(r["output_path"]) for r in rows.values())
    # The table: per item its seconds, samples/s and per-term costs.
    assert "acc_g2" in printed and "total: 6 items, 6 done" in printed
    # Run again: nothing changed, nothing recomputed.
    mtimes = {p.name: p.stat().st_mtime_ns for p in [*out.glob("*.bvh"), *out.glob("*.glb")]}
    assert len(mtimes) == 6 and (out / "ssg.glb").is_file()
    assert (
        main(
            [
                "batch",
                str(manifest),
                "--out",
                str(out),
                "--scheduler",
                cluster.scheduler_address,
                "--graph",
                f"small={graph}",
                "--quiet",
            ]
        )
        == 0
    )
    assert "6 done (6 unchanged, skipped)" in capsys.readouterr().out
    assert {p.name: p.stat().st_mtime_ns for p in [*out.glob("*.bvh"), *out.glob("*.glb")]} == mtimes
    assert store_rows(out) == rows
    # A changed option is a changed item: only it runs again.
    changed = [dict(r, weights="1,1,1") if r["output"] == "v-weights" else r for r in SIX]
    write_manifest(manifest, changed)
    assert (
        main(
            [
                "batch",
                str(manifest),
                "--out",
                str(out),
                "--scheduler",
                cluster.scheduler_address,
                "--graph",
                f"small={graph}",
                "--quiet",
            ]
        )
        == 0
    )
    after = store_rows(out)
    assert after["v-weights"]["fingerprint"] != rows["v-weights"]["fingerprint"]
    assert {k for k in after if after[k]["ended"] != rows[k]["ended"]} == {"v-weights"}


class KillOnStart(WorkerPlugin):
    """A worker plugin that kills its own process (SIGKILL, no clean-up) when the task
    of item `output` starts executing, once across the cluster (a marker file)."""

    name = "graphsvc-test-kill"

    def __init__(self, output: str, marker: str):
        self.output, self.marker = output, marker

    def setup(self, worker):
        pass

    def teardown(self, worker):
        pass

    def transition(self, key, start, finish, **kwargs):
        if finish == "executing" and f"graphsvc-batch-{self.output}-" in str(key):
            try:
                os.close(os.open(self.marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
            except FileExistsError:
                return
            os.kill(os.getpid(), signal.SIGKILL)


def run_killing(client, output: str, manifest: Path, tmp_path: Path, batch_files: Path, retries: int) -> dict:
    """run_batch into tmp_path/out while KillOnStart kills the worker that starts `output`."""
    from graphsvc.batch.run import kept_environ, run_batch

    with kept_environ():  # (what the nanny writes into ours when it restarts the killed worker)
        client.register_plugin(KillOnStart(output, str(tmp_path / "killed")), name=KillOnStart.name)
        try:
            return run_batch(
                manifest,
                tmp_path / "out",
                graphs={"small": batch_files / "small.graph"},
                client=client,
                retries=retries,
                progress=False,
            )
        finally:
            client.unregister_worker_plugin(KillOnStart.name)
            client.wait_for_workers(2, timeout=60)


def test_worker_killed_midway_every_item_done_with_the_extra_attempt(tmp_path, batch_files, client):
    link_inputs(tmp_path, batch_files)
    rows = [
        {
            "recording": f"perf{k % 4}.rec",
            "graph": "small",
            "strategy": ("viterbi", "nearest")[k % 2],
            "output": f"item{k}",
        }
        for k in range(6)
    ]
    manifest = write_manifest(tmp_path / "m.json", rows)
    summary = run_killing(client, "item3", manifest, tmp_path, batch_files, retries=2)
    assert (tmp_path / "killed").exists(), "the plugin never fired"
    out = tmp_path / "out"
    assert summary["totals"]["done"] == 6
    store = store_rows(out)
    assert {r["state"] for r in store.values()} == {"done"}
    assert store["item3"]["attempts"] == 2
    assert all(r["attempts"] >= 1 for r in store.values())
    assert leftovers(out) == []
    assert sorted(p.name for p in out.glob("*.bvh")) == [f"item{k}.bvh" for k in range(6)]
    # Each output is whole: the synthesize command's bytes.
    ref = tmp_path / "item3.bvh"
    assert (
        main(
            [
                "synthesize",
                str(batch_files / "small.graph"),
                str(tmp_path / "perf3.rec"),
                "-o",
                str(ref),
                "--strategy",
                "nearest",
            ]
        )
        == 0
    )
    assert (out / "item3.bvh").read_bytes() == ref.read_bytes()


def test_no_retries_left_the_item_fails_saying_its_worker_died(tmp_path, batch_files, client):
    link_inputs(tmp_path, batch_files)
    rows = [{"recording": f"perf{k}.rec", "graph": "small", "strategy": "nearest", "output": f"n{k}"} for k in range(3)]
    manifest = write_manifest(tmp_path / "m.json", rows)
    summary = run_killing(client, "n1", manifest, tmp_path, batch_files, retries=0)
    assert summary["failures"] == [{"output": "n1", "line": 2, "reason": "its worker died during the item"}]
    assert summary["totals"]["done"] == 2
    store = store_rows(tmp_path / "out")
    assert store["n1"]["state"] == "failed" and store["n1"]["attempts"] == 1
    assert not (tmp_path / "out" / "n1.bvh").exists() and leftovers(tmp_path / "out") == []


def test_client_killed_midway_restart_recomputes_nothing_done(tmp_path, batch_files, client):
    from graphsvc.batch.run import run_batch

    link_inputs(tmp_path, batch_files)
    rows = [
        {
            "recording": f"perf{3 - k % 2}.rec",
            "graph": "small",
            "strategy": "olng",
            "output": f"o{k}",
            "options": {"olng-k": 64},
        }
        for k in range(10)
    ]
    manifest = write_manifest(tmp_path / "m.csv", rows)
    out = tmp_path / "out"
    cmd = [
        sys.executable,
        "-c",
        "from graphsvc.cli import main; raise SystemExit(main())",
        "batch",
        str(manifest),
        "--out",
        str(out),
        "--workers",
        "1",
        "--graph",
        f"small={batch_files / 'small.graph'}",
        "--quiet",
    ]
    proc = subprocess.Popen(cmd, cwd=ROOT, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if (out / "batch.sqlite").exists() and sum(r["state"] == "done" for r in _rows_or_empty(out)) >= 2:
                break
            time.sleep(0.02)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the client, its scheduler and its worker: a machine gone
        proc.wait()
    assert proc.returncode == -signal.SIGKILL, proc.stderr.read().decode()
    before = store_rows(out)
    done = {k for k, r in before.items() if r["state"] == "done"}
    assert 2 <= len(done) < 10
    assert "running" in {r["state"] for r in before.values()}
    mtimes = {k: (out / f"{k}.bvh").stat().st_mtime_ns for k in done}
    summary = run_batch(manifest, out, graphs={"small": batch_files / "small.graph"}, client=client, progress=False)
    assert summary["totals"]["done"] == 10 and summary["totals"]["skipped"] == len(done)
    after = store_rows(out)
    for k in done:  # not recomputed
        assert after[k] == before[k]
        assert (out / f"{k}.bvh").stat().st_mtime_ns == mtimes[k]
    for k in set(after) - done:  # handed out when the client died: queued again, one more attempt
        assert after[k]["state"] == "done" and after[k]["attempts"] == before[k]["attempts"] + 1
    assert leftovers(out) == []


def _rows_or_empty(out: Path) -> list:
    try:
        return list(store_rows(out).values())
    except sqlite3.Error:
        return []


def test_items_that_fail_on_their_input_the_rest_finish(tmp_path, batch_files, cluster, capsys):
    link_inputs(tmp_path, batch_files)
    rows = [
        {"recording": "perf0.rec", "graph": "small", "strategy": "viterbi", "output": "good1"},
        {"recording": "absent.rec", "graph": "small", "strategy": "viterbi", "output": "no-recording"},
        {"recording": "perf1.rec", "graph": "nosuch", "strategy": "viterbi", "output": "no-graph"},
        {
            "recording": "perf1.rec",
            "graph": "small",
            "strategy": "viterbi",
            "output": "bad-beam",
            "options": {"beam": -1},
        },
        {
            "recording": "perf1.rec",
            "graph": "small",
            "strategy": "viterbi",
            "output": "bad-flag",
            "options": {"frobnicate": 3},
        },
        {"recording": "markers.rec", "graph": "small", "strategy": "viterbi", "output": "no-accelerations"},
        {"recording": "small.graph", "graph": "small", "strategy": "nearest", "output": "not-a-recording"},
        {"recording": "perf2.rec", "graph": "small.graph", "strategy": "nearest", "output": "good2"},
    ]
    (tmp_path / "small.graph").symlink_to(batch_files / "small.graph")
    manifest = write_manifest(tmp_path / "m.csv", rows)
    out = tmp_path / "out"
    code = main(
        [
            "batch",
            str(manifest),
            "--out",
            str(out),
            "--scheduler",
            cluster.scheduler_address,
            "--graph",
            f"small={batch_files / 'small.graph'}",
            "--quiet",
        ]
    )
    captured = capsys.readouterr()
    assert code == 1
    assert "graphsvc: 6 of 8 items failed" in captured.err
    store = store_rows(out)
    assert {k for k, r in store.items() if r["state"] == "done"} == {"good1", "good2"}
    reasons = {k: r["reason"] for k, r in store.items() if r["state"] == "failed"}
    assert "absent.rec: no such file" in reasons["no-recording"]
    assert "unknown graph 'nosuch'" in reasons["no-graph"]
    assert "beam must be a finite cost > 0" in reasons["bad-beam"]
    assert "unrecognized arguments: --frobnicate" in reasons["bad-flag"]
    assert "accelerations" in reasons["no-accelerations"]
    assert reasons["not-a-recording"]
    assert all(r["attempts"] == 1 for r in store.values())  # input failures are not retried
    assert all("\n" not in r for r in reasons.values())
    summary = json.loads((out / "summary.json").read_text())
    assert {f["output"]: f["line"] for f in summary["failures"]} == {
        "no-recording": 3,
        "no-graph": 4,
        "bad-beam": 5,
        "bad-flag": 6,
        "no-accelerations": 7,
        "not-a-recording": 8,
    }
    for name in reasons:
        assert f"failed: {name} (line" in captured.out
        assert not (out / f"{name}.bvh").exists()


@pytest.mark.parametrize(
    "case, needle",
    [
        ("unparsable", "m.csv:3: 3 fields, the header has 4"),
        ("quote", "m.csv:3: not valid CSV"),
        ("duplicate", "m.csv:3: output 'a' is also line 2's"),
        ("column", "unknown column 'colour'"),
        ("missing-column", "the header lacks column 'strategy'"),
        ("bad-name", "m.csv:2: output 'x/y' must be a plain name"),
        ("options-json", "m.csv:2: options are not valid JSON"),
        ("unwritable", "is not writable"),
        ("scheduler", "scheduler tcp://127.0.0.1:1 did not answer within 1 s"),
        ("retries", "--retries must be ≥ 0"),
        ("graph-spec", "--graph takes NAME=FILE"),
    ],
)
def test_bad_input_one_line_exit_2_nothing_written(tmp_path, capsys, case, needle):
    header = "recording,graph,strategy,output"
    body = {
        "unparsable": f"{header}\na.rec,g,viterbi,a\na.rec,g,viterbi\n",
        "quote": f'{header}\na.rec,g,viterbi,a\n"a.rec,g,viterbi,b\n',
        "duplicate": f"{header}\na.rec,g,viterbi,a\nb.rec,g,viterbi,a\n",
        "column": f"{header},colour\na.rec,g,viterbi,a,red\n",
        "missing-column": "recording,graph,output\na.rec,g,a\n",
        "bad-name": f"{header}\na.rec,g,viterbi,x/y\n",
        "options-json": f"{header},options\na.rec,g,viterbi,a,{{beam\n",
    }.get(case, f"{header}\na.rec,g,viterbi,a\n")
    (tmp_path / "m.csv").write_text(body)
    out = tmp_path / "out"
    argv = ["batch", str(tmp_path / "m.csv"), "--out", str(out), "--quiet", "--workers", "1"]
    if case == "unwritable":
        (tmp_path / "file").write_text("x")
        out = tmp_path / "file" / "out"
        argv[3] = str(out)
    if case == "scheduler":
        argv[-2:] = ["--scheduler", "tcp://127.0.0.1:1", "--timeout", "1"]
    if case == "retries":
        argv += ["--retries", "-1"]
    if case == "graph-spec":
        argv += ["--graph", "small"]
    before = sorted(p.name for p in tmp_path.iterdir())
    t0 = time.monotonic()
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2
    assert needle in err and err.count("\n") == 1 and err.startswith("graphsvc: error: ")
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert time.monotonic() - t0 < 8


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root writes into any folder")
def test_read_only_output_folder_refused(tmp_path, capsys):
    (tmp_path / "m.csv").write_text("recording,graph,strategy,output\na.rec,g,viterbi,a\n")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        assert main(["batch", str(tmp_path / "m.csv"), "--out", str(ro), "--workers", "1"]) == 2
    finally:
        ro.chmod(0o755)
    assert "is not writable" in capsys.readouterr().err and list(ro.iterdir()) == []

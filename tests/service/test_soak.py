"""A few seconds of tools/soak_service.py on the procedural graph: churn of every
kind, then no leaked stream slot, thread or health failure."""

from __future__ import annotations

import json
import subprocess
import sys

from tests.service.conftest import ROOT, _env


def test_a_short_soak_leaks_no_slot_or_thread(graph_file):
    run = subprocess.run(
        [
            sys.executable,
            str(ROOT / "tools" / "soak_service.py"),
            str(graph_file),
            "--seconds",
            "5",
            "--streams",
            "8",
            "--max-streams",
            "4",
            "--processes",
            "1",
            "--config-timeout-s",
            "0.5",
            "--sample-every",
            "0.5",
            "--seed",
            "3",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        env=_env(),
        check=False,
    )
    assert run.stdout.strip(), run.stderr[-2000:]
    result = json.loads(run.stdout)
    assert result["checks"]["no_slot_leaked"] and result["slots_probe"] == {"started": 4, "of": 4}
    assert result["checks"]["threads_bounded"], result["threads"]
    assert result["checks"]["health_serving_throughout"] and result["health"]["SERVING"] >= 3
    assert result["unexpected"]["count"] == 0, result["unexpected"]
    assert result["rejected_ms"]["max"] < 1000.0
    assert result["server_exit"] == 0
    assert result["ok"] and run.returncode == 0
    # The churn happened: well-formed streams served in full, more streams than slots
    # refused, and several kinds of failure answered.
    calls = result["calls"]
    assert calls["complete"].get("OK", 0) >= 1
    refused = sum(by.get("RESOURCE_EXHAUSTED", 0) for by in calls.values())
    assert refused >= 1
    failures = {status for by in calls.values() for status in by} - {"OK", "RESOURCE_EXHAUSTED"}
    assert len(failures) >= 3, calls

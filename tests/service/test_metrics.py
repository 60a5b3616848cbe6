"""`serve --metrics-port`: the Prometheus endpoint scraped during a stream (its
counters and histograms move with the samples), refusals by code, the load and
process figures, the Grafana dashboard's queries naming only metrics the server has,
and a bad port: one line, exit 2. (The live-worker figures: test_live_workers.py.)"""

from __future__ import annotations

import json
import os
import re
import socket
import threading

import grpc
import pytest

from graphsvc.service import client as C
from graphsvc.service._generated import graphsvc_pb2 as pb
from tests.service.conftest import ROOT, nearest_options, rpc_error, scrape, start, wait_for


@pytest.fixture(scope="module")
def metered(loaded_graphs):
    running = start(loaded_graphs, max_streams=2, metrics_port=0)
    yield running
    running.stop(0)


def test_a_scrape_during_a_stream_sees_the_counters_move(metered, recording):
    port = metered.metrics.port
    before = scrape(port)
    assert before[("graphsvc_streams_open", ())] == 0
    assert before[("graphsvc_graph_load_seconds", (("graph", "small"),))] > 0
    assert before[("graphsvc_start_seconds", ())] > 0
    front = {k: v for k, v in before.items() if k[0] == "graphsvc_process_cpu_seconds_total"}
    assert list(front) == [
        ("graphsvc_process_cpu_seconds_total", (("pid", str(os.getpid())), ("role", "front"), ("worker", "")))
    ]
    assert next(iter(front.values())) > 0
    samples = list(C.recording_samples(recording))
    with C.connect(f"127.0.0.1:{metered.port}") as conn:
        feed = C.SampleFeed(C.stream_config("small", nearest_options()))
        out = {}
        thread = threading.Thread(target=lambda: out.setdefault("r", C.run_stream(conn, feed, timeout_s=60)))
        thread.start()
        for s in samples[:40]:
            feed.put(s)
        wait_for(lambda: scrape(port)[("graphsvc_samples_total", ())] == 40, timeout_s=30)
        during = scrape(port)
        assert during[("graphsvc_streams_open", ())] == 1
        assert during[("graphsvc_streams_started_total", ())] == 1
        assert during[("graphsvc_push_seconds_count", ())] == 40
        assert during[("graphsvc_sample_seconds_count", ())] == 40
        assert during[("graphsvc_push_seconds_sum", ())] > 0
        assert during[("graphsvc_sample_seconds_sum", ())] >= during[("graphsvc_push_seconds_sum", ())]
        assert during[("graphsvc_push_seconds_bucket", (("le", "+Inf"),))] == 40
        for s in samples[40:]:
            feed.put(s)
        feed.close()
        thread.join(60)
        result = out["r"]
    after = scrape(port)
    assert after[("graphsvc_samples_total", ())] == len(samples) == result.finished.samples_received
    assert after[("graphsvc_frames_total", ())] == len(result.frames) > during[("graphsvc_frames_total", ())]
    assert after[("graphsvc_streams_open", ())] == 0
    assert not any(k[0] == "graphsvc_refusals_total" for k in after)


def test_refusals_are_counted_by_code(metered):
    port = metered.metrics.port
    with C.connect(f"127.0.0.1:{metered.port}") as conn:
        code, _ = rpc_error(conn.stub.GetGraph, pb.GetGraphRequest(name="nope"), timeout=10)
        assert code == grpc.StatusCode.NOT_FOUND
        feeds = [C.SampleFeed(C.stream_config("small")) for _ in range(3)]
        responses = [iter(conn.stub.StreamSynthesize(iter(f))) for f in feeds[:2]]
        assert [next(r).WhichOneof("message") for r in responses] == ["started", "started"]
        code, _ = rpc_error(lambda: list(conn.stub.StreamSynthesize(iter(feeds[2]))))  # beyond --max-streams 2
        assert code == grpc.StatusCode.RESOURCE_EXHAUSTED
        for f in feeds:
            f.close()
        for r in responses:
            list(r)
    counted = scrape(port)
    assert counted[("graphsvc_refusals_total", (("code", "NOT_FOUND"),))] == 1
    assert counted[("graphsvc_refusals_total", (("code", "RESOURCE_EXHAUSTED"),))] == 1


def test_the_dashboard_queries_only_metrics_the_server_has(metered):
    dashboard = json.loads((ROOT / "deploy" / "grafana-dashboard.json").read_text())
    exprs = [t["expr"] for p in dashboard["panels"] for t in p.get("targets", [])]
    assert len(exprs) >= 8
    named = {m for e in exprs for m in re.findall(r"\b(graphsvc_[a-z_]+)", e)}
    served = {k[0] for k in scrape(metered.metrics.port)} | {"graphsvc_refusals_total"}  # (none refused yet, maybe)
    assert named and named <= served, named - served


def test_a_bad_metrics_port_is_one_line(graph_file, capsys):
    from graphsvc.cli import main

    serve = ["serve", "--graph", f"small={graph_file}", "--host", "127.0.0.1", "--port", "0", "--metrics-port"]
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert main([*serve, str(port)]) == 2  # (refused before any graph loads)
    printed = capsys.readouterr()
    assert printed.out == ""
    assert printed.err == f"graphsvc: error: cannot serve metrics on 127.0.0.1:{port}: Address already in use\n"
    with pytest.raises(SystemExit) as exit_:
        main([*serve, "70000"])
    printed = capsys.readouterr()
    assert exit_.value.code == 2 and len(printed.err.splitlines()) == 1 and "--metrics-port" in printed.err, printed.err

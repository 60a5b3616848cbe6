"""Batches through the gRPC service: SubmitBatch, GetBatch, ListBatches, CancelBatch
on a real server on loopback, running on the tests' LocalCluster; and `graphsvc
client batch`."""

from __future__ import annotations

import json
import time
from pathlib import Path

import grpc
import pytest

from graphsvc.cli import main
from tests.batch.conftest import write_manifest
from tests.batch.test_batch import link_inputs


@pytest.fixture(scope="module")
def batch_root(tmp_path_factory, batch_files) -> Path:
    root = tmp_path_factory.mktemp("batches")
    link_inputs(root, batch_files)
    return root


@pytest.fixture(scope="module")
def server(batch_files, batch_root, cluster):
    from graphsvc.graph.file import load_graph
    from graphsvc.service.convert import graph_info
    from graphsvc.service.server import LoadedGraph, ServerConfig, start_server

    path = batch_files / "small.graph"
    graph = load_graph(path)
    graphs = {"small": LoadedGraph("small", path, graph, graph_info("small", graph, path.stat().st_size))}
    running = start_server(
        graphs, ServerConfig(host="127.0.0.1", port=0, batch_dir=batch_root, batch_scheduler=cluster.scheduler_address)
    )
    yield running
    running.stop(0)


@pytest.fixture
def conn(server):
    from graphsvc.service.client import connect

    with connect(f"127.0.0.1:{server.port}") as c:
        yield c


def poll(conn, batch_id, timeout_s=120.0, items=False):
    from graphsvc.service._generated import graphsvc_pb2 as pb
    from graphsvc.service.client import batch_call

    deadline = time.monotonic() + timeout_s
    while True:
        status = batch_call(conn, "GetBatch", pb.GetBatchRequest(batch_id=batch_id, items=items))
        if status.state not in ("queued", "running") or time.monotonic() > deadline:
            return status
        time.sleep(0.1)


def test_submit_poll_list_one_output_equals_synthesize(conn, batch_files, batch_root, tmp_path, capsys):
    from graphsvc.service._generated import graphsvc_pb2 as pb
    from graphsvc.service.client import batch_call, submit_batch

    rows = [
        {"recording": "perf0.rec", "graph": "small", "strategy": "viterbi", "output": "v", "weights": "0.5,1,1"},
        {"recording": "perf1.rec", "graph": "small", "strategy": "nearest", "output": "n"},
        {"recording": "absent.rec", "graph": "small", "strategy": "nearest", "output": "missing"},
    ]
    text = write_manifest(tmp_path / "m.csv", rows).read_text()
    status = submit_batch(conn, text)
    assert status.state in ("queued", "running") and status.items == 3
    status = poll(conn, status.batch_id, items=True)
    assert (status.state, status.done, status.failed, status.queued, status.running) == ("finished", 2, 1, 0, 0)
    by_name = {i.output: i for i in status.item_status}
    assert "absent.rec: no such file" in by_name["missing"].reason and by_name["v"].attempts == 1
    ref = tmp_path / "v.bvh"
    assert (
        main(
            [
                "synthesize",
                str(batch_files / "small.graph"),
                str(batch_root / "perf0.rec"),
                "-o",
                str(ref),
                "--weights",
                "0.5,1,1",
            ]
        )
        == 0
    )
    assert Path(by_name["v"].output_path).read_bytes() == ref.read_bytes()
    assert Path(by_name["v"].output_path).parent == Path(status.folder)
    listed = batch_call(conn, "ListBatches", pb.ListBatchesRequest()).batches
    assert status.batch_id in [b.batch_id for b in listed] and not any(b.item_status for b in listed)
    # The client command, on the same batch.
    capsys.readouterr()
    server = conn.address
    assert main(["client", "batch", "status", status.batch_id, "--items", "--server", server]) == 1  # an item failed
    out = capsys.readouterr().out
    assert f"{status.batch_id}: finished, 3 items: 2 done, 1 failed" in out and "missing (line 4): failed" in out
    assert main(["client", "batch", "list", "--json", "--server", server]) == 0
    assert status.batch_id in [b["batch_id"] for b in json.loads(capsys.readouterr().out)]
    one = write_manifest(tmp_path / "one.json", rows[1:2])
    assert main(["client", "batch", "submit", str(one), "--wait", "--poll", "0.1", "--json", "--server", server]) == 0
    done = json.loads(capsys.readouterr().out)
    assert (done["state"], done["done"], done["items"]) == ("finished", 1, 1)
    assert Path(done["folder"], "n.bvh").read_bytes() == Path(by_name["n"].output_path).read_bytes()


def test_cancel_queues_the_unfinished_items(conn, tmp_path):
    from graphsvc.service._generated import graphsvc_pb2 as pb
    from graphsvc.service.client import batch_call, submit_batch

    rows = [
        {"recording": "perf3.rec", "graph": "small", "strategy": "olng", "output": f"o{k}", "options": {"olng-k": 64}}
        for k in range(12)
    ]
    status = submit_batch(conn, json.dumps(rows), retries=0)
    deadline = time.monotonic() + 60
    while status.done == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
        status = batch_call(conn, "GetBatch", pb.GetBatchRequest(batch_id=status.batch_id))
    status = batch_call(conn, "CancelBatch", pb.CancelBatchRequest(batch_id=status.batch_id))
    assert status.state == "cancelled"
    assert 1 <= status.done < 12 and status.queued == 12 - status.done and status.running == 0


@pytest.mark.parametrize(
    "call, request_kwargs, code, needle",
    [
        (
            "SubmitBatch",
            {"manifest": "recording,graph,strategy,output\na.rec,small,viterbi\n"},
            grpc.StatusCode.INVALID_ARGUMENT,
            "manifest.csv:2: 3 fields, the header has 4",
        ),
        ("SubmitBatch", {"manifest": '[{"recording": 1}]'}, grpc.StatusCode.INVALID_ARGUMENT, "recording must be text"),
        (
            "SubmitBatch",
            {"manifest": "x", "format": "xml"},
            grpc.StatusCode.INVALID_ARGUMENT,
            "format must be csv or json",
        ),
        ("GetBatch", {"batch_id": "nope"}, grpc.StatusCode.NOT_FOUND, "no batch 'nope'"),
        ("CancelBatch", {"batch_id": "../x"}, grpc.StatusCode.NOT_FOUND, "no batch"),
    ],
)
def test_batch_errors_answer_their_status(conn, batch_root, call, request_kwargs, code, needle):
    from graphsvc.service._generated import graphsvc_pb2 as pb
    from graphsvc.service.client import ServiceError, batch_call

    before = sorted(p.name for p in batch_root.iterdir())
    request = getattr(
        pb,
        {"SubmitBatch": "SubmitBatchRequest", "GetBatch": "GetBatchRequest", "CancelBatch": "CancelBatchRequest"}[call],
    )(**request_kwargs)
    with pytest.raises(ServiceError) as err:
        batch_call(conn, call, request)
    assert err.value.code == code and needle in err.value.details
    assert sorted(p.name for p in batch_root.iterdir()) == before  # nothing half-made


def test_server_without_batch_dir_refuses_batches(batch_files):
    from graphsvc.graph.file import load_graph
    from graphsvc.service._generated import graphsvc_pb2 as pb
    from graphsvc.service.client import ServiceError, batch_call, connect
    from graphsvc.service.convert import graph_info
    from graphsvc.service.server import LoadedGraph, ServerConfig, start_server

    path = batch_files / "small.graph"
    graph = load_graph(path)
    running = start_server(
        {"small": LoadedGraph("small", path, graph, graph_info("small", graph, None))},
        ServerConfig(host="127.0.0.1", port=0),
    )
    try:
        with connect(f"127.0.0.1:{running.port}") as c, pytest.raises(ServiceError) as err:
            batch_call(c, "ListBatches", pb.ListBatchesRequest())
        assert err.value.code == grpc.StatusCode.FAILED_PRECONDITION and "--batch-dir" in err.value.details
    finally:
        running.stop(0)

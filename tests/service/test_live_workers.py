"""Live sessions in worker processes (`service.live_workers`): the same frames as a
session in the server's process, streams spread over the workers, a worker that dies
ends only its own streams (UNAVAILABLE) and is replaced, bad input still answered
with the right status, and no process left after stop."""

from __future__ import annotations

import os
import signal
import threading

import grpc
import pytest

from graphsvc.service import client as C
from graphsvc.service import convert
from graphsvc.service._generated import graphsvc_pb2 as pb
from tests.service.conftest import assert_frames_equal, live_frames, rpc_error, scrape, start, wait_for


@pytest.fixture(scope="module")
def worker_server(loaded_graphs):
    running = start(loaded_graphs, max_streams=6, live_workers=2, metrics_port=0)
    running.servicer.live_workers.restart_delay_s = 0.2
    yield running
    pids = running.servicer.live_workers.pids()
    running.stop(0)
    assert pids and not any(_alive(pid) for pid in pids)  # (stop waits for them)


@pytest.fixture
def wconn(worker_server):
    with C.connect(f"127.0.0.1:{worker_server.port}") as c:
        yield c


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def _whole_feed(recording, options=None) -> C.SampleFeed:
    feed = C.SampleFeed(C.stream_config("small", options))
    for sample in C.recording_samples(recording):
        feed.put(sample)
    feed.close()
    return feed


def test_workers_are_processes_of_their_own(worker_server):
    pids = worker_server.servicer.live_workers.pids()
    assert len(pids) == 2 and os.getpid() not in pids and all(_alive(p) for p in pids)


def _options(kind: str):
    from graphsvc.pipeline import Options
    from graphsvc.strategies.olng.options import OlngOptions

    return {
        "viterbi": Options(latency_s=0.4, beam=10.0),
        "nearest": Options(strategy="nearest"),
        "olng": Options(strategy="olng", olng=OlngOptions(k=24, i=6, m=12, extended=False)),
    }[kind]


@pytest.mark.parametrize("kind", ["viterbi", "nearest", "olng"])
def test_a_stream_in_a_worker_matches_a_session_here(wconn, graph, recording, kind):
    options = _options(kind)
    expected, session = live_frames(graph, recording, options)
    result = C.run_stream(wconn, _whole_feed(recording, convert.options_to_proto(options)))
    assert result.started.lag_frames == session.lag_frames
    assert_frames_equal(expected, result.frames)
    assert [[(s.clip, s.frame, s.weight) for s in f.sources] for f in result.frames] == [
        [(c, pytest.approx(fr), pytest.approx(w)) for c, fr, w in f.sources] for f in expected
    ]
    assert result.finished.samples_received == recording.num_samples
    assert result.finished.frames_emitted == len(expected)


def test_concurrent_streams_spread_over_the_workers_and_stay_independent(worker_server, wconn, graph, recording):
    from graphsvc.pipeline import Options

    expected, _ = live_frames(graph, recording, Options())
    workers = worker_server.servicer.live_workers
    feeds = [C.SampleFeed(C.stream_config("small")) for _ in range(4)]
    results = [None] * 4

    def run(i):
        results[i] = C.run_stream(wconn, feeds[i], timeout_s=60)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    wait_for(lambda: workers.sessions() == 4, timeout_s=30)
    assert sorted(len(w.sessions) for w in workers._workers) == [2, 2]  # each new one to the worker with fewest
    for feed in feeds:
        for sample in C.recording_samples(recording):
            feed.put(sample)
        feed.close()
    for t in threads:
        t.join(60)
    for result in results:
        assert_frames_equal(expected, result.frames)
    wait_for(lambda: workers.sessions() == 0)  # every session freed in its worker


def test_bad_input_gets_the_same_status_through_a_worker(worker_server, wconn, recording):
    samples = list(C.recording_samples(recording))[:4]
    unknown_label = pb.SynthesisOptions(
        constraint_sets=[pb.ConstraintSet(constraints=[pb.Constraint(start_s=0.0, end_s=1.0, label="no-such-label")])]
    )
    cases = {  # (the config is refused in the worker; the sample in the server's process)
        "label": ([pb.StreamSynthesizeRequest(config=C.stream_config("small", unknown_label))], "config.options"),
        "sample": (
            [
                pb.StreamSynthesizeRequest(config=C.stream_config("small")),
                pb.StreamSynthesizeRequest(sample=pb.SensorSample(time_s=0.0, accelerations_m_s2=[0.0] * 17)),
            ],
            "sample[0].accelerations_m_s2",
        ),
    }
    for name, (requests, mention) in cases.items():
        code, details = rpc_error(lambda r=requests: list(wconn.stub.StreamSynthesize(iter(r), timeout=30)))
        assert code == grpc.StatusCode.INVALID_ARGUMENT and mention in details, (name, code, details)
    code, details = rpc_error(
        lambda: list(
            wconn.stub.StreamSynthesize(
                iter(
                    [
                        pb.StreamSynthesizeRequest(config=C.stream_config("small")),
                        *[pb.StreamSynthesizeRequest(sample=s) for s in samples[:2]],
                        pb.StreamSynthesizeRequest(sample=samples[1]),
                    ]
                ),
                timeout=30,
            )
        )
    )
    assert code == grpc.StatusCode.INVALID_ARGUMENT and "sample[2].time_s" in details
    wait_for(lambda: worker_server.servicer.live_workers.sessions() == 0)
    wait_for(lambda: worker_server.servicer.slots.active == 0)


def test_a_cancelled_stream_frees_its_session_in_the_worker(worker_server, wconn, recording):
    feed = C.SampleFeed(C.stream_config("small"))
    call = wconn.stub.StreamSynthesize(iter(feed), metadata=wconn.metadata)
    responses = iter(call)
    assert next(responses).WhichOneof("message") == "started"
    for s in list(C.recording_samples(recording))[:5]:
        feed.put(s)
    wait_for(lambda: worker_server.servicer.live_workers.sessions() == 1)
    call.cancel()
    feed.close()
    wait_for(lambda: worker_server.servicer.live_workers.sessions() == 0)
    wait_for(lambda: worker_server.servicer.slots.active == 0)


def test_a_killed_worker_ends_its_streams_unavailable_and_is_replaced(worker_server, wconn, graph, recording):
    from graphsvc.pipeline import Options

    workers = worker_server.servicer.live_workers
    replaced = workers.replaced
    feed = C.SampleFeed(C.stream_config("small"))
    outcome = {}

    def run():
        try:
            outcome["result"] = C.run_stream(wconn, feed, timeout_s=60)
        except C.ServiceError as exc:
            outcome["error"] = exc

    thread = threading.Thread(target=run)
    thread.start()
    samples = list(C.recording_samples(recording))
    for s in samples[:5]:
        feed.put(s)
    wait_for(lambda: workers.sessions() == 1, timeout_s=30)
    victim = next(w for w in workers._workers if w.sessions)
    os.kill(victim.pid, signal.SIGKILL)
    for s in samples[5:]:
        feed.put(s)
    feed.close()
    thread.join(60)
    error = outcome["error"]
    assert error.code == grpc.StatusCode.UNAVAILABLE
    assert f"live worker process {victim.pid}" in str(error) and "killed by signal 9" in str(error)
    wait_for(lambda: workers.replaced == replaced + 1 and len(workers.pids()) == 2, timeout_s=120)
    assert victim.pid not in workers.pids()
    # What an operator sees: the restart, the refusal, each worker's CPU and memory by its slot.
    seen = scrape(worker_server.metrics.port)
    assert seen[("graphsvc_live_worker_restarts_total", ())] == workers.replaced == replaced + 1
    assert seen[("graphsvc_refusals_total", (("code", "UNAVAILABLE"),))] >= 1
    for kind in ("graphsvc_process_cpu_seconds_total", "graphsvc_process_resident_bytes"):
        series = {
            dict(labels)["pid"]: (dict(labels)["worker"], v)
            for (name, labels), v in seen.items()
            if name == kind and dict(labels)["role"] == "worker"
        }
        assert {int(p): w for p, (w, _) in series.items()} == {w.pid: str(w.index) for w in workers._workers}
        assert all(v > 0 for _, v in series.values())
    expected, _ = live_frames(graph, recording, Options())
    assert_frames_equal(expected, C.run_stream(wconn, _whole_feed(recording), timeout_s=60).frames)


def test_a_worker_that_cannot_load_its_graphs_stops_the_start(tmp_path):
    from graphsvc.errors import GraphsvcError
    from graphsvc.service.live_workers import LiveWorkers

    workers = LiveWorkers({"gone": tmp_path / "gone.graph"}, 1)
    with pytest.raises(GraphsvcError, match="could not load the graphs: .*gone.graph"):
        workers.start()


def test_a_worker_whose_graph_is_not_the_verified_one_is_refused(graph_file, graph):
    from graphsvc.errors import GraphsvcError
    from graphsvc.service.live_workers import LiveWorkers

    workers = LiveWorkers({"g": graph_file}, 1)
    workers.expect({"g": "0" * 64})  # (what the front would have verified: other bytes)
    with pytest.raises(GraphsvcError, match="the graph file of g is not the one the server verified"):
        workers.start()
    workers.stop()
    workers = LiveWorkers({"g": graph_file}, 1)
    workers.expect({"g": graph.checksum})
    workers.start()
    try:
        assert len(workers.pids()) == 1
    finally:
        workers.stop()


def test_the_default_count_is_one_a_core_and_none_on_one_core(monkeypatch):
    from graphsvc.service import live_workers

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2})
    assert live_workers.default_count() == 3
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})
    assert live_workers.default_count() == 0


def test_a_starting_session_does_not_hold_up_the_others(graph_file, graph, recording, monkeypatch):
    # A worker run as a thread of this process, so that its sessions' push can be held:
    # a session's first seconds go to the side thread, and while one is held there an
    # established session's sample is still answered.
    from multiprocessing import Pipe

    from graphsvc.pipeline import LiveSession, Options
    from graphsvc.service import live_workers

    front, back = Pipe()
    worker = threading.Thread(target=live_workers._worker_main, args=(back, {"small": str(graph_file)}), daemon=True)
    worker.start()
    assert front.poll(120) and front.recv()[1] == "ok"
    names = tuple(recording.sensor_names)

    def call(op, sid, payload):
        front.send((op, sid, payload))
        assert front.poll(60)
        return front.recv()

    def sample(k):
        return (
            False,
            (recording.timestamps_s[k], recording.accelerations[k], recording.ground_position[k], recording.heading[k]),
            {},
        )

    young = round(live_workers.YOUNG_S * graph.rate_hz)
    assert young < recording.num_samples
    assert call("open", 1, ("small", Options(), names, (), False))[:2] == (1, "ok")
    for k in range(young):
        assert call("push", 1, sample(k))[:2] == (1, "ok")
    release = threading.Event()
    push = LiveSession.push

    def held(self, *args, **kwargs):
        if threading.current_thread().name == "graphsvc-live-side":
            release.wait(60)
        return push(self, *args, **kwargs)

    monkeypatch.setattr(LiveSession, "push", held)
    assert call("open", 2, ("small", Options(), names, (), False))[:2] == (2, "ok")
    front.send(("push", 2, sample(0)))  # held on the side thread
    assert call("push", 1, sample(young))[:2] == (1, "ok")  # answered meanwhile
    release.set()
    assert front.poll(60) and front.recv()[:2] == (2, "ok")
    front.send(("stop", 0, None))
    worker.join(30)
    assert not worker.is_alive()

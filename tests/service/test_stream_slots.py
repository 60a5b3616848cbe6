"""Live-stream slots under churn: a stream that never sends its config is ended by the
configuration timeout, a stream beyond the limit is refused at once, and a configured
stream that pauses keeps its slot and resumes."""

from __future__ import annotations

import queue
import threading
import time

import grpc
import pytest

from graphsvc.errors import InputError
from graphsvc.service import client as C
from graphsvc.service._generated import graphsvc_pb2 as pb
from tests.service.conftest import start
from tests.service.conftest import wait_for as _wait_for


def _config_reader_threads() -> int:
    return sum(1 for t in threading.enumerate() if t.name == "graphsvc-config")


class _Requests:
    """A request iterator fed by hand; close() ends it (the client half-closes)."""

    def __init__(self):
        self._queue: queue.Queue = queue.Queue()

    def put(self, request) -> None:
        self._queue.put(request)

    def close(self) -> None:
        self._queue.put(None)

    def __iter__(self):
        while (item := self._queue.get()) is not None:
            yield item


@pytest.fixture
def tight_server(loaded_graphs):
    """One stream slot, a 0.5 s configuration timeout."""
    running = start(loaded_graphs, max_streams=1, config_timeout_s=0.5)
    yield running
    running.stop(0)


def test_a_stream_without_config_is_ended_and_frees_its_slot(tight_server, recording):
    with C.connect(f"127.0.0.1:{tight_server.port}") as conn:
        silent = _Requests()
        call = conn.stub.StreamSynthesize(iter(silent), timeout=30)
        t0 = time.monotonic()
        with pytest.raises(grpc.RpcError) as info:
            list(call)
        waited = time.monotonic() - t0
        silent.close()
        assert info.value.code() == grpc.StatusCode.DEADLINE_EXCEEDED
        assert "--config-timeout-s" in info.value.details()
        assert 0.4 < waited < 5.0  # the server's 0.5 s, not the client's 30 s deadline
        _wait_for(lambda: tight_server.servicer.slots.active == 0)
        _wait_for(lambda: _config_reader_threads() == 0)  # the reader ended with the call
        # The slot serves the next stream in full.
        result = C.stream_recording(conn, "small", recording, timeout_s=60)
        assert result.finished.samples_received == recording.num_samples


def test_a_config_in_time_is_served_and_leaves_no_reader_behind(tight_server, recording):
    with C.connect(f"127.0.0.1:{tight_server.port}") as conn:
        requests = _Requests()
        call = conn.stub.StreamSynthesize(iter(requests), timeout=30)
        time.sleep(0.2)  # inside the timeout
        requests.put(pb.StreamSynthesizeRequest(config=C.stream_config("small")))
        responses = iter(call)
        assert next(responses).WhichOneof("message") == "started"
        _wait_for(lambda: _config_reader_threads() == 0)
        for s in C.recording_samples(recording):
            requests.put(pb.StreamSynthesizeRequest(sample=s))
        requests.close()
        kinds = [r.WhichOneof("message") for r in responses]
        assert kinds[-1] == "finished" and kinds.count("frame") == recording.num_samples


def test_beyond_max_streams_is_refused_at_once(tight_server, recording):
    with C.connect(f"127.0.0.1:{tight_server.port}") as conn:
        holder = _Requests()
        holder.put(pb.StreamSynthesizeRequest(config=C.stream_config("small")))
        responses = iter(conn.stub.StreamSynthesize(iter(holder), timeout=30))
        assert next(responses).WhichOneof("message") == "started"
        for _ in range(3):
            extra = _Requests()
            t0 = time.monotonic()
            with pytest.raises(grpc.RpcError) as info:
                list(conn.stub.StreamSynthesize(iter(extra), timeout=30))
            extra.close()
            assert info.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
            assert time.monotonic() - t0 < 0.4  # before any config could have timed out, let alone the deadline
        holder.close()
        assert [r.WhichOneof("message") for r in responses] == ["finished"]
        _wait_for(lambda: tight_server.servicer.slots.active == 0)


def test_a_configured_stream_that_pauses_keeps_its_slot_and_resumes(tight_server, graph, recording):
    """The configuration timeout concerns the config only: a stream whose samples stop
    for a while (a player off the field) is not ended; its client's deadline, its
    cancelling or a dead connection (keepalive) ends it."""
    samples = list(C.recording_samples(recording))
    with C.connect(f"127.0.0.1:{tight_server.port}") as conn:
        feed = C.SampleFeed(C.stream_config("small"))
        for s in samples[:10]:
            feed.put(s)
        done: list = []
        runner = threading.Thread(target=lambda: done.append(C.run_stream(conn, feed, timeout_s=60)))
        runner.start()
        time.sleep(1.5)  # three configuration timeouts with no sample
        assert tight_server.servicer.slots.active == 1 and not done
        for s in samples[10:]:
            feed.put(s)
        feed.close()
        runner.join(60)
        assert done and done[0].finished.samples_received == recording.num_samples
        assert len(done[0].frames) == recording.num_samples


@pytest.mark.parametrize("timeout_s", [0.0, -1.0, float("nan"), float("inf")])
def test_the_configuration_timeout_must_be_positive_and_finite(loaded_graphs, timeout_s):
    with pytest.raises(InputError, match="--config-timeout-s"):
        start(loaded_graphs, config_timeout_s=timeout_s)


@pytest.mark.parametrize("ending", ["cancel", "deadline"])
def test_a_stream_whose_client_goes_away_frees_its_session_at_once(server, recording, ending, monkeypatch):
    """Without waiting for the cyclic garbage collector: a session holds the decoder's
    state (~100 MB on a large graph), and with streams coming and going the server's
    memory would swing by gigabytes between full collections."""
    import gc
    import weakref

    from graphsvc import pipeline

    opened = []  # weak references to the sessions the server opens
    real = pipeline.open_session

    def tracked(*args, **kwargs):
        session = real(*args, **kwargs)
        opened.append(weakref.ref(session))
        return session

    monkeypatch.setattr(pipeline, "open_session", tracked)
    samples = list(C.recording_samples(recording))

    def slow():
        yield pb.StreamSynthesizeRequest(config=C.stream_config("small"))
        for s in samples:
            time.sleep(0.02)
            yield pb.StreamSynthesizeRequest(sample=s)

    gc.collect()
    gc.disable()
    try:
        with C.connect(f"127.0.0.1:{server.port}") as conn:
            for _ in range(3):
                call = conn.stub.StreamSynthesize(slow(), timeout=0.6 if ending == "deadline" else 30)
                if ending == "cancel":
                    threading.Timer(0.3, call.cancel).start()
                with pytest.raises(grpc.RpcError) as info:
                    list(call)
                assert info.value.code() == (
                    grpc.StatusCode.CANCELLED if ending == "cancel" else grpc.StatusCode.DEADLINE_EXCEEDED
                )
            _wait_for(lambda: server.servicer.slots.active == 0)
            assert len(opened) == 3
            _wait_for(lambda: all(ref() is None for ref in opened))
    finally:
        gc.enable()


def test_the_server_stops_after_a_request_that_does_not_parse(loaded_graphs):
    """gRPC answers bytes that are no request itself (INTERNAL) and can leave the call
    unfreed; stopping must not wait for it forever: it ends at the latest give_up_s
    after the grace."""
    import gc

    running = start(loaded_graphs, max_streams=2)
    gc.collect()
    gc.disable()
    try:
        with C.connect(f"127.0.0.1:{running.port}") as conn:
            raw = conn.channel.stream_stream(
                "/graphsvc.v1.MotionGraphService/StreamSynthesize", request_serializer=None, response_deserializer=None
            )
            with pytest.raises(grpc.RpcError) as info:
                list(raw(iter([b"\xff\x01 not a request"]), timeout=10))
            assert info.value.code() == grpc.StatusCode.INTERNAL
        stopper = threading.Thread(target=running.stop, args=(0, 1.0), daemon=True)
        stopper.start()
        stopper.join(5.0)
        assert not stopper.is_alive(), "the server did not stop"
    finally:
        gc.enable()
        gc.collect()

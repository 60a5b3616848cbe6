"""Real server on a loopback ephemeral port, real client: round trips against the
library, health and reflection, status codes of bad requests, stream limits,
deadlines and cancellation."""

from __future__ import annotations

import threading
import time

import grpc
import numpy as np
import pytest

from graphsvc.service import client as C
from graphsvc.service import convert
from graphsvc.service._generated import graphsvc_pb2 as pb
from tests.service.conftest import assert_frames_equal, live_frames, start
from tests.service.conftest import rpc_error as _code
from tests.service.conftest import stream_requests as _requests
from tests.service.conftest import wait_for as _wait_for

# ---------------------------------------------------------------- graphs


def test_list_and_get_graph(conn, graph, graph_file):
    from graphsvc.graph.model import summary

    (info,) = C.list_graphs(conn)
    assert info.name == "small"
    got = convert.graph_info_dict(C.get_graph(conn, "small"))
    assert got == {**summary(graph, graph_file.stat().st_size), "params": got["params"]}
    assert got["params"]["layout"] == graph.params["layout"] == "kelly6"
    sk = convert.skeleton_from_proto(info.skeleton)
    assert sk.names == graph.skeleton.names and np.array_equal(sk.parents, graph.skeleton.parents)
    rest = np.array(info.rest_pose_accelerations_m_s2).reshape(-1, 3)
    # The procedural rest pose is a T-pose with the palms down; in anatomical frames
    # (sensors.anatomy) the left arm reads +1 g along Y, the right along −Y, legs along −X,
    # the trunk along +X.
    np.testing.assert_allclose(np.linalg.norm(rest, axis=1), 9.81, atol=1e-4)
    np.testing.assert_allclose(
        rest, [[0, 9.81, 0], [0, -9.81, 0], [-9.81, 0, 0], [-9.81, 0, 0], [9.81, 0, 0], [9.81, 0, 0]], atol=1e-3
    )


# ---------------------------------------------------------------- round trips


@pytest.mark.parametrize("latency_s, beam", [(None, None), (0.5, None), (None, 2.0), (0.5, 2.0)])
def test_synthesize_matches_library(conn, graph, recording, latency_s, beam):
    from graphsvc.motion.bvh import bvh_text
    from graphsvc.pipeline import Options, reconstruct
    from graphsvc.strategies.options import Weights

    options = Options(weights=Weights(0.5, 1.0, 1.0), latency_s=latency_s, beam=beam)
    expected = reconstruct(graph, recording, options)
    got = C.synthesize(conn, "small", recording, convert.options_to_proto(options))
    np.testing.assert_array_equal(got.node_path, expected.node_path)
    np.testing.assert_array_equal(got.motion.rotations, expected.motion.rotations.astype(np.float32))
    np.testing.assert_array_equal(got.motion.translations, expected.motion.translations.astype(np.float32))
    assert got.bvh == bvh_text(expected.motion, scale=100.0).encode()
    assert got.report["node_path"] == expected.node_path.tolist()
    assert got.report["samples"] == recording.num_samples


def test_synthesize_reorders_named_sensors(conn, graph, recording):
    """Sensors may come in any order when named; the result is the same."""
    from dataclasses import replace

    order = np.arange(recording.num_sensors)[::-1]
    shuffled = replace(
        recording,
        sensor_names=tuple(np.array(recording.sensor_names)[order]),
        accelerations=np.ascontiguousarray(recording.accelerations[:, order]),
    )
    a = C.synthesize(conn, "small", recording)
    b = C.synthesize(conn, "small", shuffled)
    np.testing.assert_array_equal(a.node_path, b.node_path)


def test_stream_matches_live_session(conn, graph, recording):
    from graphsvc.pipeline import Options

    options = Options(latency_s=0.4)
    expected, session = live_frames(graph, recording, options)
    feed = C.SampleFeed(C.stream_config("small", convert.options_to_proto(options)))
    for sample in C.recording_samples(recording):
        feed.put(sample)
    feed.close()
    result = C.run_stream(conn, feed)
    assert result.started.lag_frames == session.lag_frames
    assert result.started.rate_hz == graph.rate_hz
    assert_frames_equal(expected, result.frames)
    assert result.finished.samples_received == recording.num_samples
    assert result.finished.frames_emitted == len(expected)
    # Every frame names the sample that released it, at most lag_frames before it.
    k = np.array([f.input_sample_index for f in result.frames])
    assert (np.diff(k) >= 0).all() and k[-1] == recording.num_samples - 1
    motion = result.motion()
    assert motion.num_frames == len(expected)


def test_a_default_stream_lags_by_the_frames_it_reports(conn, recording):
    """No latency given: the decoder's 1 s (30 frames at the graph's 30 Hz), the
    synthesis' look-ahead ceil(0.35 × 30) + 1 = 12, up to 2 frames of its batches of 3,
    and 3 for the poses' filter (ceil(3σ), σ = 1/30 s): 47 frames, as `client stream
    --help` says; the recording is at the graph rate,
    so sample k is frame k's, and the last frames out of a push wait exactly that."""
    feed = C.SampleFeed(C.stream_config("small"))
    for sample in C.recording_samples(recording):
        feed.put(sample)
    feed.close()
    result = C.run_stream(conn, feed)
    assert result.started.lag_frames == 47
    waits = [f.input_sample_index - f.index for f in result.frames]
    assert max(waits) == 47 and len(result.frames) == recording.num_samples


def test_a_lone_stream_steps_with_the_threads_and_matches_the_serial_session(
    conn, server, graph, recording, monkeypatch
):
    # While a stream runs alone the server gives its steps numba's threads; the frames
    # are those of a serial LiveSession all the same.
    from graphsvc.pipeline import LiveSession, Options

    expected, _ = live_frames(graph, recording, Options())
    used = []  # whether each push and the flush ran with the threads
    push, flush = LiveSession.push, LiveSession.flush
    monkeypatch.setattr(LiveSession, "push", lambda self, *a, **kw: used.append(self.threads) or push(self, *a, **kw))
    monkeypatch.setattr(LiveSession, "flush", lambda self: used.append(self.threads) or flush(self))
    assert server.servicer.threads.running_searches == 0
    feed = C.SampleFeed(C.stream_config("small"))
    for sample in C.recording_samples(recording):
        feed.put(sample)
    feed.close()
    result = C.run_stream(conn, feed)
    assert_frames_equal(expected, result.frames)
    assert used == [True] * (recording.num_samples + 1)
    assert server.servicer.threads.running_searches == 0


def test_replay_in_real_time_reports_latency(conn, recording):
    from dataclasses import replace

    from graphsvc.pipeline import Options

    short = replace(
        recording,
        timestamps_s=recording.timestamps_s[:30],
        accelerations=recording.accelerations[:30],
        ground_position=recording.ground_position[:30],
        heading=recording.heading[:30],
    )
    seen = []
    t0 = time.perf_counter()
    result = C.stream_recording(
        conn,
        "small",
        short,
        convert.options_to_proto(Options(latency_s=0.2)),
        speed=4.0,
        on_frame=lambda f, ms: seen.append(ms),
    )
    elapsed = time.perf_counter() - t0
    assert elapsed >= (short.timestamps_s[-1] - short.timestamps_s[0]) / 4.0  # paced, not dumped
    assert len(seen) == len(result.frames) == 30
    summary = C.latency_summary(seen)
    assert summary["frames"] == 30 and 0 <= summary["p50_ms"] <= summary["p99_ms"] < 5000


# ---------------------------------------------------------------- health and reflection


def test_health(server):
    from grpc_health.v1 import health_pb2, health_pb2_grpc

    with grpc.insecure_channel(f"127.0.0.1:{server.port}") as channel:
        stub = health_pb2_grpc.HealthStub(channel)
        for service in ("", "graphsvc.v1.MotionGraphService"):
            reply = stub.Check(health_pb2.HealthCheckRequest(service=service), timeout=5)
            assert reply.status == health_pb2.HealthCheckResponse.SERVING
        code, _ = _code(stub.Check, health_pb2.HealthCheckRequest(service="nope"), timeout=5)
        assert code == grpc.StatusCode.NOT_FOUND


def _health(port: int) -> dict:
    """Each service's health status name (overall and graphsvc.v1's)."""
    from grpc_health.v1 import health_pb2, health_pb2_grpc

    with grpc.insecure_channel(f"127.0.0.1:{port}") as channel:
        stub = health_pb2_grpc.HealthStub(channel)
        return {
            service: health_pb2.HealthCheckResponse.ServingStatus.Name(
                stub.Check(health_pb2.HealthCheckRequest(service=service), timeout=10).status
            )
            for service in ("", "graphsvc.v1.MotionGraphService")
        }


def test_health_answers_not_serving_until_the_graphs_are_served(loaded_graphs):
    """`serve` binds (bind_server), loads its graphs, then start_server: in between,
    health answers NOT_SERVING and every other call UNAVAILABLE."""
    from graphsvc.service.server import ServerConfig, bind_server, start_server

    config = ServerConfig(host="127.0.0.1", port=0)
    bound = bind_server(config)
    running = None
    try:
        assert _health(bound.port) == {"": "NOT_SERVING", "graphsvc.v1.MotionGraphService": "NOT_SERVING"}
        with C.connect(f"127.0.0.1:{bound.port}") as c:
            code, details = _code(c.stub.ListGraphs, pb.ListGraphsRequest(), timeout=10)
            assert code == grpc.StatusCode.UNAVAILABLE and "loading its graphs" in details
            running = start_server(loaded_graphs, config, bound)
            assert _health(bound.port) == {"": "SERVING", "graphsvc.v1.MotionGraphService": "SERVING"}
            assert [g.name for g in C.list_graphs(c, timeout_s=10)] == ["small"]
    finally:
        running.stop(0) if running is not None else bound.close()


def test_health_answers_not_serving_while_the_calls_under_way_drain(loaded_graphs, recording):
    running = start(loaded_graphs)
    stopper = None
    try:
        with C.connect(f"127.0.0.1:{running.port}") as c:
            feed = C.SampleFeed(C.stream_config("small"))
            responses = iter(c.stub.StreamSynthesize(iter(feed), timeout=60))
            assert next(responses).WhichOneof("message") == "started"
            stopper = threading.Thread(target=running.stop, args=(60,))
            stopper.start()
            _wait_for(lambda: running.gate.stage == "draining")
            assert _health(running.port) == {"": "NOT_SERVING", "graphsvc.v1.MotionGraphService": "NOT_SERVING"}
            code, details = _code(c.stub.ListGraphs, pb.ListGraphsRequest(), timeout=10)
            assert code == grpc.StatusCode.UNAVAILABLE and "shutting down" in details
            for sample in C.recording_samples(recording):  # the stream under way goes on to its end
                feed.put(sample)
            feed.close()
            kinds = [r.WhichOneof("message") for r in responses]
            assert kinds.count("frame") == recording.num_samples and kinds[-1] == "finished"
            stopper.join(30)
            assert not stopper.is_alive()
    finally:
        if stopper is None:
            running.stop(0)


@pytest.mark.parametrize("version", ["v1alpha", "v1"])
def test_reflection_lists_and_describes_the_service(server, version):
    from google.protobuf import descriptor_pb2
    from grpc_reflection.v1alpha import reflection_pb2

    with grpc.insecure_channel(f"127.0.0.1:{server.port}") as channel:
        # What grpcurl does: list services, then fetch the file declaring one.
        call = channel.stream_stream(
            f"/grpc.reflection.{version}.ServerReflection/ServerReflectionInfo",
            request_serializer=reflection_pb2.ServerReflectionRequest.SerializeToString,
            response_deserializer=reflection_pb2.ServerReflectionResponse.FromString,
        )
        requests = [
            reflection_pb2.ServerReflectionRequest(list_services=""),
            reflection_pb2.ServerReflectionRequest(file_containing_symbol="graphsvc.v1.MotionGraphService"),
        ]
        listed, described = list(call(iter(requests), timeout=5))
    names = {s.name for s in listed.list_services_response.service}
    assert {"graphsvc.v1.MotionGraphService", "grpc.health.v1.Health"} <= names
    files = [
        descriptor_pb2.FileDescriptorProto.FromString(b)
        for b in described.file_descriptor_response.file_descriptor_proto
    ]
    (mine,) = [f for f in files if f.name == "graphsvc/v1/graphsvc.proto"]
    (service,) = mine.service
    assert [m.name for m in service.method] == [
        "ListGraphs",
        "GetGraph",
        "Synthesize",
        "StreamSynthesize",
        "SubmitBatch",
        "GetBatch",
        "ListBatches",
        "CancelBatch",
    ]
    assert service.method[3].client_streaming and service.method[3].server_streaming


# ---------------------------------------------------------------- bad requests


def test_report_arrives_with_its_types(conn, graph, recording):
    """The client's report is the library's as `synthesize --report` writes it: the
    node path and every count integers, the same keys, the same values but timings."""
    import json

    from graphsvc.pipeline import reconstruct

    got = C.synthesize(conn, "small", recording).report
    options = convert.options_from_proto(pb.SynthesisOptions(), "options")  # what the server makes of none
    want = json.loads(json.dumps(reconstruct(graph, recording, options, threads=False).report, sort_keys=True))
    assert got["node_path"] and all(type(n) is int for n in got["node_path"])

    def same(a, b, where):
        assert type(a) is type(b), f"{where}: {a!r} against {b!r}"
        if isinstance(a, dict):
            assert sorted(a) == sorted(b), where
            for k in a:
                same(a[k], b[k], f"{where}.{k}")
        elif isinstance(a, list):
            assert len(a) == len(b), where
            for k, (x, y) in enumerate(zip(a, b)):
                same(x, y, f"{where}[{k}]")
        elif not where.startswith(("report.timings_s", "report.samples_per_s")):
            assert a == b, f"{where}: {a!r} against {b!r}"

    same(got, want, "report")


def _recording_request(recording, **changes) -> pb.SynthesizeRequest:
    request = pb.SynthesizeRequest(graph="small", recording=convert.recording_to_proto(recording))
    for key, value in changes.items():
        obj = request
        *path, last = key.split(".")
        for p in path:
            obj = getattr(obj, p)
        if isinstance(value, list):
            del getattr(obj, last)[:]
            getattr(obj, last).extend(value)
        else:
            setattr(obj, last, value)
    return request


def _bad_cases(recording):
    t = recording.timestamps_s.tolist()
    acc = recording.accelerations.ravel().tolist()
    nan_t = list(t)
    nan_t[3] = float("nan")
    back_t = list(t)
    back_t[5] = back_t[4]
    inf_acc = list(acc)
    inf_acc[40] = float("inf")
    bad_constraint = pb.SynthesisOptions(
        constraint_sets=[
            pb.ConstraintSet(constraints=[pb.Constraint(start_s=2.0, end_s=1.0, contact=pb.CONTACT_STATE_LEFT)])
        ]
    )
    unknown_label = pb.SynthesisOptions(
        constraint_sets=[pb.ConstraintSet(constraints=[pb.Constraint(start_s=0.0, end_s=1.0, label="no-such-label")])]
    )
    INVALID = grpc.StatusCode.INVALID_ARGUMENT
    return {
        "unknown graph": ({"graph": "nope"}, grpc.StatusCode.NOT_FOUND, "graph"),
        "no graph": ({"graph": ""}, INVALID, "graph"),
        "sensor count": ({"recording.accelerations_m_s2": acc[:-3]}, INVALID, "recording.accelerations_m_s2"),
        "sensor names": ({"recording.sensor_names": ["a", "b"]}, INVALID, "recording.sensor_names"),
        "unknown sensor": (
            {"recording.sensor_names": ["x", *recording.sensor_names[1:]]},
            INVALID,
            "recording.sensor_names",
        ),
        "nan time": ({"recording.timestamps_s": nan_t}, INVALID, "recording.timestamps_s[3]"),
        "time backwards": ({"recording.timestamps_s": back_t}, INVALID, "recording.timestamps_s[5]"),
        "no samples": (
            {"recording.timestamps_s": [], "recording.accelerations_m_s2": []},
            INVALID,
            "recording.timestamps_s",
        ),
        "inf reading": ({"recording.accelerations_m_s2": inf_acc}, INVALID, "recording.accelerations_m_s2[40]"),
        "bad rate": ({"recording.rate_hz": 0.0}, INVALID, "recording.rate_hz"),
        "positions": ({"recording.ground_positions_m": [0.0, 1.0, 2.0]}, INVALID, "recording.ground_positions_m"),
        "negative weight": ({"options.weights.position": -1.0}, INVALID, "options.weights.position"),
        "nan latency": ({"options.latency_s": float("nan")}, INVALID, "options.latency_s"),
        "zero beam": ({"options.beam": 0.0}, INVALID, "options.beam"),
        "unknown strategy": ({"options.strategy": 7}, INVALID, "options.strategy"),
        "ssg without a marker set": ({"options.strategy": pb.STRATEGY_SSG}, INVALID, "options.ssg.markers"),
        "constraint order": ({"options": bad_constraint}, INVALID, "options.constraint_sets[0].constraints[0]"),
        "unknown label": ({"options": unknown_label}, INVALID, "no-such-label"),
    }


def test_bad_synthesize_requests_get_the_right_status(conn, recording):
    for name, (changes, code, mention) in _bad_cases(recording).items():
        options = changes.pop("options", None)
        request = _recording_request(recording, **changes)
        if options is not None:
            request.options.CopyFrom(options)
        got, details = _code(conn.stub.Synthesize, request, timeout=10)
        assert got == code, f"{name}: {got} {details}"
        assert mention in details, f"{name}: {details!r} does not name {mention!r}"
    assert C.synthesize(conn, "small", recording).motion.num_frames == recording.num_samples  # still serving


def test_wrong_layout_names_the_sensors_as_the_cli_does(conn, graph, recording):
    """The service refuses sensors that are not the graph's layout with the CLI's own
    line: the missing sensors and the strangers by name, not counts."""
    from graphsvc.errors import InputError
    from graphsvc.strategies.inputs import check_layout

    names = list(recording.sensor_names)
    wrong = ["elbow_x", *names[1:]]
    with pytest.raises(InputError) as cli:
        check_layout(graph, wrong)
    assert f"missing {names[0]}" in str(cli.value) and "not in the graph: elbow_x" in str(cli.value)
    code, details = _code(
        conn.stub.Synthesize, _recording_request(recording, **{"recording.sensor_names": wrong}), timeout=10
    )
    assert code == grpc.StatusCode.INVALID_ARGUMENT
    assert details == f"recording.sensor_names: {cli.value}"
    samples = list(C.recording_samples(recording))[:3]
    code, details = _code(
        lambda: list(
            conn.stub.StreamSynthesize(_requests(C.stream_config("small", None, names[:-1]), samples), timeout=10)
        )
    )
    assert code == grpc.StatusCode.INVALID_ARGUMENT
    assert f"missing {names[-1]}" in details and details.startswith("config.sensor_names: the recording's sensors")
    assert C.synthesize(conn, "small", recording).motion.num_frames == recording.num_samples


def _stream_cases(recording):
    samples = list(C.recording_samples(recording))[:6]
    config = C.stream_config("small")
    back = [pb.SensorSample(time_s=s.time_s, accelerations_m_s2=s.accelerations_m_s2) for s in samples]
    back[2].time_s = back[1].time_s
    short = [pb.SensorSample(time_s=0.0, accelerations_m_s2=[0.0] * 17)]
    inf = [pb.SensorSample(time_s=0.0, accelerations_m_s2=[0.0] * 17 + [float("inf")])]
    INVALID = grpc.StatusCode.INVALID_ARGUMENT
    return {
        "sample first": ([pb.StreamSynthesizeRequest(sample=samples[0])], INVALID, "config"),
        "config twice": ([pb.StreamSynthesizeRequest(config=config)] * 2, INVALID, "sample[0]"),
        "unknown graph": (list(_requests(C.stream_config("nope"), samples)), grpc.StatusCode.NOT_FOUND, "nope"),
        "ssg without a marker set": (
            list(_requests(C.stream_config("small", pb.SynthesisOptions(strategy=pb.STRATEGY_SSG)), samples)),
            INVALID,
            "config.options.ssg.markers",
        ),
        "time backwards": (list(_requests(config, back)), INVALID, "sample[2].time_s"),
        "sensor count": (list(_requests(config, short)), INVALID, "sample[0].accelerations_m_s2"),
        "inf reading": (list(_requests(config, inf)), INVALID, "sample[0].accelerations_m_s2[17]"),
        "sensor names": (
            list(_requests(C.stream_config("small", None, ["a"]), samples)),
            INVALID,
            "config.sensor_names",
        ),
        "bad weight": (
            list(
                _requests(
                    C.stream_config("small", pb.SynthesisOptions(weights=pb.CostWeights(acceleration=float("nan")))),
                    samples,
                )
            ),
            INVALID,
            "config.options.weights",
        ),
    }


def test_bad_stream_requests_get_the_right_status(conn, server, recording):
    for name, (requests, code, mention) in _stream_cases(recording).items():
        got, details = _code(lambda requests=requests: list(conn.stub.StreamSynthesize(iter(requests), timeout=10)))
        assert got == code, f"{name}: {got} {details}"
        assert mention in details, f"{name}: {details!r} does not name {mention!r}"
    _wait_for(lambda: server.servicer.slots.active == 0)  # every failed stream gave its slot back


def test_message_size_limit(loaded_graphs, recording):
    running = start(loaded_graphs, max_message_mb=0.001)  # ~1 kB: the recording is larger
    try:
        with C.connect(f"127.0.0.1:{running.port}") as conn:
            code, _ = _code(
                conn.stub.Synthesize,
                pb.SynthesizeRequest(graph="small", recording=convert.recording_to_proto(recording)),
                timeout=10,
            )
            assert code == grpc.StatusCode.RESOURCE_EXHAUSTED
            # Small messages still pass: a request for an unknown graph is answered as usual.
            code, _ = _code(conn.stub.GetGraph, pb.GetGraphRequest(name="nope"), timeout=10)
            assert code == grpc.StatusCode.NOT_FOUND
    finally:
        running.stop(0)


# ---------------------------------------------------------------- limits, deadlines, cancellation


def _rpc_threads_busy() -> int:
    """Server worker threads inside a StreamSynthesize handler right now."""
    import sys

    return sum(1 for frame in sys._current_frames().values() if _in_stream_handler(frame))


def _in_stream_handler(frame) -> bool:
    while frame is not None:
        if frame.f_code.co_name == "_stream" and "service/servicer.py" in frame.f_code.co_filename:
            return True
        frame = frame.f_back
    return False


def _open_stream(conn, recording, samples: int = 3):
    """A stream that has started and taken `samples` samples and stays open."""
    feed = C.SampleFeed(C.stream_config("small"))
    call = conn.stub.StreamSynthesize(iter(feed), metadata=conn.metadata)
    responses = iter(call)
    assert next(responses).WhichOneof("message") == "started"
    for s in list(C.recording_samples(recording))[:samples]:
        feed.put(s)
    return feed, call, responses


@pytest.fixture
def one_stream_server(loaded_graphs):
    running = start(loaded_graphs, max_streams=1)
    yield running
    running.stop(0)


def test_beyond_max_streams_is_resource_exhausted(one_stream_server, recording):
    with C.connect(f"127.0.0.1:{one_stream_server.port}") as conn:
        feed, _, responses = _open_stream(conn, recording)
        code, details = _code(lambda: list(conn.stub.StreamSynthesize(iter([]), timeout=10)))
        assert code == grpc.StatusCode.RESOURCE_EXHAUSTED and "--max-streams" in details
        feed.close()
        kinds = [r.WhichOneof("message") for r in responses]
        assert kinds[-1] == "finished"
        _wait_for(lambda: one_stream_server.servicer.slots.active == 0)
        assert C.synthesize(conn, "small", recording).node_path.size  # unary calls are not streams


def test_cancelling_mid_stream_frees_the_worker(one_stream_server, recording):
    from graphsvc.service.server import UNARY_WORKERS

    with C.connect(f"127.0.0.1:{one_stream_server.port}") as conn:
        # More cancellations than the pool has threads: a leaked worker would starve it.
        for _ in range(UNARY_WORKERS + 3):
            feed, call, _ = _open_stream(conn, recording, samples=5)
            assert one_stream_server.servicer.slots.active == 1
            call.cancel()
            feed.close()
            _wait_for(lambda: one_stream_server.servicer.slots.active == 0)
        _wait_for(lambda: _rpc_threads_busy() == 0)
        # A later stream is served in full.
        feed = C.SampleFeed(C.stream_config("small"))
        for s in C.recording_samples(recording):
            feed.put(s)
        feed.close()
        result = C.run_stream(conn, feed, timeout_s=30)
        assert result.finished.samples_received == recording.num_samples


def test_deadline_exceeded(conn, server, recording):
    code, _ = _code(
        conn.stub.Synthesize,
        pb.SynthesizeRequest(graph="small", recording=convert.recording_to_proto(recording)),
        timeout=0.001,
    )
    assert code == grpc.StatusCode.DEADLINE_EXCEEDED
    # A stream whose client keeps it open past the deadline ends, and its slot is freed.
    feed = C.SampleFeed(C.stream_config("small"))
    for s in list(C.recording_samples(recording))[:5]:
        feed.put(s)
    with pytest.raises(C.ServiceError) as info:
        C.run_stream(conn, feed, timeout_s=0.5)
    assert info.value.code == grpc.StatusCode.DEADLINE_EXCEEDED
    _wait_for(lambda: server.servicer.slots.active == 0)


def test_concurrent_streams_are_independent(conn, graph, recording):
    from graphsvc.pipeline import Options

    expected, _ = live_frames(graph, recording, Options())
    results = [None] * 3

    def run(i):
        feed = C.SampleFeed(C.stream_config("small"))
        for s in C.recording_samples(recording):
            feed.put(s)
        feed.close()
        results[i] = C.run_stream(conn, feed, timeout_s=60)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for r in results:
        assert_frames_equal(expected, r.frames)


# ---------------------------------------------------------------- every strategy through the service


def test_nearest_through_synthesize_and_stream(conn, graph, recording):
    from graphsvc.pipeline import Options, reconstruct

    options = Options(strategy="nearest")
    expected = reconstruct(graph, recording, options)
    got = C.synthesize(conn, "small", recording, convert.options_to_proto(options))
    np.testing.assert_array_equal(got.node_path, expected.node_path)
    np.testing.assert_array_equal(got.motion.rotations, expected.motion.rotations.astype(np.float32))
    assert got.report["strategy"] == "nearest"
    # Provenance: one source a frame, the node's clip and frame.
    request = _recording_request(recording)
    request.options.CopyFrom(convert.options_to_proto(options))
    prov = conn.stub.Synthesize(request, timeout=30).provenance
    assert prov.sources_per_frame == 1 and list(prov.clips) == graph.node_clip[expected.node_path].tolist()
    assert list(prov.labels) == [graph.labels[k] for k in graph.node_label[expected.node_path]]

    live, _ = live_frames(graph, recording, options)
    feed = C.SampleFeed(C.stream_config("small", convert.options_to_proto(options)))
    for sample in C.recording_samples(recording):
        feed.put(sample)
    feed.close()
    result = C.run_stream(conn, feed)
    assert_frames_equal(live, result.frames)
    assert [(s.clip, s.frame, s.weight) for s in result.frames[0].sources] == [
        (live[0].sources[0][0], pytest.approx(live[0].sources[0][1]), 1.0)
    ]


def _synthesized_and_streamed_as_the_library(conn, graph, recording, options, msg):
    """The server's Synthesize and StreamSynthesize of `recording` with `msg`, checked
    against the library's batch and live results for `options`; (synthesized, streamed)."""
    from graphsvc.pipeline import reconstruct

    expected = reconstruct(graph, recording, options)
    got = C.synthesize(conn, "small", recording, msg)
    np.testing.assert_array_equal(got.motion.rotations, expected.motion.rotations.astype(np.float32))
    live, _ = live_frames(graph, recording, options)
    feed = C.SampleFeed(C.stream_config("small", msg))
    for sample in C.recording_samples(recording):
        feed.put(sample)
    feed.close()
    result = C.run_stream(conn, feed)
    assert_frames_equal(live, result.frames)
    return got, result


def test_olng_through_synthesize_and_stream(conn, graph, recording):
    from graphsvc.pipeline import Options
    from graphsvc.strategies.olng.options import OlngOptions

    options = Options(strategy="olng", olng=OlngOptions(k=24, i=6, m=12, extended=False, w_contr=0.5))
    msg = convert.options_to_proto(options)
    assert convert.options_from_proto(msg).olng == options.olng  # every OLNG option crosses the wire
    got, result = _synthesized_and_streamed_as_the_library(conn, graph, recording, options, msg)
    assert got.report["strategy"] == "olng" and got.report["olng"]["k"] == 24
    assert len(result.frames[0].sources) > 1  # (a neighbourhood: several frames, weighted)
    bad = pb.SynthesisOptions(strategy=pb.STRATEGY_OLNG, olng=pb.OlngOptions(k=8, i=9))
    request = _recording_request(recording)
    request.options.CopyFrom(bad)
    code, details = _code(conn.stub.Synthesize, request, timeout=10)
    assert code == grpc.StatusCode.INVALID_ARGUMENT and "options.olng" in details, details
    request.options.CopyFrom(pb.SynthesisOptions(strategy=pb.STRATEGY_OLNG, olng=pb.OlngOptions(k=10**6)))
    code, details = _code(conn.stub.Synthesize, request, timeout=10)
    assert code == grpc.StatusCode.INVALID_ARGUMENT and "exceeds" in details, details


def test_piecewise_through_synthesize_and_stream(conn, graph, recording):
    from graphsvc.pipeline import Options
    from graphsvc.strategies.piecewise import PiecewiseOptions

    options = Options(strategy="piecewise", piecewise=PiecewiseOptions(method="optimise", dims=10, clusters="3"))
    msg = convert.options_to_proto(options)
    assert msg.strategy_name == "piecewise" and convert.options_from_proto(msg).piecewise == options.piecewise
    got, _ = _synthesized_and_streamed_as_the_library(conn, graph, recording, options, msg)
    assert got.report["strategy"] == "piecewise" and got.report["piecewise"]["clusters"] == 3
    request = _recording_request(recording)
    for settings, message in (
        ({"width": float("nan")}, "width"),
        ({"clusters": "many"}, "clusters"),
        ({"clusters": "100000"}, "clusters"),
        ({"dims": 250}, "pose dimension"),
    ):
        request.options.CopyFrom(pb.SynthesisOptions(strategy_name="piecewise"))
        request.options.strategy_settings.update(settings)
        code, details = _code(conn.stub.Synthesize, request, timeout=30)
        assert code == grpc.StatusCode.INVALID_ARGUMENT and message in details and "\n" not in details, details


def test_a_strategy_asked_for_an_input_it_lacks_answers_invalid_argument(conn, recording):
    request = _recording_request(recording)
    del request.recording.accelerations_m_s2[:]  # no accelerations at all: only the track
    for strategy in (pb.STRATEGY_VITERBI, pb.STRATEGY_NEAREST, pb.STRATEGY_OLNG):
        request.options.strategy = strategy
        got, details = _code(conn.stub.Synthesize, request, timeout=10)
        assert got == grpc.StatusCode.INVALID_ARGUMENT and "needs accelerations" in details, details


def test_viterbi_options_supersede_the_flat_fields():
    from graphsvc.pipeline import Options

    msg = convert.options_to_proto(Options(beam=4.0, heading_from_track=True, rest_heading_deg=30.0))
    assert msg.viterbi.beam == msg.beam == 4.0 and msg.viterbi.heading_from_track
    back = convert.options_from_proto(msg)
    assert back.beam == 4.0 and back.heading_from_track and back.rest_heading_deg == 30.0
    old = pb.SynthesisOptions(beam=2.5, heading_from_track=True, rest_heading_deg=10.0)  # an older client
    back = convert.options_from_proto(old)
    assert back.beam == 2.5 and back.heading_from_track and back.rest_heading_deg == 10.0
    new = pb.SynthesisOptions(beam=2.5, viterbi=pb.ViterbiOptions(beam=7.0))  # the new message wins
    assert convert.options_from_proto(new).beam == 7.0 and not convert.options_from_proto(new).heading_from_track
    with pytest.raises(Exception, match="options.viterbi.beam"):
        convert.options_from_proto(pb.SynthesisOptions(viterbi=pb.ViterbiOptions(beam=0.0)))
    # The pull toward the tracker: sent, read back; absent, the default; negative, refused.
    assert convert.options_from_proto(convert.options_to_proto(Options(track_pull_s=2.5))).track_pull_s == 2.5
    assert convert.options_from_proto(old).track_pull_s == Options().track_pull_s
    with pytest.raises(Exception, match="options.viterbi.track_pull_s"):
        convert.options_from_proto(pb.SynthesisOptions(viterbi=pb.ViterbiOptions(track_pull_s=-1.0)))


def test_recordings_with_orientations_and_markers_cross_the_wire(graph, recording):
    from dataclasses import replace

    T, S = recording.num_samples, recording.num_sensors
    q = np.zeros((T, S, 4), np.float32)
    q[..., 0] = 1.0
    markers = np.full((T, 2, 3), np.nan)
    markers[::2] = 0.5
    rec = replace(recording, orientations=q, marker_names=("LFHD", "RTOE"), marker_positions=markers)
    back = convert.recording_from_proto(convert.recording_to_proto(rec), graph.sensor_names)
    np.testing.assert_array_equal(back.orientations, q)
    assert back.marker_names == ("LFHD", "RTOE")
    np.testing.assert_array_equal(back.marker_positions, markers)


def test_a_stream_with_orientations_matches_a_live_session_given_them(conn, graph, recording):
    from dataclasses import replace

    from graphsvc.pipeline import Options, open_session
    from graphsvc.strategies.options import Weights

    # random orientations (none matches the path's sensors): the term weighs something
    rng = np.random.default_rng(2)
    q = rng.normal(size=(recording.num_samples, recording.num_sensors, 4)).astype(np.float32)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q[5, 1] = np.nan  # a missing one
    rec = replace(recording, orientations=q)
    options = Options(latency_s=0.4, weights=Weights(1, 1, 1, 3.0))
    session = open_session(graph, options, rec.sensor_names, orientations=True)
    expected = []
    for k in range(rec.num_samples):
        expected += session.push(
            rec.timestamps_s[k],
            rec.accelerations[k],
            rec.ground_position[k],
            rec.heading[k],
            orientations=rec.orientations[k],
        )
    expected += session.flush()
    plain, _ = live_frames(graph, recording, options)
    assert [f.node for f in expected] != [f.node for f in plain]  # (they count)
    feed = C.SampleFeed(C.stream_config("small", convert.options_to_proto(options), rec.sensor_names, (), True))
    for sample in C.recording_samples(rec):
        feed.put(sample)
    feed.close()
    assert_frames_equal(expected, C.run_stream(conn, feed).frames)
    # samples with orientations the config did not announce, or too few of them, are refused
    samples = list(C.recording_samples(rec))[:3]
    for config, mention in (
        (C.stream_config("small"), "config.orientations is not set"),
        (C.stream_config("small", None, (), (), True), None),
    ):
        if mention is None:
            samples = [
                pb.SensorSample(
                    time_s=s.time_s,
                    accelerations_m_s2=s.accelerations_m_s2,
                    orientations_wxyz=list(s.orientations_wxyz)[:-1],
                )
                for s in samples
            ]
            mention = "sample[0].orientations_wxyz"
        got, details = _code(
            lambda: list(conn.stub.StreamSynthesize(iter(list(_requests(config, samples))), timeout=10))
        )
        assert got == grpc.StatusCode.INVALID_ARGUMENT and mention in details, details

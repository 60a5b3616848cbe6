"""STRATEGY_SSG through the service: a marker-only recording (no accelerations) in
Synthesize and StreamSynthesize against the library, SsgOptions across the wire, and
the status of bad marker requests."""

from __future__ import annotations

import json
from dataclasses import replace

import grpc
import numpy as np
import pytest

from graphsvc.service import client as C
from graphsvc.service import convert
from graphsvc.service._generated import graphsvc_pb2 as pb
from tests.service.conftest import assert_frames_equal
from tests.service.conftest import rpc_error as _code
from tests.service.conftest import stream_requests as _stream_requests

INVALID = grpc.StatusCode.INVALID_ARGUMENT


def _ssg(**kw):
    from graphsvc.pipeline import Options
    from graphsvc.strategies.ssg.options import SsgOptions

    latency = kw.pop("latency_s", None)
    return Options(strategy="ssg", latency_s=latency, ssg=SsgOptions(**kw))


# ---------------------------------------------------------------- batch


@pytest.mark.parametrize(
    "options",
    [
        _ssg(markers="hands-feet"),  # "auto" offsets: nominal for a simulated recording, as the library picks
        # The recording's own marker set (sent as JSON), every option set, the offsets fitted.
        _ssg(keep=("l_hand", "r_hand", "l_foot"), window_s=0.3, overlap_s=0.1, k=6, weight=2.0, offsets="fit"),
        _ssg(markers="hands-feet", latency_s=0.5),
    ],
    ids=["preset", "meta-set-fit", "latency"],
)
def test_synthesize_matches_the_library(conn, graph, marker_recording, options):
    from graphsvc.pipeline import reconstruct

    rec = marker_recording
    expected = reconstruct(graph, rec, options)
    msg = convert.options_to_proto(options, recording=rec)
    back = convert.options_from_proto(msg).ssg
    assert replace(back, markers=None) == replace(convert.for_recording(options, rec).ssg, markers=None)
    request = pb.SynthesizeRequest(graph="small", recording=convert.recording_to_proto(rec), options=msg)
    assert len(request.recording.accelerations_m_s2) == 0 and len(request.recording.sensor_names) == 0
    response = conn.stub.Synthesize(request, timeout=60)

    motion = convert.motion_from_proto(response.motion, graph.skeleton)
    np.testing.assert_array_equal(motion.rotations, expected.motion.rotations.astype(np.float32))
    np.testing.assert_array_equal(motion.translations, expected.motion.translations.astype(np.float32))
    assert list(response.node_path) == []  # (SSG's frames are not graph nodes)
    prov, want = response.provenance, expected.provenance
    assert prov.sources_per_frame == want.clip.shape[1]
    np.testing.assert_array_equal(np.array(prov.clips).reshape(want.clip.shape), want.clip)
    np.testing.assert_array_equal(np.array(prov.frames).reshape(want.frame.shape), want.frame)
    np.testing.assert_array_equal(np.array(prov.weights).reshape(want.weight.shape), want.weight)
    assert list(prov.labels) == [str(x) for x in want.label]
    report = convert.struct_to_dict(response.report)
    assert report["strategy"] == "ssg" and report["samples"] == rec.num_samples
    assert report["ssg"]["markers"] == expected.report["ssg"]["markers"]
    assert report["ssg"]["k"] == expected.report["ssg"]["k"]
    assert report["ssg"]["offsets"]["mode"] == expected.report["ssg"]["offsets"]["mode"]


def test_ssg_options_cross_the_wire(tmp_path):
    from graphsvc.sensors.markers import PRESETS

    options = _ssg(
        markers="head-back", keep=("C7", "T10"), window_s=0.4, overlap_s=0.2, k=12, weight=0.5, offsets="nominal"
    )
    assert convert.options_from_proto(convert.options_to_proto(options)).ssg == options.ssg
    # A marker set file is read on the client's side and sent as its content.
    path = tmp_path / "mine.json"
    path.write_text(json.dumps({**PRESETS["left-foot"].to_dict(), "name": "mine"}))
    msg = convert.options_to_proto(_ssg(markers=str(path)))
    assert json.loads(msg.ssg.markers)["name"] == "mine"
    assert convert.options_from_proto(msg).ssg.markers == msg.ssg.markers
    # Unset fields stay unset: the strategy picks its defaults by the markers used.
    assert (
        convert.options_from_proto(
            pb.SynthesisOptions(strategy=pb.STRATEGY_SSG, ssg=pb.SsgOptions(markers="vicon"))
        ).ssg
        == _ssg(markers="vicon").ssg
    )


# ---------------------------------------------------------------- live


def test_stream_matches_live_session_and_batch(conn, graph, marker_recording):
    from graphsvc.pipeline import open_session, reconstruct

    rec = marker_recording
    options = _ssg(markers="hands-feet", latency_s=0.5)
    session = open_session(graph, options, marker_names=rec.marker_names)
    expected = []
    for k in range(rec.num_samples):
        expected += session.push(rec.timestamps_s[k], markers=rec.marker_positions[k])
    expected += session.flush()

    samples = list(C.recording_samples(rec))
    assert not samples[0].accelerations_m_s2 and len(samples[0].marker_positions_m) == 3 * len(rec.marker_names)
    feed = C.SampleFeed(
        C.stream_config("small", convert.options_to_proto(options, recording=rec), marker_names=rec.marker_names)
    )
    for s in samples:
        feed.put(s)
    feed.close()
    result = C.run_stream(conn, feed, timeout_s=60)
    assert result.started.lag_frames == session.lag_frames > 0
    assert_frames_equal(expected, result.frames)
    assert all(f.node == -1 for f in result.frames)
    for a, b in zip(expected, result.frames):
        assert [(s.clip, s.frame, s.weight) for s in b.sources] == [
            (c, pytest.approx(f), pytest.approx(w)) for c, f, w in a.sources
        ]
    assert result.finished.samples_received == rec.num_samples == result.finished.frames_emitted
    # The same lag in batch predicts the stream (to float32 precision).
    batch = reconstruct(graph, rec, options).motion
    got = result.motion()
    np.testing.assert_allclose(got.rotations, batch.rotations, atol=1e-6)
    np.testing.assert_allclose(got.translations, batch.translations, atol=1e-6)


def test_replayed_marker_recording_streams(conn, marker_recording):
    options = convert.options_to_proto(_ssg(latency_s=0.4), recording=marker_recording)  # the recording's set
    result = C.stream_recording(conn, "small", marker_recording, options, speed=100.0, timeout_s=60)
    assert len(result.frames) == marker_recording.num_samples
    assert result.started.lag_frames > 0


def test_sensors_an_ssg_input_also_carries_need_not_match_the_graph(conn, graph, marker_recording):
    """SSG reads no accelerations: a recording or stream may carry those of any sensors
    (the library ignores them, and so does the service)."""
    from graphsvc.pipeline import reconstruct

    T = marker_recording.num_samples
    acc = np.random.default_rng(0).standard_normal((T, 2, 3)).astype(np.float32)
    rec = replace(marker_recording, sensor_names=("imu_a", "imu_b"), accelerations=acc)
    options = _ssg(markers="hands-feet", latency_s=0.4)
    expected = reconstruct(graph, rec, options)
    assert expected.report["ignored_inputs"] == ["accelerations"]
    got = C.synthesize(conn, "small", rec, convert.options_to_proto(options, recording=rec))
    np.testing.assert_array_equal(got.motion.rotations, expected.motion.rotations.astype(np.float32))
    assert got.report["ignored_inputs"] == ["accelerations"]
    result = C.stream_recording(
        conn, "small", rec, convert.options_to_proto(options, recording=rec), speed=100.0, timeout_s=60
    )
    assert list(result.started.sensor_names) == ["imu_a", "imu_b"] and len(result.frames) == T
    np.testing.assert_allclose(result.motion().rotations, expected.motion.rotations, atol=1e-6)


# ---------------------------------------------------------------- bad requests


def _synthesize_cases(rec):
    markers = rec.marker_positions.ravel().tolist()
    all_nan = [float("nan")] * len(markers)
    inf = list(markers)
    inf[7] = float("inf")
    ssg = lambda **kw: pb.SynthesisOptions(strategy=pb.STRATEGY_SSG, ssg=pb.SsgOptions(**kw))  # noqa: E731
    return {  # name: (recording changes, options, what the message names)
        "unknown set": ({}, ssg(markers="no-such-set"), "options.ssg.markers"),
        "a server path": ({}, ssg(markers="/etc/passwd"), "reads no files"),
        "bad JSON": ({}, ssg(markers='{"name": "x", '), "options.ssg.markers"),
        "bad set": ({}, ssg(markers='{"markers": [{"name": "a", "segment": "tail"}]}'), "options.ssg.markers"),
        "no set": ({}, pb.SynthesisOptions(strategy=pb.STRATEGY_SSG), "options.ssg.markers"),
        "keep unknown": ({}, ssg(markers="hands-feet", keep=["l_hand", "LFHD"]), "options.ssg.keep"),
        "overlap": ({}, ssg(markers="hands-feet", window_s=0.2, overlap_s=0.15), "options.ssg.overlap_s"),
        "window": ({}, ssg(markers="hands-feet", window_s=0.0), "options.ssg.window_s"),
        "k": ({}, ssg(markers="hands-feet", k=0), "options.ssg.k"),
        "weight": ({}, ssg(markers="hands-feet", weight=float("nan")), "options.ssg.weight"),
        "offsets": ({}, ssg(markers="hands-feet", offsets="sideways"), "options.ssg.offsets"),
        "every marker missing": (
            {"marker_positions_m": all_nan},
            ssg(markers="hands-feet"),
            "missing for the whole input",
        ),
        "kept markers missing": (
            {"marker_positions_m": _blank(rec, ("l_hand",))},
            ssg(markers="hands-feet", keep=["l_hand"]),
            "missing for the whole input",
        ),
        "none of the set's": ({}, ssg(markers="head-back"), "none of the markers"),
        "marker count": (
            {"marker_positions_m": markers[:-3]},
            ssg(markers="hands-feet"),
            "recording.marker_positions_m",
        ),
        "inf marker": ({"marker_positions_m": inf}, ssg(markers="hands-feet"), "recording.marker_positions_m[7]"),
        "no markers": ({"marker_names": [], "marker_positions_m": []}, ssg(markers="hands-feet"), "needs markers"),
    }


def _blank(rec, names) -> list:
    """The recording's marker positions with the named markers NaN throughout."""
    points = rec.marker_positions.copy()
    points[:, [rec.marker_names.index(n) for n in names]] = np.nan
    return points.ravel().tolist()


def test_bad_ssg_synthesize_requests_are_invalid_argument(conn, marker_recording):
    for name, (changes, options, mention) in _synthesize_cases(marker_recording).items():
        request = pb.SynthesizeRequest(
            graph="small", recording=convert.recording_to_proto(marker_recording), options=options
        )
        for key, value in changes.items():
            del getattr(request.recording, key)[:]
            getattr(request.recording, key).extend(value)
        got, details = _code(conn.stub.Synthesize, request, timeout=30)
        assert got == INVALID, f"{name}: {got} {details}"
        assert mention in details, f"{name}: {details!r} does not name {mention!r}"


def test_bad_ssg_stream_requests_are_invalid_argument(conn, server, marker_recording):
    rec = marker_recording
    names = list(rec.marker_names)
    samples = list(C.recording_samples(rec))
    options = pb.SynthesisOptions(strategy=pb.STRATEGY_SSG, ssg=pb.SsgOptions(markers="hands-feet"))
    config = C.stream_config("small", options, marker_names=names)
    short = [pb.SensorSample(time_s=0.0, marker_positions_m=[0.0] * 11)]
    inf = [pb.SensorSample(time_s=0.0, marker_positions_m=[0.0] * 5 + [float("inf")] + [0.0] * 6)]
    blind = [pb.SensorSample(time_s=s.time_s, marker_positions_m=[float("nan")] * 12) for s in samples[:40]]

    def ssg(**kw):
        return C.stream_config(
            "small", pb.SynthesisOptions(strategy=pb.STRATEGY_SSG, ssg=pb.SsgOptions(**kw)), marker_names=names
        )

    cases = {  # name: (config, samples, what the message names)
        "marker count": (config, short, "sample[0].marker_positions_m"),
        "inf marker": (config, inf, "sample[0].marker_positions_m[5]"),
        "every marker missing": (config, blind, "sample[*].marker_positions_m"),
        "unknown set": (ssg(markers="no-such-set"), samples[:3], "config.options.ssg.markers"),
        "keep unknown": (ssg(markers="hands-feet", keep=["LFHD"]), samples[:3], "config.options.ssg.keep"),
        "overlap": (
            ssg(markers="hands-feet", window_s=0.2, overlap_s=0.15),
            samples[:3],
            "config.options.ssg.overlap_s",
        ),
        "offsets fit": (ssg(markers="hands-feet", offsets="fit"), samples[:3], "config.options"),
        "no marker names": (C.stream_config("small", options), samples[:3], "config.marker_names"),
        "duplicate names": (
            C.stream_config("small", options, marker_names=["l_hand"] * 4),
            samples[:3],
            "config.marker_names",
        ),
        "acc for a strategy that needs them": (
            C.stream_config("small", marker_names=names),
            samples[:3],
            "sample[0].accelerations_m_s2",
        ),
    }
    for name, (cfg, items, mention) in cases.items():
        got, details = _code(lambda: list(conn.stub.StreamSynthesize(_stream_requests(cfg, items), timeout=30)))
        assert got == INVALID, f"{name}: {got} {details}"
        assert mention in details, f"{name}: {details!r} does not name {mention!r}"
    # A blind start is fine as long as a kept marker shows up at some point.
    later = blind[:20] + samples[20:40]
    responses = list(conn.stub.StreamSynthesize(_stream_requests(config, later), timeout=30))
    assert responses[-1].finished.samples_received == 40


def test_an_unbuilt_strategy_still_answers_unimplemented(conn, recording, monkeypatch):
    import graphsvc.strategies as strategies

    strategies.available()  # (the built-in ones registered)
    monkeypatch.setattr(strategies, "_REGISTRY", {k: v for k, v in strategies._REGISTRY.items() if k != "nearest"})
    monkeypatch.setattr(strategies, "PLANNED", ("nearest",))
    options = pb.SynthesisOptions(strategy=pb.STRATEGY_NEAREST)
    request = pb.SynthesizeRequest(graph="small", recording=convert.recording_to_proto(recording), options=options)
    got, details = _code(conn.stub.Synthesize, request, timeout=30)
    assert got == grpc.StatusCode.UNIMPLEMENTED and "nearest" in details, details
    samples = list(C.recording_samples(recording))[:3]
    got, details = _code(
        lambda: list(
            conn.stub.StreamSynthesize(_stream_requests(C.stream_config("small", options), samples), timeout=30)
        )
    )
    assert got == grpc.StatusCode.UNIMPLEMENTED and "nearest" in details, details

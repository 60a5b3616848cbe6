"""Synthesize with calibrate_from_start: the server calibrates a device-frame recording
from its own first seconds against the graph, as `synthesize --calibrate-from-start`
does locally; `client synthesize` sends it; bad values answer INVALID_ARGUMENT."""

from __future__ import annotations

import grpc
import pytest

from tests.service.conftest import rpc_error


@pytest.fixture(scope="module")
def posed(tmp_path_factory):
    """7 s of the held-out performance after 2 s of an N-pose, every kelly6 sensor
    mounted up to 30° off (exact readings), and its file."""
    from graphsvc.motion.calibration_pose import with_calibration_pose
    from graphsvc.motion.procedural import generate_performance
    from graphsvc.sensors.layout import load_layout
    from graphsvc.sensors.noise import parse_noise
    from graphsvc.sensors.recording import save_recording
    from graphsvc.sensors.simulate import simulate_recording

    motion = with_calibration_pose(generate_performance(seed=1)[0].slice(30, 240), "npose", 2.0)
    rec = simulate_recording(motion, load_layout("kelly6"), parse_noise("none,mount=30"), seed=5)
    path = tmp_path_factory.mktemp("posed") / "posed.rec"
    save_recording(rec, path)
    return rec, path


def test_the_server_calibrates_from_the_start_as_synthesize_does(server, conn, graph, posed, tmp_path, capsys):
    from graphsvc.cli import main
    from graphsvc.motion.bvh import bvh_text
    from graphsvc.pipeline import calibrated_from_start, reconstruct
    from graphsvc.service.client import synthesize

    rec, path = posed
    assert rec.meta["sensor_frame"] == "device"
    expected = bvh_text(reconstruct(graph, calibrated_from_start(rec, graph, 5.0, "npose")).motion, scale=100.0)
    plain = bvh_text(reconstruct(graph, rec).motion, scale=100.0)
    assert expected != plain  # (the calibration changes the outcome: the test can tell)
    got = synthesize(conn, "small", rec, calibrate_from_start=(5.0, "npose"))
    assert got.bvh.decode() == expected
    out = tmp_path / "c.bvh"
    common = ["--server", f"127.0.0.1:{server.port}"]
    assert (
        main(
            [
                "client",
                "synthesize",
                str(path),
                "-o",
                str(out),
                *common,
                "--calibrate-from-start",
                "5",
                "--pose",
                "npose",
            ]
        )
        == 0
    )
    assert out.read_text() == expected
    capsys.readouterr()
    assert main(["client", "synthesize", str(path), "-o", str(out), *common, "--calibrate-from-start", "5"]) == 2
    assert "needs --pose" in capsys.readouterr().err


@pytest.mark.parametrize(
    "seconds, pose, needle",
    [
        (0.0, "npose", "finite number of seconds > 0"),
        (4000.0, "npose", "at most 3600"),
        (5.0, "sitting", "unknown pose"),
        (1.0, "npose", "calibration needs at least 2 s"),
    ],
)
def test_bad_calibrate_from_start_is_invalid_argument(conn, posed, seconds, pose, needle):
    from graphsvc.service._generated import graphsvc_pb2 as pb
    from graphsvc.service.convert_recording import recording_to_proto

    request = pb.SynthesizeRequest(graph="small", recording=recording_to_proto(posed[0]))
    request.calibrate_from_start.seconds, request.calibrate_from_start.pose = seconds, pose
    code, details = rpc_error(conn.stub.Synthesize, request, timeout=60)
    assert (
        code == grpc.StatusCode.INVALID_ARGUMENT and details.startswith("calibrate_from_start: ") and needle in details
    )


def test_a_stream_calibrates_from_its_own_first_seconds(conn, graph, posed, capsys, server):
    """The server holds the first 5 s, calibrates from them and then searches every
    sample calibrated: the frames of a stream of the recording calibrated beforehand."""
    from graphsvc.cli import main
    from graphsvc.pipeline import Options, calibrated_from_start
    from graphsvc.service import client as C
    from tests.service.conftest import assert_frames_equal, live_frames

    rec, path = posed
    expected, _ = live_frames(graph, calibrated_from_start(rec, graph, 5.0, "npose"), Options())
    plain, _ = live_frames(graph, rec, Options())
    assert [f.node for f in plain] != [f.node for f in expected]  # (the calibration changes the outcome)
    feed = C.SampleFeed(C.stream_config("small", calibrate_from_start=(5.0, "npose")))
    for sample in C.recording_samples(rec):
        feed.put(sample)
    feed.close()
    result = C.run_stream(conn, feed)
    assert_frames_equal(expected, result.frames)
    assert result.finished.samples_received == rec.num_samples
    # The client's stream command sends it; a stream shorter than its calibrating seconds
    # is calibrated from what it sent (here too short for one: INVALID_ARGUMENT, named).
    common = ["--server", f"127.0.0.1:{server.port}", "--speed", "1000", "--quiet"]
    assert main(["client", "stream", str(path), *common, "--calibrate-from-start", "5", "--pose", "npose"]) == 0
    assert f"{len(expected)} frames from {rec.num_samples} samples" in capsys.readouterr().out
    feed = C.SampleFeed(C.stream_config("small", calibrate_from_start=(5.0, "npose")))
    for sample in list(C.recording_samples(rec))[:40]:
        feed.put(sample)
    feed.close()
    with pytest.raises(C.ServiceError, match="INVALID_ARGUMENT: config.calibrate_from_start: .* needs at least 2 s"):
        C.run_stream(conn, feed)
    for value, needle in (
        ((5.0, "sitting"), "pose: unknown pose"),
        ((4000.0, "npose"), "seconds: must be .* at most 3600"),
    ):
        feed = C.SampleFeed(C.stream_config("small", calibrate_from_start=value))
        feed.close()
        with pytest.raises(C.ServiceError, match=f"INVALID_ARGUMENT: config.calibrate_from_start.{needle}"):
            C.run_stream(conn, feed)

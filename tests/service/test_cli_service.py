"""`graphsvc serve` as a process (token file, port 0, SIGTERM drain) and the
`graphsvc client` commands against it."""

from __future__ import annotations

import json
import re
import signal
import time

import grpc
import pytest

from graphsvc.cli import main
from graphsvc.service import client as C
from tests.service.conftest import popen_cli, run_cli


@pytest.fixture
def served(graph_file, tmp_path):
    token = tmp_path / "token"
    token.write_text("# the service's token\nabc123\n")
    proc = popen_cli(
        "serve",
        "--graph",
        f"small={graph_file}",
        "--host",
        "127.0.0.1",
        "--port",
        "0",
        "--token-file",
        token,
        "--grace-s",
        "10",
        "--max-streams",
        "2",
    )
    line = proc.stdout.readline()
    match = re.search(r"listening on 127\.0\.0\.1:(\d+)", line)
    assert match, line + proc.stderr.read() if proc.poll() is not None else line
    yield proc, f"127.0.0.1:{match.group(1)}", token
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def test_client_commands(served, rec_file, graph, recording, marker_rec_file, marker_recording, tmp_path, capsys):
    from graphsvc.motion.bvh import bvh_text
    from graphsvc.pipeline import Options, reconstruct
    from graphsvc.strategies.options import Weights

    _, address, token = served
    common = ["--server", address, "--token-file", str(token)]
    assert main(["client", "graphs", *common]) == 0
    assert capsys.readouterr().out.startswith("small: 2,")
    assert main(["client", "graphs", *common, "--graph", "small", "--json"]) == 0
    assert '"layout": "kelly6"' in capsys.readouterr().out

    out = tmp_path / "batch.bvh"
    assert main(["client", "synthesize", str(rec_file), "-o", str(out), *common, "--weights", "0.5,1,1"]) == 0
    assert f"wrote {out}: {recording.num_samples} frames" in capsys.readouterr().out
    expected = reconstruct(graph, recording, Options(weights=Weights(0.5, 1, 1)))
    assert out.read_text() == bvh_text(expected.motion, scale=100.0)
    # glTF: the returned motion as a skinned skeleton, its joints where the BVH's are.
    from graphsvc.motion.kinematics import motion_fk
    from tests.motion.test_gltf import TOLERANCE_M, gltf_positions

    glb = tmp_path / "batch.glb"
    assert main(["client", "synthesize", str(rec_file), "-o", str(glb), *common, "--weights", "0.5,1,1"]) == 0
    assert f"wrote {glb}" in capsys.readouterr().out
    _, got = gltf_positions(glb, graph.rate_hz, recording.num_samples)
    assert abs(got - motion_fk(expected.motion)[1]).max() < TOLERANCE_M

    live = tmp_path / "live.bvh"
    assert main(["client", "stream", str(rec_file), "-o", str(live), *common, "--speed", "30", "--latency", "0.3"]) == 0
    printed = capsys.readouterr().out.splitlines()
    frames = [line for line in printed if line.startswith("frame ")]
    assert len(frames) == recording.num_samples and "latency" in frames[0]
    assert re.search(r"p50 [\d.]+ ms, p99 [\d.]+ ms", printed[-2])
    assert live.stat().st_size > 0

    # Errors: one line, exit 2.
    assert main(["client", "graphs", "--server", address]) == 2
    assert "UNAUTHENTICATED" in capsys.readouterr().err
    assert (
        main(
            [
                "client",
                "synthesize",
                str(rec_file),
                "-o",
                str(out),
                *common,
                "--strategy",
                "ssg",
                "--markers",
                "hands-feet",
            ]
        )
        == 2
    )  # (an accelerometer recording: no markers)
    assert "INVALID_ARGUMENT" in (err := capsys.readouterr().err) and "needs markers" in err, err

    # SSG: a marker-only recording, the set by name or from a file (sent as its content).
    from graphsvc.sensors.markers import PRESETS
    from graphsvc.strategies.ssg.options import SsgOptions

    set_file = tmp_path / "feet.json"
    set_file.write_text(json.dumps({**PRESETS["hands-feet"].to_dict(), "name": "feet"}))
    for flags, ssg in (
        (["--markers", "hands-feet"], SsgOptions(markers="hands-feet")),
        (
            ["--markers", str(set_file), "--keep", "l_foot,r_foot", "--ssg-k", "4"],
            SsgOptions(markers=str(set_file), keep=("l_foot", "r_foot"), k=4),
        ),
    ):
        assert (
            main(["client", "synthesize", str(marker_rec_file), "-o", str(out), *common, "--strategy", "ssg", *flags])
            == 0
        )
        assert f"{marker_recording.num_samples} frames" in capsys.readouterr().out
        expected = reconstruct(graph, marker_recording, Options(strategy="ssg", ssg=ssg))
        assert out.read_text() == bvh_text(expected.motion, scale=100.0)
    # Live, with the marker set the recording names.
    assert (
        main(
            [
                "client",
                "stream",
                str(marker_rec_file),
                "-o",
                str(live),
                *common,
                "--speed",
                "30",
                "--strategy",
                "ssg",
                "--latency",
                "0.5",
                "--quiet",
            ]
        )
        == 0
    )
    assert (
        f"{marker_recording.num_samples} frames from {marker_recording.num_samples} samples" in capsys.readouterr().out
    )


def test_client_commands_apply_a_calibration_before_sending(served, graph, recording, tmp_path, capsys):
    from dataclasses import replace

    import numpy as np

    from graphsvc.motion import quat
    from graphsvc.motion.bvh import bvh_text
    from graphsvc.pipeline import reconstruct
    from graphsvc.sensors.calibration import apply_calibration, load_calibration
    from graphsvc.sensors.device_model import mounting
    from graphsvc.sensors.recording import save_recording

    _, address, token = served
    common = ["--server", address, "--token-file", str(token)]
    M = mounting(4, recording.sensor_names, 60.0)
    mounted = replace(
        recording,
        accelerations=quat.inv_rotate(M[None], recording.accelerations.astype(float)).astype(np.float32),
        meta={**recording.meta, "sensor_frame": "device"},
    )
    rec_file = tmp_path / "mounted.rec"
    save_recording(mounted, rec_file)
    cal_file = tmp_path / "cal.json"
    cal_file.write_text(
        json.dumps(
            {
                "format": "graphsvc-calibration",
                "version": 1,
                "sensors": {n: {"rotation_wxyz": M[k].tolist()} for k, n in enumerate(recording.sensor_names)},
            }
        )
    )
    out = tmp_path / "cal.bvh"
    assert main(["client", "synthesize", str(rec_file), "-o", str(out), *common, "--calibration", str(cal_file)]) == 0
    capsys.readouterr()
    expected = reconstruct(graph, apply_calibration(mounted, load_calibration(cal_file)))
    assert out.read_text() == bvh_text(expected.motion, scale=100.0)
    assert (
        main(["client", "stream", str(rec_file), *common, "--speed", "30", "--quiet", "--calibration", str(cal_file)])
        == 0
    )
    assert f"{recording.num_samples} frames" in capsys.readouterr().out
    cal_file.write_text("[]")
    assert main(["client", "stream", str(rec_file), *common, "--calibration", str(cal_file)]) == 2
    assert "not a graphsvc calibration" in capsys.readouterr().err


def _health(address: str) -> str:
    from grpc_health.v1 import health_pb2, health_pb2_grpc

    with grpc.insecure_channel(address) as channel:
        answer = health_pb2_grpc.HealthStub(channel).Check(health_pb2.HealthCheckRequest(), timeout=10)
    return health_pb2.HealthCheckResponse.ServingStatus.Name(answer.status)


def test_sigterm_drains_in_flight_streams_then_exits_0(served, recording):
    proc, address, token = served
    with C.connect(address, token=C.read_token_file(token)) as conn:
        feed = C.SampleFeed(C.stream_config("small"))
        samples = list(C.recording_samples(recording))
        call = conn.stub.StreamSynthesize(iter(feed), metadata=conn.metadata, timeout=30)
        responses = iter(call)
        assert next(responses).WhichOneof("message") == "started"
        for s in samples[:10]:
            feed.put(s)
        proc.send_signal(signal.SIGTERM)
        assert "stopping, 1 stream(s) in flight" in proc.stdout.readline()
        time.sleep(0.2)
        # New calls are refused while draining, health checks answered NOT_SERVING
        # (open without the token); the running stream goes on to the end.
        with pytest.raises(C.ServiceError) as info:
            C.list_graphs(conn, timeout_s=5)
        assert info.value.code == grpc.StatusCode.UNAVAILABLE
        assert _health(address) == "NOT_SERVING"
        for s in samples[10:]:
            feed.put(s)
        feed.close()
        kinds = [r.WhichOneof("message") for r in responses]
        assert kinds.count("frame") == recording.num_samples and kinds[-1] == "finished"
    assert proc.wait(timeout=15) == 0
    assert "stopped" in proc.stdout.read()


def test_serve_refuses_bad_arguments(graph_file, tmp_path, capsys):
    empty = tmp_path / "empty-token"
    empty.write_text("\n# nothing\n")
    cases = {  # arguments → what the one-line error must mention
        ("--graph", "nofile"): "NAME=FILE",
        ("--graph", f"a={tmp_path / 'missing.graph'}"): "missing.graph",
        ("--graph", f"a={graph_file}", "--tls-cert", str(graph_file)): "--tls-key",
        ("--graph", f"a={graph_file}", "--token-file", str(empty)): "no token",
        ("--graph", f"a={graph_file}", "--graph", f"a={graph_file}"): "twice",
    }
    for args, mention in cases.items():
        assert main(["serve", "--port", "0", *args]) == 2, args
        err = capsys.readouterr().err
        assert mention in err and err.count("\n") == 1, (args, err)


def test_serve_fails_fast_on_a_taken_port_or_bad_address(server, tmp_path, capsys):
    """The port is bound before any graph loads: the graph named here does not exist,
    so an error about the address proves the bind came first."""
    import socket

    missing = f"a={tmp_path / 'missing.graph'}"
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as held:
        held.bind(("127.0.0.1", 0))
        held.listen(1)
        plain = held.getsockname()[1]
        cases = {  # arguments → what the one-line error must mention
            ("--host", "127.0.0.1", "--port", str(plain)): f"cannot listen on 127.0.0.1:{plain}",
            ("--host", "127.0.0.1", "--port", str(server.port)): f"cannot listen on 127.0.0.1:{server.port}",
            ("--host", "256.1.1.1", "--port", "0"): "cannot listen on 256.1.1.1",
            ("--port", "99999"): "0–65535",
            ("--port", "-1"): "0–65535",
        }
        for args, mention in cases.items():
            assert main(["serve", "--graph", missing, *args]) == 2, args
            err = capsys.readouterr().err
            assert mention in err and "missing.graph" not in err and err.count("\n") == 1, (args, err)
    # the address is free again once that server is gone: the graph error now shows
    assert main(["serve", "--graph", missing, "--host", "127.0.0.1", "--port", str(plain)]) == 2
    assert "missing.graph" in capsys.readouterr().err


def test_grpc_port_reuse_is_off(server, monkeypatch, capfd):
    """A second gRPC server on the very port of a running one must fail to bind, even
    past the plain-socket check (gRPC's own SO_REUSEPORT is off), in one line with
    the reason gRPC logged, and its log line kept off stderr."""
    import errno
    import os

    from graphsvc.errors import GraphsvcError
    from graphsvc.service import server as S
    from graphsvc.service.server import ServerConfig, bind_server

    monkeypatch.setattr(S, "check_address", lambda host, port: None)
    capfd.readouterr()
    with pytest.raises(GraphsvcError) as info:
        bind_server(ServerConfig(host="127.0.0.1", port=server.port))
    assert str(info.value) == f"cannot listen on 127.0.0.1:{server.port}: {os.strerror(errno.EADDRINUSE)}"
    assert capfd.readouterr().err == ""


def test_serve_on_an_address_not_of_this_machine_says_why_in_one_line(graph_file):
    """Port 0 as well as a fixed port: exit 2 and one line with the reason; gRPC's own
    `E… add_port.cc] Failed to add port` line must not reach stderr."""
    import errno
    import os
    import socket

    host = "192.0.2.1"  # TEST-NET-1 (RFC 5737): for documentation, no machine's address
    with socket.socket() as probe:
        try:
            probe.bind((host, 0))
            pytest.skip(f"{host} is an address of this machine")
        except OSError:
            pass
    for port in (0, 50999):
        result = run_cli("serve", "--graph", f"a={graph_file}", "--host", host, "--port", port, "--live-workers", 0)
        assert result.returncode == 2, result.stderr
        assert result.stderr == f"graphsvc: error: cannot listen on {host}:{port}: {os.strerror(errno.EADDRNOTAVAIL)}\n"


# The serve command with its graph loading held until the test says so: it prints the
# bound port first (the listening line comes once the graphs are served).
_HELD_LOAD = """
import sys
import graphsvc.service.graphs as G
import graphsvc.service.server as S
from graphsvc.cli import main

bind, load = S.bind_server, G.load_graphs

def bound_then_printed(config):
    bound = bind(config)
    print("bound", bound.port, flush=True)
    return bound

def held_load(specs):
    with open(sys.argv[1]) as gate:  # blocks until the test opens the FIFO for writing
        gate.read()
    return load(specs)

S.bind_server, G.load_graphs = bound_then_printed, held_load
sys.exit(main(sys.argv[2:]))
"""


def test_serve_answers_health_not_serving_while_its_graphs_load(graph_file, tmp_path):
    import os
    import subprocess
    import sys

    from tests.service.conftest import ROOT, _env, wait_for

    gate = tmp_path / "gate"
    os.mkfifo(gate)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            _HELD_LOAD,
            str(gate),
            "serve",
            "--graph",
            f"small={graph_file}",
            "--host",
            "127.0.0.1",
            "--port",
            "0",
            "--live-workers",
            "0",
        ],
        cwd=ROOT,
        env=_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline()
        assert line.startswith("bound "), line + proc.stderr.read()
        address = f"127.0.0.1:{int(line.split()[1])}"
        assert _health(address) == "NOT_SERVING"  # the load waits on the FIFO meanwhile
        with C.connect(address) as conn:
            with pytest.raises(C.ServiceError) as info:
                C.list_graphs(conn, timeout_s=10)
            assert info.value.code == grpc.StatusCode.UNAVAILABLE and "loading its graphs" in str(info.value)
            writer = []

            def opened() -> bool:  # (the server opens its end once its load starts)
                assert proc.poll() is None, proc.stderr.read()
                try:
                    writer.append(os.open(gate, os.O_WRONLY | os.O_NONBLOCK))
                except OSError:
                    return False
                return True

            wait_for(opened, timeout_s=30)
            os.close(writer[0])  # the load goes on
            assert "listening on" in proc.stdout.readline()
            assert _health(address) == "SERVING"
            assert [g.name for g in C.list_graphs(conn, timeout_s=10)] == ["small"]
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_client_commands_name_a_devices_sensors_with_a_device_map(served, graph, recording, tmp_path, capsys):
    """A CSV whose sensors a device named (generic spellings, another order) is renamed
    by --device-map before it is sent: the same motion as the recording named as the
    layout does; without the map the server refuses it, advising one."""
    from dataclasses import replace

    from graphsvc.motion.bvh import bvh_text
    from graphsvc.pipeline import reconstruct
    from graphsvc.sensors.recording import export_csv, import_csv

    _, address, token = served
    common = ["--server", address, "--token-file", str(token)]
    export_csv(recording, tmp_path / "named.csv")
    device = {
        "l_forearm": "LeftForearm",
        "r_forearm": "forearm_r",
        "l_shin": "left-shin",
        "r_shin": "RShin",
        "lower_back": "Lower_Back",
        "chest": "CHEST",
    }
    cols = [5, 0, 3, 1, 4, 2]
    renamed = replace(
        recording,
        sensor_names=tuple(device[recording.sensor_names[c]] for c in cols),
        accelerations=recording.accelerations[:, cols],
    )
    export_csv(renamed, tmp_path / "device.csv")
    expected = bvh_text(reconstruct(graph, import_csv(tmp_path / "named.csv")).motion, scale=100.0)

    out = tmp_path / "mapped.bvh"
    assert (
        main(["client", "synthesize", str(tmp_path / "device.csv"), "-o", str(out), *common, "--device-map", "generic"])
        == 0
    )
    assert f"wrote {out}: {recording.num_samples} frames" in capsys.readouterr().out
    assert out.read_text() == expected
    assert (
        main(
            [
                "client",
                "stream",
                str(tmp_path / "device.csv"),
                *common,
                "--speed",
                "30",
                "--quiet",
                "--device-map",
                "generic",
            ]
        )
        == 0
    )
    assert f"{recording.num_samples} frames from {recording.num_samples} samples" in capsys.readouterr().out

    assert main(["client", "synthesize", str(tmp_path / "device.csv"), "-o", str(out), *common]) == 2
    err = capsys.readouterr().err
    assert "not in the graph: CHEST" in err and "--device-map (xsens, mvn, generic or a map file)" in err
    assert (
        main(["client", "synthesize", str(tmp_path / "device.csv"), "-o", str(out), *common, "--device-map", "mvn"])
        == 2
    )  # (MVN names none of these)
    assert "the mvn device map names none of the recording's sensors (CHEST, LeftForearm" in capsys.readouterr().err

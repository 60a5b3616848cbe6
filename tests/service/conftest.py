"""Fixtures of the service tests: a small graph built once from the procedural
knowledge base, a few seconds of simulated input, and real servers on loopback
ephemeral ports (no mocks of gRPC)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def graph_file(tmp_path_factory) -> Path:
    from graphsvc.graph.build import BuildOptions, build_graph
    from graphsvc.graph.file import save_graph
    from graphsvc.motion.procedural import generate_knowledge_base
    from graphsvc.sensors.layout import load_layout

    kb = generate_knowledge_base(seed=0, minutes=0.5)
    graph, _ = build_graph(kb, BuildOptions(layout=load_layout("kelly6")))
    path = tmp_path_factory.mktemp("graph") / "small.graph"
    save_graph(graph, path)
    return path


@pytest.fixture(scope="session")
def loaded_graphs(graph_file):
    from graphsvc.service.graphs import load_graphs

    return load_graphs([f"small={graph_file}"])


@pytest.fixture(scope="session")
def graph(loaded_graphs):
    return loaded_graphs["small"].graph


@pytest.fixture(scope="session")
def recording():
    """3 s of the held-out procedural performance, exact kelly6 readings, ground
    position and heading."""
    from graphsvc.motion.procedural import generate_performance
    from graphsvc.sensors.layout import load_layout
    from graphsvc.sensors.noise import PRESETS
    from graphsvc.sensors.simulate import simulate_recording

    motion = generate_performance(seed=1)[0].slice(30, 120)
    return simulate_recording(motion, load_layout("kelly6"), PRESETS["none"], seed=0)


@pytest.fixture(scope="session")
def rec_file(recording, tmp_path_factory) -> Path:
    from graphsvc.sensors.recording import save_recording

    path = tmp_path_factory.mktemp("rec") / "perf.rec"
    save_recording(recording, path)
    return path


@pytest.fixture(scope="session")
def marker_recording():
    """The same 3 s of the held-out performance (not in the graph) as the hands-feet
    markers would have been tracked: no accelerations, a 20-frame gap of every marker
    and 10 % flicker."""
    from graphsvc.motion.procedural import generate_performance
    from graphsvc.sensors.noise import parse_noise
    from graphsvc.sensors.simulate import MarkerPattern, simulate_marker_recording

    motion = generate_performance(seed=1)[0].slice(30, 120)
    pattern = MarkerPattern(gaps=((10, 20),), flicker=0.1)
    return simulate_marker_recording(motion, "hands-feet", parse_noise("none"), seed=0, pattern=pattern)


@pytest.fixture(scope="session")
def marker_rec_file(marker_recording, tmp_path_factory) -> Path:
    from graphsvc.sensors.recording import save_recording

    path = tmp_path_factory.mktemp("rec") / "markers.rec"
    save_recording(marker_recording, path)
    return path


def start(loaded_graphs, **config):
    from graphsvc.service.server import ServerConfig, start_server

    return start_server(loaded_graphs, ServerConfig(host="127.0.0.1", port=0, **config))


@pytest.fixture(scope="session")
def server(loaded_graphs):
    """An open server (no token, no TLS) shared by the tests that do not change it."""
    running = start(loaded_graphs, max_streams=4)
    yield running
    running.stop(0)


@pytest.fixture
def conn(server):
    from graphsvc.service.client import connect

    with connect(f"127.0.0.1:{server.port}") as c:
        yield c


def live_frames(graph, recording, options):
    """What a LiveSession returns for the recording's samples, pushed in order."""
    from graphsvc.pipeline import open_session

    session = open_session(graph, options, recording.sensor_names)
    frames = []
    for k in range(recording.num_samples):
        frames += session.push(
            recording.timestamps_s[k], recording.accelerations[k], recording.ground_position[k], recording.heading[k]
        )
    return frames + session.flush(), session


def run_cli(*args, timeout=60, **kwargs) -> subprocess.CompletedProcess:
    """`python -m graphsvc.cli ARGS` (graphsvc as a process)."""
    return subprocess.run(
        [sys.executable, "-m", "graphsvc.cli", *map(str, args)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
        env=_env(),
        check=False,
        **kwargs,
    )


def popen_cli(*args, **kwargs) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "graphsvc.cli", *map(str, args)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(),
        **kwargs,
    )


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def assert_frames_equal(expected, received) -> None:
    """pipeline Frames vs PoseFrame protos: same frames, nodes, labels, poses."""
    assert [f.index for f in received] == [f.index for f in expected]
    assert [f.node for f in received] == [f.node for f in expected]
    assert [f.label for f in received] == [f.label for f in expected]
    for a, b in zip(expected, received):
        assert b.time_s == pytest.approx(a.time_s, abs=1e-9)
        np.testing.assert_array_equal(np.array(b.rotations_wxyz, np.float32), a.rotations.ravel())
        np.testing.assert_array_equal(np.array(b.translations_m, np.float32), a.translations.ravel())


def wait_for(condition, timeout_s: float = 5.0) -> None:
    """Poll condition() until it holds; AssertionError after timeout_s."""
    import time

    end = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > end:
            raise AssertionError("condition not reached in time")
        time.sleep(0.02)


def rpc_error(call, *args, **kwargs):
    """(status code, details) of the RpcError a call (unary, or a stream read to its end)
    raises."""
    import grpc

    from graphsvc.service._generated import graphsvc_pb2 as pb

    with pytest.raises(grpc.RpcError) as info:
        result = call(*args, **kwargs)
        if hasattr(result, "__iter__") and not isinstance(result, pb.SynthesizeResponse):
            list(result)
    return info.value.code(), info.value.details()


def stream_requests(config, samples):
    """A StreamSynthesize request iterator: the config, then each sample."""
    from graphsvc.service._generated import graphsvc_pb2 as pb

    yield pb.StreamSynthesizeRequest(config=config)
    for s in samples:
        yield pb.StreamSynthesizeRequest(sample=s)


def scrape(port: int) -> dict:
    """The metrics endpoint on 127.0.0.1:port: (name, sorted label pairs) → value."""
    import urllib.request

    from prometheus_client.parser import text_string_to_metric_families

    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10) as response:
        text = response.read().decode()
    return {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
    }


def nearest_options():
    """SynthesisOptions of the `nearest` strategy: the cheapest live session, for tests
    of what carries the streams rather than what they compute."""
    from graphsvc.pipeline import Options
    from graphsvc.service.convert import options_to_proto

    return options_to_proto(Options(strategy="nearest"))


class VmcReceiver:
    """A VMC receiver on 127.0.0.1 (python-osc's UDP server): the messages of each
    frame, the frame ending at /VMC/Ext/T."""

    def __init__(self):
        import socket
        import threading

        from pythonosc.dispatcher import Dispatcher
        from pythonosc.osc_server import ThreadingOSCUDPServer

        self.frames: list[dict] = []
        self._current: dict = {"bones": {}}
        dispatcher = Dispatcher()
        dispatcher.set_default_handler(self._message)
        self.server = ThreadingOSCUDPServer(("127.0.0.1", 0), dispatcher)
        self.server.socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)  # (no frame dropped)
        self.port = self.server.server_address[1]
        self.lock = threading.Lock()
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def _message(self, address, *args):
        with self.lock:
            if address == "/VMC/Ext/Root/Pos":
                self._current["root"] = (args[0], np.array(args[1:4]), np.array(args[4:8]))
            elif address == "/VMC/Ext/Bone/Pos":
                self._current["bones"][args[0]] = (np.array(args[1:4]), np.array(args[4:8]))
            elif address == "/VMC/Ext/OK":
                self._current["ok"] = args
            elif address == "/VMC/Ext/T":
                self._current["t"] = args[0]
                self.frames.append(self._current)
                self._current = {"bones": {}}

    def close(self):
        self.server.shutdown()
        self.server.server_close()


@pytest.fixture
def vmc_receiver():
    r = VmcReceiver()
    yield r
    r.close()

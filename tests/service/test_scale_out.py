"""Two servers behind one client channel (`--server A,B`, gRPC's round_robin): streams
spread over both, a server killed mid-stream ends only its own streams (UNAVAILABLE),
new streams go to the survivor; an unreachable address is a warning, none answering
is one line and exit 2."""

from __future__ import annotations

import os
import re
import signal
import socket
import threading

import pytest

from graphsvc.service import client as C
from graphsvc.service.servers import NoServerAnswers, parse_servers
from tests.service.conftest import nearest_options, popen_cli, start, wait_for


def _serve(graph_file):
    return popen_cli(
        "serve",
        "--graph",
        f"small={graph_file}",
        "--host",
        "127.0.0.1",
        "--port",
        "0",
        "--live-workers",
        "0",
        "--max-streams",
        "16",
        "--grace-s",
        "0",
    )


def _port(proc) -> int:
    line = proc.stdout.readline()
    match = re.search(r"listening on 127\.0\.0\.1:(\d+)", line)
    assert match, line + (proc.stderr.read() if proc.poll() is not None else "")
    return int(match.group(1))


def _free_port() -> int:
    """A port nothing listens on (bound, then let go)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def two_servers(graph_file, loaded_graphs):
    """The server to be killed, a process of its own, and the survivor, in this one
    (it starts at once on the graphs the tests have loaded)."""
    proc = _serve(graph_file)
    survivor = start(loaded_graphs, max_streams=16)
    try:
        yield (proc, survivor), [_port(proc), survivor.port]
    finally:
        survivor.stop(0)
        if proc.poll() is None:
            proc.kill()
        proc.wait()


class _Stream:
    """A live stream on its own thread: its feed, its call, and how it ended."""

    def __init__(self, conn):
        self.feed = C.SampleFeed(C.stream_config("small", nearest_options()))
        self.call = None
        self.result = self.error = None
        self.thread = threading.Thread(target=self._run, args=(conn,), daemon=True)
        self.thread.start()

    def _run(self, conn):
        try:
            self.result = C.run_stream(conn, self.feed, on_call=lambda call: setattr(self, "call", call))
        except C.ServiceError as exc:
            self.error = exc

    def server_pid(self) -> int:
        wait_for(lambda: self.call is not None)
        value = dict(self.call.initial_metadata())["graphsvc-server"]  # (waits for the server's headers)
        return int(value.rsplit(" ", 1)[1])


def test_streams_spread_and_survive_a_server(two_servers, recording, capsys):
    (proc, _), ports = two_servers
    pids = [proc.pid, os.getpid()]
    samples = list(C.recording_samples(recording))[:45]
    with C.connect(",".join(f"127.0.0.1:{p}" for p in ports)) as conn:
        assert C.resolve_graph(conn, None).name == "small"
        streams = [_Stream(conn) for _ in range(16)]
        held = [s.server_pid() for s in streams]
        assert set(held) <= set(pids)
        assert 6 <= held.count(pids[0]) <= 10, held  # 8/8 ± 2
        for s in streams:
            for sample in samples[:15]:
                s.feed.put(sample)
        # Mid-stream: the first server dies.
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        for s in streams:
            for sample in samples[15:]:
                s.feed.put(sample)
            s.feed.close()
        for s in streams:
            s.thread.join(30)
        for s, pid in zip(streams, held):
            if pid == pids[0]:
                assert s.error is not None and s.error.code.name == "UNAVAILABLE", s.error
            else:
                assert s.error is None and s.result.finished.samples_received == len(samples)
                assert len(s.result.frames) == s.result.finished.frames_emitted > 0
                assert s.result.server.endswith(f"pid {pids[1]}")
        # New streams go to the survivor.
        fresh = [_Stream(conn) for _ in range(4)]
        assert [s.server_pid() for s in fresh] == [pids[1]] * 4
        for s in fresh:
            s.feed.close()
            s.thread.join(30)
            assert s.error is None

    # The command line: the dead address is named in a warning and the call goes on;
    # none answering is one line and exit 2.
    from graphsvc.cli import main

    dead = f"127.0.0.1:{ports[0]}"
    assert main(["client", "graphs", "--server", f"{dead},127.0.0.1:{ports[1]}"]) == 0
    printed = capsys.readouterr()
    assert printed.out.startswith("small: ")
    assert re.fullmatch(
        rf"graphsvc: warning: server {dead} does not answer \(UNAVAILABLE: .+\); carrying on with "
        rf"127\.0\.0\.1:{ports[1]}\n",
        printed.err,
    ), printed.err
    assert main(["client", "graphs", "--server", f"{dead},127.0.0.1:{_free_port()}"]) == 2
    printed = capsys.readouterr()
    assert printed.out == ""
    assert re.fullmatch(rf"graphsvc: error: no server answers: {dead} \(UNAVAILABLE: .+\); .+\n", printed.err), (
        printed.err
    )


def test_server_lists_parse():
    assert parse_servers("127.0.0.1:5001,127.0.0.1:5002").target == "ipv4:127.0.0.1:5001,127.0.0.1:5002"
    assert parse_servers("localhost:5001, 127.0.0.1:5002").target == "ipv4:127.0.0.1:5001,127.0.0.1:5002"
    listed = parse_servers("[::1]:5001,127.0.0.1:5002")
    assert listed.target == "ipv6:[::1]:5001,[::ffff:127.0.0.1]:5002"
    assert listed.addresses == ("[::1]:5001", "127.0.0.1:5002")
    one = parse_servers("players.example:50051")  # (a name: gRPC resolves it, round_robin over its records)
    assert one.target == "players.example:50051" and one.addresses == ("players.example:50051",)
    assert parse_servers("dns:///players.example:50051").target == "dns:///players.example:50051"
    assert parse_servers("ipv4:10.0.0.1:1,10.0.0.2:2").addresses == ("10.0.0.1:1", "10.0.0.2:2")
    for bad, said in [
        ("a:1,,b:2", "empty address"),
        ("a:1,b", "HOST:PORT"),
        ("a:70000,b:1", "port 1–65535"),
        ("::1:5,a:1", "brackets"),
        ("", "empty"),
        ("ipv4:10.0.0.1", "HOST:PORT"),
    ]:
        with pytest.raises(Exception, match=said):
            parse_servers(bad)


def test_no_server_answers_is_an_input_error():
    with pytest.raises(NoServerAnswers, match=r"no server answers: 127\.0\.0\.1:\d+ \(UNAVAILABLE"):
        C.connect(f"127.0.0.1:{_free_port()},127.0.0.1:{_free_port()}", warn=lambda line: None)


def test_the_envoy_front_checks_the_servers_health_and_never_cuts_a_stream():
    import yaml

    from graphsvc.service.server import SERVICE_NAME
    from tests.service.conftest import ROOT

    config = yaml.safe_load((ROOT / "deploy" / "envoy.yaml").read_text())
    (cluster,) = config["static_resources"]["clusters"]
    assert cluster["health_checks"][0]["grpc_health_check"]["service_name"] == SERVICE_NAME
    assert cluster["lb_policy"] in ("LEAST_REQUEST", "ROUND_ROBIN")
    (listener,) = config["static_resources"]["listeners"]
    manager = listener["filter_chains"][0]["filters"][0]["typed_config"]
    assert manager["codec_type"] == "HTTP2" and manager["stream_idle_timeout"] == "0s"
    (route,) = manager["route_config"]["virtual_hosts"][0]["routes"]
    assert route["route"]["cluster"] == cluster["name"] and route["route"]["timeout"] == "0s"

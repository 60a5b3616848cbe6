"""Bearer-token authentication and TLS, on real servers."""

from __future__ import annotations

import shutil
import subprocess

import grpc
import pytest

from graphsvc.service import client as C
from graphsvc.service._generated import graphsvc_pb2 as pb
from tests.service.conftest import start

TOKEN = "s3cret-token"


@pytest.fixture(scope="module")
def token_server(loaded_graphs):
    running = start(loaded_graphs, tokens=(TOKEN, "rotated-token"))
    yield running
    running.stop(0)


def _status(fn):
    with pytest.raises(C.ServiceError) as info:
        fn()
    return info.value.code


def test_token_accepted(token_server):
    for token in (TOKEN, "rotated-token"):
        with C.connect(f"127.0.0.1:{token_server.port}", token=token) as conn:
            assert [g.name for g in C.list_graphs(conn)] == ["small"]


@pytest.mark.parametrize("token", [None, "wrong", TOKEN + "x", ""])
def test_missing_or_wrong_token_is_unauthenticated(token_server, recording, token):
    with C.connect(f"127.0.0.1:{token_server.port}", token=token) as conn:
        assert _status(lambda: C.list_graphs(conn)) == grpc.StatusCode.UNAUTHENTICATED
        assert _status(lambda: C.synthesize(conn, "small", recording)) == grpc.StatusCode.UNAUTHENTICATED
        feed = C.SampleFeed(C.stream_config("small"))
        feed.close()
        assert _status(lambda: C.run_stream(conn, feed, timeout_s=10)) == grpc.StatusCode.UNAUTHENTICATED


def test_wrong_scheme_is_unauthenticated(token_server):
    from graphsvc.service._generated.graphsvc_pb2_grpc import MotionGraphServiceStub

    with grpc.insecure_channel(f"127.0.0.1:{token_server.port}") as channel:
        call = MotionGraphServiceStub(channel).ListGraphs
        with pytest.raises(grpc.RpcError) as info:
            call(pb.ListGraphsRequest(), metadata=(("authorization", f"Basic {TOKEN}"),), timeout=5)
        assert info.value.code() == grpc.StatusCode.UNAUTHENTICATED


def test_health_stays_open(token_server):
    from grpc_health.v1 import health_pb2, health_pb2_grpc

    with grpc.insecure_channel(f"127.0.0.1:{token_server.port}") as channel:
        reply = health_pb2_grpc.HealthStub(channel).Check(health_pb2.HealthCheckRequest(), timeout=5)
        assert reply.status == health_pb2.HealthCheckResponse.SERVING


@pytest.fixture(scope="module")
def certificate(tmp_path_factory):
    if shutil.which("openssl") is None:
        pytest.skip("openssl not found: cannot make a test certificate")
    folder = tmp_path_factory.mktemp("tls")
    cert, key = folder / "cert.pem", folder / "key.pem"
    subprocess.run(
        [
            "openssl",
            "req",
            "-x509",
            "-newkey",
            "rsa:2048",
            "-nodes",
            "-keyout",
            str(key),
            "-out",
            str(cert),
            "-days",
            "1",
            "-subj",
            "/CN=localhost",
            "-addext",
            "subjectAltName=DNS:localhost,IP:127.0.0.1",
        ],
        check=True,
        capture_output=True,
    )
    return cert, key


def test_tls_with_token(loaded_graphs, certificate, recording):
    cert, key = certificate
    running = start(loaded_graphs, tls_cert=cert, tls_key=key, tokens=(TOKEN,))
    try:
        address = f"localhost:{running.port}"
        with C.connect(address, token=TOKEN, tls_ca=cert) as conn:
            assert [g.name for g in C.list_graphs(conn)] == ["small"]
            assert C.synthesize(conn, "small", recording).motion.num_frames == recording.num_samples
        with C.connect(address, token="wrong", tls_ca=cert) as conn:
            assert _status(lambda: C.list_graphs(conn, timeout_s=5)) == grpc.StatusCode.UNAUTHENTICATED
        with C.connect(address, token=TOKEN) as conn:  # plaintext to a TLS port: no connection
            assert _status(lambda: C.list_graphs(conn, timeout_s=3)) == grpc.StatusCode.UNAVAILABLE
    finally:
        running.stop(0)

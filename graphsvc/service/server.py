"""The graphsvc.v1 gRPC server, bound, started, run and stopped: `bind_server` (the
port, TLS, the interceptors, every service registered: the MotionGraphService, health
and reflection), `start_server` (the graphs, batches and live workers handed to it),
`serve` (`graphsvc serve`: until SIGTERM, then the drain) and `RunningServer.stop`.

The port is bound and health checks answered (NOT_SERVING) before the graphs load;
graphs are loaded once at start (`graphs.load_graphs`: memory-mapped) and shared
read-only by every call; each live stream owns its LiveSession, in one of the live
worker processes (`live_workers`) or, without them, in this process. Calls run on a
thread pool sized for `max_streams` live streams plus a few unary calls.

The rest of the service is in its own modules: the handlers in `servicer`, the graphs
in `graphs`, a stream's slot, first message and config in `streams`, authentication
and the call gate in `interceptors`, failures → status in `status`, the conversions
in `convert_*` and `options_proto` (all named in `convert`).

Status codes: INVALID_ARGUMENT names the offending field; NOT_FOUND for an unknown
graph; UNIMPLEMENTED for a strategy not built (none at present); RESOURCE_EXHAUSTED beyond
`max_streams` concurrent streams (at once, from a spare worker); DEADLINE_EXCEEDED for a
stream that sends no config within `config_timeout_s`; UNAVAILABLE for a stream whose live worker
died, and for every call but a health check while the graphs load or, after SIGTERM,
while the calls under way drain (health answers NOT_SERVING then); UNAUTHENTICATED
without a valid token; INTERNAL (with the traceback on the server's stderr) for bugs —
bad input never takes the server down.
"""

from __future__ import annotations

import gc
import math
import re
import signal
import sys
import threading
import time
from concurrent import futures
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import grpc
from grpc_health.v1 import health, health_pb2, health_pb2_grpc
from grpc_reflection.v1alpha import reflection

from graphsvc.batch.service import BatchManager
from graphsvc.errors import GraphsvcError, InputError
from graphsvc.fileio import read_input_bytes
from graphsvc.service._generated import graphsvc_pb2 as pb
from graphsvc.service._generated import graphsvc_pb2_grpc as pb_grpc
from graphsvc.service.graphs import LoadedGraph
from graphsvc.service.interceptors import BearerTokenInterceptor, CallGate
from graphsvc.service.live_workers import LiveWorkers
from graphsvc.service.metrics import Metrics, StatusCounter
from graphsvc.service.servicer import MotionGraphServicer
from graphsvc.service.streams import CONFIG_TIMEOUT_S

SERVICE_NAME = pb.DESCRIPTOR.services_by_name["MotionGraphService"].full_name  # "graphsvc.v1.MotionGraphService"
UNARY_WORKERS = 4  # threads beyond the live streams' for ListGraphs/GetGraph/Synthesize and rejections


@dataclass(frozen=True)
class ServerConfig:
    """host/port: where to listen (port 0: any free port). tls_cert/tls_key: PEM
    files (both or neither). tokens: accepted bearer tokens (empty: no
    authentication). max_streams: concurrent StreamSynthesize calls. max_message_mb:
    largest message either way, MiB. grace_s: how long SIGTERM lets calls finish.
    config_timeout_s: how long a new stream may take to send its StreamConfig."""

    host: str = "[::]"
    port: int = 50051
    tls_cert: Path | None = None
    tls_key: Path | None = None
    tokens: tuple[str, ...] = ()
    max_streams: int = 16
    max_message_mb: float = 64.0
    grace_s: float = 10.0
    # A stream that sends no StreamConfig within this many seconds of connecting is
    # ended with DEADLINE_EXCEEDED and its slot freed.
    config_timeout_s: float = CONFIG_TIMEOUT_S
    # Batches (SubmitBatch …): their root folder (None: the server takes none), and
    # the Dask cluster they run on (a scheduler's address, else a local cluster).
    batch_dir: Path | None = None
    batch_scheduler: str | None = None
    batch_workers: int | None = None
    # Live sessions run in this many worker processes (`live_workers`); 0: in the
    # server's own process.
    live_workers: int = 0
    # Prometheus metrics on this port (`metrics`; 0: any free one), on `host`; None: none.
    metrics_port: int | None = None


# ---------------------------------------------------------------- running


@dataclass
class RunningServer:
    server: grpc.Server
    port: int
    health: health.HealthServicer
    servicer: MotionGraphServicer
    graphs: dict[str, LoadedGraph] = field(default_factory=dict)
    gate: CallGate = field(default_factory=CallGate)
    metrics: Metrics | None = None  # with its endpoint's port, metrics.port

    def stop(self, grace_s: float | None = None, give_up_s: float = 10.0) -> None:
        """Health turns NOT_SERVING (and goes on answering), every other new call is
        refused with UNAVAILABLE, the calls under way get grace_s to finish, then the
        rest are cancelled; returns at the latest give_up_s after that.

        The drain is the CallGate's, not gRPC's `stop(grace)`, which would refuse the
        health checks too for the whole grace."""
        self.health.enter_graceful_shutdown()
        self.gate.drain()
        if grace_s:
            self.gate.wait_idle(grace_s)
        done = self.server.stop(0)  # (not None: that would block until the shutdown completes)
        # gRPC's shutdown completes once every call's objects are freed, and a finished
        # call can sit in a reference cycle until the cyclic GC's next pass (gRPC's own
        # answer to request bytes that do not parse leaves one): with no allocation to
        # trigger that pass the server would wait forever. Collect while waiting. Not
        # every such call is freed even so (seen with the client in the same process),
        # so give up (the process is ending) give_up_s after the grace.
        give_up = time.monotonic() + give_up_s
        while not done.wait(0.25) and time.monotonic() < give_up:
            gc.collect()
        if self.servicer.batches is not None:
            self.servicer.batches.close()
        if self.servicer.live_workers is not None:
            self.servicer.live_workers.stop()
        if self.metrics is not None:
            self.metrics.close()


def _add_reflection(server: grpc.Server, service_names: tuple[str, ...]) -> None:
    """Server reflection, so stock tools (grpcurl, grpc_cli, Postman) can list and
    call the service without the .proto. grpcio-reflection serves
    grpc.reflection.v1alpha; v1 has the very same messages under a new package
    name, so the same servicer answers it too (newer tools ask v1 first)."""
    from grpc_reflection.v1alpha import reflection_pb2, reflection_pb2_grpc

    servicer = reflection.ReflectionServicer(service_names)
    reflection_pb2_grpc.add_ServerReflectionServicer_to_server(servicer, server)
    v1 = grpc.stream_stream_rpc_method_handler(
        servicer.ServerReflectionInfo,
        request_deserializer=reflection_pb2.ServerReflectionRequest.FromString,
        response_serializer=reflection_pb2.ServerReflectionResponse.SerializeToString,
    )
    server.add_generic_rpc_handlers(
        (grpc.method_handlers_generic_handler("grpc.reflection.v1.ServerReflection", {"ServerReflectionInfo": v1}),)
    )


def check_address(host: str, port: int) -> None:
    """Refuse, with one line, a port outside 0–65535, a host that does not resolve or
    is not an address of this machine, or an address another socket already listens on,
    before gRPC logs its own failure and before any graph is loaded. Checked with a
    plain socket bound as gRPC binds (SO_REUSEADDR on, SO_REUSEPORT off), port 0
    included (any free port: whether the host is this machine's is still checked)."""
    import socket

    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise InputError(f"--port must be 0–65535, got {port}")
    name = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    try:
        infos = socket.getaddrinfo(name or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError, OSError) as exc:
        raise InputError(f"cannot listen on {host}:{port}: not an address of this machine ({exc})") from None
    family, kind, proto, _, sockaddr = infos[0]
    try:
        with socket.socket(family, kind, proto) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(sockaddr)
    except OSError as exc:
        raise InputError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None


@contextmanager
def _fd2_captured():
    """What is written to file descriptor 2 meanwhile, in a temporary file; yields a
    list that holds the text afterwards. gRPC's C core logs a failed bind there itself
    (an `E… add_port.cc] Failed to add port …` line, whatever sys.stderr is and
    whatever GRPC_VERBOSITY was when gRPC started), so the bind runs inside this and
    the reason goes into graphsvc's own one line."""
    import os
    import tempfile

    sys.stderr.flush()
    text: list[str] = []
    with tempfile.TemporaryFile() as log:
        saved = os.dup(2)
        try:
            os.dup2(log.fileno(), 2)
            yield text
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            log.seek(0)
            text.append(log.read().decode("utf-8", "replace"))


_GRPC_LOG_PREFIX = re.compile(r"^[EWIFD]\d{4} [\d:.]+\s+\d+ [^\]]*\] ")  # E1203 16:00:37.251041 6808 add_port.cc:83]


def bind_failure_reason(log: str) -> str:
    """Why gRPC could not bind, from what it logged: each address' bind error ("Cannot
    assign requested address"), else its "Failed to add port" line, else its last
    line (without the log prefix)."""
    reasons = list(dict.fromkeys(re.findall(r"Error in bind for address '[^']*': ([^)\n]+)\)", log)))
    if reasons:
        return "; ".join(reasons)
    lines = [_GRPC_LOG_PREFIX.sub("", line).strip() for line in log.splitlines() if line.strip()]
    failed = [line for line in lines if "Failed to add port" in line]
    return (failed or lines or ["gRPC gave no reason"])[-1]


@dataclass
class BoundServer:
    """A started gRPC server on its port that answers health checks (NOT_SERVING) and
    refuses every other call (UNAVAILABLE) until start_server hands it its graphs."""

    server: grpc.Server
    port: int
    max_streams: int
    health: health.HealthServicer
    servicer: MotionGraphServicer
    gate: CallGate
    metrics: Metrics | None = None
    bound_at: float = 0.0  # time.monotonic() when the port was bound

    def close(self, give_up_s: float = 5.0) -> None:
        """Stop at once (its graphs could not be served), waiting at most give_up_s for
        gRPC's shutdown (see RunningServer.stop)."""
        self.server.stop(0).wait(give_up_s)
        if self.metrics is not None:
            self.metrics.close()


def bind_server(config: ServerConfig) -> BoundServer:
    """Validate the config, build the gRPC server, bind its port and start it with
    every service registered, health answering NOT_SERVING and every other call
    refused until start_server. `serve` binds before it loads graphs, so a taken port
    fails in a moment and health checks are answered while the graphs load."""
    if config.max_streams < 1:
        raise InputError(f"--max-streams must be at least 1, got {config.max_streams}")
    if not (math.isfinite(config.max_message_mb) and config.max_message_mb > 0):
        raise InputError(f"--max-message-mb must be positive, got {config.max_message_mb}")
    if not (math.isfinite(config.config_timeout_s) and config.config_timeout_s > 0):
        raise InputError(f"--config-timeout-s must be positive, got {config.config_timeout_s}")
    if (config.tls_cert is None) != (config.tls_key is None):
        raise InputError("TLS needs both --tls-cert and --tls-key")
    check_address(config.host, config.port)
    credentials = None
    if config.tls_cert is not None:
        credentials = grpc.ssl_server_credentials(
            [(read_input_bytes(config.tls_key, "TLS key"), read_input_bytes(config.tls_cert, "TLS certificate"))]
        )
    max_bytes = int(config.max_message_mb * 2**20)
    # SO_REUSEPORT off: two servers can never share a port (nor port 0 land on a held one).
    # Keepalive: a client whose machine or network vanished (no FIN) stops answering
    # pings, and its calls end (their slots freed) within about 40 s, idle or not.
    options = [
        ("grpc.max_receive_message_length", max_bytes),
        ("grpc.max_send_message_length", max_bytes),
        ("grpc.so_reuseport", 0),
        ("grpc.keepalive_time_ms", 30_000),
        ("grpc.keepalive_timeout_ms", 10_000),
        ("grpc.http2.max_pings_without_data", 0),
    ]
    gate = CallGate()  # outermost but for the counter: while loading or draining, nothing else runs
    interceptors = [gate] + ([BearerTokenInterceptor(config.tokens)] if config.tokens else [])
    metrics = None
    if config.metrics_port is not None:
        metrics = Metrics()
        interceptors.insert(0, StatusCounter(metrics))  # (sees what the gate and the token check refuse)
    executor = futures.ThreadPoolExecutor(
        max_workers=config.max_streams + UNARY_WORKERS, thread_name_prefix="graphsvc-rpc"
    )
    server = grpc.server(executor, interceptors=interceptors, options=options)
    address = f"{config.host}:{config.port}"
    with _fd2_captured() as logged:
        try:
            if credentials is None:
                port = server.add_insecure_port(address)
            else:
                port = server.add_secure_port(address, credentials)
        except RuntimeError:  # grpcio ≥ 1.60 raises where older versions returned 0
            port = 0
    if port == 0:
        server.stop(None)
        raise GraphsvcError(f"cannot listen on {address}: {bind_failure_reason(logged[0])}")
    if logged[0]:  # (nothing gRPC logged beside a bind that worked is lost)
        sys.stderr.write(logged[0])
    try:
        if metrics is not None:  # (after the gRPC port: the same port for both is refused here, one line)
            metrics.serve(config.host, config.metrics_port)
        servicer = MotionGraphServicer(
            {}, config.max_streams, config_timeout_s=config.config_timeout_s, metrics=metrics
        )
        pb_grpc.add_MotionGraphServiceServicer_to_server(servicer, server)
        health_servicer = health.HealthServicer(
            experimental_non_blocking=True, experimental_thread_pool=futures.ThreadPoolExecutor(max_workers=1)
        )
        health_pb2_grpc.add_HealthServicer_to_server(health_servicer, server)
        for name in ("", SERVICE_NAME):
            health_servicer.set(name, health_pb2.HealthCheckResponse.NOT_SERVING)
        _add_reflection(server, (SERVICE_NAME, health.SERVICE_NAME, reflection.SERVICE_NAME))
        server.start()
    except BaseException:
        server.stop(0).wait(5.0)
        if metrics is not None:
            metrics.close()
        raise
    return BoundServer(server, port, config.max_streams, health_servicer, servicer, gate, metrics, time.monotonic())


def start_server(
    graphs: dict[str, LoadedGraph],
    config: ServerConfig,
    bound: BoundServer | None = None,
    live_workers: LiveWorkers | None = None,
) -> RunningServer:
    """Serve `graphs` on the server bind_server started (or one bound here): once the
    live workers are ready, calls go through and health turns SERVING (port: the bound
    port). live_workers: workers already launched for these graphs (else
    config.live_workers of them are started here)."""
    bound = bound or bind_server(config)
    try:
        batches = None
        if config.batch_dir is not None:
            batches = BatchManager(
                config.batch_dir, {n: g.path for n, g in graphs.items()}, config.batch_scheduler, config.batch_workers
            )
        workers = live_workers
        if workers is None and config.live_workers:
            workers = LiveWorkers({n: g.path for n, g in graphs.items()}, config.live_workers)
        if workers is not None:
            workers.expect({n: g.graph.checksum for n, g in graphs.items()})
            workers.start()
        bound.servicer.take(graphs, batches, workers)
        if bound.metrics is not None:
            bound.metrics.attach(bound.servicer, workers)
            for name, g in graphs.items():
                bound.metrics.graph_load_seconds.labels(name).set(g.load_s)
            bound.metrics.start_seconds.set(time.monotonic() - bound.bound_at)
    except BaseException:
        bound.close()
        raise
    bound.gate.open()  # (before SERVING: a client that sees SERVING gets through)
    for name in ("", SERVICE_NAME):
        bound.health.set(name, health_pb2.HealthCheckResponse.SERVING)
    return RunningServer(bound.server, bound.port, bound.health, bound.servicer, graphs, bound.gate, bound.metrics)


def serve(
    graphs: dict[str, LoadedGraph],
    config: ServerConfig,
    announce=print,
    bound: BoundServer | None = None,
    live_workers: LiveWorkers | None = None,
) -> int:
    """Run until SIGTERM or SIGINT, then drain in-flight calls for config.grace_s and
    return 0. `announce` gets the "listening on" line (port 0 shows the real port)."""
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        running = start_server(graphs, config, bound, live_workers)
        workers = running.servicer.live_workers
        security = "TLS" if config.tls_cert else "plaintext"
        auth = f"{len(config.tokens)} token(s)" if config.tokens else "no authentication"
        announce(
            f"graphsvc serve: listening on {config.host}:{running.port} ({security}, {auth}); graphs: "
            + ", ".join(f"{g.name} ({g.info.node_count:,} nodes)" for g in graphs.values())
            + (f"; live sessions in {workers.count} worker process(es)" if workers is not None else "")
            + (
                f"; metrics on http://{config.host}:{running.metrics.port}/metrics"
                if running.metrics is not None
                else ""
            )
        )
        while not stop.wait(0.5):  # a timed wait keeps the main thread responsive to signals
            pass
        announce(
            f"graphsvc serve: stopping, {running.servicer.slots.active} stream(s) in flight, grace {config.grace_s:g} s"
        )
        running.stop(config.grace_s)
        announce("graphsvc serve: stopped")
        return 0
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)

"""The graphsvc.v1 gRPC server: graph registry, batch and live synthesis, health,
reflection, bearer-token authentication and optional TLS.

The port is bound and health checks answered (NOT_SERVING) before the graphs load;
graphs are loaded once at start (memory-mapped, graphsvc.graph.file.load_graph) and
shared read-only by every call; each live stream owns its LiveSession, in one of the
live worker processes (`live_workers`) or, without them, in this process. Calls run
on a thread pool sized for `max_streams` live streams plus a few unary calls.

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
import hmac
import math
import re
import signal
import sys
import threading
import time
import traceback
from concurrent import futures
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import grpc
from grpc_health.v1 import health, health_pb2, health_pb2_grpc
from grpc_reflection.v1alpha import reflection

from graphsvc.errors import GraphsvcError, InputError, SearchCancelled, StrategyNotImplementedError
from graphsvc.fileio import read_input_bytes, read_input_text
from graphsvc.strategies import check_options
from graphsvc.strategies import get as get_strategy
from graphsvc.strategies.threads import ThreadShare
from graphsvc.service import convert
from graphsvc.service.live_workers import LiveWorkers, WorkerLost
from graphsvc.service._generated import graphsvc_pb2 as pb
from graphsvc.service._generated import graphsvc_pb2_grpc as pb_grpc

SERVICE_NAME = pb.DESCRIPTOR.services_by_name["MotionGraphService"].full_name  # "graphsvc.v1.MotionGraphService"
HEALTH_METHOD_PREFIX = "/grpc.health.v1.Health/"  # open without a token: load balancers and probes
UNARY_WORKERS = 4  # threads beyond the live streams' for ListGraphs/GetGraph/Synthesize and rejections


@dataclass(frozen=True)
class LoadedGraph:
    """A graph the server serves. info: its GraphInfo, computed once."""

    name: str
    path: Path
    graph: object  # graphsvc.graph.model.MotionGraph
    info: pb.GraphInfo


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
    config_timeout_s: float = 10.0
    # Batches (SubmitBatch …): their root folder (None: the server takes none), and
    # the Dask cluster they run on (a scheduler's address, else a local cluster).
    batch_dir: Path | None = None
    batch_scheduler: str | None = None
    batch_workers: int | None = None
    # Live sessions run in this many worker processes (`live_workers`); 0: in the
    # server's own process.
    live_workers: int = 0


def parse_graph_spec(text: str) -> tuple[str, Path]:
    """"NAME=FILE" → (name, path)."""
    name, sep, path = text.partition("=")
    name = name.strip()
    if not sep or not name or not path:
        raise InputError(f"--graph takes NAME=FILE, got {text!r}")
    return name, Path(path)


def load_graphs(specs: list[str]) -> dict[str, LoadedGraph]:
    """Load each "NAME=FILE" graph once (memory-mapped, checksum verified)."""
    from graphsvc.graph.file import load_graph
    from graphsvc.pipeline import warm_up

    if not specs:
        raise InputError("no graphs to serve (give --graph NAME=FILE at least once)")
    graphs: dict[str, LoadedGraph] = {}
    for spec in specs:
        name, path = parse_graph_spec(spec)
        if name in graphs:
            raise InputError(f"graph name {name!r} given twice")
        graph = load_graph(path)
        # Every strategy's index, and its kernels compiled or loaded (serial, and
        # threaded for a stream running alone), now, not in the first client's call.
        warm_up(graph, threads=False)
        warm_up(graph, threads=True)
        graphs[name] = LoadedGraph(name, path, graph, convert.graph_info(name, graph, path.stat().st_size))
    return graphs


def read_tokens(path) -> tuple[str, ...]:
    """Accepted tokens: one per line; blank lines and lines starting with # are
    skipped. Several lines let a token be rotated without downtime."""
    lines = read_input_text(path, "token file").splitlines()
    tokens = tuple(t.strip() for t in lines if t.strip() and not t.strip().startswith("#"))
    if not tokens:
        raise InputError(f"{path}: no token in the token file")
    return tokens


# ---------------------------------------------------------------- authentication


class BearerTokenInterceptor(grpc.ServerInterceptor):
    """UNAUTHENTICATED unless the call carries `authorization: Bearer <token>` with
    one of `tokens`. Health checks stay open (probes carry no secrets)."""

    def __init__(self, tokens: tuple[str, ...], open_prefixes: tuple[str, ...] = (HEALTH_METHOD_PREFIX,)):
        self._tokens = tuple(t.encode("utf-8") for t in tokens)
        self._open = open_prefixes

    def _authorized(self, metadata) -> bool:
        for key, value in metadata or ():
            if key != "authorization" or not isinstance(value, str):
                continue
            scheme, _, token = value.partition(" ")
            if scheme.lower() != "bearer":
                continue
            given = token.strip().encode("utf-8")
            # Compare against every token in constant time: no early exit that
            # would tell an attacker how much of a guess was right.
            ok = False
            for t in self._tokens:
                ok |= hmac.compare_digest(given, t)
            return ok
        return False

    def intercept_service(self, continuation, handler_call_details):
        if handler_call_details.method.startswith(self._open) or self._authorized(handler_call_details.invocation_metadata):
            return continuation(handler_call_details)
        handler = continuation(handler_call_details)
        if handler is None:  # unknown method: gRPC answers UNIMPLEMENTED itself
            return None
        return _answer(handler, grpc.StatusCode.UNAUTHENTICATED,
                       "missing or invalid bearer token (metadata 'authorization: Bearer <token>')")


def _answer(handler: grpc.RpcMethodHandler, code: grpc.StatusCode, message: str) -> grpc.RpcMethodHandler:
    """A handler of the same shape as `handler` that ends the call with `code`."""

    def abort(request_or_iterator, context):
        context.abort(code, message)

    if handler.request_streaming and handler.response_streaming:
        return grpc.stream_stream_rpc_method_handler(abort)
    if handler.request_streaming:
        return grpc.stream_unary_rpc_method_handler(abort)
    if handler.response_streaming:
        return grpc.unary_stream_rpc_method_handler(abort)
    return grpc.unary_unary_rpc_method_handler(abort)


# ---------------------------------------------------------------- serving state


class CallGate(grpc.ServerInterceptor):
    """Which calls the server takes, by its stage: while the graphs load (`loading`)
    and while it drains after SIGTERM (`draining`) every call but a health check is
    answered UNAVAILABLE, so health stays open from the moment the port is bound to
    the moment the server stops; while `serving` every call goes through, and the
    calls under way are counted until each ends (gRPC's termination callback, after
    its status went out), so a drain can wait for exactly those."""

    LOADING, SERVING, DRAINING = "loading", "serving", "draining"
    REFUSALS = {LOADING: "the server is loading its graphs (health answers NOT_SERVING until it serves); try again",
                DRAINING: "the server is shutting down"}  # fmt: skip

    def __init__(self, open_prefixes: tuple[str, ...] = (HEALTH_METHOD_PREFIX,)):
        self._open = open_prefixes
        self._stage = self.LOADING
        self._active = 0
        self._changed = threading.Condition()

    @property
    def stage(self) -> str:
        return self._stage

    @property
    def active(self) -> int:
        """Calls under way (health checks not counted)."""
        return self._active

    def open(self) -> None:
        with self._changed:
            self._stage = self.SERVING

    def drain(self) -> None:
        with self._changed:
            self._stage = self.DRAINING

    def wait_idle(self, timeout_s: float) -> bool:
        """Wait until no counted call is under way, at most timeout_s; whether none is."""
        with self._changed:
            return self._changed.wait_for(lambda: self._active == 0, timeout=max(0.0, timeout_s))

    def _enter(self) -> str | None:
        """Count a call that starts now; the refusal's message when the server takes none."""
        with self._changed:
            if self._stage != self.SERVING:
                return self.REFUSALS[self._stage]
            self._active += 1
            return None

    def _leave(self) -> None:
        with self._changed:
            self._active -= 1
            self._changed.notify_all()

    def intercept_service(self, continuation, handler_call_details):
        handler = continuation(handler_call_details)
        if handler is None or handler_call_details.method.startswith(self._open):
            return handler  # (None: unknown method, gRPC answers UNIMPLEMENTED itself)
        if self._stage != self.SERVING:
            return _answer(handler, grpc.StatusCode.UNAVAILABLE, self.REFUSALS[self._stage])
        kind = ("stream" if handler.request_streaming else "unary") + "_" + \
            ("stream" if handler.response_streaming else "unary")  # fmt: skip
        return handler._replace(**{kind: self._counted(getattr(handler, kind))})

    def _counted(self, behavior):
        def run(request_or_iterator, context):
            # (checked again here: the drain may have begun since the call arrived)
            refusal = self._enter()
            if refusal is not None:
                context.abort(grpc.StatusCode.UNAVAILABLE, refusal)
            if not context.add_callback(self._leave):  # (False: the call has ended already)
                self._leave()
            return behavior(request_or_iterator, context)

        return run


# ---------------------------------------------------------------- the service


class RpcStatus(Exception):
    """End the call with this status. Raised instead of calling context.abort inside
    handlers, so one place (_abort_for) turns every failure into exactly one status."""

    def __init__(self, code: grpc.StatusCode, message: str):
        super().__init__(message)
        self.code = code
        self.message = message


MAX_DETAILS_BYTES = 2048  # a status message rides in a trailer gRPC caps at 16 KiB, percent-encoded


def status_details(text: str) -> str:
    """`text` cut to MAX_DETAILS_BYTES of UTF-8 (an echoed oversize value must not
    turn the answer into RESOURCE_EXHAUSTED)."""
    data = text.encode("utf-8")
    if len(data) <= MAX_DETAILS_BYTES:
        return text
    return data[: MAX_DETAILS_BYTES - 3].decode("utf-8", "ignore") + "…"


def _config_error(exc: InputError) -> convert.FieldError:
    """A stream's config refused: the field it names (a strategy's `check_stream` names
    what the config announced: `marker_names`), else its options."""
    name = getattr(exc, "option_field", None)
    return convert.FieldError(f"config.{name}" if name else "config.options", str(exc))


def _abort_for(context: grpc.ServicerContext, exc: BaseException) -> None:
    """Map an exception to a status and end the call (context.abort raises)."""
    if isinstance(exc, RpcStatus):
        context.abort(exc.code, status_details(exc.message))
    if isinstance(exc, StrategyNotImplementedError):
        context.abort(grpc.StatusCode.UNIMPLEMENTED, status_details(str(exc)))
    if isinstance(exc, WorkerLost):  # the session's state is gone; a new stream would work
        context.abort(grpc.StatusCode.UNAVAILABLE, status_details(str(exc)))
    if isinstance(exc, SearchCancelled):  # the client is gone or out of time; nobody reads this
        context.abort(grpc.StatusCode.CANCELLED, str(exc))
    if isinstance(exc, GraphsvcError):
        context.abort(grpc.StatusCode.INVALID_ARGUMENT, status_details(str(exc)))
    # A bug: keep the traceback for the operator, tell the client only what failed.
    traceback.print_exception(exc, file=sys.stderr)
    context.abort(grpc.StatusCode.INTERNAL, f"internal error ({type(exc).__name__}); see the server log")


class StreamSlots:
    """At most `limit` live streams at once. A slot is released exactly once, by the
    handler finishing or by gRPC's termination callback, whichever comes first."""

    def __init__(self, limit: int):
        self.limit = limit
        self._active = 0
        self._lock = threading.Lock()

    @property
    def active(self) -> int:
        return self._active

    def try_acquire(self):
        """A release function, or None when all slots are taken."""
        with self._lock:
            if self._active >= self.limit:
                return None
            self._active += 1
        released = threading.Event()

        def release():
            with self._lock:
                if not released.is_set():
                    released.set()
                    self._active -= 1

        return release


def first_message(request_iterator, timeout_s: float):
    """The first request of a stream, or None when the client half-closed before
    sending one; RpcStatus DEADLINE_EXCEEDED when none came within timeout_s.

    gRPC's request iterator has no timed read, so a short-lived thread reads the one
    message while the handler waits. On a timeout the handler ends the call, which
    ends the reader's wait too (its read raises, and the thread exits)."""
    box: list = []
    done = threading.Event()

    def read():
        try:
            box.append(next(request_iterator, None))
        except BaseException as exc:  # noqa: BLE001 — grpc.RpcError when the call ends first; handed over
            box.append(exc)
        done.set()

    threading.Thread(target=read, name="graphsvc-config", daemon=True).start()
    if not done.wait(timeout_s):
        raise RpcStatus(grpc.StatusCode.DEADLINE_EXCEEDED, f"config: no StreamConfig within {timeout_s:g} s of "
                        "connecting (the server's --config-timeout-s); the stream's slot is freed")  # fmt: skip
    if isinstance(box[0], BaseException):
        raise box[0]
    return box[0]


class MotionGraphServicer(pb_grpc.MotionGraphServiceServicer):
    def __init__(self, graphs: dict[str, LoadedGraph], max_streams: int, batches=None,
                 config_timeout_s: float = ServerConfig.config_timeout_s,
                 live_workers: LiveWorkers | None = None):  # fmt: skip
        self.graphs = graphs
        self.live_workers = live_workers  # live sessions in worker processes (None: in this process)
        self.config_timeout_s = config_timeout_s
        self.batches = batches  # a batch.service.BatchManager, or None
        self.slots = StreamSlots(max_streams)
        self.threads = ThreadShare()  # numba's threads for a live stream's steps while it runs alone

    def take(self, graphs: dict[str, LoadedGraph], batches=None, live_workers: LiveWorkers | None = None) -> None:
        """Serve these graphs (and batches, live workers) from now on: `bind_server`
        registers the servicer before the graphs load, and its CallGate lets no call
        through to it until start_server has handed them over."""
        self.graphs = graphs
        self.batches = batches
        self.live_workers = live_workers

    def _graph(self, name: str, field: str = "graph") -> LoadedGraph:
        if not name:
            raise RpcStatus(grpc.StatusCode.INVALID_ARGUMENT, f"{field}: empty graph name (ListGraphs names the graphs)")
        loaded = self.graphs.get(name)
        if loaded is None:
            raise RpcStatus(grpc.StatusCode.NOT_FOUND, f"{field}: no graph named {name!r} "
                            f"(this server has {', '.join(sorted(self.graphs))})")  # fmt: skip
        return loaded

    def ListGraphs(self, request, context):
        return pb.ListGraphsResponse(graphs=[g.info for _, g in sorted(self.graphs.items())])

    def GetGraph(self, request, context):
        try:
            return pb.GetGraphResponse(graph=self._graph(request.name, "name").info)
        except Exception as exc:  # noqa: BLE001
            _abort_for(context, exc)

    def Synthesize(self, request, context):
        from graphsvc.motion.bvh import bvh_text
        from graphsvc.pipeline import reconstruct

        try:
            graph = self._graph(request.graph).graph
            options = convert.options_from_proto(request.options, "options")
            reads_acc = "accelerations" in get_strategy(options.strategy).uses  # else any sensors, unread
            rec = convert.recording_from_proto(request.recording, graph.sensor_names, "recording", reads_acc,
                                                graph.layout.get("name", "?"))
            if not context.is_active():  # the deadline passed while waiting for a worker
                return pb.SynthesizeResponse()
            # Serial kernels: many calls share the machine (and while this one runs, a
            # live stream does not take the threads). The search polls the call and
            # stops when the client cancels or its deadline passes.
            with self.threads.running():
                result = reconstruct(graph, rec, options, threads=False, should_stop=lambda: not context.is_active())
            response = pb.SynthesizeResponse(motion=convert.motion_to_proto(result.motion),
                                              node_path=[] if result.node_path is None else result.node_path.tolist(),
                                              bvh=bvh_text(result.motion, scale=100.0).encode("utf-8"))  # fmt: skip
            if result.provenance is not None:
                response.provenance.CopyFrom(convert.provenance_to_proto(result.provenance))
            convert.report_to_proto(result.report, response)
            return response
        except Exception as exc:  # noqa: BLE001 — every failure becomes a status, never a dead worker
            _abort_for(context, exc)

    def _batch_call(self, context, call):
        from graphsvc.batch.service import BatchNotFound

        try:
            if self.batches is None:
                raise RpcStatus(grpc.StatusCode.FAILED_PRECONDITION,
                                "this server takes no batches (start it with --batch-dir DIR)")  # fmt: skip
            try:
                return call()
            except BatchNotFound as exc:
                raise RpcStatus(grpc.StatusCode.NOT_FOUND, str(exc)) from None
        except Exception as exc:  # noqa: BLE001
            _abort_for(context, exc)

    def SubmitBatch(self, request, context):
        retries = request.retries if request.HasField("retries") else None
        return self._batch_call(context, lambda: convert.batch_status_to_proto(
            self.batches.status(self.batches.submit(request.manifest, request.format, retries))))  # fmt: skip

    def GetBatch(self, request, context):
        return self._batch_call(context, lambda: convert.batch_status_to_proto(
            self.batches.status(request.batch_id, items=request.items)))  # fmt: skip

    def ListBatches(self, request, context):
        return self._batch_call(context, lambda: pb.ListBatchesResponse(
            batches=[convert.batch_status_to_proto(b) for b in self.batches.list()]))  # fmt: skip

    def CancelBatch(self, request, context):
        return self._batch_call(context, lambda: convert.batch_status_to_proto(self.batches.cancel(request.batch_id)))

    def StreamSynthesize(self, request_iterator, context):
        release = self.slots.try_acquire()
        if release is None:
            context.abort(grpc.StatusCode.RESOURCE_EXHAUSTED,
                          f"the server is at its limit of {self.slots.limit} concurrent streams (--max-streams)")
            return
        # Released when the call ends for any reason: the handler returning, the
        # client cancelling, the deadline passing, the server stopping.
        context.add_callback(release)
        try:
            with self.threads.running():
                yield from self._stream(request_iterator, context)
        except grpc.RpcError as exc:  # the client went away while we waited for its next message
            # gRPC's error sits in a reference cycle with the frame that raised it, and its
            # traceback holds this call's frames, the live session (~100 MB on a large
            # graph) among them, until the cyclic GC's next full pass. Drop the traceback
            # so the session goes now.
            exc.__traceback__ = None
            return
        except Exception as exc:  # noqa: BLE001
            _abort_for(context, exc)
        finally:
            release()

    def _stream(self, request_iterator, context):
        from graphsvc.pipeline import open_session

        first = first_message(request_iterator, self.config_timeout_s)
        if first is None:
            return  # the client half-closed without a config: nothing to do
        if first.WhichOneof("message") != "config":
            raise RpcStatus(grpc.StatusCode.INVALID_ARGUMENT, "config: the first message must carry a StreamConfig")
        config = first.config
        loaded = self._graph(config.graph, "config.graph")
        graph = loaded.graph
        names = graph.sensor_names
        options = convert.options_from_proto(config.options, "config.options")
        strategy = get_strategy(options.strategy)
        reads_acc = "accelerations" in strategy.uses
        if reads_acc:
            order = convert.sensor_order(config.sensor_names, names, "config.sensor_names", graph.layout.get("name", "?"))
        else:  # whatever sensors the samples carry (the strategy reads none): the lengths still checked
            order, names = None, tuple(config.sensor_names) or names
        marker_names = convert.marker_names_from_proto(config.marker_names, "config.marker_names")
        try:
            # (the strategy's own checks of what the stream announces, here too when a
            # worker process opens the session)
            strategy.check_stream(check_options(options), names, marker_names)
            if self.live_workers is not None:
                session = self.live_workers.open(loaded.name, options, names, marker_names, config.orientations)
            else:
                session = open_session(graph, options, names, keep_motion=False,  # the client keeps the frames
                                      marker_names=marker_names, orientations=config.orientations)  # fmt: skip
        except InputError as exc:  # e.g. a constraint label the graph does not have
            raise _config_error(exc) from None
        try:
            yield pb.StreamSynthesizeResponse(started=pb.StreamStarted(
                graph=loaded.name, rate_hz=graph.rate_hz, lag_frames=session.lag_frames, sensor_names=list(names),
                skeleton=loaded.info.skeleton))  # fmt: skip

            sample_index = -1
            previous_t = None
            frames_out = 0
            for request in request_iterator:
                if not context.is_active():
                    return  # cancelled or past the deadline: stop searching now
                kind = request.WhichOneof("message")
                if kind == "config":
                    raise RpcStatus(grpc.StatusCode.INVALID_ARGUMENT, f"sample[{sample_index + 1}]: only the first "
                                    "message may carry a config; every later one carries a sample")  # fmt: skip
                if kind is None:
                    raise RpcStatus(grpc.StatusCode.INVALID_ARGUMENT, f"sample[{sample_index + 1}]: empty message")
                sample_index += 1
                where = f"sample[{sample_index}]"
                t, acc, position, heading = convert.sample_from_proto(request.sample, len(names), order, previous_t,
                                                                      where, reads_acc)  # fmt: skip
                markers = convert.sample_markers_from_proto(request.sample, len(marker_names), where)
                orientations = convert.sample_orientations_from_proto(request.sample, len(names), order,
                                                                      config.orientations, where)  # fmt: skip
                previous_t = t
                try:
                    with self.threads.step() as threaded:  # the threads while this stream runs alone
                        session.threads = threaded
                        frames = session.push(t, acc, position, heading, markers=markers, orientations=orientations)
                except InputError as exc:
                    raise convert.FieldError(f"sample[{sample_index}]", str(exc)) from None
                for frame in frames:
                    yield pb.StreamSynthesizeResponse(frame=convert.frame_to_proto(frame, sample_index))
                frames_out += len(frames)
            if not context.is_active():
                return
            try:
                with self.threads.step() as threaded:
                    session.threads = threaded
                    frames = session.flush()
            except InputError as exc:  # (what only the stream's end tells: its samples as a whole)
                name = getattr(exc, "option_field", None)
                raise convert.FieldError(f"sample[*].{name}" if name else "sample[*]", str(exc)) from None
            for frame in frames:
                yield pb.StreamSynthesizeResponse(frame=convert.frame_to_proto(frame, max(sample_index, 0)))
                frames_out += 1
            yield pb.StreamSynthesizeResponse(finished=pb.StreamFinished(samples_received=sample_index + 1,
                                                                         frames_emitted=frames_out))  # fmt: skip
        finally:
            if self.live_workers is not None:  # (an in-process session is freed with this frame)
                session.close()


# ---------------------------------------------------------------- running


@dataclass
class RunningServer:
    server: grpc.Server
    port: int
    health: health.HealthServicer
    servicer: MotionGraphServicer
    graphs: dict[str, LoadedGraph] = field(default_factory=dict)
    gate: CallGate = field(default_factory=CallGate)

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
    server.add_generic_rpc_handlers((grpc.method_handlers_generic_handler(
        "grpc.reflection.v1.ServerReflection", {"ServerReflectionInfo": v1}),))  # fmt: skip


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

    def close(self, give_up_s: float = 5.0) -> None:
        """Stop at once (its graphs could not be served), waiting at most give_up_s for
        gRPC's shutdown (see RunningServer.stop)."""
        self.server.stop(0).wait(give_up_s)


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
        credentials = grpc.ssl_server_credentials([(read_input_bytes(config.tls_key, "TLS key"),
                                                    read_input_bytes(config.tls_cert, "TLS certificate"))])  # fmt: skip
    max_bytes = int(config.max_message_mb * 2**20)
    # SO_REUSEPORT off: two servers can never share a port (nor port 0 land on a held one).
    # Keepalive: a client whose machine or network vanished (no FIN) stops answering
    # pings, and its calls end (their slots freed) within about 40 s, idle or not.
    options = [("grpc.max_receive_message_length", max_bytes), ("grpc.max_send_message_length", max_bytes),
               ("grpc.so_reuseport", 0), ("grpc.keepalive_time_ms", 30_000), ("grpc.keepalive_timeout_ms", 10_000),
               ("grpc.http2.max_pings_without_data", 0)]  # fmt: skip
    gate = CallGate()  # outermost: while loading or draining, nothing else runs
    interceptors = [gate] + ([BearerTokenInterceptor(config.tokens)] if config.tokens else [])
    executor = futures.ThreadPoolExecutor(max_workers=config.max_streams + UNARY_WORKERS, thread_name_prefix="graphsvc-rpc")
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
        servicer = MotionGraphServicer({}, config.max_streams, config_timeout_s=config.config_timeout_s)
        pb_grpc.add_MotionGraphServiceServicer_to_server(servicer, server)
        health_servicer = health.HealthServicer(experimental_non_blocking=True,
                                                experimental_thread_pool=futures.ThreadPoolExecutor(max_workers=1))  # fmt: skip
        health_pb2_grpc.add_HealthServicer_to_server(health_servicer, server)
        for name in ("", SERVICE_NAME):
            health_servicer.set(name, health_pb2.HealthCheckResponse.NOT_SERVING)
        _add_reflection(server, (SERVICE_NAME, health.SERVICE_NAME, reflection.SERVICE_NAME))
        server.start()
    except BaseException:
        server.stop(0).wait(5.0)
        raise
    return BoundServer(server, port, config.max_streams, health_servicer, servicer, gate)


def start_server(graphs: dict[str, LoadedGraph], config: ServerConfig, bound: BoundServer | None = None,
                 live_workers: LiveWorkers | None = None) -> RunningServer:  # fmt: skip
    """Serve `graphs` on the server bind_server started (or one bound here): once the
    live workers are ready, calls go through and health turns SERVING (port: the bound
    port). live_workers: workers already launched for these graphs (else
    config.live_workers of them are started here)."""
    bound = bound or bind_server(config)
    try:
        batches = None
        if config.batch_dir is not None:
            from graphsvc.batch.service import BatchManager

            batches = BatchManager(config.batch_dir, {n: g.path for n, g in graphs.items()}, config.batch_scheduler,
                                   config.batch_workers)  # fmt: skip
        workers = live_workers
        if workers is None and config.live_workers:
            workers = LiveWorkers({n: g.path for n, g in graphs.items()}, config.live_workers)
        if workers is not None:
            workers.start()
        bound.servicer.take(graphs, batches, workers)
    except BaseException:
        bound.close()
        raise
    bound.gate.open()  # (before SERVING: a client that sees SERVING gets through)
    for name in ("", SERVICE_NAME):
        bound.health.set(name, health_pb2.HealthCheckResponse.SERVING)
    return RunningServer(bound.server, bound.port, bound.health, bound.servicer, graphs, bound.gate)


def serve(graphs: dict[str, LoadedGraph], config: ServerConfig, announce=print, bound: BoundServer | None = None,
          live_workers: LiveWorkers | None = None) -> int:  # fmt: skip
    """Run until SIGTERM or SIGINT, then drain in-flight calls for config.grace_s and
    return 0. `announce` gets the "listening on" line (port 0 shows the real port)."""
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        running = start_server(graphs, config, bound, live_workers)
        workers = running.servicer.live_workers
        security = "TLS" if config.tls_cert else "plaintext"
        auth = f"{len(config.tokens)} token(s)" if config.tokens else "no authentication"
        announce(f"graphsvc serve: listening on {config.host}:{running.port} ({security}, {auth}); graphs: "
                 + ", ".join(f"{g.name} ({g.info.node_count:,} nodes)" for g in graphs.values())
                 + (f"; live sessions in {workers.count} worker process(es)" if workers is not None else ""))  # fmt: skip
        while not stop.wait(0.5):  # a timed wait keeps the main thread responsive to signals
            pass
        announce(f"graphsvc serve: stopping, {running.servicer.slots.active} stream(s) in flight, grace {config.grace_s:g} s")
        running.stop(config.grace_s)
        announce("graphsvc serve: stopped")
        return 0
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)

"""Client side of graphsvc.v1: connect (plaintext or TLS, optional bearer token),
list graphs, synthesize a recording, stream samples live.

    conn = connect("127.0.0.1:50051", token=read_token_file("token"))
    graphs = list_graphs(conn)
    result = synthesize(conn, "tennis", recording, options_to_proto(latency_s=None))
    open("out.bvh", "wb").write(result.bvh)

Failures of the call itself (status codes) raise ServiceError, a GraphsvcError, so
the command line prints one line and exits 2.
"""

from __future__ import annotations

import queue
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

import grpc
import numpy as np

from graphsvc.errors import GraphsvcError, InputError
from graphsvc.fileio import read_input_bytes, read_input_text
from graphsvc.motion.skeleton import Motion, Skeleton
from graphsvc.sensors.recording import Recording
from graphsvc.service._generated import graphsvc_pb2 as pb
from graphsvc.service._generated import graphsvc_pb2_grpc as pb_grpc
from graphsvc.service.convert_graph import skeleton_from_proto
from graphsvc.service.convert_motion import frames_to_motion, motion_from_proto
from graphsvc.service.convert_recording import recording_to_proto, sample_to_proto
from graphsvc.service.convert_report import report_from_proto
from graphsvc.service.servers import PROBE_TIMEOUT_S, SERVER_METADATA, SERVICE_CONFIG, parse_servers, probe_all

DEFAULT_SERVER = "127.0.0.1:50051"


class ServiceError(GraphsvcError):
    """A call the server refused or that failed in transport. code: grpc.StatusCode."""

    def __init__(self, code, details: str, method: str = ""):
        self.code = code
        self.details = details
        name = code.name if code is not None else "UNKNOWN"
        super().__init__(f"{method + ': ' if method else ''}{name}: {details}")


def service_error(exc: grpc.RpcError, method: str = "") -> ServiceError:
    code = exc.code() if hasattr(exc, "code") else None
    details = exc.details() if hasattr(exc, "details") else str(exc)
    return ServiceError(code, details or "", method)


@dataclass
class Connection:
    """A channel, its stub and the metadata every call carries (the bearer token)."""

    channel: grpc.Channel
    stub: pb_grpc.MotionGraphServiceStub
    metadata: tuple[tuple[str, str], ...] = ()
    address: str = ""

    def close(self) -> None:
        self.channel.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def read_token_file(path) -> str:
    """The token: the file's first line that is neither blank nor a # comment."""
    for line in read_input_text(path, "token file").splitlines():
        if line.strip() and not line.strip().startswith("#"):
            return line.strip()
    raise InputError(f"{path}: no token in the token file")


def connect(
    address: str = DEFAULT_SERVER,
    token: str | None = None,
    tls_ca=None,
    tls_server_name: str | None = None,
    warn: Callable[[str], None] | None = None,
) -> Connection:
    """A connection to `address`: HOST:PORT, several as HOST:PORT,HOST:PORT,… or a gRPC
    target (`servers.parse_servers`), calls spread over them by gRPC's `round_robin`
    (a stream stays on its server). With several, each is probed first: warn(line) (default:
    to stderr) names one that does not answer; none answering is NoServerAnswers.
    tls_ca: PEM file of the CA that signed the server's certificate (TLS on); None:
    plaintext. token: sent as `authorization: Bearer <token>` on every call (in the
    clear without TLS). tls_server_name: the name to check the certificate against, if
    not the host."""
    servers = parse_servers(address)
    # The server enforces its message limit; the client takes whatever it is sent
    # (a long recording's motion plus BVH easily exceeds gRPC's 4 MiB default).
    options = [("grpc.max_receive_message_length", -1), ("grpc.max_send_message_length", -1)]
    credentials = None
    if tls_ca is not None:
        name = tls_server_name or servers.host
        if name:
            options.append(("grpc.ssl_target_name_override", name))
        credentials = grpc.ssl_channel_credentials(root_certificates=read_input_bytes(tls_ca, "TLS CA"))
    options.append(("grpc.service_config", SERVICE_CONFIG))
    settle_s = None
    if len(servers.addresses) > 1:
        settle_s = probe_all(
            servers, credentials, options, warn or (lambda line: print(f"graphsvc: {line}", file=sys.stderr))
        )
    if credentials is not None:
        channel = grpc.secure_channel(servers.target, credentials, options=options)
    else:
        channel = grpc.insecure_channel(servers.target, options=options)
    if settle_s is not None:
        # round_robin connects to every server at once, and picks only among those
        # connected: calls made as soon as the first is would all go to it (a bridge
        # or `client stream` makes one, so every such client would pick the same
        # server). Wait for the channel, then about as long again as the slowest probe
        # took, so the others are connected too and the first pick is round_robin's
        # own random one among them all.
        try:
            grpc.channel_ready_future(channel).result(timeout=PROBE_TIMEOUT_S)
            time.sleep(min(settle_s, 1.0))
        except grpc.FutureTimeoutError:
            pass  # (the first call says why)
    metadata = (("authorization", f"Bearer {token}"),) if token else ()
    return Connection(channel, pb_grpc.MotionGraphServiceStub(channel), metadata, address)


def list_graphs(conn: Connection, timeout_s: float | None = 30.0) -> list[pb.GraphInfo]:
    try:
        return list(conn.stub.ListGraphs(pb.ListGraphsRequest(), timeout=timeout_s, metadata=conn.metadata).graphs)
    except grpc.RpcError as exc:
        raise service_error(exc, "ListGraphs") from None


def get_graph(conn: Connection, name: str, timeout_s: float | None = 30.0) -> pb.GraphInfo:
    try:
        return conn.stub.GetGraph(pb.GetGraphRequest(name=name), timeout=timeout_s, metadata=conn.metadata).graph
    except grpc.RpcError as exc:
        raise service_error(exc, "GetGraph") from None


def resolve_graph(conn: Connection, name: str | None, timeout_s: float | None = 30.0) -> pb.GraphInfo:
    """The named graph, or the server's only graph when no name is given."""
    if name:
        return get_graph(conn, name, timeout_s)
    graphs = list_graphs(conn, timeout_s)
    if len(graphs) != 1:
        raise InputError(
            f"the server has {len(graphs)} graphs ({', '.join(g.name for g in graphs)}); choose one with --graph"
        )
    return graphs[0]


@dataclass
class BatchResult:
    """motion: on the graph's skeleton at its rate (float32 precision); node_path
    (F,) int64; bvh: BVH file bytes (centimetres); report: the search report."""

    motion: Motion
    node_path: np.ndarray
    bvh: bytes
    report: dict


def synthesize(
    conn: Connection,
    graph: str,
    rec: Recording,
    options: pb.SynthesisOptions | None = None,
    timeout_s: float | None = None,
    skeleton: Skeleton | None = None,
    calibrate_from_start: tuple[float, str] | None = None,
    performer: pb.Performer | None = None,
) -> BatchResult:
    """One Synthesize call. skeleton: the graph's (fetched with GetGraph if None);
    calibrate_from_start: (seconds, pose), the server calibrates the device-frame
    recording from its own start against the graph first. performer: the proportions to
    put the output on (`convert.performer_to_proto`); the motion's skeleton then has the
    bones the response's translations carry."""
    if skeleton is None:
        skeleton = skeleton_from_proto(get_graph(conn, graph).skeleton)
    request = pb.SynthesizeRequest(
        graph=graph, recording=recording_to_proto(rec), options=options or pb.SynthesisOptions(), performer=performer
    )
    if calibrate_from_start is not None:
        request.calibrate_from_start.seconds, request.calibrate_from_start.pose = calibrate_from_start
    try:
        response = conn.stub.Synthesize(request, timeout=timeout_s, metadata=conn.metadata)
    except grpc.RpcError as exc:
        raise service_error(exc, "Synthesize") from None
    motion = motion_from_proto(response.motion, skeleton)
    if performer is not None and motion.num_frames > 0:
        # (a joint without translation channels carries its bone's offset in every frame)
        moving = np.array([any(c.endswith("position") for c in ch) for ch in skeleton.channels])
        offsets = np.where(moving[:, None], skeleton.offsets, motion.translations[0])
        motion = motion.copy(
            skeleton=Skeleton(skeleton.names, skeleton.parents, offsets, skeleton.channels, skeleton.end_site)
        )
    return BatchResult(motion, np.array(response.node_path, np.int64), response.bvh, report_from_proto(response))


# ---------------------------------------------------------------- live


_END = object()


class SampleFeed:
    """The request side of a live stream: a config, then whatever samples are put,
    until `close()`. Records when each sample left (time.perf_counter seconds), so
    latency can be measured from the frames' input_sample_index."""

    def __init__(self, config: pb.StreamConfig):
        self._queue: queue.Queue = queue.Queue()
        self._config = config
        self.sent_at: list[float] = []  # perf_counter time each sample was handed to gRPC, by sample index

    def put(self, sample: pb.SensorSample) -> None:
        self._queue.put(sample)

    def close(self) -> None:
        self._queue.put(_END)

    def __iter__(self) -> Iterator[pb.StreamSynthesizeRequest]:
        yield pb.StreamSynthesizeRequest(config=self._config)
        while True:
            item = self._queue.get()
            if item is _END:
                return
            self.sent_at.append(time.perf_counter())
            yield pb.StreamSynthesizeRequest(sample=item)


@dataclass
class StreamResult:
    """What a live stream returned. started: the StreamStarted; frames: PoseFrames in
    arrival order; latencies_ms: per frame, arrival − send of the sample that released
    it (ms; the service's delay beyond the decoder lag); finished: StreamFinished or None."""

    started: pb.StreamStarted | None = None
    frames: list = field(default_factory=list)
    latencies_ms: list = field(default_factory=list)
    finished: pb.StreamFinished | None = None
    server: str = ""  # "HOST pid PID" of the server that held the stream (behind a balancer: which one)

    def motion(self) -> Motion:
        if self.started is None:
            raise InputError("the stream never started")
        sk = skeleton_from_proto(self.started.skeleton)
        return frames_to_motion(self.frames, sk, self.started.rate_hz)


def run_stream(
    conn: Connection,
    feed: SampleFeed,
    on_frame: Callable | None = None,
    timeout_s: float | None = None,
    on_call: Callable | None = None,
) -> StreamResult:
    """Run a StreamSynthesize call fed by `feed` until the server finishes.
    on_frame(frame, latency_ms) is called per pose frame; on_call(call) gets the
    call object (call.cancel() ends the stream early)."""
    result = StreamResult()
    call = conn.stub.StreamSynthesize(iter(feed), timeout=timeout_s, metadata=conn.metadata)
    if on_call is not None:
        on_call(call)
    try:
        for response in call:
            kind = response.WhichOneof("message")
            if kind == "frame":
                frame = response.frame
                now = time.perf_counter()
                k = frame.input_sample_index
                latency = (now - feed.sent_at[k]) * 1e3 if 0 <= k < len(feed.sent_at) else float("nan")
                result.frames.append(frame)
                result.latencies_ms.append(latency)
                if on_frame is not None:
                    on_frame(frame, latency)
            elif kind == "started":
                result.started = response.started
                result.server = dict(call.initial_metadata() or ()).get(SERVER_METADATA, "")
            elif kind == "finished":
                result.finished = response.finished
    except grpc.RpcError as exc:
        raise service_error(exc, "StreamSynthesize") from None
    finally:
        feed.close()  # lets the request thread end if the call failed early
    return result


def stream_config(
    graph: str,
    options: pb.SynthesisOptions | None = None,
    sensor_names=(),
    marker_names=(),
    orientations: bool = False,
    calibrate_from_start: tuple[float, str] | None = None,
) -> pb.StreamConfig:
    """marker_names: the markers each sample carries (`recording_samples` sends a
    recording's), in order; orientations: whether each carries the sensors' orientations;
    calibrate_from_start: (seconds, pose), the server calibrates the devices' mountings
    from the stream's first seconds."""
    config = pb.StreamConfig(
        graph=graph,
        options=options or pb.SynthesisOptions(),
        sensor_names=list(sensor_names),
        marker_names=list(marker_names),
        orientations=bool(orientations),
    )
    if calibrate_from_start is not None:
        config.calibrate_from_start.seconds, config.calibrate_from_start.pose = calibrate_from_start
    return config


def recording_samples(rec: Recording) -> Iterator[pb.SensorSample]:
    """The recording's samples as SensorSamples, in order: its accelerations (none for a
    marker-only recording), track, heading, markers (for its marker_names) and orientations."""
    for k in range(rec.num_samples):
        acc = None if rec.accelerations is None else rec.accelerations[k]
        pos = None if rec.ground_position is None else rec.ground_position[k]
        head = None if rec.heading is None else float(rec.heading[k])
        markers = None if rec.marker_positions is None else rec.marker_positions[k]
        orient = None if rec.orientations is None else rec.orientations[k]
        yield sample_to_proto(rec.timestamps_s[k], acc, pos, head, markers, orient)


def replay(rec: Recording, feed: SampleFeed, speed: float = 1.0, stop: threading.Event | None = None) -> None:
    """Put the recording's samples into `feed` at their timestamps (divided by
    `speed`: 2 = twice as fast), then close it. Runs in the caller's thread."""
    if not (speed > 0):
        raise InputError(f"--speed must be positive, got {speed}")
    t = rec.timestamps_s
    start = time.perf_counter()
    try:
        for k, sample in enumerate(recording_samples(rec)):
            delay = start + (t[k] - t[0]) / speed - time.perf_counter()
            if stop is None:
                time.sleep(max(delay, 0.0))
            elif stop.wait(max(delay, 0.0)):
                return  # the stream ended early
            feed.put(sample)
    finally:
        feed.close()


def stream_recording(
    conn: Connection,
    graph: str,
    rec: Recording,
    options: pb.SynthesisOptions | None = None,
    speed: float = 1.0,
    on_frame: Callable | None = None,
    timeout_s: float | None = None,
    calibrate_from_start: tuple[float, str] | None = None,
) -> StreamResult:
    """Replay `rec` in real time (÷ speed) through StreamSynthesize (its markers too,
    when it has them); calibrate_from_start as `stream_config`."""
    marker_names = rec.marker_names if rec.marker_positions is not None else ()
    feed = SampleFeed(
        stream_config(
            graph, options, rec.sensor_names, marker_names, rec.orientations is not None, calibrate_from_start
        )
    )
    stop = threading.Event()
    sender = threading.Thread(target=replay, args=(rec, feed, speed, stop), name="graphsvc-replay", daemon=True)
    sender.start()
    try:
        return run_stream(conn, feed, on_frame, timeout_s)
    finally:
        stop.set()
        sender.join(timeout=5.0)


def latency_summary(latencies_ms: Iterable[float]) -> dict:
    """{"frames", "p50_ms", "p99_ms", "max_ms"} over the finite latencies."""
    a = np.asarray(list(latencies_ms), np.float64)
    a = a[np.isfinite(a)]
    if a.size == 0:
        return {"frames": 0, "p50_ms": None, "p99_ms": None, "max_ms": None}
    return {
        "frames": int(a.size),
        "p50_ms": round(float(np.percentile(a, 50)), 3),
        "p99_ms": round(float(np.percentile(a, 99)), 3),
        "max_ms": round(float(a.max()), 3),
    }


def batch_call(conn: Connection, method: str, request, timeout_s: float | None = 30.0):
    """A batch method (SubmitBatch, GetBatch, ListBatches, CancelBatch) with `request`;
    ServiceError when it fails."""
    try:
        return getattr(conn.stub, method)(request, timeout=timeout_s, metadata=conn.metadata)
    except grpc.RpcError as exc:
        raise service_error(exc, method) from None


def submit_batch(
    conn: Connection, manifest_text: str, fmt: str = "", retries: int | None = None, timeout_s: float | None = 30.0
) -> pb.BatchStatus:
    request = pb.SubmitBatchRequest(manifest=manifest_text, format=fmt)
    if retries is not None:
        request.retries = retries
    return batch_call(conn, "SubmitBatch", request, timeout_s)

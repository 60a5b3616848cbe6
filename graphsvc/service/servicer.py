"""The graphsvc.v1 MotionGraphService's handlers: the graphs (ListGraphs, GetGraph),
a recording's reconstruction (Synthesize), live streams (StreamSynthesize) and batches
(SubmitBatch, GetBatch, ListBatches, CancelBatch).

Each handler finds the graph by name among the loaded ones (`graphs.LoadedGraph`),
reads the request through the conversions (`convert_*`, `options_proto`), leaves the
work to the strategy (`pipeline.reconstruct`, a live session opened here or in a live
worker process) or the BatchManager, and turns every failure into one status
(`status.abort_for`). A stream takes a slot (`streams.StreamSlots`) for as long as it
runs; its first message must be its StreamConfig.
"""

from __future__ import annotations

import os
import socket
import time

import grpc

from graphsvc import pipeline
from graphsvc.batch.service import BatchNotFound
from graphsvc.errors import FieldError, InputError
from graphsvc.motion.bvh import bvh_text
from graphsvc.service._generated import graphsvc_pb2 as pb
from graphsvc.service._generated import graphsvc_pb2_grpc as pb_grpc
from graphsvc.service.convert_motion import frame_to_proto, motion_to_proto, provenance_to_proto
from graphsvc.service.convert_recording import recording_from_proto
from graphsvc.service.convert_report import batch_status_to_proto, report_to_proto
from graphsvc.service.graphs import LoadedGraph
from graphsvc.service.live_workers import LiveWorkers
from graphsvc.service.options_proto import options_from_proto, performer_from_proto
from graphsvc.service.servers import SERVER_METADATA
from graphsvc.service.status import RpcStatus, abort_for
from graphsvc.service.streams import CONFIG_TIMEOUT_S, StartCalibration, StreamInput, StreamSlots, first_message
from graphsvc.strategies import check_options
from graphsvc.strategies import get as get_strategy
from graphsvc.strategies.threads import ThreadShare


def _config_error(exc: InputError) -> FieldError:
    """A stream's config refused: the field it names (a strategy's `check_stream` names
    what the config announced: `marker_names`), else its options."""
    name = getattr(exc, "option_field", None)
    return FieldError(f"config.{name}" if name else "config.options", str(exc))


class MotionGraphServicer(pb_grpc.MotionGraphServiceServicer):
    """The service's handlers over the loaded graphs (`graphs`, by name), the batches
    (a BatchManager, or None) and the live workers (None: sessions in this process)."""

    def __init__(
        self,
        graphs: dict[str, LoadedGraph],
        max_streams: int,
        batches=None,
        config_timeout_s: float = CONFIG_TIMEOUT_S,
        live_workers: LiveWorkers | None = None,
        metrics=None,
    ):
        self.graphs = graphs
        self.metrics = metrics  # a metrics.Metrics, or None (no --metrics-port)
        # Sent at the start of every stream (initial metadata SERVER_METADATA): which
        # server behind a balancer holds it.
        self.identity = f"{socket.gethostname()} pid {os.getpid()}"
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
            raise RpcStatus(
                grpc.StatusCode.INVALID_ARGUMENT, f"{field}: empty graph name (ListGraphs names the graphs)"
            )
        loaded = self.graphs.get(name)
        if loaded is None:
            raise RpcStatus(
                grpc.StatusCode.NOT_FOUND,
                f"{field}: no graph named {name!r} (this server has {', '.join(sorted(self.graphs))})",
            )
        return loaded

    def ListGraphs(self, request, context):
        return pb.ListGraphsResponse(graphs=[g.info for _, g in sorted(self.graphs.items())])

    def GetGraph(self, request, context):
        try:
            return pb.GetGraphResponse(graph=self._graph(request.name, "name").info)
        except Exception as exc:  # noqa: BLE001
            abort_for(context, exc)

    def Synthesize(self, request, context):
        try:
            graph = self._graph(request.graph).graph
            options = options_from_proto(request.options, "options")
            performer = (
                performer_from_proto(request.performer, graph.skeleton, graph.params.get("mapping"))
                if request.HasField("performer")
                else None
            )
            reads_acc = "accelerations" in get_strategy(options.strategy).uses  # else any sensors, unread
            rec = recording_from_proto(
                request.recording, graph.sensor_names, "recording", reads_acc, graph.layout.get("name", "?")
            )
            if request.HasField("calibrate_from_start"):  # (device frames: calibrated here, against the graph)
                c = request.calibrate_from_start
                try:
                    rec = pipeline.calibrated_from_start(rec, graph, c.seconds, c.pose)
                except InputError as exc:
                    raise FieldError("calibrate_from_start", str(exc)) from None
            if not context.is_active():  # the deadline passed while waiting for a worker
                return pb.SynthesizeResponse()
            # Serial kernels: many calls share the machine (and while this one runs, a
            # live stream does not take the threads). The search polls the call and
            # stops when the client cancels or its deadline passes.
            with self.threads.running():
                result = pipeline.reconstruct(
                    graph, rec, options, threads=False, should_stop=lambda: not context.is_active()
                )
            if performer is not None:
                result = pipeline.put_on_performer(graph, result, performer)
            response = pb.SynthesizeResponse(
                motion=motion_to_proto(result.motion),
                node_path=[] if result.node_path is None else result.node_path.tolist(),
                bvh=bvh_text(result.motion, scale=100.0).encode("utf-8"),
            )
            if result.provenance is not None:
                response.provenance.CopyFrom(provenance_to_proto(result.provenance))
            report_to_proto(result.report, response)
            return response
        except Exception as exc:  # noqa: BLE001 — every failure becomes a status, never a dead worker
            abort_for(context, exc)

    def _batch_call(self, context, call):
        try:
            if self.batches is None:
                raise RpcStatus(
                    grpc.StatusCode.FAILED_PRECONDITION, "this server takes no batches (start it with --batch-dir DIR)"
                )
            try:
                return call()
            except BatchNotFound as exc:
                raise RpcStatus(grpc.StatusCode.NOT_FOUND, str(exc)) from None
        except Exception as exc:  # noqa: BLE001
            abort_for(context, exc)

    def SubmitBatch(self, request, context):
        retries = request.retries if request.HasField("retries") else None
        return self._batch_call(
            context,
            lambda: batch_status_to_proto(
                self.batches.status(self.batches.submit(request.manifest, request.format, retries))
            ),
        )

    def GetBatch(self, request, context):
        return self._batch_call(
            context, lambda: batch_status_to_proto(self.batches.status(request.batch_id, items=request.items))
        )

    def ListBatches(self, request, context):
        return self._batch_call(
            context, lambda: pb.ListBatchesResponse(batches=[batch_status_to_proto(b) for b in self.batches.list()])
        )

    def CancelBatch(self, request, context):
        return self._batch_call(context, lambda: batch_status_to_proto(self.batches.cancel(request.batch_id)))

    def StreamSynthesize(self, request_iterator, context):
        release = self.slots.try_acquire()
        if release is None:
            context.abort(
                grpc.StatusCode.RESOURCE_EXHAUSTED,
                f"the server is at its limit of {self.slots.limit} concurrent streams (--max-streams)",
            )
            return
        # Released when the call ends for any reason: the handler returning, the
        # client cancelling, the deadline passing, the server stopping.
        context.add_callback(release)
        try:
            # Which server holds the stream (behind a balancer, for the client to tell).
            context.send_initial_metadata(((SERVER_METADATA, self.identity),))
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
            abort_for(context, exc)
        finally:
            release()

    def _stream(self, request_iterator, context):
        first = first_message(request_iterator, self.config_timeout_s)
        if first is None:
            return  # the client half-closed without a config: nothing to do
        if first.WhichOneof("message") != "config":
            raise RpcStatus(grpc.StatusCode.INVALID_ARGUMENT, "config: the first message must carry a StreamConfig")
        config = first.config
        loaded = self._graph(config.graph, "config.graph")
        graph = loaded.graph
        options = options_from_proto(config.options, "config.options")
        strategy = get_strategy(options.strategy)
        stream = StreamInput.of(config, graph, strategy)
        calibration = StartCalibration.of(config, graph, stream.names)
        session = self._open_session(loaded, options, strategy, stream)
        metrics = self.metrics
        if metrics is not None:
            metrics.streams_started.inc()
        try:
            yield pb.StreamSynthesizeResponse(
                started=pb.StreamStarted(
                    graph=loaded.name,
                    rate_hz=graph.rate_hz,
                    lag_frames=session.lag_frames,
                    sensor_names=list(stream.names),
                    skeleton=loaded.info.skeleton,
                )
            )

            sample_index = -1
            previous_t = None
            frames_out = 0
            for request in request_iterator:
                if not context.is_active():
                    return  # cancelled or past the deadline: stop searching now
                kind = request.WhichOneof("message")
                if kind == "config":
                    raise RpcStatus(
                        grpc.StatusCode.INVALID_ARGUMENT,
                        f"sample[{sample_index + 1}]: only the first "
                        "message may carry a config; every later one carries a sample",
                    )
                if kind is None:
                    raise RpcStatus(grpc.StatusCode.INVALID_ARGUMENT, f"sample[{sample_index + 1}]: empty message")
                sample_index += 1
                arrived = time.perf_counter()
                sample = stream.sample(request.sample, previous_t, f"sample[{sample_index}]")
                previous_t = sample[0]
                for frame in self._push(
                    session, [sample] if calibration is None else calibration.add(sample), sample_index
                ):
                    yield pb.StreamSynthesizeResponse(frame=frame_to_proto(frame, sample_index))
                    frames_out += 1
                    if metrics is not None:
                        metrics.frames.inc()
                if metrics is not None:
                    metrics.samples.inc()
                    metrics.sample_seconds.observe(time.perf_counter() - arrived)
            if not context.is_active():
                return
            if calibration is not None:  # (a stream that ended within its calibrating seconds)
                for frame in self._push(session, calibration.finish(), sample_index):
                    yield pb.StreamSynthesizeResponse(frame=frame_to_proto(frame, sample_index))
                    frames_out += 1
                    if metrics is not None:
                        metrics.frames.inc()
            try:
                with self.threads.step() as threaded:
                    session.threads = threaded
                    frames = session.flush()
            except InputError as exc:  # (what only the stream's end tells: its samples as a whole)
                name = getattr(exc, "option_field", None)
                raise FieldError(f"sample[*].{name}" if name else "sample[*]", str(exc)) from None
            for frame in frames:
                yield pb.StreamSynthesizeResponse(frame=frame_to_proto(frame, max(sample_index, 0)))
                frames_out += 1
            if metrics is not None:
                metrics.frames.inc(len(frames))
            yield pb.StreamSynthesizeResponse(
                finished=pb.StreamFinished(samples_received=sample_index + 1, frames_emitted=frames_out)
            )
        finally:
            if self.live_workers is not None:  # (an in-process session is freed with this frame)
                session.close()

    def _push(self, session, samples, sample_index: int) -> list:
        """The frames `samples` (`StreamInput.sample`'s tuples) make, pushed in order; a
        refusal names sample[sample_index], the one that arrived last."""
        frames = []
        for t, acc, position, heading, markers, orientations in samples:
            try:
                start = time.perf_counter()
                with self.threads.step() as threaded:  # the threads while this stream runs alone
                    session.threads = threaded
                    frames += session.push(t, acc, position, heading, markers=markers, orientations=orientations)
                if self.metrics is not None:
                    self.metrics.push_seconds.observe(time.perf_counter() - start)
            except InputError as exc:
                raise FieldError(f"sample[{sample_index}]", str(exc)) from None
        return frames

    def _open_session(self, loaded: LoadedGraph, options, strategy, stream: StreamInput):
        """The stream's live session, in a live worker process or in this one, once the
        strategy's own checks of what the stream announces pass (here too when a worker
        opens the session); a refusal names the config's field."""
        try:
            strategy.check_stream(check_options(options), stream.names, stream.marker_names)
            if self.live_workers is not None:
                return self.live_workers.open(
                    loaded.name, options, stream.names, stream.marker_names, stream.orientations
                )
            return pipeline.open_session(
                loaded.graph,
                options,
                stream.names,
                keep_motion=False,  # (the client keeps them)
                marker_names=stream.marker_names,
                orientations=stream.orientations,
            )
        except InputError as exc:  # e.g. a constraint label the graph does not have
            raise _config_error(exc) from None

#!/usr/bin/env python3
"""Where a live sample's CPU goes in the server: the live session's push (search and
synthesis), the message conversions, and gRPC's own per-message cost.

    .venv/bin/python tools/probe_service.py GRAPH_FILE --recordings DIR [--streams 8] [--samples 600]
                                            [--beam 10] [--live-paths PATHS] [--no-refine]
    .venv/bin/python tools/probe_service.py GRAPH_FILE --only grpc

Prints one JSON object:
    session      per sample, ms, in one process without gRPC, the streams' samples
                 pushed round-robin (each stream its own LiveSession, beam --beam):
                 decode_ms (a serialized request → the session's arrays, as the server
                 checks them), push_ms (LiveSession.push: search step and synthesis),
                 synthesis_ms (the part of push_ms in the streaming synthesis),
                 encode_ms (the released frames → serialized responses), all after
                 the first warm_samples; start_push_ms (a session's longest push
                 among its first warm_samples: the one that starts its search over
                 the first second's samples at once, every node live) and
                 first_samples_ms (all those pushes), each a session's mean
    grpc_sync    a server with the service's thread-pool server and a handler that
                 only answers each request message with a pose-frame-sized response:
                 cpu_ms_per_message (the server process's CPU a request in and a
                 response out, clients in another process) and messages_per_s, for
                 --streams concurrent streams sending as fast as they are answered
    grpc_aio     the same through gRPC's asyncio server (grpc.aio)
session is what a sample costs without any server; grpc_* is what a server of the
service pays a sample on top (a message in, one out), whatever the graph.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing as mp
import sys
import threading
import time
from concurrent import futures
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

METHOD = "/probe.Echo/Stream"
FRAME_FLOATS = 27 * 7  # a pose frame's rotations and translations on a 27-joint skeleton


def session_costs(
    graph_path: str,
    recordings: list[str],
    streams: int,
    samples: int,
    beam: float,
    live_paths: int | None = None,
    refine: bool = True,
) -> dict:
    import numpy as np
    from bench_service import joined_recordings

    from graphsvc.pipeline import open_session
    from graphsvc.service import convert
    from graphsvc.service._generated import graphsvc_pb2 as pb
    from graphsvc.service.graphs import load_graphs
    from graphsvc.strategies.start import start_samples
    from graphsvc.synthesis.stream import StreamingSynthesizer

    spent = [0.0]  # seconds inside the streaming synthesis (a part of push_ms)
    add = StreamingSynthesizer.add

    def timed_add(self, *args, **kwargs):
        t = time.perf_counter()
        try:
            return add(self, *args, **kwargs)
        finally:
            spent[0] += time.perf_counter() - t

    StreamingSynthesizer.add = timed_add
    graph = load_graphs([f"probe={graph_path}"])["probe"].graph
    msg = pb.SynthesisOptions(beam=beam)
    if live_paths is not None:
        msg.strategy_name = "viterbi"
        msg.strategy_settings.update({"live_paths": live_paths})
    if not refine:
        msg.shared_settings.update({"refine": False})
    options = convert.options_from_proto(msg, "options")
    names = graph.sensor_names
    sessions = [open_session(graph, options, names, keep_motion=False) for _ in range(streams)]
    inputs = [joined_recordings(recordings, samples, seed) for seed in range(streams)]
    # A throwaway session through its start first: the kernels' loading and first
    # calls are no stream's start.
    spare = open_session(graph, options, names, keep_motion=False)
    acc, pos, head = inputs[0]
    for k in range(min(samples, 2 * start_samples(graph.rate_hz))):
        spare.push(k / graph.rate_hz, acc[k], None if pos is None else pos[k], None if head is None else head[k])
    del spare
    warm = min(60, samples // 4)
    opening = min(samples, int(round(5 * graph.rate_hz)))  # a stream's first 5 s
    cpu_first = np.zeros((streams, opening))  # each session's pushes' process CPU in its first 5 s
    totals = np.zeros(3)
    counted = 0
    steady_cpu = [0.0]  # the pushes' process CPU after `warm`, s
    first_pushes = np.zeros((streams, warm))  # each session's pushes before `warm`
    for k in range(samples):
        for i in range(streams):
            acc, pos, head = inputs[i]
            wire = pb.StreamSynthesizeRequest(
                sample=convert.sample_to_proto(
                    k / graph.rate_hz, acc[k], None if pos is None else pos[k], None if head is None else head[k]
                ),
            ).SerializeToString()
            t0 = time.perf_counter()
            sample = pb.StreamSynthesizeRequest.FromString(wire).sample
            t, a, p, h = convert.sample_from_proto(
                sample, len(names), None, None if k == 0 else (k - 1) / graph.rate_hz, "sample"
            )
            markers = convert.sample_markers_from_proto(sample, 0, "sample")
            orientations = convert.sample_orientations_from_proto(sample, len(names), None, False, "sample")
            if k == warm and i == 0:
                spent[0] = 0.0
            t1 = time.perf_counter()
            c1 = time.process_time()
            frames = sessions[i].push(t, a, p, h, markers=markers, orientations=orientations)
            t2 = time.perf_counter()
            c2 = time.process_time()
            if k < opening:
                cpu_first[i, k] = c2 - c1
            if k < warm:
                first_pushes[i, k] = t2 - t1
            for f in frames:
                pb.StreamSynthesizeResponse(frame=convert.frame_to_proto(f, k)).SerializeToString()
            t3 = time.perf_counter()
            if k >= warm:
                steady_cpu[0] += c2 - c1
                totals += (t1 - t0, t2 - t1, t3 - t2)
                counted += 1
    ms = 1e3 * totals / max(1, counted)
    return {
        "streams": streams,
        "samples": counted,
        "beam": beam,
        "live_paths": getattr(options.own, "live_paths", None),
        "refine": options.shared.refine,
        "decode_ms": round(float(ms[0]), 4),
        "push_ms": round(float(ms[1]), 4),
        "synthesis_ms": round(1e3 * spent[0] / max(1, counted), 4),
        "encode_ms": round(float(ms[2]), 4),
        "warm_samples": warm,
        "start_push_ms": round(float(1e3 * first_pushes.max(axis=1).mean()), 2),
        "first_samples_ms": round(float(1e3 * first_pushes.sum(axis=1).mean()), 2),
        "start_push_cpu_ms": round(float(1e3 * cpu_first.max(axis=1).mean()), 2),
        "start_push_cpu_ms_max": round(float(1e3 * cpu_first.max()), 2),
        "opening_cpu_ms_by_s": [
            round(float(1e3 * cpu_first[:, j : j + int(graph.rate_hz)].sum(axis=1).mean()), 2)
            for j in range(0, opening, int(graph.rate_hz))
        ],
        "steady_cpu_ms": round(float(1e3 * steady_cpu[0] / max(1, counted)), 4),
    }


# ---------------------------------------------------------------- gRPC alone


def _response() -> bytes:
    from graphsvc.service._generated import graphsvc_pb2 as pb

    frame = pb.PoseFrame(index=1, time_s=0.1, node=12345, label="walk", input_sample_index=1)
    frame.rotations_wxyz.extend([0.5] * (27 * 4))
    frame.translations_m.extend([0.25] * (27 * 3))
    frame.sources.add(clip=3, frame=40.0, weight=1.0)
    return pb.StreamSynthesizeResponse(frame=frame).SerializeToString()


def _request() -> bytes:
    from graphsvc.service import convert
    from graphsvc.service._generated import graphsvc_pb2 as pb

    return pb.StreamSynthesizeRequest(
        sample=convert.sample_to_proto(0.1, [[0.1, 9.8, 0.2]] * 4, (1.0, 2.0), 0.3)
    ).SerializeToString()


def _echo_clients(address: str, streams: int, messages: int, results) -> None:
    """streams concurrent calls, each sending `messages` requests one at a time, the
    next as soon as the previous one's answer came back."""
    import queue

    import grpc

    channel = grpc.insecure_channel(address)
    call = channel.stream_stream(METHOD, request_serializer=None, response_deserializer=None)
    request = _request()

    def run():
        answers: queue.SimpleQueue = queue.SimpleQueue()

        def requests():
            for _ in range(messages):
                yield request
                answers.get()

        for _ in call(requests()):
            answers.put(None)

    t0 = time.perf_counter()
    threads = [threading.Thread(target=run) for _ in range(streams)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    results.put(time.perf_counter() - t0)
    channel.close()


def _measure(address: str, streams: int, messages: int) -> dict:
    ctx = mp.get_context("spawn")
    results = ctx.Queue()
    client = ctx.Process(target=_echo_clients, args=(address, streams, messages, results))
    cpu0 = time.process_time()
    client.start()
    wall = results.get(timeout=600)
    cpu = time.process_time() - cpu0
    client.join()
    total = streams * messages
    return {
        "streams": streams,
        "messages": total,
        "cpu_ms_per_message": round(1e3 * cpu / total, 4),
        "messages_per_s": round(total / wall, 1),
    }


def grpc_sync(streams: int, messages: int) -> dict:
    import grpc

    response = _response()

    def handler(request_iterator, context):
        for _ in request_iterator:
            yield response

    server = grpc.server(futures.ThreadPoolExecutor(max_workers=streams + 4), options=[("grpc.so_reuseport", 0)])
    server.add_generic_rpc_handlers(
        (
            grpc.method_handlers_generic_handler(
                "probe.Echo", {"Stream": grpc.stream_stream_rpc_method_handler(handler)}
            ),
        )
    )
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    try:
        _measure(f"127.0.0.1:{port}", 1, 200)  # warm-up
        return _measure(f"127.0.0.1:{port}", streams, messages)
    finally:
        server.stop(None)


def grpc_aio(streams: int, messages: int) -> dict:
    import grpc

    response = _response()

    async def handler(request_iterator, context):
        async for _ in request_iterator:
            yield response

    async def main():
        server = grpc.aio.server(options=[("grpc.so_reuseport", 0)])
        server.add_generic_rpc_handlers(
            (
                grpc.method_handlers_generic_handler(
                    "probe.Echo", {"Stream": grpc.stream_stream_rpc_method_handler(handler)}
                ),
            )
        )
        port = server.add_insecure_port("127.0.0.1:0")
        await server.start()
        loop = asyncio.get_running_loop()
        try:
            await loop.run_in_executor(None, _measure, f"127.0.0.1:{port}", 1, 200)
            return await loop.run_in_executor(None, _measure, f"127.0.0.1:{port}", streams, messages)
        finally:
            await server.stop(None)

    return asyncio.run(main())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("graph", metavar="GRAPH_FILE", nargs="?")
    parser.add_argument("--recordings", metavar="DIR", help=".rec recordings the streams play (joined)")
    parser.add_argument("--streams", type=int, default=8, help="streams side by side (default 8)")
    parser.add_argument("--samples", type=int, default=600, help="samples a stream (default 600)")
    parser.add_argument(
        "--messages", type=int, default=2000, help="messages a stream for the gRPC probes (default 2000)"
    )
    parser.add_argument("--beam", type=float, default=10.0, help="beam of the sessions (default 10)")
    parser.add_argument(
        "--live-paths",
        type=int,
        metavar="PATHS",
        help="the sessions' --viterbi-live-paths (default: the option's; 0: the beam alone)",
    )
    parser.add_argument("--no-refine", action="store_true", help="the sessions without the refinement")
    parser.add_argument("--only", choices=("session", "grpc"), help="one part only")
    args = parser.parse_args(argv)
    out = {}
    if args.only != "grpc":
        if not (args.graph and args.recordings):
            raise SystemExit("the session part needs GRAPH_FILE and --recordings DIR (or --only grpc)")
        recs = sorted(str(p) for p in Path(args.recordings).glob("*.rec"))
        if not recs:
            raise SystemExit(f"{args.recordings}: no .rec recordings")
        out["session"] = session_costs(
            args.graph, recs, args.streams, args.samples, args.beam, args.live_paths, not args.no_refine
        )
    if args.only != "session":
        out["grpc_sync"] = grpc_sync(args.streams, args.messages)
        out["grpc_aio"] = grpc_aio(args.streams, args.messages)
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/env python3
"""Benchmark of live synthesis: N concurrent StreamSynthesize calls at the graph rate
against a `graphsvc serve` subprocess on loopback.

    .venv/bin/python tools/bench_service.py bandai.graph                 # 8, 16, 32, 64 streams × 20 s
    .venv/bin/python tools/bench_service.py small.graph --levels 1,2 --seconds 2
    .venv/bin/python tools/bench_service.py G --recordings DIR --beam 10 --levels 8,16,24,32 --stagger 0,20
                                                                   # at kick-off and staggered

Prints one JSON object per level (and per --stagger value, each level at each):
    streams        concurrent live streams
    p50_ms, p99_ms latency from sending a sample to receiving the pose it released,
                   i.e. beyond the configured decoder lag (PoseFrame.input_sample_index)
    p99_settled_ms p99 of the samples sent after the first SETTLE_S seconds: all streams
                   start together, and a search's first samples keep most nodes live
                   (a beam search's too), so the start is a burst the rest is not
    p99_by_5s_ms   p99 of each 5 s of the streams' own time (0–5 s, 5–10 s, …): the
                   start's backlog and how long it takes to clear
    dropped        frames that never came back (samples sent − frames received, plus
                   the frames of streams that failed to start)
    late_sends     samples the clients sent more than one period late (client overload:
                   the latencies are then not the server's alone)
    errors         failed streams by status code
    server_rss_mb  peak memory of the server and its live workers during the level, MiB
                   (their proportional set sizes summed: the memory-mapped graph's
                   pages, shared, are counted once)
    server_cores   the server's and its live workers' CPU time during the level's
                   sending, in cores
    front_cores    the part of server_cores in the server's own process (gRPC, the
                   messages' checks and encoding; all of it without live workers)
                   (CPU seconds a second)
    machine_cores  the whole machine's busy CPU time over the same span, in cores: the
                   clients run on the same machine, so when this nears the core count
                   the machine, not the server alone, is the limit

    server_cpu_ms_per_sample  the server's CPU time from the start of the sending until
                   every stream was answered, divided by the samples sent, ms

Input: by default each stream plays a random walk through the graph's own edges (their
sensor metadata plus white noise σ 0.3 m/s²), so any graph can be benchmarked without
recordings. With --recordings DIR each stream plays the `.rec` recordings in DIR (e.g.
`graphsvc simulate` of clips the graph was built without) in its own seeded order,
joined end to end (each clip's track moved to start where the previous one ended),
with everything they carry: accelerations, ground position and heading. Clients run
in several processes (--streams-per-process) so that the Python client does not
become the bottleneck.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SETTLE_S = 3.0  # p99_settled_ms leaves out the samples sent in a level's first seconds
WINDOW_S = 5.0  # p99_by_5s_ms: a p99 for each such stretch of the streams' time
sys.path.insert(0, str(ROOT))


def random_walk(graph, steps: int, rng: np.random.Generator) -> tuple[int, np.ndarray]:
    """(first node, edges (steps,) int64): a random walk through the graph's edges from a
    random node, each step a random outgoing edge; dead ends jump to a random node."""
    order = np.argsort(graph.edge_src, kind="stable")  # edges grouped by source
    starts = np.searchsorted(graph.edge_src[order], np.arange(graph.num_nodes + 1))
    first = node = int(rng.integers(graph.num_nodes))
    edges = np.empty(steps, np.int64)
    for k in range(steps):
        lo, hi = starts[node], starts[node + 1]
        while lo == hi:  # dead end
            node = int(rng.integers(graph.num_nodes))
            lo, hi = starts[node], starts[node + 1]
        edges[k] = e = order[int(rng.integers(lo, hi))]
        node = int(graph.edge_dst[e])
    return first, edges


def random_walk_readings(graph_path: str, samples: int, seed: int) -> np.ndarray:
    """(samples, S, 3) float32 m/s²: a random walk through the graph's edges
    (`random_walk`), each step's edge metadata plus white noise."""
    from graphsvc.graph.file import load_graph

    graph = load_graph(graph_path)
    rng = np.random.default_rng(seed)
    _, edges = random_walk(graph, samples, rng)
    out = np.asarray(graph.edge_acc[edges], dtype=np.float32)
    return out + rng.normal(0.0, 0.3, out.shape).astype(np.float32)


def joined_recordings(
    paths: list[str], samples: int, seed: int
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(acc (samples, S, 3) float32, ground position (samples, 2) or None, heading
    (samples,) or None): the recordings in a seeded random order, repeated as needed,
    joined end to end; each recording's track is moved to start where the previous
    one's ended."""
    from graphsvc.sensors.recording import load_recording

    rng = np.random.default_rng(seed)
    recs = [load_recording(p) for p in paths]
    acc, pos, head = [], [], []
    have, end = 0, np.zeros(2)
    while have < samples:
        for k in rng.permutation(len(recs)):
            rec = recs[k]
            acc.append(rec.accelerations)
            if rec.ground_position is not None:
                track = rec.ground_position - rec.ground_position[0] + end
                end = track[-1]
                pos.append(track)
            if rec.heading is not None:
                head.append(rec.heading)
            have += rec.num_samples
            if have >= samples:
                break
    whole = lambda parts: np.concatenate(parts)[:samples] if len(parts) == len(acc) else None  # noqa: E731
    return np.asarray(whole(acc), np.float32), whole(pos), whole(head)


def _stream_inputs(graph_path: str, recordings: list[str] | None, samples: int, seed: int):
    """What one stream sends: joined_recordings, or a random walk's readings."""
    if recordings:
        return joined_recordings(recordings, samples, seed)
    return random_walk_readings(graph_path, samples, seed=seed), None, None


def _client_process(
    address,
    graph_name,
    graph_path,
    stream_ids,
    seconds,
    rate_hz,
    options_bytes,
    start_at,
    results,
    recordings=None,
    stagger_s=0.0,
    streams=1,
):
    """Run len(stream_ids) paced streams in threads; put one result dict per stream.
    options_bytes: the streams' SynthesisOptions, serialized. Stream i of `streams`
    sends its first sample stagger_s · i / streams after start_at."""
    from graphsvc.service import client as C
    from graphsvc.service import convert
    from graphsvc.service._generated import graphsvc_pb2 as pb

    samples = round(seconds * rate_hz)
    inputs = {i: _stream_inputs(graph_path, recordings, samples, seed=i) for i in stream_ids}
    options = pb.SynthesisOptions.FromString(options_bytes)
    conn = C.connect(address)

    def run(i):
        acc, pos, head = inputs[i]
        feed = C.SampleFeed(C.stream_config(graph_name, options))
        late = 0
        stop = threading.Event()

        def pace():
            nonlocal late
            try:
                for k in range(samples):
                    due = start_at + stagger_s * i / streams + k / rate_hz
                    delay = due - time.time()
                    if delay > 0:
                        if stop.wait(delay):
                            return
                    elif -delay > 1.0 / rate_hz:
                        late += 1
                    feed.put(
                        convert.sample_to_proto(
                            k / rate_hz, acc[k], None if pos is None else pos[k], None if head is None else head[k]
                        )
                    )
            finally:
                feed.close()

        sender = threading.Thread(target=pace, daemon=True)
        sender.start()
        error = None
        latencies, frames, released_by = [], 0, []
        try:
            result = C.run_stream(conn, feed, timeout_s=seconds + 120)
            latencies, frames = result.latencies_ms, len(result.frames)
            released_by = [f.input_sample_index for f in result.frames]
        except C.ServiceError as exc:
            error = exc.code.name if exc.code is not None else "UNKNOWN"
        stop.set()
        sender.join()
        results.put(
            {
                "stream": i,
                "sent": len(feed.sent_at),
                "frames": frames,
                "latencies_ms": latencies,
                "released_by": released_by,
                "late_sends": late,
                "error": error,
                "expected": samples,
            }
        )

    threads = [threading.Thread(target=run, args=(i,)) for i in stream_ids]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    conn.close()


def process_tree(pid: int) -> list[int]:
    """pid and every process descended from it (the server's live workers)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(children.get(p, ()))
    return out


def cpu_seconds(pid: int, tree: bool = True) -> float:
    """User + system CPU time (s) so far of a process and (tree) its descendants alive now."""
    total = 0.0
    for p in process_tree(pid) if tree else [pid]:
        try:
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            if p == pid:
                return float("nan")
            continue
        total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return total


def machine_busy_seconds() -> float:
    """Busy CPU time (s) of all cores so far (/proc/stat: everything but idle and iowait)."""
    values = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    return (sum(values[:8]) - values[3] - values[4]) / os.sysconf("SC_CLK_TCK")


def rss_mb(pid: int) -> float:
    """Memory of a process and its descendants, MiB: the sum of their proportional set
    sizes (a page shared by k of them, as the memory-mapped graph, counts 1/k in each)."""
    total, found = 0.0, False
    for p in process_tree(pid):
        try:
            text = Path(f"/proc/{p}/smaps_rollup").read_text()
        except OSError:
            continue
        m = re.search(r"^Pss:\s+(\d+) kB", text, re.M)
        if m:
            total, found = total + int(m.group(1)) / 1024, True
    return total if found else float("nan")


def run_level(
    address,
    graph_name,
    graph_path,
    streams,
    seconds,
    rate_hz,
    options_bytes,
    per_process,
    server_pid,
    recordings=None,
    stagger_s=0.0,
) -> dict:
    ctx = mp.get_context("spawn")  # no fork after gRPC is loaded
    results = ctx.Queue()
    start_at = time.time() + 3.0 + 0.05 * streams  # time for the client processes to load inputs
    ids = list(range(streams))
    procs = [
        ctx.Process(
            target=_client_process,
            args=(
                address,
                graph_name,
                graph_path,
                ids[i : i + per_process],
                seconds,
                rate_hz,
                options_bytes,
                start_at,
                results,
                recordings,
                stagger_s,
                streams,
            ),
        )
        for i in range(0, streams, per_process)
    ]
    for p in procs:
        p.start()
    peak = 0.0
    collected = []
    cpu = []  # (wall, server CPU, machine busy) when the sending starts and ends
    while len(collected) < streams:
        peak = max(peak, rss_mb(server_pid)) if server_pid else peak
        now = time.time()
        if server_pid and len(cpu) < 2 and now >= start_at + (seconds if cpu else 0.0) + (stagger_s if cpu else 0.0):
            cpu.append((now, cpu_seconds(server_pid), machine_busy_seconds(), cpu_seconds(server_pid, tree=False)))
        try:
            collected.append(results.get(timeout=0.5))
        except queue.Empty:
            if not any(p.is_alive() for p in procs) and results.empty():
                break
    if len(cpu) == 1:  # every stream ended within the last poll
        cpu.append((time.time(), cpu_seconds(server_pid), machine_busy_seconds(), cpu_seconds(server_pid, tree=False)))
    cpu_to_end = cpu_seconds(server_pid) - cpu[0][1] if server_pid and cpu else None  # every stream answered
    for p in procs:
        p.join()
    latencies = np.concatenate([np.asarray(r["latencies_ms"], float) for r in collected]) if collected else np.zeros(0)
    released_by = np.concatenate([np.asarray(r["released_by"], float) for r in collected]) if collected else np.zeros(0)
    settled = latencies[np.isfinite(latencies) & (released_by >= SETTLE_S * rate_hz)]
    window = np.floor(released_by / (WINDOW_S * rate_hz))
    by_window = [
        round(float(np.percentile(latencies[(window == w) & np.isfinite(latencies)], 99)), 1)
        for w in range(int(window.max()) + 1 if window.size else 0)
        if ((window == w) & np.isfinite(latencies)).any()
    ]
    latencies = latencies[np.isfinite(latencies)]
    errors: dict[str, int] = {}
    for r in collected:
        if r["error"]:
            errors[r["error"]] = errors.get(r["error"], 0) + 1
    expected = round(seconds * rate_hz) * streams
    return {
        "streams": streams,
        "p50_ms": round(float(np.percentile(latencies, 50)), 3) if latencies.size else None,
        "p99_ms": round(float(np.percentile(latencies, 99)), 3) if latencies.size else None,
        "p99_settled_ms": round(float(np.percentile(settled, 99)), 3) if settled.size else None,
        "p99_by_5s_ms": by_window,
        "dropped": int(expected - sum(r["frames"] for r in collected)),
        "late_sends": int(sum(r["late_sends"] for r in collected)),
        "errors": errors,
        "server_rss_mb": round(peak, 1) if server_pid else None,
        "server_cores": round((cpu[1][1] - cpu[0][1]) / (cpu[1][0] - cpu[0][0]), 2) if len(cpu) == 2 else None,
        "machine_cores": round((cpu[1][2] - cpu[0][2]) / (cpu[1][0] - cpu[0][0]), 2) if len(cpu) == 2 else None,
        "front_cores": round((cpu[1][3] - cpu[0][3]) / (cpu[1][0] - cpu[0][0]), 2) if len(cpu) == 2 else None,
        "server_cpu_ms_per_sample": round(1e3 * cpu_to_end / max(1, sum(r["sent"] for r in collected)), 3)
        if cpu_to_end is not None
        else None,
        "seconds": seconds,
        "rate_hz": rate_hz,
    }


def stop_servers(procs) -> None:
    """SIGTERM every server process, then wait up to 15 s for each (killed after)."""
    for proc in procs:
        proc.send_signal(signal.SIGTERM)
    for proc in procs:
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()


def start_server(graph_path: str, max_streams: int, *extra: str) -> tuple[subprocess.Popen, str]:
    """A `graphsvc serve` subprocess on a free loopback port serving graph_path as
    "bench" (extra: more serve flags); (process, address)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "graphsvc.cli",
            "serve",
            "--graph",
            f"bench={graph_path}",
            "--host",
            "127.0.0.1",
            "--port",
            "0",
            "--max-streams",
            str(max_streams),
            "--grace-s",
            "2",
            *extra,
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    line = proc.stdout.readline()
    m = re.search(r"listening on (127\.0\.0\.1:\d+)", line)
    if not m:
        proc.kill()
        raise SystemExit(f"the server did not start: {line!r}")
    return proc, m.group(1)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("graph", metavar="GRAPH_FILE")
    parser.add_argument("--levels", default="8,16,32,64", help="concurrent streams per level (default 8,16,32,64)")
    parser.add_argument("--seconds", type=float, default=20.0, help="length of each level (default 20)")
    parser.add_argument("--rate", type=float, help="samples per second per stream (default: the graph rate)")
    parser.add_argument("--latency", type=float, help="decoder lag in seconds (default: the server's, 1 s)")
    parser.add_argument("--beam", type=float, metavar="COST", help="beam search (default: the exact search)")
    parser.add_argument("--streams-per-process", type=int, default=8, help="client streams per process (default 8)")
    parser.add_argument("--server", metavar="ADDR", help="benchmark a running server (graph name 'bench') instead")
    parser.add_argument(
        "--recordings", metavar="DIR", help="play these .rec recordings (joined) instead of random walks"
    )
    parser.add_argument(
        "--stagger",
        default="0",
        metavar="S[,S...]",
        help="start the streams one after another over S seconds (default 0: all at once, a "
        "kick-off); several: every level at each",
    )
    parser.add_argument(
        "--no-refine", action="store_true", help="the streams without the refinement (shared setting refine: false)"
    )
    parser.add_argument("--live-workers", type=int, metavar="N", help="the server's --live-workers (default: its own)")
    args = parser.parse_args(argv)
    levels = [int(x) for x in args.levels.split(",") if x]
    staggers = [float(x) for x in args.stagger.split(",") if x]
    recordings = sorted(str(p) for p in Path(args.recordings).glob("*.rec")) if args.recordings else None
    if args.recordings and not recordings:
        raise SystemExit(f"{args.recordings}: no .rec recordings")

    from graphsvc.graph.file import load_graph
    from graphsvc.service._generated import graphsvc_pb2 as pb

    graph_path = str(Path(args.graph).resolve())
    rate = args.rate or float(load_graph(graph_path).rate_hz)
    proc = None
    if args.server:
        address, server_pid = args.server, None
    else:
        extra = () if args.live_workers is None else ("--live-workers", str(args.live_workers))
        proc, address = start_server(graph_path, max(levels), *extra)
        server_pid = proc.pid
    options = pb.SynthesisOptions()
    if args.latency is not None:
        options.latency_s = args.latency
    if args.beam is not None:
        options.beam = args.beam
    if args.no_refine:
        options.shared_settings.update({"refine": False})
    options_bytes = options.SerializeToString()
    try:
        # Warm-up: the first stream loads the compiled search kernels.
        run_level(
            address, "bench", graph_path, 1, min(2.0, args.seconds), rate, options_bytes, 1, server_pid, recordings
        )
        for stagger in staggers:
            for streams in levels:
                print(
                    f"level {streams} streams × {args.seconds:g} s, started over {stagger:g} s ...",
                    file=sys.stderr,
                    flush=True,
                )
                result = run_level(
                    address,
                    "bench",
                    graph_path,
                    streams,
                    args.seconds,
                    rate,
                    options_bytes,
                    args.streams_per_process,
                    server_pid,
                    recordings,
                    stagger,
                )
                print(json.dumps(dict(result, stagger_s=stagger)), flush=True)
    finally:
        if proc is not None:
            stop_servers([proc])
    return 0


if __name__ == "__main__":
    sys.exit(main())

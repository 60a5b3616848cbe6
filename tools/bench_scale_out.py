#!/usr/bin/env python3
"""Benchmark of live synthesis spread over several servers: N `graphsvc serve`
subprocesses on loopback, the clients given all their addresses (`--server A,B`, gRPC's
round_robin), the same paced streams as tools/bench_service.py.

    .venv/bin/python tools/bench_scale_out.py G --servers 2 --live-workers 1 --levels 16 --seconds 20 --beam 10

On one machine the servers share its cores: the figures show the spread and what the
extra processes cost, not the capacity of more machines. Prints one JSON object per
level: bench_service.py's keys (latency beyond the lag, p99 by 5 s, dropped, errors,
late sends; the server keys left null), and
    servers                 how many
    streams_by_server       the streams each server started (its graphsvc_streams_started_total)
    servers_cores           CPU seconds a second of every server and its live workers, while the clients send
    machine_cores           the whole machine's, clients included
    servers_cpu_ms_per_sample  the servers' CPU from the first sample until every stream was answered, over the samples
    servers_rss_mb          the servers' summed proportional set sizes at the level's end, MiB
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

import bench_service as B  # noqa: E402 (the paced streams, the CPU and memory probes)


def start_servers(graph_path: str, count: int, max_streams: int, live_workers: int | None):
    """`count` servers, started at once; [(process, address, metrics port)]."""
    extra = ["--metrics-port", "0"] + ([] if live_workers is None else ["--live-workers", str(live_workers)])
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    procs = [
        subprocess.Popen(
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
        for _ in range(count)
    ]
    out = []
    for proc in procs:
        line = proc.stdout.readline()
        m = re.search(r"listening on (127\.0\.0\.1:\d+).*metrics on http://[^:]+:(\d+)/metrics", line)
        if not m:
            for p in procs:
                p.kill()
            raise SystemExit(f"a server did not start: {line!r}")
        out.append((proc, m.group(1), int(m.group(2))))
    return out


def streams_started(metrics_port: int) -> float:
    with urllib.request.urlopen(f"http://127.0.0.1:{metrics_port}/metrics", timeout=10) as r:
        m = re.search(r"^graphsvc_streams_started_total (\S+)$", r.read().decode(), re.M)
    return float(m.group(1)) if m else 0.0


def servers_cpu(servers) -> float:
    return sum(B.cpu_seconds(proc.pid) for proc, _, _ in servers)


def run_level(
    servers, address, graph_path, streams, seconds, rate, options_bytes, per_process, recordings, stagger_s
) -> dict:
    """bench_service.run_level over every server, with the servers' CPU measured from
    the first sample (run_level's start) to the level's end, and the spread."""
    before = [streams_started(port) for _, _, port in servers]
    marks: dict[str, tuple] = {}
    start_at = time.time() + 3.0 + 0.05 * streams  # (as run_level computes it)

    def sample_cpu():
        while time.time() < start_at:
            time.sleep(0.05)
        marks["start"] = (time.time(), servers_cpu(servers), B.machine_busy_seconds())
        while time.time() < start_at + seconds + stagger_s:
            time.sleep(0.05)
        marks["sent"] = (time.time(), servers_cpu(servers), B.machine_busy_seconds())

    probe = threading.Thread(target=sample_cpu, daemon=True)
    probe.start()
    result = B.run_level(
        address, "bench", graph_path, streams, seconds, rate, options_bytes, per_process, None, recordings, stagger_s
    )
    end_cpu = servers_cpu(servers)
    probe.join(1.0)
    after = [streams_started(port) for _, _, port in servers]
    t0, c0, m0 = marks.get("start", (None, None, None))
    t1, c1, m1 = marks.get("sent", (None, None, None))
    sent = round(seconds * rate) * streams
    result.update(
        {
            "servers": len(servers),
            "streams_by_server": [int(a - b) for a, b in zip(after, before)],
            "servers_cores": round((c1 - c0) / (t1 - t0), 2) if t1 else None,
            "machine_cores": round((m1 - m0) / (t1 - t0), 2) if t1 else None,
            "servers_cpu_ms_per_sample": round(1e3 * (end_cpu - c0) / max(1, sent), 3) if c0 is not None else None,
            "servers_rss_mb": round(sum(B.rss_mb(proc.pid) for proc, _, _ in servers), 1),
        }
    )
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("graph", metavar="GRAPH_FILE")
    parser.add_argument("--servers", type=int, default=2, help="servers to start (default 2)")
    parser.add_argument("--live-workers", type=int, metavar="N", help="each server's --live-workers (default: its own)")
    parser.add_argument("--levels", default="16", help="concurrent streams per level, all servers (default 16)")
    parser.add_argument("--seconds", type=float, default=20.0, help="length of each level (default 20)")
    parser.add_argument("--beam", type=float, metavar="COST", help="beam search (default: the exact search)")
    parser.add_argument("--latency", type=float, help="decoder lag in seconds (default: the server's, 1 s)")
    parser.add_argument(
        "--recordings", metavar="DIR", help="play these .rec recordings (joined) instead of random walks"
    )
    parser.add_argument(
        "--stagger",
        type=float,
        default=0.0,
        metavar="S",
        help="start the streams one after another over S seconds (default 0: all at once)",
    )
    parser.add_argument("--streams-per-process", type=int, default=8, help="client streams per process (default 8)")
    args = parser.parse_args(argv)
    levels = [int(x) for x in args.levels.split(",") if x]
    recordings = sorted(str(p) for p in Path(args.recordings).glob("*.rec")) if args.recordings else None

    from graphsvc.graph.file import load_graph
    from graphsvc.service._generated import graphsvc_pb2 as pb

    graph_path = str(Path(args.graph).resolve())
    rate = float(load_graph(graph_path).rate_hz)
    options = pb.SynthesisOptions()
    if args.latency is not None:
        options.latency_s = args.latency
    if args.beam is not None:
        options.beam = args.beam
    options_bytes = options.SerializeToString()
    servers = start_servers(graph_path, args.servers, max(levels), args.live_workers)
    address = ",".join(a for _, a, _ in servers)
    try:
        for _ in servers:  # warm-up: each server's first stream loads its kernels
            B.run_level(address, "bench", graph_path, len(servers), 2.0, rate, options_bytes, 8, None, recordings)
        for streams in levels:
            print(
                f"level {streams} streams × {args.seconds:g} s over {len(servers)} servers ...",
                file=sys.stderr,
                flush=True,
            )
            result = run_level(
                servers,
                address,
                graph_path,
                streams,
                args.seconds,
                rate,
                options_bytes,
                args.streams_per_process,
                recordings,
                args.stagger,
            )
            print(json.dumps(dict(result, stagger_s=args.stagger)), flush=True)
    finally:
        B.stop_servers([proc for proc, _, _ in servers])
    return 0


if __name__ == "__main__":
    sys.exit(main())

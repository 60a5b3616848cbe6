#!/usr/bin/env python3
"""Soak of the live service: churn against a `graphsvc serve` subprocess on loopback
for a bounded time, then checks that it is back where it started.

    .venv/bin/python tools/soak_service.py GRAPH_FILE                      # 64 clients × 600 s
    .venv/bin/python tools/soak_service.py small.graph --seconds 5 --streams 8 --max-streams 4

`--streams` clients (threads in `--processes` processes) each make calls one after the
other until `--seconds` have passed, each call a scenario drawn at random:

    complete      config, 1–10 s of samples at the graph rate, half-close: every frame
                  and StreamFinished must come back (a well-formed call)
    disconnect    config, samples, then the client cancels mid-stream
    deadline      config, samples until a 0.3–3 s deadline expires
    malformed     one of: a sample first, a second config, an empty message, a sample
                  of the wrong length, a NaN time, an unknown graph, a bad option,
                  bytes that are no message at all
    out_of_order  config, samples, then a sample earlier than the one before
    no_config     connect and send nothing (the server's --config-timeout-s ends it)
    unary         ListGraphs, or GetGraph of a graph that does not exist

Every call has a deadline, so the tool stops by itself: after --seconds plus at most
the longest call (about a minute), and a hard stop kills the clients beyond that. Each
scenario's answer must be one it allows (RESOURCE_EXHAUSTED is allowed for every
stream, and must come at once). Meanwhile health is checked every second, and the
server's RSS and thread count sampled. At the end the tool opens --max-streams streams
at once (all must start: no slot leaked), closes them, stops the server with SIGTERM
(exit 0 expected) and prints one JSON object:

    calls           scenario → status → count; unexpected: count and the first few
    rejected_ms     RESOURCE_EXHAUSTED answers: p50, p99 and slowest, ms (a wait for a
                    slot would take a stream's length)
    health          SERVING / other / failed checks, and the slowest check, ms
    rss_mb          samples (s, MiB) of the server and its live workers (summed
                    proportional set sizes), and after the warm-up (the first fifth):
                    the medians of its first and last quarter and their ratio − 1
                    (growth)
    threads         at the start, the most seen, at the end, and the bound (the start
                    plus the server's worker pool plus THREAD_SLACK)
    slots_probe     streams started out of --max-streams after the churn
    server_exit     the server's exit code after SIGTERM
    ok              every check above passed

Loopback only: the server is started by the tool on 127.0.0.1.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import queue
import re
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from bench_service import random_walk_readings, rss_mb, start_server  # noqa: E402

SCENARIOS = {
    "complete": 0.35,
    "disconnect": 0.15,
    "deadline": 0.10,
    "malformed": 0.15,
    "out_of_order": 0.10,
    "no_config": 0.05,
    "unary": 0.10,
}
MALFORMED = (
    "sample_first",
    "second_config",
    "empty_message",
    "wrong_length",
    "nan_time",
    "unknown_graph",
    "bad_option",
    "garbage",
)
# The answers each scenario allows (a stream may also be refused at its limit).
EXPECTED = {
    "complete": {"OK"},
    "disconnect": {"CANCELLED"},
    "deadline": {"DEADLINE_EXCEEDED"},
    "malformed": {"INVALID_ARGUMENT", "NOT_FOUND"},
    "out_of_order": {"INVALID_ARGUMENT"},
    "no_config": {"DEADLINE_EXCEEDED"},
    "unary": {"OK", "NOT_FOUND"},
}
# gRPC's own answer to bytes that do not parse as the request message.
GARBAGE_EXPECTED = {"INTERNAL", "INVALID_ARGUMENT"}
STREAM_METHOD = "/graphsvc.v1.MotionGraphService/StreamSynthesize"
CALL_SLACK_S = 60.0  # a complete stream's deadline beyond its samples' duration
# Threads the server may hold beyond its worker pool: gRPC core's executor and timer
# threads come and go with the load, and the health service's pool starts at its first check.
THREAD_SLACK = 4


def thread_count(pid: int) -> int | None:
    try:
        m = re.search(r"Threads:\s+(\d+)", Path(f"/proc/{pid}/status").read_text())
    except OSError:
        return None
    return int(m.group(1)) if m else None


# ---------------------------------------------------------------- clients


class _Client:
    """One client: calls one after another until `end_at`, tallying the answers."""

    def __init__(
        self, conn, graph: str, readings: np.ndarray, rate_hz: float, config_timeout_s: float, seed: int, tally
    ):
        from graphsvc.service._generated import graphsvc_pb2 as pb

        self.pb = pb
        self.conn = conn
        self.graph = graph
        self.readings = readings  # (K, S, 3): looped
        self.rate = rate_hz
        self.config_timeout_s = config_timeout_s
        self.rng = np.random.default_rng(seed)
        self.tally = tally
        self.stop = threading.Event()

    def _sample(self, k: int, t: float | None = None):
        from graphsvc.service import convert

        return self.pb.StreamSynthesizeRequest(
            sample=convert.sample_to_proto(k / self.rate if t is None else t, self.readings[k % len(self.readings)])
        )

    def _config(self, **options):
        return self.pb.StreamSynthesizeRequest(
            config=self.pb.StreamConfig(graph=self.graph, options=self.pb.SynthesisOptions(beam=10.0, **options))
        )

    def _paced(self, first, count: int, start: int = 0, then=()):
        """first, then `count` samples at the graph rate, then `then`'s requests."""
        yield first
        t0 = time.monotonic()
        for k in range(start, start + count):
            delay = t0 + (k - start) / self.rate - time.monotonic()
            if delay > 0 and self.stop.wait(delay):
                return
            yield self._sample(k)
        yield from then

    def _stream(self, requests, timeout_s: float, on_call=None):
        """(status name, responses by kind) of a StreamSynthesize call."""
        import grpc

        call = self.conn.stub.StreamSynthesize(requests, timeout=timeout_s, metadata=self.conn.metadata)
        if on_call is not None:
            on_call(call)
        kinds = {"started": 0, "frame": 0, "finished": 0}
        try:
            for response in call:
                kinds[response.WhichOneof("message")] += 1
        except grpc.RpcError as exc:
            return exc.code().name, kinds
        return "OK", kinds

    def run_one(self) -> None:
        scenario = str(self.rng.choice(list(SCENARIOS), p=list(SCENARIOS.values())))
        t0 = time.monotonic()
        status, detail, expected = getattr(self, "_" + scenario)()
        elapsed_ms = 1e3 * (time.monotonic() - t0)
        self.tally(scenario, status, elapsed_ms, expected, detail)
        if status == "RESOURCE_EXHAUSTED":  # back off, as a client at a full server would
            self.stop.wait(float(self.rng.uniform(0.05, 0.5)))

    def _complete(self):
        n = int(self.rng.integers(1, 11) * self.rate)
        status, kinds = self._stream(self._paced(self._config(), n), n / self.rate + CALL_SLACK_S)
        if status == "OK" and (kinds["frame"] != n or kinds["finished"] != 1 or kinds["started"] != 1):
            return status, f"complete: {n} samples, answered {kinds}", set()
        return status, "", EXPECTED["complete"]

    def _disconnect(self):
        n = int(self.rng.integers(1, 6) * self.rate)
        holder, answered = {}, threading.Event()
        delay = float(self.rng.uniform(0.1, n / self.rate))

        def cancel_later():
            if not answered.wait(delay) and "call" in holder:
                holder["call"].cancel()

        canceller = threading.Thread(target=cancel_later, daemon=True)
        canceller.start()
        status, _ = self._stream(
            self._paced(self._config(), 10 * n),
            10 * n / self.rate + CALL_SLACK_S,
            on_call=lambda call: holder.setdefault("call", call),
        )
        answered.set()  # (refused at once: nothing to cancel)
        canceller.join()
        return status, "", EXPECTED["disconnect"]

    def _deadline(self):
        deadline = float(self.rng.uniform(0.3, 3.0))
        status, _ = self._stream(self._paced(self._config(), int(10 * self.rate * deadline) + 30), deadline)
        return status, "", EXPECTED["deadline"]

    def _out_of_order(self):
        k = int(self.rng.integers(2, 60))
        status, _ = self._stream(
            self._paced(self._config(), k, then=[self._sample(0, t=0.5 / self.rate)]), k / self.rate + CALL_SLACK_S
        )
        return status, "", EXPECTED["out_of_order"]

    def _no_config(self):
        gate = threading.Event()

        def nothing():
            gate.wait(self.config_timeout_s + CALL_SLACK_S)
            return
            yield  # a generator that sends nothing

        status, _ = self._stream(nothing(), self.config_timeout_s + CALL_SLACK_S)
        gate.set()
        return status, "", EXPECTED["no_config"]

    def _unary(self):
        import grpc

        pb = self.pb
        try:
            if self.rng.random() < 0.5:
                self.conn.stub.ListGraphs(pb.ListGraphsRequest(), timeout=CALL_SLACK_S, metadata=self.conn.metadata)
            else:
                self.conn.stub.GetGraph(
                    pb.GetGraphRequest(name="no-such-graph"), timeout=CALL_SLACK_S, metadata=self.conn.metadata
                )
            return "OK", "", EXPECTED["unary"]
        except grpc.RpcError as exc:
            return exc.code().name, "", EXPECTED["unary"]

    def _malformed(self):
        import grpc

        pb = self.pb
        kind = str(self.rng.choice(MALFORMED))
        if kind == "garbage":
            raw = self.conn.channel.stream_stream(STREAM_METHOD, request_serializer=None, response_deserializer=None)
            try:
                list(
                    raw(
                        iter([bytes(self.rng.integers(0, 256, 64, dtype=np.uint8))]),
                        timeout=CALL_SLACK_S,
                        metadata=self.conn.metadata,
                    )
                )
                return "OK", "garbage answered OK", GARBAGE_EXPECTED
            except grpc.RpcError as exc:
                return exc.code().name, "", GARBAGE_EXPECTED
        bad_sample = pb.StreamSynthesizeRequest(sample=pb.SensorSample(time_s=0.0, accelerations_m_s2=[1.0] * 5))
        requests = {
            "sample_first": [self._sample(0)],
            "second_config": [self._config(), self._sample(0), self._config()],
            "empty_message": [self._config(), pb.StreamSynthesizeRequest()],
            "wrong_length": [self._config(), bad_sample],
            "nan_time": [self._config(), self._sample(0, t=math.nan)],
            "unknown_graph": [pb.StreamSynthesizeRequest(config=pb.StreamConfig(graph="no-such-graph"))],
            "bad_option": [self._config(latency_s=-1.0)],
        }[kind]
        gate = threading.Event()

        def then_hold():  # the bad message, then stay open until answered
            yield from requests
            gate.wait(CALL_SLACK_S)

        status, _ = self._stream(then_hold(), CALL_SLACK_S)
        gate.set()
        return status, "", EXPECTED["malformed"]


def _client_process(address, graph_path, ids, end_at, config_timeout_s, seed, results) -> None:
    """Run one client per id in threads until end_at; put one summary dict."""
    from graphsvc.graph.file import load_graph
    from graphsvc.service import client as C

    rate = float(load_graph(graph_path).rate_hz)
    conn = C.connect(address)
    lock = threading.Lock()
    calls: dict = {}
    unexpected: list = []
    rejected_ms: list = []

    def tally(scenario, status, elapsed_ms, expected, detail):
        with lock:
            calls.setdefault(scenario, {}).setdefault(status, 0)
            calls[scenario][status] += 1
            if status == "RESOURCE_EXHAUSTED" and scenario != "unary":
                rejected_ms.append(round(elapsed_ms, 1))
            elif status not in expected or detail:
                unexpected.append(f"{scenario}: {status} {detail}".strip())

    clients = [
        _Client(
            conn,
            "bench",
            random_walk_readings(graph_path, 300, seed * 1000 + i),
            rate,
            config_timeout_s,
            seed * 1000 + i,
            tally,
        )
        for i in ids
    ]

    def run(client):
        while time.time() < end_at:
            client.run_one()

    threads = [threading.Thread(target=run, args=(c,)) for c in clients]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    conn.close()
    results.put({"calls": calls, "unexpected": unexpected, "rejected_ms": rejected_ms})


# ---------------------------------------------------------------- the server's side


class _Monitor(threading.Thread):
    """Health every second; RSS and threads every `every_s` seconds."""

    def __init__(self, address: str, pid: int, every_s: float):
        super().__init__(daemon=True)
        self.address, self.pid, self.every_s = address, pid, every_s
        self.done = threading.Event()
        self.t0 = time.monotonic()
        self.health = {"SERVING": 0, "other": 0, "failed": 0, "slowest_ms": 0.0}
        self.rss: list = []
        self.threads: list = []

    def run(self) -> None:
        import grpc
        from grpc_health.v1 import health_pb2, health_pb2_grpc

        channel = grpc.insecure_channel(self.address)
        stub = health_pb2_grpc.HealthStub(channel)
        next_sample = 0.0
        while not self.done.wait(1.0):
            t = time.monotonic() - self.t0
            start = time.monotonic()
            try:
                answer = stub.Check(health_pb2.HealthCheckRequest(), timeout=2.0)
                self.health["SERVING" if answer.status == health_pb2.HealthCheckResponse.SERVING else "other"] += 1
            except grpc.RpcError:
                self.health["failed"] += 1
            self.health["slowest_ms"] = max(self.health["slowest_ms"], round(1e3 * (time.monotonic() - start), 1))
            if t >= next_sample:
                self.rss.append((round(t, 1), round(rss_mb(self.pid), 1)))
                self.threads.append((round(t, 1), thread_count(self.pid)))
                next_sample = t + self.every_s
        channel.close()


def rss_growth(samples: list, warmup_s: float) -> dict:
    """After the warm-up: the medians of the first and the last quarter of the RSS
    samples, and their ratio − 1."""
    after = [mb for t, mb in samples if t >= warmup_s]
    if len(after) < 4:
        return {"first_mb": None, "last_mb": None, "growth": None}
    q = max(1, len(after) // 4)
    first, last = float(np.median(after[:q])), float(np.median(after[-q:]))
    return {"first_mb": round(first, 1), "last_mb": round(last, 1), "growth": round(last / first - 1.0, 4)}


def slots_probe(address: str, n: int, timeout_s: float = 30.0) -> int:
    """Open n streams at once; how many started (all must when no slot leaked). All
    are closed again."""
    import grpc

    from graphsvc.service import client as C

    conn = C.connect(address)
    feeds, calls, started = [], [], 0
    try:
        for _ in range(n):
            feed = C.SampleFeed(C.stream_config("bench"))
            feeds.append(feed)
            calls.append(conn.stub.StreamSynthesize(iter(feed), timeout=timeout_s, metadata=conn.metadata))
        for call in calls:
            try:
                started += next(iter(call)).WhichOneof("message") == "started"
            except (grpc.RpcError, StopIteration):
                pass
    finally:
        for feed in feeds:
            feed.close()
        for call in calls:
            try:
                for _ in call:
                    pass
            except grpc.RpcError:
                pass
        conn.close()
    return started


def soak(
    graph_path: str,
    seconds: float,
    streams: int,
    processes: int,
    max_streams: int,
    config_timeout_s: float,
    every_s: float,
    seed: int,
) -> dict:
    proc, address = start_server(graph_path, max_streams, "--config-timeout-s", f"{config_timeout_s:g}")
    from graphsvc.service.server import UNARY_WORKERS

    try:
        threads_start = thread_count(proc.pid)
        monitor = _Monitor(address, proc.pid, every_s)
        monitor.start()
        ctx = mp.get_context("spawn")
        results = ctx.Queue()
        end_at = time.time() + seconds
        ids = list(range(streams))
        per = math.ceil(streams / max(1, processes))
        workers = [
            ctx.Process(
                target=_client_process,
                args=(address, graph_path, ids[i : i + per], end_at, config_timeout_s, seed, results),
            )
            for i in range(0, streams, per)
        ]
        for w in workers:
            w.start()
        summaries, hard_stop = [], end_at + 2 * CALL_SLACK_S + config_timeout_s
        while len(summaries) < len(workers) and time.time() < hard_stop:
            try:
                summaries.append(results.get(timeout=1.0))
            except queue.Empty:
                if not any(w.is_alive() for w in workers) and results.empty():
                    break
        for w in workers:
            w.join(timeout=5)
            if w.is_alive():  # past the hard stop: a call outlived every deadline
                w.kill()
        time.sleep(1.0)  # cancelled calls' callbacks run
        probe = slots_probe(address, max_streams)
        time.sleep(1.0)
        monitor.done.set()
        monitor.join()
        threads_end = thread_count(proc.pid)
        rss_end = rss_mb(proc.pid)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            exit_code = proc.wait(timeout=30)
        except Exception:  # noqa: BLE001 — subprocess.TimeoutExpired: it hung on shutdown
            proc.kill()
            exit_code = None

    calls: dict = {}
    unexpected: list = []
    for s in summaries:
        for scenario, by_status in s["calls"].items():
            for status, count in by_status.items():
                calls.setdefault(scenario, {}).setdefault(status, 0)
                calls[scenario][status] += count
        unexpected += s["unexpected"]
    rejected = np.array([ms for s in summaries for ms in s["rejected_ms"]], float)
    rejected_ms_max = float(rejected.max()) if rejected.size else 0.0
    rejected_ms = {
        q: round(float(np.percentile(rejected, p)), 1) if rejected.size else None for q, p in (("p50", 50), ("p99", 99))
    }
    threads_bound = (threads_start or 0) + max_streams + UNARY_WORKERS + THREAD_SLACK
    threads_max = max((n for _, n in monitor.threads if n is not None), default=None)
    growth = rss_growth(monitor.rss, warmup_s=seconds / 5)
    checks = {
        "clients_finished": len(summaries) == len(workers),
        "no_unexpected_answer": not unexpected,
        "rejections_at_once": rejected_ms_max < 1000.0,
        "health_serving_throughout": monitor.health["other"] == 0 and monitor.health["failed"] == 0,
        "rss_flat": growth["growth"] is None or growth["growth"] <= 0.10,
        "threads_bounded": threads_end is not None and threads_end <= threads_bound,
        "no_slot_leaked": probe == max_streams,
        "server_exit_0": exit_code == 0,
    }
    return {
        "seconds": seconds,
        "streams": streams,
        "max_streams": max_streams,
        "config_timeout_s": config_timeout_s,
        "calls": calls,
        "calls_total": sum(sum(v.values()) for v in calls.values()),
        "unexpected": {"count": len(unexpected), "first": unexpected[:10]},
        "rejected_ms": {**rejected_ms, "max": round(rejected_ms_max, 1)},
        "health": monitor.health,
        "rss_mb": {"samples": monitor.rss, **growth, "end": round(rss_end, 1)},
        "threads": {"start": threads_start, "max": threads_max, "end": threads_end, "bound": threads_bound},
        "slots_probe": {"started": probe, "of": max_streams},
        "server_exit": exit_code,
        "checks": checks,
        "ok": all(checks.values()),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("graph", metavar="GRAPH_FILE")
    parser.add_argument("--seconds", type=float, default=600.0, help="how long the clients make calls (default 600)")
    parser.add_argument("--streams", type=int, default=64, help="concurrent clients (default 64)")
    parser.add_argument("--processes", type=int, default=4, help="client processes (default 4)")
    parser.add_argument("--max-streams", type=int, default=16, help="the server's --max-streams (default 16, as serve)")
    parser.add_argument(
        "--config-timeout-s", type=float, default=2.0, help="the server's --config-timeout-s (default 2)"
    )
    parser.add_argument("--sample-every", type=float, default=5.0, help="RSS and thread samples, s (default 5)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if not (0 < args.seconds <= 24 * 3600 and 1 <= args.streams <= 1024 and 1 <= args.max_streams):
        raise SystemExit("--seconds must be in (0, 86400], --streams in 1–1024, --max-streams ≥ 1")
    result = soak(
        str(Path(args.graph).resolve()),
        args.seconds,
        args.streams,
        args.processes,
        args.max_streams,
        args.config_timeout_s,
        args.sample_every,
        args.seed,
    )
    print(json.dumps(result), flush=True)
    return 0 if result["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())

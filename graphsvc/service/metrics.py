"""Prometheus metrics of a server (`graphsvc serve --metrics-port P`), with the
`prometheus_client` library: an HTTP endpoint `/metrics` in the text format, beside
the gRPC port.

Live streams: `graphsvc_streams_open`, `graphsvc_streams_started_total`,
`graphsvc_samples_total`, `graphsvc_frames_total`; per sample, histograms of the push
into its session (`graphsvc_push_seconds`) and of its arrival to its frames handed to
gRPC (`graphsvc_sample_seconds`); `graphsvc_refusals_total{code}` (every call ended with
an error status, whoever ended it: `StatusCounter`); `graphsvc_live_worker_restarts_total`;
per process (the front, each live worker) `graphsvc_process_cpu_seconds_total` and
`graphsvc_process_resident_bytes`; `graphsvc_graph_load_seconds{graph}`,
`graphsvc_start_seconds`. What each means: docs/service.md, Metrics.

The endpoint's own `python_*`/`process_*` metrics are prometheus_client's defaults for
the scraping process, left out here: `graphsvc_process_*` cover every process of the
server. The per-process figures are read at scrape time (psutil), nothing polls
between scrapes.
"""

from __future__ import annotations

import os

import grpc

from graphsvc.errors import InputError

LATENCY_BUCKETS_S = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)


class Metrics:
    """The server's metrics in their own registry (several servers in one process, as
    the tests run them, do not mix). `attach(servicer, live_workers)` names what the
    gauges read at scrape time; `serve(host, port)` starts the HTTP endpoint."""

    def __init__(self):
        from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

        self.registry = CollectorRegistry()
        r = self.registry
        self.streams_started = Counter("graphsvc_streams_started", "live streams that started", registry=r)
        self.samples = Counter("graphsvc_samples", "samples received on live streams", registry=r)
        self.frames = Counter("graphsvc_frames", "pose frames sent on live streams", registry=r)
        self.push_seconds = Histogram(
            "graphsvc_push_seconds",
            "a sample's push into its live session, seconds",
            buckets=LATENCY_BUCKETS_S,
            registry=r,
        )
        self.sample_seconds = Histogram(
            "graphsvc_sample_seconds",
            "a sample's arrival to its frames handed to gRPC, seconds",
            buckets=LATENCY_BUCKETS_S,
            registry=r,
        )
        self.refusals = Counter("graphsvc_refusals", "calls ended with an error status, by code", ["code"], registry=r)
        self.graph_load_seconds = Gauge(
            "graphsvc_graph_load_seconds", "loading a graph, seconds", ["graph"], registry=r
        )
        self.start_seconds = Gauge("graphsvc_start_seconds", "port bound → taking calls, seconds", registry=r)
        self.servicer = None
        self.live_workers = None
        self.httpd = None
        self.port: int | None = None
        r.register(_ScrapeTime(self))

    def attach(self, servicer, live_workers=None) -> None:
        self.servicer = servicer
        self.live_workers = live_workers

    def serve(self, host: str, port: int) -> int:
        """Start the HTTP endpoint on host:port (port 0: any free one); the port.
        InputError, one line, for a port out of range or one that cannot be bound."""
        from prometheus_client import start_http_server

        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
            raise InputError(f"--metrics-port must be 0–65535, got {port}")
        addr = host[1:-1] if host.startswith("[") and host.endswith("]") else host
        try:
            self.httpd, _ = start_http_server(port, addr=addr or "0.0.0.0", registry=self.registry)
        except OSError as exc:
            raise InputError(f"cannot serve metrics on {host}:{port}: {exc.strerror or exc}") from None
        self.port = int(self.httpd.server_port)
        return self.port

    def close(self) -> None:
        if self.httpd is not None:
            self.httpd.shutdown()
            self.httpd.server_close()
            self.httpd = None

    def refused(self, code) -> None:
        self.refusals.labels(code.name if isinstance(code, grpc.StatusCode) else str(code)).inc()


class _ScrapeTime:
    """What is read when scraped: streams open, worker restarts, each process's CPU
    and memory."""

    def __init__(self, metrics: Metrics):
        self.metrics = metrics

    def describe(self):
        return []  # (nothing to check at registration: the values exist only at scrape time)

    def collect(self):
        import psutil
        from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

        m = self.metrics
        slots = m.servicer.slots.active if m.servicer is not None else 0
        yield GaugeMetricFamily("graphsvc_streams_open", "live streams holding a slot", value=slots)
        restarts = m.live_workers.replaced if m.live_workers is not None else 0
        yield CounterMetricFamily(
            "graphsvc_live_worker_restarts", "live workers that died and were started again", value=restarts
        )
        cpu = CounterMetricFamily(
            "graphsvc_process_cpu_seconds",
            "CPU time of the server's processes, seconds",
            labels=["role", "worker", "pid"],
        )
        rss = GaugeMetricFamily(
            "graphsvc_process_resident_bytes",
            "resident memory of the server's processes",
            labels=["role", "worker", "pid"],
        )
        processes = [("front", "", os.getpid())]
        if m.live_workers is not None:
            processes += [("worker", str(index), pid) for index, pid in m.live_workers.processes()]
        for role, worker, pid in processes:
            try:
                p = psutil.Process(pid)
                times, memory = p.cpu_times(), p.memory_info()
            except psutil.Error:  # (a worker that died since: gone from this scrape)
                continue
            labels = [role, worker, str(pid)]
            cpu.add_metric(labels, times.user + times.system)
            rss.add_metric(labels, memory.rss)
        yield cpu
        yield rss


class StatusCounter(grpc.ServerInterceptor):
    """Counts every call the server ends with an error status, by code, whoever ends
    it (a handler, the call gate while loading or draining, the token check): the
    outermost interceptor, it reads the call's code when its handler returns."""

    def __init__(self, metrics: Metrics):
        self.metrics = metrics

    def _count(self, context) -> None:
        code = context.code()
        if code is not None and code != grpc.StatusCode.OK:
            self.metrics.refused(code)

    def intercept_service(self, continuation, handler_call_details):
        handler = continuation(handler_call_details)
        if handler is None:
            return None
        kind = (
            ("stream" if handler.request_streaming else "unary")
            + "_"
            + ("stream" if handler.response_streaming else "unary")
        )
        behavior = getattr(handler, kind)
        if handler.response_streaming:

            def run(request_or_iterator, context):
                try:
                    yield from behavior(request_or_iterator, context)
                finally:
                    self._count(context)
        else:

            def run(request_or_iterator, context):
                try:
                    return behavior(request_or_iterator, context)
                finally:
                    self._count(context)

        return handler._replace(**{kind: run})

"""`graphsvc serve`: graphs over gRPC (graphsvc.v1)."""

from __future__ import annotations

from pathlib import Path

from graphsvc.cli.args import command, print_flushed
from graphsvc.errors import GraphsvcError
from graphsvc.flags import COUNT, PATH, ranged


def _cmd_serve(args) -> int:
    from graphsvc.service.graphs import load_graphs, parse_graph_spec
    from graphsvc.service.interceptors import read_tokens
    from graphsvc.service.live_workers import LiveWorkers, default_count
    from graphsvc.service.server import ServerConfig, bind_server, serve

    tokens = read_tokens(args.token_file) if args.token_file else ()
    config = ServerConfig(
        host=args.host,
        port=args.port,
        tls_cert=args.tls_cert and Path(args.tls_cert),
        tls_key=args.tls_key and Path(args.tls_key),
        tokens=tokens,
        max_streams=args.max_streams,
        max_message_mb=args.max_message_mb,
        grace_s=args.grace_s,
        config_timeout_s=args.config_timeout_s,
        batch_dir=args.batch_dir and Path(args.batch_dir),
        batch_scheduler=args.batch_scheduler,
        batch_workers=args.batch_workers,
        metrics_port=args.metrics_port,
        live_workers=default_count() if args.live_workers is None else args.live_workers,
    )
    if config.batch_dir is None and (args.batch_scheduler or args.batch_workers):
        raise GraphsvcError("--batch-scheduler and --batch-workers need --batch-dir")
    if (config.tls_cert is None) != (config.tls_key is None):
        raise GraphsvcError("TLS needs both --tls-cert and --tls-key")
    # A taken port or a bad address fails here, before the graphs load; from here on
    # health checks are answered (NOT_SERVING until `serve` has the graphs served).
    bound = bind_server(config)
    workers = None
    try:
        if config.live_workers:  # (they load the graphs while this process does)
            workers = LiveWorkers(dict(parse_graph_spec(spec) for spec in args.graph), config.live_workers)
            workers.launch()
        graphs = load_graphs(args.graph)
    except BaseException:
        bound.close()
        if workers is not None:
            workers.stop()
        raise
    return serve(graphs, config, announce=print_flushed, bound=bound, live_workers=workers)


def add_serve(sub) -> None:
    p = command(
        sub,
        "serve",
        "serve graphs over gRPC (graphsvc.v1)",
        "Serve graphs over gRPC (graphsvc.v1): live streams, batch synthesis, graph info, health and "
        "reflection. The port is bound first (health answers NOT_SERVING while the graphs load), then SERVING "
        "until SIGTERM or Ctrl-C, which drains the calls under way (see docs/service.md).",
    )
    p.add_argument(
        "--graph",
        action="append",
        required=True,
        metavar="NAME=FILE",
        help="a graph to serve under NAME (repeatable; at least one)",
    )
    p.add_argument("--host", default="[::]", help="address to bind (default [::]: all interfaces)")
    p.add_argument("--port", type=int, default=50051, help="TCP port (default 50051; 0: any free port)")
    p.add_argument(
        "--tls-cert",
        metavar="F",
        type=PATH,
        help="PEM certificate chain: serve TLS (with --tls-key; default: plaintext)",
    )
    p.add_argument("--tls-key", metavar="F", type=PATH, help="PEM private key of --tls-cert (default: none, plaintext)")
    p.add_argument(
        "--token-file",
        metavar="F",
        type=PATH,
        help="accepted bearer tokens, one per line: require one (default: no authentication)",
    )
    p.add_argument(
        "--max-streams",
        type=COUNT,
        default=16,
        metavar="N",
        help="concurrent live streams; more get RESOURCE_EXHAUSTED (default 16)",
    )
    p.add_argument(
        "--max-message-mb",
        type=ranged(float, 0.0, 2047.0, low_open=True),
        default=64.0,
        metavar="M",
        help="largest message either way, MiB (default 64)",
    )
    p.add_argument(
        "--grace-s",
        type=ranged(float, 0.0, 3600.0),
        default=10.0,
        metavar="S",
        help="on SIGTERM, time for in-flight calls to finish, health answering NOT_SERVING (default 10)",
    )
    p.add_argument(
        "--config-timeout-s",
        type=float,
        default=10.0,
        metavar="S",
        help="a stream that sends no config within S seconds of connecting ends with DEADLINE_EXCEEDED (default 10)",
    )
    p.add_argument(
        "--live-workers",
        type=ranged(int, 0, 256),
        metavar="N",
        help="run the live streams' sessions in N worker processes, each stream in one (default: one a "
        "core, 0 on a single core; 0: in the server's process)",
    )
    p.add_argument(
        "--metrics-port",
        type=ranged(int, 0, 65535),
        metavar="P",
        help="serve Prometheus metrics at http://HOST:P/metrics (0: any free port, printed; default: none; "
        "docs/service.md, Metrics)",
    )
    p.add_argument(
        "--batch-dir",
        metavar="DIR",
        type=PATH,
        help="take batches (SubmitBatch …): their folders go here, and a "
        "manifest's relative paths are taken from here (default: "
        "take no batches)",
    )
    p.add_argument(
        "--batch-scheduler",
        metavar="ADDRESS",
        help="run batches on this Dask scheduler (default: a local cluster, started at the first batch)",
    )
    p.add_argument("--batch-workers", type=COUNT, metavar="N", help="the local cluster's workers (default: one a core)")
    p.set_defaults(run=_cmd_serve)

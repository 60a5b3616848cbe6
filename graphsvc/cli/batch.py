"""`graphsvc batch`: a manifest of recordings on a local or an existing Dask cluster."""

from __future__ import annotations

import sys
from pathlib import Path

from graphsvc.cli.args import command
from graphsvc.flags import COUNT, PATH


def _cmd_batch(args) -> int:
    from graphsvc.batch.run import format_summary, run_batch
    from graphsvc.service.graphs import parse_graph_spec

    graphs = dict(parse_graph_spec(spec) for spec in args.graph or [])
    summary = run_batch(
        args.manifest,
        args.out,
        graphs=graphs,
        scheduler=args.scheduler,
        workers=args.workers,
        retries=args.retries,
        progress=False if args.quiet else None,
        timeout_s=args.timeout,
    )
    print(format_summary(summary))
    print(f"summary: {Path(args.out) / 'summary.json'}")
    failed = summary["totals"]["failed"]
    if failed:
        print(f"graphsvc: {failed} of {summary['totals']['items']} items failed", file=sys.stderr)
        return 1
    return 0


def add_batch(sub) -> None:
    p = command(
        sub,
        "batch",
        "reconstruct a manifest of recordings on a local or existing Dask cluster",
        "Reconstruct every row of a manifest as `synthesize` would (the same bytes), on a local or an "
        "existing Dask cluster, resumably: a rerun skips what is done.",
    )
    p.add_argument(
        "manifest",
        metavar="MANIFEST",
        type=PATH,
        help="CSV (header row) or JSON: recording, graph, strategy, output, [weights, constraints, "
        "calibration, options]; docs/batch.md",
    )
    p.add_argument("--out", required=True, metavar="DIR", type=PATH, help="outputs, the job store and the summary")
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="an existing Dask scheduler, e.g. tcp://host:8786 (default: $DASK_SCHEDULER_ADDRESS, else a"
        " local cluster)",
    )
    where.add_argument("--workers", type=COUNT, metavar="N", help="local cluster workers (default: one a core)")
    p.add_argument(
        "--retries",
        type=int,
        default=2,
        metavar="R",
        help="further attempts after a failure that is not the input's (a worker died; default 2)",
    )
    p.add_argument(
        "--graph",
        action="append",
        metavar="NAME=PATH",
        help="a graph the manifest names (repeatable; default: the manifest's paths)",
    )
    p.add_argument(
        "--timeout", type=float, default=10.0, metavar="S", help="wait this long for the scheduler (default 10)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=_cmd_batch)

"""What a batch worker runs for one item: the `synthesize` command's own function
(`pipeline.synthesize_files`) on the item's files, into the batch folder.

A task carries paths, the graph's checksum and the item's flags, never arrays. Each
worker process opens a graph memory-mapped once (kept for the process's life, keyed
by path and checksum) and warms a strategy's kernels and index on it once, before
its first item; the search then runs on serial kernels (one thread a worker: the
workers are the parallelism). Threaded and serial kernels give the same path, so an
item's BVH equals `graphsvc synthesize`'s byte for byte.

A user error (a recording that does not fit, options refused) is returned as the
item's reason, not raised: it fails the same way on any worker, so it is not retried.
Anything else raises, and the client may retry it.
"""

from __future__ import annotations

import time
from pathlib import Path

from graphsvc.batch.manifest import parse_item_options
from graphsvc.errors import GraphsvcError, InputError
from graphsvc.evaluate.metrics import motion_plausibility
from graphsvc.fileio import file_sha256
from graphsvc.flags import performer_from_flags
from graphsvc.graph.file import load_graph
from graphsvc.pipeline import synthesize_files, warm_up

_GRAPHS: dict = {}  # (path, checksum) → MotionGraph, memory-mapped
_WARM: set = set()  # (path, checksum, strategy) whose kernels and index are loaded


def worker_graph(path: str, checksum: str):
    """The graph file at `path`, opened once per process; InputError if its contents
    changed since the batch was planned."""
    key = (path, checksum)
    graph = _GRAPHS.get(key)
    if graph is None:
        graph = load_graph(path, mmap=True)
        if graph.checksum != checksum:
            raise InputError(
                f"graph {path} changed since the batch was planned (checksum {graph.checksum[:12]}…, "
                f"planned {checksum[:12]}…)"
            )
        _GRAPHS[key] = graph
    return graph


def warm(graph, key: tuple, strategy: str) -> float:
    """Load `strategy`'s kernels and index for `graph` once per process; the seconds it took (0 after)."""
    if (*key, strategy) in _WARM:
        return 0.0
    seconds = warm_up(graph, threads=False, strategies=[strategy])
    _WARM.add((*key, strategy))
    return seconds


def _seen(motion, mapping) -> dict:
    """The output's jitter and foot skate (`evaluate.metrics.motion_plausibility`), or
    nothing for a skeleton no joint map knows."""
    try:
        return {k: v for k, v in motion_plausibility(motion, mapping).items() if k in ("jitter_km_s3", "skate_cm_s")}
    except GraphsvcError:
        return {}


def run_item(task: dict) -> dict:
    """Reconstruct one planned item (`manifest.plan_item`'s task) into
    out_dir/OUTPUT.bvh (or .glb, .gltf: the task's format) and OUTPUT.json. Returns its
    figures, or {"error": reason} for a user error."""
    t0 = time.perf_counter()
    out_dir = Path(task["out_dir"])
    output = out_dir / f"{task['output']}.{task.get('format', 'bvh')}"
    report_path = out_dir / f"{task['output']}.json"
    try:
        options, args = parse_item_options(task["argv"])
        graph = worker_graph(task["graph"], task["graph_checksum"])
        warm_s = warm(graph, (task["graph"], task["graph_checksum"]), options.strategy)
        performer = performer_from_flags(args, graph.skeleton, graph.params.get("mapping"))
        result = synthesize_files(
            graph,
            task["graph"],
            task["recording"],
            output,
            options,
            report_path=report_path,
            scale=args.scale,
            up=args.up,
            units=args.units,
            device_map=args.device_map,
            calibration=args.calibration,
            threads=False,
            calibrate_from_start=None if args.calibrate_from_start is None else (args.calibrate_from_start, args.pose),
            performer=performer,
        )
    except GraphsvcError as exc:
        return {"error": str(exc)}
    r = result.report
    return {
        "seconds": time.perf_counter() - t0,
        "warm_up_s": warm_s,
        "samples": r["samples"],
        "input_s": r["samples"] / float(graph.rate_hz),
        "samples_per_s": r.get("samples_per_s"),
        "cost": r.get("cost"),
        "terms": r.get("terms", {}),
        "output": str(output),
        "checksum": file_sha256(output),
        # what a viewer sees of the output (no truth here: `graphsvc evaluate` compares)
        **_seen(result.motion, graph.params.get("mapping")),
        "report": str(report_path),
    }

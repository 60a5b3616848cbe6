"""Commands on motion graphs: `build`, `info`, `relayout`."""

from __future__ import annotations

import contextlib
import json
import time
from pathlib import Path

from graphsvc.cli.args import command, file_arg
from graphsvc.fileio import check_outputs
from graphsvc.flags import COUNT, LAYOUT_HELP, PATH, RATE_HZ


def _cmd_build(args) -> int:
    from graphsvc.graph.build import BuildOptions, build_graph, load_knowledge_base
    from graphsvc.graph.connectivity import connectivity, format_connectivity
    from graphsvc.graph.file import save_graph
    from graphsvc.graph.model import format_summary, summary
    from graphsvc.motion.joints import load_mapping_file
    from graphsvc.motion.retarget import load_target_skeleton
    from graphsvc.sensors.layout import load_layout

    out = Path(args.output)
    check_outputs(
        [("-o", out, None)],
        [("a knowledge-base file", k) for k in args.kb]
        + [("the joint map", file_arg(args.mapping)), ("the target skeleton", args.skeleton)],
    )
    progress = False if args.quiet else None
    augment = tuple(a for a in (args.augment or "").split(",") if a)
    mapping = load_mapping_file(args.mapping) if args.mapping and args.mapping != "guess" else None
    target = load_target_skeleton(args.skeleton, mapping or args.mapping) if args.skeleton else None
    options = BuildOptions(
        rate_hz=args.rate,
        layout=load_layout(args.layout),
        msv=not args.no_msv,
        interp=not args.no_interp,
        bridges=not args.no_bridges,
        augment=augment,
        mapping=mapping,
        jobs=args.jobs,
        progress=progress,
    )
    with _clip_map(args) as clip_map:
        t0 = time.perf_counter()
        motions = load_knowledge_base(
            args.kb,
            exclude=args.exclude or [],
            augment=augment,
            jobs=args.jobs,
            progress=progress,
            skeleton=target,
            mapping=mapping or args.mapping,
            clip_map=clip_map,
        )
        load_s = time.perf_counter() - t0
        options = _graph_mapping(options, motions, mapping, args.mapping)
        graph, report = build_graph(motions, options, clip_map=clip_map)
    t0 = time.perf_counter()
    save_graph(graph, out)
    timings = {"load_s": load_s, **report.timings, "write_s": time.perf_counter() - t0}
    print(f"wrote {out}")
    print(format_summary(summary(graph, out.stat().st_size)))
    t0 = time.perf_counter()
    print(format_connectivity(connectivity(graph)))
    timings["connectivity_s"] = time.perf_counter() - t0
    retargeted = sorted({m.retargeted_from for m in motions if m.retargeted_from})
    if retargeted:
        n = sum(1 for m in motions if m.retargeted_from)
        print(f"{n} clips retargeted onto the graph's skeleton from {', '.join(retargeted)}")
    if report.still_clips:
        print(
            f"{len(report.still_clips)} clips without foot-contact changes get transition candidates every "
            f"{options.still_clip_step_s:g} s"
        )
    print(
        "times: "
        + ", ".join(f"{k[:-2]} {v:.2f} s" for k, v in timings.items())
        + f" (total {sum(timings.values()):.2f} s)"
    )
    return 0


def _graph_mapping(options, motions, mapping, flag):
    """The build options with the graph's joint map: a map given for a source retargeted
    onto a built-in family is not the graph's; `--mapping guess` guesses from the
    knowledge base's skeleton (one a graph: its first clip's) and prints the guess."""
    from dataclasses import replace

    from graphsvc.motion.joints import guess_mapping
    from graphsvc.motion.retarget import skeleton_table

    if mapping is not None and any(m.retargeted_from for m in motions):
        options = replace(options, mapping=skeleton_table(motions[0].skeleton, mapping)[1])
    if flag == "guess" and motions:
        guessed, missing = guess_mapping(motions[0].skeleton)
        options = replace(options, mapping=guessed)
        print(f"guessed joint map: {json.dumps(guessed)}" + (f" (missing: {', '.join(missing)})" if missing else ""))
    return options


@contextlib.contextmanager
def _clip_map(args):
    """Where the per-clip stages run: None (the build's threads) without --scheduler or
    --workers, else Dask tasks on that scheduler's cluster or on a local one of N
    workers, closed on the way out."""
    if args.scheduler is None and args.workers is None:
        yield None
        return
    from graphsvc.batch.run import cluster_map, connect

    client, cluster = connect(args.scheduler, args.workers, args.timeout)
    try:
        yield cluster_map(client)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _cmd_info(args) -> int:
    from graphsvc.graph.connectivity import connectivity, format_connectivity
    from graphsvc.graph.file import load_graph
    from graphsvc.graph.model import format_summary, summary

    graph = load_graph(args.graph)
    info = summary(graph, Path(args.graph).stat().st_size)
    info["params"] = graph.params
    info["connectivity"] = connectivity(graph)
    if args.json:
        print(json.dumps(info, indent=2, sort_keys=True))
    else:
        print(format_summary(info))
        print(format_connectivity(info["connectivity"]))
    return 0


def _cmd_relayout(args) -> int:
    from dataclasses import replace

    from graphsvc.graph.file import load_graph, save_graph
    from graphsvc.graph.metadata import edge_up_vectors, recompute_accelerations
    from graphsvc.graph.model import READING_DTYPE
    from graphsvc.sensors.anatomy import ANATOMICAL
    from graphsvc.sensors.layout import load_layout

    out = Path(args.output)
    check_outputs([("-o", out, None)], [("the graph", args.graph), ("the layout file", args.layout)])
    layout = load_layout(args.layout)
    graph = load_graph(args.graph)
    acc = recompute_accelerations(graph, layout)
    params = {**graph.params, "layout": layout.name, "sensor_frames": ANATOMICAL}  # (an older graph's converted)
    save_graph(
        replace(
            graph,
            edge_acc=acc.astype(READING_DTYPE),
            edge_up=edge_up_vectors(graph, layout),
            layout=layout.to_dict(),
            params=params,
        ),
        out,
    )
    print(f"wrote {out}: edge metadata for layout {layout.name} ({', '.join(layout.sensor_names)})")
    return 0


def add_build(sub) -> None:
    p = command(
        sub,
        "build",
        "build a motion graph from a knowledge base",
        "Build the motion graph of a knowledge base of motion clips: transitions at foot contacts, speed "
        "variations, interpolated nodes, bridges between actions, and each edge's sensor readings for a "
        "layout.",
    )
    p.add_argument(
        "kb", nargs="+", metavar="KB", type=PATH, help="motion files, folders or globs (.bvh, .amc, DeepMimic .txt)"
    )
    p.add_argument("-o", "--output", required=True, metavar="GRAPH", type=PATH, help="the graph file to write")
    p.add_argument("--rate", type=RATE_HZ, default=30.0, metavar="HZ", help="graph rate (default 30)")
    p.add_argument(
        "--layout",
        default="wrists-ankles",
        metavar="LAYOUT",
        help=f"sensor layout of the edge metadata: {LAYOUT_HELP} (default wrists-ankles)",
    )
    p.add_argument("--no-msv", action="store_true", help="no slow-down nodes or speed-up edges")
    p.add_argument("--no-interp", action="store_true", help="no interpolation nodes")
    p.add_argument("--no-bridges", action="store_true", help="no bridges between actions (blended transitions)")
    p.add_argument("--exclude", action="append", metavar="GLOB", help="leave out matching files (repeatable)")
    p.add_argument("--augment", metavar="KINDS", help="add copies: mirror, reverse (comma-separated; default none)")
    p.add_argument(
        "--mapping",
        metavar="FILE|guess",
        type=PATH,
        help="joint map JSON for skeletons graphsvc does not know, or 'guess' (`graphsvc mapping`)",
    )
    p.add_argument(
        "--skeleton",
        metavar="FILE",
        type=PATH,
        help="a .bvh/.amc whose skeleton every clip is retargeted onto (default: the first source's; "
        "clips of other skeletons are retargeted onto it)",
    )
    p.add_argument(
        "--jobs", type=COUNT, default=1, metavar="N", help="threads for loading and preparing clips (default 1)"
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="load and prepare clips as tasks on an existing Dask scheduler, e.g. tcp://host:8786 "
        "(the same graph as a local build)",
    )
    where.add_argument(
        "--workers", type=COUNT, metavar="N", help="load and prepare clips on a local Dask cluster of N workers"
    )
    p.add_argument(
        "--timeout", type=float, default=10.0, metavar="S", help="wait this long for the --scheduler (default 10)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=_cmd_build)


def add_info(sub) -> None:
    p = command(
        sub,
        "info",
        "describe a graph file",
        "Describe a graph file: nodes and edges by kind, labels, layout, build parameters, connectivity.",
    )
    p.add_argument("graph", metavar="GRAPH", type=PATH, help="a graph file (`graphsvc build`)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a summary")
    p.set_defaults(run=_cmd_info)


def add_relayout(sub) -> None:
    p = command(
        sub,
        "relayout",
        "recompute a graph's sensor metadata for another layout",
        "Recompute a graph's per-edge sensor readings for another layout (or an older graph's for today's "
        "sensor frames), without the knowledge base.",
    )
    p.add_argument("graph", metavar="GRAPH", type=PATH, help="the graph file to read")
    p.add_argument("--layout", required=True, metavar="LAYOUT", help=LAYOUT_HELP)
    p.add_argument(
        "-o", "--output", required=True, metavar="OUT", type=PATH, help="the graph file to write (not the input)"
    )
    p.set_defaults(run=_cmd_relayout)

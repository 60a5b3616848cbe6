"""Evaluation commands: `evaluate` (`graphsvc.evaluate.run`) and `report`."""

from __future__ import annotations

from pathlib import Path

from graphsvc.cli.args import command, file_arg, print_note, print_notes
from graphsvc.fileio import check_outputs
from graphsvc.flags import (
    COUNT,
    LAYOUT_HELP,
    PATH,
    SEED,
    add_performer_flags,
    add_pose_flag,
    add_search_flags,
    options_from_flags,
    ranged,
)


def _cmd_evaluate(args) -> int:
    from graphsvc.evaluate.run import EvalConfig, run, summary_lines
    from graphsvc.strategies import check_options

    if args.pose is not None and args.calibrate_from_start is None:
        from graphsvc.errors import InputError

        raise InputError("--pose goes with --calibrate-from-start S")
    options, notes = options_from_flags(args)
    options = check_options(options)
    print_notes(notes)
    config = EvalConfig(
        kb=tuple(args.kb),
        test=args.test,
        graph=args.graph,
        layout=args.layout,
        augment=args.augment,
        noise=args.noise,
        position_noise=args.position_noise,
        options=options,
        seed=args.seed,
        jobs=args.jobs,
        mixed=args.mixed,
        hold_out=args.hold_out,
        actors=args.actors,
        mapping=args.mapping,
        flicker=args.flicker,
        gap_fraction=args.gap_fraction,
        json=args.json,
        keep_motions=args.keep_motions,
        report_html=args.report_html,
        pose_oracle=args.pose_oracle,
        calibrate_from_start=args.calibrate_from_start,
        calibration_pose=args.pose or "npose",
        performer=args.performer,
        height=args.height,
        performer_mapping=args.performer_mapping,
        progress=False if args.quiet else None,
    )
    summary = run(config, note=print_note, write_page=_write_page)
    for line in summary_lines(summary, config):
        print(line)
    return 0


def _write_page(path, summary: dict, folder: Path) -> None:
    """The page of an evaluation whose clips are kept in `folder`."""
    from graphsvc.report.html import write_html
    from graphsvc.report.load import evaluation_document

    write_html(path, evaluation_document(summary, folder))


def _cmd_report(args) -> int:
    from graphsvc.report.html import write_html
    from graphsvc.report.load import load_document

    out = Path(args.output)
    check_outputs(
        [("-o", out, (".html", ".htm"))],
        [("the result", args.result), ("the truth", args.truth), ("the joint map", file_arg(args.mapping))],
    )
    notes = []
    doc = load_document(args.result, truth=args.truth, truth_mapping=args.mapping, notes=notes)
    write_html(out, doc)
    print_notes(notes)
    print(
        f"wrote {out}: {len(doc['clips'])} clip{'s' if len(doc['clips']) != 1 else ''}, "
        f"{out.stat().st_size / 1e6:.1f} MB"
    )
    return 0


def add_evaluate(sub) -> None:
    p = command(
        sub,
        "evaluate",
        "leave-one-out evaluation on a knowledge base",
        "Evaluate a strategy on a knowledge base: each test clip's sensors are simulated and reconstructed on "
        "a graph that hides its takes (or its clip, actor or action), and scored against it; or joined "
        "performances of several clips (--mixed). Metrics: docs/evaluation.md.",
    )
    p.add_argument(
        "kb",
        nargs="+",
        metavar="KB",
        type=PATH,
        help="knowledge-base files, folders or globs (.bvh, .amc, DeepMimic .txt)",
    )
    p.add_argument(
        "--test",
        required=True,
        metavar="GLOB",
        help="test the KB files whose name matches, e.g. '*_00[14].bvh' (several: comma-separated)",
    )
    p.add_argument(
        "--layout",
        metavar="LAYOUT",
        help=f"sensor layout: {LAYOUT_HELP} (default wrists-ankles, or the graph's with --graph)",
    )
    p.add_argument(
        "--graph",
        metavar="GRAPH",
        type=PATH,
        help="a graph built from the same KB, instead of building one (default: build)",
    )
    p.add_argument(
        "--augment", metavar="KINDS", help="build with copies: mirror, reverse (held out with their clip; default none)"
    )
    p.add_argument(
        "--noise",
        default="default",
        metavar="NOISE",
        help="PRESET[,key=value...] (default: the 'default' preset, docs/sensors.md)",
    )
    p.add_argument(
        "--position-noise",
        type=ranged(float, 0.0, 1e3),
        metavar="M",
        help="keep the overhead tracker's positions with this σ in metres (0: exact; default: the noise "
        "preset's tracker, when it has one)",
    )
    add_search_flags(p, constraints=False)
    p.add_argument(
        "--flicker",
        type=float,
        metavar="P",
        help="a strategy reading optical markers: each simulated marker unseen this share of samples, in short "
        "dropouts (default 0)",
    )
    p.add_argument(
        "--gap-fraction",
        type=float,
        metavar="F",
        help="a strategy reading optical markers: random gaps of 5–80 samples (every marker unseen) until this "
        "share of samples (default 0)",
    )
    p.add_argument(
        "--seed", type=SEED, default=0, help="noise seed (each clip's is derived from it and its name; default 0)"
    )
    p.add_argument(
        "--jobs",
        type=COUNT,
        default=1,
        metavar="N",
        help="evaluate N clips at once in worker processes (and build with N threads; default 1)",
    )
    p.add_argument(
        "--mixed",
        type=int,
        metavar="N",
        help="score performances of N test clips with N different labels joined end to end (one performer "
        "each; their clips hidden together) instead of each clip alone",
    )
    p.add_argument(
        "--hold-out",
        default="takes",
        choices=("clip", "takes", "actor", "content"),
        help="what a test clip hides from the graph: its performance (clip), every take of its content × "
        "style (takes, the default), every clip of its performer (actor) or of its content label "
        "(content); docs/evaluation.md",
    )
    p.add_argument(
        "--actors",
        metavar="FILE",
        type=PATH,
        help="actor map for --hold-out actor: JSON {clip name or glob: actor} (default: from the clips' "
        "names, where they say)",
    )
    p.add_argument(
        "--mapping",
        metavar="FILE|guess",
        type=PATH,
        help="the test clips' joint map when their skeleton is not the graph's (JSON, or 'guess')",
    )
    p.add_argument("--json", metavar="OUT.json", type=PATH, help="write per-clip and mean metrics as JSON")
    p.add_argument(
        "--keep-motions",
        metavar="DIR",
        type=PATH,
        help="keep each clip's reconstruction, truth, input and timeline here (for `graphsvc report`)",
    )
    p.add_argument(
        "--report-html", metavar="OUT.html", type=PATH, help="write the HTML report: metrics table and 3D viewer"
    )
    p.add_argument(
        "--pose-oracle",
        action="store_true",
        help="also score the pose-oracle floor: per frame the usable graph pose closest to the truth"
        " (oracle_joint_err_cm), the bound any strategy that retrieves poses faces",
    )
    p.add_argument(
        "--calibrate-from-start",
        type=ranged(float, 0.0, 3600.0, low_open=True),
        metavar="S",
        help="devices worn as in the field: put 2 s of --pose before each test clip, calibrate the "
        "devices' mountings (noise mount=D) from the recording's first S seconds, the pose and the "
        "motion after it, without the hidden clips, and score the clip's part (S ≥ 4; default: none)",
    )
    add_pose_flag(p, what="with --calibrate-from-start: the pose put before each test clip (default npose)")
    add_performer_flags(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=_cmd_evaluate)


def add_report(sub) -> None:
    p = command(
        sub,
        "report",
        "a self-contained HTML page of a result",
        "Write one self-contained HTML page of a result: a 3D viewer of the reconstruction (beside the truth), "
        "time-aligned errors, sensor readings, source clips and constraints.",
    )
    p.add_argument(
        "result",
        metavar="RESULT",
        type=PATH,
        help="a `synthesize --report` JSON, an `evaluate --json` output with --keep-motions, or a batch folder",
    )
    p.add_argument("-o", "--output", required=True, metavar="OUT.html", type=PATH, help="the page to write (.html)")
    p.add_argument(
        "--truth",
        metavar="MOTION",
        type=PATH,
        help="the true motion (.bvh, .amc, DeepMimic .txt) of a synthesize report, shown beside it (default: none)",
    )
    p.add_argument(
        "--mapping",
        metavar="FILE|guess",
        type=PATH,
        help="joint map JSON of the --truth skeleton when graphsvc does not know it, or 'guess' (`graphsvc "
        "mapping`); without one its error charts are left out, with a note (default: a built-in map)",
    )
    p.set_defaults(run=_cmd_report)

"""An evaluation run as one call: what `graphsvc evaluate` and tools/accuracy.py do.

`run(EvalConfig(...))` checks every argument before the long work starts (one
InputError naming the flag of `graphsvc evaluate` that was wrong), builds the graph of
the knowledge base or loads one, picks the test clips, works out what each hides
(`protocols.hide_lists`), evaluates them (`loo.run_leave_one_out`), writes the files
asked for (the JSON, kept motions, the HTML page) and returns the summary: the
dictionary `--json` writes. `summary_lines` formats what the command prints of it.

The HTML page belongs to `graphsvc.report`, a layer above this one: the caller that
asks for a page passes the function that writes it (`write_page`).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

from graphsvc.errors import InputError, SkeletonError
from graphsvc.evaluate import loo, protocols
from graphsvc.evaluate.mixed import mixed_items
from graphsvc.evaluate.report import format_table
from graphsvc.fileio import check_outputs, write_text_atomic
from graphsvc.graph.build import BuildOptions, build_graph, load_knowledge_base
from graphsvc.graph.file import load_graph
from graphsvc.motion.joints import joint_map, load_mapping_file
from graphsvc.motion.library import find_motion_files, load_motion
from graphsvc.motion.proportions import (
    check_height,
    complete_lengths,
    lengths_for_height,
    performer_segments,
    segment_lengths,
    skeleton_height,
)
from graphsvc.sensors.layout import load_layout
from graphsvc.sensors.noise import parse_noise
from graphsvc.sensors.simulate import MarkerPattern, check_pattern
from graphsvc.strategies import check_options, get
from graphsvc.strategies.options import Options, values_of

# (path, summary with each clip's kept files, the folder they are in) → the page written
PageWriter = Callable[[str, dict, Path], None]


@dataclass(frozen=True)
class EvalConfig:
    """What to evaluate, as `graphsvc evaluate`'s flags say it (the same names and
    defaults).

    kb: knowledge-base files, folders or globs. test: the test files' name pattern(s),
    comma-separated. graph: a graph built from the same knowledge base (None: build
    one, with `layout` — default wrists-ankles — and `augment`, comma-separated kinds).
    noise: a noise spec (`sensors.noise.parse_noise`); position_noise: the tracker's σ
    in metres, which keeps the positions. options: the reconstruction's (checked here).
    seed: the noise seed. jobs: clips evaluated at once (and build threads). mixed: join
    this many test clips a performance. hold_out: clip, takes, actor or content;
    actors: the actor map file. mapping: the test clips' joint map (a file or 'guess').
    flicker, gap_fraction: how simulated optical markers are lost. json: the summary's
    file; keep_motions: a folder for each clip's files; report_html: the page (with the
    `write_page` of `run`). pose_oracle: score the pose-oracle floor too
    (`evaluate.oracle`: `oracle_joint_err_cm` per clip and in the mean).
    calibrate_from_start, calibration_pose: put 2 s of the pose before each test clip
    and calibrate the devices from the recording's first this many seconds, the pose and
    the motion after it (`loo.calibrated_test_input`; None: no calibration). performer,
    height: every reconstruction put on a performer's proportions before it is scored (a
    performer file, or a height in metres: `motion.proportions`; performer_mapping: the
    joint map of a performer motion file). progress: progress bars (None: on a terminal;
    False: none)."""

    kb: tuple[str, ...]
    test: str
    graph: str | None = None
    layout: str | None = None
    augment: str | None = None
    noise: str = "default"
    position_noise: float | None = None
    options: Options = field(default_factory=Options)
    seed: int = 0
    jobs: int = 1
    mixed: int | None = None
    hold_out: str = "takes"
    actors: str | None = None
    mapping: str | None = None
    flicker: float | None = None
    gap_fraction: float | None = None
    json: str | None = None
    keep_motions: str | None = None
    report_html: str | None = None
    pose_oracle: bool = False
    calibrate_from_start: float | None = None
    calibration_pose: str = "npose"
    performer: str | None = None
    height: float | None = None
    performer_mapping: str | None = None
    progress: bool | None = None


def run(config: EvalConfig, note: Callable[[str], None] | None = None, write_page: PageWriter | None = None) -> dict:
    """Evaluate as `config` says and return the summary (what `config.json`, when given,
    holds: per clip and mean metrics, and the run's config; each clip's `kept` files
    only with `keep_motions`). note: called with each remark for the user as it comes
    (an option ignored by the strategy, a test clip not in the graph, an actor map's
    problem). write_page: writes `config.report_html` (`PageWriter`). InputError (or
    another GraphsvcError) before the graph is built or loaded for an argument that
    does not fit."""
    note = note or (lambda text: None)
    if config.report_html and write_page is None:
        raise ValueError("a report_html page needs write_page, the function that writes it")
    # Every argument is checked before the (long) build and searches start.
    options = check_options(config.options)
    strategy = get(options.strategy)
    noise = parse_noise(config.noise)
    if config.position_noise is not None:
        if not (config.position_noise >= 0 and config.position_noise != float("inf")):
            raise InputError(f"--position-noise must be a finite number of metres ≥ 0, got {config.position_noise}")
        noise = replace(noise, position=config.position_noise)
    # The tracker stream is there when asked for: --position-noise, or a noise spec
    # with a tracker σ (the default and harsh presets, position=M).
    pattern = MarkerPattern((), config.flicker or 0.0, config.gap_fraction or 0.0)
    check_pattern(pattern)
    test_mapping = config.mapping
    if test_mapping and test_mapping != "guess":
        test_mapping = load_mapping_file(test_mapping)
    setup = loo.EvalSetup(
        noise=noise,
        positions=config.position_noise is not None or noise.position > 0,
        options=options,
        seed=config.seed,
        pattern=pattern,
        mapping=test_mapping,
    )
    strategy.check_simulation(options)
    if not loo.reads_markers(setup) and (config.flicker or config.gap_fraction):
        raise InputError("--flicker and --gap-fraction apply to a strategy that reads optical markers")
    if options.heading_from_track and not setup.positions:
        raise InputError("--heading-from-track needs the tracker's positions: give --position-noise M")
    if config.jobs < 1:
        raise InputError(f"--jobs must be ≥ 1, got {config.jobs}")
    if config.mixed is not None and config.mixed < 2:
        raise InputError(f"--mixed needs at least 2 clips a performance, got {config.mixed}")
    if config.graph and config.augment:
        raise InputError("--augment applies when building the graph; a --graph file keeps its own copies")
    actor_map = protocols.load_actor_map(config.actors) if config.actors else None
    setup = replace(setup, protocol=config.hold_out, pose_oracle=bool(config.pose_oracle))
    if config.calibrate_from_start is not None:
        from graphsvc.motion.calibration_pose import POSES

        least = loo.CALIBRATION_POSE_S + 2.0  # (the pose, then 2 s of motion: `sensors.calibration`)
        if not (math.isfinite(config.calibrate_from_start) and config.calibrate_from_start >= least):
            raise InputError(
                f"--calibrate-from-start must be a finite number of seconds ≥ {least:g} (the "
                f"{loo.CALIBRATION_POSE_S:g} s pose put before each clip, then motion), "
                f"got {config.calibrate_from_start}"
            )
        if config.calibration_pose not in POSES:
            raise InputError(f"unknown calibration pose {config.calibration_pose!r} (one of {', '.join(POSES)})")
        if loo.reads_markers(setup) or config.mixed is not None:
            raise InputError(
                "--calibrate-from-start applies to a strategy reading body-worn devices, one clip at a "
                "time (not --mixed)"
            )
        setup = replace(
            setup, calibrate_from_start=float(config.calibrate_from_start), calibration_pose=config.calibration_pose
        )
    check_outputs(
        [("--json", config.json, (".json",)), ("--report-html", config.report_html, (".html", ".htm"))],
        [("a knowledge-base file", k) for k in config.kb]
        + [
            ("the graph", config.graph),
            ("the actor map", config.actors),
            ("the joint map", None if config.mapping in (None, "guess") else config.mapping),
            ("the performer", config.performer),
            (
                "the performer's joint map",
                None if config.performer_mapping in (None, "guess") else config.performer_mapping,
            ),
        ],
    )
    performer = _performer_given(config)
    keep_tmp = None
    if config.keep_motions:
        keep = Path(config.keep_motions)
        if not keep.parent.is_dir():
            raise InputError(f"--keep-motions {keep}: folder {keep.parent} does not exist")
        if keep.exists() and not keep.is_dir():
            raise InputError(f"--keep-motions {keep}: is a file, not a folder")
        keep.mkdir(exist_ok=True)
        setup = replace(setup, keep_dir=str(keep.resolve()))
    elif config.report_html:  # (the page holds everything: the clips' files live only until it is written)
        import tempfile

        keep_tmp = tempfile.TemporaryDirectory(prefix="graphsvc-report-")
        setup = replace(setup, keep_dir=keep_tmp.name)
    try:
        layout = load_layout(config.layout) if config.layout else None

        t0 = time.perf_counter()
        files = find_motion_files(list(config.kb))
        names = [f.name for f in files]
        picked = loo.select_clips(names, config.test)
        if not picked:
            raise InputError(
                f"--test {config.test!r} matches none of the {len(files)} knowledge-base files (matched "
                "against file names, e.g. '*_001.bvh')"
            )
        if config.graph:
            graph = load_graph(config.graph)
            if layout is not None and layout.name != graph.layout.get("name"):
                raise InputError(
                    f"{config.graph} was built for layout {graph.layout.get('name')!r}, not "
                    f"{layout.name!r} (rebuild it or run `graphsvc relayout`)"
                )
            tests = [load_motion(files[k]) for k in picked]
            check_test_skeletons(tests, test_mapping if test_mapping is not None else graph.params.get("mapping"))
            indices = loo.match_graph_clips(graph, tests)
            offsets = {k: m.skeleton.offsets for m, k in zip(tests, indices) if k is not None}
            missing = [m.name for m, k in zip(tests, indices) if k is None]
            if missing:
                note(
                    f"{len(missing)} test clips are not in {config.graph} and are evaluated with nothing hidden: "
                    + ", ".join(missing[:5])
                    + (" …" if len(missing) > 5 else "")
                )
            build_s = time.perf_counter() - t0
        else:
            augment = tuple(a for a in (config.augment or "").split(",") if a)
            motions = load_knowledge_base(
                [str(f) for f in files], augment=augment, jobs=config.jobs, progress=config.progress
            )
            graph, _ = build_graph(
                motions,
                BuildOptions(
                    layout=layout or load_layout("wrists-ankles"),
                    augment=augment,
                    jobs=config.jobs,
                    progress=config.progress,
                ),
            )
            # load_knowledge_base keeps the files' order and appends augmented copies,
            # so file k is graph clip k.
            tests = [motions[k] for k in picked]
            check_test_skeletons(tests, test_mapping if test_mapping is not None else graph.params.get("mapping"))
            offsets = {k: m.skeleton.offsets for k, m in enumerate(motions)}
            build_s = time.perf_counter() - t0
        if performer is not None:
            setup = replace(setup, performer=_performer_lengths(graph, config, performer))
        hides = protocols.hide_lists(graph, tests, config.hold_out, offsets, actor_map)
        if config.hold_out == "actor":
            for problem in protocols.check_actor_map(protocols.graph_clips(graph, offsets), actor_map):
                note(problem)
        items = list(zip(tests, hides))
        if config.mixed is not None:
            items = mixed_items(
                tests, hides, config.mixed, float(graph.rate_hz), graph.params.get("mapping"), config.seed
            )
            if not items:
                raise InputError(
                    f"--mixed {config.mixed}: the test clips of no one performer cover {config.mixed} different labels"
                )
        t0 = time.perf_counter()
        rows = loo.run_leave_one_out(
            graph, items, setup, jobs=config.jobs, graph_path=config.graph, progress=config.progress
        )
        eval_s = time.perf_counter() - t0
        out = loo.summarize_run(rows)
        out["mean"]["peak_rss_mb"] = round(loo.peak_rss_mb(), 1)
        out["config"] = {
            "kb": list(config.kb),
            "test": config.test,
            "graph": config.graph,
            "layout": graph.layout.get("name"),
            "graph_nodes": graph.num_nodes,
            "graph_edges": graph.num_edges,
            "inputs": loo.inputs_description(setup),
            "noise": noise.to_dict(),
            "positions": setup.positions,
            "options": options.to_dict(),
            "seed": config.seed,
            "jobs": config.jobs,
            "build_s": round(build_s, 2),
            "evaluate_s": round(eval_s, 2),
            "mixed": config.mixed,
            "hold_out": config.hold_out,
            "actors": config.actors,
            **(
                {"calibrate_from_start": setup.calibrate_from_start, "calibration_pose": setup.calibration_pose}
                if setup.calibrate_from_start
                else {}
            ),
            **({"keep_motions": setup.keep_dir} if config.keep_motions else {}),
            **(
                {
                    "performer": {
                        "file": config.performer,
                        "height_m": round(skeleton_height(setup.performer), 4),
                        "segments_m": {k: round(v, 6) for k, v in setup.performer.items()},
                    }
                }
                if setup.performer is not None
                else {}
            ),
        }
        # Without --keep-motions the clips' files live only until the page is written:
        # the summary does not point at them (`graphsvc report` of its JSON then says so).
        saved = (
            out
            if config.keep_motions
            else {**out, "clips": [{k: v for k, v in c.items() if k != "kept"} for c in out["clips"]]}
        )
        if config.json:
            write_text_atomic(config.json, json.dumps(saved, indent=1, sort_keys=True) + "\n")
        if config.report_html:
            write_page(
                config.report_html,
                {**out, "config": {**out["config"], "keep_motions": setup.keep_dir}},
                Path(setup.keep_dir),
            )
    finally:
        if keep_tmp is not None:
            keep_tmp.cleanup()
    return saved


def summary_lines(summary: dict, config: EvalConfig) -> list[str]:
    """What `graphsvc evaluate` prints of `run`'s summary: the page written, the metrics
    table (`report.format_table`) and one line of what was evaluated on what, how long
    it took and the files written."""
    cfg = summary["config"]
    options = check_options(config.options)
    lines = [f"wrote {config.report_html}"] if config.report_html else []
    lines.append(format_table(summary))
    w = options.weights
    what = (
        f"{len(summary['clips'])} joined performances of {config.mixed} actions" if config.mixed else "leave-one-out"
    ) + f" (hold-out {config.hold_out})"
    searched = (
        f"{cfg['graph_nodes']:,} nodes, {cfg['inputs']}, strategy {options.strategy}"
        if "markers" in get(options.strategy).needs
        else f"{cfg['graph_nodes']:,} nodes ({cfg['layout']}), {cfg['inputs']}, "
        f"weights {w.acc:g},{w.position:g},{w.heading:g},{w.orientation:g}"
        + "".join(f", {k} {v}" for k, v in values_of(options.own, changed_only=True).items())
    )
    mean = summary["mean"]
    if cfg.get("calibrate_from_start"):
        flagged = mean.get("calibration_flagged_clips", 0)
        lines.append(
            f"devices calibrated from their first {cfg['calibrate_from_start']:g} s ({loo.CALIBRATION_POSE_S:g} s"
            f" of {cfg['calibration_pose']} put before each clip, then its motion): mounting error "
            f"{mean['calibration_error_deg']:.1f}° (mean over sensors and clips)"
            + (f"; {flagged} clips with a sensor the quality check named" if flagged else "")
        )
    lines.append(
        f"{what} on {searched}; graph {cfg['build_s']:.1f} s, evaluation {cfg['evaluate_s']:.1f} s, "
        f"peak memory {summary['mean']['peak_rss_mb']:,.0f} MB" + (f"; wrote {config.json}" if config.json else "")
    )
    return lines


def _performer_given(config: EvalConfig):
    """What --performer or --height gives, read and checked before any work: a performer
    file's segments, a height in metres, or None."""
    if config.performer is not None and config.height is not None:
        raise InputError("--performer and --height: give one or the other")
    if config.performer_mapping is not None and config.performer is None:
        raise InputError("--performer-mapping applies to a --performer motion file")
    if config.height is not None:
        return check_height(config.height)
    if config.performer is not None:
        return performer_segments(config.performer, config.performer_mapping)
    return None


def _performer_lengths(graph, config: EvalConfig, given) -> dict:
    """Every segment's length on the graph's skeleton for what `_performer_given` read."""
    kb = segment_lengths(graph.skeleton, graph.params.get("mapping"))
    if config.height is not None:
        return lengths_for_height(kb, given)
    return complete_lengths(kb, given, str(config.performer))


def check_test_skeletons(tests, mapping) -> None:
    """Every test clip's joints found (SkeletonError naming --mapping otherwise), before
    any note is printed or any search starts."""
    for m in tests:
        try:
            joint_map(m.skeleton, mapping)
        except SkeletonError as exc:
            raise SkeletonError(f"test clip {m.name}: {exc}") from None

"""Recording → motion: the one entry the CLI, the evaluation and the gRPC service share.

Dispatch only. `reconstruct` looks the strategy up by name (`graphsvc.strategies`),
checks the recording against it and the graph and puts it on the graph's sample grid
(`strategies.base.prepare_input`), and runs the strategy's batch reconstruction;
`open_session(graph, options)` opens the strategy's live session. Both raise InputError
for recordings that do not fit (naming a missing input, sensor or label) and
StrategyNotImplementedError for strategies not built yet.

With `latency_s` set, a strategy's batch decoding runs the very same live decoding,
so `reconstruct` predicts what a live client gets.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from graphsvc.errors import InputError
from graphsvc.fileio import check_outputs, write_texts_atomic
from graphsvc.graph.model import MotionGraph
from graphsvc.motion.output import MOTION_OUTPUT_SUFFIXES, motion_file_bytes
from graphsvc.motion.proportions import on_performer, performer_skeleton, skeleton_height
from graphsvc.sensors.calibration import apply_calibration, check_calibration, load_calibration, mounting_angle_deg
from graphsvc.sensors.devices import DEVICES, apply_device_map, unmapped_note
from graphsvc.sensors.devices import device_map as load_device_map
from graphsvc.sensors.files import read_recording
from graphsvc.sensors.grid import readings_at_rate
from graphsvc.sensors.recording import Recording
from graphsvc.strategies import available, check_options, open_session
from graphsvc.strategies import get as get_strategy
from graphsvc.strategies.base import prepared_index
from graphsvc.strategies.inputs import check_layout, prepare_input
from graphsvc.strategies.live import LiveSession
from graphsvc.strategies.options import (
    Options,
    SharedOptions,
    Weights,
    check_constraints,
    load_constraints,
    parse_weights,
)
from graphsvc.strategies.results import Frame, Provenance, Reconstruction, path_labels
from graphsvc.strategies.sources import compact_sources
from graphsvc.strategies.start import start_state

# The library's face for a reconstruction: what callers import from here.
__all__ = [
    "Frame",
    "LiveSession",
    "Options",
    "Provenance",
    "Reconstruction",
    "SharedOptions",
    "Weights",
    "check_constraints",
    "check_layout",
    "check_options",
    "load_constraints",
    "open_session",
    "parse_weights",
    "path_labels",
    "read_recording_file",
    "read_searched_recording",
    "readings_at_rate",
    "reconstruct",
    "start_state",
    "synthesize_files",
    "warm_up",
]


def reconstruct(
    graph: MotionGraph,
    rec: Recording,
    options: Options = Options(),
    allowed: np.ndarray | None = None,
    threads: bool = True,
    should_stop: Callable[[], bool] | None = None,
) -> Reconstruction:
    """The motion a recording's measurements describe, by `options.strategy`. allowed:
    (N,) bool node mask (leave-one-out evaluation) or None; threads: numba threads
    inside the strategy (False where many run side by side); should_stop: callable
    polled during the search, raising SearchCancelled when it returns true."""
    options = check_options(options)
    strategy = get_strategy(options.strategy)
    t0 = time.perf_counter()
    inp = prepare_input(strategy, graph, rec, options)
    index = prepared_index(strategy, graph)
    prepare_s = time.perf_counter() - t0
    result = strategy.reconstruct(index, graph, inp, options, allowed=allowed, threads=threads, should_stop=should_stop)
    own = result.report
    timings = own.pop("timings_s", {})
    report = {
        "strategy": options.strategy,
        "options": options.to_dict(),
        "graph": {
            "nodes": graph.num_nodes,
            "edges": graph.num_edges,
            "rate_hz": float(graph.rate_hz),
            "layout": graph.layout.get("name"),
        },
        "samples": inp.num_samples,
        "input_rate_hz": inp.input_rate_hz,
        "resampled": inp.resampled,
        "heading_source": inp.heading_source,
        "constraint_sets": len(inp.constraints),
        **own,
        # (every report has these four, a strategy's own after them)
        "timings_s": {
            "warm_up": timings.get("warm_up", 0.0),
            "prepare": round(prepare_s, 4),
            "search": timings.get("search", 0.0),
            "synthesis": timings.get("synthesis", 0.0),
            **{k: v for k, v in timings.items() if k not in ("warm_up", "search", "synthesis")},
        },
    }
    report["samples_per_s"] = report.pop("samples_per_s", None)
    ignored_options = strategy.ignored_options(options)
    if inp.ignored_inputs:
        report["ignored_inputs"] = inp.ignored_inputs
    if ignored_options:
        report["ignored_options"] = ignored_options
    result.report = report
    return result


def warm_up(graph: MotionGraph, threads: bool = False, strategies=None) -> float:
    """Load each strategy's compiled code and make its index and tables for `graph` now
    (numba compiles on a fresh install, or loads from its cache), not on a client's
    first sample. strategies: names (default: every built one). Returns the seconds."""
    t0 = time.perf_counter()
    for name in strategies or available():
        s = get_strategy(name)
        s.warm_up(prepared_index(s, graph), graph, threads)
    return time.perf_counter() - t0


def synthesize_files(
    graph: MotionGraph,
    graph_path,
    recording_path,
    output,
    options: Options = Options(),
    report_path=None,
    scale: float = 100.0,
    up=None,
    units=None,
    device_map=None,
    calibration=None,
    threads: bool = True,
    notes=None,
    calibrate_from_start=None,
    performer=None,
) -> Reconstruction:
    """`graphsvc synthesize` as a function, for the CLI and a batch alike: read the
    recording (up, units: as the file does not say), name a device's sensors as the
    graph's layout does (device_map: a built-in device or a map file), turn a device's readings into
    the layout's frames (calibration: a `graphsvc calibrate` file; or calibrate_from_start:
    (seconds, pose), calibrated from the recording's own start against the graph,
    `graph.calibration.calibrate_from_start`), reconstruct, write the motion as its
    suffix says (`motion.output`: .bvh in `scale` units a metre, .glb or .gltf) and, given
    report_path, the report JSON — each atomically, the report renamed into place before
    the motion (a motion is never without its report); InputError, before anything is
    read, when an output would replace an input or the other output or has a suffix
    other than .bvh, .glb, .gltf (output) and .json (report), and before anything is
    written when the motion cannot be written in its format.
    The report's 'files' names the output, graph and recording (and how the recording
    was read); a strategy without a node path adds each frame's heaviest `sources`
    (`strategies.sources.compact_sources`). performer: segment lengths
    (`motion.proportions.performer_lengths`) the output is put on (`on_performer`: the
    returned motion and the BVH; the report's `performer` says which), None: the graph
    skeleton's. notes: a list that
    collects remarks for the user (None: dropped). Same inputs, same output bytes, with
    or without threads."""
    check_outputs(
        [("the output", output, MOTION_OUTPUT_SUFFIXES), ("the report", report_path, (".json",))],
        [
            ("the graph", graph_path),
            ("the recording", recording_path),
            ("the calibration", calibration),
            ("the device map", None if device_map in DEVICES else device_map),
        ],
    )
    rec = read_searched_recording(
        graph, recording_path, up, units, device_map, calibration, notes, calibrate_from_start
    )
    result = reconstruct(graph, rec, options, threads=threads)
    if performer is not None:
        result = put_on_performer(graph, result, performer)
    data = motion_file_bytes(output, result.motion, scale)
    result.report["files"] = {
        "output": str(Path(output).resolve()),
        "graph": str(Path(graph_path).resolve()),
        "recording": str(Path(recording_path).resolve()),
    }
    read = {
        k: v
        for k, v in (
            ("up", up),
            ("units", units),
            ("device_map", device_map and _resolved_if_file(device_map)),
            ("calibration", calibration and _resolved_if_file(calibration)),
            (
                "calibrate_from_start",
                calibrate_from_start and {"seconds": calibrate_from_start[0], "pose": calibrate_from_start[1]},
            ),
        )
        if v
    }
    if read:  # (how the recording was read, for `graphsvc report`)
        result.report["files"]["read"] = read
    if result.node_path is None and result.provenance is not None:
        result.report["sources"] = compact_sources(result.provenance)
    # The report lands first: a motion is never found without its report, even when the
    # process is killed between the two (a batch's outputs stay in pairs).
    report = [(report_path, json.dumps(result.report, indent=1, sort_keys=True) + "\n")] if report_path else []
    write_texts_atomic(report + [(output, data)])
    return result


def put_on_performer(graph: MotionGraph, result: Reconstruction, lengths: dict) -> Reconstruction:
    """`result` with its motion on a performer's segment lengths (`motion.proportions`:
    the graph skeleton rescaled, the same local rotations, translations scaled with the
    legs) and the report's `performer`: the segment lengths and the height they stand
    for, in metres."""
    mapping = graph.params.get("mapping")
    skeleton = performer_skeleton(result.motion.skeleton, lengths, mapping)
    report = {
        **result.report,
        "performer": {
            "segments_m": {k: round(float(v), 6) for k, v in lengths.items()},
            "height_m": round(skeleton_height(lengths), 4),
        },
    }
    return replace(result, motion=on_performer(result.motion, skeleton, mapping), report=report)


def read_searched_recording(
    graph: MotionGraph,
    recording_path,
    up=None,
    units=None,
    device_map=None,
    calibration=None,
    notes=None,
    calibrate_from_start: tuple[float, str] | None = None,
) -> Recording:
    """A recording as `synthesize_files` searches it on `graph`: `read_recording_file`
    for the graph's layout and sensors; calibrate_from_start (seconds, pose): its
    mountings calibrated from its own first seconds against `graph` and applied
    (`calibrated_from_start`)."""
    rec = read_recording_file(
        recording_path,
        up,
        units,
        device_map,
        calibration,
        None if calibrate_from_start else notes,
        layout_name=graph.layout.get("name"),
        sensor_names=graph.sensor_names,
    )
    return rec if not calibrate_from_start else calibrated_from_start(rec, graph, *calibrate_from_start, notes=notes)


def calibrated_from_start(
    rec: Recording, graph: MotionGraph, seconds: float, pose: str, hidden_clips=(), notes=None
) -> Recording:
    """A device-frame recording in the layout's frames, its mountings calibrated from its
    own first `seconds` in `pose` against `graph` (`graph.calibration.calibrate_from_start`);
    meta "calibration" says so. The calibrating seconds stay in the recording. notes: a
    list that collects a line on the calibration (each sensor's mounting angle and
    residual), or None."""
    from graphsvc.graph.calibration import calibrate_from_start

    cal = calibrate_from_start(rec, graph, seconds, pose, hidden_clips)
    if notes is not None:
        a, b = cal["rest_s"]
        notes.append(
            f"calibrated from its first {seconds:g} s ({pose}, rest {a:.2f}–{b:.2f} s): "
            + ", ".join(
                f"{n} {mounting_angle_deg(item):.1f}° (residual {item['residual_deg']:.1f}°)"
                for n, item in cal["sensors"].items()
            )
        )
    return apply_calibration(rec, check_calibration(cal, f"its first {seconds:g} s ({pose})"))


def read_recording_file(
    recording_path,
    up=None,
    units=None,
    device_map=None,
    calibration=None,
    notes=None,
    layout_name=None,
    sensor_names=None,
) -> Recording:
    """A recording file as it is searched, here or sent to a server (`graphsvc client`):
    read (up, units: as the file does not say), a device's sensors named as the layout
    `layout_name` does (device_map: a built-in device, `sensors.devices.DEVICES`, or a
    map file), its readings turned into the layout's frames (calibration: a `graphsvc
    calibrate` file). sensor_names: the graph's sensors, the order a device map puts
    them in (a note names those it leaves without a device sensor); an Xsens recording
    not named so without a device map is refused (None: not checked). notes: a list
    that collects remarks for the user, or None."""
    rec = read_recording(recording_path, up=up, units=units)
    if device_map:
        rec = apply_device_map(rec, load_device_map(device_map, layout_name, rec.sensor_names), order=sensor_names)
        note = unmapped_note(rec, sensor_names, device_map) if sensor_names is not None else None
        if note is not None and notes is not None:
            notes.append(note)
    elif (
        sensor_names is not None
        and rec.meta.get("imported_from") == "mvnx"
        and tuple(rec.sensor_names) != tuple(sensor_names)
    ):
        raise InputError(
            f"{recording_path} names its sensors as Xsens does ({', '.join(rec.sensor_names[:4])}"
            f"{' …' if rec.num_sensors > 4 else ''}): "
            f"give --device-map xsens (or a map file) to name them as layout "
            f"{layout_name!r} does ({', '.join(sensor_names)})"
        )
    if calibration:
        rec = apply_calibration(rec, load_calibration(calibration))
    elif rec.meta.get("sensor_frame") == "device" and rec.accelerations is not None and notes is not None:
        notes.append(
            f"{recording_path}'s readings are in each device's own frame; they are used as if in the "
            "layout's sensor frames (give --calibration CAL.json from `graphsvc calibrate`)"
        )
    return rec


def _resolved_if_file(name) -> str:
    """An absolute path for a file name, a built-in name ('xsens') as it is."""
    from pathlib import Path

    return str(Path(name).resolve()) if Path(name).is_file() else str(name)

"""A recording checked against a strategy and a graph, and put on the graph's sample grid.

`prepare_input` checks what a recording carries against what the strategy needs and can
use (`recording_inputs`, `check_inputs`: a missing input refused by name, the others
listed as ignored), its sensors against the graph's layout (`check_layout`, one wording
for the CLI and the service; the graph's sensors in another order are put in the
graph's, `in_sensor_order`) and its constraints against the graph and the recording's
length, then resamples it to the graph's rate (`sensors.grid`): a `PreparedInput`, which
is all a strategy's batch reconstruction reads.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field, replace

import numpy as np

from graphsvc.errors import InputError
from graphsvc.graph.model import MotionGraph
from graphsvc.sensors.anatomy import check_frames
from graphsvc.sensors.devices import DEVICES
from graphsvc.sensors.grid import markers_at_rate, readings_at_rate, values_at_rate
from graphsvc.sensors.layout import PRESETS, layout_from_dict, root_sensor
from graphsvc.sensors.noise import CausalTrackHeading, heading_from_track
from graphsvc.sensors.orientation import orientation_cue
from graphsvc.sensors.recording import Recording
from graphsvc.strategies.base import INPUTS, Strategy
from graphsvc.strategies.options import Options, check_constraints


def tracked_streams(options: Options, position, heading):
    """The tracker streams the weights keep: (position or None, heading or None)."""
    return (position if options.weights.position else None), (heading if options.weights.heading else None)


def graph_cue(graph: MotionGraph, orientations) -> np.ndarray:
    """(..., S, W) the orientation cue the graph's edges carry (`graph.edge_up`: its width
    W says which, `sensors.orientation`) of orientations (..., S, 4); NaN where missing."""
    width = int(graph.edge_up.shape[-1])
    root = root_sensor(layout_from_dict(graph.layout)) if width != 3 else None
    return orientation_cue(np.asarray(orientations, dtype=np.float64), width, root)


def recording_inputs(rec: Recording) -> set[str]:
    """Which of INPUTS a recording carries."""
    have = set()
    if rec.accelerations is not None and rec.accelerations.size:
        have.add("accelerations")
    if getattr(rec, "orientations", None) is not None:
        have.add("orientations")
    if getattr(rec, "marker_positions", None) is not None:
        have.add("markers")
    if rec.ground_position is not None:
        have.add("ground_position")
    if rec.heading is not None:
        have.add("heading")
    if rec.constraints:
        have.add("constraints")
    return have


def check_inputs(strategy: Strategy, have: set[str]) -> list[str]:
    """InputError naming the first input `strategy` needs that `have` lacks; else the
    inputs present that it cannot use (sorted)."""
    for name in INPUTS:
        if name in strategy.needs and name not in have:
            raise InputError(f"strategy {strategy.name!r} needs {name.replace('_', ' ')}, and the recording has none")
    return sorted(have - set(strategy.uses))


def layout_mismatch(mine, theirs, order_matters: bool = True) -> str | None:
    """What separates a stream's sensor names `theirs` from a layout's `mine`: the
    missing sensors, those not in the layout, duplicates or (order_matters) the
    order; None when they agree. One wording for the CLI and the service."""
    mine, theirs = tuple(mine), tuple(theirs)
    if mine == theirs:
        return None
    counts = Counter(theirs)  # (linear: a stream may announce any number of names)
    missing = [n for n in mine if n not in counts]
    known = set(mine)
    extra = [n for n in counts if n not in known]
    dup = [n for n, c in counts.items() if c > 1]
    parts = []
    if missing:
        parts.append(f"missing {_names(missing)}")
    if extra:
        parts.append(f"not in the graph: {_names(extra)}")
    if dup:
        parts.append(f"named twice: {_names(dup)}")
    if not parts:
        if not order_matters:
            return None
        parts.append(f"order {', '.join(theirs)} instead of {', '.join(mine)}")
    return "; ".join(parts)


def _names(names: list, most: int = 8) -> str:
    return ", ".join(names[:most]) + (f" … (+{len(names) - most})" if len(names) > most else "")


def layout_mismatch_message(layout_name: str, mine, theirs, order_matters: bool = True) -> str | None:
    """The line that refuses sensors `theirs` for a graph whose layout `layout_name`
    has sensors `mine`, or None when they fit. Its advice: a device map where some of
    `theirs` are no layout preset's sensors (a device's own names), else another graph."""
    what = layout_mismatch(mine, theirs, order_matters)
    if what is None:
        return None
    known = set(mine).union(*(p.sensor_names for p in PRESETS.values()))
    if any(n not in known for n in theirs):
        advice = f"give --device-map ({', '.join(DEVICES[:-1])}, {DEVICES[-1]} or a map file) to name them as the layout does"
    else:
        advice = "rebuild the graph or run `graphsvc relayout`"
    return f"the recording's sensors do not match the graph's layout {layout_name!r}: {what} ({advice})"


def in_sensor_order(rec: Recording, names) -> Recording:
    """`rec` with its sensors in the order `names` gives, where they are the same
    sensors in another order; else `rec` as it is (`check_layout` then says what does
    not fit)."""
    names = tuple(names)
    if tuple(rec.sensor_names) == names or layout_mismatch(names, rec.sensor_names, order_matters=False) is not None:
        return rec
    cols = [rec.sensor_names.index(n) for n in names]
    pick = lambda a: None if a is None else np.ascontiguousarray(a[:, cols])  # noqa: E731
    return replace(rec, sensor_names=names, accelerations=pick(rec.accelerations), orientations=pick(rec.orientations))


def check_layout(graph: MotionGraph, sensor_names) -> None:
    """InputError unless the stream's sensors are the graph's, in the same order."""
    message = layout_mismatch_message(graph.layout.get("name", "?"), graph.sensor_names, sensor_names)
    if message is not None:
        raise InputError(message)


@dataclass
class PreparedInput:
    """A recording checked against a graph and put on its sample grid: T samples of
    accelerations (T, S, 3) m/s² (S = 0 for a strategy that reads none), ground
    positions (T, 2) m and headings (T,) rad (or None), labelled marker positions (T, M,
    3) m (or None), the constraint sets, and what the report says about them."""

    acc: np.ndarray
    position: np.ndarray | None
    heading: np.ndarray | None
    constraints: list
    resampled: bool
    heading_source: str
    input_rate_hz: float
    ignored_inputs: list = field(default_factory=list)
    markers: np.ndarray | None = None  # (T, M, 3) m, NaN = not seen
    marker_names: tuple = ()
    meta: dict = field(default_factory=dict)  # the recording's provenance
    # (T, S, W) the sensors' measured orientation cue, of the graph's kind
    # (`sensors.orientation`: "up" vectors or rotations relative to the root sensor;
    # NaN = missing), where the strategy uses orientations and the graph has their
    # metadata; else None
    up: np.ndarray | None = None

    @property
    def num_samples(self) -> int:
        return int(self.acc.shape[0])


def check_constraint_times(constraints, duration_s: float) -> None:
    """InputError for a constraint interval that starts at or after the recording's
    end (it could never hold); one that only ends past it is kept."""
    for k, cset in enumerate(constraints):
        for j, c in enumerate(cset):
            start, end = float(c["start_s"]), float(c["end_s"])
            if start >= duration_s:
                raise InputError(
                    f"constraint set {k}: constraint {j} ({start:g}–{end:g} s) starts after the "
                    f"recording ends ({duration_s:g} s)"
                )


def prepare_input(strategy: Strategy, graph: MotionGraph, rec: Recording, options: Options) -> PreparedInput:
    """Check `rec` for `strategy` on `graph` and resample it to the graph rate (module
    docstring). Raises InputError naming what does not fit."""
    rec.validate()
    constraints = rec.constraints if options.constraints is None else options.constraints
    have = recording_inputs(rec) | ({"constraints"} if constraints else set())
    ignored = check_inputs(strategy, have)
    if "accelerations" in strategy.uses:
        rec = in_sensor_order(rec, graph.sensor_names)
        check_layout(graph, rec.sensor_names)
        check_frames(graph.params, rec.meta)
    constraints = check_constraints(constraints, graph) if "constraints" in strategy.uses else []
    check_constraint_times(constraints, rec.num_samples / rec.rate_hz)
    acc, position, heading, resampled = readings_at_rate(rec, graph.rate_hz)
    if "accelerations" not in strategy.uses:
        acc = np.zeros((acc.shape[0], 0, 3))
    markers = markers_at_rate(rec, graph.rate_hz) if "markers" in strategy.uses else None
    up = None
    if getattr(rec, "orientations", None) is not None and "orientations" in strategy.uses:
        if graph.edge_up is None:  # (a graph file written before orientation metadata)
            ignored = sorted(set(ignored) | {"orientations"})
        else:
            up = values_at_rate(rec, graph_cue(graph, rec.orientations), graph.rate_hz)
    heading_source = "recording" if heading is not None else "none"
    if options.heading_from_track:
        if position is None:
            raise InputError("--heading-from-track needs ground positions, and the recording has none")
        rate = float(graph.rate_hz)
        rest = math.radians(options.rest_heading_deg)
        if options.latency_s is None:
            heading = heading_from_track(position, rate, options.speed_threshold, rest)
        else:
            track = CausalTrackHeading(rate, options.speed_threshold, rest)
            heading = np.array([track.push(p) for p in position])
        heading_source = "track"
    return PreparedInput(
        acc,
        position,
        heading,
        constraints,
        resampled,
        heading_source,
        float(rec.rate_hz),
        ignored,
        markers,
        tuple(rec.marker_names) if markers is not None else (),
        dict(rec.meta),
        up,
    )

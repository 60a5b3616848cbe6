"""The multilinear strategy behind the common interface: batch only.

A recording is segmented and classified by the Viterbi search (`strategies.viterbi`,
its own options and the shared weights; the hidden clips hidden from it too): the
path's content label a frame, and its foot contacts. `plan_units` cuts each run of one
label into motion units: for a locomotion class, steps from one touchdown of the path
to the next (`model.touchdowns`; the stretch before the first and after the last is
the end or the start of a step of the tensor's reference length, fitted on the frames
it shares with the run); for any other class the run is one unit. With
`--multilinear-label` the whole recording is that class. A run shorter than
MIN_RUN_S, or of a class (or foot) without a tensor, keeps the search's own frames.

Each unit's coefficients are fitted to its readings (`fit`); the units' values are
joined by the offset blending of `synthesis.path` (`blend_cuts`, BLEND_S either side
of each cut) and put on the root's own track: their steps and turns integrated from
the first measured position and heading, with a tracker the offset to its positions
filtered and smoothed over the recording, the heading pulled toward the measured one
(`synthesis.track`, as the per-frame strategies do), then the poses filtered
(`smooth_s`); with `--multilinear-hold-feet` the feet the units plant are held
(`synthesis.foot_hold`, against the search's own planted feet).

A live stream is refused: a unit is fitted once the search has placed its end, which
the fixed-lag search settles only a second or more later, and then the whole unit at
once.

Index: every recorded clip's frames (`model.frame_data`), cached beside the graph; the
model learned from the clips a run may use, cached beside it too, one file per
hold-out and options (`model.model_key`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from graphsvc.errors import InputError, SearchCancelled
from graphsvc.graph.derived import derived
from graphsvc.graph.model import MotionGraph
from graphsvc.graph.poses import node_translations
from graphsvc.motion.skeleton import Motion
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.strategies.base import Strategy, prepared_index
from graphsvc.strategies.index import cached_arrays
from graphsvc.strategies.inputs import PreparedInput, tracked_streams
from graphsvc.strategies.live import LiveSession
from graphsvc.strategies.multilinear.fit import Body, fit_unit, graph_body, local_frames, placed, unit_times
from graphsvc.strategies.multilinear.model import (
    MIN_STEP_S,
    Tensor,
    align_hemispheres,
    frame_data,
    learn,
    model_key,
    tensors_of,
    touchdowns,
    usable_clips,
)
from graphsvc.strategies.multilinear.options import MultilinearOptions
from graphsvc.strategies.options import Options, track_pull
from graphsvc.strategies.results import Provenance, Reconstruction, label_runs
from graphsvc.strategies.start import start_state
from graphsvc.synthesis.foot_hold import FootHold
from graphsvc.synthesis.local_pose import pose_vectors
from graphsvc.synthesis.path import blend_cuts, path_tables
from graphsvc.synthesis.smooth import smooth_poses
from graphsvc.synthesis.track import FixedLagSmoother, TrackModel, advance_own_track, shift_to_smoothed

INDEX_VERSION = 2
MIN_RUN_S = 0.3
BLEND_S = 0.15  # half the blending window at a cut between units
SOURCES = 3  # the heaviest original units a frame's provenance names
LIVE_REFUSAL = (
    "multilinear reconstructs whole recordings only (synthesize, evaluate, batch): a motion unit is "
    "fitted once the search has placed its end, so live streams are refused"
)


def learned_model(graph: MotionGraph, data: dict, own: MultilinearOptions, allowed=None) -> dict:
    """The model's arrays for these options and allowed nodes: from the cache beside the
    graph (learned and written there the first time), held for the graph object."""
    clips = usable_clips(graph, allowed)
    key = model_key(own, clips)
    return derived(
        graph,
        ("multilinear model", key),
        lambda: cached_arrays(graph, f"multilinear-{key}", INDEX_VERSION, lambda: learn(graph, data, clips, own)),
    )


@dataclass
class Unit:
    """A motion unit of a recording: it spans frames [start, end) (possibly past the
    recording's ends) and fills frames [lo, hi); tensor: its index in the model, −1 for
    the search's own frames; label: its class."""

    start: int
    end: int
    lo: int
    hi: int
    tensor: int
    label: int


def plan_units(
    labels: np.ndarray, contacts: np.ndarray, lookup: dict, locomotion: set, rate_hz: float, frames: dict
) -> list[Unit]:
    """The units of a recording (module docstring) from its per-frame class labels (T,)
    and foot contacts (T, 2); lookup: (label, foot) → tensor index (foot −1 for whole
    units); frames: tensor index → its reference length."""
    T = labels.shape[0]
    out: list[Unit] = []
    bounds = np.flatnonzero(np.diff(labels)) + 1
    for a, b in zip(np.concatenate([[0], bounds]), np.concatenate([bounds, [T]])):
        a, b, c = int(a), int(b), int(labels[a])
        if b - a < MIN_RUN_S * rate_hz and not (a == 0 and b == T):
            out.append(Unit(a, b, a, b, -1, c))
        elif c not in locomotion:
            out.append(Unit(a, b, a, b, lookup.get((c, -1), -1), c))
        else:
            events = [(t + a, f) for t, f in touchdowns(contacts[a:b], max(1, round(MIN_STEP_S * rate_hz)))]
            if not events:
                out.append(Unit(a, b, a, b, -1, c))
                continue
            t0, f0 = events[0]
            if t0 > a:  # (the end of the step before the first touchdown: the other foot's)
                k = lookup.get((c, 1 - f0), -1)
                n = frames.get(k, t0 - a)
                out.append(Unit(min(a, t0 - n) if k >= 0 else a, t0, a, t0, k, c))
            for (t, f), (u, _) in zip(events, events[1:]):
                out.append(Unit(t, u, t, u, lookup.get((c, f), -1), c))
            tl, fl = events[-1]
            if tl < b:
                k = lookup.get((c, fl), -1)
                n = frames.get(k, b - tl)
                out.append(Unit(tl, max(b, tl + n) if k >= 0 else b, tl, b, k, c))
    return out


class MultilinearStrategy(Strategy):
    name = "multilinear"
    needs = frozenset({"accelerations"})
    uses = frozenset({"accelerations", "ground_position", "heading"})
    summary = "per motion unit the mix of a class's takes whose simulated readings fit (Tautges 2012, ch. 2)"
    options_class = MultilinearOptions
    shared = frozenset({"track_pull_s", "track_sigma_m", "track_drift", "smooth_s"})

    def prepare(self, graph: MotionGraph) -> dict:
        return cached_arrays(graph, self.name, INDEX_VERSION, lambda: frame_data(graph))

    def describe_lag(self, rate_hz: float) -> str:
        return "not at all: live streams are refused (whole recordings only)"

    def check_stream(self, options: Options, sensor_names, marker_names) -> None:
        raise InputError(LIVE_REFUSAL)

    def ignored_options(self, options: Options) -> list[str]:
        out = ["latency_s"] if options.latency_s is not None else []
        return sorted(out + super().ignored_options(options))

    def reconstruct(
        self,
        index,
        graph: MotionGraph,
        inp: PreparedInput,
        options: Options,
        allowed: np.ndarray | None = None,
        threads: bool = True,
        should_stop=None,
    ) -> Reconstruction:
        from graphsvc.strategies import get

        own = self.own(options)
        rate = float(graph.rate_hz)
        t0 = time.perf_counter()
        arrays = learned_model(graph, index, own, allowed)
        tensors = tensors_of(arrays)
        learn_s = time.perf_counter() - t0
        T = inp.num_samples
        shortest = min(t.frames for t in tensors)
        if T < shortest:
            raise InputError(
                f"multilinear: the recording's {T} samples ({T / rate:.2f} s) are shorter than one motion "
                f"unit (the shortest the model holds is {shortest} frames, {shortest / rate:.2f} s)"
            )
        forced = None if own.label is None else self._forced_label(graph, tensors, own.label)

        t0 = time.perf_counter()
        viterbi = get("viterbi")
        search_options = Options(
            strategy="viterbi",
            weights=options.weights,
            shared=replace(options.shared, refine=False),
            settings=options.settings,
            heading_from_track=options.heading_from_track,
        )
        found = viterbi.reconstruct(
            prepared_index(viterbi, graph), graph, inp, search_options, allowed, threads, should_stop
        )
        nodes, edges = found.node_path, found.edge_path
        search_s = time.perf_counter() - t0

        t0 = time.perf_counter()
        labels = np.asarray(graph.node_label)[nodes].astype(np.int64)
        if forced is not None:
            labels[:] = forced
        contacts = np.asarray(graph.node_contacts)[nodes]
        lookup = {(t.label, t.foot): k for k, t in enumerate(tensors)}
        units = plan_units(
            labels,
            contacts,
            lookup,
            set(int(x) for x in np.asarray(arrays["locomotion"])),
            rate,
            {k: t.frames for k, t in enumerate(tensors)},
        )
        body = graph_body(graph)
        values = self._search_values(graph, found.motion, nodes, edges, body)
        align_hemispheres(values, np.asarray(index["hemispheres"]), body.layout.slot)
        trans_of = node_translations(graph, nodes)
        acc = np.asarray(inp.acc, dtype=np.float64) / GRAVITY
        S = acc.shape[1]
        entered = values[np.maximum(np.arange(T) - 1, 0)].copy()
        sources = [[] for _ in range(T)]
        rows = []
        for u in units:
            if should_stop is not None and should_stop():
                raise SearchCancelled("reconstruction cancelled")
            if u.tensor < 0:
                for t in range(u.lo, u.hi):
                    sources[t] = [(int(graph.node_clip[nodes[t]]), float(graph.node_frame[nodes[t]]), 1.0)]
                continue
            t = tensors[u.tensor]
            L = u.end - u.start
            frames = np.arange(u.start, u.end)
            inside = (frames >= max(u.lo, 0)) & (frames < min(u.hi, T))
            measured = np.full((L, S, 3), np.nan)
            measured[inside] = acc[frames[inside]]
            # (on the bone lengths of the clip the search played at the unit's first frame)
            unit_body = replace(body, trans=node_translations(graph, int(nodes[u.lo])))
            fit = fit_unit(t, measured, inside, unit_body, own.prior, own.warp, own.evaluations)
            k = u.lo - u.start
            values[u.lo : u.hi] = fit.values[k : k + u.hi - u.lo]
            trans_of[u.lo : u.hi] = unit_body.trans
            entered[u.lo] = fit.values[k - 1] if k > 0 else 2.0 * fit.values[k] - fit.values[min(k + 1, L - 1)]
            w = t.row_weights(fit.x_s, fit.x_r)
            order = np.argsort(-np.abs(w), kind="stable")[:SOURCES]
            share = np.abs(w[order]) / max(float(np.abs(w[order]).sum()), 1e-12)
            times = unit_times(t.frames, L, fit.warp)
            for f in range(u.lo, u.hi):
                ref = times[f - u.start]
                sources[f] = [
                    (int(t.row_clip[r]), float(np.interp(ref, np.arange(t.frames), t.row_frame[r])), float(s))
                    for r, s in zip(order, share)
                ]
            rows.append(
                {
                    "class": graph.labels[u.label],
                    "foot": ("left", "right", "whole")[t.foot],
                    "start_frame": u.lo,
                    "frames": u.hi - u.lo,
                    "unit_frames": L,
                    "x_style": [round(float(x), 5) for x in fit.x_s],
                    "x_repetition": [round(float(x), 5) for x in fit.x_r],
                    "warp": [round(float(w), 4) for w in fit.warp],
                    "cost": round(fit.cost, 6),
                    "start_cost": round(fit.start_cost, 6),
                    "start_row": fit.start_row,
                    "evaluations": fit.evaluations,
                }
            )
        motion = self._assemble(
            graph, body, values, trans_of, entered, units, inp, options, found.motion if own.hold_feet else None
        )
        fit_s = time.perf_counter() - t0
        frame_labels = np.asarray(graph.labels, dtype=object)[labels]
        K = SOURCES
        clip, frame, weight = np.full((T, K), -1, np.int64), np.zeros((T, K)), np.zeros((T, K))
        for t, src in enumerate(sources):
            for j, (c, f, w) in enumerate(src[:K]):
                clip[t, j], frame[t, j], weight[t, j] = c, f, w
        fallback = sum(u.hi - u.lo for u in units if u.tensor < 0)
        report = {
            "cost": float(sum(r["cost"] * r["frames"] for r in rows)),
            "multilinear": {
                "tensors": [
                    {
                        "class": graph.labels[t.label],
                        "foot": ("left", "right", "whole")[t.foot],
                        "frames": t.frames,
                        "styles": int(t.u_style.shape[0]),
                        "repetitions": int(t.u_rep.shape[0]),
                        "kept": list(t.kept),
                    }
                    for t in tensors
                ],
                "units": rows,
                "search_frames": int(fallback),
                "search_labels": found.report.get("labels", []),
                "class": None if forced is None else graph.labels[forced],
            },
            "labels": label_runs(list(frame_labels)),
            "timings_s": {"warm_up": round(learn_s, 4), "search": round(search_s, 4), "synthesis": round(fit_s, 4)},
            "samples_per_s": round(T / max(search_s + fit_s, 1e-9), 1),
        }
        return Reconstruction(motion, None, None, report, Provenance(clip, frame, weight, frame_labels))

    @staticmethod
    def _forced_label(graph: MotionGraph, tensors: list[Tensor], name: str) -> int:
        if name not in graph.labels:
            raise InputError(
                f"multilinear label {name!r} is not a class of the knowledge base ({', '.join(graph.labels)})"
            )
        c = graph.labels.index(name)
        if not any(t.label == c for t in tensors):
            raise InputError(
                f"multilinear label {name!r}: the class has fewer than two takes usable "
                f"(clips named <content>_<style>_<take>), no tensor to fit"
            )
        return c

    @staticmethod
    def _search_values(graph: MotionGraph, motion: Motion, nodes, edges, body: Body) -> np.ndarray:
        """(T, V) the search's own frames as unit values: their local poses, the path's
        steps and turns, its contacts."""
        d = body.layout.dims
        T = nodes.size
        out = np.zeros((T, d + 5))
        out[:, :d] = pose_vectors(
            motion.rotations.astype(np.float64), motion.translations.astype(np.float64), body.parents, body.layout
        )
        out[1:, d : d + 2] = np.asarray(graph.edge_offset)[edges]
        out[1:, d + 2] = np.asarray(graph.edge_heading)[edges]
        out[:, d + 3 : d + 5] = np.asarray(graph.node_contacts)[nodes]
        return out

    @staticmethod
    def _assemble(
        graph: MotionGraph,
        body: Body,
        values,
        trans_of,
        entered,
        units,
        inp: PreparedInput,
        options: Options,
        searched: Motion | None,
    ) -> Motion:
        """The units' values blended at their cuts and put on the root's track; with the
        search's motion, the feet held while the units say they are planted (moving as
        the search's planted feet move: `synthesis.foot_hold`)."""
        rate = float(graph.rate_hz)
        d = body.layout.dims
        T = values.shape[0]
        rot, _, rel, height = local_frames(values, body)
        trans = trans_of.copy()
        cuts = np.array(sorted({u.lo for u in units if 0 < u.lo < T}), np.int64)
        if cuts.size:
            e_rot, _, e_rel, e_height = local_frames(entered[cuts], body)
            blend_cuts(
                rot,
                trans,
                rel,
                height,
                path_tables(graph).below,
                cuts,
                e_rot,
                trans[cuts],
                e_rel,
                e_height,
                BLEND_S,
                rate,
            )
        position, heading = tracked_streams(options, inp.position, inp.heading)
        state = _Track(options, rate, *start_state(position, heading, rate))
        ground, turning = np.empty((T, 2)), np.empty(T)
        for t in range(T):
            state.t = t
            advance_own_track(
                state,
                values[t, d : d + 2],
                float(values[t, d + 2]),
                values[t, d + 3 : d + 5] > 0.5,
                None if position is None else position[t],
                None if heading is None else heading[t],
            )
            ground[t], turning[t] = state.ground, state.heading
        rot, trans = placed(rot, trans, rel, height, ground, turning, body)
        shift_to_smoothed(state.track_inputs, state.track_model, body.parents, trans)
        rot, trans = smooth_poses(rot, trans, options.shared.smooth_s * rate)
        if searched is not None:
            hold = FootHold(graph.skeleton, rate, graph.params.get("mapping"))
            rot = hold.apply(rot, trans, searched.rotations, searched.translations, values[:, d + 3 : d + 5] > 0.5)
        return Motion(graph.skeleton, rot, trans, rate, name="synthesized", source="multilinear")


class _Track:
    """The root's own track, one frame at a time (`synthesis.track.advance_own_track`)."""

    def __init__(self, options: Options, rate: float, ground0, heading0: float):
        self.alpha = track_pull(options.shared.track_pull_s, rate)
        self.track_model = (
            TrackModel(options.shared.track_sigma_m, options.shared.track_drift, rate)
            if options.weights.position
            else None
        )
        self.filter = None if self.track_model is None else FixedLagSmoother(self.track_model, 0)
        self.track_inputs: list | None = [] if self.track_model is not None else None
        self.t = 0
        self.own = np.asarray(ground0, dtype=np.float64).copy()
        self.ground = self.own
        self.heading = float(heading0)
        self.placed = self.heading_placed = False


class MultilinearSession(LiveSession):
    """Refused (module docstring): opening one raises InputError."""

    def _open(self, allowed, threads: bool) -> None:
        raise InputError(LIVE_REFUSAL)

    def _decode(self, acc, position, heading, markers=None, up=None):
        raise InputError(LIVE_REFUSAL)

    def _finish(self):
        return []


MultilinearStrategy.session_class = MultilinearSession
STRATEGY = MultilinearStrategy()

"""The SSG strategy behind the common interface (Tautges 2012, ch. 4): full-body motion
from sparse, gappy optical markers, by a subsequence graph over the knowledge base.

Input: labelled marker positions (a recording's markers) and a marker set naming each
marker's segment and offset (`sensors.markers`): the options' `markers`, else the set
the recording names. Markers the set does not define are ignored (the report lists
them). Per window of the input the k best subsequences of the knowledge base are
retrieved by subsequence DTW (`dtw`), joined into the subsequence graph (`graph`), and
the cheapest path is played with a cross-fade over each overlap (`synthesis`); gaps of
half a window or more are bridged by extending the subsequences on either side
(`decoder`). Real markers' offsets are fitted to the input first (`offsets`).

Batch and live run one decoder (`decoder.SsgDecoder`): batch without a lag finds the
cheapest path over the whole input; with `latency_s` (and live) each window is
committed a fixed number of windows later, and a live stream's frames equal the
batch's with the same lag.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace

import numpy as np

from graphsvc.errors import GraphsvcError, InputError, SearchCancelled
from graphsvc.graph.derived import derived
from graphsvc.graph.model import MotionGraph
from graphsvc.motion.skeleton import Motion
from graphsvc.sensors.markers import PRESETS as MARKER_PRESETS
from graphsvc.sensors.markers import TRUNK_SEGMENTS, MarkerSet, keep_markers, load_marker_set, marker_set_from_dict
from graphsvc.sensors.simulate import simulate_marker_recording
from graphsvc.strategies.base import Strategy, prepared_index
from graphsvc.strategies.inputs import PreparedInput
from graphsvc.strategies.live import LiveSession
from graphsvc.strategies.options import Options, on_field
from graphsvc.strategies.results import Provenance, Reconstruction, label_runs
from graphsvc.strategies.ssg import dtw
from graphsvc.strategies.ssg.decoder import SsgDecoder, Windows
from graphsvc.strategies.ssg.graph import BACKWARD, FORWARD, RETRIEVED
from graphsvc.strategies.ssg.index import SsgIndex, WindowPoints, load_index, point_window, window_points
from graphsvc.strategies.ssg.offsets import FIT_ROUNDS, FIT_SETTLED_M, FIT_SPAN_S, fit_offsets, fitted_set
from graphsvc.strategies.ssg.options import SsgOptions, parse_marker_set
from graphsvc.strategies.ssg.synthesis import poses, provenance

# A knowledge-base cloud holds at most this many points (markers × frames of the point
# window): with many markers the window keeps fewer frames (its ends, its centre).
MAX_POINTS = 64


def used_markers(options: SsgOptions, names: tuple, meta: dict | None) -> tuple[MarkerSet, np.ndarray, list, list]:
    """The marker set the input is matched with and how: (the set's kept markers the
    input has, in the set's order; their columns in the input (M,); the input's
    markers the set does not define; kept markers the input lacks)."""
    if options.markers is not None:
        marker_set = parse_marker_set(options.markers)
    elif meta and isinstance(meta.get("marker_set"), dict):
        marker_set = marker_set_from_dict(meta["marker_set"], "the recording's marker set")
    else:
        raise InputError(
            "strategy 'ssg' needs a marker set: give --markers (hands-feet, left-foot, head-back, vicon, "
            "or a marker set file)"
        )
    marker_set = keep_markers(marker_set, options.keep)
    have = {n: k for k, n in enumerate(names)}
    kept = [m for m in marker_set.markers if m.name in have]
    missing = [m.name for m in marker_set.markers if m.name not in have]
    if not kept:
        raise InputError(
            f"the input has none of the markers of set {marker_set.name!r} "
            f"({', '.join(marker_set.marker_names[:8])}{' …' if len(marker_set.markers) > 8 else ''}); "
            f"it has {', '.join(names[:8]) or 'none'}"
        )
    used = MarkerSet(marker_set.name, tuple(kept))
    ignored = [n for n in names if n not in used.marker_names]
    return used, np.array([have[m.name] for m in kept], dtype=np.int64), ignored, missing


def windows_for(marker_set: MarkerSet, options: SsgOptions, rate_hz: float) -> tuple[Windows, SsgOptions]:
    """N, o, k and the weight at the graph rate (`SsgOptions.resolved`)."""
    o = options.resolved(all(m.segment in TRUNK_SEGMENTS for m in marker_set.markers))
    if o.overlap_s > 0.5 * o.window_s:
        raise InputError(f"SSG overlap ({o.overlap_s:g} s) must be at most half the window ({o.window_s:g} s)")
    n = max(2, int(round(o.window_s * rate_hz)))
    overlap = min(int(round(o.overlap_s * rate_hz)), n // 2)
    return Windows(n, overlap, int(o.k), float(o.weight)), o


def lag_windows(latency_s: float | None, w: Windows, rate_hz: float, ahead: int) -> int | None:
    """Windows L a committed one waits for, the fewest so that a frame is final within
    `latency_s`: the first frame of window c comes out when window c + L + 1 is
    searched, `ahead` frames after its last is in, so a frame waits at most
    `lag_frames(L)` = (L + 1) · step + N − 1 + ahead frames (at least a window, a step and
    `ahead`, whatever the latency)."""
    if latency_s is None:
        return None
    return max(0, int(math.ceil((latency_s * rate_hz - w.n + 1 - ahead) / w.step - 1e-9)) - 1)


def lag_frames(lag: int, w: Windows, ahead: int) -> int:
    return (lag + 1) * w.step + w.n - 1 + ahead


def looks_ahead(rate_hz: float) -> int:
    """Frames a local cost's point cloud reaches past its frame (`index.point_window`)."""
    return point_window(rate_hz)[0]


def _prepared_markers(graph: MotionGraph, index: SsgIndex, marker_set: MarkerSet, local: np.ndarray | None):
    """The knowledge base's markers (F, M, 3) and their window clouds, once per graph,
    set and offsets."""
    key = (
        "ssg markers",
        json.dumps(marker_set.to_dict(), sort_keys=True),
        None if local is None else np.round(local, 9).tobytes(),
    )

    def make():
        kb_markers = index.markers(marker_set, local)
        h, _ = point_window(float(graph.rate_hz))
        return kb_markers, window_points(index, kb_markers, h, MAX_POINTS)

    return derived(graph, key, make)


class SsgStrategy(Strategy):
    name = "ssg"
    needs = frozenset({"markers"})
    uses = frozenset({"markers"})
    summary = "sparse, gappy optical markers: the subsequences of the knowledge base that fit each window, joined"
    options_class = SsgOptions

    def prepare(self, graph: MotionGraph) -> SsgIndex:
        return load_index(graph)

    def warm_up(self, index, graph: MotionGraph, threads: bool = False) -> None:
        warm_up()

    def ignored_options(self, options: Options) -> list[str]:
        out = ["heading_from_track"] if options.heading_from_track else []
        return sorted(out + super().ignored_options(options))

    def options_for_recording(self, options: Options, rec) -> Options:
        """The marker set the recording names when the options name none, and "auto"
        offsets as "nominal" for a recording graphsvc simulated (auto fits the offsets
        unless it was): what the recording's provenance decides, for a client that does
        not send it."""
        o = self.own(options)
        meta = rec.meta or {}
        if o.markers is None and isinstance(meta.get("marker_set"), dict):
            o = replace(o, markers=json.dumps(meta["marker_set"], sort_keys=True))
        if o.offsets == "auto" and meta.get("simulated"):
            o = replace(o, offsets="nominal")
        return replace(options, own=o)

    def describe_lag(self, rate_hz: float) -> str:
        return "within S (at least a window and a step)"

    def to_wire(self, own: SsgOptions) -> SsgOptions:
        """A marker set that is neither a built-in name nor JSON text is a file on this
        side: sent as its JSON."""
        text = None if own.markers is None else own.markers.strip()
        if text is None or text.startswith("{") or text in MARKER_PRESETS:
            return own
        return replace(own, markers=json.dumps(load_marker_set(text).to_dict(), sort_keys=True))

    def check_wire(self, values: dict, chosen: bool) -> None:
        text = values.get("markers")
        if text is None:
            if chosen:  # (the library would take the recording's own set, which does not cross the wire)
                raise on_field(
                    InputError(
                        f"strategy {self.name!r} needs a marker set: a built-in name "
                        f"({', '.join(MARKER_PRESETS)}) or a marker set as JSON"
                    ),
                    "markers",
                )
            return
        if isinstance(text, str) and not text.strip().startswith("{") and text.strip() not in MARKER_PRESETS:
            raise on_field(
                InputError(
                    f"unknown marker set {text!r}: not a built-in set ({', '.join(MARKER_PRESETS)}) "
                    "nor a marker set as JSON (the server reads no files)"
                ),
                "markers",
            )

    def check_stream(self, options: Options, sensor_names, marker_names) -> None:
        if not marker_names:
            raise on_field(
                InputError(f"strategy {self.name!r} needs the names of the markers the stream carries"), "marker_names"
            )
        if self.own(options).offsets == "fit":
            raise InputError(
                "SSG offsets 'fit' needs the whole input: fit them in a batch run (its report's "
                "fitted_marker_set) and stream with that set"
            )
        try:
            used_markers(self.own(options), tuple(marker_names), None)
        except GraphsvcError as exc:  # none of the set's (kept) markers among the stream's
            raise on_field(exc, "marker_names") from None

    def check_simulation(self, options: Options) -> None:
        if not self.own(options).markers:
            raise InputError(f"--strategy {self.name} reads optical markers: give the set to simulate, --markers")

    def simulate_input(
        self, motion, layout, options: Options, noise, seed: int, rate_hz: float, mapping=None, pattern=None
    ):
        """The markers of the options' set (those kept) lost to `pattern`."""
        self.check_simulation(options)
        o = self.own(options)
        kwargs = {} if pattern is None else {"pattern": pattern}
        return simulate_marker_recording(
            motion,
            load_marker_set(o.markers),
            noise,
            seed=seed,
            rate_hz=rate_hz,
            mapping=mapping,
            keep=o.keep,
            **kwargs,
        )

    def describe_input(self, options: Options, noise, pattern=None) -> str:
        o = self.own(options)
        kept = f" ({','.join(o.keep)})" if o.keep else ""
        text = f"markers {o.markers}{kept}, σ {noise.marker:g} mm"
        if pattern is not None:
            text += (
                (f", {100 * pattern.gap_fraction:g} % in gaps" if pattern.gap_fraction else "")
                + (f", gaps {pattern.gaps}" if pattern.gaps else "")
                + (f", flicker {100 * pattern.flicker:g} %" if pattern.flicker else "")
            )
        return text

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
        t0 = time.perf_counter()
        warm_up()
        idx = index.with_allowed(allowed)
        if idx.searchable == 0:
            raise InputError("every knowledge-base frame is hidden: nothing to search")
        own = self.own(options)
        used, columns, ignored, missing = used_markers(own, inp.marker_names, inp.meta)
        points = np.asarray(inp.markers, dtype=np.float64)[:, columns]
        seen = np.isfinite(points).all(axis=-1)
        if not seen.any():
            raise InputError(f"every kept marker ({', '.join(used.marker_names)}) is missing for the whole input")
        points = np.where(seen[..., None], points, 0.0)
        rate = float(graph.rate_hz)
        w, resolved = windows_for(used, own, rate)
        lag = lag_windows(options.latency_s, w, rate, looks_ahead(rate))
        mode = own.offsets
        fit = mode == "fit" or (mode == "auto" and not inp.meta.get("simulated"))
        warm_up_s = time.perf_counter() - t0

        t0 = time.perf_counter()
        decoder = _run(graph, idx, used, None, w, lag, points, seen, should_stop)
        offsets_report = {"mode": "fit" if fit else "nominal"}
        if fit:
            span = min(len(points), max(w.n, int(round(FIT_SPAN_S * rate))))
            per_frame, carrier = idx.marker_locals(used)
            nominal = local = per_frame[0]
            for rounds in range(1, FIT_ROUNDS + 1):
                a, f, wt = decoder.sources(0, span)
                fitted = fit_offsets(idx, carrier, nominal, points[:span], seen[:span], decoder.anchors, a, f, wt)
                moved = float(np.abs(fitted - local).max())
                local = fitted
                decoder = _run(graph, idx, used, local, w, lag, points, seen, should_stop)
                if moved < FIT_SETTLED_M:
                    break
            offsets_report.update(
                {
                    "rounds": rounds,
                    "fitted_on_s": round(span / rate, 3),
                    "moved_cm": {
                        m.name: round(float(np.linalg.norm(local[j] - nominal[j])) * 100.0, 2)
                        for j, m in enumerate(used.markers)
                    },
                    "fitted_marker_set": fitted_set(used, local).to_dict(),
                }
            )
        search_s = time.perf_counter() - t0

        t0 = time.perf_counter()
        T = points.shape[0]
        a, f, wt = decoder.sources(0, T)
        rot, trans = poses(graph, idx, decoder.anchors, a, f, wt)
        clip, frame, weight, labels = provenance(graph, idx, a, f, wt)
        motion = Motion(graph.skeleton, rot, trans, rate, name="synthesized", source="ssg")
        synth_s = time.perf_counter() - t0
        report = _report(
            decoder,
            used,
            resolved,
            w,
            lag,
            ignored,
            missing,
            offsets_report,
            seen,
            labels,
            idx,
            warm_up_s,
            search_s,
            synth_s,
        )
        return Reconstruction(motion, None, None, report, Provenance(clip, frame, weight, labels))


def _run(graph, idx, used, local, w, lag, points, seen, should_stop) -> SsgDecoder:
    kb_markers, kb = _prepared_markers(graph, idx, used, local)
    decoder = SsgDecoder(idx, kb_markers, kb, w, float(graph.rate_hz), lag, expected_frames=len(points))
    # The whole input at once lets the local costs come in blocks of rows (a wider
    # matrix product is cheaper a row); with a lag, frame by frame as a live stream
    # arrives, so the rows — and the frames — are the live ones bit for bit (a BLAS
    # product's rounding depends on its width).
    block = 256 if lag is None else 1  # (a cancelled client is noticed within a block)
    for t in range(0, len(points), block):
        if should_stop is not None and t % 256 == 0 and should_stop():
            raise SearchCancelled("reconstruction cancelled")
        decoder.push(points[t : t + block], seen[t : t + block])
    decoder.finish()
    return decoder


def _report(
    decoder: SsgDecoder,
    used: MarkerSet,
    o: SsgOptions,
    w: Windows,
    lag,
    ignored,
    missing,
    offsets,
    seen,
    labels,
    idx: SsgIndex,
    warm_up_s,
    search_s,
    synth_s,
) -> dict:
    """The report of an SSG run (docs/ssg.md)."""
    path = []
    node_cost = transition = 0.0
    for z, node in enumerate(decoder.path):
        layer = decoder.layers[z]
        A = decoder.anchors[int(layer.anchor[node])]
        frames = A.frames_at(np.arange(layer.start, layer.stop))
        node_cost += float(layer.cost[node])
        if z:
            transition += float(decoder.edges[z - 1][decoder.path[z - 1], node])
        path.append(
            {
                "start_frame": layer.start,
                "frames": layer.stop - layer.start,
                "kind": ("retrieved", "forward", "backward")[int(layer.kind[node])],
                "clip": int(idx.clip[int(frames[0])]),
                "clip_frames": [
                    round(float(idx.clip_frame[int(frames[0])] + frames[0] % 1), 2),
                    round(float(idx.clip_frame[int(frames[-1])] + frames[-1] % 1), 2),
                ],
                "cost": round(float(layer.cost[node]), 8),
            }
        )
    kinds = [layer.kind for layer in decoder.layers]
    T = seen.shape[0]
    total = search_s
    return {
        "cost": node_cost + w.weight * transition,
        "terms": {"node_m2": node_cost, "transition_m2": transition},
        "ssg": {
            "marker_set": used.name,
            "markers": list(used.marker_names),
            "window_frames": w.n,
            "overlap_frames": w.o,
            "k": w.k,
            "weight": w.weight,
            "window_s": round(o.window_s, 6),
            "overlap_s": round(o.overlap_s, 6),
            "lag_windows": lag,
            "offsets": offsets,
        },
        "windows": len(decoder.layers),
        "blind_windows": int(sum(layer.blind for layer in decoder.layers)),
        "nodes": {
            "retrieved": int(sum((k == RETRIEVED).sum() for k in kinds)),
            "forward": int(sum((k == FORWARD).sum() for k in kinds)),
            "backward": int(sum((k == BACKWARD).sum() for k in kinds)),
        },
        "dtw_cells": int(decoder.cells),
        "seen": round(float(seen.mean()), 4),
        "ignored_markers": ignored,
        "missing_markers": missing,
        "candidate_frames": idx.searchable,
        "path": path,
        "labels": label_runs(list(labels)),
        "timings_s": {"warm_up": round(warm_up_s, 4), "search": round(search_s, 4), "synthesis": round(synth_s, 4)},
        "samples_per_s": round(T / max(total, 1e-9), 1),
    }


_warmed = False


def warm_up() -> None:
    """Load the compiled kernels (numba compiles them on a fresh install) on a toy case."""
    global _warmed
    if _warmed:
        return
    F, P = 16, 6
    rng = np.random.default_rng(0)
    pts = rng.standard_normal((4, F, P)).astype(np.float32)
    kb = WindowPoints(pts[0], pts[1], pts[2], np.abs(pts[3]), np.array([-1, 0, 1]), np.ones(3))  # (P = 3 · 2)
    points = rng.standard_normal((5, 2, 3))
    seen = np.ones((5, 2), dtype=bool)
    C = dtw.local_costs(kb, points, seen, np.arange(5), np.ones(F, dtype=bool))
    D = np.empty(C.shape)
    step = np.empty(C.shape, dtype=np.int8)
    run_start = np.zeros(F, dtype=bool)
    run_start[0] = True
    dtw.subsequence_dtw(C, run_start, D, step)
    dtw.k_best(D, step, 2)
    _warmed = True


class SsgSession(LiveSession):
    """SSG live: marker samples in; each window is committed once `lag` more windows
    are in (options.latency_s, default LiveSession.DEFAULT_LATENCY_S), its frames out
    then. Offsets are the set's own (a fitted set from a batch run's report can be
    passed as the marker set)."""

    def _open(self, allowed, threads: bool) -> None:
        graph, options = self.graph, self.options
        index = prepared_index(self.strategy, graph).with_allowed(allowed)
        self.used, self.columns, self.ignored, self.missing = used_markers(self.own, self.marker_names, None)
        self.windows, _ = windows_for(self.used, self.own, self.rate)
        latency = self.DEFAULT_LATENCY_S if options.latency_s is None else options.latency_s
        lag = lag_windows(latency, self.windows, self.rate, looks_ahead(self.rate))
        kb_markers, kb = _prepared_markers(graph, index, self.used, None)
        warm_up()
        self.index = index
        self.decoder = SsgDecoder(index, kb_markers, kb, self.windows, self.rate, lag, prune=True)
        self.lag_frames = lag_frames(lag, self.windows, self.decoder.ahead)
        self.any_seen = False

    def _decode(self, acc, position, heading, markers=None, up=None):
        points = np.asarray(markers, dtype=np.float64)[self.columns]
        seen = np.isfinite(points).all(axis=-1)
        self.any_seen |= bool(seen.any())
        return self._frames(self.decoder.push(np.where(seen[:, None], points, 0.0), seen))

    def _frames(self, ranges):
        out = []
        for a, b in ranges:
            an, f, wt = self.decoder.sources(a, b)
            rot, trans = poses(self.graph, self.index, self.decoder.anchors, an, f, wt)
            clip, frame, weight, labels = provenance(self.graph, self.index, an, f, wt)
            out += self._emit(a, rot, trans, provenance=Provenance(clip, frame, weight, labels))
        return out

    def _finish(self):
        if not self.any_seen:  # (as a batch run refuses such a recording; a stream can only tell at its end)
            raise on_field(
                InputError(
                    f"every kept marker ({', '.join(self.used.marker_names)}) is NaN in all "
                    f"{self.samples_in} samples: nothing to match"
                ),
                "marker_positions_m",
            )
        return self._frames(self.decoder.finish())


SsgStrategy.session_class = SsgSession
STRATEGY = SsgStrategy()

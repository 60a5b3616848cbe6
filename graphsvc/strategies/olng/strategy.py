"""The OLNG strategy behind the common interface: batch and live run one decoder
(`decoder.OlngDecoder`) sample by sample, so a live session's frames are the batch's,
each emitted as its sample arrives (the steps look back only: no look-ahead).

Index: `index.load_index` (cached beside the graph file); hidden clips are dropped at
query time. Its own options: `options.OlngOptions` (K, M, I, the step set, the energy weights, foot
clean-up); the root is fused with the tracker's positions with the shared `track_sigma_m` and
`track_drift` (`synthesis.track`: a Kalman filter live, and in batch the smoother over the
whole recording, unless `latency_s` asks for what a live client gets), the heading pulled
with `track_pull_s`; a batch run without `latency_s` filters the poses (`smooth_s`,
`synthesis.smooth`), which a live frame, final as its sample arrives, cannot be; a
weight of 0 for position or heading leaves that stream out.
"""

from __future__ import annotations

import time

import numpy as np

from graphsvc.errors import InputError, SearchCancelled
from graphsvc.graph.model import MotionGraph
from graphsvc.motion.skeleton import Motion
from graphsvc.strategies.base import Strategy, prepared_index
from graphsvc.strategies.inputs import PreparedInput, tracked_streams
from graphsvc.strategies.live import LiveSession
from graphsvc.strategies.olng.decoder import SOURCES, OlngDecoder
from graphsvc.strategies.olng.index import OlngIndex, load_index
from graphsvc.strategies.olng.options import OlngOptions
from graphsvc.strategies.olng.pose import pose_model
from graphsvc.strategies.options import Options, track_pull
from graphsvc.strategies.results import Provenance, Reconstruction, label_runs
from graphsvc.synthesis.sensor_orientations import clip_sensor_placements, imposes
from graphsvc.synthesis.smooth import smooth_poses
from graphsvc.synthesis.track import TrackModel, shift_to_smoothed


def resolved_options(index: OlngIndex, options: OlngOptions) -> OlngOptions:
    """K and I filled in for the index, and checked against what it can return."""
    o = options.resolved(index.searchable)
    if o.k > index.searchable:
        raise InputError(f"OLNG K ({o.k}) exceeds the knowledge base's {index.searchable} searchable frames")
    if o.i > o.k:
        raise InputError(f"OLNG I ({o.i}) must not exceed K ({o.k})")
    return o


def make_decoder(graph: MotionGraph, index: OlngIndex, options: Options, own: OlngOptions) -> OlngDecoder:
    rate = float(graph.rate_hz)
    model = (
        TrackModel(options.shared.track_sigma_m, options.shared.track_drift, rate) if options.weights.position else None
    )
    decoder = OlngDecoder(
        graph,
        index,
        pose_model(graph),
        resolved_options(index, own),
        track_pull(options.shared.track_pull_s, rate),
        model,
    )
    decoder.up_weight = float(options.weights.orientation)  # (used where the samples carry the orientation cue)
    decoder.impose = decoder.up_weight > 0 and imposes(graph)
    if decoder.impose:
        clip_sensor_placements(graph)  # (made now, not on the first sample)
    return decoder


class OlngStrategy(Strategy):
    name = "olng"
    needs = frozenset({"accelerations"})
    uses = frozenset({"accelerations", "orientations", "ground_position", "heading"})
    summary = "per sample the neighbourhood of knowledge-base frames moving as the readings do, and an optimised pose"
    options_class = OlngOptions
    # (the heading's pull, the root's fusion, the poses' filter in batch)
    shared = frozenset({"track_pull_s", "track_sigma_m", "track_drift", "smooth_s"})

    def prepare(self, graph: MotionGraph) -> OlngIndex:
        return load_index(graph)

    def warm_up(self, index, graph: MotionGraph, threads: bool = False) -> None:
        warm_up(graph, index)

    def ignored_options(self, options: Options) -> list[str]:
        # Every frame is final as its sample arrives; a latency asks for what a live client
        # gets: the tracker filtered, not smoothed over the whole recording, and the poses
        # not filtered.
        out = []
        if options.weights.acc != 1.0:
            out.append("weights.acc")  # (its own energy weights: olng)
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
        t0 = time.perf_counter()
        idx = index.with_allowed(allowed)
        decoder = make_decoder(graph, idx, options, self.own(options))
        if options.latency_s is None:
            decoder.track_inputs = []  # (for the smoother over the whole recording)
        up = inp.up if options.weights.orientation > 0 else None
        if up is not None:
            idx.oriented_tree(decoder.up_weight)  # (made once per weight, with the warm-up's time)
        warm_up(graph, index)
        warm_up_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        position, heading = tracked_streams(options, inp.position, inp.heading)
        T = inp.num_samples
        J = graph.skeleton.num_joints
        rot, trans = np.empty((T, J, 4)), np.empty((T, J, 3))
        clip, frame, weight = np.full((T, SOURCES), -1, np.int64), np.zeros((T, SOURCES)), np.zeros((T, SOURCES))
        labels, rows = [], []
        for t in range(T):
            if should_stop is not None and t % 64 == 0 and should_stop():
                raise SearchCancelled("reconstruction cancelled")
            r, tr, sources, label, row = decoder.step(
                inp.acc[t],
                None if position is None else position[t],
                None if heading is None else heading[t],
                None if up is None else up[t],
            )
            rot[t], trans[t] = r[0], tr[0]
            for k, (c, f, w) in enumerate(sources):
                clip[t, k], frame[t, k], weight[t, k] = c, f, w
            labels.append(label)
            rows.append(row)
        smooth_root(decoder, trans)
        if options.latency_s is None:  # (live frames are final as they come: no filter over later ones)
            rot, trans = smooth_poses(rot, trans, options.shared.smooth_s * float(graph.rate_hz))
        total_s = time.perf_counter() - t0
        motion = Motion(graph.skeleton, rot, trans, float(graph.rate_hz), name="synthesized", source="olng")
        provenance = Provenance(clip, frame, weight, np.asarray(labels, dtype=object))
        return Reconstruction(motion, None, None, report(decoder, rows, labels, warm_up_s, total_s), provenance)


def smooth_root(decoder: OlngDecoder, trans: np.ndarray) -> None:
    """A batch run's root, in place on translations (T, J, 3): each frame shifted from the
    tracker's filtered offset, which a live frame gets, to the smoother's over the whole
    recording (`synthesis.track`), the whole body at once."""
    shift_to_smoothed(decoder.track_inputs, decoder.track_model, decoder.parents, trans)


def report(decoder: OlngDecoder, rows: list[dict], labels: list, warm_up_s: float, total_s: float) -> dict:
    """The report of an OLNG run (README, *Report*)."""
    o = decoder.options
    T = len(rows)

    def col(name):
        return np.array([r[name] for r in rows], dtype=np.float64)

    # search: the neighbours and the lattice; synthesis: the pose, root and feet.
    search_s = float(np.sum(col("nn_ms")) + np.sum(col("olng_ms"))) / 1e3 if T else 0.0
    timings = {
        "warm_up": round(warm_up_s, 4),
        "search": round(search_s, 4),
        "synthesis": round(max(total_s - search_s, 0.0), 4),
    }
    for name in ("nn_ms", "olng_ms", "optimise_ms"):
        timings[f"median_{name}"] = round(float(np.median(col(name))), 3) if T else 0.0
    return {
        "cost": float(col("cost").sum()) if T else 0.0,
        "terms": {
            "path_cost": float(col("cost").sum()) if T else 0.0,
            "energy": float(col("energy").sum()) if T else 0.0,
        },
        "olng": {
            "k": o.k,
            "i": o.i,
            "m": o.m,
            "extended": o.extended,
            "w_prior": o.w_prior,
            "w_contr": o.w_contr,
            "w_pose": o.w_pose,
            "w_motion": o.w_motion,
            "w_smooth": o.w_smooth,
            "fix_feet": o.fix_feet,
            "track_pull_alpha": round(decoder.alpha, 6),
        },
        **(
            {
                "track": {
                    "sigma_m": decoder.track_model.sigma_m,
                    "drift": decoder.track_model.drift,
                    "smoothed": decoder.track_inputs is not None,
                }
            }
            if decoder.track_model
            else {}
        ),
        "candidate_frames": int(decoder.index.searchable),
        "per_frame": {
            "path_cost": [round(v, 5) for v in col("cost")],
            "energy": [round(v, 5) for v in col("energy")],
            "path_length": [round(v, 3) for v in col("path_length")],
            "subspace_dims": [int(v) for v in col("subspace")],
            "iterations": [int(v) for v in col("iterations")],
            "dropped": [int(v) for v in col("dropped")],
        },
        "mean_path_length": round(float(col("path_length").mean()), 3) if T else 0.0,
        "incomplete_samples": int(sum(not r["complete"] for r in rows)),
        "labels": label_runs(labels),
        "timings_s": timings,
        "samples_per_s": round(T / max(total_s, 1e-9), 1),
    }


def warm_up(graph: MotionGraph, index: OlngIndex) -> None:
    """Run a few samples through a decoder, so numba loads every kernel now."""
    if getattr(index, "_warmed", False):
        return
    o = OlngOptions(k=min(8, index.frames), i=min(4, index.frames), m=4)
    decoder = OlngDecoder(graph, index, pose_model(graph), o, 0.1, TrackModel(0.1, 0.3, float(graph.rate_hz)))
    reading = np.asarray(index.readings[min(2, index.frames - 1)], dtype=np.float64).reshape(-1, 3) * 9.81
    decoder.track_inputs = []
    for t in range(3):
        decoder.step(reading, np.zeros(2), 0.0)
    smooth_root(decoder, np.zeros((3, graph.skeleton.num_joints, 3)))
    index._warmed = True


class OlngSession(LiveSession):
    """OLNG live: each grid sample's frame as it arrives (lag 0)."""

    def _open(self, allowed, threads: bool) -> None:
        graph, options = self.graph, self.options
        index = prepared_index(self.strategy, graph)
        self.decoder = make_decoder(graph, index.with_allowed(allowed), options, self.own)
        if self.reads_up:
            self.decoder.index.oriented_tree(self.decoder.up_weight)  # (made now, not on a client's first sample)
        warm_up(graph, index)
        self.lag_frames = 0
        self.frame_index = 0

    def _decode(self, acc, position, heading, markers=None, up=None):
        position, heading = tracked_streams(self.options, position, heading)
        rot, trans, sources, label, _ = self.decoder.step(acc, position, heading, up)
        clip = np.full((1, SOURCES), -1, np.int64)
        frame, weight = np.zeros((1, SOURCES)), np.zeros((1, SOURCES))
        for k, (c, f, w) in enumerate(sources):
            clip[0, k], frame[0, k], weight[0, k] = c, f, w
        out = self._emit(
            self.frame_index, rot, trans, provenance=Provenance(clip, frame, weight, np.array([label], object))
        )
        self.frame_index += 1
        return out

    def _finish(self):
        return []


OlngStrategy.session_class = OlngSession
STRATEGY = OlngStrategy()

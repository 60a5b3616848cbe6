"""The piecewise strategy behind the common interface: batch and live run one decoder
(`PiecewiseDecoder`) sample by sample, so a live session's frames are the batch's,
each emitted as its sample arrives (nothing looks ahead: lag 0).

Per sample: its cluster (the mixture's marginal over the readings), the cluster's RBF
map (the reduced pose, the root's step, turn and foot contacts), and with
`--piecewise-method optimise` the pose of eq. 6.2–6.4 instead (`model`). The pose is
put on the skeleton at the root's own track: the predicted steps integrated from the
first measured position and heading; with a tracker the offset to its positions is
Kalman-filtered (`synthesis.track`, the shared `track_sigma_m` and `track_drift`; it
moves while a predicted foot is free) and the heading pulled toward the measured one
(`track_pull_s`), as the other per-frame strategies do. A batch run without
`latency_s` smooths the root offsets over the whole recording and filters the poses
(`smooth_s`); with one it is what a live client gets. A sample with a sensor missing
repeats the previous frame's pose and step (the first: the largest cluster's mean).

Index: the knowledge-base frames' readings, poses and steps (`model.frame_data`),
cached beside the graph; the model learned from the frames a run may use, cached
beside it too, one file per hold-out and options (`model.model_key`).
"""

from __future__ import annotations

import time

import numpy as np

from graphsvc.errors import SearchCancelled
from graphsvc.graph.derived import derived
from graphsvc.graph.model import MotionGraph
from graphsvc.graph.poses import node_rotations, node_translations
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.motion.placement import place_poses
from graphsvc.motion.skeleton import Motion
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.strategies.base import Strategy, prepared_index
from graphsvc.strategies.index import cached_arrays
from graphsvc.strategies.inputs import PreparedInput, tracked_streams
from graphsvc.strategies.live import LiveSession
from graphsvc.strategies.options import Options, track_pull
from graphsvc.strategies.piecewise.model import Model, check_against, frame_data, learn, model_key, training_rows
from graphsvc.strategies.piecewise.options import PiecewiseOptions
from graphsvc.strategies.results import Provenance, Reconstruction, label_runs
from graphsvc.synthesis.local_pose import pose_layout
from graphsvc.synthesis.smooth import smooth_poses
from graphsvc.synthesis.track import FixedLagSmoother, TrackModel, advance_own_track, shift_to_smoothed

INDEX_VERSION = 1


def learned_model(graph: MotionGraph, data: dict, own: PiecewiseOptions, allowed=None) -> dict:
    """The model's arrays for these options and allowed nodes: from the cache beside the
    graph (learned and written there the first time), held for the graph object."""
    return _learned(graph, data, own, training_rows(data, allowed))[0]


def shared_model(graph: MotionGraph, data: dict, own: PiecewiseOptions, allowed=None) -> Model:
    """The Model of `learned_model` with what a sample reads of it made (its kd-trees,
    the optimisation's inverses), once a graph, options and hold-out: it keeps no
    stream's state, so every decoder of this process shares it."""
    rows = training_rows(data, allowed)
    arrays, key = _learned(graph, data, own, rows)
    return derived(
        graph,
        ("piecewise decoder model", key, own.w_smooth, own.w_control, own.assign),
        lambda: Model(arrays, np.asarray(data["readings"])[rows], own.w_smooth, own.w_control, own.assign),
    )


def _learned(graph: MotionGraph, data: dict, own: PiecewiseOptions, rows: np.ndarray) -> tuple[dict, str]:
    check_against(own, rows.size, np.asarray(data["poses"]).shape[1])
    key = model_key(own, data, rows)
    arrays = derived(
        graph,
        ("piecewise model", key),
        lambda: cached_arrays(graph, f"piecewise-{key}", INDEX_VERSION, lambda: learn(data, rows, own)),
    )
    return arrays, key


class PiecewiseDecoder:
    """One stream's state. step(acc (S, 3) m/s², position (2,) or None, heading or None)
    → (rotations (1, J, 4), translations (1, J, 3), (clip, frame) of the nearest centre
    or None, label, row)."""

    def __init__(self, graph: MotionGraph, model: Model, options: Options, own: PiecewiseOptions):
        self.graph = graph
        self.model = model
        arrays = model.arrays
        self.method = own.method
        self.rate = float(graph.rate_hz)
        self.parents = np.ascontiguousarray(graph.skeleton.parents, dtype=np.int64)
        self.layout = pose_layout(graph.skeleton, graph.params.get("mapping"))
        node = int(np.asarray(arrays["template"])[0])
        self.template = (
            node_rotations(graph, node)[None],
            node_translations(graph, node)[None],
        )
        self.alpha = track_pull(options.shared.track_pull_s, self.rate)
        self.track_model = (
            TrackModel(options.shared.track_sigma_m, options.shared.track_drift, self.rate)
            if options.weights.position
            else None
        )
        self.filter = None if self.track_model is None else FixedLagSmoother(self.track_model, 0)
        self.track_inputs: list | None = None  # (measured − own, gate, filtered offset) a frame, for a batch's smoother
        self.t = -1
        self.last: np.ndarray | None = None  # the previous frame's outputs
        self.last_source = -1
        self.r1 = self.r2 = None
        self.own = np.zeros(2)
        self.ground = np.zeros(2)
        self.heading = 0.0
        self.placed = self.heading_placed = False
        sizes = np.diff(np.asarray(arrays["start"]))
        self.fallback = int(np.argmax(sizes))

    def step(self, acc, position=None, heading=None):
        self.t += 1
        c = np.asarray(acc, dtype=np.float64).reshape(-1) / GRAVITY
        complete = bool(np.all(np.isfinite(c)))
        m = self.model
        if complete:
            k = m.cluster(c)
            y, source = m.rbf(k, c) if self.method == "rbf-fit" else m.local(k, c)
            if self.method == "optimise":  # (the prior centred on the cluster's local estimate)
                y[: m.d] = m.optimise(k, c, self.r1, self.r2, y[: m.d].copy())
        elif self.last is not None:
            k, y, source = -1, self.last.copy(), self.last_source
        else:
            k, source = self.fallback, -1
            y = m.out_mean[k].copy()
        self.last, self.last_source = y, source
        r = y[: m.d]
        self.r2, self.r1 = self.r1, r.copy()
        step, turn, contacts = y[m.d : m.d + 2], float(y[m.d + 2]), y[m.d + 3 : m.d + 5] > 0.5
        advance_own_track(self, step, turn, contacts, position, heading)
        rot, trans = self._place(m.pose(r))
        for root in np.flatnonzero(self.parents < 0):  # onto the fused track, the whole body at once
            trans[0, root, 0] += self.ground[0] - self.own[0]
            trans[0, root, 2] += self.ground[1] - self.own[1]
        node = source
        g = self.graph
        where = None if node < 0 else (int(g.node_clip[node]), float(g.node_frame[node]))
        label = g.labels[int(g.node_label[node])] if node >= 0 else ""
        return rot, trans, where, label, {"cluster": k, "complete": complete}

    def _place(self, p: np.ndarray):
        """Local rotations and translations (1, J, 4/3) of pose vector p at the own track."""
        lay = self.layout
        rot, trans = self.template[0].copy(), self.template[1].copy()
        q = p[5:].reshape(-1, 4)
        rot[0, lay.joints] = q / np.linalg.norm(q, axis=1, keepdims=True)
        src_rot, src_pos = forward_kinematics(rot, trans, self.parents)
        rel = (p[0:4] / np.linalg.norm(p[0:4]))[None]
        place_poses(
            rot,
            trans,
            rel,
            np.array([p[4]]),
            self.own[None],
            np.array([self.heading]),
            src_rot,
            src_pos,
            self.parents,
            lay.pelvis,
            lay.carrier,
        )
        return rot, trans


class PiecewiseStrategy(Strategy):
    name = "piecewise"
    needs = frozenset({"accelerations"})
    uses = frozenset({"accelerations", "ground_position", "heading"})
    summary = "per sample a pose from its cluster's local model of the readings (Xie 2009): RBF or optimised"
    options_class = PiecewiseOptions
    shared = frozenset({"track_pull_s", "track_sigma_m", "track_drift", "smooth_s"})

    def prepare(self, graph: MotionGraph) -> dict:
        return cached_arrays(graph, self.name, INDEX_VERSION, lambda: frame_data(graph))

    def ignored_options(self, options: Options) -> list[str]:
        out = ["weights.acc"] if options.weights.acc != 1.0 else []
        return sorted(out + super().ignored_options(options))

    def decoder(self, graph: MotionGraph, index: dict, options: Options, allowed=None) -> PiecewiseDecoder:
        own = self.own(options)
        return PiecewiseDecoder(graph, shared_model(graph, index, own, allowed), options, own)

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
        decoder = self.decoder(graph, index, options, allowed)
        if options.latency_s is None:
            decoder.track_inputs = []
        learn_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        position, heading = tracked_streams(options, inp.position, inp.heading)
        T = inp.num_samples
        J = graph.skeleton.num_joints
        rot, trans = np.empty((T, J, 4)), np.empty((T, J, 3))
        clip, frame, weight = np.full((T, 1), -1, np.int64), np.zeros((T, 1)), np.zeros((T, 1))
        labels, clusters, incomplete = [], [], 0
        for t in range(T):
            if should_stop is not None and t % 256 == 0 and should_stop():
                raise SearchCancelled("reconstruction cancelled")
            r, tr, where, label, row = decoder.step(
                inp.acc[t], None if position is None else position[t], None if heading is None else heading[t]
            )
            rot[t], trans[t] = r[0], tr[0]
            if where is not None:
                clip[t, 0], frame[t, 0], weight[t, 0] = where[0], where[1], 1.0
            labels.append(label)
            clusters.append(row["cluster"])
            incomplete += not row["complete"]
        shift_to_smoothed(decoder.track_inputs, decoder.track_model, decoder.parents, trans)
        if options.latency_s is None:
            rot, trans = smooth_poses(rot, trans, options.shared.smooth_s * float(graph.rate_hz))
        total_s = time.perf_counter() - t0
        motion = Motion(graph.skeleton, rot, trans, float(graph.rate_hz), name="synthesized", source="piecewise")
        own = self.own(options)
        model = decoder.model
        arrays = decoder.model.arrays
        report = {
            "cost": 0.0,
            "piecewise": {
                "method": own.method,
                "reduce": own.reduce,
                "assign": own.assign,
                "dims": model.d,
                "clusters": model.K,
                "bic": dict(
                    zip((int(k) for k in arrays["bic_counts"]), (round(float(v), 1) for v in arrays["bic_values"]))
                ),
                "centres": int(model.centres.shape[0]),
            },
            "per_frame": {"cluster": [int(k) for k in clusters]},
            "incomplete_samples": incomplete,
            "labels": label_runs(labels),
            "timings_s": {"warm_up": round(learn_s, 4), "search": round(total_s, 4), "synthesis": 0.0},
            "samples_per_s": round(T / max(total_s, 1e-9), 1),
        }
        provenance = Provenance(clip, frame, weight, np.asarray(labels, dtype=object))
        return Reconstruction(motion, None, None, report, provenance)


class PiecewiseSession(LiveSession):
    """Piecewise live: each grid sample's frame as it arrives (lag 0)."""

    def _open(self, allowed, threads: bool) -> None:
        graph = self.graph
        self.decoder = self.strategy.decoder(graph, prepared_index(self.strategy, graph), self.options, allowed)
        self.lag_frames = 0
        self.frame_index = 0

    def _decode(self, acc, position, heading, markers=None, up=None):
        position, heading = tracked_streams(self.options, position, heading)
        rot, trans, where, label, _ = self.decoder.step(acc, position, heading)
        clip = np.array([[-1 if where is None else where[0]]], np.int64)
        frame = np.array([[0.0 if where is None else where[1]]])
        weight = np.array([[0.0 if where is None else 1.0]])
        out = self._emit(
            self.frame_index, rot, trans, provenance=Provenance(clip, frame, weight, np.array([label], object))
        )
        self.frame_index += 1
        return out

    def _finish(self):
        return []


PiecewiseStrategy.session_class = PiecewiseSession
STRATEGY = PiecewiseStrategy()

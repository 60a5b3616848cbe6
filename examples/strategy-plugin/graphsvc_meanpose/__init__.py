"""`--strategy meanpose`: the knowledge base's mean pose held for the whole input, placed
on the overhead tracker's ground position and heading where the recording has them.

A floor for every table: a strategy that does not beat holding one typical pose has
learnt nothing from the sensors. The pose is the knowledge-base frame nearest the
per-joint mean of every original frame's local rotations (the root's rotation taken
relative to the frame's heading), so it is a real pose of the knowledge base, with its
bone lengths and root height; `--meanpose-label idle` averages the frames of one
content label only (the mean standing pose). Hidden clips (a leave-out evaluation) are
left out of the mean.

A worked example of a strategy installed as its own package (docs/code-layout.md,
"Adding a strategy"): one options dataclass, one `Strategy` subclass, one live session,
and the entry point in pyproject.toml.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from graphsvc.errors import InputError
from graphsvc.graph.model import NODE_ORIGINAL, MotionGraph
from graphsvc.graph.poses import node_rotations, node_translations
from graphsvc.motion import quat
from graphsvc.motion.skeleton import Motion
from graphsvc.strategies.base import Strategy
from graphsvc.strategies.live import LiveSession
from graphsvc.strategies.options import Options, option
from graphsvc.strategies.results import Provenance, Reconstruction, label_runs


@dataclass(frozen=True)
class MeanPoseOptions:
    label: str | None = option(
        None,
        metavar="LABEL",
        help="average only the knowledge-base frames of this content label, e.g. idle (default: every frame)",
    )


def mean_pose_node(graph: MotionGraph, allowed: np.ndarray | None, label: str | None) -> int:
    """The original node nearest (summed joint angles) the per-joint mean of the
    allowed original frames' local rotations (of `label`'s clips only, when given)."""
    nodes = np.asarray(graph.node_kind) == NODE_ORIGINAL
    if allowed is not None:
        nodes &= np.asarray(allowed, dtype=bool)
    if label is not None:
        if label not in graph.labels:
            raise InputError(f"meanpose label {label!r} is not one of the graph's ({', '.join(graph.labels)})")
        nodes &= np.asarray(graph.node_label) == graph.labels.index(label)
    nodes = np.flatnonzero(nodes)
    if not nodes.size:
        raise InputError("no knowledge-base frame to average (every one hidden, or none of the label)")
    rot = node_rotations(graph, nodes)  # (K, J, 4)
    rot[:, 0] = quat.mul(quat.about_y(-np.asarray(graph.node_heading[nodes], dtype=np.float64)), rot[:, 0])
    rot *= np.sign(np.sum(rot * rot[:1], axis=-1, keepdims=True) + 1e-12)  # one hemisphere a joint
    mean = quat.normalize(rot.mean(axis=0))
    angles = 2.0 * np.arccos(np.clip(np.abs(np.sum(rot * mean, axis=-1)), 0.0, 1.0))  # (K, J)
    return int(nodes[np.argmin(angles.sum(axis=1))])


def place(graph: MotionGraph, node: int, ground: np.ndarray, heading: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Node `node`'s pose at each of T ground positions (T, 2) and headings (T,):
    rotations (T, J, 4) and translations (T, J, 3), turned and moved at the root joint."""
    T = ground.shape[0]
    rot = np.repeat(node_rotations(graph, node)[None], T, axis=0)
    trans = np.repeat(node_translations(graph, node)[None], T, axis=0)
    turn = quat.about_y(heading - float(graph.node_heading[node]))
    rot[:, 0] = quat.mul(turn, rot[:, 0])
    trans[:, 0] = quat.rotate(turn, trans[:, 0])
    g0 = np.zeros((T, 3))
    g0[:, [0, 2]] = np.asarray(graph.node_ground[node], dtype=np.float64)
    shift = -quat.rotate(turn, g0)
    shift[:, [0, 2]] += ground
    trans[:, 0, [0, 2]] += shift[:, [0, 2]]
    return rot, trans


def held(values: np.ndarray | None, T: int, width: int) -> np.ndarray:
    """(T, width) values with each missing one (NaN, or no stream) the last measured
    before it (the first measured, before any; zeros without any)."""
    out = np.zeros((T, width)) if values is None else np.asarray(values, dtype=np.float64).reshape(T, width).copy()
    ok = np.isfinite(out).all(axis=1)
    if not ok.any():
        return np.zeros((T, width))
    last = out[np.argmax(ok)].copy()
    for t in range(T):
        if ok[t]:
            last = out[t]
        else:
            out[t] = last
    return out


class MeanPoseStrategy(Strategy):
    name = "meanpose"
    needs = frozenset()
    uses = frozenset({"ground_position", "heading"})  # (the sensors' readings are listed as ignored: a floor)
    summary = "the knowledge base's mean pose held still, placed on the track: the floor every strategy must beat"
    options_class = MeanPoseOptions

    def prepare(self, graph: MotionGraph) -> dict:
        return {}  # (a node a label and hidden set: `mean_pose_node`, cheap)

    def reconstruct(
        self, index, graph: MotionGraph, inp, options: Options, allowed=None, threads: bool = True, should_stop=None
    ) -> Reconstruction:
        t0 = time.perf_counter()
        node = mean_pose_node(graph, allowed, self.own(options).label)
        T = inp.num_samples
        rot, trans = place(graph, node, held(inp.position, T, 2), held(inp.heading, T, 1)[:, 0])
        motion = Motion(graph.skeleton, rot, trans, float(graph.rate_hz), name="synthesized", source="meanpose")
        seconds = time.perf_counter() - t0
        label = graph.labels[int(graph.node_label[node])]
        provenance = Provenance(
            np.full((T, 1), int(graph.node_clip[node])),
            np.full((T, 1), float(graph.node_frame[node])),
            np.ones((T, 1)),
            np.array([label] * T, dtype=object),
        )
        report = {
            "meanpose": {
                "node": node,
                "clip": graph.clips[int(graph.node_clip[node])]["name"],
                "frame": float(graph.node_frame[node]),
                "label": label,
            },
            "labels": label_runs([label] * T),
            "timings_s": {"search": round(seconds, 4)},
            "samples_per_s": round(T / max(seconds, 1e-9), 1),
        }
        return Reconstruction(motion, None, None, report, provenance)


class MeanPoseSession(LiveSession):
    """Each sample's frame at once: the pose placed where the sample's track says."""

    def _open(self, allowed, threads: bool) -> None:
        graph = self.graph
        self.node = mean_pose_node(graph, allowed, self.own.label)
        label = graph.labels[int(graph.node_label[self.node])]
        self.provenance = Provenance(
            np.array([[int(graph.node_clip[self.node])]]),
            np.array([[float(graph.node_frame[self.node])]]),
            np.ones((1, 1)),
            np.array([label], dtype=object),
        )
        self.ground, self.heading = np.zeros(2), 0.0
        self.frame_index = 0

    def _decode(self, acc, position, heading, markers=None, up=None):
        if position is not None and np.isfinite(position).all():
            self.ground = np.asarray(position, dtype=np.float64)
        if heading is not None and np.isfinite(heading):
            self.heading = float(heading)
        rot, trans = place(self.graph, self.node, self.ground[None], np.array([self.heading]))
        out = self._emit(self.frame_index, rot, trans, provenance=self.provenance)
        self.frame_index += 1
        return out

    def _finish(self):
        return []


MeanPoseStrategy.session_class = MeanPoseSession
STRATEGY = MeanPoseStrategy()

"""The SSG index: every knowledge-base frame's world pose, and the marker clouds a
marker set puts on them.

Frames are the graph's original nodes, sorted by clip and frame, so a clip's frames are
consecutive; `run_start` marks the first frame of each run of consecutive frames (a
clip, or the part of one between frames the graph left out): a subsequence never
crosses into another run. Each frame keeps its world joint rotations and positions as
its clip played them (the clip's own bones and place in the world), from which any
marker set's virtual markers (`sensors.markers`) and the canonical joints the
transition cost compares are taken. The arrays are cached beside the graph file
(`strategies.index`, memory-mapped on later loads).

For a marker set, `window_points` stacks each frame's markers over a short window of
frames around it (Kovar et al. 2002's point clouds over time, which Tautges 2012, §4.3.3
uses for the local cost): coordinates relative to the frame's own root on the ground,
so the local cost's products stay small numbers in float32.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphsvc.errors import InputError
from graphsvc.graph.model import NODE_ORIGINAL, MotionGraph
from graphsvc.graph.poses import node_poses
from graphsvc.motion import quat
from graphsvc.motion.joints import canonical_indices, joint_map
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.motion.skeleton import Skeleton
from graphsvc.sensors.markers import MarkerSet, place_markers
from graphsvc.strategies.index import cached_arrays

INDEX_VERSION = 1


def build_arrays(graph: MotionGraph) -> dict[str, np.ndarray]:
    """nodes (F,) int64 original nodes by clip and frame; run_start (F,) bool;
    world_rot (F, J, 4) and world_pos (F, J, 3) float32."""
    nodes = np.flatnonzero(np.asarray(graph.node_kind) == NODE_ORIGINAL)
    clip = np.asarray(graph.node_clip)[nodes].astype(np.int64)
    frame = np.asarray(graph.node_frame)[nodes].astype(np.float64)
    order = np.lexsort((frame, clip))
    nodes, clip, frame = nodes[order], clip[order], frame[order]
    run_start = np.ones(nodes.size, dtype=bool)
    run_start[1:] = (clip[1:] != clip[:-1]) | (frame[1:] - frame[:-1] != 1.0)
    rot = np.empty((nodes.size, graph.skeleton.num_joints, 4), dtype=np.float32)
    pos = np.empty((nodes.size, graph.skeleton.num_joints, 3), dtype=np.float32)
    parents = graph.skeleton.parents
    for lo in range(0, nodes.size, 8192):
        sel = nodes[lo : lo + 8192]
        r, p = forward_kinematics(*node_poses(graph, sel), parents)
        rot[lo : lo + sel.size], pos[lo : lo + sel.size] = r, p
    return {"nodes": nodes.astype(np.int64), "run_start": run_start, "world_rot": rot, "world_pos": pos}


class SsgIndex:
    """The arrays of `build_arrays`, and what the strategy reads of them. allowed (N,)
    bool over graph nodes: the frames a retrieval may use (None: all)."""

    def __init__(self, graph: MotionGraph, arrays: dict, allowed: np.ndarray | None = None):
        self.nodes = np.asarray(arrays["nodes"])
        if self.nodes.size == 0:
            raise InputError("the graph has no original frames for SSG")
        self.run_start = np.ascontiguousarray(arrays["run_start"], dtype=np.bool_)
        self.world_rot = arrays["world_rot"]
        self.world_pos = arrays["world_pos"]
        self.run_id = np.cumsum(self.run_start) - 1
        starts = np.flatnonzero(self.run_start)
        ends = np.append(starts[1:], self.nodes.size) - 1
        self.run_first = starts[self.run_id]  # (F,) first frame of each frame's run
        self.run_last = ends[self.run_id]  # (F,) last frame
        self.clip = np.asarray(graph.node_clip)[self.nodes].astype(np.int64)
        self.clip_frame = np.asarray(graph.node_frame)[self.nodes].astype(np.float64)
        self.canonical = canonical_indices(graph.skeleton, graph.params.get("mapping"))
        table = joint_map(graph.skeleton, graph.params.get("mapping"))
        self.pelvis = table["pelvis"]
        self.clip_offsets = np.asarray(graph.clip_offsets)
        self.skeleton = graph.skeleton
        self.mapping = graph.params.get("mapping")
        self.allowed = (
            np.ones(self.nodes.size, dtype=bool) if allowed is None else np.asarray(allowed, dtype=bool)[self.nodes]
        )

    @property
    def frames(self) -> int:
        return int(self.nodes.size)

    @property
    def searchable(self) -> int:
        return int(self.allowed.sum())

    def with_allowed(self, allowed: np.ndarray | None) -> SsgIndex:
        other = object.__new__(SsgIndex)
        other.__dict__.update(self.__dict__)
        other.allowed = (
            np.ones(self.nodes.size, dtype=bool) if allowed is None else np.asarray(allowed, dtype=bool)[self.nodes]
        )
        return other

    def marker_locals(self, marker_set: MarkerSet) -> tuple[np.ndarray, np.ndarray]:
        """(F, M, 3) each frame's marker offsets in their carriers' frames — the set placed
        on its clip's own skeleton (bones differ by performer) — and the carriers (M,)."""
        M = len(marker_set.markers)
        out = np.empty((self.frames, M, 3))
        carrier = None
        for offsets in np.unique(self.clip_offsets.reshape(len(self.clip_offsets), -1), axis=0):
            clips = np.flatnonzero((self.clip_offsets.reshape(len(self.clip_offsets), -1) == offsets).all(axis=1))
            sk = Skeleton(
                self.skeleton.names,
                self.skeleton.parents,
                offsets.reshape(-1, 3),
                self.skeleton.channels,
                self.skeleton.end_site,
            )
            placement = place_markers(marker_set, sk, self.mapping)
            carrier = placement.carrier
            out[np.isin(self.clip, clips)] = placement.local
        return out, carrier

    def markers(self, marker_set: MarkerSet, local: np.ndarray | None = None) -> np.ndarray:
        """(F, M, 3) float64 world positions of the set's markers on every frame (in its
        clip's world). local: (M, 3) offsets for every frame instead of the set's own."""
        per_frame, carrier = self.marker_locals(marker_set)
        if local is not None:
            per_frame = np.broadcast_to(np.asarray(local, dtype=np.float64), per_frame.shape)
        out = np.empty(per_frame.shape)
        for lo in range(0, self.frames, 16384):
            sl = slice(lo, lo + 16384)
            rot = self.world_rot[sl][:, carrier].astype(np.float64)
            out[sl] = self.world_pos[sl][:, carrier] + quat.rotate(rot, per_frame[sl])
        return out

    def joints(self, frames: np.ndarray) -> np.ndarray:
        """(..., 19, 3) canonical joint world positions at fractional frames (linear
        between a frame and the next of its run)."""
        f = np.asarray(frames, dtype=np.float64)
        lo = np.floor(f).astype(np.int64)
        hi = np.minimum(lo + 1, self.run_last[lo])
        w = (f - lo)[..., None, None]
        a = self.world_pos[lo][..., self.canonical, :].astype(np.float64)
        b = self.world_pos[hi][..., self.canonical, :].astype(np.float64)
        return a * (1.0 - w) + b * w


def load_index(graph: MotionGraph) -> SsgIndex:
    return SsgIndex(graph, cached_arrays(graph, "ssg", INDEX_VERSION, lambda: build_arrays(graph)))


# ---------------------------------------------------------------- window clouds

# The local cost's point clouds span this much time around a frame, weighted by a
# Gaussian tapering to both ends (Tautges 2012, §4.3.3: 15 frames at 60 Hz).
POINT_WINDOW_S = 0.25


def point_window(rate_hz: float) -> tuple[int, np.ndarray]:
    """(h, weights (2h + 1,)): the half-width in frames of `POINT_WINDOW_S` at the
    graph rate and its Gaussian weights (σ = (h + 1) / 2 frames, 1 at the centre)."""
    return point_window_weights(max(1, int(round(0.5 * POINT_WINDOW_S * float(rate_hz)))))


def point_window_weights(h: int) -> tuple[int, np.ndarray]:
    tau = np.arange(-h, h + 1, dtype=np.float64)
    return h, np.exp(-0.5 * (tau / (0.5 * (h + 1))) ** 2)


@dataclass
class WindowPoints:
    """Each frame's markers at the frames τ around it: x, y, z (F, P) float32, relative
    to the frame's root on the ground (x, z) and the floor (y); sq (F, P) their squared
    norms; P = len(taus) · M points ordered (τ, marker); weights (len(taus),) the
    Gaussian weight of each τ."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    sq: np.ndarray
    taus: np.ndarray
    weights: np.ndarray


def window_taus(h: int, markers: int, max_points: int) -> np.ndarray:
    """The offsets τ a cloud holds: −h … h, or as many of them as `max_points` allows
    for `markers` markers, spread evenly and always the centre."""
    count = 2 * h + 1
    if count * markers > max_points:
        count = max(1, max_points // markers)
        count -= 1 - count % 2  # odd: the centre is one of them
    return np.unique(np.round(np.linspace(-h, h, count)).astype(np.int64))


def window_points(index: SsgIndex, kb_markers: np.ndarray, h: int, max_points: int = 1 << 30) -> WindowPoints:
    """kb_markers (F, M, 3) → WindowPoints over `window_taus`; a frame near its run's
    end repeats the run's last frame (the clip held still), as the first its first."""
    F, M, _ = kb_markers.shape
    taus = window_taus(h, M, max_points)
    _, all_weights = point_window_weights(h)
    ref = index.world_pos[:, index.pelvis].astype(np.float64)  # (F, 3)
    f = np.arange(F)
    pts = np.stack([kb_markers[np.clip(f + tau, index.run_first, index.run_last)] for tau in taus], axis=1)
    x = (pts[..., 0] - ref[:, None, None, 0]).reshape(F, -1)
    y = pts[..., 1].reshape(F, -1)
    z = (pts[..., 2] - ref[:, None, None, 2]).reshape(F, -1)
    sq = x * x + y * y + z * z
    as32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)  # noqa: E731
    return WindowPoints(as32(x), as32(y), as32(z), as32(sq), taus, all_weights[taus + h])

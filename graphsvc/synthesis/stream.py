"""Synthesis of a path that arrives a few frames at a time (live streams).

A frame's pose depends on the path around it: a blend centred on a cut reaches half
its window before the cut, and the foot clean-up accumulates from the start of the
contact span (and fades out over a short window after it). So a frame is final once the
path is known `lookahead` frames past it, and each update re-synthesizes a trailing
stretch that starts early enough to hold those influences (the contact spans open or
fading out, at most `max_back_s`), from the root
position and heading the stream has reached there. Frames come out once, in order.
"""

from __future__ import annotations

import math

import numpy as np

from graphsvc.graph import metadata as meta
from graphsvc.graph.model import MotionGraph
from graphsvc.synthesis.path import FOOT_BLEND_S, path_tables, synthesize_motion
from graphsvc.synthesis.smooth import StreamingSmoother
from graphsvc.synthesis.track import FixedLagSmoother, TrackModel, free_steps


def lookahead_frames(rate_hz: float, blend_s: float = 0.7) -> int:
    """Frames the path must be known past a frame before its pose is final: half the
    blend window, plus one."""
    return int(math.ceil(0.5 * blend_s * rate_hz)) + 1


class StreamingSynthesizer:
    """add(nodes, arrival_edges[, positions]) → (first frame index, rotations (K, J, 4),
    translations (K, J, 3)) of the frames that became final; finish() → the rest.
    track_model, with each frame's measured position (K, 2) m given to add (NaN: none):
    the root's track is the path's own fused with them (`synthesis.track`), each frame's
    offset smoothed over the `lookahead` frames after it that a frame waits for anyway.
    smooth_frames: σ (frames) of the poses' filter (`synthesis.smooth`), which holds
    each frame back until the h = ⌈3σ⌉ after it are final too (`smooth_lag`). refiner:
    a `strategies.refine.Refiner` its owner feeds the samples: each final frame's pose
    gets its correction before the filter, as `strategies.refine.refine_motion` does in
    batch (it reads the path's nodes a few frames past the frame, within `lookahead`)."""

    def __init__(
        self,
        graph: MotionGraph,
        start_ground,
        start_heading: float,
        blend_s: float = 0.7,
        flight_root_blend_s: float = 0.1,
        fix_feet: bool = True,
        max_back_s: float = 10.0,
        batch: int = 1,
        track_model: TrackModel | None = None,
        smooth_frames: float = 0.0,
        refiner=None,
    ):
        self.graph = graph
        self.smoother = StreamingSmoother(smooth_frames, graph.skeleton.num_joints)
        self.refiner = refiner
        self.smooth_lag = self.smoother.h
        self.blend_s = blend_s
        self.flight_root_blend_s = flight_root_blend_s
        self.fix_feet = fix_feet
        rate = float(graph.rate_hz)
        self.lookahead = lookahead_frames(rate, blend_s)
        self.track = None if track_model is None else FixedLagSmoother(track_model, self.lookahead)
        # Synthesize once `batch` frames are final, not every frame: each update
        # re-synthesizes a trailing stretch, so this divides the cost by `batch` and
        # adds up to batch − 1 frames of delay.
        self.batch = max(1, int(batch))
        self.max_back = int(math.ceil(max_back_s * rate))
        self.foot_blend = max(1, round(FOOT_BLEND_S * rate))  # synthesis' blend-out after a contact span
        # The trailing stretch of the path still needed: frames base, base+1, ...
        self.base = 0
        self.nodes = np.zeros(0, np.int64)
        self.edges = np.zeros(0, np.int64)  # arrival edge of each node (−1 for frame 0)
        self.heading = [float(start_heading)]
        self.plain = [np.asarray(start_ground, dtype=np.float64).reshape(2)]  # the path's own track
        self.ground: list = []  # the fused track of the frames whose offset is final (with a track model)
        self.done = 0  # frames emitted

    def add(self, nodes: np.ndarray, arrival_edges: np.ndarray, positions: np.ndarray | None = None):
        """Append decided frames (and their measured positions (K, 2), NaN where none);
        return the frames now final."""
        nodes = np.asarray(nodes, dtype=np.int64)
        edges = np.asarray(arrival_edges, dtype=np.int64)
        positions = (
            np.full((nodes.size, 2), np.nan)
            if positions is None
            else np.asarray(positions, dtype=np.float64).reshape(nodes.size, 2)
        )
        first = self.base + self.nodes.size == 0
        new = edges[(1 if first else 0) :]
        if new.size:
            # integrate_path, as a batch synthesis does (the path's own track): the same
            # float64 steps, so the same root.
            offsets, turns = self.graph.edge_offset[new], self.graph.edge_heading[new]
            g, h = meta.integrate_path(self.plain[-1], self.heading[-1], offsets, turns)
            self.plain.extend(g[1:])
            self.heading.extend(h[1:].tolist())
        if self.track is not None:
            free = free_steps(self.graph.node_contacts[nodes])
            for k in range(nodes.size):  # (each frame's measured − own offset: the smoother's input)
                t = self.base + self.nodes.size + k
                self.track.push(positions[k] - self.plain[t - self.base], free[k])
                self._take_finals()
        self.nodes = np.concatenate([self.nodes, nodes])
        self.edges = np.concatenate([self.edges, edges])
        until = self.base + self.nodes.size - self.lookahead
        if until - self.done < self.batch:
            J = self.graph.skeleton.num_joints
            return self.smoother.done, np.zeros((0, J, 4)), np.zeros((0, J, 3))
        return self._filtered(self._synthesize(until))

    def finish(self):
        if self.track is not None:
            self.track.flush()
            self._take_finals()
        a = self._filtered(self._synthesize(self.base + self.nodes.size), self.base + self.nodes.size - 1)
        b = self.smoother.finish()
        return a[0], np.concatenate([a[1], b[1]]), np.concatenate([a[2], b[2]])

    def _filtered(self, part, last: int | None = None):
        """Final frames through the refinement's correction (last: the path's last frame,
        at the end) and the poses' filter."""
        if self.refiner is not None:
            first, rot, trans = part
            rot, trans = self.refiner.correct(first, rot, trans, self._nodes_of, last)
            part = first, rot, trans
        return self.smoother.add(*part)

    def _nodes_of(self, lo: int, hi: int) -> np.ndarray:
        return self.nodes[lo - self.base : hi - self.base]

    def _take_finals(self) -> None:
        """The fused track of the frames whose smoothed offset became final."""
        while self.track.finals:
            t = self.base + len(self.ground)
            self.ground.append(self.plain[t - self.base] + self.track.take(t))

    def _before_cuts(self, start: int, lo: int) -> int:
        """Move a window's first frame back before every cut whose blend reaches it: a
        cut blends the frames up to half a window after it, and the window must hold
        the frame before the cut to blend them as a whole-path synthesis does."""
        b = self.base
        half = int(math.ceil(0.5 * self.blend_s * self.graph.rate_hz))
        continuous = path_tables(self.graph).continuous
        while start > lo:
            t = np.arange(max(lo + 1, start - half), start + 1)  # frames a cut at t would reach start from
            if t.size == 0:
                break
            e = self.edges[t - b]
            cut = ~continuous[e] | (self.graph.edge_src[e] != self.nodes[t - 1 - b])
            if not cut.any():
                break
            start = int(t[np.argmax(cut)]) - 1  # the earliest such cut, from its frame before
        return start

    def _synthesize(self, until: int):
        J = self.graph.skeleton.num_joints
        if until <= self.done:
            return self.done, np.zeros((0, J, 4)), np.zeros((0, J, 3))
        b = self.base
        start = max(b, self.done - self.lookahead - 1)
        if self.fix_feet and self.done > 0:
            # Reach back to where the contact spans still acting at `done` began: those
            # open there, and those that ended in the blend-out before it (their offset,
            # accumulated over the whole span, is still being faded out).
            lo = max(b, self.done - self.max_back)
            contacts = self.graph.node_contacts[self.nodes[lo - b : self.done + 1 - b]]
            fade = self.foot_blend + 1
            for side in range(2):
                recent = np.flatnonzero(contacts[-fade:, side])
                if recent.size:
                    last = contacts.shape[0] - min(fade, contacts.shape[0]) + int(recent[-1])
                    run = contacts[last::-1, side]
                    length = run.size if run.all() else int(np.argmin(run))
                    start = min(start, lo + last + 1 - length)
            start = max(lo, self._before_cuts(start, lo))
        k = start - b
        track = None
        if self.track is not None:
            # The frames past the final ones (synthesized, not emitted): their own track
            # at the last final offset.
            final = np.array(self.ground[k:]).reshape(-1, 2)
            n = final.shape[0]
            last = final[-1] - self.plain[k + n - 1] if n else np.zeros(2)
            track = np.concatenate([final, np.array(self.plain[k + n :]).reshape(-1, 2) + last])
        motion = synthesize_motion(
            self.graph,
            self.nodes[k:],
            self.edges[k + 1 :],
            self.plain[k],
            self.heading[k],
            blend_s=self.blend_s,
            flight_root_blend_s=self.flight_root_blend_s,
            fix_feet=self.fix_feet,
            allow_jumps=True,
            track=track,
        )
        lo, hi = self.done - start, until - start
        first = self.done
        self.done = until
        # Forget what no later window can reach.
        drop = max(0, self.done - self.max_back - self.lookahead - 2 - self.base)
        if drop > 256:
            self.nodes, self.edges = self.nodes[drop:], self.edges[drop:]
            del self.ground[:drop], self.plain[:drop], self.heading[:drop]
            self.base += drop
        # Copies: a view would keep the whole window's arrays alive with the frames
        # (135 kB a frame held by a session that keeps its motion, instead of 1.7).
        return first, motion.rotations[lo:hi].copy(), motion.translations[lo:hi].copy()

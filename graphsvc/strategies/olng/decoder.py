"""OLNG, one sample at a time: neighbours, the neighbourhood graph, the pose, the root,
the feet. Batch and live run this same decoder over the samples, so they agree frame
for frame.

Per sample t (readings a_t, optionally a ground position and heading):

1. The K nearest knowledge-base frames (`index.OlngIndex.query`) become the lattice's
   newest column (`lattice.Lattice`); its I cheapest paths give the neighbourhood and
   their weights. A sample with a sensor missing cannot be queried (a kd-tree cannot
   leave an axis out): its column is the previous one's frames each moved one frame on
   in its clip, at the same costs, and the pose leaves out the control term.
2. The pose (`pose`): the neighbours' poses aligned to the previous pose's quaternion
   signs, their weighted PCA, and the energy minimised from the previous pose.
3. The root: each neighbour's own step into its frame (its original edge's ground
   offset and turn) averaged by weight and applied at the current heading, snapped to
   the first measured position and heading that arrive. With a tracker, the offset from
   this own track to the measured positions is Kalman-filtered (`synthesis.track`, the
   shared `track_sigma_m` and `track_drift`; it moves only while the neighbourhood's
   vote has a foot off the ground), and the heading is pulled toward the measured one
   by the share α = 1 − exp(−1 / (τ · rate)) (τ = `track_pull_s`). The pose is placed
   on the own track and the whole body then shifted by the filtered offset, as Viterbi
   synthesis does, so the correction does not bend the legs of a held foot. A batch
   run then replaces the filtered offsets by the smoothed ones (`strategy`).
4. The feet (`OlngOptions.fix_feet`, off by default): while the neighbourhood's weighted contact vote for a foot is over one
   half, its ankle and toe move only as the neighbours' own ankles and toes moved
   (heel and toe roll kept, as in Viterbi synthesis), from where they were when the
   contact began (two-bone IK, `synthesis.path`), blended out over FOOT_BLEND_S after
   it ends. Causal, so a live
   frame is final as it is made.
"""

from __future__ import annotations

import math
import time

import numpy as np

from graphsvc.errors import InputError
from graphsvc.graph.model import MotionGraph
from graphsvc.graph.poses import node_rotations, node_translations
from graphsvc.motion import quat
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.motion.placement import place_poses
from graphsvc.sensors.accelerometer import G_UP, GRAVITY
from graphsvc.sensors.orientation import normalised_rows
from graphsvc.strategies.olng.index import OlngIndex
from graphsvc.strategies.olng.lattice import Lattice, LatticeOptions
from graphsvc.strategies.olng.options import OlngOptions
from graphsvc.strategies.olng.pose import (
    EnergyTerms,
    PoseModel,
    optimise,
    pose_positions,
    sensor_orientations,
    weighted_pca,
)
from graphsvc.synthesis.path import FOOT_BLEND_S, _two_bone_ik, path_tables
from graphsvc.synthesis.sensor_orientations import impose_at_nodes
from graphsvc.synthesis.track import FixedLagSmoother, TrackModel, advance_own_track

SOURCES = 8  # provenance: the heaviest neighbours a frame lists


class OlngDecoder:
    """One stream's OLNG state. step(acc (S, 3) m/s², position (2,) or None, heading or
    None) → (rotations (J, 4), translations (J, 3), sources [(clip, frame, weight)],
    label, row), row being the frame's report entry."""

    def __init__(
        self,
        graph: MotionGraph,
        index: OlngIndex,
        model: PoseModel,
        options: OlngOptions,
        pull_alpha: float,
        track_model: TrackModel | None = None,
    ):
        self.graph = graph
        self.index = index
        self.model = model
        self.options = options
        self.lattice = Lattice(index.run_of, LatticeOptions(options.k, options.m, options.i, options.extended))
        self.alpha = float(pull_alpha)  # the heading's pull toward the tracker's
        self.track_model = track_model
        self.filter = None if track_model is None else FixedLagSmoother(track_model, 0)
        # Per frame (measured − own (2,), gate, filtered offset (2,)) for a batch's
        # smoother, when it is a list (a live session keeps none).
        self.track_inputs: list | None = None
        self.up_weight = 0.0  # W_R: the weight of the sensors' orientation cue in the neighbour query (0: not used)
        self.impose = False  # whether measured orientations relative to a root sensor are imposed on the pose
        self.rate = float(graph.rate_hz)
        self.parents = np.ascontiguousarray(graph.skeleton.parents, dtype=np.int64)
        sk = graph.skeleton
        self.offsets = np.asarray(sk.offsets, dtype=np.float64)[model.active].copy()
        self.edge_offset = np.asarray(graph.edge_offset, dtype=np.float64)
        self.edge_heading = np.asarray(graph.edge_heading, dtype=np.float64)
        runs = index.run_of
        n = runs.size
        prev = np.arange(n) - 1
        prev[0] = 0
        same = runs[np.maximum(prev, 0)] == runs
        self.prev = np.where(same, prev, np.arange(n))
        nxt = np.arange(n) + 1
        nxt[-1] = n - 1
        self.next = np.where(runs[nxt] == runs, nxt, np.arange(n))
        tables = path_tables(graph)
        j = tables.joints
        self.legs = np.array([[j[f"{s}_{k}"] for k in ("hip", "knee", "ankle", "toe")] for s in ("l", "r")], np.int64)
        self.t = -1
        self.p_prev: np.ndarray | None = None
        self.x_t: np.ndarray | None = None
        self.x_tm1: np.ndarray | None = None
        self.ground = np.zeros(2)  # fused with the tracker
        self.own = np.zeros(2)  # the neighbours' steps alone: where the pose is placed
        self.heading = 0.0
        self.placed = False
        self.heading_placed = False
        self.last_frames: np.ndarray | None = None
        self.last_distances: np.ndarray | None = None
        self.pins = [None, None]  # per foot: (ankle, toe) world targets while in contact
        self.fade = [None, None]  # per foot: (offset ankle, offset toe, frames since)

    # ------------------------------------------------------------ one sample

    def step(self, acc, position=None, heading=None, up=None):
        """up: (S, W) the sensors' measured orientation cue (`sensors.orientation`), or
        None; used (weighed by `up_weight`) when every sensor's is finite."""
        t0 = time.perf_counter()
        self.t += 1
        reading = np.asarray(acc, dtype=np.float64).reshape(-1) / GRAVITY
        complete = bool(np.all(np.isfinite(reading)))
        dropped = 0
        cue = None
        if up is not None:
            cue, valid = normalised_rows(up)
            up = cue.reshape(-1) if valid.all() else None
            cue = np.where(valid[:, None], cue, np.nan)
        if complete:
            nb = self.index.query(reading, self.options.k, up, self.up_weight if up is not None else 0.0)
            frames, distances, dropped = nb.frames, nb.distances, nb.dropped
        elif self.last_frames is not None:
            frames, distances = self.next[self.last_frames], self.last_distances
        else:
            raise InputError("the first OLNG sample needs every sensor's reading (a sensor is missing)")
        t1 = time.perf_counter()
        self.lattice.push(frames, distances)
        self.last_frames, self.last_distances = frames, distances
        col = self.lattice.column()
        order, best, cost, w = self.lattice.best(self.options.i, col)
        lengths = col["length"][order]
        t2 = time.perf_counter()
        p, energy, iterations, dims = self._pose(best, w, np.asarray(acc, dtype=np.float64) if complete else None)
        x = pose_positions(p, self.offsets, self.model)
        self.x_tm1, self.x_t, self.p_prev = self.x_t, x, p
        heading_before = self.heading
        contacts = self._contacts(best, w)
        self._root(best, w, position, heading, contacts)
        rot, trans = self._place(best[0], p)
        if self.impose and cue is not None:  # (each measured segment gets its measured orientation)
            rot = impose_at_nodes(self.graph, rot, cue[None], self.index.nodes[best[:1]])
        if self.options.fix_feet:
            self._fix_feet(rot, trans, contacts, self._foot_steps(best, w, heading_before))
        for root in np.flatnonzero(self.parents < 0):  # onto the fused track, the whole body at once
            trans[0, root, 0] += self.ground[0] - self.own[0]
            trans[0, root, 2] += self.ground[1] - self.own[1]
        t3 = time.perf_counter()
        sources, label = self._sources(best, w)
        row = {
            "cost": float(cost[0]),
            "energy": energy,
            "iterations": iterations,
            "subspace": dims,
            "path_length": float(np.dot(w, lengths)),
            "dropped": int(dropped),
            "complete": complete,
            "nn_ms": (t1 - t0) * 1e3,
            "olng_ms": (t2 - t1) * 1e3,
            "optimise_ms": (t3 - t2) * 1e3,
        }
        return rot, trans, sources, label, row

    # ------------------------------------------------------------ parts

    def _pose(self, best, w, acc):
        o = self.options
        idx = self.index
        Q = np.asarray(idx.poses[best], dtype=np.float64)
        ref = self.p_prev if self.p_prev is not None else Q[0]
        slots = self.model.slot
        for s in slots:  # each quaternion to the reference's side
            flip = Q[:, s : s + 4] @ ref[s : s + 4] < 0.0
            Q[flip, s : s + 4] *= -1.0
        mean, basis, _ = weighted_pca(Q, w)
        X = np.asarray(idx.positions[best], dtype=np.float64)
        f1, f2 = self.prev[best], self.prev[self.prev[best]]
        X1 = np.asarray(idx.positions[f1], dtype=np.float64)
        X2 = np.asarray(idx.positions[f2], dtype=np.float64)
        Ja = self.model.active.size
        S = self.model.sensor_a.size
        zeros = np.zeros((Ja, 3))
        weights = np.array([o.w_prior * o.w_pose, o.w_prior * o.w_motion, o.w_prior * o.w_smooth, o.w_contr])
        if self.x_t is None:
            weights[1:] = 0.0
            motion = accel = np.zeros((w.size, Ja, 3))
            control = np.zeros((w.size, S, 3))
        else:
            motion = self.x_t[None] + (X - X1)
            accel = (X - 2.0 * X1 + X2) * (self.rate * self.rate)
            control = np.zeros((w.size, S, 3))
            if self.x_tm1 is None:
                weights[2] = 0.0
            if acc is None or S == 0:
                weights[3] = 0.0
            else:
                control = self._control(X, X2, f1, best, w, acc)
        terms = EnergyTerms(
            Q,
            np.ascontiguousarray(w, dtype=np.float64),
            self.offsets,
            np.ascontiguousarray(motion),
            np.ascontiguousarray(accel),
            np.ascontiguousarray(control),
            zeros if self.x_t is None else self.x_t,
            zeros if self.x_tm1 is None else self.x_tm1,
            weights,
            self.rate,
        )
        start = self.p_prev if self.p_prev is not None else Q[0]
        p, energy, iterations = optimise(mean, basis, start, terms, self.model)
        return p, energy, iterations, int(basis.shape[1])

    def _sensor_points(self, X):
        m = self.model
        al = m.along[:, None]
        return (1.0 - al) * X[..., m.sensor_a, :] + al * X[..., m.sensor_b, :]

    def _control(self, X, X2, f1, best, w, acc):
        """x̃ᵢ = s_t + vᵢΔt + ½α̂Δt² (`pose` module docstring)."""
        dt = 1.0 / self.rate
        a_hat = quat.rotate(sensor_orientations(self.p_prev, self.model), acc) - G_UP
        step = self.edge_offset[self.index.edges[best]]
        step1 = self.edge_offset[self.index.edges[f1]]
        ground_acc = w @ (step - step1) * (self.rate * self.rate)
        a_hat[:, 0] -= ground_acc[0]
        a_hat[:, 2] -= ground_acc[1]
        s_t = self._sensor_points(self.x_t)
        v_dt = 0.5 * (self._sensor_points(X) - self._sensor_points(X2))
        return s_t[None] + v_dt + 0.5 * a_hat[None] * dt * dt

    def _root(self, best, w, position, heading, contacts):
        e = self.index.edges[best]
        step = w @ self.edge_offset[e] if self.t > 0 else np.zeros(2)
        turn = float(w @ self.edge_heading[e]) if self.t > 0 else 0.0
        advance_own_track(self, step, turn, contacts, position, heading)

    def _place(self, node_frame: int, p: np.ndarray):
        """Local rotations and translations (J, 4/3) of pose p at the current root."""
        g = self.graph
        m = self.model
        node = int(self.index.nodes[node_frame])
        rot = node_rotations(g, node)[None].copy()
        trans = node_translations(g, node)[None].copy()
        for k in range(1, m.active.size):
            q = p[m.slot[k] : m.slot[k] + 4]
            rot[0, m.active[k]] = q / np.linalg.norm(q)
            trans[0, m.active[k]] = self.offsets[k]
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
            m.pelvis,
            m.carrier,
        )
        return rot, trans

    def _contacts(self, best, w) -> np.ndarray:
        nodes = self.index.nodes[best]
        vote = w @ np.asarray(self.graph.node_contacts[nodes], dtype=np.float64)
        return vote > 0.5

    def _foot_steps(self, best, w, heading_before: float) -> np.ndarray:
        """(2, 2, 3): per foot, the world step (m) of its ankle and toe from the last
        frame to this one as the neighbours' own feet moved (each neighbour's step in
        its previous frame's heading frame, weighted, turned to the output's heading)."""
        X = np.asarray(self.index.positions[best], dtype=np.float64)
        f1 = self.prev[best]
        X1 = np.asarray(self.index.positions[f1], dtype=np.float64)
        e = self.index.edges[best]
        turn = np.where(f1 == best, 0.0, self.edge_heading[e])
        step = np.where((f1 == best)[:, None], 0.0, self.edge_offset[e])
        c, s = np.cos(turn)[:, None], np.sin(turn)[:, None]
        out = np.zeros((2, 2, 3))
        where = {int(j): k for k, j in enumerate(self.model.active)}
        ch, sh = math.cos(heading_before), math.sin(heading_before)
        for side in range(2):
            for n, joint in enumerate((self.legs[side, 2], self.legs[side, 3])):
                k = where.get(int(joint))
                if k is None:
                    continue
                x, x1 = X[:, k], X1[:, k]
                d = np.stack(
                    [
                        c[:, 0] * x[:, 0] + s[:, 0] * x[:, 2] + step[:, 0] - x1[:, 0],
                        x[:, 1] - x1[:, 1],
                        -s[:, 0] * x[:, 0] + c[:, 0] * x[:, 2] + step[:, 1] - x1[:, 2],
                    ],
                    axis=1,
                )
                m = w @ d
                out[side, n] = (ch * m[0] + sh * m[2], m[1], -sh * m[0] + ch * m[2])
        return out

    def _fix_feet(self, rot, trans, contacts, steps):
        world_rot, world_pos = forward_kinematics(rot, trans, self.parents)
        hips = self.legs[:, 0]
        lateral = world_pos[0, hips[0]] - world_pos[0, hips[1]]
        lateral = lateral / max(np.linalg.norm(lateral), 1e-12)
        blend = max(1, round(FOOT_BLEND_S * self.rate))
        for side in range(2):
            hip, knee, ankle, toe = self.legs[side]
            here = world_pos[0, ankle].copy(), world_pos[0, toe].copy()
            if contacts[side]:
                if self.pins[side] is None:
                    self.pins[side] = here
                    self.fade[side] = None
                    continue
                pin = self.pins[side]
                target = self.pins[side] = (pin[0] + steps[side, 0], pin[1] + steps[side, 1])
                self.fade[side] = (target[0] - here[0], target[1] - here[1], 0)
            else:
                self.pins[side] = None
                if self.fade[side] is None:
                    continue
                da, dt_, k = self.fade[side]
                k += 1
                if k > blend:
                    self.fade[side] = None
                    continue
                self.fade[side] = (da, dt_, k)
                share = 1.0 - k / (blend + 1.0)
                target = (here[0] + share * da, here[1] + share * dt_)
            _two_bone_ik(
                rot,
                world_rot,
                world_pos,
                self.parents,
                hip,
                knee,
                ankle,
                toe,
                np.asarray(target[0]),
                np.asarray(target[1]),
                lateral,
                0,
            )
            world_rot, world_pos = forward_kinematics(rot, trans, self.parents)

    def _sources(self, best, w):
        g = self.graph
        nodes = self.index.nodes[best]
        top = np.argsort(-w, kind="stable")[:SOURCES]
        share = w[top] / max(w[top].sum(), 1e-12)
        sources = [(int(g.node_clip[nodes[i]]), float(g.node_frame[nodes[i]]), float(s)) for i, s in zip(top, share)]
        votes = np.bincount(np.asarray(g.node_label)[nodes], weights=w, minlength=len(g.labels))
        return sources, g.labels[int(np.argmax(votes))]

"""Feet kept moving as they moved before a change of pose (live and batch alike).

A correction added to a synthesized path's poses (`strategies.refine`) moves the legs
a little, and a planted foot with them. While a foot's contact flag is on, its ankle and
toe here move from one frame to the next exactly as they did before the correction —
the path's clean-up had already planted them — from where the corrected pose put them
on the span's first frame; after the span the difference fades out over `FOOT_BLEND_S`
(never into the next span). `synthesis.path`'s analytic two-bone IK reaches the targets
(the knee bending in its own plane, the foot swung toward the toe's target).

Causal: a frame's targets depend on it and the frames before it, and `FootHold.apply`
carries the state from one call to the next, so a stream fed chunk by chunk gives the
frames of one call over the whole motion.
"""

from __future__ import annotations

import numba
import numpy as np

from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.synthesis.path import FOOT_BLEND_S, _smoothstep, _two_bone_ik

# the state of one foot: in span, frames since it ended, then (3,) each: the ankle's and
# the toe's accumulated drift, their last offsets, their positions a frame before as
# corrected and as they were
_STATE = 2 + 8 * 3


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _hold(rot, world_rot, world_pos, before_pos, parents, legs, contacts, blend, state):
    """In place on rot (T, J, 4) and state (2, _STATE) (module docstring). world_* the
    corrected pose's FK, before_pos (T, J, 3) the uncorrected pose's joint positions."""
    T = rot.shape[0]
    lateral = np.empty(3)
    targets = np.empty((2, 3))
    off = np.empty((2, 3))
    for t in range(T):
        hl, hr = legs[0, 0], legs[1, 0]
        for c in range(3):
            lateral[c] = world_pos[t, hl, c] - world_pos[t, hr, c]
        m = max(np.sqrt(lateral[0] ** 2 + lateral[1] ** 2 + lateral[2] ** 2), 1e-12)
        for c in range(3):
            lateral[c] /= m
        for side in range(2):
            st = state[side]
            joints = (legs[side, 2], legs[side, 3])  # ankle, toe
            if contacts[t, side]:
                for k in range(2):
                    j = joints[k]
                    for c in range(3):
                        if st[0] > 0.0:  # (in the span: the drift from the uncorrected step)
                            st[2 + 3 * k + c] += (world_pos[t, j, c] - st[14 + 3 * k + c]) - (
                                before_pos[t, j, c] - st[20 + 3 * k + c]
                            )
                        else:
                            st[2 + 3 * k + c] = 0.0
                        off[k, c] = -st[2 + 3 * k + c]
                        st[8 + 3 * k + c] = off[k, c]
                st[0] = 1.0
                st[1] = 0.0
            else:
                st[0] = 0.0
                st[1] += 1.0
                w = 0.0
                if st[1] <= blend:
                    w = 1.0 - _smoothstep(st[1] / (blend + 1.0))
                for k in range(2):
                    for c in range(3):
                        off[k, c] = st[8 + 3 * k + c] * w
            for k in range(2):
                j = joints[k]
                for c in range(3):
                    st[14 + 3 * k + c] = world_pos[t, j, c]
                    st[20 + 3 * k + c] = before_pos[t, j, c]
            moved = 0.0
            for k in range(2):
                for c in range(3):
                    targets[k, c] = world_pos[t, joints[k], c] + off[k, c]
                    moved += abs(off[k, c])
            if moved > 1e-7:
                _two_bone_ik(
                    rot,
                    world_rot,
                    world_pos,
                    parents,
                    legs[side, 0],
                    legs[side, 1],
                    joints[0],
                    joints[1],
                    targets[0],
                    targets[1],
                    lateral,
                    t,
                )


class FootHold:
    """apply(rot, trans, before_rot, before_trans, contacts (K, 2)) → the corrected
    rotations (K, J, 4) with the feet held (a copy; the state carried to the next
    call). A skeleton without toes is left as it is (`enabled`)."""

    def __init__(self, skeleton, rate_hz: float, mapping=None):
        table = joint_map(skeleton, mapping)
        self.enabled = not ({"l_toe", "r_toe"} & getattr(table, "missing", frozenset()))
        self.parents = np.ascontiguousarray(skeleton.parents, dtype=np.int64)
        self.legs = np.array(
            [[table[f"{s}_{n}"] for n in ("hip", "knee", "ankle", "toe")] for s in ("l", "r")], dtype=np.int64
        )
        self.blend = max(1, round(FOOT_BLEND_S * rate_hz))
        self.state = np.zeros((2, _STATE))
        self.state[:, 1] = 1e9  # (no span yet: nothing to fade)

    def apply(self, rot, trans, before_rot, before_trans, contacts) -> np.ndarray:
        rot = np.array(rot, dtype=np.float64, copy=True)
        if not self.enabled or rot.shape[0] == 0:
            return rot
        trans = np.asarray(trans, dtype=np.float64)
        world_rot, world_pos = forward_kinematics(rot, trans, self.parents)
        _, before = forward_kinematics(
            np.asarray(before_rot, dtype=np.float64), np.asarray(before_trans, dtype=np.float64), self.parents
        )
        _hold(
            rot,
            world_rot,
            world_pos,
            before,
            self.parents,
            self.legs,
            np.ascontiguousarray(contacts, dtype=np.bool_),
            self.blend,
            self.state,
        )
        return rot

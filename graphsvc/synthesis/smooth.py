"""A light temporal filter over a reconstruction's poses: the frame-to-frame jitter a
path of knowledge-base frames carries (a cut's blend, a speed-variation node, the foot
clean-up's IK switching on and off) is high-frequency, and a Gaussian over a few
frames removes it without moving the motion: every joint's local rotation (signs
aligned to the frame's own, the weighted sum normalised) and translation (the root's
position on the ground and its height) is the weighted mean of its values over the
frames around it. Planted feet stay planted: a foot that does not move is averaged
with itself. Edges repeat the first and the last frame.

Batch: `smooth_motion` over the whole motion. Live: `StreamingSmoother` takes the
frames a stream made final and gives each one back once the h frames after it are in
(h = ⌈3σ⌉ frames), the same sums in the same order, so a stream equals the batch bit
for bit.

Written here: a Gaussian over quaternions with their signs aligned is a few lines of
numba; scipy.ndimage.gaussian_filter1d filters each component alone, which mixes the
two signs of a quaternion, and its truncation differs from a stream's window.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


def gaussian_taps(sigma_frames: float) -> np.ndarray:
    """The filter's weights (2h + 1,), summing to 1, h = ⌈3σ⌉; (1,) [1.0] for σ ≤ 0."""
    sigma = float(sigma_frames)
    if not sigma > 0.0:
        return np.ones(1)
    h = int(math.ceil(3.0 * sigma))
    k = np.arange(-h, h + 1, dtype=np.float64)
    w = np.exp(-0.5 * (k / sigma) ** 2)
    return w / w.sum()


def half_width(sigma_frames: float) -> int:
    """h: the frames after a frame that its smoothed pose waits for."""
    return (gaussian_taps(sigma_frames).size - 1) // 2


@_jit
def _smooth(rot, trans, first, last, w, lo, hi, out_rot, out_trans):
    """Frames lo … hi − 1 (global indices) of the filtered motion into out_*[t − lo],
    from the frames rot (N, J, 4), trans (N, J, 3) holding global frames first …
    first + N − 1; a neighbour's index is clamped to [0, last]."""
    h = (w.shape[0] - 1) // 2
    J = rot.shape[1]
    for t in range(lo, hi):
        c = t - first
        for j in range(J):
            cw, cx, cy, cz = rot[c, j, 0], rot[c, j, 1], rot[c, j, 2], rot[c, j, 3]
            sw = 0.0
            sx = 0.0
            sy = 0.0
            sz = 0.0
            tx = 0.0
            ty = 0.0
            tz = 0.0
            for k in range(w.shape[0]):
                f = min(max(t + k - h, 0), last) - first
                qw, qx, qy, qz = rot[f, j, 0], rot[f, j, 1], rot[f, j, 2], rot[f, j, 3]
                s = w[k] if cw * qw + cx * qx + cy * qy + cz * qz >= 0.0 else -w[k]
                sw += s * qw
                sx += s * qx
                sy += s * qy
                sz += s * qz
                tx += w[k] * trans[f, j, 0]
                ty += w[k] * trans[f, j, 1]
                tz += w[k] * trans[f, j, 2]
            n = math.sqrt(sw * sw + sx * sx + sy * sy + sz * sz)
            if n > 0.0:
                out_rot[t - lo, j, 0] = sw / n
                out_rot[t - lo, j, 1] = sx / n
                out_rot[t - lo, j, 2] = sy / n
                out_rot[t - lo, j, 3] = sz / n
            else:
                out_rot[t - lo, j, 0] = cw
                out_rot[t - lo, j, 1] = cx
                out_rot[t - lo, j, 2] = cy
                out_rot[t - lo, j, 3] = cz
            out_trans[t - lo, j, 0] = tx
            out_trans[t - lo, j, 1] = ty
            out_trans[t - lo, j, 2] = tz


def smooth_poses(rot: np.ndarray, trans: np.ndarray, sigma_frames: float) -> tuple[np.ndarray, np.ndarray]:
    """The filtered rotations (T, J, 4) and translations (T, J, 3) of a whole motion
    (float64 copies; the input when σ ≤ 0)."""
    w = gaussian_taps(sigma_frames)
    if w.size == 1 or rot.shape[0] == 0:
        return rot, trans
    rot = np.ascontiguousarray(rot, dtype=np.float64)
    trans = np.ascontiguousarray(trans, dtype=np.float64)
    T = rot.shape[0]
    out_rot, out_trans = np.empty_like(rot), np.empty_like(trans)
    _smooth(rot, trans, 0, T - 1, w, 0, T, out_rot, out_trans)
    return out_rot, out_trans


class StreamingSmoother:
    """add(first, rot (K, J, 4), trans (K, J, 3)) of the next final frames → (first,
    rot, trans) of the frames whose smoothed pose is now known (the h frames after
    them are in); finish() → the rest, the last frame repeated past the end. Keeps the
    last 2h + 1 frames."""

    def __init__(self, sigma_frames: float, joints: int):
        self.w = gaussian_taps(sigma_frames)
        self.h = (self.w.size - 1) // 2
        self.first = 0  # global index of the buffer's first frame
        self.rot = np.zeros((0, joints, 4))
        self.trans = np.zeros((0, joints, 3))
        self.done = 0  # frames given back

    def add(self, first: int, rot: np.ndarray, trans: np.ndarray):
        if self.h == 0:
            self.done = first + len(rot)
            return first, rot, trans
        if len(rot):
            if first != self.first + len(self.rot):
                raise ValueError(f"frames must arrive in order: expected {self.first + len(self.rot)}, got {first}")
            self.rot = np.concatenate([self.rot, np.asarray(rot, dtype=np.float64)])
            self.trans = np.concatenate([self.trans, np.asarray(trans, dtype=np.float64)])
        end = self.first + len(self.rot)
        return self._give(end - self.h, end - 1 + self.h)  # (no neighbour past the end yet: none clamped there)

    def finish(self):
        end = self.first + len(self.rot)
        return self._give(end, end - 1)

    def _give(self, until: int, last: int):
        """Frames done … until − 1, neighbours clamped to [0, last]."""
        J = self.rot.shape[1]
        if until <= self.done or not len(self.rot):
            return self.done, np.zeros((0, J, 4)), np.zeros((0, J, 3))
        lo = self.done
        out_rot, out_trans = np.empty((until - lo, J, 4)), np.empty((until - lo, J, 3))
        _smooth(self.rot, self.trans, self.first, last, self.w, lo, until, out_rot, out_trans)
        self.done = until
        keep = max(0, self.done - self.h - self.first)  # (frames before done − h: no later frame reaches them)
        if keep:
            self.rot, self.trans = self.rot[keep:], self.trans[keep:]
            self.first += keep
        return lo, out_rot, out_trans

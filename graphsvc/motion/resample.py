"""Resampling motions to a target frame rate: rotations by slerp, translations
linearly ."""

from __future__ import annotations

import numpy as np

from graphsvc.errors import InputError
from graphsvc.motion import quat
from graphsvc.motion.skeleton import Motion


def sample_times(num_frames: int, rate_hz: float, target_hz: float) -> np.ndarray:
    """Source-frame coordinates (float, in frames) of the output frames: the output
    covers the source's time span [0, (F−1)/rate] at the target rate."""
    span = (num_frames - 1) / rate_hz
    count = int(np.floor(span * target_hz + 1e-9)) + 1
    return np.arange(count) * (rate_hz / target_hz)


def resample_arrays(
    rotations: np.ndarray, translations: np.ndarray, rate_hz: float, target_hz: float
) -> tuple[np.ndarray, np.ndarray]:
    """(F, J, 4), (F, J, 3) at rate_hz → (F', J, 4), (F', J, 3) at target_hz."""
    F = rotations.shape[0]
    if F == 0:
        raise InputError("cannot resample a motion with zero frames")
    coords = sample_times(F, rate_hz, target_hz)
    lo = np.minimum(np.floor(coords).astype(np.int64), F - 1)
    hi = np.minimum(lo + 1, F - 1)
    frac = coords - lo
    rot = quat.slerp(rotations[lo], rotations[hi], frac[:, None])
    trans = translations[lo] + (translations[hi] - translations[lo]) * frac[:, None, None]
    return rot, trans


def resample(motion: Motion, target_hz: float) -> Motion:
    """The motion at `target_hz`; returned unchanged (not copied) when rates match."""
    if not (np.isfinite(target_hz) and target_hz > 0):
        raise InputError(f"target rate must be positive, got {target_hz}")
    if abs(motion.rate_hz - target_hz) < 1e-9:
        return motion
    rot, trans = resample_arrays(motion.rotations, motion.translations, motion.rate_hz, target_hz)
    return motion.copy(rotations=rot, translations=trans, rate_hz=float(target_hz))

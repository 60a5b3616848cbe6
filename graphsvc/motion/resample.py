"""Resampling motions to a target frame rate: rotations by slerp, translations
linearly; from a uniform rate (`resample`) or from frames at uneven times
(`resample_times`: a DeepMimic file's per-frame durations)."""

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


def interpolate_frames(
    rotations: np.ndarray, translations: np.ndarray, coords: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(F, J, 4), (F, J, 3) at fractional frame coordinates `coords` (F',) in [0, F−1]:
    slerp and linear interpolation between the two frames each falls between."""
    F = rotations.shape[0]
    if F == 0:
        raise InputError("cannot resample a motion with zero frames")
    lo = np.minimum(np.floor(coords).astype(np.int64), F - 1)
    hi = np.minimum(lo + 1, F - 1)
    frac = coords - lo
    rot = quat.slerp(rotations[lo], rotations[hi], frac[:, None])
    trans = translations[lo] + (translations[hi] - translations[lo]) * frac[:, None, None]
    return rot, trans


def resample_arrays(
    rotations: np.ndarray, translations: np.ndarray, rate_hz: float, target_hz: float
) -> tuple[np.ndarray, np.ndarray]:
    """(F, J, 4), (F, J, 3) at rate_hz → (F', J, 4), (F', J, 3) at target_hz."""
    if rotations.shape[0] == 0:
        raise InputError("cannot resample a motion with zero frames")
    return interpolate_frames(rotations, translations, sample_times(rotations.shape[0], rate_hz, target_hz))


# A clip whose span is a whole number of output frames but for its durations' rounding
# (DeepMimic writes 1/60 s as 0.016666) keeps its last frame within this many frames.
END_TOLERANCE_FRAMES = 0.05


def resample_times(
    rotations: np.ndarray, translations: np.ndarray, times: np.ndarray, target_hz: float
) -> tuple[np.ndarray, np.ndarray]:
    """Frames at times `times` (F,) in seconds, non-decreasing from 0 → frames every
    1/target_hz s over [0, times[-1]]; the last output frame is the last frame when the
    span falls short of a whole output frame by less than END_TOLERANCE_FRAMES."""
    times = np.asarray(times, dtype=np.float64)
    if times.shape != (rotations.shape[0],) or times.size == 0:
        raise InputError("resampling needs one time per frame and at least one frame")
    if np.any(np.diff(times) < 0):
        raise InputError("frame times must not decrease")
    count = int(np.floor(times[-1] * target_hz + END_TOLERANCE_FRAMES)) + 1
    at = np.minimum(np.arange(count) / target_hz, times[-1])
    # Frames at one instant (a zero duration): the last of them holds from that instant on.
    keep = np.nonzero(np.append(np.diff(times) > 0, True))[0]
    coords = np.interp(at, times[keep], np.arange(keep.size, dtype=np.float64))
    return interpolate_frames(rotations[keep], translations[keep], coords)


def resample(motion: Motion, target_hz: float) -> Motion:
    """The motion at `target_hz`; returned unchanged (not copied) when rates match."""
    if not (np.isfinite(target_hz) and target_hz > 0):
        raise InputError(f"target rate must be positive, got {target_hz}")
    if abs(motion.rate_hz - target_hz) < 1e-9:
        return motion
    rot, trans = resample_arrays(motion.rotations, motion.translations, motion.rate_hz, target_hz)
    return motion.copy(rotations=rot, translations=trans, rate_hz=float(target_hz))

"""A sensor's orientation as the strategies read it: the orientation cue.

A device reports its orientation in a world frame whose vertical is gravity's and whose
heading is its own: a magnetometer's north, wandering as the device's yaw drifts, and
never the knowledge base's. What can be compared with the knowledge base's sensors is
therefore what a rotation about the vertical leaves alone. Two cues, by layout:

- **Tilt** (`sensor_up`; layouts without a root sensor): per sensor its "up", the
  world's vertical seen in its frame — three values, two degrees of freedom. Yaw-free
  for every sensor on its own, so each device's own yaw drift costs nothing; a forearm
  turning about the vertical is invisible.
- **Relative to the root** (`relative_orientations`; layouts with a sensor on the
  pelvis, `sensors.layout.root_sensor`: kelly6's `lower_back`, dip6's `pelvis`): per
  sensor its rotation in the root sensor's heading frame H⁻¹·R_s, H the root's rotation
  about the vertical (the twist of its quaternion about world +Y), as the nine entries
  of the rotation matrix divided by √2. A rotation about the vertical common to every
  sensor (the unknown global heading, a common heading drift) cancels; each limb keeps
  its tilt against gravity and gains its heading relative to the pelvis, all three
  degrees of freedom, as learned sparse-IMU posers read it (Yi et al. 2021,
  "TransPose: real-time 3D human translation and pose estimation with six inertial
  sensors": orientations relative to the root). The root's own row is its tilt (its
  yaw removed). A device's own yaw drift still moves its heading relative to the
  root's by the difference of the two drifts.

Both cues compare as the chord² between measured and knowledge-base values, which for
both is 2 − 2·cos θ (≈ θ², at most 4) per sensor, θ the angle between the two up
vectors or between the two relative rotations (‖R₁ − R₂‖²_F / 2 = 3 − tr(R₁ᵀR₂)):
the orientation weight W_R means the same for either. `orientation_cue` picks the
cue from the width the graph stores (`graph.edge_up`, (E, S, 3) or (E, S, 9)), so
graphs built before the relative cue keep the tilt.
"""

from __future__ import annotations

import numpy as np

TILT_WIDTH = 3
RELATIVE_WIDTH = 9
WIDTHS = (TILT_WIDTH, RELATIVE_WIDTH)
# The norm of each sensor's row of a cue: a unit up vector; a rotation matrix's
# Frobenius norm √3, divided by √2.
ROW_NORM = {TILT_WIDTH: 1.0, RELATIVE_WIDTH: float(np.sqrt(1.5))}


def sensor_up(orientation: np.ndarray) -> np.ndarray:
    """(..., 3) world +Y seen in the sensor frames of orientations (..., 4) w, x, y, z
    (each the sensor frame's rotation into the world): R(q)ᵀ·ŷ, the second row of R(q),
    a unit vector. NaN orientations give NaN."""
    q = np.asarray(orientation, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)], axis=-1)


def heading_twist(orientation: np.ndarray) -> np.ndarray:
    """(..., 4) the rotation about world +Y in orientations (..., 4): the twist of the
    swing–twist decomposition, (w, 0, y, 0) normalised. A rotation of exactly 180° about
    a horizontal axis has none; it gets the identity. NaN in, NaN out."""
    q = np.asarray(orientation, dtype=np.float64)
    w, y = q[..., 0], q[..., 2]
    norm = np.sqrt(w * w + y * y)
    tiny = norm < 1e-12
    safe = np.where(tiny, 1.0, norm)
    out = np.zeros(q.shape)
    out[..., 0] = np.where(tiny, 1.0, w / safe)
    out[..., 2] = np.where(tiny, 0.0, y / safe)
    return out


def _matrix(q: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices of quaternions (..., 4) w, x, y, z (normalised here)."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )


def relative_orientations(orientation: np.ndarray, root: int) -> np.ndarray:
    """(..., S, 9) each sensor's rotation in the root sensor's heading frame, H⁻¹·R_s
    row-major, ÷ √2 (module docstring), from orientations (..., S, 4) w, x, y, z, each
    the sensor frame's rotation into the world. A sensor whose quaternion, or the
    root's, is missing (NaN or zero) gives NaN."""
    q = np.asarray(orientation, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        h = _matrix(heading_twist(q[..., root, :]))  # (..., 3, 3)
        r = _matrix(q)  # (..., S, 3, 3)
        rel = np.einsum("...ji,...sjk->...sik", h, r)
    return rel.reshape(rel.shape[:-2] + (RELATIVE_WIDTH,)) / np.sqrt(2.0)


def orientation_cue(orientation: np.ndarray, width: int, root: int | None) -> np.ndarray:
    """(..., S, width) the cue of orientations (..., S, 4): the tilt (width 3) or the
    orientations relative to sensor `root` (width 9; root required)."""
    if width == TILT_WIDTH:
        with np.errstate(invalid="ignore", divide="ignore"):
            return sensor_up(orientation)
    if width != RELATIVE_WIDTH or root is None:
        raise ValueError(f"no orientation cue of width {width} with root {root}")
    return relative_orientations(orientation, root)


def normalised_rows(cue: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cue with each sensor's row scaled to its cue's norm (`ROW_NORM`), zeros where
    missing; (..., S) bool where a row is present: finite and non-zero). A resampled
    or noisy row comes back to the norm of an exact one."""
    u = np.asarray(cue, dtype=np.float64)
    norm = np.linalg.norm(u, axis=-1)
    valid = np.isfinite(norm) & (norm > 0)
    scale = ROW_NORM[u.shape[-1]] / np.where(valid, norm, 1.0)
    return np.where(valid[..., None], u * scale[..., None], 0.0), valid

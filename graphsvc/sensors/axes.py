"""A world with +Z up onto graphsvc's world (+Y up, facing +Z, +X the body's left), as
every reader of a device's or an optical capture's file turns it (`sensors.devices`:
MVNX, `sensors.recording`: a device CSV's ``up=z``, `sensors.optical`: C3D and marker
CSV).

The change is cyclic, (x, y, z) → (y, z, x): a Z-up world's X (forward) becomes
graphsvc's Z, its Y (left) X, its Z (up) Y. For points it is a permutation of the
coordinates (`to_y_up`); for orientations it is the rotation Q_Z_UP_TO_Y_UP = (0.5,
−0.5, −0.5, −0.5) (w, x, y, z), −120° about (1, 1, 1)/√3, and a sensor frame's
orientation becomes q_world = Q_Z_UP_TO_Y_UP ⊗ q (`z_up_to_y_up`). Readings stay in each
sensor's own frame, which this does not touch.
"""

from __future__ import annotations

import numpy as np

from graphsvc.motion import quat

# A Z-up world (X forward, Y left) onto graphsvc's Y-up world: (x, y, z) → (y, z, x).
# Its matrix has columns X → (0, 0, 1), Y → (1, 0, 0), Z → (0, 1, 0).
Q_Z_UP_TO_Y_UP = np.array([0.5, -0.5, -0.5, -0.5])


def to_y_up(points: np.ndarray, up: str) -> np.ndarray:
    """(..., 3) points with `up` ("y" or "z") vertical → +Y up (module docstring)."""
    if up == "y":
        return points
    return points[..., [1, 2, 0]]


def z_up_to_y_up(q: np.ndarray) -> np.ndarray:
    """Orientations (..., 4) (w, x, y, z) of sensor frames in a Z-up world (X forward, Y
    left) → the same frames in graphsvc's Y-up world: Q_Z_UP_TO_Y_UP ⊗ q. NaN stays
    NaN; the dtype is kept."""
    q = np.asarray(q)
    return quat.mul(Q_Z_UP_TO_Y_UP, q.astype(np.float64)).astype(q.dtype, copy=False)

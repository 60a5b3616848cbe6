"""A sensor's orientation as the searches read it: its "up", the world's vertical seen
in the sensor's frame. It is all of an orientation a yaw drift leaves alone (a device
without a magnetometer reports a heading that wanders about the vertical), and what the
orientation weight R compares: a recording's measured "up" (`strategies.inputs`)
against the graph's edges' (`graph.metadata.edge_up_vectors`), both by `sensor_up`."""

from __future__ import annotations

import numpy as np


def sensor_up(orientation: np.ndarray) -> np.ndarray:
    """(..., 3) world +Y seen in the sensor frames of orientations (..., 4) w, x, y, z
    (each the sensor frame's rotation into the world): R(q)ᵀ·ŷ, the second row of R(q),
    a unit vector. NaN orientations give NaN."""
    q = np.asarray(orientation, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)], axis=-1)

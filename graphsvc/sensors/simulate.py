"""Clip → input stream: what the body-worn sensors and the overhead tracker would
have reported while the clip was performed ."""

from __future__ import annotations

import numpy as np

from graphsvc.motion import signals
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.resample import resample
from graphsvc.motion.skeleton import Motion, check_finite
from graphsvc.sensors.accelerometer import simulate_accelerations
from graphsvc.sensors.layout import Layout, place
from graphsvc.sensors.noise import NoiseModel, corrupt_accelerations, corrupt_heading, corrupt_positions
from graphsvc.sensors.recording import Recording


def simulate_recording(
    motion: Motion,
    layout: Layout,
    noise: NoiseModel,
    seed: int = 0,
    rate_hz: float | None = None,
    mapping=None,
) -> Recording:
    """A Recording of `motion` at `rate_hz` (default: the clip's rate) with the
    layout's accelerometers, ground position and heading, corrupted by `noise`
    drawn from `np.random.default_rng(seed)` (same seed → same bytes)."""
    check_finite(motion)
    if rate_hz is not None:
        motion = resample(motion, rate_hz)
    rate = motion.rate_hz
    world_rot, world_pos = motion_fk(motion)
    table = joint_map(motion.skeleton, mapping)
    placement = place(layout, motion.skeleton, mapping)
    exact = simulate_accelerations(world_rot, world_pos, placement, rate)
    position = signals.ground_position(world_pos, table["pelvis"])
    heading = signals.heading(world_pos, table)

    rng = np.random.default_rng(seed)
    acc = corrupt_accelerations(exact, noise, rng)
    noisy_position = corrupt_positions(position, noise, rng, rate)
    noisy_heading = corrupt_heading(heading, noisy_position, rate, noise, rng)
    rec = Recording(
        rate_hz=float(rate),
        timestamps_s=np.arange(motion.num_frames, dtype=np.float64) / rate,
        sensor_names=layout.sensor_names,
        accelerations=acc,
        ground_position=noisy_position,
        heading=noisy_heading,
        layout=layout.to_dict(),
        meta={
            "source": motion.source or motion.name,
            "clip": motion.name,
            "labels": list(motion.labels),
            "noise": noise.to_dict(),
            "seed": int(seed),
            "simulated": True,
        },
    )
    rec.validate()
    return rec

"""Clip → input stream: what the body-worn sensors and the overhead tracker would
have reported while the clip was performed (`simulate_recording`), or what an optical
system would have tracked of a marker set, with its gaps and flicker
(`simulate_marker_recording`)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphsvc.errors import InputError
from graphsvc.motion import quat, signals
from graphsvc.motion.joints import JointMapping, joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.resample import resample
from graphsvc.motion.skeleton import Motion, check_finite
from graphsvc.sensors.accelerometer import second_derivative, sensor_poses, to_sensor_frames
from graphsvc.sensors.anatomy import ANATOMICAL
from graphsvc.sensors.device_model import TISSUE_SEGMENTS, impacts, mounting, orientation_output, soft_tissue
from graphsvc.sensors.layout import Layout, anatomical_placement
from graphsvc.sensors.markers import MarkerSet, keep_markers, load_marker_set, marker_positions, place_markers
from graphsvc.sensors.noise import NoiseModel, corrupt_accelerations, corrupt_heading, corrupt_positions
from graphsvc.sensors.recording import Recording


def device_readings(
    world_rot: np.ndarray, world_pos: np.ndarray, placement, table, rate_hz: float, noise: NoiseModel, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """The readings (F, S, 3) m/s² of the layout's sensors as mounted devices, before
    the per-sample noise (`corrupt_accelerations`), and their frames' world orientations
    (F, S, 4): the ideal accelerometer of `sensors.accelerometer`, on soft tissue, with
    foot-strike jolts, each sensor turned by its mounting (`sensors.device_model`; none
    of it unless the noise model asks)."""
    position, orientation = sensor_poses(world_rot, world_pos, placement)
    world_acc = second_derivative(position, rate_hz)
    legs = [k for k, spec in enumerate(placement.layout.sensors) if spec.segment in TISSUE_SEGMENTS]
    if noise.tissue and legs:
        world_acc = world_acc.copy()
        world_acc[:, legs] = soft_tissue(world_acc[:, legs], rate_hz, noise.tissue, noise.tissue_damping)
    if noise.impact:
        contacts = signals.foot_contacts(world_pos, table, rate_hz)
        segments = [s.segment for s in placement.layout.sensors]
        world_acc = world_acc + impacts(contacts, segments, rate_hz, noise.impact)
    device = quat.mul(orientation, mounting(seed, placement.layout.sensor_names, noise.mount)[None])
    return to_sensor_frames(device, world_acc), device


def simulate_recording(
    motion: Motion,
    layout: Layout,
    noise: NoiseModel,
    seed: int = 0,
    rate_hz: float | None = None,
    mapping: JointMapping = None,
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
    placement = anatomical_placement(layout, motion.skeleton, mapping, world_rot, world_pos)
    exact, device = device_readings(world_rot, world_pos, placement, table, rate, noise, seed)
    position = signals.ground_position(world_pos, table["pelvis"])
    heading = signals.heading(world_pos, table)

    rng = np.random.default_rng(seed)
    acc, misalign = corrupt_accelerations(exact, noise, rng, misalignment=True)
    noisy_position = corrupt_positions(position, noise, rng, rate)
    noisy_heading = corrupt_heading(heading, noisy_position, rate, noise, rng)
    orientations = None
    if noise.orientations:
        (orient_rng,) = rng.spawn(1)  # (its own stream: the other draws stay as they were)
        orientations = orientation_output(
            quat.mul(device, misalign[None]), rate, noise.orient_sigma, noise.yaw_drift, orient_rng, noise.heading_drift
        ).astype(np.float32)
    rec = Recording(
        rate_hz=float(rate),
        timestamps_s=np.arange(motion.num_frames, dtype=np.float64) / rate,
        sensor_names=layout.sensor_names,
        accelerations=acc,
        ground_position=noisy_position,
        heading=noisy_heading,
        orientations=orientations,
        layout=layout.to_dict(),
        meta={
            "source": motion.source or motion.name,
            "clip": motion.name,
            "labels": list(motion.labels),
            "noise": noise.to_dict(),
            "seed": int(seed),
            "simulated": True,
            "sensor_frames": ANATOMICAL,  # (the layout's frames' convention, `sensors.anatomy`)
            # (a mounting turns each reading into its device's frame: calibration's input)
            "sensor_frame": "device" if noise.mount else "layout",
            **({"missing_joints": sorted(table.missing)} if getattr(table, "missing", None) else {}),
        },
    )
    rec.validate()
    return rec


# ---------------------------------------------------------------- optical markers

# Random gaps (`MarkerPattern.gap_fraction`) last 5 to 80 samples, the range of Tautges
# 2012, §4.4; a flickering marker stays unseen for 3 samples on average.
GAP_FRAMES = (5, 80)
FLICKER_RUN = 3.0


@dataclass(frozen=True)
class MarkerPattern:
    """How markers are lost: gaps (start, length) in frames of the clip as loaded (every
    marker unseen), flicker: the share of samples each marker is unseen for in short
    dropouts (a two-state chain per marker, FLICKER_RUN samples a dropout on average),
    gap_fraction: random whole gaps (GAP_FRAMES long, none longer than what is still to
    cover, placed by the seed) until this share of samples is in one."""

    gaps: tuple[tuple[int, int], ...] = ()
    flicker: float = 0.0
    gap_fraction: float = 0.0

    def to_dict(self) -> dict:
        return {"gaps": [list(g) for g in self.gaps], "flicker": self.flicker, "gap_fraction": self.gap_fraction}


def parse_gaps(text: str | None) -> tuple[tuple[int, int], ...]:
    """'START:LEN,...' (frames) → ((start, length), ...); InputError for anything else."""
    if not text:
        return ()
    out = []
    for part in str(text).split(","):
        part = part.strip()
        start, sep, length = part.partition(":")
        try:
            s, n = int(start), int(length)
        except ValueError:
            raise InputError(f"gaps must be START:LEN frame counts separated by commas, got {part!r}") from None
        if not sep or s < 0 or n < 1:
            raise InputError(f"gap {part!r}: need START ≥ 0 and LEN ≥ 1 frames")
        out.append((s, n))
    return tuple(out)


def check_pattern(pattern: MarkerPattern) -> None:
    for name in ("flicker", "gap_fraction"):
        v = getattr(pattern, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (0.0 <= v < 1.0):
            raise InputError(f"{name.replace('_', ' ')} must be a share in [0, 1), got {v!r}")


def marker_visibility(
    times_s: np.ndarray, num_markers: int, pattern: MarkerPattern, clip_rate_hz: float, rng: np.random.Generator
) -> np.ndarray:
    """(T, M) bool: whether each marker is seen at each sample time (s, from 0). Draws
    happen in one order whatever the settings (flicker, then random gaps)."""
    check_pattern(pattern)
    T, M = times_s.shape[0], num_markers
    seen = np.ones((T, M), dtype=bool)
    # Flicker: a chain per marker, unseen with stationary probability p, leaving a
    # dropout with probability 1 / FLICKER_RUN per sample.
    u = rng.random((T, M))
    p = float(pattern.flicker)
    if p > 0:
        recover = 1.0 / FLICKER_RUN
        drop = min(1.0, p * recover / (1.0 - p))
        state = u[0] < p
        seen[0] = ~state
        for t in range(1, T):
            state = np.where(state, u[t] >= recover, u[t] < drop)
            seen[t] = ~state
    for start, length in pattern.gaps:
        t0, t1 = start / clip_rate_hz, (start + length) / clip_rate_hz
        seen[(times_s >= t0 - 1e-9) & (times_s < t1 - 1e-9)] = False
    target = int(round(pattern.gap_fraction * T))
    if target > 0:
        in_gap = np.zeros(T, dtype=bool)
        lo, hi = GAP_FRAMES
        while in_gap.sum() < target:
            n = int(rng.integers(lo, hi + 1))
            n = min(n, T, max(lo, target - int(in_gap.sum())))  # (a short clip is not swallowed whole)
            s = int(rng.integers(0, T - n + 1))
            in_gap[s : s + n] = True
        seen[in_gap] = False
    return seen


def simulate_marker_recording(
    motion: Motion,
    marker_set: str | Path | MarkerSet,
    noise: NoiseModel,
    seed: int = 0,
    rate_hz: float | None = None,
    mapping: JointMapping = None,
    keep: Iterable[str] | None = None,
    pattern: MarkerPattern = MarkerPattern(),
) -> Recording:
    """A Recording of `motion`'s labelled optical markers (`sensors.markers`): the set's
    markers (those named in `keep`, or all) placed on the clip's own skeleton, at
    `rate_hz` (default the clip's), lost to `pattern` and moved by `noise.marker` (mm)
    drawn from `np.random.default_rng(seed)` (same seed → same bytes). It carries no
    accelerations; its meta holds the marker set, so `synthesize` needs no --markers."""
    check_finite(motion)
    marker_set = keep_markers(load_marker_set(marker_set), keep)
    clip_rate = float(motion.rate_hz)
    if rate_hz is not None:
        motion = resample(motion, rate_hz)
    rate = float(motion.rate_hz)
    world_rot, world_pos = motion_fk(motion)
    points = marker_positions(world_rot, world_pos, place_markers(marker_set, motion.skeleton, mapping))
    times = np.arange(motion.num_frames, dtype=np.float64) / rate
    rng = np.random.default_rng(seed)
    seen = marker_visibility(times, len(marker_set.markers), pattern, clip_rate, rng)
    points = points + rng.standard_normal(points.shape) * (noise.marker / 1000.0)
    points[~seen] = np.nan
    rec = Recording(
        rate_hz=rate,
        timestamps_s=times,
        sensor_names=(),
        accelerations=None,
        marker_names=marker_set.marker_names,
        marker_positions=points,
        meta={
            "source": motion.source or motion.name,
            "clip": motion.name,
            "labels": list(motion.labels),
            "marker_set": marker_set.to_dict(),
            "pattern": pattern.to_dict(),
            "noise": {"marker": noise.marker},
            "seen": round(float(seen.mean()), 4),
            "seed": int(seed),
            "simulated": True,
        },
    )
    rec.validate()
    return rec

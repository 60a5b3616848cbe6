"""What a real body-worn IMU adds to the ideal accelerometer of `sensors.accelerometer`:
a mounting rotation, soft tissue between bone and sensor, impact transients at foot
strikes, and an orientation output that is noisy and drifts in yaw. `simulate_recording`
applies them when the noise model asks (`sensors.noise`: keys mount, tissue,
tissue_damping, impact, orientations, orient_sigma, yaw_drift; the `real` preset).

- **Mounting** (`mounting`): each sensor strapped on rotated by up to D° about a random
  axis, drawn from the seed and the sensor's name only, so two recordings with one seed
  share a mounting (a calibration take and the match). The sensor then reads in its
  mounted frame, R_mount ⊗ …; the layout's frame is what calibration recovers.
- **Soft tissue** (`soft_tissue`): a sensor on the legs (`TISSUE_SEGMENTS`: thigh,
  shin, foot; the forearms' straps sit on skin close to bone, and the reference
  recording of `tools/fit_real_noise.py` shows them within 1 m/s² of the optical
  track) rides on the skin, a damped spring
  (natural frequency f, damping ratio ζ) on the bone point: with y the sensor's
  displacement from the bone point, ÿ + 2ζω ẏ + ω² y = −a_bone, and the sensor's
  acceleration a_bone + ÿ = −2ζω ẏ − ω² y. Solved exactly between samples with the
  bone's acceleration held (zero-order hold), so a spring faster than the sample rate
  still rings as it would, seen at the samples.
- **Impacts** (`impacts`): at each foot strike (a contact starting, `motion.signals`) the
  leg's sensors take a decaying jolt along the world's vertical, A·e^(−t/τ)·cos(2π f t)
  (τ = 25 ms, f = 15 Hz), full on the shin and foot, half on the thigh, a quarter on
  the pelvis and trunk, none on the arms and head.
- **Orientation output** (`orientation_output`): the device's orientation (mounting and
  misalignment included) turned by white noise of σ degrees about a random axis per
  sample, by a yaw that wanders about the world's vertical (a random walk, degrees
  per √s: a device without a magnetometer), and by a heading drift common to every
  device (a random walk about the vertical too: the world frame the devices share
  turning away from the knowledge base's, as a magnetic field distorted over the
  pitch turns every device's north alike).
"""

from __future__ import annotations

import hashlib

import numpy as np
from scipy.linalg import expm

from graphsvc.motion import quat

TISSUE_SEGMENTS = frozenset({"l_hip", "r_hip", "l_knee", "r_knee", "l_ankle", "r_ankle", "l_toe", "r_toe"})
IMPACT_TAU_S = 0.025
IMPACT_HZ = 15.0
# The share of an impact each segment's sensor takes (the segment's canonical joint).
IMPACT_SHARE = {
    "l_knee": 1.0,
    "r_knee": 1.0,
    "l_ankle": 1.0,
    "r_ankle": 1.0,
    "l_toe": 1.0,
    "r_toe": 1.0,
    "l_hip": 0.5,
    "r_hip": 0.5,
    "pelvis": 0.25,
    "spine": 0.25,
    "chest": 0.25,
}


def mounting(seed: int, names, degrees: float) -> np.ndarray:
    """(S, 4) each sensor's mounting rotation (w, x, y, z): about a uniformly random axis,
    by an angle uniform in [0, degrees], drawn from (seed, sensor name) alone."""
    out = np.zeros((len(names), 4))
    out[:, 0] = 1.0
    if not degrees:
        return out
    for k, name in enumerate(names):
        digest = hashlib.sha256(f"mount/{int(seed)}/{name}".encode()).digest()
        rng = np.random.default_rng(int.from_bytes(digest[:8], "little"))
        axis = rng.standard_normal(3)
        axis /= np.linalg.norm(axis)
        out[k] = quat.from_axis_angle(axis, np.deg2rad(rng.uniform(0.0, degrees)))
    return out


def soft_tissue(world_acc: np.ndarray, rate_hz: float, hz: float, damping: float) -> np.ndarray:
    """(F, ...) bone-point accelerations (m/s², along axis 0 in time) → the sensor's, on a
    damped spring of natural frequency `hz` and damping ratio `damping` (module
    docstring). hz 0: rigid (unchanged)."""
    if not hz:
        return world_acc
    w = 2.0 * np.pi * float(hz)
    A = np.array([[0.0, 1.0], [-w * w, -2.0 * damping * w]])
    B = np.array([0.0, -1.0])
    dt = 1.0 / float(rate_hz)
    # Zero-order hold: [x; u] evolves by expm([[A, B], [0, 0]] dt).
    M = np.zeros((3, 3))
    M[:2, :2], M[:2, 2] = A, B
    E = expm(M * dt)
    Ad, Bd = E[:2, :2], E[:2, 2]
    flat = np.asarray(world_acc, dtype=np.float64).reshape(world_acc.shape[0], -1)
    state = np.zeros((2, flat.shape[1]))  # (y, ẏ) per channel: settled on the first acceleration
    state[0] = -flat[0] / (w * w)
    out = np.empty_like(flat)
    for t in range(flat.shape[0]):
        out[t] = -w * w * state[0] - 2.0 * damping * w * state[1]
        state = Ad @ state + np.outer(Bd, flat[t])
    return out.reshape(world_acc.shape)


def impacts(contacts: np.ndarray, segments, rate_hz: float, amplitude: float) -> np.ndarray:
    """(F, S, 3) world accelerations (m/s²) of foot-strike jolts: contacts (F, 2) bool
    (left, right), segments (S,) each sensor's canonical segment name."""
    F = contacts.shape[0]
    out = np.zeros((F, len(segments), 3))
    if not amplitude:
        return out
    t = np.arange(F) / float(rate_hz)
    for side, prefix in enumerate(("l_", "r_")):
        strikes = np.flatnonzero(contacts[1:, side] & ~contacts[:-1, side]) + 1
        pulse = np.zeros(F)
        for s0 in strikes:
            dt = t[s0:] - t[s0]
            pulse[s0:] += np.exp(-dt / IMPACT_TAU_S) * np.cos(2.0 * np.pi * IMPACT_HZ * dt)
        for k, seg in enumerate(segments):
            share = IMPACT_SHARE.get(seg, 0.0)
            if seg.startswith(("l_", "r_")) and not seg.startswith(prefix):
                continue  # (the other leg's strike)
            if not seg.startswith(("l_", "r_")):
                share *= 0.5  # (the trunk takes half of each foot's)
            out[:, k, 1] += amplitude * share * pulse
    return out


def orientation_output(
    orientation: np.ndarray,
    rate_hz: float,
    sigma_deg: float,
    yaw_drift_deg: float,
    rng: np.random.Generator,
    heading_drift_deg: float = 0.0,
) -> np.ndarray:
    """(F, S, 4) the device orientations a real IMU would report: white rotation noise of
    σ degrees about a random axis a sample, a yaw about world +Y wandering
    `yaw_drift_deg` per √s (a random walk from 0) for each device, and one wandering
    `heading_drift_deg` per √s common to all (drawn after the others: a model without
    it reports what it did before, bit for bit)."""
    F, S = orientation.shape[:2]
    axis = rng.standard_normal((F, S, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    angle = np.deg2rad(sigma_deg) * rng.standard_normal((F, S))
    yaw = np.cumsum(rng.standard_normal((F, S)), axis=0) * np.deg2rad(yaw_drift_deg) / np.sqrt(float(rate_hz))
    yaw -= yaw[:1]
    noisy = quat.mul(quat.from_axis_angle(axis, angle), orientation)
    if heading_drift_deg:
        common = np.cumsum(rng.standard_normal(F)) * np.deg2rad(heading_drift_deg) / np.sqrt(float(rate_hz))
        yaw = yaw + (common - common[0])[:, None]
    return quat.normalize(quat.mul(quat.about_y(yaw), noisy))

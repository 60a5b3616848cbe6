"""The sensor noise model and its presets.

Applied in the order a real device produces it: the sensor is mounted slightly
rotated about its X axis (misalignment), each axis has a constant bias, white noise
is added, the ADC clips at ±range g, and some samples are lost (NaN). The overhead
tracker errs as trackers do: white noise per sample, a systematic offset (a fixed
distance in a direction drawn per recording: Kelly et al. measured 13.7 cm between
their overhead camera and Vicon) and a slowly wandering error (a random walk, σ per
√s), and loses samples; heading comes from the exact pose, a noisy copy of it, the rule
of Kelly et al. 2013, §6, from the (noisy) track, or is absent.

Optical markers err by white noise of σ `marker` millimetres per axis (their
dropouts and gaps are a pattern of their own: `sensors.simulate.marker_visibility`).

Spec strings: a preset name, optionally followed by overrides, or overrides alone
(starting from `none`): "default", "default,drop=0.02", "sigma=0.3,bias=0.1".
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np

from graphsvc.errors import InputError
from graphsvc.motion import quat
from graphsvc.sensors.accelerometer import GRAVITY

HEADING_MODES = ("exact", "noisy", "rule", "none")


@dataclass(frozen=True)
class NoiseModel:
    sigma: float = 0.0  # white noise, m/s² (per axis, per sample)
    bias: float = 0.0  # constant bias per sensor and axis, uniform in ±bias m/s²
    misalign: float = 0.0  # rotation about sensor X, uniform in ±misalign degrees
    range: float = float("inf")  # clipping at ±range g
    drop: float = 0.0  # probability that a sensor's sample is lost (NaN)
    position: float = 0.0  # overhead-tracker ground-position noise σ, metres
    position_drop: float = 0.0  # probability that a tracker sample is lost
    position_offset: float = 0.0  # systematic tracker offset, metres, in a direction drawn per recording
    position_walk: float = 0.0  # wandering tracker error: a random walk, metres per √s on each axis
    heading: str = "exact"  # exact | noisy | rule | none
    heading_sigma: float = 0.0  # degrees, for heading=noisy
    rest_heading: float = 0.0  # degrees, for heading=rule: facing when slower than speed_threshold
    speed_threshold: float = 2.0  # m/s, for heading=rule
    marker: float = 0.0  # optical marker position noise σ, millimetres (per axis, per sample)
    # A real device (`sensors.device_model`):
    mount: float = 0.0  # mounting rotation about a random axis per sensor, up to this many degrees
    tissue: float = 0.0  # soft tissue: natural frequency (Hz) of the spring between bone and sensor; 0: rigid
    tissue_damping: float = 0.3  # its damping ratio
    impact: float = 0.0  # foot-strike jolt on the shins, m/s² (less up the leg and trunk)
    orientations: float = 0.0  # 1: the recording carries the devices' orientation output
    orient_sigma: float = 0.0  # its white noise, degrees
    yaw_drift: float = 0.0  # its yaw random walk, degrees per √s
    heading_drift: float = 0.0  # a yaw random walk common to every device, degrees per √s

    def to_dict(self) -> dict:
        out = asdict(self)
        out["range"] = None if np.isinf(self.range) else self.range
        return out


PRESETS: dict[str, NoiseModel] = {
    "none": NoiseModel(),
    # The evaluation defaults (Kelly et al.'s ±12 g sensors, tracker σ = 10 cm).
    # Markers: an optical system's typical 1 mm.
    "default": NoiseModel(
        sigma=0.5, bias=0.2, misalign=5.0, range=12.0, position=0.10, heading="noisy", heading_sigma=10.0, marker=1.0
    ),
    # The default sensors with a tracker that errs as real ones do: offset by Kelly et
    # al.'s 13.7 cm and wandering 3 cm per √s (10 cm after 10 s, 23 cm after a minute).
    "tracker": NoiseModel(
        sigma=0.5,
        bias=0.2,
        misalign=5.0,
        range=12.0,
        position=0.10,
        heading="noisy",
        heading_sigma=10.0,
        position_offset=0.137,
        position_walk=0.03,
        marker=1.0,
    ),
    # A poorly mounted, lossy setup for robustness checks.
    # Real IMUs (`sensors.device_model`; fitted by tools/fit_real_noise.py so simulated
    # forearm and shin sensors differ from their ideal selves as a real recording's
    # differed from its optical track: gravity-free norms 0.86 and 5.5 m/s² RMS,
    # correlations 0.99 and 0.70, against 0.8–1.0 / 0.99 and 5.4–5.6 / 0.6–0.7): white
    # noise 0.8 m/s², the legs' sensors on a 3 Hz spring damped 0.5, 20 m/s² jolts at foot
    # strikes; an orientation output with 2° of noise, each device's yaw drifting 0.5° per
    # √s and the heading they share 1° per √s; the default tracker.
    "real": NoiseModel(
        sigma=0.8,
        bias=0.2,
        misalign=5.0,
        range=12.0,
        position=0.10,
        heading="noisy",
        heading_sigma=10.0,
        marker=1.0,
        tissue=3.0,
        tissue_damping=0.5,
        impact=20.0,
        orientations=1.0,
        orient_sigma=2.0,
        yaw_drift=0.5,
        heading_drift=1.0,
    ),
    "harsh": NoiseModel(
        sigma=1.0,
        bias=0.5,
        misalign=10.0,
        range=8.0,
        drop=0.05,
        position=0.30,
        position_drop=0.05,
        heading="rule",
        heading_sigma=20.0,
        marker=5.0,
    ),
}


def parse_noise(spec: str) -> NoiseModel:
    """Parse "PRESET[,key=value...]" or "key=value[,...]" into a NoiseModel."""
    parts = [p.strip() for p in spec.split(",") if p.strip()]
    if not parts:
        raise InputError("empty noise specification")
    model = PRESETS["none"]
    if "=" not in parts[0]:
        if parts[0] not in PRESETS:
            raise InputError(f"unknown noise preset {parts[0]!r} (presets: {', '.join(PRESETS)})")
        model = PRESETS[parts[0]]
        parts = parts[1:]
    names = {f.name: f.type for f in fields(NoiseModel)}
    changes: dict[str, Any] = {}  # (heading: a mode, the others numbers)
    for part in parts:
        key, _, value = part.partition("=")
        key = key.strip().replace("-", "_")
        if key not in names or not value:
            raise InputError(f"bad noise option {part!r}; options: {', '.join(names)}")
        if key == "heading":
            if value not in HEADING_MODES:
                raise InputError(f"heading must be one of {', '.join(HEADING_MODES)}, got {value!r}")
            changes[key] = value
            continue
        try:
            number = float(value)
        except ValueError:
            raise InputError(f"noise option {key} needs a number, got {value!r}") from None
        if np.isnan(number) or number < 0 or (key in ("drop", "position_drop") and number > 1):
            raise InputError(f"noise option {key}={value} is out of range")
        if key == "orientations" and number not in (0.0, 1.0):
            raise InputError(f"noise option orientations is 0 or 1, got {value!r}")
        if key == "mount" and number > 180:
            raise InputError(f"noise option mount is at most 180 degrees, got {value!r}")
        changes[key] = number
    return replace(model, **changes)


def corrupt_accelerations(acc: np.ndarray, model: NoiseModel, rng: np.random.Generator, misalignment: bool = False):
    """(T, S, 3) exact readings in m/s² → noisy float32 readings (NaN = dropped); with
    misalignment, also (S, 4) each sensor's misalignment rotation (about its X)."""
    T, S, _ = acc.shape
    out = acc.astype(np.float64)
    # Draws happen in a fixed order whatever the settings, so one option changing
    # does not reshuffle the noise of the others for the same seed.
    angles = np.deg2rad(rng.uniform(-1.0, 1.0, S) * model.misalign)
    bias = rng.uniform(-1.0, 1.0, (S, 3)) * model.bias
    white = rng.standard_normal((T, S, 3)) * model.sigma
    lost = rng.random((T, S)) < model.drop
    mount = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), angles)
    if model.misalign:
        out = quat.inv_rotate(mount[None], out)
    out = out + bias[None] + white
    limit = model.range * GRAVITY
    out = np.clip(out, -limit, limit)
    out[lost] = np.nan
    return (out.astype(np.float32), mount) if misalignment else out.astype(np.float32)


def corrupt_positions(
    position: np.ndarray, model: NoiseModel, rng: np.random.Generator, rate_hz: float = 30.0
) -> np.ndarray:
    """(T, 2) ground positions in metres at `rate_hz` → noisy copy, NaN where the tracker
    lost the player. The offset and the random walk are drawn from a generator spawned
    from rng, which leaves rng's own draws (white noise, losses, and what is drawn
    after) as they were without them."""
    white = rng.standard_normal(position.shape) * model.position
    lost = rng.random(position.shape[0]) < model.position_drop
    out = position + white
    if model.position_offset or model.position_walk:
        (drift_rng,) = rng.spawn(1)
        angle = drift_rng.uniform(0.0, 2.0 * np.pi)
        offset = model.position_offset * np.array([np.cos(angle), np.sin(angle)])
        steps = drift_rng.standard_normal(position.shape) * (model.position_walk / np.sqrt(float(rate_hz)))
        out = out + offset + np.cumsum(steps, axis=0)
    out[lost] = np.nan
    return out


def heading_from_track(
    position: np.ndarray,
    rate_hz: float,
    speed_threshold: float = 2.0,
    rest_heading: float = 0.0,
    window_s: float = 0.5,
) -> np.ndarray:
    """Kelly et al. 2013, §6: face the direction of travel while moving faster than `speed_threshold`
    (m/s), else `rest_heading` (radians; e.g. facing the net). position: (T, 2) (x, z)
    metres, NaN allowed. Velocity from a Savitzky–Golay fit over `window_s`, which
    tames the tracker's noise (σ = 10 cm at 30 Hz would make raw differences useless)."""
    from scipy.signal import savgol_filter

    T = position.shape[0]
    out = np.full(T, float(rest_heading))
    valid = np.all(np.isfinite(position), axis=-1)
    if valid.sum() < 2:
        return out
    t = np.arange(T)
    filled = np.stack([np.interp(t, t[valid], position[valid, k]) for k in range(2)], axis=-1)
    window = int(round(window_s * rate_hz)) | 1
    window = min(window, T if T % 2 else T - 1)
    if window >= 3:
        velocity = savgol_filter(filled, window, polyorder=min(2, window - 1), deriv=1, axis=0) * rate_hz
    else:
        velocity = np.gradient(filled, axis=0) * rate_hz
    speed = np.linalg.norm(velocity, axis=-1)
    moving = speed > speed_threshold
    out[moving] = np.arctan2(velocity[moving, 0], velocity[moving, 1])
    return out


def corrupt_heading(
    heading: np.ndarray, noisy_position: np.ndarray, rate_hz: float, model: NoiseModel, rng: np.random.Generator
) -> np.ndarray | None:
    """(T,) heading in radians as the chosen heading source would report it."""
    white = rng.standard_normal(heading.shape[0])
    if model.heading == "none":
        return None
    if model.heading == "exact":
        return heading.copy()
    if model.heading == "noisy":
        return quat.wrap_angle(heading + np.deg2rad(model.heading_sigma) * white)
    return heading_from_track(noisy_position, rate_hz, model.speed_threshold, np.deg2rad(model.rest_heading))


class CausalTrackHeading:
    """`heading_from_track` for live streams: the velocity is the least-squares slope
    of the last `window_s` of positions (no look-ahead), so a stream's heading can be
    derived sample by sample. Same rule: direction of travel above
    `speed_threshold` (m/s), else `rest_heading` (rad). NaN positions are skipped."""

    def __init__(self, rate_hz: float, speed_threshold: float = 2.0, rest_heading: float = 0.0, window_s: float = 0.5):
        self.rate_hz = float(rate_hz)
        self.speed_threshold = float(speed_threshold)
        self.rest_heading = float(rest_heading)
        self.size = max(2, int(round(window_s * rate_hz)))
        self.times = np.full(self.size, np.nan)
        self.points = np.full((self.size, 2), np.nan)
        self.t = 0

    def push(self, position) -> float:
        """Heading (rad) at this sample given its (2,) position in metres (or None)."""
        k = self.t % self.size
        self.t += 1
        p = np.full(2, np.nan) if position is None else np.asarray(position, dtype=np.float64)
        self.times[k] = (self.t - 1) / self.rate_hz
        self.points[k] = p
        valid = np.isfinite(self.points).all(axis=1) & np.isfinite(self.times)
        if valid.sum() < 2:
            return self.rest_heading
        t = self.times[valid] - self.times[valid].mean()
        denom = float(t @ t)
        if denom <= 0:
            return self.rest_heading
        velocity = t @ (self.points[valid] - self.points[valid].mean(axis=0)) / denom
        if float(np.hypot(velocity[0], velocity[1])) > self.speed_threshold:
            return float(np.arctan2(velocity[0], velocity[1]))
        return self.rest_heading

"""Procedural motion knowledge base: labelled clips synthesised without any data.

A clip is first *planned* as sparse keys, then *rendered* to per-frame arrays:

- scalar channels (pelvis ground position, height, heading, trunk twist/lean, wrist
  targets in the chest frame, elbow pole directions, ...) keyed at step or action
  times and interpolated with PCHIP, which is C1 and never overshoots the keys (so
  holds stay still and extremes stay where they were authored);
- foot *plants*: per foot, intervals [t_land, t_off] during which the foot is fixed
  to the ground at an anchor (heel rising about the planted toe at the end of the
  stance), joined by minimum-jerk swing arcs.

Rendering solves analytic two-bone IK for the legs (hip → knee → ankle, knee toward
the foot's heading) and the arms (shoulder → elbow → wrist, elbow toward a keyed
pole), after lowering the pelvis just enough for both ankles to stay reachable, so
planted feet never slide. Locomotion keys come from a footstep planner (cadence,
duty factor and step length as functions of speed: walking has double support,
running a flight phase); swings and punches are authored key poses with footwork
and weight shifts. Everything is deterministic given a seed
(`np.random.default_rng(seed)` is the only source of randomness).

Conventions: metres, seconds, radians; Y up, ground y = 0; heading is the
rotation about +Y, 0 facing +Z, the character's left is +X; the rest pose is a
T-pose. Per-frame content labels of a performance are returned alongside it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.ndimage import gaussian_filter1d, maximum_filter1d

from graphsvc.motion import quat
from graphsvc.motion.skeleton import Motion, Skeleton

ROOT_CHANNELS = (
    "Xposition",
    "Yposition",
    "Zposition",
    "Zrotation",
    "Xrotation",
    "Yrotation",
)
JOINT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")

CONTENT_LABELS = (
    "walk",
    "run",
    "stop",
    "idle",
    "forehand",
    "backhand",
    "overhead",
    "punch",
)

# Adult of ~1.75 m (head_End at 1.73 m), T-pose, faces +Z, left is +X.
_BONES = (  # name, parent, offset (m)
    ("pelvis", None, (0.0, 0.99, 0.0)),
    ("spine", "pelvis", (0.0, 0.10, 0.0)),
    ("chest", "spine", (0.0, 0.14, 0.0)),
    ("neck", "chest", (0.0, 0.22, 0.0)),
    ("head", "neck", (0.0, 0.10, 0.0)),
    ("head_End", "head", (0.0, 0.18, 0.0)),
    ("l_shoulder", "chest", (0.17, 0.19, 0.0)),
    ("l_elbow", "l_shoulder", (0.29, 0.0, 0.0)),
    ("l_wrist", "l_elbow", (0.26, 0.0, 0.0)),
    ("l_wrist_End", "l_wrist", (0.18, 0.0, 0.0)),
    ("r_shoulder", "chest", (-0.17, 0.19, 0.0)),
    ("r_elbow", "r_shoulder", (-0.29, 0.0, 0.0)),
    ("r_wrist", "r_elbow", (-0.26, 0.0, 0.0)),
    ("r_wrist_End", "r_wrist", (-0.18, 0.0, 0.0)),
    ("l_hip", "pelvis", (0.09, -0.07, 0.0)),
    ("l_knee", "l_hip", (0.0, -0.42, 0.0)),
    ("l_ankle", "l_knee", (0.0, -0.42, 0.0)),
    ("l_toe", "l_ankle", (0.0, -0.06, 0.13)),
    ("l_toe_End", "l_toe", (0.0, 0.0, 0.05)),
    ("r_hip", "pelvis", (-0.09, -0.07, 0.0)),
    ("r_knee", "r_hip", (0.0, -0.42, 0.0)),
    ("r_ankle", "r_knee", (0.0, -0.42, 0.0)),
    ("r_toe", "r_ankle", (0.0, -0.06, 0.13)),
    ("r_toe_End", "r_toe", (0.0, 0.0, 0.05)),
)
_IDX = {name: i for i, (name, _, _) in enumerate(_BONES)}
_OFF = {name: np.array(off) for name, _, off in _BONES}

THIGH = 0.42
SHIN = 0.42
UPPER_ARM = 0.29
FOREARM = 0.26
ANKLE_H = 0.08  # ankle height above ground with the foot flat (m)
TOE_H = 0.02  # toe (ball) height with the foot flat (m)
TOE_FROM_ANKLE = _OFF["l_toe"]  # (3,) foot frame
PELVIS_H = 0.99  # rest pelvis height (m)
STAND_H = (
    PELVIS_H - 0.01
)  # knees a touch soft when standing (hip–ankle at 98.8 % of the leg)
STAND_W = 0.10  # lateral half-distance between standing feet (m)
G = 9.81


def standard_skeleton() -> Skeleton:
    """The procedural skeleton: 19 canonical joints plus 5 end sites (head, hand
    tips, toe tips). Root channels: position + ZXY rotation; others ZXY rotation."""
    names = tuple(n for n, _, _ in _BONES)
    parents = np.array([-1 if p is None else _IDX[p] for _, p, _ in _BONES])
    end = np.array([n.endswith("_End") for n in names])
    channels = tuple(
        ROOT_CHANNELS if p is None else () if n.endswith("_End") else JOINT_CHANNELS
        for n, p, _ in _BONES
    )
    offsets = np.array([off for _, _, off in _BONES], dtype=float)
    return Skeleton(names, parents, offsets, channels, end)


# --------------------------------------------------------------------------- maths


def _fwd(heading: float) -> np.ndarray:
    """Ground-plane (x, z) forward direction at `heading`."""
    return np.array([np.sin(heading), np.cos(heading)])


def _left(heading: float) -> np.ndarray:
    """Ground-plane (x, z) left direction at `heading` (+X at heading 0)."""
    return np.array([np.cos(heading), -np.sin(heading)])


def _min_jerk(tau: np.ndarray) -> np.ndarray:
    """0 → 1 with zero velocity and acceleration at both ends (C2)."""
    tau = np.clip(tau, 0.0, 1.0)
    return tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)


def _bump(tau: np.ndarray) -> np.ndarray:
    """0 → 1 → 0 over [0, 1], peak at 0.5, C2 at the ends."""
    tau = np.clip(tau, 0.0, 1.0)
    return 64.0 * tau**3 * (1.0 - tau) ** 3


def _rot_x(angle: np.ndarray) -> np.ndarray:
    return quat.from_axis_angle(
        np.array([1.0, 0.0, 0.0]), np.asarray(angle, dtype=float)
    )


def _rot_z(angle: np.ndarray) -> np.ndarray:
    return quat.from_axis_angle(
        np.array([0.0, 0.0, 1.0]), np.asarray(angle, dtype=float)
    )


def _frame(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrix with columns a, b, a × b (a ⟂ b, unit)."""
    return np.stack([a, b, np.cross(a, b)], axis=-1)


@numba.njit(cache=True)
def _bend_directions(u, pole):
    """Unit directions (F, 3) ⟂ u toward which the middle joint bends: the pole's
    component across the limb where the pole is well across it, otherwise (pole
    nearly along the limb) the previous frame's direction carried over, blended
    smoothly, so the elbow never flips when a pole and a limb line up."""
    F = u.shape[0]
    out = np.empty((F, 3))
    prev = np.zeros(3)
    for t in range(F):
        pn = pole[t] / max(np.sqrt(np.sum(pole[t] ** 2)), 1e-12)
        b = pn - np.sum(pn * u[t]) * u[t]
        n = np.sqrt(np.sum(b * b))
        w = min(1.0, max(0.0, (n - 0.15) / 0.45))
        w = w * w * (3.0 - 2.0 * w)
        if t == 0 or w >= 1.0:
            c = b
        else:
            q = prev - np.sum(prev * u[t]) * u[t]
            c = w * b / max(n, 1e-12) + (1.0 - w) * q
        cn = np.sqrt(np.sum(c * c))
        if cn < 1e-9:  # fully degenerate: any perpendicular
            c = (
                np.array([u[t, 1], -u[t, 0], 0.0])
                if abs(u[t, 2]) < 0.9
                else np.array([0.0, u[t, 2], -u[t, 1]])
            )
            cn = np.sqrt(np.sum(c * c))
        out[t] = c / cn
        prev = out[t]
    return out


def two_bone_ik(
    root, target, pole, parent_rot, l1, l2, rest_dir, rest_pole, soft=False
):
    """Analytic two-bone IK over frames.

    root, target, pole: (F, 3) world positions of the first joint, the end effector
    target and a direction the middle joint should bend toward. parent_rot: (F, 4)
    world rotation of the first joint's parent. l1, l2: bone lengths (m). rest_dir:
    (3,) direction of both bones in the rest pose; rest_pole: (3,) direction in
    which the middle joint moves when the limb bends in the rest frame.
    Returns local rotations (F, 4) of the first and middle joints and the first
    joint's world rotation (F, 4). Out-of-reach targets are clamped to 99.95 % of
    full extension, so the caller must keep targets reachable; with soft=True,
    distances beyond 85 % of full extension saturate smoothly below 98 % instead (near
    full extension the middle joint's position changes infinitely fast with the
    distance, which would spike its acceleration)."""
    vec = target - root
    dist = np.linalg.norm(vec, axis=-1, keepdims=True)
    u = vec / np.maximum(dist, 1e-9)
    if soft:
        r0, r1 = 0.85 * (l1 + l2), 0.98 * (l1 + l2)
        dist = np.where(
            dist > r0, r0 + (r1 - r0) * np.tanh((dist - r0) / (r1 - r0)), dist
        )
    d = np.clip(dist, abs(l1 - l2) + 1e-3, (l1 + l2) * 0.9995)
    cos_a = np.clip((l1 * l1 + d * d - l2 * l2) / (2.0 * l1 * d), -1.0, 1.0)
    sin_a = np.sqrt(1.0 - cos_a * cos_a)
    b = _bend_directions(
        np.ascontiguousarray(u.reshape(-1, 3)),
        np.ascontiguousarray(pole.reshape(-1, 3)),
    )
    dir1 = cos_a * u + sin_a * b
    perp1 = -sin_a * u + cos_a * b
    mid = root + l1 * dir1
    dir2 = (root + d * u) - mid
    dir2 /= np.linalg.norm(dir2, axis=-1, keepdims=True)
    rest = _frame(np.asarray(rest_dir, float), np.asarray(rest_pole, float))
    world1 = quat.from_matrix(_frame(dir1, perp1) @ rest.T)
    local1 = quat.mul(quat.conjugate(parent_rot), world1)
    local2 = quat.between(
        np.broadcast_to(np.asarray(rest_dir, float), dir2.shape),
        quat.inv_rotate(world1, dir2),
    )
    return local1, local2, world1


# --------------------------------------------------------------------------- plan

NEUTRAL = {
    "px": 0.0, "pz": 0.0, "py": STAND_H, "yaw": 0.0, "pyaw": 0.0, "lean": 0.02, "roll": 0.0,
    "twist": 0.0, "tlean": 0.02, "tside": 0.0, "hyaw": 0.0, "hpitch": 0.0,
    # wrist targets relative to the shoulder, chest frame, x positive away from the midline
    "l_wx": 0.03, "l_wy": -0.52, "l_wz": 0.07, "r_wx": 0.03, "r_wy": -0.52, "r_wz": 0.07,
    # elbow pole directions, same convention
    "l_px": 0.3, "l_py": 0.0, "l_pz": -1.0, "r_px": 0.3, "r_py": 0.0, "r_pz": -1.0,
    "l_hand": 0.0, "r_hand": 0.0,
}  # fmt: skip
_HANG = (0.03, -0.52, 0.07)
_BACK_POLE = (0.3, 0.0, -1.0)


@dataclass
class _Plant:
    """A foot fixed to the ground over [t_land, t_off] with its flat-foot ankle at
    (x, ANKLE_H, z) and the foot facing `heading`. `heel` (rad) is how far the heel
    has risen about the toe by t_off over the last `heel_s` seconds; `lift` (m) is the
    extra ankle clearance of the swing that *leads to* this plant."""

    t_land: float
    t_off: float
    x: float
    z: float
    heading: float
    heel: float = 0.0
    heel_s: float = 0.0
    lift: float = 0.05


@dataclass
class _Plan:
    """Sparse keys of one clip. `t` is the time up to which the plan is authored;
    `base` the pelvis ground point (x, z) and `heading` the body heading there."""

    keys: dict = field(default_factory=lambda: {k: [] for k in NEUTRAL})
    plants: tuple = field(default_factory=lambda: ([], []))  # left, right
    segments: list = field(default_factory=list)  # (t0, t1, label)
    t: float = 0.0
    base: np.ndarray = field(default_factory=lambda: np.zeros(2))
    heading: float = 0.0
    v: float = 0.0
    next_foot: int = 0

    def key(self, name: str, t: float, value: float) -> None:
        self.keys[name].append((float(t), float(value)))

    def last(self, name: str) -> float:
        return self.keys[name][-1][1] if self.keys[name] else NEUTRAL[name]

    def hold(self, t: float, names=None) -> None:
        """Pin channels at their current values at time t, so later keys start
        moving only from t (PCHIP would otherwise ease from the previous key)."""
        for n in names or self.keys:
            self.key(n, t, self.last(n))

    def wrist(self, side: str, t: float, rel, pole=None, hand=None) -> None:
        """Key a wrist target (x away from the midline, y up, z forward, metres from
        the shoulder in the chest frame) and optionally the elbow pole / hand flex."""
        for c, v in zip("xyz", rel):
            self.key(f"{side}_w{c}", t, v)
        if pole is not None:
            for c, v in zip("xyz", pole):
                self.key(f"{side}_p{c}", t, v)
        if hand is not None:
            self.key(f"{side}_hand", t, hand)

    def pelvis_at(self, t: float, xz, **values) -> None:
        self.key("px", t, xz[0])
        self.key("pz", t, xz[1])
        for k, v in values.items():
            self.key(k, t, v)

    def anchor(self, foot: int) -> np.ndarray:
        p = self.plants[foot][-1]
        return np.array([p.x, p.z])

    def step(
        self,
        foot: int,
        t_lift: float,
        t_land: float,
        xz,
        heading: float,
        heel=0.0,
        heel_s=0.0,
        lift=0.05,
    ):
        """End the foot's current plant at t_lift (heel rising `heel` rad over the last
        `heel_s` s of it) and plant it again at t_land at ankle ground point xz."""
        prev = self.plants[foot][-1]
        t_lift = max(t_lift, prev.t_land + 0.15)
        t_land = max(t_land, t_lift + 0.18)
        prev.t_off = t_lift
        prev.heel = heel
        prev.heel_s = (
            min(heel_s, 0.45 * (t_lift - prev.t_land))
            if np.isfinite(prev.t_land)
            else heel_s
        )
        self.plants[foot].append(
            _Plant(t_land, np.inf, float(xz[0]), float(xz[1]), heading, lift=lift)
        )
        return t_land

    def body(self, x: float, z: float, heading=None) -> np.ndarray:
        """Ground point x left / z forward of the current base, in world (x, z)."""
        h = self.heading if heading is None else heading
        return self.base + x * _left(h) + z * _fwd(h)


def _new_plan(rng, heading=None) -> _Plan:
    plan = _Plan()
    plan.heading = float(rng.uniform(-np.pi, np.pi)) if heading is None else heading
    plan.base = np.zeros(2)
    for foot, side in ((0, 1.0), (1, -1.0)):
        xz = plan.base + side * STAND_W * _left(plan.heading)
        plan.plants[foot].append(
            _Plant(-np.inf, np.inf, xz[0], xz[1], plan.heading + side * 0.08)
        )
    for k, v in NEUTRAL.items():
        plan.key(k, 0.0, v)
    plan.pelvis_at(0.0, plan.base, yaw=plan.heading)
    return plan


# --------------------------------------------------------------------------- locomotion


def _gait(v: float, run: bool) -> tuple[float, float, bool]:
    """Cadence (steps/s) and duty factor (stance fraction of a stride) at speed v
    (m/s). Walking duty > 0.5 gives double support, running duty < 0.5 a flight."""
    if run and v >= 1.0:  # decelerating runners keep jogging down to ~1 m/s
        return 2.55 + 0.12 * v, min(0.45, 0.36 - 0.015 * (v - 2.5)), True
    v = min(v, 2.0)
    return 1.25 + 0.5 * v, 0.64 - 0.03 * v, False


def _smooth_curve(
    rng, t0: float, t1: float, every: float, lo: float, hi: float, zero_prob=0.3
):
    """A smooth random function on [t0, t1]: (times, values) to use with np.interp
    after PCHIP densification; values in [lo, hi], some segments exactly 0."""
    n = max(2, int(np.ceil((t1 - t0) / every)) + 2)
    times = t0 + np.arange(n) * every
    vals = rng.uniform(lo, hi, n)
    vals[rng.random(n) < zero_prob] = 0.0
    dense_t = np.linspace(times[0], times[-1], 20 * n)
    return dense_t, PchipInterpolator(times, vals)(dense_t)


def _locomote(
    plan: _Plan,
    rng,
    run: bool,
    v_target: float,
    t_end: float,
    turn=None,
    stop=True,
    label=None,
):
    """Footstep planner: steps from plan.t until t_end at v_target (accelerating from
    the current speed), turning at rate `turn` ((times, rad/s) curve), then, if
    `stop`, decelerating to a standstill with a closing step beside the stance foot.

    Keys per step: pelvis ground point and heading at mid-stance (swayed toward the
    stance foot), pelvis height at mid-stance and between mid-stances (walk: high /
    low, run: low / high), pelvis yaw, trunk counter-twist and arm swing at landing."""
    t = plan.t
    t_start = t
    v = plan.v
    th = plan.heading
    b = plan.base.copy()
    accel = 2.5 if run else 1.2
    decel = 3.0 if run else 1.3
    if v == 0.0:
        plan.hold(t)
    T_prev = 1.0 / _gait(v, run)[0]
    first = v == 0.0
    while True:
        stopping = t >= t_end
        if stopping and not stop:
            break
        if stopping:
            v_next = max(0.0, v - decel * T_prev)
        elif v < v_target:
            v_next = min(v_target, v + accel * T_prev)
        else:
            v_next = max(v_target, v - decel * T_prev)
        foot = plan.next_foot
        side = 1.0 if foot == 0 else -1.0
        if stopping and v_next < 0.3:
            _close_step(plan, t, b, th, foot, v, run)
            plan.segments.append((t_start, t, label or ("run" if run else "walk")))
            plan.segments.append((t, plan.t, "stop"))
            return
        f, duty, running = _gait(v_next, run)
        T = 1.0 / f
        omega = 0.0 if turn is None else float(np.interp(t + T, *turn))
        th_next = th + omega * T
        S = 0.5 * (v + v_next) * T
        heading_mid = 0.5 * (th + th_next)
        if (
            not first
        ):  # between mid-stances the pelvis follows the speed ramp (trapezoid rule)
            plan.pelvis_at(
                t + 0.5 * T, b + (0.375 * v + 0.125 * v_next) * T * _fwd(heading_mid)
            )
        b = b + S * _fwd(heading_mid)
        D = duty * 2.0 * T  # stance duration
        swing = max(0.22, (1.0 - duty) * 2.0 * T)
        a = (
            0.45 if running else 0.4
        )  # fraction of stance before the pelvis passes the foot
        t_mid = t + T
        if first:  # from standing: leave time to shift weight and swing
            t_mid = t + 0.15 + swing + a * D
            first = False
        t_land = t_mid - a * D
        w = 0.06 if running else 0.085
        anchor = b + side * w * _left(th_next)
        vv = max(v, v_next)
        heel = (0.6 if running else 0.5 + 0.15 * vv) * min(1.0, vv / 0.8)
        heel_s = 0.12 if running else 0.3
        lift = (0.10 + 0.03 * v_next) if running else (0.04 + 0.02 * v_next)
        t_land = plan.step(
            foot,
            t_land - swing,
            t_land,
            anchor,
            th_next + side * 0.08,
            heel,
            heel_s,
            lift,
        )
        # pelvis: sway toward the stance foot, bob (walk: vault over the stance leg;
        # run: compress in stance, rise in flight), lean into turns
        sway = (0.012 if running else 0.03 * min(1.0, v_next / 1.0)) * side
        pb = b + sway * _left(th_next)
        lean_turn = -np.arctan(v_next * omega / G)
        if running:
            y_mid, y_between = STAND_H - 0.045 - 0.01 * v_next, STAND_H - 0.005
        else:
            y_mid, y_between = STAND_H - 0.004, STAND_H - 0.02 - 0.01 * v_next
        plan.key("py", 0.5 * (t + t_mid), y_between)
        plan.pelvis_at(
            t_mid, pb, py=y_mid, yaw=th_next, roll=0.6 * lean_turn + side * 0.04 * min(1.0, v_next),
            lean=0.08 if running else 0.03, tlean=0.06 + 0.01 * v_next if running else 0.03 + 0.01 * v_next,
            tside=0.3 * lean_turn - side * 0.03 * min(1.0, v_next),
        )  # fmt: skip
        amp = min(1.0, v_next / 1.2)
        pyaw = -side * (0.10 if running else 0.07) * amp
        chest = side * (0.12 if running else 0.06) * amp
        plan.key("pyaw", t_land, pyaw)
        plan.key("twist", t_land, chest - pyaw)
        plan.key("hpitch", t_land, 0.0)
        _arm_swing_keys(plan, t_land, foot, v_next, running)
        plan.next_foot = 1 - foot
        t, v, th, T_prev = t_mid, v_next, th_next, T
    plan.t, plan.v, plan.heading, plan.base = t, v, th, b
    plan.segments.append((t_start, t, label or ("run" if run else "walk")))


def _arm_swing_keys(plan: _Plan, t: float, foot: int, v: float, running: bool) -> None:
    """At a landing of `foot`, the opposite arm is forward and the same-side arm back."""
    amp = min(1.0, v / 1.3)
    if running:
        base = np.array([0.0, -0.30, 0.25])
        fwd, back = 0.55 * amp, -0.45 * amp
    else:
        base = np.array(_HANG)
        fwd, back = 0.38 * amp, -0.28 * amp
    for side, beta in (
        (("r" if foot == 0 else "l"), fwd),
        (("l" if foot == 0 else "r"), back),
    ):
        c, s = np.cos(beta), np.sin(beta)
        y = base[1] * c - base[2] * s
        z = -base[1] * s + base[2] * c
        x = base[0] - (0.06 if running else 0.02) * max(
            0.0, s
        )  # forward swing crosses the body
        plan.wrist(side, t, (x + 0.03, y, z), _BACK_POLE)


def _close_step(
    plan: _Plan, t: float, b: np.ndarray, th: float, foot: int, v: float, run: bool
) -> None:
    """Bring `foot` beside the other and settle into a standstill. The foot lifts as
    it would in gait (shortly after the other foot landed), so it never trails far
    behind the pelvis while the body decelerates over the stance foot."""
    side = 1.0 if foot == 0 else -1.0
    other = plan.anchor(1 - foot)
    t_lift = max(plan.plants[1 - foot][-1].t_land + 0.06, t - 0.3)
    # place beside the stance foot, across the body line
    target = other + side * (STAND_W + 0.085) * _left(th)
    mid = 0.5 * (other + target)
    t_land = plan.step(
        foot,
        t_lift,
        max(t + 0.2, t_lift + 0.4),
        target,
        th + side * 0.08,
        0.3 * min(1.0, v / 0.8),
        0.15,
        0.035,
    )
    t_end = t_land + 0.35
    plan.pelvis_at(
        t_end, mid, py=STAND_H, yaw=th, roll=0.0, lean=0.02, tlean=0.02, tside=0.0
    )
    plan.key("py", 0.5 * (t + t_land), STAND_H - 0.01)
    plan.key("pyaw", t_land, 0.0)
    plan.key("twist", t_land, 0.0)
    for s in "lr":
        plan.wrist(s, t_end, _HANG, _BACK_POLE)
    plan.t, plan.v, plan.heading, plan.base, plan.next_foot = (
        t_end,
        0.0,
        th,
        mid,
        1 - foot,
    )


# --------------------------------------------------------------------------- standing and actions


def _idle(plan: _Plan, rng, duration: float, label="idle") -> None:
    """Stand: slow weight shifts from foot to foot, head looking around, arms loose."""
    t0 = plan.t
    plan.hold(t0)
    t = t0
    while t < t0 + duration - 1.0:
        t = min(t + rng.uniform(1.0, 2.2), t0 + duration - 0.6)
        shift = rng.uniform(-0.045, 0.045)
        plan.pelvis_at(
            t, plan.body(shift, rng.uniform(-0.02, 0.02)), py=STAND_H - abs(shift) * 0.1,
            pyaw=rng.uniform(-0.08, 0.08), roll=-shift * 1.2, tside=shift * 0.8, twist=rng.uniform(-0.1, 0.1),
            hyaw=rng.uniform(-0.6, 0.6), hpitch=rng.uniform(-0.15, 0.2),
        )  # fmt: skip
        for s in "lr":
            j = rng.uniform(-0.03, 0.03, 3)
            plan.wrist(s, t + rng.uniform(-0.2, 0.2), np.array(_HANG) + j, _BACK_POLE)
    t1 = t0 + duration
    plan.pelvis_at(
        t1,
        plan.base,
        py=STAND_H,
        pyaw=0.0,
        roll=0.0,
        tside=0.0,
        twist=0.0,
        hyaw=0.0,
        hpitch=0.0,
    )
    for s in "lr":
        plan.wrist(s, t1, _HANG, _BACK_POLE)
    plan.segments.append((t0, t1, label))
    plan.t = t1


def _jitter(rng, scale=0.08):
    """A random timing/amplitude factor near 1."""
    return float(1.0 + rng.uniform(-scale, scale))


_READY_L = (-0.14, -0.36, 0.30)  # both hands in front on the racket
_READY_R = (-0.12, -0.35, 0.30)


def _swing(plan: _Plan, rng, kind: str) -> None:
    """One racket stroke with the right arm from a ready stance, then recovery.
    Keys: trunk and pelvis rotation, weight shift with a step, wrist path through
    backswing → contact → follow-through. Durations ~2.5–3 s."""
    t0 = plan.t
    plan.hold(t0)

    def j(scale=0.08):
        return _jitter(rng, scale)

    t = t0 + 0.45 * j()
    stance = plan.base.copy()
    plan.pelvis_at(
        t, stance, py=STAND_H - 0.05 * j(), tlean=0.15 * j(), lean=0.05, hyaw=0.0
    )
    plan.wrist("l", t, _READY_L, (0.5, -0.5, -0.6), 0.0)
    plan.wrist("r", t, _READY_R, (0.5, -0.5, -0.6), 0.0)
    if kind == "forehand":
        tb = t + 0.6 * j()  # end of backswing
        plan.pelvis_at(
            tb,
            plan.body(-0.06, -0.02),
            pyaw=-0.45 * j(),
            twist=-0.55 * j(),
            py=STAND_H - 0.06,
            tside=0.05,
        )
        plan.wrist("r", tb, (0.35, -0.15 * j(), -0.15), (0.6, -0.6, -0.5), 0.3)
        plan.wrist("l", tb, (-0.30, -0.15, 0.40), (0.5, -0.5, -0.5))
        # step in with the left foot during the backswing, weight onto it in the swing
        tl = plan.step(
            0,
            tb - 0.35,
            tb - 0.05,
            plan.body(0.05, 0.32 * j()),
            plan.heading - 0.25,
            0.0,
            0.0,
            0.05,
        )
        tc = tb + 0.24 * j(0.05)  # contact
        plan.pelvis_at(
            tc,
            plan.body(0.03, 0.14),
            pyaw=0.05,
            twist=0.0,
            py=STAND_H - 0.05,
            tside=0.0,
        )
        plan.wrist("r", tc, (0.20, -0.28, 0.40), (0.5, -0.8, -0.2), 0.0)
        plan.wrist("l", tc, (0.20, -0.25, 0.25), (0.5, -0.5, -0.5))
        tf = tc + 0.22 * j(0.05)
        plan.pelvis_at(tf, plan.body(0.06, 0.18), pyaw=0.3, twist=0.35 * j(), hyaw=-0.2)
        plan.wrist("r", tf, (-0.35, 0.08, 0.25), (0.6, -0.2, -0.8), -0.2)
        plan.wrist("l", tf, (0.15, -0.35, 0.10), _BACK_POLE)
        foot, back = 0, (STAND_W, 0.0)
    elif kind == "backhand":
        tb = t + 0.6 * j()
        plan.pelvis_at(
            tb,
            plan.body(0.05, -0.02),
            pyaw=0.4 * j(),
            twist=0.55 * j(),
            py=STAND_H - 0.06,
            tside=-0.05,
        )
        plan.wrist("r", tb, (-0.35, -0.33, 0.12), (0.4, -0.6, -0.6), -0.3)
        plan.wrist("l", tb, (-0.25, -0.25, 0.30), (0.5, -0.5, -0.5))
        tl = plan.step(
            1,
            tb - 0.35,
            tb - 0.05,
            plan.body(-0.02, 0.32 * j()),
            plan.heading + 0.35,
            0.0,
            0.0,
            0.05,
        )
        tc = tb + 0.25 * j(0.05)
        plan.pelvis_at(
            tc,
            plan.body(-0.05, 0.14),
            pyaw=0.0,
            twist=-0.05,
            py=STAND_H - 0.05,
            tside=0.0,
        )
        plan.wrist("r", tc, (0.15, -0.30, 0.42), (0.6, -0.7, 0.0), 0.0)
        plan.wrist("l", tc, (0.15, -0.30, 0.15), _BACK_POLE)
        tf = tc + 0.22 * j(0.05)
        plan.pelvis_at(
            tf, plan.body(-0.06, 0.16), pyaw=-0.15, twist=-0.3 * j(), hyaw=0.15
        )
        plan.wrist("r", tf, (0.45, 0.12, 0.18), (0.8, 0.2, -0.5), 0.2)
        plan.wrist("l", tf, (0.30, -0.30, -0.10), _BACK_POLE)
        foot, back = 1, (-STAND_W, 0.0)
    else:  # overhead, serve-like: trophy pose, knee bend, upward swing, step through
        tb = t + 0.9 * j()  # trophy
        plan.pelvis_at(tb, plan.body(-0.04, -0.03), pyaw=-0.35 * j(), twist=-0.45 * j(), py=STAND_H - 0.08 * j(),
                       tlean=-0.12, tside=0.15, hpitch=-0.35)  # fmt: skip
        plan.wrist("l", tb - 0.2, (0.05, 0.48, 0.15), (0.5, -0.5, -0.5), 0.0)
        plan.wrist("r", tb, (0.18, 0.16, -0.22), (1.0, 0.5, -0.4), 0.3)
        td = tb + 0.18 * j(0.05)  # racket drop behind the back
        plan.wrist("r", td, (0.05, 0.02, -0.28), (0.6, 1.0, -0.2), 0.5)
        plan.pelvis_at(
            td, plan.body(-0.02, 0.0), py=STAND_H - 0.07, pyaw=-0.25, twist=-0.3
        )
        tc = td + 0.26 * j(0.05)  # contact, reaching up
        plan.pelvis_at(tc, plan.body(0.0, 0.08), py=STAND_H + 0.002, pyaw=0.05, twist=0.1, tlean=0.1, tside=-0.1,
                       hpitch=-0.2)  # fmt: skip
        plan.wrist("r", tc, (-0.05, 0.48, 0.18), (0.8, 0.3, -0.3), 0.0)
        plan.wrist("l", tc, (-0.10, -0.25, 0.30), (0.5, -0.5, -0.5))
        # the arm stays long as it sweeps down in front (an arc, not a chord past the shoulder)
        plan.wrist("r", tc + 0.12, (-0.12, 0.02, 0.48), (0.7, -0.5, -0.3), -0.1)
        tf = tc + 0.30 * j(0.05)
        plan.pelvis_at(tf, plan.body(0.0, 0.22), py=STAND_H - 0.05, pyaw=0.2, twist=0.4, tlean=0.35, tside=0.0,
                       hpitch=0.1)  # fmt: skip
        plan.wrist("r", tf, (-0.35, -0.38, 0.20), (0.6, -0.6, -0.4), -0.2)
        plan.wrist("l", tf, (0.05, -0.40, 0.10), _BACK_POLE)
        tl = plan.step(
            1,
            tc - 0.02,
            tf + 0.05,
            plan.body(-0.06, 0.40 * j()),
            plan.heading + 0.1,
            0.3,
            0.12,
            0.07,
        )
        foot, back = 1, (-STAND_W, 0.0)
    # recovery: weight back, front foot returns, arms to ready then down
    tr = max(tf, tl) + 0.55 * j()
    plan.pelvis_at(
        tr,
        stance,
        pyaw=0.0,
        twist=0.0,
        py=STAND_H - 0.03,
        tlean=0.08,
        tside=0.0,
        hyaw=0.0,
        hpitch=0.0,
    )
    plan.wrist("r", tr, _READY_R, (0.5, -0.5, -0.6), 0.0)
    plan.wrist("l", tr, _READY_L, (0.5, -0.5, -0.6), 0.0)
    side = 1.0 if foot == 0 else -1.0
    plan.step(
        foot,
        tr - 0.3,
        tr + 0.05,
        plan.body(*back),
        plan.heading + side * 0.08,
        0.0,
        0.0,
        0.04,
    )
    te = tr + 0.5 * j()
    plan.pelvis_at(te, stance, py=STAND_H, tlean=0.02, lean=0.02)
    for s in "lr":
        plan.wrist(s, te, _HANG, _BACK_POLE, 0.0)
    plan.segments.append((t0, te, kind))
    plan.t = te


_GUARD = (-0.07, 0.15, 0.22)  # fists by the chin
_GUARD_POLE = (0.3, -1.0, -0.1)  # elbows down


def _punches(plan: _Plan, rng, count: int) -> None:
    """Boxing: step into an orthodox guard (left foot forward), throw `count` punches
    (jab = left, cross = right with hip and shoulder rotation), step back out."""
    t0 = plan.t
    plan.hold(t0)
    stance = plan.base.copy()
    t = plan.step(
        0,
        t0 + 0.1,
        t0 + 0.45,
        plan.body(STAND_W + 0.02, 0.25),
        plan.heading - 0.2,
        0.0,
        0.0,
        0.04,
    )
    guard_xz = plan.body(0.01, 0.1)
    t += 0.15
    plan.pelvis_at(
        t, guard_xz, py=STAND_H - 0.04, pyaw=-0.25, twist=0.0, tlean=0.1, hpitch=0.1
    )
    for s in "lr":
        plan.wrist(s, t, _GUARD, _GUARD_POLE, 0.0)
    arm = "l"
    for _ in range(count):
        t += rng.uniform(0.12, 0.35)
        plan.hold(
            t,
            [
                "px",
                "pz",
                "pyaw",
                "twist",
                "l_wx",
                "l_wy",
                "l_wz",
                "r_wx",
                "r_wy",
                "r_wz",
            ],
        )
        t_hit = t + rng.uniform(0.15, 0.19)
        height = rng.uniform(0.08, 0.2)
        if arm == "l":  # jab: straight from the left shoulder, a little shoulder turn
            plan.wrist("l", t_hit, (-0.10, height, 0.50), (0.8, -0.6, 0.0))
            plan.pelvis_at(t_hit, plan.body(0.01, 0.12), twist=-0.15)
        else:  # cross: hips and shoulders drive the right hand across
            plan.wrist("r", t_hit, (-0.14, height, 0.48), (0.8, -0.6, 0.0))
            plan.pelvis_at(t_hit, plan.body(0.02, 0.16), pyaw=-0.05, twist=0.35)
        t = t_hit + rng.uniform(0.03, 0.06)
        plan.hold(t, ["l_wx", "l_wy", "l_wz", "r_wx", "r_wy", "r_wz", "twist", "pyaw"])
        t += rng.uniform(0.2, 0.26)
        plan.wrist(arm, t, _GUARD, _GUARD_POLE)
        plan.pelvis_at(t, guard_xz, pyaw=-0.25, twist=0.0)
        arm = ("r" if arm == "l" else "l") if rng.random() < 0.75 else arm
    t += 0.3
    plan.pelvis_at(
        t + 0.3, stance, py=STAND_H, pyaw=0.0, twist=0.0, tlean=0.02, hpitch=0.0
    )
    t = plan.step(
        0, t, t + 0.35, plan.body(STAND_W, 0.0), plan.heading + 0.08, 0.0, 0.0, 0.04
    )
    for s in "lr":
        plan.wrist(s, t + 0.2, _HANG, _BACK_POLE)
    plan.segments.append((t0, t + 0.3, "punch"))
    plan.t = t + 0.3


# --------------------------------------------------------------------------- rendering


def _channels(plan: _Plan, t: np.ndarray) -> dict[str, np.ndarray]:
    """PCHIP through each channel's keys (the last key wins at equal times);
    held constant outside the keyed range."""
    out = {}
    for name, keys in plan.keys.items():
        kt = np.array([k[0] for k in keys])
        kv = np.array([k[1] for k in keys])
        order = np.argsort(kt, kind="stable")
        kt, kv = kt[order], kv[order]
        keep = np.append(kt[1:] > kt[:-1] + 1e-9, True)  # last of equal times
        kt, kv = kt[keep], kv[keep]
        if kt.size == 1:
            out[name] = np.full(t.shape, kv[0])
        else:
            out[name] = PchipInterpolator(kt, kv)(np.clip(t, kt[0], kt[-1]))
    return out


def _foot_track(plants: list, t: np.ndarray):
    """Ankle world positions (F, 3), foot world rotations (F, 4) and toe local
    rotations (F, 4) of one foot from its plants. In stance the toe is fixed and the
    heel rises about it (ankle moves, toe does not); swings are minimum-jerk in the
    ground plane with a C2 lift arc, leaving from and landing at rest."""
    F = t.shape[0]
    ankle = np.zeros((F, 3))
    yaw = np.zeros(F)
    pitch = np.zeros(F)
    toe_pitch = np.zeros(F)
    swing_w = np.zeros(F)
    heel_vec = -TOE_FROM_ANKLE  # toe → ankle in the foot frame

    def heel_ankle(p, a):
        """Ankle position with the heel raised a (rad) about the planted toe."""
        q = quat.mul(quat.about_y(np.full(np.shape(a), p.heading)), _rot_x(a))
        toe = np.array([p.x, ANKLE_H, p.z]) + quat.rotate(
            quat.about_y(p.heading), TOE_FROM_ANKLE
        )
        return toe + quat.rotate(q, np.broadcast_to(heel_vec, np.shape(a) + (3,)))

    for k, p in enumerate(plants):
        m = (t >= p.t_land) & (t <= p.t_off)
        if m.any():
            if p.heel > 0.0 and np.isfinite(p.t_off):
                a = p.heel * _min_jerk(
                    (t[m] - (p.t_off - p.heel_s)) / max(p.heel_s, 1e-6)
                )
            else:
                a = np.zeros(m.sum())
            ankle[m] = heel_ankle(p, a)
            yaw[m] = p.heading
            pitch[m] = a
            toe_pitch[m] = -a  # toes stay flat on the ground
        if k + 1 < len(plants):
            n = plants[k + 1]
            m = (t > p.t_off) & (t < n.t_land)
            if m.any():
                tau = (t[m] - p.t_off) / (n.t_land - p.t_off)
                s = _min_jerk(tau)
                p0 = heel_ankle(p, np.array(p.heel))
                p1 = np.array([n.x, ANKLE_H, n.z])
                ankle[m] = p0 + (p1 - p0) * s[:, None]
                # the heel kicks up early in the swing (peak at tau ~ 0.4)
                ankle[m, 1] += n.lift * _bump(tau**0.85)
                swing_w[m] = _min_jerk(tau / 0.2) * _min_jerk((1.0 - tau) / 0.2)
                dh = quat.wrap_angle(n.heading - p.heading)
                yaw[m] = p.heading + dh * s
                pitch[m] = p.heel * (1.0 - s) - 0.15 * _bump(tau)
                toe_pitch[m] = -p.heel * (1.0 - s)
    foot_rot = quat.mul(quat.about_y(yaw), _rot_x(pitch))
    # keep the toe above the floor in early swing (raise the ankle if needed)
    toe_y = (
        ankle[:, 1]
        + quat.rotate(foot_rot, np.broadcast_to(TOE_FROM_ANKLE, (F, 3)))[:, 1]
    )
    ankle[:, 1] += np.maximum(0.0, TOE_H - toe_y)
    stance = np.zeros(F, dtype=bool)
    for p in plants:
        stance |= (t >= p.t_land) & (t <= p.t_off)
    return ankle, foot_rot, _rot_x(toe_pitch), stance, swing_w


def _render(plan: _Plan, sk: Skeleton, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Local rotations (F, J, 4) and translations (F, J, 3) of the plan sampled at
    times t (s)."""
    F = t.shape[0]
    c = _channels(plan, t)
    yaw = c["yaw"] + c["pyaw"]
    pelvis_rot = quat.mul(
        quat.about_y(yaw), quat.mul(_rot_x(c["lean"]), _rot_z(c["roll"]))
    )
    feet = [_foot_track(plan.plants[f], t) for f in (0, 1)]
    pelvis = np.stack([c["px"], c["py"], c["pz"]], -1)

    # Lower the pelvis where an ankle would be out of reach (dilate, then smooth, twice,
    # so the correction is C1-smooth yet covers every violating frame).
    reach = (THIGH + SHIN) * 0.99  # knees never snap straight (see two_bone_ik)
    for _ in range(2):
        allowed = np.full(F, np.inf)
        for f, hip in ((0, "l_hip"), (1, "r_hip")):
            hip_w = pelvis + quat.rotate(pelvis_rot, np.broadcast_to(_OFF[hip], (F, 3)))
            ankle, stance = feet[f][0], feet[f][3]
            horiz2 = np.sum((hip_w[:, [0, 2]] - ankle[:, [0, 2]]) ** 2, axis=-1)
            max_hip_y = ankle[:, 1] + np.sqrt(np.maximum(reach**2 - horiz2, 0.0))
            # only planted feet constrain the pelvis; swing feet are pulled in below
            allowed = np.minimum(
                allowed,
                np.where(stance, max_hip_y - (hip_w[:, 1] - pelvis[:, 1]), np.inf),
            )
        deficit = np.maximum(0.0, pelvis[:, 1] - allowed)
        if not deficit.any():
            break
        sigma = 0.05 * _rate_of(t)
        deficit = (
            gaussian_filter1d(
                maximum_filter1d(deficit, 2 * int(np.ceil(2 * sigma)) + 1), sigma
            )
            * 1.05
        )
        pelvis[:, 1] -= deficit + 1e-4

    R = quat.identity((F, sk.num_joints))
    T = np.broadcast_to(sk.offsets, (F, sk.num_joints, 3)).copy()
    T[:, 0] = pelvis
    R[:, 0] = pelvis_rot

    # trunk: twist / lean / side bend split over spine and chest; head steadies gaze
    def trunk(share):
        return quat.mul(
            quat.about_y(share * c["twist"]),
            quat.mul(_rot_x(share * c["tlean"]), _rot_z(share * c["tside"])),
        )

    R[:, _IDX["spine"]] = trunk(0.45)
    R[:, _IDX["chest"]] = trunk(0.55)
    head_yaw = c["hyaw"] - 0.8 * (c["pyaw"] + c["twist"])
    head_pitch = c["hpitch"] - 0.7 * (c["lean"] + c["tlean"])
    head_side = -0.7 * (c["roll"] + c["tside"])
    R[:, _IDX["neck"]] = quat.mul(
        quat.about_y(0.4 * head_yaw),
        quat.mul(_rot_x(0.4 * head_pitch), _rot_z(0.4 * head_side)),
    )
    R[:, _IDX["head"]] = quat.mul(
        quat.about_y(0.6 * head_yaw),
        quat.mul(_rot_x(0.6 * head_pitch), _rot_z(0.6 * head_side)),
    )

    spine_w = quat.mul(pelvis_rot, R[:, _IDX["spine"]])
    spine_p = pelvis + quat.rotate(pelvis_rot, np.broadcast_to(_OFF["spine"], (F, 3)))
    chest_w = quat.mul(spine_w, R[:, _IDX["chest"]])
    chest_p = spine_p + quat.rotate(spine_w, np.broadcast_to(_OFF["chest"], (F, 3)))

    for s, sign in (("l", 1.0), ("r", -1.0)):
        flip = np.array([sign, 1.0, 1.0])  # side-local x (away from midline) → chest x
        rel = np.stack([c[f"{s}_wx"], c[f"{s}_wy"], c[f"{s}_wz"]], -1) * flip
        pole = np.stack([c[f"{s}_px"], c[f"{s}_py"], c[f"{s}_pz"]], -1) * flip
        shoulder = chest_p + quat.rotate(
            chest_w, np.broadcast_to(_OFF[f"{s}_shoulder"], (F, 3))
        )
        l1, l2, _ = two_bone_ik(
            shoulder, shoulder + quat.rotate(chest_w, rel), quat.rotate(chest_w, pole), chest_w,
            UPPER_ARM, FOREARM, (sign, 0.0, 0.0), (0.0, 0.0, -1.0), soft=True,
        )  # fmt: skip
        R[:, _IDX[f"{s}_shoulder"]] = l1
        R[:, _IDX[f"{s}_elbow"]] = l2
        R[:, _IDX[f"{s}_wrist"]] = _rot_z(sign * c[f"{s}_hand"])  # flex/extend the hand

    for f, s in ((0, "l"), (1, "r")):
        ankle, foot_rot, toe_rot, _, swing_w = feet[f]
        hip = pelvis + quat.rotate(
            pelvis_rot, np.broadcast_to(_OFF[f"{s}_hip"], (F, 3))
        )
        ankle = _soft_reach(hip, ankle, swing_w, THIGH + SHIN)
        knee_dir = quat.rotate(
            foot_rot, np.broadcast_to(np.array([0.0, 0.0, 1.0]), (F, 3))
        )
        knee_dir[:, 1] = 0.0
        l1, l2, hip_w = two_bone_ik(
            hip,
            ankle,
            knee_dir,
            pelvis_rot,
            THIGH,
            SHIN,
            (0.0, -1.0, 0.0),
            (0.0, 0.0, 1.0),
        )
        R[:, _IDX[f"{s}_hip"]] = l1
        R[:, _IDX[f"{s}_knee"]] = l2
        R[:, _IDX[f"{s}_ankle"]] = quat.mul(
            quat.conjugate(quat.mul(hip_w, l2)), foot_rot
        )
        R[:, _IDX[f"{s}_toe"]] = toe_rot
    # one sign per quaternion stream: keep w ≥ 0 for tidy interpolation downstream
    R *= np.where(R[..., :1] < 0.0, -1.0, 1.0)
    return R, T


def _soft_reach(
    hip: np.ndarray, ankle: np.ndarray, weight: np.ndarray, length: float
) -> np.ndarray:
    """Pull swing-foot targets (F, 3) smoothly back within reach of the hip: beyond
    90 % of the leg length, distances saturate (tanh) below full extension. Blended
    in by `weight` (0 at lift-off and landing), so planted feet are never moved."""
    vec = ankle - hip
    d = np.linalg.norm(vec, axis=-1, keepdims=True)
    r0, r1 = 0.88 * length, 0.985 * length
    soft = np.where(d > r0, r0 + (r1 - r0) * np.tanh((d - r0) / (r1 - r0)), d)
    pulled = hip + vec * (soft / np.maximum(d, 1e-9))
    return ankle + weight[:, None] * (pulled - ankle)


def _rate_of(t: np.ndarray) -> float:
    return 1.0 / (t[1] - t[0]) if t.shape[0] > 1 else 30.0


def _motion(
    plan: _Plan,
    sk: Skeleton,
    rate_hz: float,
    t0: float,
    t1: float,
    name: str,
    label: str,
    seed: int,
    frame_labels: dict | None = None,
):
    t = t0 + np.arange(round((t1 - t0) * rate_hz)) / rate_hz
    R, T = _render(plan, sk, t)
    if frame_labels is not None:
        frame_labels[name] = _segment_labels(plan, t, label)
    return Motion(
        sk, R, T, rate_hz, name=name, source=f"procedural:seed={seed}", labels=(label,)
    )


def _segment_labels(plan: _Plan, t: np.ndarray, default: str) -> np.ndarray:
    """(F,) the content label of each frame time from the plan's phases (walking,
    stopping, standing, a stroke, …); `default` where no phase is recorded."""
    out = np.full(t.shape[0], default, dtype=object)
    for a, b, lab in plan.segments:
        out[(t >= a) & (t < b)] = lab
    return out.astype(str)


# --------------------------------------------------------------------------- public generators


def _turns(rng, t0: float, t1: float, max_rate: float):
    return _smooth_curve(rng, t0, t1, rng.uniform(1.5, 3.0), -max_rate, max_rate)


def make_clip(
    kind: str,
    rng,
    sk: Skeleton,
    rate_hz: float,
    duration: float,
    name: str,
    seed: int = 0,
    frame_labels: dict | None = None,
) -> Motion:
    """One clip of content `kind` (one of CONTENT_LABELS), about `duration` seconds.
    frame_labels: a dict that receives the clip's per-frame content labels under its
    name (a stop clip walks before it stops, a stroke clip stands between strokes).

    walk/run: cruising at a random speed (walk 0.8–1.8 m/s, run 2.5–4.5 m/s) along a
    curved path, cropped after the start-up. stop: walking or running with one or two
    stops (decelerate, close the feet, stand, restart). idle: standing. Strokes and
    punches: repeated from a standing start, so clips may run a little longer."""
    plan = _new_plan(rng)
    if kind in ("walk", "run"):
        run = kind == "run"
        v = rng.uniform(2.5, 4.5) if run else rng.uniform(0.8, 1.8)
        pre = 2.5
        _locomote(
            plan,
            rng,
            run,
            v,
            pre + duration + 1.0,
            _turns(rng, 0.0, pre + duration + 3.0, 0.6),
            stop=False,
        )
        return _motion(plan, sk, rate_hz, pre, pre + duration, name, kind, seed, frame_labels)
    if kind == "stop":
        run = rng.random() < 0.4
        _idle(plan, rng, 0.6)
        t_clip0 = rng.uniform(0.0, 0.5)
        stops = 1 if duration < 9.0 else 2
        span = (duration - 0.6) / stops
        for _ in range(stops):
            v = rng.uniform(2.5, 4.0) if run else rng.uniform(0.9, 1.7)
            cruise = max(1.5, span - 3.5)
            _locomote(
                plan,
                rng,
                run,
                v,
                plan.t + cruise,
                _turns(rng, plan.t, plan.t + cruise + 4.0, 0.4),
                stop=True,
            )
            _idle(plan, rng, rng.uniform(1.0, 1.8), label="stop")
        return _motion(plan, sk, rate_hz, t_clip0, plan.t, name, kind, seed, frame_labels)
    if kind == "idle":
        _idle(plan, rng, duration)
        return _motion(plan, sk, rate_hz, 0.0, plan.t, name, kind, seed, frame_labels)
    if kind in ("forehand", "backhand", "overhead"):
        _idle(plan, rng, 0.4)
        while plan.t < duration - 1.5:
            _swing(plan, rng, kind)
            _idle(plan, rng, rng.uniform(0.3, 0.9), label="idle")
        return _motion(plan, sk, rate_hz, 0.0, plan.t, name, kind, seed, frame_labels)
    if kind == "punch":
        _idle(plan, rng, 0.3)
        while plan.t < duration - 2.0:
            _punches(plan, rng, int(rng.integers(3, 8)))
            _idle(plan, rng, rng.uniform(0.4, 1.0), label="idle")
        return _motion(plan, sk, rate_hz, 0.0, plan.t, name, kind, seed, frame_labels)
    raise ValueError(
        f"unknown procedural content {kind!r}; expected one of {', '.join(CONTENT_LABELS)}"
    )


def generate_knowledge_base(
    seed: int = 0, rate_hz: float = 30.0, minutes: float = 3.0, frame_labels: dict | None = None
) -> list[Motion]:
    """About `minutes` of labelled clips (5–15 s each) cycling through every content
    label in a seed-shuffled order, so even a short knowledge base has all of them.
    Names are "<label>_<nn>"; labels=(content,). Deterministic by seed. frame_labels:
    a dict that receives each clip's per-frame labels (`make_clip`), for
    `build_graph(..., frame_labels=)`."""
    rng = np.random.default_rng(seed)
    sk = standard_skeleton()
    clips: list[Motion] = []
    counts = {k: 0 for k in CONTENT_LABELS}
    total = 0.0
    order: list[str] = []
    while total < minutes * 60.0:
        if not order:
            order = [CONTENT_LABELS[i] for i in rng.permutation(len(CONTENT_LABELS))]
        kind = order.pop(0)
        counts[kind] += 1
        clip = make_clip(
            kind,
            rng,
            sk,
            rate_hz,
            float(rng.uniform(5.0, 12.0)),
            f"{kind}_{counts[kind]:02d}",
            seed,
            frame_labels,
        )
        clips.append(clip)
        total += clip.duration_s
    return clips


def generate_performance(
    seed: int = 1, rate_hz: float = 30.0, seconds: float = 20.0
) -> tuple[Motion, np.ndarray]:
    """A continuous held-out performance (use a seed not used for the knowledge base):
    idle → walk → stop → a stroke → run → stop → punches → ..., repeated until
    `seconds`. Returns the Motion (labels=("performance",)) and a (F,) array of
    per-frame content labels (strings from CONTENT_LABELS)."""
    rng = np.random.default_rng(seed)
    sk = standard_skeleton()
    plan = _new_plan(rng)
    _idle(plan, rng, rng.uniform(1.0, 1.5))
    strokes = [("forehand", "backhand", "overhead")[i] for i in rng.permutation(3)]
    i = 0
    while plan.t < seconds:
        run = i % 2 == 1
        v = rng.uniform(2.6, 4.0) if run else rng.uniform(1.0, 1.6)
        cruise = rng.uniform(2.0, 3.5)
        _locomote(
            plan,
            rng,
            run,
            v,
            plan.t + cruise,
            _turns(rng, plan.t, plan.t + cruise + 4.0, 0.5),
            stop=True,
        )
        _idle(plan, rng, rng.uniform(0.5, 1.0), label="stop")
        if i % 2 == 0:
            _swing(plan, rng, strokes[(i // 2) % 3])
        else:
            _punches(plan, rng, int(rng.integers(3, 6)))
        _idle(plan, rng, rng.uniform(0.4, 0.8))
        i += 1
    t1 = min(plan.t, seconds) if plan.t > seconds + 3.0 else plan.t
    motion = _motion(
        plan, sk, rate_hz, 0.0, t1, f"performance_s{seed}", "performance", seed
    )
    t = np.arange(motion.num_frames) / rate_hz
    labels = np.full(motion.num_frames, "idle", dtype="<U8")
    for a, b, lab in plan.segments:
        labels[(t >= a) & (t < b)] = lab
    return motion, labels

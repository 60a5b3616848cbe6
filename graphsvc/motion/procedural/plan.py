"""Planning a procedural clip as sparse keys: the plan (scalar channels, foot
plants, labelled phases), the footstep planner for walking and running, standing,
racket swings and punches."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import PchipInterpolator

from graphsvc.motion.procedural.body import STAND_H, STAND_W, G, _fwd, _left

# --------------------------------------------------------------------------- plan

NEUTRAL = {
    "px": 0.0,
    "pz": 0.0,
    "py": STAND_H,
    "yaw": 0.0,
    "pyaw": 0.0,
    "lean": 0.02,
    "roll": 0.0,
    "twist": 0.0,
    "tlean": 0.02,
    "tside": 0.0,
    "hyaw": 0.0,
    "hpitch": 0.0,
    # wrist targets relative to the shoulder, chest frame, x positive away from the midline
    "l_wx": 0.03,
    "l_wy": -0.52,
    "l_wz": 0.07,
    "r_wx": 0.03,
    "r_wy": -0.52,
    "r_wz": 0.07,
    # elbow pole directions, same convention
    "l_px": 0.3,
    "l_py": 0.0,
    "l_pz": -1.0,
    "r_px": 0.3,
    "r_py": 0.0,
    "r_pz": -1.0,
    "l_hand": 0.0,
    "r_hand": 0.0,
}
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
        prev.heel_s = min(heel_s, 0.45 * (t_lift - prev.t_land)) if np.isfinite(prev.t_land) else heel_s
        self.plants[foot].append(_Plant(t_land, np.inf, float(xz[0]), float(xz[1]), heading, lift=lift))
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
        plan.plants[foot].append(_Plant(-np.inf, np.inf, xz[0], xz[1], plan.heading + side * 0.08))
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


def _smooth_curve(rng, t0: float, t1: float, every: float, lo: float, hi: float, zero_prob=0.3):
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
        if not first:  # between mid-stances the pelvis follows the speed ramp (trapezoid rule)
            plan.pelvis_at(t + 0.5 * T, b + (0.375 * v + 0.125 * v_next) * T * _fwd(heading_mid))
        b = b + S * _fwd(heading_mid)
        D = duty * 2.0 * T  # stance duration
        swing = max(0.22, (1.0 - duty) * 2.0 * T)
        a = 0.45 if running else 0.4  # fraction of stance before the pelvis passes the foot
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
            t_mid,
            pb,
            py=y_mid,
            yaw=th_next,
            roll=0.6 * lean_turn + side * 0.04 * min(1.0, v_next),
            lean=0.08 if running else 0.03,
            tlean=0.06 + 0.01 * v_next if running else 0.03 + 0.01 * v_next,
            tside=0.3 * lean_turn - side * 0.03 * min(1.0, v_next),
        )
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
        x = base[0] - (0.06 if running else 0.02) * max(0.0, s)  # forward swing crosses the body
        plan.wrist(side, t, (x + 0.03, y, z), _BACK_POLE)


def _close_step(plan: _Plan, t: float, b: np.ndarray, th: float, foot: int, v: float, run: bool) -> None:
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
    plan.pelvis_at(t_end, mid, py=STAND_H, yaw=th, roll=0.0, lean=0.02, tlean=0.02, tside=0.0)
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
            t,
            plan.body(shift, rng.uniform(-0.02, 0.02)),
            py=STAND_H - abs(shift) * 0.1,
            pyaw=rng.uniform(-0.08, 0.08),
            roll=-shift * 1.2,
            tside=shift * 0.8,
            twist=rng.uniform(-0.1, 0.1),
            hyaw=rng.uniform(-0.6, 0.6),
            hpitch=rng.uniform(-0.15, 0.2),
        )
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
    plan.pelvis_at(t, stance, py=STAND_H - 0.05 * j(), tlean=0.15 * j(), lean=0.05, hyaw=0.0)
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
        plan.pelvis_at(tf, plan.body(-0.06, 0.16), pyaw=-0.15, twist=-0.3 * j(), hyaw=0.15)
        plan.wrist("r", tf, (0.45, 0.12, 0.18), (0.8, 0.2, -0.5), 0.2)
        plan.wrist("l", tf, (0.30, -0.30, -0.10), _BACK_POLE)
        foot, back = 1, (-STAND_W, 0.0)
    else:  # overhead, serve-like: trophy pose, knee bend, upward swing, step through
        tb = t + 0.9 * j()  # trophy
        plan.pelvis_at(
            tb,
            plan.body(-0.04, -0.03),
            pyaw=-0.35 * j(),
            twist=-0.45 * j(),
            py=STAND_H - 0.08 * j(),
            tlean=-0.12,
            tside=0.15,
            hpitch=-0.35,
        )
        plan.wrist("l", tb - 0.2, (0.05, 0.48, 0.15), (0.5, -0.5, -0.5), 0.0)
        plan.wrist("r", tb, (0.18, 0.16, -0.22), (1.0, 0.5, -0.4), 0.3)
        td = tb + 0.18 * j(0.05)  # racket drop behind the back
        plan.wrist("r", td, (0.05, 0.02, -0.28), (0.6, 1.0, -0.2), 0.5)
        plan.pelvis_at(td, plan.body(-0.02, 0.0), py=STAND_H - 0.07, pyaw=-0.25, twist=-0.3)
        tc = td + 0.26 * j(0.05)  # contact, reaching up
        plan.pelvis_at(
            tc, plan.body(0.0, 0.08), py=STAND_H + 0.002, pyaw=0.05, twist=0.1, tlean=0.1, tside=-0.1, hpitch=-0.2
        )
        plan.wrist("r", tc, (-0.05, 0.48, 0.18), (0.8, 0.3, -0.3), 0.0)
        plan.wrist("l", tc, (-0.10, -0.25, 0.30), (0.5, -0.5, -0.5))
        # the arm stays long as it sweeps down in front (an arc, not a chord past the shoulder)
        plan.wrist("r", tc + 0.12, (-0.12, 0.02, 0.48), (0.7, -0.5, -0.3), -0.1)
        tf = tc + 0.30 * j(0.05)
        plan.pelvis_at(
            tf, plan.body(0.0, 0.22), py=STAND_H - 0.05, pyaw=0.2, twist=0.4, tlean=0.35, tside=0.0, hpitch=0.1
        )
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
    plan.pelvis_at(t, guard_xz, py=STAND_H - 0.04, pyaw=-0.25, twist=0.0, tlean=0.1, hpitch=0.1)
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
    plan.pelvis_at(t + 0.3, stance, py=STAND_H, pyaw=0.0, twist=0.0, tlean=0.02, hpitch=0.0)
    t = plan.step(0, t, t + 0.35, plan.body(STAND_W, 0.0), plan.heading + 0.08, 0.0, 0.0, 0.04)
    for s in "lr":
        plan.wrist(s, t + 0.2, _HANG, _BACK_POLE)
    plan.segments.append((t0, t + 0.3, "punch"))
    plan.t = t + 0.3

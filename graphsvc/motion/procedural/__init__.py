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

The modules: `body` (skeleton, proportions, IK), `plan` (keys and phases: locomotion,
standing, swings, punches), `render` (plan → rotations and translations); this one
holds the public generators.
"""

from __future__ import annotations

import numpy as np

from graphsvc.motion.procedural.body import CONTENT_LABELS, standard_skeleton
from graphsvc.motion.procedural.plan import _idle, _locomote, _new_plan, _Plan, _punches, _smooth_curve, _swing
from graphsvc.motion.procedural.render import _render
from graphsvc.motion.skeleton import Motion, Skeleton


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
    return Motion(sk, R, T, rate_hz, name=name, source=f"procedural:seed={seed}", labels=(label,))


def _segment_labels(plan: _Plan, t: np.ndarray, default: str) -> np.ndarray:
    """(F,) the content label of each frame time from the plan's phases (walking,
    stopping, standing, a stroke, …); `default` where no phase is recorded."""
    out = np.full(t.shape[0], default, dtype=object)
    for a, b, lab in plan.segments:
        out[(t >= a) & (t < b)] = lab
    return out.astype(str)


# --------------------------------------------------------------------------- public generators


def _cruise_and_stop(
    plan, rng, run: bool, speed: float, cruise_s: float, max_turn_rate: float, stand_s: tuple[float, float]
) -> None:
    """Walk or run at `speed` for cruise_s seconds (turning at up to max_turn_rate),
    stop, and stand for a time drawn from stand_s, labelled "stop"."""
    _locomote(
        plan, rng, run, speed, plan.t + cruise_s, _turns(rng, plan.t, plan.t + cruise_s + 4.0, max_turn_rate), stop=True
    )
    _idle(plan, rng, rng.uniform(*stand_s), label="stop")


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
            _cruise_and_stop(plan, rng, run, v, max(1.5, span - 3.5), 0.4, (1.0, 1.8))
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
    raise ValueError(f"unknown procedural content {kind!r}; expected one of {', '.join(CONTENT_LABELS)}")


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


def generate_performance(seed: int = 1, rate_hz: float = 30.0, seconds: float = 20.0) -> tuple[Motion, np.ndarray]:
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
        _cruise_and_stop(plan, rng, run, v, rng.uniform(2.0, 3.5), 0.5, (0.5, 1.0))
        if i % 2 == 0:
            _swing(plan, rng, strokes[(i // 2) % 3])
        else:
            _punches(plan, rng, int(rng.integers(3, 6)))
        _idle(plan, rng, rng.uniform(0.4, 0.8))
        i += 1
    t1 = min(plan.t, seconds) if plan.t > seconds + 3.0 else plan.t
    motion = _motion(plan, sk, rate_hz, 0.0, t1, f"performance_s{seed}", "performance", seed)
    t = np.arange(motion.num_frames) / rate_hz
    return motion, _segment_labels(plan, t, "idle")

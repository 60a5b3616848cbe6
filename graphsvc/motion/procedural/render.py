"""Rendering a plan to per-frame arrays: PCHIP channels, planted feet and swing
arcs, the pelvis lowered until both ankles reach, leg and arm IK."""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.ndimage import gaussian_filter1d, maximum_filter1d

from graphsvc.motion import quat
from graphsvc.motion.procedural.body import (
    _IDX,
    _OFF,
    ANKLE_H,
    FOREARM,
    SHIN,
    THIGH,
    TOE_FROM_ANKLE,
    TOE_H,
    UPPER_ARM,
    _bump,
    _min_jerk,
    _rot_x,
    _rot_z,
    two_bone_ik,
)
from graphsvc.motion.procedural.plan import _Plan
from graphsvc.motion.skeleton import Skeleton

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
        toe = np.array([p.x, ANKLE_H, p.z]) + quat.rotate(quat.about_y(p.heading), TOE_FROM_ANKLE)
        return toe + quat.rotate(q, np.broadcast_to(heel_vec, np.shape(a) + (3,)))

    for k, p in enumerate(plants):
        m = (t >= p.t_land) & (t <= p.t_off)
        if m.any():
            if p.heel > 0.0 and np.isfinite(p.t_off):
                a = p.heel * _min_jerk((t[m] - (p.t_off - p.heel_s)) / max(p.heel_s, 1e-6))
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
    toe_y = ankle[:, 1] + quat.rotate(foot_rot, np.broadcast_to(TOE_FROM_ANKLE, (F, 3)))[:, 1]
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
    pelvis_rot = quat.mul(quat.about_y(yaw), quat.mul(_rot_x(c["lean"]), _rot_z(c["roll"])))
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
        deficit = gaussian_filter1d(maximum_filter1d(deficit, 2 * int(np.ceil(2 * sigma)) + 1), sigma) * 1.05
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
        shoulder = chest_p + quat.rotate(chest_w, np.broadcast_to(_OFF[f"{s}_shoulder"], (F, 3)))
        l1, l2, _ = two_bone_ik(
            shoulder,
            shoulder + quat.rotate(chest_w, rel),
            quat.rotate(chest_w, pole),
            chest_w,
            UPPER_ARM,
            FOREARM,
            (sign, 0.0, 0.0),
            (0.0, 0.0, -1.0),
            soft=True,
        )
        R[:, _IDX[f"{s}_shoulder"]] = l1
        R[:, _IDX[f"{s}_elbow"]] = l2
        R[:, _IDX[f"{s}_wrist"]] = _rot_z(sign * c[f"{s}_hand"])  # flex/extend the hand

    for f, s in ((0, "l"), (1, "r")):
        ankle, foot_rot, toe_rot, _, swing_w = feet[f]
        hip = pelvis + quat.rotate(pelvis_rot, np.broadcast_to(_OFF[f"{s}_hip"], (F, 3)))
        ankle = _soft_reach(hip, ankle, swing_w, THIGH + SHIN)
        knee_dir = quat.rotate(foot_rot, np.broadcast_to(np.array([0.0, 0.0, 1.0]), (F, 3)))
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
        R[:, _IDX[f"{s}_ankle"]] = quat.mul(quat.conjugate(quat.mul(hip_w, l2)), foot_rot)
        R[:, _IDX[f"{s}_toe"]] = toe_rot
    # one sign per quaternion stream: keep w ≥ 0 for tidy interpolation downstream
    R *= np.where(R[..., :1] < 0.0, -1.0, 1.0)
    return R, T


def _soft_reach(hip: np.ndarray, ankle: np.ndarray, weight: np.ndarray, length: float) -> np.ndarray:
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

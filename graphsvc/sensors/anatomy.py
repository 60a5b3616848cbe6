"""Anatomical sensor frames: a sensor's frame defined from its segment's anatomy, the
same on every skeleton, so readings simulated from any skeleton, the knowledge base's,
and a real sensor's after calibration are comparable.

A joint's local frame is whatever its skeleton's author chose (a BVH's rest pose may be
a T-pose, an N-pose or anything else, and any joint may carry an extra constant twist),
so a frame taken from the rest pose ("Z up in the rest pose", the convention graph
files and recordings of format `rest-pose` use) reads differently on two skeletons doing
the same motion. The anatomical frame of a sensor on segment j (running from joint j
toward joint k) is:

- X along the bone, from j toward k (down the limbs, up the trunk, forward on the foot);
- Y from an anatomical reference, made orthogonal to X:
  - upper arm and forearm: the elbow's flexion axis, (wrist − elbow) × (elbow − shoulder);
  - thigh and shin: the knee's flexion axis, (knee − hip) × (ankle − knee);
  - foot: the ankle's axis, (toe − ankle) × (ankle − knee);
  - pelvis and spine: the hip line, r_hip − l_hip; chest, neck, head: the shoulder line;
- Z = X × Y.

Standing with the arms at the sides (N-pose) or in a T-pose with the palms down, every
limb and trunk sensor's Z points forward; Y points to the body's left on the limbs
(in a T-pose: up on the left arm, down on the right) and to its right on the trunk; on
the foot Z points up.

Skeletons put the forearm's twist (pronation) in different joints: CMU's in the
wrist, the Bandai-Namco skeleton's in the forearm. So that a forearm sensor reads the
same on both, its frame does not turn with that twist: X follows the forearm, Y is the
elbow's axis as the upper arm carries it (`CARRIED_BY`; `Placement.carrier`), made
orthogonal to X. The elbow's axis sits still in the upper arm's frame whichever joint
holds the twist (the estimates of one skeleton's clips agree within 0.1°), where the
forearm's own average twist varies from clip to clip by 10° (median) to 30°.

Joint positions alone give the bone axis at every frame but the flexion axis only where
the joint is bent, so the frame is estimated from motion: each reference vector is
carried into the segment's local frame at every frame (where it is constant for a rigid
segment and a hinge joint) and averaged, each frame weighted by how well it defines the
axis (the cross product's length, |sin| of the flexion times the bones' lengths). A
small prior from the rest pose, assuming the elbows bend forward and the knees back,
keeps the frame defined for a motion that never bends a joint. The result is a
constant rotation per sensor in its segment's frame (`Placement.rotation`; for a
carried sensor, its X and the carried axis), which the simulator, the graph builder
and the searches apply at every frame.
"""

from __future__ import annotations

import numpy as np

from graphsvc.errors import InputError
from graphsvc.motion import quat
from graphsvc.motion.kinematics import forward_kinematics

# The sensor-frame conventions a recording's or a graph's readings may be in.
ANATOMICAL = "anatomical"
REST_POSE = "rest-pose"  # graphs and recordings made before anatomical frames
CONVENTIONS = (ANATOMICAL, REST_POSE)

# Per canonical segment, the reference for Y: ("cross", a, b, c) is (b − a) × (c − b) of
# the joints' world positions; ("line", l, r) is r − l.
_ARM = {"l": ("cross", "l_wrist", "l_elbow", "l_shoulder"), "r": ("cross", "r_wrist", "r_elbow", "r_shoulder")}
_LEG = {"l": ("cross", "l_hip", "l_knee", "l_ankle"), "r": ("cross", "r_hip", "r_knee", "r_ankle")}
_FOOT = {"l": ("cross", "l_toe", "l_ankle", "l_knee"), "r": ("cross", "r_toe", "r_ankle", "r_knee")}
_HIPS = ("line", "l_hip", "r_hip")
_SHOULDERS = ("line", "l_shoulder", "r_shoulder")
REFERENCE = {
    "pelvis": _HIPS,
    "spine": _HIPS,
    "chest": _SHOULDERS,
    "neck": _SHOULDERS,
    "head": _SHOULDERS,
    "l_shoulder": _ARM["l"],
    "l_elbow": _ARM["l"],
    "l_wrist": _ARM["l"],
    "r_shoulder": _ARM["r"],
    "r_elbow": _ARM["r"],
    "r_wrist": _ARM["r"],
    "l_hip": _LEG["l"],
    "l_knee": _LEG["l"],
    "r_hip": _LEG["r"],
    "r_knee": _LEG["r"],
    "l_ankle": _FOOT["l"],
    "l_toe": _FOOT["l"],
    "r_ankle": _FOOT["r"],
    "r_toe": _FOOT["r"],
}

# Sensors whose Y the upper arm carries (module docstring), and the upper arm's bone.
CARRIED_BY = {"l_elbow": "l_shoulder", "r_elbow": "r_shoulder", "l_wrist": "l_shoulder", "r_wrist": "r_shoulder"}
CARRIED_TOWARD = {"l_shoulder": "l_elbow", "r_shoulder": "r_elbow"}

# The rest-pose prior's weight, in frames of the clip's most bent pose: enough to
# define a frame that the motion leaves undefined (a joint never bent), too little to
# move one the motion defines (a second of motion bending a joint by 10° outweighs it a
# hundredfold).
PRIOR_WEIGHT = 0.05


def recording_frames(meta: dict) -> str | None:
    """The convention of a recording's readings: meta["sensor_frames"]; a simulated
    recording without it predates anatomical frames (rest-pose); None when unknown
    (a device's own frames, or another program's file)."""
    if meta.get("sensor_frames") in CONVENTIONS:
        return meta["sensor_frames"]
    if meta.get("simulated") and meta.get("sensor_frame", "layout") == "layout":
        return REST_POSE
    return None


def check_frames(graph_params: dict, meta: dict, what: str = "the recording") -> None:
    """InputError when a recording's readings and a graph's are in different sensor-frame
    conventions (they would be compared axis by axis, silently wrong)."""
    ours = recording_frames(meta)
    theirs = graph_params.get("sensor_frames", REST_POSE)
    if ours is not None and ours != theirs:
        fix = (
            "convert the graph with `graphsvc relayout G --layout L -o NEW` (or rebuild it)"
            if theirs == REST_POSE
            else "simulate the recording again"
        )
        raise InputError(f"{what}'s readings are in {ours} sensor frames, the graph's in {theirs}: {fix}")


def reference_vectors(world_pos: np.ndarray, table, segment: str) -> np.ndarray:
    """(F, 3) the segment's Y reference (module docstring) at each frame, unnormalised:
    a cross product's length is the flexion's |sin| times the two bones' lengths."""
    kind, *joints = REFERENCE[segment]
    p = [world_pos[:, table[j]] for j in joints]
    if kind == "line":
        return p[1] - p[0]
    return np.cross(p[1] - p[0], p[2] - p[1])


def _rest_prior(rest_pos: np.ndarray, table, segment: str) -> np.ndarray:
    """The Y reference in a rest pose assumed to stand facing forward: the elbows bend
    toward the front, the knees toward the back (the foot's and the trunk's references
    are defined without bending)."""
    kind, *joints = REFERENCE[segment]
    if kind == "line" or segment.endswith(("ankle", "toe")):
        return reference_vectors(rest_pos[None], table, segment)[0]
    left = rest_pos[table["l_hip"]] - rest_pos[table["r_hip"]]
    up = rest_pos[table["neck"]] - rest_pos[table["pelvis"]]
    forward = np.cross(left, up)
    forward /= max(np.linalg.norm(forward), 1e-9)
    a, b, c = (rest_pos[table[j]] for j in joints)
    if segment[2:] in ("shoulder", "elbow", "wrist"):  # (c − b) the upper arm, the forearm bent forward
        return np.cross(forward * np.linalg.norm(b - a), c - b)
    return np.cross(b - a, -forward * np.linalg.norm(c - b))  # the shin bent back


def estimate_rotations(
    world_rot: np.ndarray, world_pos: np.ndarray, rest_rot: np.ndarray, rest_pos: np.ndarray, table, segments, towards
) -> np.ndarray:
    """(S, 4) each sensor frame's rotation relative to its segment's joint frame (w, x, y,
    z): the anatomical frame (module docstring) averaged over the frames of world_rot
    (F, J, 4) and world_pos (F, J, 3), plus the rest pose's prior (rest_rot (J, 4),
    rest_pos (J, 3)). segments, towards: (S,) canonical names."""
    out = np.empty((len(segments), 4))
    for s, (seg, tow) in enumerate(zip(segments, towards)):
        j, k = table[seg], table[tow]
        bone = quat.inv_rotate(world_rot[:, j], world_pos[:, k] - world_pos[:, j]).sum(axis=0)
        bone += quat.inv_rotate(rest_rot[j], rest_pos[k] - rest_pos[j])
        x = bone / max(np.linalg.norm(bone), 1e-12)
        ref = quat.inv_rotate(world_rot[:, j], reference_vectors(world_pos, table, seg))
        prior = quat.inv_rotate(rest_rot[j], _rest_prior(rest_pos, table, seg))
        scale = np.linalg.norm(prior)
        y = ref.sum(axis=0) + PRIOR_WEIGHT * prior / max(scale, 1e-12) * max(scale, _typical(ref))
        y -= np.dot(y, x) * x
        n = np.linalg.norm(y)
        if n < 1e-9:  # (no reference at all: any axis across the bone)
            y = np.eye(3)[int(np.argmin(np.abs(x)))]
            y -= np.dot(y, x) * x
            n = np.linalg.norm(y)
        y /= n
        out[s] = quat.from_matrix(np.stack([x, y, np.cross(x, y)], axis=1))
    return out


def _typical(ref: np.ndarray) -> float:
    """A reference vector's length at full evidence: the largest seen (a joint bent by
    90°), so the prior weighs as PRIOR_WEIGHT such frames."""
    return float(np.linalg.norm(ref, axis=1).max()) if ref.size else 0.0


def rest_pose(skeleton) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (J, 4) and positions (J, 3) of the skeleton with every joint at
    its rest rotation."""
    J = skeleton.num_joints
    rot = np.zeros((1, J, 4))
    rot[..., 0] = 1.0
    offsets = np.array(skeleton.offsets, dtype=np.float64)[None].copy()
    offsets[0, 0] = 0.0
    world_rot, world_pos = forward_kinematics(rot, offsets, skeleton.parents)
    return world_rot[0], world_pos[0]

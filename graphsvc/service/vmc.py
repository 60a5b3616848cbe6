"""Pose frames out to live animation tools over the VMC protocol (Virtual Motion Capture:
OSC over UDP, read by VSeeFace, Unity's EVMC4U, Unreal's VMC4UE, Blender's VMC4B and
other add-ons), encoded with the `python-osc` library's encoders (`VmcSender` says why
not its builders): `graphsvc client stream … --vmc HOST:PORT` and `sensor-bridge --vmc
HOST:PORT` send each frame as it arrives.

Each frame is one OSC bundle:

    /VMC/Ext/Root/Pos  "root" px py pz qx qy qz qw   the avatar's root: the pelvis on the ground, no rotation
    /VMC/Ext/Bone/Pos  NAME   px py pz qx qy qz qw   per humanoid bone: its local position and rotation
    /VMC/Ext/OK        1                             an avatar is loaded
    /VMC/Ext/T         t                             the frame's time, seconds

Bones are Unity's humanoid names, mapped from graphsvc's canonical joints
(`motion.joints`): pelvis → Hips, spine → Spine, chest → Chest, neck → Neck, head →
Head, l_shoulder → LeftUpperArm, l_elbow → LeftLowerArm, l_wrist → LeftHand, l_hip →
LeftUpperLeg, l_knee → LeftLowerLeg, l_ankle → LeftFoot, l_toe → LeftToes, and the
right side alike; a joint the skeleton lacks (`joints.OPTIONAL`) is not sent, its
child's parent being the next bone up. Each bone's parent is the next humanoid bone
up the body (the upper arm's is the chest: the shoulder bone Unity has between them
stays at rest).

Rotations are those of a normalised humanoid (VRM's convention, what the receivers
expect): in a T-pose facing +Z every bone's rotation is the identity. graphsvc's
skeletons have their own rest poses (the Bandai-Namco rest is no T-pose), so each bone
carries a fixed rest correction C (`vmc_rig`): the pelvis and the chest turned upright
facing +Z (the hips' and the shoulders' right-to-left lines onto +X, the line up to the
neck onto +Y), each other segment (the limbs, the spine, the neck) turned the shortest
way from its parent's onto the T-pose's direction (arms out along ±X, legs down, the
spine up); hands, feet, toes and the head keep their parent's. A bone's world rotation is then D = W·C⁻¹ (W its joint's
world rotation in the frame), its local rotation D_parent⁻¹·D, and its local position
D_parent⁻¹·(p − p_parent): at rest (W = 1) that is C_parent·(the rest offset), the
T-pose's bone offset, constant whenever the joints between two humanoid bones do not
bend on their own. Positions and rotations rebuild the frame's joint positions
exactly (to float32), whatever C is.

Coordinates: graphsvc is right-handed, Y up, metres, a body at rest facing +Z with its
left at +X; Unity is left-handed, Y up, metres, facing +Z with its left at −X. The
change is the mirror of X: a position (x, y, z) → (−x, y, z); a rotation (w, x, y, z)
→ (w, x, −y, −z) (M·R·M with M = diag(−1, 1, 1)), sent in Unity's order (x, y, z, w).
"""

from __future__ import annotations

import ipaddress
import socket
import struct
from dataclasses import dataclass

import numpy as np

from graphsvc.errors import InputError
from graphsvc.motion import quat
from graphsvc.motion.joints import CANONICAL, joint_map
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.motion.skeleton import Skeleton
from graphsvc.service.servers import split_host_port

UNITY_BONES = {
    "pelvis": "Hips",
    "spine": "Spine",
    "chest": "Chest",
    "neck": "Neck",
    "head": "Head",
    "l_shoulder": "LeftUpperArm",
    "l_elbow": "LeftLowerArm",
    "l_wrist": "LeftHand",
    "r_shoulder": "RightUpperArm",
    "r_elbow": "RightLowerArm",
    "r_wrist": "RightHand",
    "l_hip": "LeftUpperLeg",
    "l_knee": "LeftLowerLeg",
    "l_ankle": "LeftFoot",
    "l_toe": "LeftToes",
    "r_hip": "RightUpperLeg",
    "r_knee": "RightLowerLeg",
    "r_ankle": "RightFoot",
    "r_toe": "RightToes",
}
# The next humanoid bone up the body (before the joints a skeleton lacks are skipped).
HUMANOID_PARENT = {
    "spine": "pelvis",
    "chest": "spine",
    "neck": "chest",
    "head": "neck",
    "l_shoulder": "chest",
    "l_elbow": "l_shoulder",
    "l_wrist": "l_elbow",
    "r_shoulder": "chest",
    "r_elbow": "r_shoulder",
    "r_wrist": "r_elbow",
    "l_hip": "pelvis",
    "l_knee": "l_hip",
    "l_ankle": "l_knee",
    "l_toe": "l_ankle",
    "r_hip": "pelvis",
    "r_knee": "r_hip",
    "r_ankle": "r_knee",
    "r_toe": "r_ankle",
}
# The T-pose's direction of each segment (joint → its child joint), in graphsvc's
# axes of a body facing +Z (left: +X); the bones not listed keep their parent's correction.
TPOSE_SEGMENTS = {
    "spine": ("chest", (0.0, 1.0, 0.0)),
    "chest": ("neck", (0.0, 1.0, 0.0)),
    "neck": ("head", (0.0, 1.0, 0.0)),
    "l_shoulder": ("l_elbow", (1.0, 0.0, 0.0)),
    "l_elbow": ("l_wrist", (1.0, 0.0, 0.0)),
    "r_shoulder": ("r_elbow", (-1.0, 0.0, 0.0)),
    "r_elbow": ("r_wrist", (-1.0, 0.0, 0.0)),
    "l_hip": ("l_knee", (0.0, -1.0, 0.0)),
    "l_knee": ("l_ankle", (0.0, -1.0, 0.0)),
    "r_hip": ("r_knee", (0.0, -1.0, 0.0)),
    "r_knee": ("r_ankle", (0.0, -1.0, 0.0)),
}
# The trunk's bones whose rest frame is set whole: (the joint above, whose direction
# goes to +Y; the two joints whose right-to-left line goes to +X).
TPOSE_FRAMES = {"pelvis": ("neck", ("l_hip", "r_hip")), "chest": ("neck", ("l_shoulder", "r_shoulder"))}
MIRROR_X = np.array([-1.0, 1.0, 1.0])
MIRROR_Q = np.array([1.0, 1.0, -1.0, -1.0])  # (w, x, y, z) → (w, x, −y, −z)


@dataclass(frozen=True)
class VmcRig:
    """A skeleton's humanoid bones, in order (every bone after its parent). joints: (B,)
    the skeleton joint of each; parent: (B,) the parent bone (−1: Hips); correction:
    (B, 4) C, each bone's rest correction (wxyz, graphsvc's axes); offsets: (B, 3) the
    T-pose's local offsets, metres in graphsvc's axes (Hips: its rest height)."""

    names: tuple[str, ...]
    joints: np.ndarray
    parent: np.ndarray
    correction: np.ndarray
    offsets: np.ndarray
    parents: np.ndarray  # the skeleton's


def vmc_rig(skeleton: Skeleton, mapping=None) -> VmcRig:
    """The rig of `skeleton` (its joints found by `joints.joint_map(skeleton, mapping)`)."""
    table = joint_map(skeleton, mapping)
    present = [c for c in CANONICAL if c not in table.missing]
    J = skeleton.num_joints
    _, rest = forward_kinematics(quat.identity((1, J)), skeleton.offsets[None].astype(np.float64), skeleton.parents)
    rest = rest[0]

    def above(c: str) -> str | None:  # the nearest present humanoid ancestor
        c = HUMANOID_PARENT.get(c)
        while c is not None and c in table.missing:
            c = HUMANOID_PARENT.get(c)
        return c

    correction: dict[str, np.ndarray] = {}
    for c in present:
        parent = above(c)
        base = quat.identity() if parent is None else correction[parent]
        if c in TPOSE_FRAMES:  # the trunk's frame, whatever its parent's
            upper, (l, r) = TPOSE_FRAMES[c]
            base = _upright(rest[table[upper]] - rest[table[c]], rest[table[l]] - rest[table[r]], base)
        segment = TPOSE_SEGMENTS.get(c)
        if segment is not None and segment[0] not in table.missing:
            along = quat.rotate(base, rest[table[segment[0]]] - rest[table[c]])
            if np.linalg.norm(along) > 1e-9:
                base = quat.mul(quat.between(along, np.array(segment[1])), base)
        correction[c] = base
    order = [c for c in present]
    index = {c: k for k, c in enumerate(order)}
    parent = np.array([index[above(c)] if above(c) is not None else -1 for c in order], np.int64)
    joints = np.array([table[c] for c in order], np.int64)
    corr = np.array([correction[c] for c in order])
    offsets = np.array(
        [
            quat.rotate(corr[parent[k]], rest[joints[k]] - rest[joints[parent[k]]])
            if parent[k] >= 0
            else np.array([0.0, rest[joints[k]][1], 0.0])
            for k in range(len(order))
        ]
    )
    return VmcRig(
        tuple(UNITY_BONES[c] for c in order), joints, parent, corr, offsets, np.asarray(skeleton.parents, np.int64)
    )


def _upright(up: np.ndarray, left: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """The rotation taking `up` onto +Y and `left` (made orthogonal to it) onto +X: a
    body upright facing +Z; `fallback` when either is degenerate."""
    if np.linalg.norm(up) < 1e-9 or np.linalg.norm(np.cross(left, up)) < 1e-9:
        return fallback
    y = up / np.linalg.norm(up)
    x = left - np.dot(left, y) * y
    x /= np.linalg.norm(x)
    return quat.from_matrix(np.stack([x, y, np.cross(x, y)]))  # (rows: the rotation onto X, Y, Z)


def pose_to_vmc(
    rig: VmcRig, rotations: np.ndarray, translations: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One frame's local rotations (J, 4) and translations (J, 3) → (root position (3,),
    bone local positions (B, 3), bone local rotations (B, 4) as (x, y, z, w)), in Unity's
    axes (the module docstring)."""
    world_rot, world_pos = forward_kinematics(
        np.asarray(rotations, np.float64)[None], np.asarray(translations, np.float64)[None], rig.parents
    )
    W, P = world_rot[0][rig.joints], world_pos[0][rig.joints]
    D = quat.normalize(quat.mul(W, quat.conjugate(rig.correction)))
    hips = rig.parent < 0
    root = np.array([P[hips][0, 0], 0.0, P[hips][0, 2]])
    Dp = np.where(hips[:, None], quat.identity((len(D),)), D[np.maximum(rig.parent, 0)])
    Pp = np.where(hips[:, None], root, P[np.maximum(rig.parent, 0)])
    local_rot = quat.mul(quat.conjugate(Dp), D)
    local_pos = quat.inv_rotate(Dp, P - Pp)
    local_rot = local_rot * MIRROR_Q
    return root * MIRROR_X, local_pos * MIRROR_X, local_rot[:, [1, 2, 3, 0]]


def parse_vmc_address(text: str) -> tuple[str, int]:
    """ "HOST:PORT" (IPv6 in brackets) → (numeric address, port); InputError, one line,
    for a malformed address, a port outside 1–65535 or a host that does not resolve."""
    host, port = split_host_port(text, "--vmc", "a VMC receiver, e.g. 127.0.0.1:39539")
    try:
        return str(ipaddress.ip_address(host)), int(port)
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, int(port), type=socket.SOCK_DGRAM)
    except (socket.gaierror, UnicodeError, OSError) as exc:
        raise InputError(f"--vmc {text!r}: cannot resolve {host} ({exc})") from None
    return infos[0][4][0], int(port)


def _message_head(address: str, tags: str, *strings: str) -> bytes:
    """An OSC message's fixed start: its address, its type tags and leading strings
    (python-osc's encoding of each)."""
    from pythonosc.parsing.osc_types import write_string

    return write_string(address) + write_string("," + tags) + b"".join(write_string(x) for x in strings)


def _element(message: bytes) -> bytes:
    return struct.pack(">i", len(message)) + message


class VmcSender:
    """Sends pose frames (PoseFrame protos, or anything with rotations_wxyz,
    translations_m and time_s) to a VMC receiver at `address` ("HOST:PORT"), one OSC
    bundle a frame, over UDP. A failed send (the network down) is counted, never
    raised: the stream goes on. sent, failed: frames; error: the first failure's reason.

    Each message's fixed start (address, type tags, the bone's name) is encoded once
    with python-osc's encoders, and each frame's numbers are packed behind it: python-osc's
    message and bundle builders parse back every datagram they build, which made a
    frame cost 1.3 ms; this way 0.3 ms, most of it the kinematics and the bones'
    rotations (tools/bench_vmc.py), about 1 % of a core for a 30 Hz stream.
    """

    BUNDLE_HEAD = b"#bundle\x00" + struct.pack(">Q", 1)  # (time tag 1: immediately)

    def __init__(self, address: str, skeleton: Skeleton, mapping=None):
        host, port = parse_vmc_address(address)
        self.address = address
        self.target = (host, port)
        self.rig = vmc_rig(skeleton, mapping)
        self.J = skeleton.num_joints
        self.socket = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
        self.sent = self.failed = 0
        self.error: str | None = None
        self._root = _message_head("/VMC/Ext/Root/Pos", "sfffffff", "root")
        self._bones = [_message_head("/VMC/Ext/Bone/Pos", "sfffffff", name) for name in self.rig.names]
        self._ok = _element(_message_head("/VMC/Ext/OK", "i") + struct.pack(">i", 1))
        self._time = _message_head("/VMC/Ext/T", "f")
        # The kinematics kernel compiled or loaded now, not on the stream's first frame.
        self.bundle(quat.identity((self.J,)), skeleton.offsets, 0.0)

    def bundle(self, rotations_wxyz, translations_m, time_s: float) -> bytes:
        """The OSC bundle of one frame, as sent."""
        rot = np.asarray(rotations_wxyz, np.float64).reshape(self.J, 4)
        trans = np.asarray(translations_m, np.float64).reshape(self.J, 3)
        root, positions, rotations = pose_to_vmc(self.rig, rot, trans)
        values = np.concatenate([positions, rotations], axis=1).astype(">f4")
        parts = [self.BUNDLE_HEAD, _element(self._root + np.r_[root, 0.0, 0.0, 0.0, 1.0].astype(">f4").tobytes())]
        parts += [_element(head + row.tobytes()) for head, row in zip(self._bones, values)]
        parts += [self._ok, _element(self._time + struct.pack(">f", float(time_s)))]
        return b"".join(parts)

    def send(self, frame, *_) -> None:
        """Send one frame (usable as a stream's on_frame(frame, latency_ms))."""
        try:
            self.socket.sendto(self.bundle(frame.rotations_wxyz, frame.translations_m, frame.time_s), self.target)
            self.sent += 1
        except OSError as exc:
            self.failed += 1
            self.error = self.error or (exc.strerror or str(exc))

    def close(self) -> None:
        self.socket.close()

    def summary(self) -> str:
        line = f"vmc: {self.sent} frames sent to {self.address}"
        return line + (f"; {self.failed} failed ({self.error})" if self.failed else "")

"""DeepMimic motion files: the JSON clips of the DeepMimic humanoid (Peng et al. 2018,
"DeepMimic: Example-Guided Deep Reinforcement Learning of Physics-Based Character
Skills") that pybullet ships in `pybullet_data/data/motions`, read into a Motion.

A file is `{"Loop": "wrap" | "none", "Frames": [[...], ...]}`; each frame holds its
duration (seconds to the next frame), the root's position (3, metres) and rotation (a
quaternion w, x, y, z), then each joint of the character in its order: a quaternion
(w, x, y, z) for a spherical joint, one angle (radians, about the joint's axis) for a
revolute one (knees, elbows), nothing for a fixed one (wrists). The character is the
humanoid of pybullet's `humanoid/humanoid.urdf` at the scale pybullet's DeepMimic
environment loads it with (0.25): `HUMANOID` transcribes it, and `character_from_urdf`
reads any URDF of that shape (a test checks the two agree). Rest pose: Y up, facing +X,
its right side at +Z, arms down; every joint's frame is its parent's, translated.

graphsvc's world is Y up with a figure facing +Z (left at +X): the reader turns
everything 90° about Y (`TO_GRAPHSVC`), which keeps every angle and length. Uneven
per-frame durations are resampled to one rate (`resample.resample_times`). The
humanoid has no head joint and no toes; `SITES` adds end sites for them from its
collision shapes (the centre of the head's sphere, the front edge of each foot's box at
its sole), so the canonical joints (`joints.BUILTIN_MAPS["deepmimic"]`) all exist but
the spine, which the chest stands in for.

The format is small JSON, read with the standard library; no maintained reader of it
exists outside the simulators that play it.
"""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphsvc.errors import FormatError, InputError
from graphsvc.fileio import read_input_bytes
from graphsvc.motion import quat
from graphsvc.motion.resample import resample_times
from graphsvc.motion.skeleton import POSITION_CHANNELS, Motion, Skeleton

URDF_SCALE = 0.25  # pybullet's DeepMimic environment: loadURDF("humanoid/humanoid.urdf", globalScaling=0.25)

# The humanoid's joints in the frames' order, as humanoid.urdf gives them (file units:
# URDF_SCALE of them make a metre): name, parent, type, origin xyz. Revolute joints
# turn about +Z.
HUMANOID_URDF = (
    ("root", None, "root", (0.0, 0.0, 0.0)),
    ("chest", "root", "spherical", (0.0, 0.944604, 0.0)),
    ("neck", "chest", "spherical", (0.0, 0.895576, 0.0)),
    ("right_hip", "root", "spherical", (0.0, 0.0, 0.339548)),
    ("right_knee", "right_hip", "revolute", (0.0, -1.686184, 0.0)),
    ("right_ankle", "right_knee", "spherical", (0.0, -1.639480, 0.0)),
    ("right_shoulder", "chest", "spherical", (-0.0962, 0.974, 0.73244)),
    ("right_elbow", "right_shoulder", "revolute", (0.0, -1.099152, 0.0)),
    ("right_wrist", "right_elbow", "fixed", (0.0, -1.035788, 0.0)),
    ("left_hip", "root", "spherical", (0.0, 0.0, -0.339548)),
    ("left_knee", "left_hip", "revolute", (0.0, -1.686184, 0.0)),
    ("left_ankle", "left_knee", "spherical", (0.0, -1.639480, 0.0)),
    ("left_shoulder", "chest", "spherical", (-0.0962, 0.974, -0.73244)),
    ("left_elbow", "left_shoulder", "revolute", (0.0, -1.099152, 0.0)),
    ("left_wrist", "left_elbow", "fixed", (0.0, -1.035788, 0.0)),
)

# End sites graphsvc adds (file units, in the parent's frame), from humanoid.urdf's
# collision shapes: the neck link's sphere (centre 0 0.7 0), each ankle link's box
# (centre 0.18 -0.09 0, size 0.708 0.22 0.36): its front edge (0.18 + 0.354) at its
# sole (-0.09 - 0.11).
SITES = (
    ("head", "neck", (0.0, 0.7, 0.0)),
    ("right_toe", "right_ankle", (0.534, -0.2, 0.0)),
    ("left_toe", "left_ankle", (0.534, -0.2, 0.0)),
)

# DeepMimic's frame (facing +X, right at +Z) → graphsvc's (facing +Z, left at +X): -90° about Y.
TO_GRAPHSVC = quat.about_y(-0.5 * math.pi)

ROOT_CHANNELS = POSITION_CHANNELS + ("Zrotation", "Xrotation", "Yrotation")
JOINT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")
WIDTH = {"spherical": 4, "revolute": 1, "fixed": 0}  # values a joint takes in a frame
MAX_UPSAMPLING = 1000  # a file's durations may not make more than this many frames of each of its own
MAX_POSITION_M = 1e6  # a root further from the origin is a broken file
RATE_SNAP = 1e-3  # a rate within this fraction of a whole number of Hz is that number


@dataclass(frozen=True, eq=False)
class Character:
    """A DeepMimic character: names (J,), parents (J,) int (-1 for the root), kinds
    ("root", "spherical", "revolute", "fixed"), offsets (J, 3) from the parent in metres
    and axes (J, 3) of the revolute joints (zero for the others), in the character's
    frame (Y up, facing +X), in the order their values appear in a frame; sites: end
    sites (name, parent index, offset in metres) added for the canonical joints."""

    names: tuple[str, ...]
    parents: np.ndarray
    kinds: tuple[str, ...]
    offsets: np.ndarray
    axes: np.ndarray
    sites: tuple[tuple[str, int, tuple[float, float, float]], ...] = ()

    @property
    def frame_width(self) -> int:
        """Values in one frame: duration, root position and rotation, every joint's."""
        return 8 + sum(WIDTH[k] for k in self.kinds[1:])


def humanoid_character() -> Character:
    """The DeepMimic humanoid (`HUMANOID_URDF` at `URDF_SCALE`), with its `SITES`."""
    names = tuple(n for n, _, _, _ in HUMANOID_URDF)
    parents = np.array([-1 if p is None else names.index(p) for _, p, _, _ in HUMANOID_URDF])
    kinds = tuple(k for _, _, k, _ in HUMANOID_URDF)
    offsets = np.array([o for _, _, _, o in HUMANOID_URDF]) * URDF_SCALE
    axes = np.array([[0.0, 0.0, 1.0] if k == "revolute" else [0.0, 0.0, 0.0] for k in kinds])
    sites = tuple((n, names.index(p), tuple(np.array(o) * URDF_SCALE)) for n, p, o in SITES)
    return Character(names, parents, kinds, offsets, axes, sites)


def _floats(text: str | None, default: str, path, what: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in (text or default).split()])
    except ValueError:
        raise FormatError(path, f"{what}: not three numbers: {text!r}") from None
    if values.shape != (3,) or not np.all(np.isfinite(values)):
        raise FormatError(path, f"{what}: not three finite numbers: {text!r}")
    return values


def character_from_urdf(path, scale: float = URDF_SCALE) -> Character:
    """The character a URDF file describes, its joints in file order (the order of a
    DeepMimic frame's values): the link no joint moves is the root (a fixed joint at
    its origin to one child link, pybullet's "base", is passed over); spherical,
    revolute and fixed joints, their origins times `scale`; origins must not be
    rotated (rpy 0, as DeepMimic's characters). No sites (they are not joints)."""
    path = Path(path)
    try:
        # (pybullet's humanoid.urdf ends in a NUL byte, which its own parser passes over)
        robot = ET.fromstring(read_input_bytes(path, "URDF").rstrip(b"\x00 \t\r\n"))
    except ET.ParseError as exc:
        raise FormatError(path, f"not valid XML: {exc}") from None
    joints = robot.findall("joint")
    children = {j.find("child").get("link") for j in joints if j.find("child") is not None}
    roots = [link.get("name") for link in robot.findall("link") if link.get("name") not in children]
    if len(roots) != 1:
        raise FormatError(path, f"expected one root link, found {len(roots)}")
    root = roots[0]
    parsed = []
    for j in joints:
        parent, child, origin = j.find("parent"), j.find("child"), j.find("origin")
        if parent is None or child is None:
            raise FormatError(path, f"joint {j.get('name')!r} lacks its parent or child link")
        rpy = _floats(origin.get("rpy") if origin is not None else None, "0 0 0", path, f"joint {j.get('name')!r} rpy")
        xyz = _floats(origin.get("xyz") if origin is not None else None, "0 0 0", path, f"joint {j.get('name')!r} xyz")
        axis = j.find("axis")
        axis = _floats(axis.get("xyz") if axis is not None else None, "1 0 0", path, f"joint {j.get('name')!r} axis")
        kind = j.get("type")
        if kind not in WIDTH:
            raise FormatError(
                path,
                f"joint {j.get('name')!r} is {kind!r}: a DeepMimic character has spherical, revolute and fixed joints",
            )
        if np.any(rpy != 0):
            raise FormatError(path, f"joint {j.get('name')!r} has a rotated origin (rpy {rpy.tolist()})")
        parsed.append((j.get("name"), parent.get("link"), child.get("link"), kind, xyz, axis))
    base = [p for p in parsed if p[1] == root and p[3] == "fixed" and not np.any(p[4])]
    if len(base) == 1 and sum(p[1] == root for p in parsed) == 1:
        parsed.remove(base[0])
        root = base[0][2]
    link_joint = {root: 0}
    names, parents, kinds, offsets, axes = [root], [-1], ["root"], [np.zeros(3)], [np.zeros(3)]
    for name, parent, child, kind, xyz, axis in parsed:
        if parent not in link_joint:
            raise FormatError(path, f"joint {name!r} hangs from link {parent!r}, which no earlier joint reaches")
        link_joint[child] = len(names)
        names.append(name)
        parents.append(link_joint[parent])
        kinds.append(kind)
        offsets.append(xyz * scale)
        axes.append(axis / (np.linalg.norm(axis) or 1.0) if kind == "revolute" else np.zeros(3))
    return Character(tuple(names), np.array(parents), tuple(kinds), np.array(offsets), np.array(axes))


def _depth_first(parents: np.ndarray) -> np.ndarray:
    """The joints in depth-first order, children by index: the order a BVH file lists
    them in, so a written clip reads back with the same skeleton."""
    order, stack = [], [0]
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(int(c) for c in np.nonzero(parents == j)[0][::-1])
    return np.array(order, dtype=np.int64)


def skeleton_of(character: Character) -> tuple[Skeleton, np.ndarray]:
    """The graphsvc skeleton of a character, in graphsvc's frame, and for each of its
    joints the character's joint (or site, numbered after the joints) it is: joints and
    sites in depth-first order; fixed joints without children and sites are end sites;
    the root has position and rotation channels, the other moving joints ZXY rotations
    (a revolute joint's one angle among them)."""
    J = len(character.names)
    has_child = np.zeros(J, bool)
    has_child[character.parents[character.parents >= 0]] = True
    names = character.names + tuple(n for n, _, _ in character.sites)
    parents = np.concatenate([character.parents, [p for _, p, _ in character.sites]]).astype(np.int64)
    offsets = np.concatenate([character.offsets, np.array([o for _, _, o in character.sites]).reshape(-1, 3)])
    end = [k == "fixed" and not has_child[j] for j, k in enumerate(character.kinds)] + [True] * len(character.sites)
    channels = [
        ROOT_CHANNELS if k == "root" else () if e else JOINT_CHANNELS
        for k, e in zip(character.kinds + ("site",) * len(character.sites), end)
    ]
    order = _depth_first(parents)
    new = np.empty_like(order)
    new[order] = np.arange(order.size)
    skeleton = Skeleton(
        tuple(names[j] for j in order),
        np.where(parents[order] < 0, -1, new[parents[order]]),
        quat.rotate(TO_GRAPHSVC, offsets[order]),
        tuple(channels[j] for j in order),
        np.array(end)[order],
    )
    return skeleton, order


# ---------------------------------------------------------------- detection and labels

_OBJECT = re.compile(rb"^\s*\{")
_HEAD = re.compile(rb'^\s*\{[\s\S]*?"Frames"\s*:')
SNIFF_BYTES = 4096


def _head(path) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read(SNIFF_BYTES)
    except OSError:
        return b""


def is_deepmimic(path) -> bool:
    """Whether a file looks like a DeepMimic motion file: a JSON object whose
    "Frames" key appears within its first SNIFF_BYTES bytes (what a folder scan
    collects among .txt files)."""
    return bool(_HEAD.match(_head(path)))


def may_be_deepmimic(path) -> bool:
    """Whether a .txt file named directly is read as a DeepMimic motion file: it
    starts with a JSON object (whose faults the reader then names)."""
    return bool(_OBJECT.match(_head(path)))


def clip_label(stem: str) -> str:
    """A clip's content label from its file name: the character prefix and take
    numbers dropped ("humanoid3d_walk" → "walk", "turn_left0" → "turn_left",
    "0walk_forward" → "walk_forward")."""
    label = re.sub(r"^[A-Za-z]+3d_", "", stem)
    label = re.sub(r"^\d+_?", "", label)
    label = re.sub(r"_?\d+$", "", label)
    return label or stem


def sample_name(stem: str) -> str:
    """The file stem a clip is written under as BVH: its label, then its take number
    after an underscore ("turn_left0" → "turn_left_0"), which graphsvc's label rule for
    other files drops again."""
    label = clip_label(stem)
    take = re.search(r"(\d+)$", stem)
    return f"{label}_{take.group(1)}" if take and label != stem else label


# ---------------------------------------------------------------- reading


def _columns(character: Character) -> list[str]:
    """What each value of a frame is, for messages."""
    cols = ["duration", "root position x", "root position y", "root position z"]
    cols += [f"root rotation {c}" for c in "wxyz"]
    for name, kind in zip(character.names[1:], character.kinds[1:]):
        cols += [f"{name} rotation {c}" for c in "wxyz"] if kind == "spherical" else [f"{name} angle"] * WIDTH[kind]
    return cols


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _frames(path: Path, data, character: Character) -> np.ndarray:
    """The frames as an (F, W) array, every shape and value checked."""
    if not isinstance(data, dict):
        raise FormatError(path, 'not a DeepMimic motion file: expected a JSON object {"Loop": ..., "Frames": [...]}')
    if "Frames" not in data:
        raise FormatError(path, 'missing key "Frames" (the DeepMimic motion file\'s list of frames)')
    frames = data["Frames"]
    if not isinstance(frames, list):
        raise FormatError(path, '"Frames" is not a list of frames')
    if not frames:
        raise FormatError(path, "zero frames")
    if "Loop" in data and not isinstance(data["Loop"], str):
        raise FormatError(path, '"Loop" is not a string ("wrap" or "none")')
    joints = len(character.names)
    for key in ("RightJoints", "LeftJoints"):
        items = data.get(key, [])
        if not isinstance(items, list) or not all(_is_number(i) and isinstance(i, int) for i in items):
            raise FormatError(path, f'"{key}" is not a list of joint numbers')
        bad = [i for i in items if not 0 <= i < joints]
        if bad:
            raise FormatError(path, f'"{key}" names joint {bad[0]}, which the skeleton lacks (joints 0–{joints - 1})')
    width = character.frame_width
    cols = _columns(character)
    for k, frame in enumerate(frames):
        if not isinstance(frame, list) or not all(_is_number(v) for v in frame):
            raise FormatError(path, f"frame {k} is not a list of numbers")
        if len(frame) > width:
            raise FormatError(
                path,
                f"frame {k} has {len(frame)} values, {len(frame) - width} more than the skeleton's "
                f"{joints} joints take ({width}): values for a joint the skeleton lacks",
            )
        if len(frame) < width:
            raise FormatError(
                path,
                f"frame {k} has {len(frame)} values; the skeleton's {joints} joints take {width} "
                f"(from {cols[len(frame)]} on missing)",
            )
    values = np.array(frames, dtype=np.float64)
    bad = ~np.isfinite(values)
    if bad.any():
        k, c = (int(i[0]) for i in np.nonzero(bad))
        raise FormatError(path, f"frame {k}: non-finite value ({values[k, c]}) for {cols[c]}")
    negative = np.nonzero(values[:, 0] < 0)[0]
    if negative.size:
        raise FormatError(path, f"frame {int(negative[0])}: negative duration {values[negative[0], 0]:g} s")
    return values


def frame_rate(durations: np.ndarray) -> float:
    """The uniform rate a clip is resampled to: the inverse of its median frame
    duration (the last frame's is the wrap back to the first, and not counted),
    snapped to whole Hz within RATE_SNAP (0.016666 s → 60 Hz)."""
    positive = durations[:-1][durations[:-1] > 0] if durations.size > 1 else durations[durations > 0]
    if positive.size == 0:
        raise InputError("every frame lasts 0 s: no frame rate")
    rate = 1.0 / float(np.median(positive))
    return float(round(rate)) if abs(rate - round(rate)) <= RATE_SNAP * rate else rate


def _quaternions(path: Path, values: np.ndarray, name: str) -> np.ndarray:
    """Unit quaternions; scaled by their largest component first, so no length overflows."""
    largest = np.abs(values).max(axis=-1, keepdims=True)
    zero = np.nonzero(largest[:, 0] < 1e-6)[0]
    if zero.size:
        raise FormatError(path, f"frame {int(zero[0])}: {name}'s rotation quaternion has zero length")
    return quat.normalize(values / largest)


def motion_from_frames(path, values: np.ndarray, character: Character, rate_hz: float | None = None) -> Motion:
    """A Motion from checked (F, W) frame values: local rotations and the root's
    position in graphsvc's frame, resampled to `rate_hz` (default `frame_rate`)."""
    path = Path(path)
    F = values.shape[0]
    J = len(character.names) + len(character.sites)
    rot = quat.identity((F, J))
    rot[:, 0] = _quaternions(path, values[:, 4:8], "root")
    far = np.nonzero(np.abs(values[:, 1:4]).max(axis=1) > MAX_POSITION_M)[0]
    if far.size:
        raise FormatError(path, f"frame {int(far[0])}: root position beyond ±{MAX_POSITION_M:g} m")
    c = 8
    for j, (name, kind) in enumerate(zip(character.names, character.kinds)):
        if kind == "spherical":
            rot[:, j] = _quaternions(path, values[:, c : c + 4], name)
        elif kind == "revolute":
            rot[:, j] = quat.from_axis_angle(character.axes[j], values[:, c])
        c += WIDTH.get(kind, 0)
    skeleton, order = skeleton_of(character)
    trans = np.broadcast_to(skeleton.offsets, (F, J, 3)).copy()
    # Every local rotation conjugated by the turn, the root's position turned.
    rot = quat.mul(quat.mul(TO_GRAPHSVC, rot[:, order]), quat.conjugate(TO_GRAPHSVC))
    trans[:, 0] = quat.rotate(TO_GRAPHSVC, values[:, 1:4])
    durations = values[:, 0]
    try:
        rate = frame_rate(durations) if rate_hz is None else float(rate_hz)
    except InputError as exc:
        raise FormatError(path, str(exc)) from None
    times = np.concatenate([[0.0], np.cumsum(durations[:-1])])
    frames = times[-1] * rate
    if not (np.isfinite(rate) and rate > 0 and np.isfinite(frames) and frames <= MAX_UPSAMPLING * F):
        raise FormatError(
            path,
            f"frame durations spanning {times[-1]:g} s make {frames:.3g} frames at {rate:g} Hz "
            f"of the file's {F}: more than {MAX_UPSAMPLING} times as many",
        )
    rot, trans = resample_times(rot, trans, times, rate)
    return Motion(skeleton, rot, trans, rate, name=path.stem, source=str(path))


def read_deepmimic(path, character: Character | None = None, rate_hz: float | None = None) -> Motion:
    """Read a DeepMimic motion file into a Motion (see the module docstring); the
    character defaults to the DeepMimic humanoid. FormatError naming the file for a
    file that is not JSON, lacks "Frames", has zero frames, a frame of the wrong
    length (values for a joint the skeleton lacks, or too few), a non-finite value,
    a negative duration or a zero quaternion."""
    path = Path(path)
    character = character or humanoid_character()
    raw = read_input_bytes(path, "DeepMimic motion")
    try:
        data = json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise FormatError(path, f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"not valid JSON: {exc.msg}", exc.lineno) from None
    except RecursionError:
        raise FormatError(path, "not valid JSON: nested too deeply") from None
    return motion_from_frames(path, _frames(path, data, character), character, rate_hz)

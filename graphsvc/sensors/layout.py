"""Sensor layouts: where accelerometers sit on the body and how they are oriented.

A sensor is attached to a segment named by a canonical joint (the segment runs from
that joint to `toward`, the next canonical joint down the bone), at fraction `along`
of the way, plus an optional offset in the segment's frame. Its frame is anatomical
(`sensors.anatomy`: X along the bone, Y from the joint's flexion axis or the hip or
shoulder line, the same on every skeleton), estimated from the motion it rides on
(`anatomical_placement`). Graphs and recordings made before anatomical frames used
the rest-pose convention (`place` without motion, `rest_rotation`): X along the bone,
Z "up" for arm segments and "forward" for leg and trunk segments in the skeleton's rest
pose, orthogonalised against X; Y = Z × X. A layout file may instead give the sensor's
rotation relative to the segment explicitly (then it is used as given, in either
convention).

Layout files are JSON or TOML:

    {"name": "my-layout",
     "sensors": [{"name": "r_wrist", "segment": "r_elbow", "toward": "r_wrist",
                  "along": 0.9, "offset_m": [0, 0, 0],
                  "rotation_wxyz": [1, 0, 0, 0]}]}   # optional, replaces the default frame

`toward` defaults to the canonical child of `segment`, `along` to 0.5.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from graphsvc.errors import LayoutError, SkeletonError
from graphsvc.motion import quat
from graphsvc.motion.joints import CANONICAL, CANONICAL_CHILD, joint_map
from graphsvc.motion.skeleton import Skeleton
from graphsvc.sensors import anatomy


@dataclass(frozen=True)
class SensorSpec:
    name: str
    segment: str
    toward: str
    along: float = 0.5
    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_wxyz: tuple[float, float, float, float] | None = None

    def to_dict(self) -> dict:
        out = {
            "name": self.name,
            "segment": self.segment,
            "toward": self.toward,
            "along": self.along,
            "offset_m": list(self.offset_m),
        }
        if self.rotation_wxyz is not None:
            out["rotation_wxyz"] = list(self.rotation_wxyz)
        return out


@dataclass(frozen=True)
class Layout:
    name: str
    sensors: tuple[SensorSpec, ...] = field(default_factory=tuple)

    @property
    def sensor_names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.sensors)

    def to_dict(self) -> dict:
        return {"name": self.name, "sensors": [s.to_dict() for s in self.sensors]}


def _sensor(name, segment, along, toward=None):
    return SensorSpec(name=name, segment=segment, toward=toward or CANONICAL_CHILD[segment], along=along)


PRESETS: dict[str, Layout] = {
    # Tautges et al.: four sensors on the forearms near the wrists and on the shins near the ankles.
    "wrists-ankles": Layout(
        "wrists-ankles",
        (
            _sensor("l_wrist", "l_elbow", 0.9),
            _sensor("r_wrist", "r_elbow", 0.9),
            _sensor("l_ankle", "l_knee", 0.9),
            _sensor("r_ankle", "r_knee", 0.9),
        ),
    ),
    # Kelly et al.: both forearms, both shins, lower back and chest.
    "kelly6": Layout(
        "kelly6",
        (
            _sensor("l_forearm", "l_elbow", 0.5),
            _sensor("r_forearm", "r_elbow", 0.5),
            _sensor("l_shin", "l_knee", 0.5),
            _sensor("r_shin", "r_knee", 0.5),
            _sensor("lower_back", "pelvis", 0.5),
            _sensor("chest", "chest", 0.5),
        ),
    ),
    # Kelly et al.'s single-sensor case on the racket hand.
    "right-wrist": Layout("right-wrist", (_sensor("r_wrist", "r_elbow", 0.9),)),
    # DIP-IMU's six (Huang et al. 2018), in its order: both forearms near the wrists, both
    # shins just below the knees, the head (on the head's segment, at its joint; X toward
    # the neck, no joint lying above it) and the pelvis, the root sensor.
    "dip6": Layout(
        "dip6",
        (
            _sensor("l_wrist", "l_elbow", 0.9),
            _sensor("r_wrist", "r_elbow", 0.9),
            _sensor("l_knee", "l_knee", 0.1),
            _sensor("r_knee", "r_knee", 0.1),
            _sensor("head", "head", 0.0, "neck"),
            _sensor("pelvis", "pelvis", 0.0),
        ),
    ),
}


def preset_names() -> str:
    """The presets, comma-separated, as help texts and messages list them."""
    return ", ".join(PRESETS)


ROOT_SEGMENT = "pelvis"


def root_sensor(layout: Layout) -> int | None:
    """The index of the layout's root sensor, the first on the pelvis segment (kelly6's
    `lower_back`, dip6's `pelvis`), against which the others' orientations are read
    (`sensors.orientation`); None when no sensor is on the pelvis."""
    for i, s in enumerate(layout.sensors):
        if s.segment == ROOT_SEGMENT:
            return i
    return None


def layout_from_dict(data: dict, source: str = "layout") -> Layout:
    """Validate a layout description (as in a layout file or a recording)."""
    if not isinstance(data, dict) or not isinstance(data.get("sensors"), list) or not data["sensors"]:
        raise LayoutError(f"{source}: expected {{'name': ..., 'sensors': [ ... ]}} with at least one sensor")
    sensors = []
    for i, item in enumerate(data["sensors"]):
        where = f"{source}: sensor {i}"
        if not isinstance(item, dict):
            raise LayoutError(f"{where}: expected an object")
        unknown = set(item) - {"name", "segment", "toward", "along", "offset_m", "rotation_wxyz"}
        if unknown:
            raise LayoutError(f"{where}: unknown keys {', '.join(sorted(unknown))}")
        segment = item.get("segment")
        if segment not in CANONICAL:
            raise LayoutError(f"{where}: segment must be a canonical joint ({', '.join(CANONICAL)}), got {segment!r}")
        toward = item.get("toward", CANONICAL_CHILD.get(segment))
        if toward not in CANONICAL or toward == segment:
            raise LayoutError(f"{where}: 'toward' must name another canonical joint, got {toward!r}")
        name = item.get("name", segment)
        if not isinstance(name, str) or not name:
            raise LayoutError(f"{where}: name must be a non-empty string")
        try:
            along = float(item.get("along", 0.5))
            offset = tuple(float(v) for v in item.get("offset_m", (0.0, 0.0, 0.0)))
            rotation = item.get("rotation_wxyz")
            rotation = None if rotation is None else tuple(float(v) for v in rotation)
        except (TypeError, ValueError):
            raise LayoutError(f"{where}: along, offset_m and rotation_wxyz must be numbers") from None
        if len(offset) != 3 or not np.all(np.isfinite(offset)) or not np.isfinite(along):
            raise LayoutError(f"{where}: offset_m must be 3 finite numbers and along finite")
        if rotation is not None and (
            len(rotation) != 4 or not np.isfinite(rotation).all() or np.linalg.norm(rotation) < 1e-6
        ):
            raise LayoutError(f"{where}: rotation_wxyz must be 4 finite numbers, not all zero")
        sensors.append(SensorSpec(name, segment, toward, along, offset, rotation))
    names = [s.name for s in sensors]
    if len(set(names)) != len(names):
        raise LayoutError(f"{source}: sensor names must be unique")
    return Layout(str(data.get("name", source)), tuple(sensors))


def load_layout(name_or_path: str) -> Layout:
    """A preset by name, or a JSON/TOML layout file."""
    if name_or_path in PRESETS:
        return PRESETS[name_or_path]
    path = Path(name_or_path)
    if not path.exists():
        raise LayoutError(f"unknown layout {name_or_path!r}: not a preset ({preset_names()}) and no such file")
    try:
        text = path.read_text()
        data = tomllib.loads(text) if path.suffix.lower() == ".toml" else json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise LayoutError(f"{path}: not a valid layout file: {exc}") from None
    data.setdefault("name", path.stem)
    return layout_from_dict(data, str(path))


@dataclass(frozen=True)
class Placement:
    """A layout resolved against one skeleton. Arrays have one row per sensor (S):
    segment (S,) joint index, toward (S,) joint index, along (S,), offset (S, 3) metres
    in the segment frame, rotation (S, 4) sensor frame relative to the segment.
    carrier (S,): −1 for a sensor rigid on its segment; else the joint whose frame
    carries the sensor's Y axis, `axis` (S, 3) in that joint's frame, while X follows
    the segment (rotation's X): the forearm's frame, which then does not turn with the
    forearm's twist (`sensors.anatomy`). convention: ANATOMICAL or REST_POSE."""

    layout: Layout
    segment: np.ndarray
    toward: np.ndarray
    along: np.ndarray
    offset: np.ndarray
    rotation: np.ndarray
    carrier: np.ndarray
    axis: np.ndarray
    convention: str = "rest-pose"


def _rest_world_positions(skeleton: Skeleton) -> np.ndarray:
    pos = np.zeros((skeleton.num_joints, 3))
    for j in range(1, skeleton.num_joints):
        pos[j] = pos[skeleton.parents[j]] + skeleton.offsets[j]
    return pos


def rest_rotation(bone_dir: np.ndarray, segment: str) -> np.ndarray:
    """Sensor frame relative to a segment whose rest-pose world rotation is the
    identity: X along the bone, Z toward +Y (arms) or +Z (legs, trunk), orthogonalised."""
    x = bone_dir / np.linalg.norm(bone_dir)
    is_arm = segment.endswith(("shoulder", "elbow", "wrist"))
    preferred = [np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])]
    if not is_arm:
        preferred.reverse()
    preferred.append(np.array([1.0, 0.0, 0.0]))
    for ref in preferred:
        z = ref - np.dot(ref, x) * x
        if np.linalg.norm(z) > 0.3:  # ref not nearly parallel to the bone
            break
    z /= np.linalg.norm(z)
    y = np.cross(z, x)
    return quat.from_matrix(np.stack([x, y, z], axis=1))


_PLACEMENTS: dict = {}


def place(layout: Layout, skeleton: Skeleton, mapping=None) -> Placement:
    """Resolve a layout on a skeleton. Raises SkeletonError naming a missing joint.

    Results are cached on the layout and the skeleton's geometry: a knowledge base
    has hundreds of clips but only a few distinct skeletons."""
    key = (layout, skeleton.names, skeleton.parents.tobytes(), skeleton.offsets.tobytes(), repr(mapping))
    cached = _PLACEMENTS.get(key)
    if cached is None:
        if len(_PLACEMENTS) > 256:
            _PLACEMENTS.clear()
        cached = _PLACEMENTS[key] = _place(layout, skeleton, mapping)
        for arr in (
            cached.segment,
            cached.toward,
            cached.along,
            cached.offset,
            cached.rotation,
            cached.carrier,
            cached.axis,
        ):
            arr.flags.writeable = False  # shared between callers
    return cached


def _place(layout: Layout, skeleton: Skeleton, mapping) -> Placement:
    try:
        table = joint_map(skeleton, mapping)
    except SkeletonError as exc:
        raise SkeletonError(f"layout {layout.name!r} cannot be placed: {exc}") from None
    rest = _rest_world_positions(skeleton)
    segment, toward, rotation = [], [], []
    for s in layout.sensors:
        seg, tow = table[s.segment], table[s.toward]
        bone = rest[tow] - rest[seg]
        if np.linalg.norm(bone) < 1e-6:
            lacks = [j for j in (s.segment, s.toward) if j in getattr(table, "missing", ())]
            raise SkeletonError(
                f"sensor {s.name!r}: joints {s.segment} and {s.toward} coincide in this skeleton"
                + (f" (it has no {' or '.join(lacks)})" if lacks else "")
            )
        segment.append(seg)
        toward.append(tow)
        if s.rotation_wxyz is not None:
            rotation.append(quat.normalize(np.array(s.rotation_wxyz)))
        else:
            rotation.append(rest_rotation(bone, s.segment))
    S = len(layout.sensors)
    return Placement(
        layout=layout,
        segment=np.array(segment, dtype=np.int64),
        toward=np.array(toward, dtype=np.int64),
        along=np.array([s.along for s in layout.sensors]),
        offset=np.array([s.offset_m for s in layout.sensors], dtype=float).reshape(-1, 3),
        rotation=np.array(rotation).reshape(-1, 4),
        carrier=np.full(S, -1, dtype=np.int64),
        axis=np.zeros((S, 3)),
    )


def anatomical_placement(
    layout: Layout, skeleton: Skeleton, mapping, world_rot: np.ndarray, world_pos: np.ndarray
) -> Placement:
    """The layout on a skeleton with anatomical sensor frames (`sensors.anatomy`),
    estimated from the motion world_rot (F, J, 4), world_pos (F, J, 3) that the sensors
    ride on (a clip, or a sample of a graph's nodes). Sensors whose layout gives
    rotation_wxyz keep it."""
    base = place(layout, skeleton, mapping)
    table = joint_map(skeleton, mapping)
    rest_rot, rest_pos = anatomy.rest_pose(skeleton)
    segments = [s.segment for s in layout.sensors]
    towards = [s.toward for s in layout.sensors]
    rotation = anatomy.estimate_rotations(world_rot, world_pos, rest_rot, rest_pos, table, segments, towards)
    carrier = np.full(len(segments), -1, dtype=np.int64)
    axis = np.zeros((len(segments), 3))
    for k, (seg, spec) in enumerate(zip(segments, layout.sensors)):
        if spec.rotation_wxyz is not None:
            rotation[k] = base.rotation[k]
            continue
        upper = anatomy.CARRIED_BY.get(seg)
        if upper is not None:  # Y: the elbow's axis as the upper arm carries it
            carrier[k] = table[upper]
            up_rot = anatomy.estimate_rotations(
                world_rot, world_pos, rest_rot, rest_pos, table, [upper], [anatomy.CARRIED_TOWARD[upper]]
            )[0]
            axis[k] = quat.rotate(up_rot, np.array([0.0, 1.0, 0.0]))
    out = replace(base, rotation=rotation, carrier=carrier, axis=axis, convention=anatomy.ANATOMICAL)
    for arr in (out.rotation, out.carrier, out.axis):
        arr.flags.writeable = False
    return out

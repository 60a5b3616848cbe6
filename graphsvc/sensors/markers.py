"""Optical marker sets: where labelled markers sit on the body, and their positions.

A marker is carried rigidly by one segment (a canonical joint's frame: `segment`) and
sits, in the skeleton's rest pose, at canonical joint `at` (default: the segment's own
joint), moved `along` the bone toward canonical joint `toward` (a fraction; negative
values reach beyond `at`, away from `toward`), plus `offset_m` in the rest pose's axes
(X to the body's left, Y up, Z forward; metres). On any skeleton of the knowledge base
the same definition gives the same anatomical spot, scaled by that skeleton's bones.

Built-in sets (`PRESETS`): `hands-feet` (4: the backs of the hands and the tops of the
forefeet), `left-foot` (1), `head-back` (4: LFHD, RFHD, C7, T10) and `vicon` (the 41
markers of the Vicon Plug-in-Gait-style set used by CMU's and HDM05's C3D files: head
LFHD RFHD LBHD RBHD, trunk C7 T10 CLAV STRN RBAC, arms LSHO LUPA LELB LFRM LWRA LWRB
LFIN and R…, pelvis LFWT RFWT LBWT RBWT, legs LTHI LKNE LSHN LANK LHEE LTOE LMT5 and
R…). Their offsets are nominal (a typical adult); real markers sit where the
performer's skin put them, which the SSG strategy estimates (`strategies.ssg.offsets`).

Marker set files are JSON or TOML:

    {"name": "my-markers",
     "markers": [{"name": "LWRA", "segment": "l_elbow", "at": "l_wrist", "offset_m": [0, 0, 0.03]},
                 {"name": "LTHI", "segment": "l_hip", "toward": "l_knee", "along": 0.5,
                  "offset_m": [0.07, 0, 0]}]}

`at` defaults to `segment`, `toward` to none (then `along` must be 0), `offset_m` to
zeros.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from graphsvc.errors import InputError, LayoutError, SkeletonError
from graphsvc.motion import quat
from graphsvc.motion.joints import CANONICAL, joint_map
from graphsvc.motion.skeleton import Skeleton


@dataclass(frozen=True)
class MarkerSpec:
    name: str
    segment: str
    at: str | None = None
    toward: str | None = None
    along: float = 0.0
    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def to_dict(self) -> dict:
        out = {"name": self.name, "segment": self.segment, "offset_m": list(self.offset_m)}
        if self.at is not None and self.at != self.segment:
            out["at"] = self.at
        if self.toward is not None:
            out["toward"] = self.toward
            out["along"] = self.along
        return out


@dataclass(frozen=True)
class MarkerSet:
    name: str
    markers: tuple[MarkerSpec, ...] = field(default_factory=tuple)

    @property
    def marker_names(self) -> tuple[str, ...]:
        return tuple(m.name for m in self.markers)

    def to_dict(self) -> dict:
        return {"name": self.name, "markers": [m.to_dict() for m in self.markers]}


def _mirror(spec: MarkerSpec, name: str) -> MarkerSpec:
    """The right-side twin of a left-side marker (X negated, l_ joints → r_)."""
    side = lambda j: None if j is None else ("r_" + j[2:] if j.startswith("l_") else j)  # noqa: E731
    x, y, z = spec.offset_m
    return MarkerSpec(name, side(spec.segment), side(spec.at), side(spec.toward), spec.along, (-x, y, z))


def _vicon() -> tuple[MarkerSpec, ...]:
    M = MarkerSpec
    left = [
        M("LFHD", "head", offset_m=(0.07, 0.10, 0.08)),
        M("LBHD", "head", offset_m=(0.07, 0.10, -0.08)),
        M("LSHO", "chest", at="l_shoulder", offset_m=(0.0, 0.05, 0.0)),
        M("LUPA", "l_shoulder", toward="l_elbow", along=0.6, offset_m=(0.0, 0.0, -0.05)),
        M("LELB", "l_shoulder", at="l_elbow", offset_m=(0.0, 0.0, -0.04)),
        M("LFRM", "l_elbow", toward="l_wrist", along=0.5, offset_m=(0.0, 0.04, 0.0)),
        M("LWRA", "l_elbow", at="l_wrist", offset_m=(0.0, 0.0, 0.03)),
        M("LWRB", "l_elbow", at="l_wrist", offset_m=(0.0, 0.0, -0.03)),
        M("LFIN", "l_wrist", toward="l_elbow", along=-0.3),
        M("LFWT", "pelvis", at="l_hip", offset_m=(0.02, 0.08, 0.07)),
        M("LBWT", "pelvis", at="l_hip", offset_m=(0.0, 0.09, -0.12)),
        M("LTHI", "l_hip", toward="l_knee", along=0.6, offset_m=(0.07, 0.0, 0.0)),
        M("LKNE", "l_hip", at="l_knee", offset_m=(0.05, 0.0, 0.0)),
        M("LSHN", "l_knee", toward="l_ankle", along=0.5, offset_m=(0.04, 0.0, 0.03)),
        M("LANK", "l_knee", at="l_ankle", offset_m=(0.04, 0.0, 0.0)),
        M("LHEE", "l_ankle", offset_m=(0.0, -0.03, -0.07)),
        M("LTOE", "l_ankle", at="l_toe", offset_m=(0.0, 0.02, 0.0)),
        M("LMT5", "l_ankle", at="l_toe", offset_m=(0.04, 0.01, -0.03)),
    ]
    trunk = [
        M("C7", "chest", at="neck", offset_m=(0.0, 0.0, -0.08)),
        M("T10", "spine", toward="chest", along=0.5, offset_m=(0.0, 0.0, -0.12)),
        M("CLAV", "chest", toward="neck", along=0.9, offset_m=(0.0, 0.0, 0.08)),
        M("STRN", "chest", toward="neck", along=0.3, offset_m=(0.0, 0.0, 0.12)),
        M("RBAC", "chest", toward="neck", along=0.4, offset_m=(-0.08, 0.0, -0.11)),
    ]
    out = []
    for spec in left:
        out.append(spec)
        out.append(_mirror(spec, "R" + spec.name[1:]))
    by_name = {s.name: s for s in out + trunk}
    order = (
        "LFHD RFHD LBHD RBHD C7 T10 CLAV STRN RBAC LSHO LUPA LELB LFRM LWRA LWRB LFIN RSHO RUPA RELB RFRM "
        "RWRA RWRB RFIN LFWT RFWT LBWT RBWT LTHI LKNE LSHN LANK LHEE LTOE LMT5 RTHI RKNE RSHN RANK RHEE RTOE "
        "RMT5"
    ).split()
    return tuple(by_name[n] for n in order)


_VICON = _vicon()
_BY_NAME = {s.name: s for s in _VICON}
_L_HAND = MarkerSpec("l_hand", "l_wrist", toward="l_elbow", along=-0.25)
_L_FOOT = MarkerSpec("l_foot", "l_ankle", at="l_toe", offset_m=(0.0, 0.02, 0.0))

PRESETS: dict[str, MarkerSet] = {
    # The thesis' first test (Tautges 2012, §4.4): one marker on each hand and foot.
    "hands-feet": MarkerSet("hands-feet", (_L_HAND, _mirror(_L_HAND, "r_hand"), _L_FOOT, _mirror(_L_FOOT, "r_foot"))),
    # Its sparsest input: a single foot marker.
    "left-foot": MarkerSet("left-foot", (_L_FOOT,)),
    # What an occluded outdoor shot left (§4.4): the head and the upper back.
    "head-back": MarkerSet("head-back", tuple(_BY_NAME[n] for n in ("LFHD", "RFHD", "C7", "T10"))),
    "vicon": MarkerSet("vicon", _VICON),
}

# Segments on the head and trunk: a set whose markers all sit on these says little about
# the limbs (the SSG's defaults then follow the thesis' head-and-back settings).
TRUNK_SEGMENTS = frozenset({"pelvis", "spine", "chest", "neck", "head"})


def marker_set_from_dict(data: dict, source: str = "marker set") -> MarkerSet:
    """Validate a marker set description (as in a file, a recording's meta or a request)."""
    if not isinstance(data, dict) or not isinstance(data.get("markers"), list) or not data["markers"]:
        raise LayoutError(f"{source}: expected {{'name': ..., 'markers': [ ... ]}} with at least one marker")
    markers = []
    for i, item in enumerate(data["markers"]):
        where = f"{source}: marker {i}"
        if not isinstance(item, dict):
            raise LayoutError(f"{where}: expected an object")
        unknown = set(item) - {"name", "segment", "at", "toward", "along", "offset_m"}
        if unknown:
            raise LayoutError(f"{where}: unknown keys {', '.join(sorted(unknown))}")
        name = item.get("name")
        if not isinstance(name, str) or not name or name != name.strip() or set(name) & set(',"\r\n'):
            raise LayoutError(f"{where}: name must be a non-empty string without commas, quotes or edge spaces")
        where = f"{source}: marker {name!r}"
        segment = item.get("segment")
        if segment not in CANONICAL:
            raise LayoutError(f"{where}: segment must be a canonical joint ({', '.join(CANONICAL)}), got {segment!r}")
        at, toward = item.get("at", segment), item.get("toward")
        if at not in CANONICAL:
            raise LayoutError(f"{where}: 'at' must be a canonical joint, got {at!r}")
        if toward is not None and (toward not in CANONICAL or toward == at):
            raise LayoutError(f"{where}: 'toward' must name another canonical joint, got {toward!r}")
        try:
            along = float(item.get("along", 0.0))
            offset = tuple(float(v) for v in item.get("offset_m", (0.0, 0.0, 0.0)))
        except (TypeError, ValueError):
            raise LayoutError(f"{where}: along and offset_m must be numbers") from None
        if len(offset) != 3 or not np.all(np.isfinite(offset)) or not np.isfinite(along):
            raise LayoutError(f"{where}: offset_m must be 3 finite numbers and along finite")
        if toward is None and along != 0.0:
            raise LayoutError(f"{where}: 'along' needs 'toward'")
        markers.append(MarkerSpec(name, segment, None if at == segment else at, toward, along, offset))
    names = [m.name for m in markers]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise LayoutError(f"{source}: duplicate marker names: {', '.join(dup)}")
    return MarkerSet(str(data.get("name", source)), tuple(markers))


def load_marker_set(name_or_path) -> MarkerSet:
    """A built-in set by name, or a JSON/TOML marker set file (module docstring)."""
    if isinstance(name_or_path, MarkerSet):
        return name_or_path
    if isinstance(name_or_path, dict):
        return marker_set_from_dict(name_or_path)
    if name_or_path in PRESETS:
        return PRESETS[name_or_path]
    path = Path(name_or_path)
    if not path.is_file():
        raise LayoutError(
            f"unknown marker set {str(name_or_path)!r}: not a built-in set ({', '.join(PRESETS)}) and no such file"
        )
    try:
        text = path.read_text(encoding="utf-8")
        data = tomllib.loads(text) if path.suffix.lower() == ".toml" else json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise LayoutError(f"{path}: not a valid marker set file: {exc}") from None
    if isinstance(data, dict):
        data.setdefault("name", path.stem)
    return marker_set_from_dict(data, str(path))


def parse_names(text: str | None) -> tuple[str, ...] | None:
    """'A,B,C' → ('A', 'B', 'C'); None or empty → None."""
    if text is None:
        return None
    names = tuple(n.strip() for n in str(text).split(",") if n.strip())
    return names or None


def keep_markers(marker_set: MarkerSet, keep) -> MarkerSet:
    """The set restricted to the names in `keep` (in the set's order); None keeps all.
    InputError for a name the set does not define."""
    if keep is None:
        return marker_set
    keep = tuple(keep)
    unknown = [n for n in keep if n not in marker_set.marker_names]
    if unknown:
        raise InputError(
            f"marker set {marker_set.name!r} defines no marker {', '.join(unknown)} "
            f"(it has {', '.join(marker_set.marker_names)})"
        )
    if not keep:
        raise InputError("no markers kept")
    return replace(marker_set, markers=tuple(m for m in marker_set.markers if m.name in keep))


@dataclass(frozen=True)
class MarkerPlacement:
    """A marker set resolved on one skeleton: carrier (M,) joint index whose world frame
    carries each marker, local (M, 3) its offset in that frame (m)."""

    marker_set: MarkerSet
    carrier: np.ndarray
    local: np.ndarray


def _rest_positions(skeleton: Skeleton) -> np.ndarray:
    pos = np.zeros((skeleton.num_joints, 3))
    for j in range(1, skeleton.num_joints):
        pos[j] = pos[skeleton.parents[j]] + skeleton.offsets[j]
    return pos


def place_markers(marker_set: MarkerSet, skeleton: Skeleton, mapping=None) -> MarkerPlacement:
    """Resolve `marker_set` on `skeleton` (its rest pose's world rotations are the
    identity, as for every skeleton graphsvc reads). SkeletonError for a skeleton
    without the canonical joints."""
    try:
        table = joint_map(skeleton, mapping)
    except SkeletonError as exc:
        raise SkeletonError(f"marker set {marker_set.name!r} cannot be placed: {exc}") from None
    rest = _rest_positions(skeleton)
    carrier, local = [], []
    for m in marker_set.markers:
        lacks = [j for j in (m.segment, m.at, m.toward) if j is not None and j in table.missing]
        if lacks:
            raise SkeletonError(f"marker {m.name!r} sits on {', '.join(lacks)}, which this skeleton lacks")
        c = table[m.segment]
        at = rest[table[m.at or m.segment]]
        point = at + np.asarray(m.offset_m, dtype=np.float64)
        if m.toward is not None:
            point = point + m.along * (rest[table[m.toward]] - at)
        carrier.append(c)
        local.append(point - rest[c])
    return MarkerPlacement(
        marker_set, np.array(carrier, dtype=np.int64), np.array(local, dtype=np.float64).reshape(-1, 3)
    )


def marker_positions(
    world_rot: np.ndarray, world_pos: np.ndarray, placement: MarkerPlacement, local: np.ndarray | None = None
) -> np.ndarray:
    """(F, M, 3) world positions (m) of the placed markers on poses given by world
    rotations (F, J, 4) and positions (F, J, 3); local: (M, 3) offsets replacing the
    placement's (estimated ones)."""
    local = placement.local if local is None else np.asarray(local, dtype=np.float64)
    c = placement.carrier
    return world_pos[:, c] + quat.rotate(world_rot[:, c], np.broadcast_to(local, world_rot.shape[:1] + local.shape))

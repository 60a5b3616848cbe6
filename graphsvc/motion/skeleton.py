"""Skeleton and motion as flat arrays.

A Skeleton is a joint hierarchy in topological order (every parent precedes its
children). A Motion holds, per frame and joint, the local rotation (a quaternion,
(w, x, y, z)) and the local translation relative to the parent joint, in metres.
Joints without translation channels carry their rest offset in every frame, so
forward kinematics never needs to know which joints had channels.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from graphsvc.errors import InputError, SkeletonError

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")


@dataclass(frozen=True, eq=False)
class Skeleton:
    """names: J joint names; parents: (J,) int, -1 for the root; offsets: (J, 3) rest
    offsets from the parent in metres; channels: per joint the BVH channel names in
    file order (empty for end sites); end_site: (J,) bool."""

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    end_site: np.ndarray

    def __post_init__(self):
        parents = np.asarray(self.parents, dtype=np.int64)
        if len(self.names) == 0:
            raise SkeletonError("skeleton has no joints")
        if len(set(self.names)) != len(self.names):
            dup = sorted({n for n in self.names if self.names.count(n) > 1})
            raise SkeletonError(f"duplicate joint names: {', '.join(dup)}")
        if parents.shape != (len(self.names),) or parents[0] != -1:
            raise SkeletonError("parents must list one entry per joint, root first")
        if np.any(parents[1:] >= np.arange(1, len(parents))) or np.any(parents[1:] < 0):
            raise SkeletonError("joints must be in topological order with a single root")
        object.__setattr__(self, "parents", parents)
        object.__setattr__(self, "offsets", np.asarray(self.offsets, dtype=np.float64).reshape(-1, 3))
        object.__setattr__(self, "end_site", np.asarray(self.end_site, dtype=bool))

    @property
    def num_joints(self) -> int:
        return len(self.names)

    @property
    def num_joints_excluding_end_sites(self) -> int:
        """The joints as a user counts them (a BVH's ROOT and JOINT entries): what
        `inspect`, `mapping` and a graph's summary print."""
        return int(len(self.names) - np.count_nonzero(self.end_site))

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise SkeletonError(f"skeleton has no joint named {name!r}") from None

    def children(self, joint: int) -> list[int]:
        return [int(j) for j in np.nonzero(self.parents == joint)[0]]

    def topology(self) -> tuple:
        """What two skeletons must share to be one topology (bone lengths may differ)."""
        return (self.names, tuple(int(p) for p in self.parents), self.channels)

    def same_topology(self, other: Skeleton) -> bool:
        return self.topology() == other.topology()

    def bone_lengths(self) -> np.ndarray:
        return np.linalg.norm(self.offsets, axis=-1)


@dataclass(eq=False)
class Motion:
    """rotations: (F, J, 4) local quaternions; translations: (F, J, 3) local
    translations in metres; rate_hz: frames per second. name/source/labels describe
    where the clip came from (labels: content label first, then user tags);
    retargeted_from: the skeleton family it was captured on when it was put on another
    skeleton (`retarget`), else empty."""

    skeleton: Skeleton
    rotations: np.ndarray
    translations: np.ndarray
    rate_hz: float
    name: str = ""
    source: str = ""
    labels: tuple[str, ...] = field(default_factory=tuple)
    retargeted_from: str = ""

    def __post_init__(self):
        J = self.skeleton.num_joints
        self.rotations = np.asarray(self.rotations, dtype=np.float64)
        self.translations = np.asarray(self.translations, dtype=np.float64)
        if self.rotations.ndim != 3 or self.rotations.shape[1:] != (J, 4):
            raise InputError(f"rotations must be (frames, {J}, 4), got {self.rotations.shape}")
        if self.translations.shape != self.rotations.shape[:2] + (3,):
            raise InputError(f"translations must be (frames, {J}, 3), got {self.translations.shape}")
        if not (np.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise InputError(f"frame rate must be positive and finite, got {self.rate_hz}")

    @property
    def num_frames(self) -> int:
        return self.rotations.shape[0]

    @property
    def duration_s(self) -> float:
        return self.num_frames / self.rate_hz

    def copy(self, **changes) -> Motion:
        out = replace(self, **changes)
        if "rotations" not in changes:
            out.rotations = self.rotations.copy()
        if "translations" not in changes:
            out.translations = self.translations.copy()
        return out

    def slice(self, start: int, stop: int) -> Motion:
        return replace(
            self,
            rotations=self.rotations[start:stop].copy(),
            translations=self.translations[start:stop].copy(),
        )


def check_finite(motion: Motion) -> None:
    """Refuse NaN/inf values and empty motions with a specific error."""
    where = motion.source or motion.name or "motion"
    if motion.num_frames == 0:
        raise InputError(f"{where}: motion has zero frames")
    for label, arr in (("rotations", motion.rotations), ("translations", motion.translations)):
        bad = ~np.isfinite(arr)
        if bad.any():
            frame = int(np.nonzero(bad.any(axis=tuple(range(1, arr.ndim))))[0][0])
            raise InputError(f"{where}: non-finite {label} at frame {frame}")

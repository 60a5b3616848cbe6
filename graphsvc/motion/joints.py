"""Canonical joints  and their mapping onto concrete skeletons.

Sensors and metrics address joints by canonical name; each skeleton family maps
those names onto its own joints. Built-in maps cover the CMU ASF skeleton (a joint
sits at the start of the ASF bone it is named after), the Bandai-Namco BVH skeleton
and graphsvc's procedural skeleton; any other skeleton needs a JSON mapping file
`{"pelvis": "Hips", "l_wrist": "LeftHand", ...}`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from graphsvc.errors import FormatError, SkeletonError
from graphsvc.motion.skeleton import Skeleton

CANONICAL = (
    "pelvis", "spine", "chest", "neck", "head",
    "l_shoulder", "r_shoulder", "l_elbow", "r_elbow", "l_wrist", "r_wrist",
    "l_hip", "r_hip", "l_knee", "r_knee", "l_ankle", "r_ankle", "l_toe", "r_toe",
)  # fmt: skip

# The next canonical joint down each bone: the direction a segment points in.
CANONICAL_CHILD = {
    "pelvis": "spine", "spine": "chest", "chest": "neck", "neck": "head",
    "l_shoulder": "l_elbow", "l_elbow": "l_wrist", "r_shoulder": "r_elbow", "r_elbow": "r_wrist",
    "l_hip": "l_knee", "l_knee": "l_ankle", "l_ankle": "l_toe",
    "r_hip": "r_knee", "r_knee": "r_ankle", "r_ankle": "r_toe",
}  # fmt: skip

MIRROR = {n: ("r_" + n[2:] if n.startswith("l_") else "l_" + n[2:] if n.startswith("r_") else n) for n in CANONICAL}

BUILTIN_MAPS: dict[str, dict[str, str]] = {
    "procedural": {n: n for n in CANONICAL},
    "bandai": {
        "pelvis": "Hips", "spine": "Spine", "chest": "Chest", "neck": "Neck", "head": "Head",
        "l_shoulder": "UpperArm_L", "r_shoulder": "UpperArm_R",
        "l_elbow": "LowerArm_L", "r_elbow": "LowerArm_R",
        "l_wrist": "Hand_L", "r_wrist": "Hand_R",
        "l_hip": "UpperLeg_L", "r_hip": "UpperLeg_R",
        "l_knee": "LowerLeg_L", "r_knee": "LowerLeg_R",
        "l_ankle": "Foot_L", "r_ankle": "Foot_R", "l_toe": "Toes_L", "r_toe": "Toes_R",
    },
    "cmu": {
        "pelvis": "root", "spine": "upperback", "chest": "thorax", "neck": "lowerneck",
        "head": "head", "l_shoulder": "lhumerus", "r_shoulder": "rhumerus",
        "l_elbow": "lradius", "r_elbow": "rradius", "l_wrist": "lwrist", "r_wrist": "rwrist",
        "l_hip": "lfemur", "r_hip": "rfemur", "l_knee": "ltibia", "r_knee": "rtibia",
        "l_ankle": "lfoot", "r_ankle": "rfoot", "l_toe": "ltoes", "r_toe": "rtoes",
    },
}  # fmt: skip


def load_mapping_file(path) -> dict[str, str]:
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise FormatError(path, "mapping file not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FormatError(path, f"not valid JSON: {exc}") from None
    if not isinstance(data, dict) or not all(isinstance(v, str) for v in data.values()):
        raise FormatError(path, 'expected a JSON object {"canonical_name": "joint_name", ...}')
    unknown = sorted(set(data) - set(CANONICAL))
    if unknown:
        raise FormatError(path, f"unknown canonical joints: {', '.join(unknown)}")
    return data


def joint_map(skeleton: Skeleton, mapping: dict[str, str] | str | Path | None = None) -> dict[str, int]:
    """Canonical name → joint index in `skeleton`. With no mapping, the first built-in
    map whose joints all exist is used. A partial mapping file is completed from
    the built-in map that matches best."""
    names = set(skeleton.names)
    if isinstance(mapping, (str, Path)):
        mapping = load_mapping_file(mapping)
    candidates = list(BUILTIN_MAPS.items())
    if mapping is not None:
        best = max(candidates, key=lambda kv: sum(v in names for v in kv[1].values()))[1]
        mapping = {**{k: v for k, v in best.items() if v in names}, **mapping}
        candidates = [("given", mapping)]
    for family, table in candidates:
        missing = [c for c in CANONICAL if table.get(c) not in names]
        if not missing:
            return {c: skeleton.index(table[c]) for c in CANONICAL}
    if mapping is not None:
        raise SkeletonError(
            "joint mapping leaves canonical joints unmapped or names joints the skeleton "
            f"lacks: {', '.join(missing)}"
        )
    raise SkeletonError(
        "unknown skeleton (not CMU, Bandai-Namco or procedural); give a joint mapping "
        f"file. Skeleton joints: {', '.join(skeleton.names[:12])}..."
    )


def canonical_indices(skeleton: Skeleton, mapping=None) -> np.ndarray:
    """(19,) joint indices of CANONICAL in `skeleton`'s order."""
    table = joint_map(skeleton, mapping)
    return np.array([table[c] for c in CANONICAL], dtype=np.int64)

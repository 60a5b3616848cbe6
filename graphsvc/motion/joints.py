"""Canonical joints and their mapping onto concrete skeletons.

Sensors and metrics address joints by canonical name; each skeleton family maps
those names onto its own joints. Built-in maps cover the CMU ASF skeleton (a joint
sits at the start of the ASF bone it is named after), the Bandai-Namco BVH skeleton,
the DeepMimic humanoid (no spine) and graphsvc's procedural skeleton; any other skeleton needs a JSON mapping file
`{"pelvis": "Hips", "l_wrist": "LeftHand", ...}`, or `--mapping guess`, which proposes
one from the joint names (`guess_mapping`). A mapping may leave out the joints a
skeleton lacks among spine, chest, neck and the toes (`OPTIONAL`): they map to a
stand-in, and the table lists them as missing, so metrics compare only what both
skeletons have.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from graphsvc.errors import FormatError, SkeletonError
from graphsvc.fileio import read_json_file
from graphsvc.motion.skeleton import Skeleton

CANONICAL = (
    "pelvis",
    "spine",
    "chest",
    "neck",
    "head",
    "l_shoulder",
    "r_shoulder",
    "l_elbow",
    "r_elbow",
    "l_wrist",
    "r_wrist",
    "l_hip",
    "r_hip",
    "l_knee",
    "r_knee",
    "l_ankle",
    "r_ankle",
    "l_toe",
    "r_toe",
)

# The next canonical joint down each bone: the direction a segment points in.
CANONICAL_CHILD = {
    "pelvis": "spine",
    "spine": "chest",
    "chest": "neck",
    "neck": "head",
    "l_shoulder": "l_elbow",
    "l_elbow": "l_wrist",
    "r_shoulder": "r_elbow",
    "r_elbow": "r_wrist",
    "l_hip": "l_knee",
    "l_knee": "l_ankle",
    "l_ankle": "l_toe",
    "r_hip": "r_knee",
    "r_knee": "r_ankle",
    "r_ankle": "r_toe",
}

MIRROR = {n: ("r_" + n[2:] if n.startswith("l_") else "l_" + n[2:] if n.startswith("r_") else n) for n in CANONICAL}

BUILTIN_MAPS: dict[str, dict[str, str]] = {
    "procedural": {n: n for n in CANONICAL},
    "bandai": {
        "pelvis": "Hips",
        "spine": "Spine",
        "chest": "Chest",
        "neck": "Neck",
        "head": "Head",
        "l_shoulder": "UpperArm_L",
        "r_shoulder": "UpperArm_R",
        "l_elbow": "LowerArm_L",
        "r_elbow": "LowerArm_R",
        "l_wrist": "Hand_L",
        "r_wrist": "Hand_R",
        "l_hip": "UpperLeg_L",
        "r_hip": "UpperLeg_R",
        "l_knee": "LowerLeg_L",
        "r_knee": "LowerLeg_R",
        "l_ankle": "Foot_L",
        "r_ankle": "Foot_R",
        "l_toe": "Toes_L",
        "r_toe": "Toes_R",
    },
    "cmu": {
        "pelvis": "root",
        "spine": "upperback",
        "chest": "thorax",
        "neck": "lowerneck",
        "head": "head",
        "l_shoulder": "lhumerus",
        "r_shoulder": "rhumerus",
        "l_elbow": "lradius",
        "r_elbow": "rradius",
        "l_wrist": "lwrist",
        "r_wrist": "rwrist",
        "l_hip": "lfemur",
        "r_hip": "rfemur",
        "l_knee": "ltibia",
        "r_knee": "rtibia",
        "l_ankle": "lfoot",
        "r_ankle": "rfoot",
        "l_toe": "ltoes",
        "r_toe": "rtoes",
    },
    # The DeepMimic humanoid (motion/deepmimic.py): one trunk joint, the chest, so no
    # spine (the chest stands in); head and toes are end sites graphsvc adds.
    "deepmimic": {
        "pelvis": "root",
        "chest": "chest",
        "neck": "neck",
        "head": "head",
        "l_shoulder": "left_shoulder",
        "r_shoulder": "right_shoulder",
        "l_elbow": "left_elbow",
        "r_elbow": "right_elbow",
        "l_wrist": "left_wrist",
        "r_wrist": "right_wrist",
        "l_hip": "left_hip",
        "r_hip": "right_hip",
        "l_knee": "left_knee",
        "r_knee": "right_knee",
        "l_ankle": "left_ankle",
        "r_ankle": "right_ankle",
        "l_toe": "left_toe",
        "r_toe": "right_toe",
    },
}


def load_mapping_file(path) -> dict[str, str]:
    path = Path(path)
    data = read_json_file(path, "joint mapping")
    if not isinstance(data, dict) or not all(isinstance(v, str) for v in data.values()):
        raise FormatError(path, 'expected a JSON object {"canonical_name": "joint_name", ...}')
    unknown = sorted(set(data) - set(CANONICAL))
    if unknown:
        raise FormatError(path, f"unknown canonical joints: {', '.join(unknown)}")
    return data


# Canonical joints a skeleton may lack (another pipeline's BVH: no spine joint, no toes,
# no neck), each with the canonical joints that stand in for it, nearest first: a
# sensor, a marker or a contact test on a missing joint uses its stand-in's position;
# metrics compare only the joints both skeletons have.
OPTIONAL = {
    "spine": ("chest", "pelvis"),
    "chest": ("spine", "neck"),
    "neck": ("chest", "head"),
    "l_toe": ("l_ankle",),
    "r_toe": ("r_ankle",),
}


class JointTable(dict):
    """Canonical name → joint index (every canonical name; a joint the skeleton lacks
    maps to its stand-in, `OPTIONAL`). missing: the canonical joints the skeleton lacks;
    family: the map's name (a built-in family, "given" or "guessed")."""

    def __init__(self, table: dict, missing=(), family: str = ""):
        super().__init__(table)
        self.missing = frozenset(missing)
        self.family = family

    def present(self) -> list[str]:
        """The canonical joints the skeleton has, in CANONICAL's order."""
        return [c for c in CANONICAL if c not in self.missing]


def _complete(skeleton: Skeleton, table: dict[str, str], family: str, allow_missing: bool) -> JointTable | None:
    """The JointTable of a name map, or None when a joint it needs is not there (a
    required one, or any when `allow_missing` is False)."""
    names = set(skeleton.names)
    absent = [c for c in CANONICAL if table.get(c) not in names]
    if absent and (not allow_missing or any(c not in OPTIONAL for c in absent)):
        return None
    out = {c: skeleton.index(table[c]) for c in CANONICAL if c not in absent}
    for c in absent:
        stand_in = next((s for s in OPTIONAL[c] if s in out), None)
        if stand_in is None:
            return None
        out[c] = out[stand_in]
    return JointTable({c: out[c] for c in CANONICAL}, absent, family)


# A joint map as the functions take it: canonical → skeleton joint names, a map file, "guess", or None (built in).
JointMapping = dict[str, str] | str | Path | None


def joint_map(skeleton: Skeleton, mapping: JointMapping = None) -> JointTable:
    """Canonical name → joint index in `skeleton` (a `JointTable`). With no mapping, the
    first built-in map whose joints all exist is used. A mapping (a dict, a file, or
    "guess" for `guess_mapping`'s proposal) is completed from the built-in map that
    matches best; it may leave out the joints of `OPTIONAL` the skeleton lacks (they map
    to their stand-ins and are listed in `missing`), never the others."""
    names = set(skeleton.names)
    family = "given"
    if isinstance(mapping, str) and mapping == "guess":
        mapping, _ = guess_mapping(skeleton)
        family = "guessed"
    elif isinstance(mapping, (str, Path)):
        mapping = load_mapping_file(mapping)
    if mapping is None:
        for name, table in BUILTIN_MAPS.items():
            # (a built-in map that leaves out an optional joint says its skeleton lacks it)
            found = _complete(skeleton, table, name, allow_missing=not set(CANONICAL) <= set(table))
            if found is not None:
                return found
        guess, _ = guess_mapping(skeleton)
        raise SkeletonError(
            "unknown skeleton (not CMU, Bandai-Namco, DeepMimic or procedural): give a joint mapping file (--mapping FILE) or "
            f"--mapping guess (`graphsvc mapping CLIP` shows the guess: {_short(guess)}). "
            f"Skeleton joints: {', '.join(skeleton.names[:12])}..."
        )
    best = max(BUILTIN_MAPS.values(), key=lambda t: sum(v in names for v in t.values()))
    table = {**{k: v for k, v in best.items() if v in names}, **mapping}
    found = _complete(skeleton, table, family, allow_missing=True)
    if found is None:
        absent = [c for c in CANONICAL if table.get(c) not in names]
        required = [c for c in absent if c not in OPTIONAL]
        raise SkeletonError(
            "joint mapping leaves canonical joints unmapped or names joints the skeleton "
            f"lacks: {', '.join(required or absent)}"
            + (f" (only {', '.join(OPTIONAL)} may be left out)" if required else "")
        )
    return found


def _short(mapping: dict) -> str:
    return ", ".join(f"{c}={mapping[c]}" for c in CANONICAL if c in mapping) or "nothing found"


def canonical_indices(skeleton: Skeleton, mapping=None, names=None) -> np.ndarray:
    """Joint indices of the canonical joints `names` (default: all of CANONICAL; a
    missing one gives its stand-in) in `skeleton`'s order."""
    table = joint_map(skeleton, mapping)
    return np.array([table[c] for c in (CANONICAL if names is None else names)], dtype=np.int64)


def common_joints(*tables: JointTable) -> list[str]:
    """The canonical joints every table's skeleton has, in CANONICAL's order (what a
    metric may compare between two skeletons)."""
    missing = frozenset().union(*(t.missing for t in tables))
    return [c for c in CANONICAL if c not in missing]


# ---------------------------------------------------------------- guessing a map


# Per canonical joint (side stripped), name words that name it, most telling first.
_WORDS = {
    "pelvis": ("hips", "pelvis", "hip", "root"),
    "spine": ("spine", "spine1", "lowerback", "abdomen", "torso", "waist"),
    "chest": ("chest", "spine2", "upperchest", "thorax", "upperback", "chest2", "spine3"),
    "neck": ("neck", "neck1", "lowerneck"),
    "head": ("head",),
    "shoulder": ("upperarm", "arm", "humerus", "shoulder"),
    "elbow": ("forearm", "lowerarm", "elbow", "radius"),
    "wrist": ("wrist", "hand"),
    "hip": ("upleg", "upperleg", "thigh", "femur", "hip"),
    "knee": ("leg", "lowerleg", "knee", "shin", "calf", "tibia"),
    "ankle": ("foot", "ankle"),
    "toe": ("toebase", "toe", "toes", "ball"),
}
_ALL_WORDS = frozenset(w for words in _WORDS.values() for w in words)
_CENTRE = ("pelvis", "spine", "chest", "neck", "head")
_LIMB = ("shoulder", "elbow", "wrist", "hip", "knee", "ankle", "toe")


def _words(name: str) -> tuple[str, str]:
    """(side "l" | "r" | "", the name's body-part word): namespace prefixes dropped
    (`mixamorig:`), the side taken off either end, separators and case removed."""
    base = name.split(":")[-1].split("|")[-1]
    side = ""
    m = re.match(r"^(Left|Right|left|right|L|R)(?=[A-Z_.\- ]|$)", base) or re.match(r"^(l|r)(?=[_.\- ])", base)
    if m:
        side = m.group(1)[0].lower()
        base = base[m.end() :]
    else:
        m = re.search(r"(?<=[a-z0-9_.\- ])(Left|Right|left|right|L|R|l|r)$", base)
        if m and (m.group(1) in ("Left", "Right", "left", "right") or base[m.start() - 1] in "_.- "):
            side = m.group(1)[0].lower()
            base = base[: m.start()]
    base = re.sub(r"[^a-z0-9]", "", base.lower())
    if not side and base[:1] in ("l", "r") and base[1:] in _ALL_WORDS:  # CMU: lhumerus, rtibia
        side, base = base[0], base[1:]
    return side, base


def guess_mapping(skeleton: Skeleton) -> tuple[dict[str, str], list[str]]:
    """A proposed joint map for a skeleton graphsvc does not know, from its joint names
    (`LeftElbow`, `l_elbow`, `LeftForeArm`, `mixamorig:LeftForeArm`, `Elbow_L`, …):
    each canonical joint takes the first name word of `_WORDS` found on its side, and a
    limb's joints must descend from one another (shoulder → elbow → wrist, hip → knee →
    ankle → toe; a collar/clavicle above the shoulder is passed over). Returns (map,
    canonical joints not found)."""
    parsed = [_words(n) for n in skeleton.names]
    parents = skeleton.parents

    def ancestors(j):
        out = set()
        while parents[j] >= 0:
            j = int(parents[j])
            out.add(j)
        return out

    def find(words, side, below=None):
        for w in words:
            for j, (s, base) in enumerate(parsed):
                if s == side and base == w and not skeleton.end_site[j]:
                    if below is None or below in ancestors(j):
                        return j
        return None

    out: dict[str, str] = {}
    for c in _CENTRE:
        j = find(_WORDS[c], "")
        if j is not None and skeleton.names[j] not in out.values():
            out[c] = skeleton.names[j]
    for side in ("l", "r"):
        for chain in (("shoulder", "elbow", "wrist"), ("hip", "knee", "ankle", "toe")):
            above = None
            for part in chain:
                j = find(_WORDS[part], side, above)
                if j is None:
                    break
                out[f"{side}_{part}"] = skeleton.names[j]
                above = j
    # A trunk without a joint named like a spine (Hips → Chest → Chest2 → Neck): the
    # joints between the pelvis and the neck are the spine, lowest, and the chest, highest.
    index = {n: k for k, n in enumerate(skeleton.names)}
    if "pelvis" in out and "neck" in out and "spine" not in out:
        j, between = index[out["neck"]], []
        while parents[j] >= 0 and skeleton.names[int(parents[j])] != out["pelvis"]:
            j = int(parents[j])
            between.append(skeleton.names[j])
        if len(between) >= 2 and skeleton.names[int(parents[index[between[-1]]])] == out["pelvis"]:
            out["spine"], out["chest"] = between[-1], between[0]
    return out, [c for c in CANONICAL if c not in out]

"""The performer's proportions: named segment lengths, and a motion put on them.

A segment joins two canonical joints (`SEGMENTS`: the 18 edges of the canonical tree,
pelvis → spine → chest → neck → head, chest → shoulder → elbow → wrist, pelvis → hip →
knee → ankle → toe on each side); its length is the sum of the lengths of the bones
between them (one bone on most skeletons; a clavicle joint between chest and shoulder
makes two), which no joint's rotation changes. A canonical joint the skeleton lacks
(`joints.OPTIONAL`) stands in as its map says, so a skeleton without a spine joint
has a zero `upper_spine` and its `lower_spine` reaches the chest.

A performer's lengths come from one of:

- a skeleton (a BVH or ASF/AMC of the performer: `segment_lengths`, through the
  canonical joint map, or a mapping for a foreign skeleton);
- a JSON file `{"format": "graphsvc-performer", "version": 1, "segments_m": {name:
  metres}}` (`load_performer_file`): the segments it leaves out are the knowledge
  base's scaled by the mean ratio of the ones it gives (`complete_lengths`);
- a height in metres (`lengths_for_height`): the knowledge base's lengths scaled
  uniformly so that `skeleton_height` is that height.

Height (`skeleton_height`): the canonical chain from ankle to head — the mean of the
two legs' thigh + shin, plus lower_spine + upper_spine + chest + neck — divided by
`HEIGHT_FRACTION` = 0.80, the share of the stature that chain spans on the procedural
character (1.40 m of its 1.75 m: the ankle's 8 cm above the floor, the hip's 7 cm below
the pelvis and the 18 cm from the head joint to the crown are the rest). It is a
definition, not a measurement: a skeleton family that places its joints otherwise
(Bandai-Namco's head joint sits at the top of the neck) reads a few centimetres off.

`performer_skeleton` rescales a skeleton's bone offsets so its segments have the
given lengths (each bone between a segment's joints by that segment's ratio, any other
bone by the ratio of the segment that ends at its nearest canonical ancestor: a head
end site by the neck's, a hand by the forearm's; the bones above the pelvis by the
legs'). `on_performer` puts a motion on such a skeleton: the same local rotations,
and translation channels scaled by the ratio of the legs (`leg_length`: pelvis → hip
→ knee → ankle), so the feet stay on the floor and the stride scales with the legs.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from graphsvc.errors import FormatError, InputError, SkeletonError
from graphsvc.fileio import read_json_file
from graphsvc.motion.joints import joint_map
from graphsvc.motion.skeleton import POSITION_CHANNELS, Motion, Skeleton

FORMAT = "graphsvc-performer"
VERSION = 1

# name → (proximal, distal) canonical joints
SEGMENTS = {
    "lower_spine": ("pelvis", "spine"),
    "upper_spine": ("spine", "chest"),
    "chest": ("chest", "neck"),
    "neck": ("neck", "head"),
    "l_clavicle": ("chest", "l_shoulder"),
    "l_upper_arm": ("l_shoulder", "l_elbow"),
    "l_forearm": ("l_elbow", "l_wrist"),
    "r_clavicle": ("chest", "r_shoulder"),
    "r_upper_arm": ("r_shoulder", "r_elbow"),
    "r_forearm": ("r_elbow", "r_wrist"),
    "l_pelvis": ("pelvis", "l_hip"),
    "l_thigh": ("l_hip", "l_knee"),
    "l_shin": ("l_knee", "l_ankle"),
    "l_foot": ("l_ankle", "l_toe"),
    "r_pelvis": ("pelvis", "r_hip"),
    "r_thigh": ("r_hip", "r_knee"),
    "r_shin": ("r_knee", "r_ankle"),
    "r_foot": ("r_ankle", "r_toe"),
}

HEIGHT_FRACTION = 0.80
TRUNK = ("lower_spine", "upper_spine", "chest", "neck")
MAX_HEIGHT_M = 3.0  # (a height above this is a unit mistake: centimetres given as metres)


def rest_positions(skeleton: Skeleton) -> np.ndarray:
    """(J, 3) each joint's position with every rotation the identity: its offsets summed
    from the root's (parents precede children)."""
    pos = np.zeros((skeleton.num_joints, 3))
    pos[0] = skeleton.offsets[0]
    for j in range(1, skeleton.num_joints):
        pos[j] = pos[skeleton.parents[j]] + skeleton.offsets[j]
    return pos


def segment_lengths(skeleton: Skeleton, mapping=None) -> dict[str, float]:
    """{segment: metres} of every segment of `SEGMENTS` on `skeleton` (its canonical joint
    map, or `mapping` as `joints.joint_map` takes it), in SEGMENTS' order."""
    table = joint_map(skeleton, mapping)
    bones = skeleton.bone_lengths()
    pos = rest_positions(skeleton)
    out = {}
    for name, path in _segment_paths(skeleton, table).items():
        a, b = SEGMENTS[name]
        # (a mapping may name a distal joint that does not descend from the proximal one:
        # their distance with every rotation the identity)
        out[name] = (
            float(bones[path].sum()) if path is not None else float(np.linalg.norm(pos[table[b]] - pos[table[a]]))
        )
    return out


def skeleton_height(lengths: dict) -> float:
    """The stature in metres that segment lengths stand for (module docstring): (mean
    of the legs' thigh + shin + the trunk's four segments) / HEIGHT_FRACTION."""
    legs = 0.5 * (lengths["l_thigh"] + lengths["l_shin"] + lengths["r_thigh"] + lengths["r_shin"])
    return (legs + sum(lengths[s] for s in TRUNK)) / HEIGHT_FRACTION


def leg_length(lengths: dict) -> float:
    """The mean of the two legs' pelvis → hip → knee → ankle, in metres: what a standing
    pelvis's height scales with."""
    return 0.5 * sum(lengths[f"{s}_pelvis"] + lengths[f"{s}_thigh"] + lengths[f"{s}_shin"] for s in "lr")


def _ratio(new: float, old: float) -> float:
    """new / old, 1 for an old length of 0 (nothing to scale)."""
    return new / old if old > 0.0 else 1.0


def check_height(height: float) -> float:
    """A performer's height in metres as a float; InputError unless finite, > 0 and at
    most MAX_HEIGHT_M."""
    try:
        h = float(height)
    except (TypeError, ValueError):
        raise InputError(f"height must be a number of metres, got {height!r}") from None
    if not (math.isfinite(h) and 0.0 < h <= MAX_HEIGHT_M):
        raise InputError(f"height must be a finite number of metres > 0 and at most {MAX_HEIGHT_M:g}, got {height!r}")
    return h


def lengths_for_height(kb_lengths: dict, height: float) -> dict[str, float]:
    """The knowledge base's segment lengths scaled uniformly to a performer `height`
    metres tall (`skeleton_height`). InputError for a height that is not a positive
    number of metres (`check_height`)."""
    h = check_height(height)
    kb_height = skeleton_height(kb_lengths)
    if not kb_height > 0.0:
        raise InputError("the knowledge base's skeleton has no height (its legs and trunk have no length)")
    return {name: v * (h / kb_height) for name, v in kb_lengths.items()}


def _length_ok(v) -> bool:
    """A segment length: a number of metres, finite, ≥ 0 and at most MAX_HEIGHT_M (no
    segment is longer than a body is tall: more is a unit mistake)."""
    return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v) and 0.0 <= v <= MAX_HEIGHT_M


def complete_lengths(kb_lengths: dict, given: dict, where: str = "segment lengths") -> dict[str, float]:
    """Every segment of `kb_lengths` (the knowledge base's): those `given` as given, the
    others the knowledge base's times the mean ratio given / knowledge base of the given
    segments the knowledge base has (a zero one it lacks, `segment_lengths`). InputError
    naming `where` for an unknown segment, a length that is not a number of metres in
    [0, MAX_HEIGHT_M], or nothing given."""
    unknown = sorted(set(given) - set(SEGMENTS))
    if unknown:
        raise InputError(f"{where}: unknown segments: {', '.join(unknown)} (known: {', '.join(SEGMENTS)})")
    values = {}
    for name, v in given.items():
        if not _length_ok(v):
            raise InputError(
                f"{where}: segment {name} must be a number of metres ≥ 0 and at most {MAX_HEIGHT_M:g}, got {v!r}"
            )
        values[name] = float(v)
    ratios = [values[n] / kb_lengths[n] for n in values if kb_lengths.get(n, 0.0) > 0.0]
    if not ratios:
        raise InputError(f"{where}: no segment given that the knowledge base's skeleton has")
    k = float(np.mean(ratios))
    return {name: values.get(name, v * k) for name, v in kb_lengths.items()}


def load_performer_file(path) -> dict[str, float]:
    """The `segments_m` of a performer JSON file (module docstring), checked: FormatError
    naming the file for a document of another format or version, unknown segment names
    (listed) or lengths that are not numbers of metres in [0, MAX_HEIGHT_M];
    MissingFileError when absent."""
    data = read_json_file(path, "performer")
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise FormatError(path, f'expected a JSON object with "format": "{FORMAT}"')
    if data.get("version") != VERSION:
        raise FormatError(path, f"unsupported version {data.get('version')!r} (this graphsvc reads {VERSION})")
    segments = data.get("segments_m")
    if not isinstance(segments, dict) or not segments:
        raise FormatError(path, '"segments_m" must be a non-empty object {segment: metres}')
    extra = sorted(set(data) - {"format", "version", "segments_m", "name", "height_m"})
    if extra:
        raise FormatError(path, f"unknown keys: {', '.join(extra)}")
    unknown = sorted(set(segments) - set(SEGMENTS))
    if unknown:
        raise FormatError(path, f"unknown segments: {', '.join(unknown)} (known: {', '.join(SEGMENTS)})")
    for name, v in segments.items():
        if not _length_ok(v):
            raise FormatError(
                path, f"segment {name} must be a number of metres ≥ 0 and at most {MAX_HEIGHT_M:g}, got {v!r}"
            )
    return {name: float(v) for name, v in segments.items()}


def performer_segments(performer, mapping=None) -> dict[str, float]:
    """The segments a performer file gives: a .json performer file's `segments_m`
    (`load_performer_file`), or every segment of a .bvh/.amc motion's skeleton
    (`segment_lengths`, through its joint map or `mapping`); SkeletonError naming the
    file and --performer-mapping for a skeleton without one."""
    path = Path(performer)
    if path.suffix.lower() == ".json":
        return load_performer_file(path)
    from graphsvc.motion.library import load_motion

    skeleton = load_motion(path).skeleton
    try:
        return segment_lengths(skeleton, mapping)
    except SkeletonError as exc:  # (its joint map is the performer's flag's)
        raise SkeletonError(f"performer {path}: " + str(exc).replace("--mapping", "--performer-mapping")) from None


def performer_lengths(
    kb_skeleton: Skeleton, performer=None, height=None, mapping=None, kb_mapping=None
) -> dict[str, float]:
    """Every segment's length in metres for a performer given as a file (`performer`: a
    .json performer file, or a .bvh/.amc motion whose skeleton is measured through its
    joint map or `mapping`) or as a `height` in metres, on the knowledge base's skeleton
    `kb_skeleton` (its joint map, or `kb_mapping`). InputError for both or neither given
    or a bad height; FormatError / MissingFileError for a bad or absent file."""
    if (performer is None) == (height is None):
        raise InputError("give the performer as a file or as a height, one of the two")
    kb = segment_lengths(kb_skeleton, kb_mapping)
    if height is not None:
        return lengths_for_height(kb, height)
    return complete_lengths(kb, performer_segments(performer, mapping), str(performer))


def _segment_paths(skeleton: Skeleton, table) -> dict[str, list[int] | None]:
    """{segment: the joints whose bone (parent → joint) lies between its two joints, or
    None when its distal joint does not descend from its proximal one}."""
    paths = {}
    for name, (a, b) in SEGMENTS.items():
        ja, j, path = table[a], table[b], []
        while j != ja and j >= 0:
            path.append(j)
            j = int(skeleton.parents[j])
        paths[name] = path if j == ja else None
    return paths


def performer_skeleton(kb_skeleton: Skeleton, lengths: dict, mapping=None) -> Skeleton:
    """`kb_skeleton` with its bone offsets rescaled so its segments have `lengths` (a
    segment left out: scaled by the mean ratio of those given, `complete_lengths`);
    bones off every segment by the ratio of the segment that ends at their nearest
    canonical ancestor, those above the pelvis by the legs' (`leg_length`). mapping:
    the skeleton's joint map when it has no built-in one. InputError for an unknown
    segment or a bad length."""
    table = joint_map(kb_skeleton, mapping)
    kb = segment_lengths(kb_skeleton, mapping)
    want = complete_lengths(kb, dict(lengths))
    ratio = {n: (want[n] / kb[n] if kb[n] > 0.0 else 1.0) for n in SEGMENTS}
    legs = _ratio(leg_length(want), leg_length(kb))
    factor = np.full(kb_skeleton.num_joints, np.nan)
    for name, path in _segment_paths(kb_skeleton, table).items():
        if path:
            factor[path] = ratio[name]
    ends = {table[b]: n for n, (a, b) in SEGMENTS.items() if table[b] != table[a]}
    for j in range(kb_skeleton.num_joints):
        if np.isnan(factor[j]):
            p = int(kb_skeleton.parents[j])
            while p >= 0 and p not in ends and p != table["pelvis"]:
                p = int(kb_skeleton.parents[p])
            factor[j] = ratio[ends[p]] if p in ends else legs
    return Skeleton(
        kb_skeleton.names,
        kb_skeleton.parents,
        kb_skeleton.offsets * factor[:, None],
        kb_skeleton.channels,
        kb_skeleton.end_site,
    )


def on_performer(motion: Motion, skeleton: Skeleton, mapping=None) -> Motion:
    """`motion` on `skeleton` (one topology with the motion's, other bone lengths: a
    `performer_skeleton`): the same local rotations; the bones of joints without
    translation channels the skeleton's offsets, translation channels scaled by the
    ratio of the legs (`leg_length`, through the joint map or `mapping`). InputError
    when the topologies differ."""
    if not motion.skeleton.same_topology(skeleton):
        raise InputError("the performer's skeleton is not the motion's (other joints or channels)")
    k = _ratio(leg_length(segment_lengths(skeleton, mapping)), leg_length(segment_lengths(motion.skeleton, mapping)))
    moving = np.array([any(c in POSITION_CHANNELS for c in ch) for ch in skeleton.channels])
    translations = np.where(moving[None, :, None], motion.translations * k, skeleton.offsets[None])
    return motion.copy(skeleton=skeleton, translations=translations)

"""Data augmentation: left/right mirror images and time reversal of clips.

Mirroring happens in world space: the mirrored pose puts every joint where its
left/right partner was, reflected by W = diag(-1, 1, 1) (x → -x; Y up, ground XZ).
Any vertical mirror plane gives the same motion up to a heading rotation and a
ground translation, so x = 0 is as good as the character's own sagittal plane.

Local joint frames are arbitrary (the Bandai BVH rest pose lies along +X, its
hip frame has the legs at ∓Y while its chest frame has the shoulders at ±Z, and
its right-side limb frames are the left ones negated), so each joint j gets its
own reflection M[j]: the map from j's local frame to its partner's local frame,
fitted to the rest offsets of j's children. With it

    world rotation'[j] = W · R[partner j] · M[j]       (det = +1: a rotation)
    world position'[j] = W · P[partner j]

and in local terms, with p = parent(j) and M[parent of root] = W,

    local rotation'[j]    = M[p]ᵀ · local[partner j] · M[j]
    local translation'[j] = M[p]ᵀ · translation[partner j].

The M[j] are diagonal sign matrices, so the mirror only flips signs and
reorders quaternion components: mirroring twice returns the original exactly
(up to quaternion sign).
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

from graphsvc.errors import SkeletonError
from graphsvc.motion import quat
from graphsvc.motion.skeleton import Motion, Skeleton

WORLD_MIRROR = np.diag([-1.0, 1.0, 1.0])  # x → -x

# Reflections (det = -1) a joint frame may need, in order of preference when
# several fit a joint's children equally well. -I first: rigs built by
# "behaviour" mirroring (Bandai limbs) negate all axes of the right-side frames,
# which makes equal local rotations on both sides mirror images of each other.
_CANDIDATES = (
    np.diag([-1.0, -1.0, -1.0]),
    np.diag([-1.0, 1.0, 1.0]),
    np.diag([1.0, -1.0, 1.0]),
    np.diag([1.0, 1.0, -1.0]),
)
_W_INDEX = 1

FIT_TOLERANCE = 0.25  # max |M·o − o_partner| / |o| for a frame reflection to count as fitting
_TIE = 1e-3  # residuals this close (relative) are equally good fits
_MIN_OFFSET_M = 1e-6  # child offsets shorter than this (end sites at the joint) constrain nothing

_SUFFIXES = (("_L", "_R"), (".L", ".R"), ("_l", "_r"), (".l", ".r"))
_WORDS = (("Left", "Right"), ("left", "right"), ("LEFT", "RIGHT"))
_PREFIXES = (("l_", "r_"), ("L_", "R_"))
_END = "_End"


def _swap(name: str, names: set[str]) -> tuple[str, bool]:
    """The partner name by convention and whether the name carries an explicit
    side marker (a marked name whose partner is missing is an error, an unmarked
    one is a midline joint)."""
    if name.endswith(_END) and len(name) > len(_END):
        base, marked = _swap(name[: -len(_END)], names)
        return base + _END, marked
    for a, b in _SUFFIXES:
        for x, y in ((a, b), (b, a)):
            if name.endswith(x) and len(name) > len(x):
                return name[: -len(x)] + y, True
    for a, b in _WORDS:
        for x, y in ((a, b), (b, a)):
            if x in name:
                return name.replace(x, y, 1), True
    for a, b in _PREFIXES:
        for x, y in ((a, b), (b, a)):
            if name.startswith(x) and len(name) > len(x):
                return y + name[len(x) :], True
    # CMU style (lfemur/rfemur): a bare l/r prefix is a side marker only when the
    # other side exists, so "root" or "lowerback" stay midline joints.
    if len(name) > 1 and name[0] in "lr":
        other = ("r" if name[0] == "l" else "l") + name[1:]
        if other in names:
            return other, True
    return name, False


def mirror_pairs(names: Sequence[str], parents: np.ndarray | None = None) -> np.ndarray:
    """(J,) int index of each joint's left/right partner (itself on the midline),
    from naming conventions: suffixes _L/_R and .L/.R (either case), Left/Right
    anywhere, prefixes l_/r_, CMU l/r prefixes (lfemur/rfemur) when both exist;
    "<joint>_End" end sites follow their joint.

    With `parents` (J,) the pairing must also respect the hierarchy: the root is
    its own partner and a partner's parent is the parent's partner. Raises
    SkeletonError for a side-marked joint without partner or an inconsistent
    pairing."""
    names = tuple(names)
    index = {n: i for i, n in enumerate(names)}
    present = set(names)
    pairs = np.arange(len(names), dtype=np.int64)
    for i, n in enumerate(names):
        other, marked = _swap(n, present)
        if other == n:
            continue
        if other not in index:
            if marked:
                raise SkeletonError(f"joint {n!r} has no mirror partner {other!r}")
            continue
        pairs[i] = index[other]
    bad = np.nonzero(pairs[pairs] != np.arange(len(names)))[0]
    if bad.size:
        j = int(bad[0])
        raise SkeletonError(
            f"mirror pairing is not symmetric: {names[j]!r} → {names[pairs[j]]!r} → {names[pairs[pairs[j]]]!r}"
        )
    if parents is not None:
        parents = np.asarray(parents, dtype=np.int64)
        if parents.shape != pairs.shape:
            raise SkeletonError(f"parents must have one entry per joint ({len(names)}), got {parents.shape}")
        roots = parents < 0
        if np.any(pairs[roots] != np.nonzero(roots)[0]):
            raise SkeletonError("the root joint cannot have a mirror partner")
        expect = np.where(roots, -1, pairs[np.maximum(parents, 0)])
        bad = np.nonzero(parents[pairs] != expect)[0]
        if bad.size:
            j = int(bad[0])
            raise SkeletonError(
                f"mirror partners {names[j]!r} and {names[pairs[j]]!r} hang from "
                f"{names[parents[j]]!r} and {names[parents[pairs[j]]]!r}, which are not partners"
            )
    return pairs


def mirror_frames(skeleton: Skeleton, pairs: np.ndarray | None = None) -> np.ndarray:
    """(J, 3, 3) reflections M[j] (det -1) from joint j's local frame to its
    partner's, chosen so that M[j]·offset[c] ≈ offset[partner c] for j's children c.

    Candidates are -I, diag(-1,1,1), diag(1,-1,1) and diag(1,1,-1); a joint keeps
    those that fit its children best. A bone along one axis leaves two fitting,
    a joint whose children sit at the joint (end sites) leaves all four; such
    ties go, in order, to the convention the joint's subtree settles (Bandai's
    spine frame follows its chest, not its hips), to the parent's reflection (W
    for the root), then to the candidate order. Raises SkeletonError when no
    candidate fits a joint within FIT_TOLERANCE."""
    if pairs is None:
        pairs = mirror_pairs(skeleton.names, skeleton.parents)
    J = skeleton.num_joints
    offsets, parents = skeleton.offsets, skeleton.parents
    children = [np.nonzero(parents == j)[0] for j in range(J)]
    K = len(_CANDIDATES)

    fits = np.ones((J, K), dtype=bool)  # candidates that fit joint j equally best
    for j in range(J):
        src, dst = offsets[children[j]], offsets[pairs[children[j]]]
        scale = np.maximum(np.linalg.norm(src, axis=-1), np.linalg.norm(dst, axis=-1))
        keep = scale > _MIN_OFFSET_M
        if not keep.any():
            continue
        src, dst, scale = src[keep], dst[keep], scale[keep]
        resid = np.array([np.max(np.linalg.norm(src @ m.T - dst, axis=-1) / scale) for m in _CANDIDATES])
        best = resid.min()
        if best > FIT_TOLERANCE:
            raise SkeletonError(
                f"no axis reflection maps the children of {skeleton.names[j]!r} onto those of "
                f"{skeleton.names[pairs[j]]!r} (best relative misfit {best:.2f}); the skeleton's "
                "rest pose is not left/right symmetric in its local frames"
            )
        fits[j] = resid <= best + _TIE

    below = np.full(J, -1)  # candidate settled by the subtree, -1 while open
    for j in range(J - 1, -1, -1):
        if fits[j].sum() == 1:
            below[j] = int(np.argmax(fits[j]))
        else:
            settled = [below[c] for c in children[j] if below[c] >= 0 and fits[j, below[c]]]
            below[j] = settled[0] if settled else -1

    choice = np.full(J, -1)
    for j in range(J):
        if choice[j] >= 0:
            continue  # set with its partner
        inherited = _W_INDEX if parents[j] < 0 else choice[parents[j]]
        if below[j] >= 0:
            k = below[j]
        elif fits[j, inherited]:
            k = inherited
        else:
            k = int(np.argmax(fits[j]))
        # M[partner] = M[j]⁻¹ = M[j] (diagonal) makes mirroring an involution.
        choice[j] = choice[pairs[j]] = k
    return np.stack(_CANDIDATES)[choice]


def _proper_quat(reflections: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) of the rotations -M for reflections M (..., 3, 3):
    M = -(−M), and the two minus signs cancel in Mᵀ·L·M'."""
    # -M is a diagonal rotation (identity or a half turn about an axis), whose
    # quaternion has components in {0, ±1}: round scipy's output so a double
    # mirror reproduces the input exactly.
    return np.round(quat.from_matrix(-reflections))


def mirror_motion(motion: Motion) -> Motion:
    """The left/right mirror image of `motion`: world positions become
    W·P[partner] with W = diag(-1, 1, 1), world rotations W·R[partner]·M[j]
    (see mirror_frames). Returns a Motion named "<name>_mirror" with the same
    source and its labels mirrored too ("walk-turn-left" → "walk-turn-right").

    The skeleton is kept when it is symmetric (mirrored offsets within 1e-9 m);
    otherwise (CMU subjects' left and right bones differ by millimetres) the
    mirror gets a skeleton of the same topology with the partners' bone offsets,
    so its translations still equal its offsets where there are no position
    channels."""
    sk = motion.skeleton
    pairs = mirror_pairs(sk.names, sk.parents)
    frames = mirror_frames(sk, pairs)
    parent_frames = np.where(
        (sk.parents < 0)[:, None, None], WORLD_MIRROR, frames[np.maximum(sk.parents, 0)]
    )  # (J, 3, 3)

    # local'[j] = M[p]ᵀ·L[σj]·M[j] = (−M[p])ᵀ·L[σj]·(−M[j]): a product of rotations.
    qp = _proper_quat(parent_frames)
    qj = _proper_quat(frames)
    rotations = quat.mul(quat.mul(quat.conjugate(qp), motion.rotations[:, pairs]), qj)
    translations = np.einsum("jki,fjk->fji", parent_frames, motion.translations[:, pairs])

    offsets = np.einsum("jki,jk->ji", parent_frames, sk.offsets[pairs])
    if np.allclose(offsets, sk.offsets, rtol=0.0, atol=1e-9):
        skeleton = sk
    else:
        skeleton = Skeleton(sk.names, sk.parents, offsets, sk.channels, sk.end_site)
    return motion.copy(
        skeleton=skeleton,
        rotations=rotations,
        translations=translations,
        name=motion.name + "_mirror",
        labels=tuple(mirror_label(label) for label in motion.labels),
    )


_SIDE_WORDS = {"left": "right", "right": "left", "Left": "Right", "Right": "Left", "LEFT": "RIGHT", "RIGHT": "LEFT"}


def mirror_label(label: str) -> str:
    """Swap the words left and right in a label: a mirrored left-hand wave is a
    right-hand wave. Other text is unchanged."""
    return re.sub(r"(?<![A-Za-z])(left|right|Left|Right|LEFT|RIGHT)(?![a-z])", lambda m: _SIDE_WORDS[m.group(1)], label)


def reverse_motion(motion: Motion) -> Motion:
    """The clip played backwards, named "<name>_reverse" (same labels and source)."""
    return motion.copy(
        rotations=motion.rotations[::-1].copy(),
        translations=motion.translations[::-1].copy(),
        name=motion.name + "_reverse",
    )

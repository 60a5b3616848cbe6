"""Motion of one skeleton put on another of other joints: one knowledge base from
several capture sources.

Two skeleton families (CMU's ASF, Bandai-Namco's BVH, graphsvc's procedural one) differ
in their joints (CMU has clavicles, lower back, hands, fingers and thumbs; Bandai-Namco
a root joint on the floor and zero-length end sites), their bone lengths and the rest
directions of their bones (CMU's rest pose is a T-pose, Bandai-Namco's points every
bone along its joint's x axis). Local rotations therefore mean nothing from one to the
other. What both share are the canonical joints (`joints.CANONICAL`) and, per frame,
where each canonical bone points in the world. `retarget` carries those over, joint by
joint down the target's hierarchy, in world terms:

- a canonical joint with a canonical child (`joints.CANONICAL_CHILD`; the next one the
  target has where it lacks that child): the rotation that makes the target's bone
  point where the source's points (exactly), turned about that bone by the source's
  twist. The twist is measured against each skeleton's reference pose (`reference_pose`:
  the mean local rotation of each joint over the clips of that skeleton): the source
  joint's world rotation compared with the shortest swing of its reference rotation
  onto the bone's direction, and the same turn applied to the target's shortest swing
  of its own reference rotation. Both reference rotations are taken under the joint's
  nearest canonical ancestor as placed, the joints between at their reference
  rotations (as the target's are), so the two swings start from corresponding poses;
- the pelvis and the chest: their canonical child's direction exactly, the twist about
  it from the across-body direction (right → left hip, right → left shoulder), which
  fixes the facing without any reference;
- a canonical joint without a canonical child (head, wrists, toes): the source's
  world rotation change from its reference pose, applied to the target's;
- every other joint of the target (a root joint on the floor, clavicles, lower back,
  hands, fingers): its reference local rotation.

Bone lengths are the target's; the pelvis's world position is the source's scaled by
the ratio of the legs (`proportions.leg_length`: height and stride scale with the
legs, as `proportions.on_performer` puts a motion on a performer), realised at the
target's carrier joint (`placement.joint_tables`); then the whole clip is moved
vertically so its feet rest at the target's resting foot heights (the 5th percentile of
ankle and toe heights over a clip, as `signals.foot_contacts` measures them; the
target's is the mean over its reference clips).

What a retargeted clip loses: the joints the target lacks (CMU's fingers, thumbs and
hand joints on a Bandai-Namco skeleton; its clavicles, lower back and upper neck keep
the target's reference rotations, so a shrug or a bend of the lower back alone shows
only through where the canonical joints go), the twist of the target's joints off the
canonical chains, and, where the two reference poses differ, part of the twist about
each canonical bone (a forearm's pronation, a thigh's rotation). Canonical joint
directions are kept exactly; positions up to the target's bone lengths.

Written here rather than taken from a library: what it needs is the project's own
canonical joint map and flat arrays; the numpy below is the whole method.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from graphsvc.errors import MissingFileError, SkeletonError
from graphsvc.motion import quat
from graphsvc.motion.joints import CANONICAL_CHILD, JointTable, joint_map
from graphsvc.motion.kinematics import forward_kinematics, motion_fk
from graphsvc.motion.library import load_motion
from graphsvc.motion.placement import joint_tables
from graphsvc.motion.proportions import leg_length, segment_lengths
from graphsvc.motion.skeleton import Motion, Skeleton

# Joints whose twist comes from the across-body direction: (left, right) canonical joints.
ACROSS = {"pelvis": ("l_hip", "r_hip"), "chest": ("l_shoulder", "r_shoulder")}
FOOT_PERCENTILE = 5.0  # (signals.foot_contacts' resting height)


@dataclass(frozen=True)
class Side:
    """One skeleton as retargeting sees it: its joint table, the joint map given for it
    (None for a built-in family), its reference local rotations (J, 4) and its resting
    ankle and toe heights (2,) in metres."""

    skeleton: Skeleton
    table: JointTable
    mapping: dict | None
    reference: np.ndarray
    foot_rest: np.ndarray


def skeleton_table(skeleton: Skeleton, mapping=None) -> tuple[JointTable, dict | None]:
    """The canonical joint table of `skeleton`: a built-in family's when one fits, else
    through `mapping` (a dict, a file or "guess"); (table, the mapping used or None)."""
    try:
        return joint_map(skeleton), None
    except SkeletonError:
        if mapping is None:
            raise
    return joint_map(skeleton, mapping), mapping


def topology_key(skeleton: Skeleton) -> tuple:
    """What clips of one skeleton family share (joint names and hierarchy)."""
    return skeleton.names, tuple(int(p) for p in skeleton.parents)


def reference_pose(motions: list[Motion]) -> np.ndarray:
    """(J, 4) each joint's mean local rotation over every frame of `motions` (one
    topology): quaternions put in the hemisphere of the first frame's, summed and
    normalised (the rotation nearest the frames' mean for spreads under a half turn)."""
    pivot = motions[0].rotations[0]
    total = np.zeros_like(pivot)
    for m in motions:
        sign = np.where(np.sum(m.rotations * pivot, axis=-1, keepdims=True) < 0.0, -1.0, 1.0)
        total += np.sum(m.rotations * sign, axis=0)
    norm = np.linalg.norm(total, axis=-1, keepdims=True)
    return np.where(norm > 1e-12, total / np.maximum(norm, 1e-12), quat.IDENTITY)


def _feet(table: JointTable) -> tuple[list[int], list[int]]:
    return [table["l_ankle"], table["r_ankle"]], [table["l_toe"], table["r_toe"]]


def rest_heights(world_pos: np.ndarray, table: JointTable) -> np.ndarray:
    """(2,) a clip's resting ankle and toe heights: the 5th percentile over its frames
    and both feet of each (`signals.foot_contacts`)."""
    ankles, toes = _feet(table)
    return np.array(
        [np.percentile(world_pos[:, ankles, 1], FOOT_PERCENTILE), np.percentile(world_pos[:, toes, 1], FOOT_PERCENTILE)]
    )


def make_side(skeleton: Skeleton, motions: list[Motion], mapping=None) -> Side:
    """A skeleton with the clips of its family that define its reference pose and
    resting foot heights (`motions`, one topology with it; at least one)."""
    if not motions:
        raise SkeletonError("a skeleton to retarget with needs at least one clip of it for its reference pose")
    table, used = skeleton_table(skeleton, mapping)
    feet = np.mean([rest_heights(motion_fk(m)[1], table) for m in motions], axis=0)
    return Side(skeleton, table, used, reference_pose(motions), feet)


def _children_table(table: JointTable) -> dict[int, tuple[str, str]]:
    """Joint index → (its canonical name, the canonical child its bone points to: the
    next one the skeleton has), for the canonical joints the skeleton has."""
    out = {}
    for c in table.present():
        child = CANONICAL_CHILD.get(c)
        while child is not None and child in table.missing:
            child = CANONICAL_CHILD.get(child)
        out[table[c]] = (c, child)
    return out


def local_vector(skeleton: Skeleton, reference: np.ndarray, top: int, joint: int) -> np.ndarray:
    """(3,) where `joint` sits in `top`'s frame with every joint between them at its
    reference rotation (`joint` descends from `top`)."""
    path = []
    j = joint
    while j != top:
        if j < 0:
            raise SkeletonError(f"{skeleton.names[joint]} does not descend from {skeleton.names[top]}")
        path.append(j)
        j = int(skeleton.parents[j])
    q, v = quat.IDENTITY, np.zeros(3)
    for m in reversed(path):
        v = v + quat.rotate(q, skeleton.offsets[m])
        q = quat.mul(q, reference[m])
    return v


def _unit(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """v normalised along its last axis; `fallback` where v has no length."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 1e-9, v / np.maximum(n, 1e-9), fallback)


def _twist(q: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The twist of q (F, 4) about unit axes (F, 3) (its swing-twist decomposition),
    the identity where q is a half turn about an axis across them."""
    w = q[:, :1]
    along = np.sum(q[:, 1:] * axis, axis=-1, keepdims=True) * axis
    t = np.concatenate([w, along], axis=-1)
    return _unit(t, quat.IDENTITY)


def _frame_rotation(u_local: np.ndarray, w_local: np.ndarray, u: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(F, 4) the rotations taking u_local onto u (F, 3) exactly and w_local as near
    w (F, 3) as the first allows: the orthonormal frame of (u, w) times the transpose
    of that of (u_local, w_local)."""

    def frame(a, b):
        e1 = _unit(a, np.array([0.0, 1.0, 0.0]))
        e2 = _unit(b - np.sum(b * e1, axis=-1, keepdims=True) * e1, np.array([1.0, 0.0, 0.0]))
        return np.stack([e1, e2, np.cross(e1, e2)], axis=-1)

    F = u.shape[0]
    local = frame(np.broadcast_to(u_local, (F, 3)), np.broadcast_to(w_local, (F, 3)))
    return quat.from_matrix(frame(u, w) @ np.swapaxes(local, -1, -2))


def _continuous(q: np.ndarray) -> np.ndarray:
    """(F, J, 4) quaternions with signs chosen so each joint's never jump between frames."""
    flip = np.ones(q.shape[:2] + (1,))
    flip[1:, :, 0] = np.where(np.sum(q[1:] * q[:-1], axis=-1) < 0.0, -1.0, 1.0)
    return q * np.cumprod(flip, axis=0)


def _world_rotations(
    motion: Motion, source: Side, target: Side, src_rot: np.ndarray, src_pos: np.ndarray
) -> np.ndarray:
    """(F, J_target, 4) the target's world rotations, joint by joint (module docstring)."""
    tsk, ssk = target.skeleton, source.skeleton
    F = motion.num_frames
    canon = _children_table(target.table)
    src = source.table
    world = np.empty((F, tsk.num_joints, 4))

    def src_point(c):
        return src_pos[:, src[c]]

    present = {src[c] for c in src.present()}

    def src_guess_of(js):
        # The source joint's reference rotation under its nearest canonical ancestor,
        # the joints between at their reference rotations, as the target's are.
        q, a = source.reference[js], int(ssk.parents[js])
        while a >= 0 and a not in present:
            q = quat.mul(source.reference[a], q)
            a = int(ssk.parents[a])
        return quat.mul(src_rot[:, a], q) if a >= 0 else np.broadcast_to(q, (F, 4))

    for j in range(tsk.num_joints):
        p = int(tsk.parents[j])
        parent = world[:, p] if p >= 0 else quat.identity((F,))
        guess = quat.mul(parent, target.reference[j])  # the reference rotation under the actual parent
        if j not in canon:
            world[:, j] = guess
            continue
        c, child = canon[j]
        js = src[c]
        src_guess = src_guess_of(js)
        if child is None or c in source.table.missing:
            # no bone direction: the source's change from its reference, in the world
            world[:, j] = quat.mul(quat.mul(src_rot[:, js], quat.conjugate(src_guess)), guess)
            continue
        v_t = local_vector(tsk, target.reference, j, target.table[child])
        a_t = quat.rotate(guess, np.broadcast_to(v_t, (F, 3)))
        d = _unit(src_point(child) - src_point(c), _unit(a_t, np.array([0.0, 1.0, 0.0])))
        if c in ACROSS:
            left, right = ACROSS[c]
            across_t = local_vector(tsk, target.reference, j, target.table[left]) - local_vector(
                tsk, target.reference, j, target.table[right]
            )
            world[:, j] = _frame_rotation(v_t, across_t, d, src_point(left) - src_point(right))
            continue
        swing = quat.mul(quat.between(a_t, d), guess)
        # The source's twist about the bone: its rotation against its own shortest swing.
        v_s = local_vector(ssk, source.reference, js, src[child]) if child not in source.table.missing else None
        if v_s is None or np.linalg.norm(v_s) < 1e-9:
            world[:, j] = swing
            continue
        a_s = quat.rotate(src_guess, np.broadcast_to(v_s, (F, 3)))
        src_swing = quat.mul(quat.between(a_s, d), src_guess)
        turn = _twist(quat.mul(src_rot[:, js], quat.conjugate(src_swing)), d)
        world[:, j] = quat.normalize(quat.mul(turn, swing))
    return world


def retarget(motion: Motion, source: Side, target: Side) -> Motion:
    """`motion` (on `source`'s skeleton, one topology) put on `target`'s skeleton
    (module docstring): canonical bone directions the source's, bone lengths the
    target's, the pelvis path scaled by the legs' ratio, the feet at the target's
    resting heights. Name, source file and labels are kept; `retargeted_from` names
    the source skeleton's family."""
    tsk = target.skeleton
    F, J = motion.num_frames, tsk.num_joints
    src_rot, src_pos = motion_fk(motion)
    world = _world_rotations(motion, source, target, src_rot, src_pos)
    local = world.copy()
    has_parent = tsk.parents >= 0
    local[:, has_parent] = quat.mul(quat.conjugate(world[:, tsk.parents[has_parent]]), world[:, has_parent])
    local = _continuous(quat.normalize(local))

    k = leg_length(segment_lengths(tsk, target.mapping)) / leg_length(segment_lengths(source.skeleton, source.mapping))
    pelvis = target.table["pelvis"]
    want = src_pos[:, source.table["pelvis"]] * k
    translations = np.broadcast_to(tsk.offsets, (F, J, 3)).copy()
    _, carrier = joint_tables(tsk, target.table)
    _, pos = forward_kinematics(local, translations, tsk.parents)
    # Move the carrier by what puts the pelvis where it is wanted, in its parent's frame.
    shift = want - pos[:, pelvis]
    _, pos = forward_kinematics(local, _moved(translations, world, tsk, carrier, shift), tsk.parents)
    lift = float(np.mean(target.foot_rest - rest_heights(pos, target.table)))
    translations = _moved(translations, world, tsk, carrier, shift + np.array([0.0, lift, 0.0]))
    return Motion(
        tsk,
        local,
        translations,
        motion.rate_hz,
        name=motion.name,
        source=motion.source,
        labels=motion.labels,
        retargeted_from=source.table.family or "given",
    )


def _moved(
    translations: np.ndarray, world: np.ndarray, skeleton: Skeleton, carrier: int, shift: np.ndarray
) -> np.ndarray:
    """translations with the carrier joint moved by `shift` (F, 3) in the world."""
    out = translations.copy()
    p = int(skeleton.parents[carrier])
    out[:, carrier] += shift if p < 0 else quat.inv_rotate(world[:, p], shift)
    return out


def pool_skeletons(
    motions: list[Motion],
    skeleton: Motion | None = None,
    mapping=None,
    first: int = 0,
    clip_map=None,
    progress: bool | None = None,
) -> list[Motion]:
    """Every clip on one skeleton: `skeleton`'s (a motion whose skeleton is the target;
    its frames join its family's clips in the reference pose), else that of the
    family of clip `first`, its bone offsets averaged over the family's clips. Clips
    of the target's family are returned as they are, the others retargeted (`retarget`),
    in the same order. A knowledge base of one family without `skeleton` is returned
    unchanged. SkeletonError for a skeleton without canonical joints. clip_map: where
    the clips are retargeted (`graph.build.ClipMap`: threads, Dask tasks; default here,
    one after another)."""
    if not motions:
        return motions
    families: dict[tuple, list[Motion]] = {}
    for m in motions:
        families.setdefault(topology_key(m.skeleton), []).append(m)
    if skeleton is None and len(families) == 1:
        return motions
    if skeleton is not None:
        key = topology_key(skeleton.skeleton)
        target_sk, refs = skeleton.skeleton, [skeleton] + families.get(key, [])
    else:
        key = topology_key(motions[first].skeleton)
        refs = families[key]
        base = refs[0].skeleton
        offsets = np.mean([m.skeleton.offsets for m in refs], axis=0)
        target_sk = Skeleton(base.names, base.parents, offsets, base.channels, base.end_site)
    target = make_side(target_sk, refs, mapping)
    sides = {k: make_side(ms[0].skeleton, ms, mapping) for k, ms in families.items() if k != key}
    todo = [i for i, m in enumerate(motions) if topology_key(m.skeleton) != key]
    run = clip_map or (lambda fn, items, **_: [fn(x) for x in items])
    done = run(
        partial(_retarget_from, sides=sides, target=target),
        [motions[i] for i in todo],
        desc="retargeting",
        progress=progress,
    )
    out = list(motions)
    for i, m in zip(todo, done):
        out[i] = m
    return out


def _retarget_from(motion: Motion, sides: dict, target: Side) -> Motion:
    """`retarget` of one clip from its family's side (`sides`, by `topology_key`), with
    the clip's own bone lengths."""
    base = sides[topology_key(motion.skeleton)]
    return retarget(motion, Side(motion.skeleton, base.table, base.mapping, base.reference, base.foot_rest), target)


def load_target_skeleton(path, mapping=None) -> Motion:
    """The motion file (.bvh or .amc) whose skeleton a knowledge base is put on
    (`pool_skeletons`' `skeleton`). MissingFileError when absent; SkeletonError naming
    the file when no canonical joint map fits its skeleton."""
    if not Path(path).is_file():
        raise MissingFileError(path, "target skeleton")
    motion = load_motion(path)
    try:
        skeleton_table(motion.skeleton, mapping)
    except SkeletonError as exc:
        raise SkeletonError(f"{path}: no canonical joints to retarget onto: {exc}") from None
    return motion

"""Mixed-action performances: held-out clips of different actions joined end to end.

A match is not one action, so accuracy is also measured on performances that change
action (`graphsvc evaluate --mixed N`, `tools/join_clips.py`). A performance is made
by joining clips as they are: each clip's ground track is shifted so that it starts
where the previous one ended, while its heading and pose stay as recorded. The seams
therefore jump in pose and heading, which is part of the test: the search has to leave
one action for the next within a few samples. Truth labels are per frame, each clip's
content label.

Grouping (`mixed_groups`): a performance is one performer, so clips are grouped by
skeleton (equal bone offsets; in Bandai's data an actor has one set), shuffled by the
seed, and dealt into performances of N clips with N different labels; clips left
over (fewer than N distinct labels remain) are not used.
"""

from __future__ import annotations

import numpy as np

from graphsvc.errors import InputError
from graphsvc.graph.metadata import rotate_ground
from graphsvc.motion import quat, signals
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.resample import resample
from graphsvc.motion.skeleton import Motion


def _label(motion: Motion) -> str:
    return motion.labels[0] if motion.labels else motion.name


def join_clips(
    motions: list[Motion], rate_hz: float, mapping=None, name: str | None = None, turn: bool = False
) -> tuple[Motion, np.ndarray]:
    """One performance of the clips in order, at `rate_hz` (module docstring).

    turn: also turn each clip about its first ground position so that it starts
    facing where the previous one ended (the seams then jump in pose only); off by
    default, the protocol of the module docstring. Returns the joined Motion (on the
    first clip's skeleton; every clip keeps its own bone lengths, which the per-frame
    translations carry) and its (F,) per-frame content labels. Clips must share one
    skeleton topology."""
    if not motions:
        raise InputError("no clips to join")
    first = motions[0]
    rot, trans, labels = [], [], []
    end, end_heading = None, 0.0
    for m in motions:
        if not m.skeleton.same_topology(first.skeleton):
            raise InputError(
                f"{m.name}: its skeleton differs from {first.name}'s; a performance has one skeleton topology"
            )
        m = resample(m, rate_hz)
        table = joint_map(m.skeleton, mapping)
        pos = motion_fk(m)[1]
        ground, heading = signals.ground_position(pos, table["pelvis"]), signals.heading(pos, table)
        r = m.rotations
        t = m.translations.copy()
        if turn and end is not None:
            # R_y(d) about the clip's first ground position, applied at the root joint.
            d = float(end_heading - heading[0])
            r = r.copy()
            r[:, 0] = quat.mul(quat.about_y(np.full(r.shape[0], d)), r[:, 0])
            angle, about = np.full(r.shape[0], d), np.broadcast_to(ground[0], ground.shape)
            t[:, 0, [0, 2]] = rotate_ground(t[:, 0, [0, 2]] - about, angle, about)
            ground = rotate_ground(ground - about, angle, about)
            heading = heading + d
        shift = np.zeros(2) if end is None else end - ground[0]
        t[:, 0, 0] += shift[0]  # the root joint's translation moves the whole figure
        t[:, 0, 2] += shift[1]
        end, end_heading = ground[-1] + shift, heading[-1]
        rot.append(r)
        trans.append(t)
        labels += [_label(m)] * m.num_frames
    joined = Motion(
        first.skeleton,
        np.concatenate(rot),
        np.concatenate(trans),
        rate_hz,
        name=name or "+".join(m.name for m in motions),
        source="joined clips",
        labels=("mixed",),
    )
    return joined, np.array(labels, dtype=object)


def mixed_groups(motions: list[Motion], n: int, seed: int = 0) -> list[list[int]]:
    """Indices into `motions` of performances of `n` clips with `n` different labels,
    each of one skeleton (module docstring). Deterministic by seed."""
    if n < 2:
        raise InputError(f"--mixed needs at least 2 clips a performance, got {n}")
    by_performer: dict = {}
    for k, m in enumerate(motions):
        by_performer.setdefault(np.round(m.skeleton.offsets, 6).tobytes(), []).append(k)
    rng = np.random.default_rng(seed)
    groups = []
    for key in sorted(by_performer):
        pool = [by_performer[key][i] for i in rng.permutation(len(by_performer[key]))]
        while True:
            group, used = [], set()
            for k in pool:
                if _label(motions[k]) not in used:
                    group.append(k)
                    used.add(_label(motions[k]))
                    if len(group) == n:
                        break
            if len(group) < n:
                break
            groups.append(group)
            pool = [k for k in pool if k not in group]
    return groups


def mixed_items(
    tests: list[Motion], indices: list, n: int, rate_hz: float, mapping=None, seed: int = 0, turn: bool = False
) -> list[tuple]:
    """`loo.run_leave_one_out` items of the joined performances of `tests` (`mixed_groups`):
    (joined motion named mixed_NN, the graph clip indices to hide, per-frame labels).
    indices: per test clip its graph clip index, a list of graph clips it hides
    (`protocols.hide_lists`), or None."""
    items = []
    for g, group in enumerate(mixed_groups(tests, n, seed)):
        motion, labels = join_clips([tests[k] for k in group], rate_hz, mapping, name=f"mixed_{g + 1:02d}", turn=turn)
        motion.source = " + ".join(tests[k].name for k in group)
        hide = sorted({int(i) for k in group if indices[k] is not None for i in np.atleast_1d(indices[k])})
        items.append((motion, hide, labels))
    return items

"""Measured sensor orientations imposed on a pose: each segment that carries a sensor
turned so that the sensor's orientation relative to the root sensor's heading is the
measured one.

The orientation cue relative to the root (`sensors.orientation.relative_orientations`)
gives each sensor's rotation H⁻¹·R_s in the root sensor's heading frame. On an output
pose whose root sensor has heading H_out (the twist about world +Y of its orientation),
sensor s's measured world orientation is T_s = H_out·(H⁻¹·R_s). Segments are visited
parent first; each gets, in the world, the rotation that puts its sensor at T_s:

- a sensor rigid on its segment (`Placement.carrier` −1: trunk, head, shins): the
  segment's world rotation T_s·P_s⁻¹, P_s the sensor's rotation in the segment frame;
- a forearm sensor, whose frame's X follows the forearm while its Y is carried by the
  upper arm (`sensors.anatomy`): only the forearm's direction, the shortest rotation
  that turns the sensor's current X onto T_s's X, so the pose's own twist is kept;

and its joint's local rotation becomes the parent's world rotation⁻¹ times it: the
segment and everything below it turn, its parent stays. The root sensor's row is its
tilt alone, so the root keeps the pose's heading. Joint positions follow from the
rotations (the offsets are the skeleton's), so only rotations change.
"""

from __future__ import annotations

import numpy as np

from graphsvc.graph.derived import derived
from graphsvc.graph.metadata import clip_placements
from graphsvc.motion import quat
from graphsvc.sensors.layout import layout_from_dict, root_sensor
from graphsvc.sensors.orientation import RELATIVE_WIDTH, heading_twist


def clip_sensor_placements(graph) -> dict:
    """The graph layout's placement on each of its clips (`graph.metadata.clip_placements`:
    the anatomical frames estimated per clip), as rotation (C, S, 4), segment (S,),
    carrier (S,) and the root sensor's index; made once per graph in a process."""

    def make() -> dict:
        layout = layout_from_dict(graph.layout)
        every = clip_placements(graph, layout)
        return {
            "rotation": np.stack([p.rotation for p in every]),
            "segment": every[0].segment,
            "carrier": every[0].carrier,
            "root": root_sensor(layout),
        }

    return derived(graph, "sensor_orientations.placements", make)


def imposes(graph) -> bool:
    """Whether measured orientations can be imposed on the graph's poses: its orientation
    cue is relative to a root sensor."""
    return graph.edge_up is not None and graph.edge_up.shape[-1] == RELATIVE_WIDTH


def impose_at_nodes(graph, local: np.ndarray, cue: np.ndarray, nodes) -> np.ndarray:
    """`impose_sensor_orientations` on K poses (K, J, 4) played from graph nodes (K,), each
    on its node's clip's placement; cue (K, S, 9), NaN rows where not measured."""
    cue = np.asarray(cue, dtype=np.float64)
    present = np.all(np.isfinite(cue), axis=-1)
    table = clip_sensor_placements(graph)
    clip = np.asarray(graph.node_clip, dtype=np.int64)[np.asarray(nodes, dtype=np.int64)]
    return impose_sensor_orientations(
        local,
        graph.skeleton.parents,
        np.where(present[..., None], cue, 0.0),
        table["rotation"][clip],
        table["segment"],
        table["carrier"],
        table["root"],
        present,
    )


def world_rotations(local: np.ndarray, parents) -> np.ndarray:
    """(K, J, 4) world rotations of local joint rotations (K, J, 4), parents first."""
    world = np.empty_like(local)
    for j, p in enumerate(parents):
        world[:, j] = local[:, j] if p < 0 else quat.mul(world[:, p], local[:, j])
    return world


def cue_rotations(cue: np.ndarray) -> np.ndarray:
    """(..., S, 4) quaternions of a relative cue (..., S, 9) (matrices ÷ √2; the nearest
    rotation where noise or resampling bent them). Rows that are not finite give NaN."""
    m = np.asarray(cue, dtype=np.float64).reshape(cue.shape[:-1] + (3, 3)) * np.sqrt(2.0)
    ok = np.all(np.isfinite(m), axis=(-1, -2))
    out = np.full(cue.shape[:-1] + (4,), np.nan)
    if ok.any():
        u, _, vt = np.linalg.svd(m[ok])
        r = u @ vt
        r[np.linalg.det(r) < 0] *= -1.0  # (a reflection only from a degenerate row)
        out[ok] = quat.from_matrix(r)
    return out


def impose_sensor_orientations(
    local: np.ndarray,
    parents,
    cue: np.ndarray,
    rotation: np.ndarray,
    segment: np.ndarray,
    carrier: np.ndarray,
    root: int,
    present: np.ndarray,
) -> np.ndarray:
    """Local rotations (K, J, 4) with each present sensor's measured orientation imposed
    (module docstring). cue (K, S, 9): the measured cue relative to the root sensor;
    rotation (K, S, 4): each sensor's rotation in its segment's frame on each frame's
    placement; segment (S,), carrier (S,): the placement's; present (K, S) bool: the
    sensors whose cue is measured (a frame without the root's imposes nothing)."""
    if cue.shape[-1] != RELATIVE_WIDTH:
        raise ValueError("measured orientations are imposed from the cue relative to a root sensor")
    out = np.array(local, dtype=np.float64, copy=True)
    K = out.shape[0]
    if K == 0:
        return out
    parents = np.asarray(parents)
    world = world_rotations(out, parents)
    use = present & present[:, root : root + 1]
    heading = heading_twist(quat.mul(world[:, segment[root]], rotation[:, root]))  # H_out
    target = quat.mul(heading[:, None], cue_rotations(cue))  # T_s (K, S, 4)
    depth = np.array([_depth(parents, int(j)) for j in segment])
    x = np.array([1.0, 0.0, 0.0])
    for s in np.argsort(depth, kind="stable"):
        rows = np.flatnonzero(use[:, s])
        if rows.size == 0:
            continue
        j = int(segment[s])
        now = world[rows, j]
        if carrier[s] < 0:
            want = quat.mul(target[rows, s], quat.conjugate(rotation[rows, s]))
        else:
            current = quat.rotate(quat.mul(now, rotation[rows, s]), x)
            wanted = quat.rotate(target[rows, s], x)
            want = quat.mul(quat.between(current, wanted), now)
        p = int(parents[j])
        out[rows, j] = quat.normalize(want if p < 0 else quat.mul(quat.conjugate(world[rows, p]), want))
        world = world_rotations(out, parents)
    return out


def _depth(parents, j: int) -> int:
    d = 0
    while parents[j] >= 0:
        j = int(parents[j])
        d += 1
    return d

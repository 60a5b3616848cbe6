"""The pose-oracle floor: per truth frame, the knowledge-base pose closest to it.

A strategy that outputs the graph's poses (retrieval: `nearest`, the search) can do no
better on joint error than picking, every frame, the node whose pose is closest to the
truth's; that choice needs the truth, so no strategy can make it, and its error is the
floor any retrieval faces. The distance is `metrics.joint_err_cm`'s: both frames in
their own ground position and heading (the metric aligns a prediction that way), the
mean Euclidean distance over the joints both skeletons have. Only the nodes a
hold-out leaves usable count.

The search: a k-d tree (scipy's `cKDTree`) over the nodes' stacked local positions
gives each truth frame its `CANDIDATES` nearest under the stacked (root-sum-square)
distance, and the mean per-joint distance picks the best of them; the two distances
rank poses nearly alike, so the figure is the floor within a hair (a slightly high one
where they disagree).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from graphsvc.graph.model import MotionGraph
from graphsvc.graph.poses import node_rotations, node_translations
from graphsvc.motion import signals
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import forward_kinematics

CANDIDATES = 16
CHUNK = 32768


def local_positions(pos: np.ndarray, ground: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """(T, P, 3) joint positions in each frame's own ground point and heading: (x, z)
    less the ground position, turned by −heading (`metrics` convention), y kept."""
    c, s = np.cos(-heading)[:, None], np.sin(-heading)[:, None]
    x = pos[..., 0] - ground[:, 0:1]
    z = pos[..., 2] - ground[:, 1:2]
    out = np.empty(pos.shape, dtype=np.float64)
    out[..., 0] = c * x + s * z
    out[..., 1] = pos[..., 1]
    out[..., 2] = -s * x + c * z
    return out


def node_local_positions(graph: MotionGraph, names: list[str]) -> np.ndarray:
    """(N, P, 3) float32: every node's joints `names` (canonical names) in its own
    ground point and heading."""
    table = joint_map(graph.skeleton, graph.params.get("mapping"))
    picked = [table[n] for n in names]
    out = np.empty((graph.num_nodes, len(names), 3), np.float32)
    for lo in range(0, graph.num_nodes, CHUNK):
        n = np.arange(lo, min(lo + CHUNK, graph.num_nodes))
        _, world = forward_kinematics(
            node_rotations(graph, n),
            node_translations(graph, n),
            graph.skeleton.parents,
        )
        ground = signals.ground_position(world, table["pelvis"])
        out[lo : lo + n.size] = local_positions(world[:, picked], ground, signals.heading(world, table))
    return out


def pose_oracle(nodes_local: np.ndarray, allowed: np.ndarray, truth_local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per truth frame (T,) the least joint error (cm) over the allowed nodes and the
    node that has it. nodes_local (N, P, 3) (`node_local_positions`), allowed (N,) bool,
    truth_local (T, P, 3) (`local_positions` of the truth's same joints)."""
    usable = np.flatnonzero(np.asarray(allowed, dtype=bool))
    N, P = usable.size, nodes_local.shape[1]
    flat = np.ascontiguousarray(nodes_local[usable].reshape(N, P * 3), dtype=np.float64)
    k = min(CANDIDATES, N)
    _, near = cKDTree(flat).query(truth_local.reshape(len(truth_local), P * 3), k=k)
    near = near.reshape(len(truth_local), k)
    err = np.linalg.norm(flat[near].reshape(len(truth_local), k, P, 3) - truth_local[:, None], axis=-1).mean(axis=-1)
    best = np.argmin(err, axis=1)
    rows = np.arange(len(truth_local))
    return 100.0 * err[rows, best], usable[near[rows, best]]

"""The benchmarks' generated graph: clips as chains of original edges plus random
transitions, at any size (the largest of Kelly et al. 2013, G_E, is 100,686 nodes and 317,600 edges)."""

from __future__ import annotations

import numpy as np


def generated_graph(nodes: int, edges: int, sensors: int = 6, clip_frames: int = 300, seed: int = 0):
    """Clips as chains of original edges plus random transitions. As in a built graph,
    an edge reads what its destination reads in its own clip (so edges into one node
    share a reading), except a fifth of the non-original edges, which stand for
    speed variations and read something of their own."""
    from graphsvc.graph.model import graph_from_edges

    rng = np.random.default_rng(seed)
    idx = np.arange(nodes)
    chain = idx[(idx + 1) % clip_frames != 0][:-1]  # original edges inside clips
    src = [chain]
    dst = [chain + 1]
    extra = edges - len(chain)
    src.append(rng.integers(0, nodes, extra))
    dst.append(rng.integers(0, nodes, extra))
    src, dst = np.concatenate(src), np.concatenate(dst)
    pairs = np.unique(np.stack([src, dst], 1), axis=0)
    while len(pairs) < edges:  # top up duplicates removed by unique
        more = rng.integers(0, nodes, (edges - len(pairs), 2))
        pairs = np.unique(np.concatenate([pairs, more]), axis=0)
    E = len(pairs)
    contacts = rng.random((nodes, 2)) < 0.7
    node_reading = rng.normal(0, 9.81, (nodes, sensors, 3)).astype(np.float32)
    acc = node_reading[pairs[:, 1]]
    own = (pairs[:, 1] != pairs[:, 0] + 1) & (rng.random(E) < 0.2)
    acc[own] = rng.normal(0, 9.81, (int(own.sum()), sensors, 3))
    return graph_from_edges(
        pairs[:, 0],
        pairs[:, 1],
        acc,
        offsets=rng.normal(0, 0.05, (E, 2)),
        dheading=rng.normal(0, 0.03, E),
        contacts=contacts,
        labels=rng.integers(0, 2, nodes),
    )

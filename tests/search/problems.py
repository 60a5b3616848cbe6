"""Small random search problems shared by the search tests."""

import numpy as np

from graphsvc.graph.model import graph_from_edges


def tiny_graph(src, dst, acc, offsets=None, dheading=None, contacts=None, labels=None, kinds=None):
    """A MotionGraph with N nodes and the given edges (sorted by destination here)."""
    return graph_from_edges(src, dst, acc, offsets, dheading, contacts, labels, kinds)


def path_cost(g, nodes, meas):
    total = 0.0
    for t in range(1, len(nodes)):
        e = np.nonzero((g.edge_src == nodes[t - 1]) & (g.edge_dst == nodes[t]))[0]
        if not len(e):
            return None
        total += np.mean(np.sum((g.edge_acc[e[0]].astype(float) / 9.81 - meas[t] / 9.81) ** 2, axis=-1))
    return total


def random_graph(rng, N=40, out=3, S=2):
    src = np.repeat(np.arange(N), out)
    dst = rng.integers(0, N, len(src))
    pairs = np.unique(np.stack([src, dst], 1), axis=0)
    E = len(pairs)
    return tiny_graph(
        pairs[:, 0],
        pairs[:, 1],
        rng.normal(0, 9.81, (E, S, 3)),
        offsets=rng.normal(0, 0.05, (E, 2)),
        dheading=rng.normal(0, 0.05, E),
        contacts=rng.random((N, 2)) < 0.6,
        labels=rng.integers(0, 2, N),
    )


def random_up(rng, shape):
    """Random unit vectors (…, 3)."""
    u = rng.normal(size=shape)
    return u / np.linalg.norm(u, axis=-1, keepdims=True)


def random_walk_problem(seed, T=70):
    """random_graph and T samples for it: random readings (T, 2, 3) m/s², a random-walk
    ground track (T, 2) m and heading (T,) rad."""
    rng = np.random.default_rng(seed)
    g = random_graph(rng)
    meas = rng.normal(0, 9.81, (T, 2, 3))
    position = np.cumsum(rng.normal(0, 0.05, (T, 2)), axis=0)
    heading = np.cumsum(rng.normal(0, 0.05, T))
    return g, meas, position, heading


def shared_reading_graph(rng, N=1200, out=3, S=2):
    """A graph shaped like a built one: edges mostly read their destination's own
    reading (a node's shared edges), a fifth of the rest a reading of their own; big
    enough (N / SELECT_CHUNKS ≫ 8) that pass 1 runs its eight-wide loops."""
    src = np.repeat(np.arange(N), out)
    dst = rng.integers(0, N, len(src))
    pairs = np.unique(np.stack([src, dst], 1), axis=0)
    E = len(pairs)
    node_reading = rng.normal(0, 9.81, (N, S, 3))
    acc = node_reading[pairs[:, 1]]
    own = rng.random(E) < 0.2
    acc[own] = rng.normal(0, 9.81, (int(own.sum()), S, 3))
    return tiny_graph(
        pairs[:, 0],
        pairs[:, 1],
        acc,
        offsets=rng.normal(0, 0.05, (E, 2)),
        dheading=rng.normal(0, 0.03, E),
        kinds=(rng.random(E) < 0.3).astype(np.uint8),
    )

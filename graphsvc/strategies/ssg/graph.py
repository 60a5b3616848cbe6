"""The subsequence graph (Tautges 2012, §4.3.4): layers of retrieved subsequences, one a
window of the input, edges between consecutive layers, the cheapest path.

A layer covers input frames [start, stop); consecutive layers overlap. Its nodes are
subsequences of the knowledge base laid along those frames — `frames` (K, stop − start)
fractional knowledge-base frames (index positions) and the rigid transform (θ about +Y,
then a ground translation) that places each one on the input:

- retrieved (`RETRIEVED`): found by the subsequence DTW for this window; cost: its DTW
  cost per input frame (m²). Each is the anchor of its own chain.
- extended forward (`FORWARD`) or backward (`BACKWARD`): in a window with too few
  markers seen to search (a gap at least half a window long), the subsequences of the
  layer before the gap continued forward, and those of the layer after it continued
  backward, each at its own warping factor (knowledge-base frames an input frame) and
  with its own transform (§4.3.5, *Gaps*); a chain ends where its run of frames ends
  (the pose holds). Cost: the fixed-transform distance to whatever markers the window
  does have (m² an input frame).

Edges: a node continues its own chain at no cost (the same subsequence); a forward
chain can only be continued, a backward one only entered from a retrieved or forward
node and continued to its anchor. Every other pair (a retrieved or forward node into a
retrieved or backward one) is a transition, whose cost is eq. 4.4: the mean squared
distance (m²) between the two subsequences' canonical joints over the frames the two
windows share, each placed by its own transform. A path's cost is the sum of its
nodes' costs and `weight` times its transitions'. The graph is a chain of small layers:
the cheapest path is a forward pass keeping each node's best predecessor, a layer's
edges at once — the shortest path in a DAG, written here rather than taken from
networkx: on a minute of input (360 windows of 16 nodes) it takes 2 ms against
networkx's 210 ms to build the same graph and search it (the same path; tested), and a
live decoder runs it again at every window.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

RETRIEVED, FORWARD, BACKWARD = 0, 1, 2


@dataclass
class Anchor:
    """A retrieved subsequence, the root of a chain: its layer, its window's frames
    (fractional index positions), its transform, its warping factor and its run."""

    layer: int
    start: int
    stop: int
    frames: np.ndarray
    theta: float
    tx: float
    tz: float
    warp: float
    run_first: int
    run_last: int

    def frames_at(self, n: np.ndarray) -> np.ndarray:
        """The chain's knowledge-base frame at input frames n: the anchor's own inside its
        window, else continued at its warping factor, held at its run's ends."""
        n = np.asarray(n, dtype=np.int64)
        out = np.empty(n.shape)
        inside = (n >= self.start) & (n < self.stop)
        out[inside] = self.frames[n[inside] - self.start]
        after = n >= self.stop
        out[after] = self.frames[-1] + self.warp * (n[after] - (self.stop - 1))
        before = n < self.start
        out[before] = self.frames[0] - self.warp * (self.start - n[before])
        return np.clip(out, self.run_first, self.run_last)


@dataclass
class Layer:
    """One window's nodes: kind (K,) int8, anchor (K,) int (index into the graph's
    anchors), cost (K,) m² an input frame. blind: too few markers seen to search it."""

    start: int
    stop: int
    blind: bool
    kind: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    anchor: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    cost: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def size(self) -> int:
        return int(self.kind.size)

    def add(self, kind: int, anchors, costs) -> None:
        anchors = np.asarray(anchors, dtype=np.int64).reshape(-1)
        self.kind = np.concatenate([self.kind, np.full(anchors.size, kind, np.int8)])
        self.anchor = np.concatenate([self.anchor, anchors])
        self.cost = np.concatenate([self.cost, np.asarray(costs, dtype=np.float64).reshape(-1)])

    def frames(self, anchors: list[Anchor]) -> np.ndarray:
        """(K, stop − start) each node's knowledge-base frames over the layer."""
        n = np.arange(self.start, self.stop)
        return np.stack([anchors[a].frames_at(n) for a in self.anchor]) if self.size else np.zeros((0, n.size))


def placed(joints: np.ndarray, theta: np.ndarray, tx: np.ndarray, tz: np.ndarray) -> np.ndarray:
    """Points (K, ..., 3) in their clips' worlds → placed on the input: R_y(θ) then
    (tx, 0, tz), per leading index."""
    c = np.cos(theta).reshape((-1,) + (1,) * (joints.ndim - 2))
    s = np.sin(theta).reshape(c.shape)
    out = np.empty_like(joints)
    out[..., 0] = c * joints[..., 0] + s * joints[..., 2] + np.reshape(tx, c.shape)
    out[..., 1] = joints[..., 1]
    out[..., 2] = -s * joints[..., 0] + c * joints[..., 2] + np.reshape(tz, c.shape)
    return out


def edge_costs(prev: Layer, nxt: Layer, anchors: list[Anchor], joints_at) -> np.ndarray:
    """(K_prev, K_next) edge costs (module docstring; inf: no edge). joints_at(frames) →
    (..., 19, 3) canonical joints at fractional index frames."""
    out = np.full((prev.size, nxt.size), np.inf)
    if not prev.size or not nxt.size:
        return out
    same = prev.anchor[:, None] == nxt.anchor[None, :]
    out[same] = 0.0  # (the same subsequence going on)
    # Transitions: from a retrieved or forward node into a retrieved or backward one.
    transition = (prev.kind[:, None] != BACKWARD) & (nxt.kind[None, :] != FORWARD) & ~same
    if transition.any() and nxt.start < prev.stop:
        n = np.arange(nxt.start, prev.stop)
        a = _placed_joints(prev, n, anchors, joints_at)  # (Kp, L, 19, 3)
        b = _placed_joints(nxt, n, anchors, joints_at)  # (Kn, L, 19, 3)
        # Mean squared distance over frames and joints, every pair at once.
        aa = (a * a).sum(axis=(1, 2, 3))
        bb = (b * b).sum(axis=(1, 2, 3))
        ab = a.reshape(prev.size, -1) @ b.reshape(nxt.size, -1).T
        d = np.maximum(aa[:, None] + bb[None, :] - 2.0 * ab, 0.0) / (n.size * a.shape[2])
        out[transition] = d[transition]
    elif transition.any():
        out[transition] = 0.0  # windows that only touch: nothing to compare
    return out


def _placed_joints(layer: Layer, n: np.ndarray, anchors: list[Anchor], joints_at) -> np.ndarray:
    frames = np.stack([anchors[a].frames_at(n) for a in layer.anchor])  # (K, L)
    th = np.array([anchors[a].theta for a in layer.anchor])
    tx = np.array([anchors[a].tx for a in layer.anchor])
    tz = np.array([anchors[a].tz for a in layer.anchor])
    return placed(joints_at(frames), th, tx, tz)


def weighted(edges: np.ndarray, weight: float) -> np.ndarray:
    """weight × edge costs, a missing edge (inf) staying missing whatever the weight (0 ×
    inf would be NaN)."""
    return np.where(np.isinf(edges), np.inf, weight * np.where(np.isinf(edges), 0.0, edges))


def cheapest_path(
    layers: list[Layer], edges: list[np.ndarray], weight: float, first: int = 0, entry: np.ndarray | None = None
) -> tuple[np.ndarray, float]:
    """The cheapest path through layers[first:] (one node index a layer) and its cost.
    edges[a]: layer a → a + 1 costs; entry: (K_first,) cost of entering each node of
    layer `first` (a committed predecessor's edges; None: from the source, free)."""
    dp = layers[first].cost + (0.0 if entry is None else weighted(entry, weight))
    back = []
    for a in range(first, len(layers) - 1):
        total = dp[:, None] + weighted(edges[a], weight)
        best = np.argmin(total, axis=0)
        back.append(best)
        dp = layers[a + 1].cost + total[best, np.arange(total.shape[1])]
    end = int(np.argmin(dp))
    cost = float(dp[end])
    path = [end]
    for best in reversed(back):
        path.append(int(best[path[-1]]))
    return np.array(path[::-1], dtype=np.int64), cost

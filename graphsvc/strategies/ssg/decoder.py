"""The SSG decoder: input frames in, windows retrieved, the subsequence graph grown and
its path committed — one object for batch and live alike.

Windows of N frames start every N − o frames from the first (Tautges 2012, §4.3.2);
a window is searched once its last frame is in, and the few after it that its last
local costs' point clouds reach (`ahead`), so every local cost sees the same frames
whether the input arrives frame by frame or at once. At the end of the input one more
window reaches its last frame, starting where it overlaps only the window before.
A window with markers seen in at most half its frames is *blind*: a gap at least N/2
long (shorter gaps are ignored, §4.3.5) — it is not searched, its nodes are the
neighbouring windows' subsequences extended through it (`graph`). With no lag the
cheapest path is found once all input is in; with a lag of L windows, each window is
committed (its node taken from the cheapest path to the newest window) once L more
windows are in, and its frames are final then — so a live stream and a batch run with
the same lag agree frame for frame. A live decoder cannot see past a gap: chains are
extended backward only into windows not yet committed, and windows before the first
searchable one wait for it.

Memory: a live decoder (`prune`) holds constant memory however long its stream. Once
a window is committed nothing reads its layer again but the few windows after it (the
cross-fade of `sources`, the entry edges of the next commit, the forward costs the
next window's continuations start from), so all but the last KEEP_COMMITTED committed
layers are dropped — their nodes, edges, forward costs and the anchors no kept layer
refers to (a chain extended through a long gap keeps its anchor) — and the input
frames before the oldest kept layer with them. Each list keeps absolute indices
(`Tail`); the frames the decoder outputs are the same, pruned or not.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass

import numpy as np

from graphsvc.strategies.ssg import dtw
from graphsvc.strategies.ssg.graph import (
    BACKWARD,
    FORWARD,
    RETRIEVED,
    Anchor,
    Layer,
    cheapest_path,
    edge_costs,
    placed,
    weighted,
)
from graphsvc.strategies.ssg.index import SsgIndex, WindowPoints

COST_BLOCK = 64  # input frames whose local costs one matrix product computes (when they are in)
KEEP_COMMITTED = 4  # committed layers a pruning decoder keeps (module docstring)
PRUNE_EVERY = 16  # layers dropped at a time (each pruning walks the kept layers' anchors)


class Tail:
    """A list whose oldest items can be dropped (`drop_before`) while every index stays
    absolute: `len` counts the dropped ones, and reading one is an IndexError."""

    def __init__(self, items=()):
        self.base = 0  # the index of items[0]
        self.items = list(items)

    def __len__(self) -> int:
        return self.base + len(self.items)

    def _at(self, i: int) -> int:
        if i < 0:
            return len(self.items) + i
        if i < self.base:
            raise IndexError(f"item {i} was dropped (kept from {self.base})")
        return i - self.base

    def __getitem__(self, i: int):
        return self.items[self._at(i)]

    def __setitem__(self, i: int, value) -> None:
        self.items[self._at(i)] = value

    def __iter__(self):
        return iter(self.items)

    def append(self, value) -> None:
        self.items.append(value)

    def extend(self, values) -> None:
        self.items.extend(values)

    def truncate(self, n: int) -> None:
        """Drop the items from index n on."""
        del self.items[max(0, n - self.base) :]

    def drop_before(self, n: int) -> None:
        """Drop the items before index n."""
        if n > self.base:
            del self.items[: n - self.base]
            self.base = n


@dataclass(frozen=True)
class Windows:
    """N frames a window, o frames overlap, k subsequences a window, and the weight of
    the transition costs against the node costs."""

    n: int
    o: int
    k: int
    weight: float

    @property
    def step(self) -> int:
        return self.n - self.o


def align(q: np.ndarray, qseen: np.ndarray, k: np.ndarray) -> tuple[float, float, float]:
    """(θ, tx, tz) placing points k on points q best (least squares over a rotation about
    +Y and a ground translation, Kovar et al. 2002): q, k (..., 3) m, qseen (...) bool
    (the pairs to use, weight 1 each)."""
    q, k = q[qseen], k[qseen]
    if not len(q):
        return 0.0, 0.0, 0.0
    qc, kc = q.mean(axis=0), k.mean(axis=0)
    a = q - qc
    b = k - kc
    A = float(np.sum(a[:, 0] * b[:, 0] + a[:, 2] * b[:, 2]))
    B = float(np.sum(a[:, 0] * b[:, 2] - a[:, 2] * b[:, 0]))
    theta = float(np.arctan2(B, A)) if A * A + B * B > 1e-18 else 0.0
    c, s = np.cos(theta), np.sin(theta)
    return theta, float(qc[0] - (c * kc[0] + s * kc[2])), float(qc[2] - (-s * kc[0] + c * kc[2]))


WARP_SMOOTHING = 5  # frames: the moving average over a subsequence's warping path


def smooth_warp(frames: np.ndarray, width: int = WARP_SMOOTHING) -> np.ndarray:
    """A warping path's knowledge-base frames (one an input frame) averaged over `width`
    input frames, the ends extended by point reflection: the steps of eq. 4.2 advance a
    subsequence by ½, 1 or 2 frames a row, which played as they come make the motion
    stutter at up to twice its speed; averaged, it moves at the path's local rate. A
    path at a constant rate (a copy of the input) is unchanged, and the result stays
    monotone and inside the path's first and last frames."""
    f = np.asarray(frames, dtype=np.float64)
    h = min(width // 2, len(f) - 1)
    if h < 1:
        return f
    padded = np.concatenate([2 * f[0] - f[h:0:-1], f, 2 * f[-1] - f[-2 : -h - 2 : -1]])
    out = np.convolve(padded, np.ones(2 * h + 1) / (2 * h + 1), mode="valid")
    return np.clip(out, f[0], f[-1])


class SsgDecoder:
    """See the module docstring. index: the SSG index (hidden frames set); kb_markers
    (F, M, 3): its frames' markers; kb: their window clouds; windows: N, o, k, weight;
    lag: windows a committed one waits for (None: the whole input at once); prune: drop
    what no window can still use (module docstring, *Memory*; needs a lag) — a live
    session's, whose frames are read as they become final; a batch run reads its layers
    and anchors at the end."""

    def __init__(
        self,
        index: SsgIndex,
        kb_markers: np.ndarray,
        kb: WindowPoints,
        windows: Windows,
        rate_hz: float,
        lag: int | None = None,
        expected_frames: int = 0,
        prune: bool = False,
    ):
        self.index = index
        self.kb_markers = kb_markers
        self.kb = kb
        self.w = windows
        self.lag = lag
        self.ahead = int(np.max(kb.taus)) if len(kb.taus) else 0  # frames a local cost looks ahead
        import numba

        self.chunks = dtw.run_chunks(index.run_start, 4 * numba.get_num_threads())
        M = kb_markers.shape[1]
        cap = max(expected_frames, 256)
        self.points = np.zeros((cap, M, 3))  # input frames base, base + 1, …, T − 1
        self.seen = np.zeros((cap, M), dtype=bool)
        self.T = 0
        self.base = 0  # the first input frame held (a pruning decoder drops those before)
        self.prune = bool(prune) and lag is not None
        self.back = max(0, -int(np.min(kb.taus))) if len(kb.taus) else 0  # frames a local cost looks back
        self.layers = Tail()  # Layer
        self.stops = Tail()  # each layer's stop, increasing (`sources` finds a frame's windows)
        self.edges = Tail()  # edges[a]: layer a → a + 1
        self.anchors: dict[int, Anchor] = {}  # by number, in order of retrieval
        self.next_anchor = 0
        self.retrieved = False  # whether any layer has retrieved nodes
        self.path = Tail()  # committed node of each committed layer
        self.emitted = 0  # input frames final so far
        self.rows: dict[int, np.ndarray] = {}  # local cost rows by input frame
        self.finished = False
        self.searched = 0
        self.cells = 0
        self.dp = Tail()  # `_forward`'s costs, valid for layers below dp_valid
        self.dp_valid = 0

    # ---------------------------------------------------------------- input

    def push(self, points: np.ndarray, seen: np.ndarray) -> list[tuple[int, int]]:
        """Input frames: points (M, 3) or (K, M, 3) m, seen (M,) or (K, M) bool (a live
        stream pushes one at a time, a batch run all at once; the result is the same).
        A window is searched once the frames its local costs look at are in (its last
        frame and `ahead` more). Returns the frame ranges [a, b) that became final
        (`sources`)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, *self.points.shape[1:])
        seen = np.asarray(seen, dtype=bool).reshape(-1, self.seen.shape[1])
        K = points.shape[0]
        if self.T + K - self.base > len(self.points):
            self._make_room(K)
        self.points[self.T - self.base : self.T + K - self.base] = points
        self.seen[self.T - self.base : self.T + K - self.base] = seen
        self.T += K
        out = []
        while True:
            start = len(self.layers) * self.w.step
            if self.T < start + self.w.n + self.ahead:
                return out
            self._add_layer(start, start + self.w.n)
            out += self._commit()

    def finish(self) -> list[tuple[int, int]]:
        """The end of the input: the windows still waiting, the last window, the final
        path, every frame final."""
        if self.finished:
            return []
        self.finished = True
        if self.T == 0:
            return []
        out = []
        while len(self.layers) * self.w.step + self.w.n <= self.T:
            start = len(self.layers) * self.w.step
            self._add_layer(start, start + self.w.n)
            out += self._commit()
        if not self.layers:
            self._add_layer(0, self.T)
        elif self.layers[-1].stop < self.T:
            floor = self.layers[-2].stop if len(self.layers) >= 2 else 0
            self._add_layer(max(self.T - self.w.n, floor), self.T)
        if not self.retrieved:
            self._search_anyway()
        first = len(self.path)
        entry = self._entry(first)
        nodes, _ = cheapest_path(self.layers, self.edges, self.w.weight, first, entry)
        self.path.extend(int(v) for v in nodes)
        return out + self._emit(self.T)

    def _make_room(self, K: int) -> None:
        """Room for K more input frames: the frames a pruning decoder no longer needs
        dropped (those before its oldest kept layer and what a local cost looks back),
        then, if that is not enough, the buffers doubled."""
        keep = (
            max(self.base, min(self.layers[self.layers.base].start - self.back, self.T))
            if self.prune and self.layers.base
            else self.base
        )
        if keep > self.base:
            held = self.T - keep
            self.points[:held] = self.points[keep - self.base : self.T - self.base]
            self.seen[:held] = self.seen[keep - self.base : self.T - self.base]
            self.base = keep
        if self.T + K - self.base > len(self.points):
            grow = max(self.T + K - self.base, 2 * len(self.points))
            self.points = np.concatenate([self.points, np.zeros((grow - len(self.points),) + self.points.shape[1:])])
            self.seen = np.concatenate([self.seen, np.zeros((grow - len(self.seen), self.seen.shape[1]), bool)])

    def _input(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        """Input frames [start, stop): points (L, M, 3), seen (L, M)."""
        if start < self.base:
            raise IndexError(f"input frame {start} was dropped (kept from {self.base})")
        return self.points[start - self.base : stop - self.base], self.seen[start - self.base : stop - self.base]

    @property
    def retained_bytes(self) -> int:
        """Bytes of the arrays the decoder holds: input frames, layers, edges, forward
        costs, anchors' frames and local cost rows (flat after a pruning decoder's first
        minute; a growing one's grow with the input)."""
        arrays = [self.points, self.seen, *self.edges, *self.dp, *self.rows.values()]
        arrays += [a for layer in self.layers for a in (layer.kind, layer.anchor, layer.cost)]
        arrays += [A.frames for A in self.anchors.values()]
        return int(sum(a.nbytes for a in arrays))

    # ---------------------------------------------------------------- layers

    def _data_rows(self, start: int, stop: int) -> int:
        return int(self._input(start, stop)[1].any(axis=1).sum())

    def _add_layer(self, start: int, stop: int, force: bool = False) -> None:
        blind = not force and 2 * self._data_rows(start, stop) <= stop - start
        layer = Layer(start, stop, blind)
        self.layers.append(layer)
        self.stops.append(stop)
        z = len(self.layers) - 1
        if z:
            self.edges.append(np.zeros((0, 0)))
        if not blind:
            self._retrieve(layer, z)
            blind = layer.blind = not layer.size  # (every frame hidden: nothing found)
        if blind:
            prev = self.layers[z - 1] if z else None
            if prev is not None and prev.size:
                keep = prev.kind != BACKWARD
                anchors = prev.anchor[keep]
                layer.add(FORWARD, anchors, self._extension_costs(layer, anchors))
        else:
            self._extend_backward(z)
        if z:
            self._refresh_edges(z - 1)

    def _retrieve(self, layer: Layer, z: int) -> None:
        start, stop = layer.start, layer.stop
        C = self._cost_rows(start, stop)
        N, F = C.shape
        D = np.empty((N, F))
        step = np.empty((N, F), dtype=np.int8)
        dtw.subsequence_dtw(C, self.index.run_start, D, step, self.chunks)
        self.searched += 1
        self.cells += N * F
        found = dtw.k_best(D, step, self.w.k)
        found += self._continuations(z, D, step, {int(f[-1]) for _, f in found})
        anchors, costs = [], []
        for cost, frames in found:
            a = self._anchor(z, start, stop, frames)
            anchors.append(a)
            costs.append(cost / N)
        layer.add(RETRIEVED, anchors, costs)
        self.retrieved |= bool(anchors)

    def _continuations(self, z: int, D: np.ndarray, step: np.ndarray, ends: set) -> list:
        """The best subsequence ending where each of the k nodes of the window before with
        the cheapest paths to them, played on at its warping factor, ends in this one —
        when the k best missed it. With markers that cannot tell poses apart (a single marker standing
        still matches every stance of every clip) the k best are an arbitrary few of
        many equal ones; the subsequence that simply goes on is always among the
        candidates, so the graph can keep a motion coherent."""
        if not z or self.layers[z - 1].blind:
            return []
        prev = self.layers[z - 1]
        last = self.layers[z].stop - 1
        out = []
        best = np.argsort(self._forward(z - 1), kind="stable")[: self.w.k]  # the k with the cheapest paths to them
        for a in prev.anchor[best]:
            end = int(np.rint(self.anchors[a].frames_at(np.array([last]))[0]))
            if end in ends or not np.isfinite(D[-1, end]):
                continue
            frames = np.empty(D.shape[0])
            dtw.backtrack(step, end, frames)
            ends.add(end)
            out.append((float(D[-1, end]), frames))
        return out

    def _forward(self, z: int) -> np.ndarray:
        """(K,) the cost of the cheapest path from the first window to each node of layer
        z (kept per layer; recomputed from the first layer whose nodes or edges changed)."""
        self.dp.truncate(self.dp_valid)
        while len(self.dp) <= z:
            a = len(self.dp)
            cost = self.layers[a].cost
            if a == 0:
                self.dp.append(cost)
            else:
                self.dp.append(
                    cost
                    + np.min(
                        self.dp[a - 1][:, None] + weighted(self.edges[a - 1], self.w.weight), axis=0, initial=np.inf
                    )
                )
        self.dp_valid = len(self.dp)
        return self.dp[z]

    def _anchor(self, z: int, start: int, stop: int, frames: np.ndarray) -> int:
        frames = smooth_warp(frames)
        kb = self._kb_at(frames)  # (L, M, 3)
        theta, tx, tz = align(*self._input(start, stop), kb)
        first = int(self.index.run_first[int(frames[-1])])
        last = int(self.index.run_last[int(frames[-1])])
        warp = float(frames[-1] - frames[0]) / max(1, len(frames) - 1)
        a = self.next_anchor
        self.anchors[a] = Anchor(z, start, stop, np.asarray(frames, dtype=np.float64), theta, tx, tz, warp, first, last)
        self.next_anchor += 1
        return a

    def _extend_backward(self, z: int) -> None:
        """Backward chains from layer z's retrieved nodes into the blind layers before it
        that are not committed yet."""
        a = z - 1
        if a < len(self.path) or a < 0 or not self.layers[a].blind:
            return
        mine = self.layers[z].anchor[self.layers[z].kind == RETRIEVED]
        while a >= len(self.path) and a >= 0 and self.layers[a].blind:
            layer = self.layers[a]
            layer.add(BACKWARD, mine, self._extension_costs(layer, mine))
            self.dp_valid = min(self.dp_valid, a)
            a -= 1
        for p in range(
            max(a, 0), z - 1
        ):  # (the edges into and out of each extended layer, once; z − 1 → z: the caller)
            self._refresh_edges(p)

    def _search_anyway(self) -> None:
        """No window had markers seen in more than half its frames: search the one with
        the most, and extend it through the others."""
        rows = [self._data_rows(layer.start, layer.stop) for layer in self.layers]
        best = int(np.argmax(rows))
        spans = [(layer.start, layer.stop) for layer in self.layers]  # (nothing committed: none dropped)
        self.layers, self.edges, self.anchors, self.dp, self.dp_valid, self.stops = (
            Tail(),
            Tail(),
            {},
            Tail(),
            0,
            Tail(),
        )
        self.next_anchor = 0
        for z, (s, e) in enumerate(spans):
            self._add_layer(s, e, force=z == best)

    def _refresh_edges(self, a: int) -> None:
        self.edges[a] = edge_costs(self.layers[a], self.layers[a + 1], self.anchors, self.index.joints)
        self.dp_valid = min(self.dp_valid, a + 1)

    def _kb_at(self, frames: np.ndarray) -> np.ndarray:
        """(..., M, 3) knowledge-base markers at fractional index frames."""
        f = np.asarray(frames, dtype=np.float64)
        lo = np.floor(f).astype(np.int64)
        hi = np.minimum(lo + 1, self.index.run_last[lo])
        w = (f - lo)[..., None, None]
        return self.kb_markers[lo] * (1.0 - w) + self.kb_markers[hi] * w

    def _extension_costs(self, layer: Layer, anchors: np.ndarray) -> np.ndarray:
        """Each chain's fixed-transform distance (m² an input frame) to the markers the
        layer's frames have."""
        n = np.arange(layer.start, layer.stop)
        points, seen = self._input(layer.start, layer.stop)
        if not seen.any() or not len(anchors):
            return np.zeros(len(anchors))
        out = np.empty(len(anchors))
        for i, a in enumerate(anchors):
            A = self.anchors[a]
            kb = placed(self._kb_at(A.frames_at(n))[None], np.array([A.theta]), np.array([A.tx]), np.array([A.tz]))[0]
            d = ((kb - points) ** 2).sum(axis=-1)
            per_row = np.where(seen.any(axis=1), (d * seen).sum(axis=1) / np.maximum(seen.sum(axis=1), 1), 0.0)
            out[i] = per_row.sum() / n.size
        return out

    # ---------------------------------------------------------------- local costs

    def _cost_rows(self, start: int, stop: int) -> np.ndarray:
        """(stop − start, F) float32 local cost rows, computed once per input frame (a
        block of frames at a time in batch) and dropped once no window needs them."""
        need = [n for n in range(start, stop) if n not in self.rows]
        if need:
            # A block of rows at once where the frames they look at are in (a batch run's
            # whole input): one wider matrix product is cheaper a row.
            ready = self.T if self.finished else self.T - self.ahead
            hi = min(ready, max(stop, need[0] + COST_BLOCK))
            need = list(range(need[0], max(hi, stop)))
            frames = np.asarray(need, dtype=np.int64)
            # (frames held from `base` on, which lies before every frame these look at:
            # `_make_room`)
            C = dtw.local_costs(
                self.kb,
                self.points[: self.T - self.base],
                self.seen[: self.T - self.base],
                frames - self.base,
                self.index.allowed,
            )
            for i, n in enumerate(need):
                self.rows[n] = C[i]
        for n in [n for n in self.rows if n < start]:
            del self.rows[n]
        return np.stack([self.rows[n] for n in range(start, stop)])

    # ---------------------------------------------------------------- commit

    def _entry(self, first: int) -> np.ndarray | None:
        if first == 0:
            return None
        return self.edges[first - 1][self.path[first - 1]]

    def _commit(self) -> list[tuple[int, int]]:
        if self.lag is None:
            return []
        out = []
        z = len(self.layers) - 1
        while z - len(self.path) > self.lag:
            c = len(self.path)
            if not self.layers[c].size:
                break  # (no searchable window yet: it waits)
            nodes, _ = cheapest_path(self.layers, self.edges, self.w.weight, c, self._entry(c))
            self.path.append(int(nodes[0]))
            out += self._emit(self.layers[c + 1].start)
        if self.prune and len(self.path) - KEEP_COMMITTED - self.layers.base >= PRUNE_EVERY:
            self._drop_committed(len(self.path) - KEEP_COMMITTED)
        return out

    def _drop_committed(self, first: int) -> None:
        """Drop the layers before `first` (committed, and not among the last
        KEEP_COMMITTED), their edges, stops and path entries, the forward costs before
        them (computed first up to the newest committed layer, where they are final:
        the next windows' continuations start from them, never from a dropped layer's)
        and the anchors no kept layer refers to. The input frames before the kept
        layers go when the buffer is next full (`_make_room`)."""
        self._forward(len(self.path) - 1)
        for tail in (self.layers, self.stops, self.edges, self.path, self.dp):
            tail.drop_before(first)
        used = set()
        for layer in self.layers:
            used.update(layer.anchor.tolist())
        self.anchors = {a: A for a, A in self.anchors.items() if a in used}

    def _emit(self, upto_frame: int) -> list[tuple[int, int]]:
        if upto_frame <= self.emitted:
            return []
        a, self.emitted = self.emitted, upto_frame
        return [(a, upto_frame)]

    # ---------------------------------------------------------------- output

    def sources(self, a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Frames [a, b) as up to two placed sources each: anchor (L, 2) int (−1: none),
        index frame (L, 2) float, weight (L, 2) — the cross-fade of eq. 4.5 over each
        overlap, C¹ (α = 1 − (3u² − 2u³), u = (t + 1) / (overlap + 1))."""
        L = b - a
        anchor = np.full((L, 2), -1, dtype=np.int64)
        frame = np.zeros((L, 2))
        weight = np.zeros((L, 2))
        # The committed windows reaching [a, b): their stops increase, so they start at the
        # first window ending after a (a live stream's frames cost the same an hour in).
        for z in range(bisect.bisect_right(self.stops, a, self.stops.base, len(self.path)), len(self.path)):
            layer, node = self.layers[z], self.path[z]
            if layer.start >= b:
                break
            lo, hi = max(a, layer.start), min(b, layer.stop)
            an = int(layer.anchor[node])
            n = np.arange(lo, hi)
            f = self.anchors[an].frames_at(n)
            w = np.ones(n.size)
            nxt = self.layers[z + 1] if z + 1 < len(self.path) else None
            prv = self.layers[z - 1] if z >= 1 else None
            if nxt is not None and nxt.start < layer.stop:  # fading out into the next window
                L_ov = layer.stop - nxt.start
                u = (n - nxt.start + 1) / (L_ov + 1.0)
                fade = np.where(n >= nxt.start, 1.0 - (3 * u * u - 2 * u**3), 1.0)
                w = w * fade
            if prv is not None and layer.start < prv.stop:  # fading in from the one before
                L_ov = prv.stop - layer.start
                u = (n - layer.start + 1) / (L_ov + 1.0)
                fade = np.where(n < prv.stop, 3 * u * u - 2 * u**3, 1.0)
                w = w * fade
            slot = np.where(anchor[n - a, 0] < 0, 0, 1)
            rows = n - a
            anchor[rows, slot] = an
            frame[rows, slot] = f
            weight[rows, slot] = w
        total = weight.sum(axis=1, keepdims=True)
        weight = np.where(total > 0, weight / np.where(total > 0, total, 1.0), weight)
        return anchor, frame, weight

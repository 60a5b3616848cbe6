"""Streaming Viterbi decoders : samples in one at a time, final
frames out as soon as they are decided.

- `FixedLagDecoder`: one incremental search over the whole stream. After sample t,
  frame t − L is emitted from the best path (fixed lag L), and earlier when every
  surviving path already agrees on it (the converged-prefix commit). An emitted frame
  is never changed; when a later best path disagrees with what was emitted, the
  output jumps there (counted in `revisions`), and synthesis blends it like a cut.
- `SlidingWindowDecoder`: Kelly et al. 2013, §6.4 / fig. 10 for comparison: each sample, a fresh search
  over the last W samples; frame t − L of that window's best path is emitted.

Both emit (nodes, arrival_edges): arrival_edges[k] is the edge by which the deciding
path entered nodes[k] (−1 for frame 0). Consecutive emitted nodes are joined by their
edge except after a revision.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from graphsvc.errors import InputError
from graphsvc.graph.model import MotionGraph
from graphsvc.strategies.options import Weights
from graphsvc.strategies.start import start_placement
from graphsvc.strategies.viterbi.batch import compile_constraints
from graphsvc.strategies.viterbi.search import ViterbiSearch


def _check_lag(lag: int) -> int:
    if isinstance(lag, bool) or not isinstance(lag, (int, np.integer)) or lag < 0:
        raise InputError(f"lag must be a non-negative whole number of samples, got {lag!r}")
    return int(lag)


class _Requirements:
    """Constraint sets → the per-set requirement (kind, value) of one sample."""

    def __init__(self, graph: MotionGraph, constraint_sets, rate_hz: float):
        self.graph = graph
        self.sets = list(constraint_sets or [])
        self.gamma = len(self.sets)
        self.rate_hz = float(rate_hz)
        compile_constraints(graph, self.sets, np.zeros(0))  # unknown labels fail now, not mid-stream
        self._none = (np.zeros(0, np.int64), np.zeros(0, np.int64))

    def at(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        if not self.gamma:  # the common case, once per sample: no work
            return self._none
        kinds, values = compile_constraints(self.graph, self.sets, np.array([t / self.rate_hz]))
        return kinds[:, 0], values[:, 0]


class FixedLagDecoder:
    """Incremental Viterbi search emitting each frame `lag` samples after it arrives
    (or earlier, once all survivors share it).

    push(acc (S, 3) m/s², position (2,) m or None, heading rad or None) at the graph
    rate → (nodes, arrival_edges) newly final; flush() → the rest."""

    # Longest lag (samples) served by the dense window alone: (lag + 1 + BLOCK) × N
    # bytes — 103 MB on a 268k-node graph at 256 (8.5 s at 30 Hz) — instead of the
    # window plus a survivor store, which only pays for much longer lags.
    DENSE_MAX_LAG = 256

    def __init__(
        self,
        graph: MotionGraph,
        weights: Weights = Weights(),
        lag: int = 0,
        constraint_sets=None,
        allowed: np.ndarray | None = None,
        rate_hz: float | None = None,
        threads: bool = True,
        placed: bool | None = None,
        store: bool | None = None,
        beam: float | None = None,
        start_samples: int = 1,
        pull_s: float | None = None,
        oriented: bool = False,
        max_live: int | None = None,
        catch_up: int | None = None,
    ):
        """oriented: weigh the samples' measured "up" vectors (see ViterbiSearch). placed: see ViterbiSearch (None: from the weights; a caller that knows no
        position or heading will come passes False, which makes each step cheaper).
        store: keep survivors in ViterbiSearch's survivor store (True) or only the last
        lag + 1 samples' back-pointers, dense (False: its `window` mode); None: the
        window for lags up to DENSE_MAX_LAG samples, the store beyond. beam: see
        ViterbiSearch (None: the exact search). start_samples: the search starts once
        this many samples have arrived (or at flush), its paths placed where
        `strategies.base.start_placement` puts them from those samples' positions and
        headings, as a batch search given the same `start` does; 1: at the first
        sample's measurements. No frame is emitted before. pull_s: see ViterbiSearch.
        max_live: a beam search bounded to this many live paths after each sample
        (`ViterbiSearch.max_live`), which starts (with start_samples > 1) at the nodes
        `ViterbiSearch.seed` picks for this many from the start's second sample: a
        start's steps are then sparse ones where every node was live (the kick-off of
        many streams at once), and no later step keeps more. None or 0: the beam alone,
        every node starting a path, as in a batch search (an exact search always).
        catch_up: with start_samples > 1, the search steps at most this many samples a
        push until it has caught up with the samples waiting at its start (the push
        that starts it: its start and catch_up − 1 steps), so that a start costs a few
        steps a push over the next pushes instead of start_samples steps in one; the
        frames are those of the start in one push, each released by a later push.
        None or 0: every waiting sample in the push that starts the search."""
        self.graph = graph
        self.lag = _check_lag(lag)
        self.requirements = _Requirements(graph, constraint_sets, rate_hz or graph.rate_hz)
        if store is None:
            store = self.lag > self.DENSE_MAX_LAG
        self.search = ViterbiSearch(
            graph,
            weights,
            self.requirements.gamma,
            allowed,
            threads,
            placed,
            window=None if store else self.lag + 1,
            beam=beam,
            pull_s=pull_s,
            oriented=oriented,
        )
        self.start_samples = max(1, int(start_samples))
        self.max_live = int(max_live) if max_live and beam is not None else None
        self.search.max_live = self.max_live
        self.catch_up = int(catch_up) if catch_up and catch_up > 0 else None
        self._seed = None  # where a bounded search's paths start (`_start_pending`)
        self._pending: list = []  # samples (acc, position, heading) that arrived before the search started
        self.emitted = 0  # frames emitted so far
        self.last_node = -1
        self.revisions = 0  # emitted frames not reached from the previous emitted frame
        self.converged_frames = 0  # frames emitted because all survivors agreed, before their lag ran out

    @property
    def samples(self) -> int:
        return self.search.t + 1 + len(self._pending)

    @property
    def started(self) -> bool:
        return self.search.t >= 0

    def push(self, acc, position=None, heading=None, up=None) -> tuple[np.ndarray, np.ndarray]:
        """One sample: accelerations (S, 3) m/s², position (2,) m, heading rad, the
        sensors' "up" vectors (S, 3) (an oriented decoder's; None: missing)."""
        if self._pending or (not self.started and self.start_samples > 1):
            self._pending.append((acc, position, heading, up))
            if not self.started:
                if len(self._pending) == 2 and self.max_live:  # (the seed in a push that has no step)
                    self._seed = self.search.seed(acc, self.max_live, up)
                if len(self._pending) < self.start_samples:
                    return np.zeros(0, np.int64), np.zeros(0, np.int64)
                return self._start_pending()
            return self._catch_up(self.catch_up)
        return self._advance(acc, position, heading, up)

    def _advance(self, acc, position, heading, up=None) -> tuple[np.ndarray, np.ndarray]:
        t = self.search.t + 1
        kinds, values = self.requirements.at(t)
        if t == 0:
            self.search.start(position, heading, kinds, values, live=self._seed)
        else:
            self.search.step(acc, position, heading, kinds, values, up=up)
        final = max(self.search.converged_t, t - self.lag)
        self.converged_frames += max(0, final - max(self.emitted - 1, t - self.lag))
        return self._emit(final)

    def _start_pending(self) -> tuple[np.ndarray, np.ndarray]:
        """Start the search placed from the samples waiting, then run them (or, with
        catch_up, the first of them) through it."""
        pending = self._pending
        position = np.array(
            [np.full(2, np.nan) if p is None else np.asarray(p, dtype=np.float64) for _, p, _, _ in pending]
        )
        heading = np.array([np.nan if h is None else float(h) for _, _, h, _ in pending])
        p0, h0 = start_placement(position, heading, self.requirements.rate_hz)
        if self.max_live and len(pending) > 1 and self._seed is None:
            self._seed = self.search.seed(pending[1][0], self.max_live, pending[1][3])
        self._pending = pending[1:]
        first = self._advance(pending[0][0], p0, h0)  # (sample 0 places the paths; its readings are not scored)
        rest = self._catch_up(None if self.catch_up is None else self.catch_up - 1)
        return np.concatenate([first[0], rest[0]]), np.concatenate([first[1], rest[1]])

    def _catch_up(self, most: int | None) -> tuple[np.ndarray, np.ndarray]:
        """Step the search through at most `most` of the samples waiting (None: all)."""
        count = len(self._pending) if most is None else min(most, len(self._pending))
        steps, self._pending = self._pending[:count], self._pending[count:]
        out = [self._advance(acc, p, h, u) for acc, p, h, u in steps]
        if not out:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        return np.concatenate([n for n, _ in out]), np.concatenate([e for _, e in out])

    def flush(self) -> tuple[np.ndarray, np.ndarray]:
        """Everything not yet emitted, from the best path now."""
        if not self.started and not self._pending:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        out = [self._start_pending()] if not self.started else []
        out += [self._catch_up(None), self._emit(self.search.t)]
        return np.concatenate([n for n, _ in out]), np.concatenate([e for _, e in out])

    def _emit(self, until: int) -> tuple[np.ndarray, np.ndarray]:
        if until < self.emitted:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        nodes, edges = self.search.trace_arrivals(self.search.best_node(), self.emitted)
        count = until - self.emitted + 1
        nodes, edges = nodes[:count], edges[:count]
        if self.emitted > 0 and self.graph.edge_src[edges[0]] != self.last_node:
            self.revisions += 1
        self.emitted += count
        self.last_node = int(nodes[-1])
        # Emitted frames are never traced again: their survivors can go.
        self.search.forget_before(self.emitted)
        return nodes, edges


class SlidingWindowDecoder:
    """Kelly et al. 2013, §6.4: at each sample, search the last `window` samples afresh (every node a
    possible start, at the window's first measured position and heading) and emit
    frame t − lag of the best path. Costs `window` times the fixed-lag decoder."""

    def __init__(
        self,
        graph: MotionGraph,
        weights: Weights = Weights(),
        window: int = 30,
        lag: int = 0,
        constraint_sets=None,
        allowed: np.ndarray | None = None,
        rate_hz: float | None = None,
        oriented: bool = False,
    ):
        """oriented: weigh the samples' measured "up" vectors (see ViterbiSearch)."""
        self.graph = graph
        self.weights = weights
        self.oriented = bool(oriented)
        self.lag = _check_lag(lag)
        window = _check_lag(window)
        if window < self.lag + 2:
            raise InputError(f"window ({window} samples) must exceed the lag ({self.lag}) by at least 2")
        self.window = window
        self.requirements = _Requirements(graph, constraint_sets, rate_hz or graph.rate_hz)
        self.allowed = allowed
        self.buffer: deque = deque(maxlen=window)
        self.t = -1
        self.emitted = 0
        self.last_node = -1
        self.revisions = 0

    @property
    def samples(self) -> int:
        return self.t + 1

    def _search(self) -> tuple[np.ndarray, np.ndarray, int]:
        """Best path over the buffered window: nodes, arrival edges, first sample."""
        first = self.t - len(self.buffer) + 1
        search = ViterbiSearch(self.graph, self.weights, self.requirements.gamma, self.allowed, oriented=self.oriented)
        for k, (acc, position, heading, up) in enumerate(self.buffer):
            kinds, values = self.requirements.at(first + k)
            if k == 0:
                search.start(position, heading, kinds, values)
            else:
                search.step(acc, position, heading, kinds, values, up=up)
        nodes, edges = search.trace_arrivals(search.best_node(), 0)
        if first > 0:
            edges[0] = -1  # the window's start was entered from outside it: unknown
        return nodes, edges, first

    def push(self, acc, position=None, heading=None, up=None) -> tuple[np.ndarray, np.ndarray]:
        """One sample, as FixedLagDecoder.push."""
        self.t += 1
        self.buffer.append((np.asarray(acc, dtype=np.float64), position, heading, up))
        until = self.t - self.lag
        if until < self.emitted:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        return self._emit(until)

    def flush(self) -> tuple[np.ndarray, np.ndarray]:
        if self.t < self.emitted:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        return self._emit(self.t)

    def _emit(self, until: int) -> tuple[np.ndarray, np.ndarray]:
        nodes, edges, first = self._search()
        lo = self.emitted - first
        nodes, edges = nodes[lo : until - first + 1], edges[lo : until - first + 1]
        if self.emitted > 0 and (edges[0] < 0 or self.graph.edge_src[edges[0]] != self.last_node):
            self.revisions += 1
        self.emitted = until + 1
        self.last_node = int(nodes[-1])
        return nodes, edges


def decode_stream(decoder, acc: np.ndarray, position=None, heading=None, up=None) -> tuple[np.ndarray, np.ndarray]:
    """Push a whole input (T, S, 3) through a streaming decoder and flush: the node
    path (T,) and arrival edges (T,) it emits. up: (T, S, 3) measured "up" vectors for
    an oriented decoder, or None."""
    out_nodes, out_edges = [], []
    for t in range(acc.shape[0]):
        n, e = decoder.push(
            acc[t],
            None if position is None else position[t],
            None if heading is None else heading[t],
            None if up is None else up[t],
        )
        out_nodes.append(n)
        out_edges.append(e)
    n, e = decoder.flush()
    out_nodes.append(n)
    out_edges.append(e)
    return np.concatenate(out_nodes), np.concatenate(out_edges)

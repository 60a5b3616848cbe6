"""The Viterbi search's back-pointers (Kelly et al. 2013, §5.1, after Abbasfar and Yao):
`SurvivorMemory`, which `search.ViterbiSearch` is made of beside its step.

Instead of the N × T back-pointer lattice the search keeps the newest samples' lattice
rows dense, one byte a node, in a ring of BLOCK + STORE_WINDOW rows (a batch search:
twice both). When the ring is full it walks back from all live nodes and appends only
the oldest BLOCK rows' points that some live path passes through to a survivor store
(the kernels: `store`); by then most paths have merged. When the store has doubled, one
backward sweep keeps what the live paths still reach. The compression ratio reported is
the full lattice's memory (N·T points of 4 bytes) over the peak memory held for it. Once
every survivor passes through one point, the prefix up to it is final (the
converged-prefix commit of streaming decoders). A fixed-lag decoder's search keeps a
dense window instead and no store (`window`). docs/search.md, *Survivor memory*.
"""

from __future__ import annotations

import numpy as np

from graphsvc.errors import InputError
from graphsvc.strategies.viterbi.store import (
    EDGE,
    NODE,
    PARENT,
    TIME,
    _append_block,
    _block_levels,
    _collect,
    _converged_row,
    _converged_until,
    _trace,
)


class SurvivorMemory:
    """The dense ring of the newest lattice rows, the survivor store, the ancestors a
    flush may start from, and the trace back through them. A search made of it holds
    N, t (the newest sample), state (the kernels' (N, width) rows), incoming and
    edge_src (the graph's tables), sets them before `_init_memory`, and per sample
    calls `_make_room`, advances t, writes its arrivals into `_free_row()` (carrying
    `_ancestors()`), then calls `_row_written`."""

    # Rows moved into the store (or dropped) at a time, and rows kept dense beyond them:
    # each walk back through the ring is shared by BLOCK samples. On the built Bandai
    # dataset-2 graph (268k nodes) 128 + 128 took 4.6 ms a sample in steady state,
    # 64 + 128 5.2 ms, and 32 + 0 (the store taking every row at once) 8.3 ms. A batch
    # search, which has no latency to keep low, takes BATCH_RING_SCALE times both: fewer,
    # longer walks, over paths that have merged more (built kelly6 graph, 2,880 samples:
    # mode A 2.28 against 2.47–2.54 ms a sample, APO 5.80 against 6.01; 512 + 256 rows
    # 2.21 and 5.62, for 1.5 times the memory; G_E unchanged), unless its input is too
    # short to fill a block (`batch.batch_ring`).
    BLOCK = 128
    STORE_WINDOW = 128
    BATCH_RING_SCALE = 2
    # Carry ancestors (see `_init_memory`) while more than this share of the nodes are
    # distinct paths' nodes at the newest row a flush lists: then the walk through the
    # newer rows costs more than a gather a node a step (built kelly6 graph: 7.5 %, where
    # carrying took a flush from 0.83 to 0.28 ms a sample; generated G_E: under 0.05 %,
    # where carrying cost 4 % of a step and saved nothing).
    ANCESTOR_SHARE = 0.01

    def _init_memory(self, N: int, window: int | None, ring: tuple[int, int] | None) -> None:
        """window: keep only the last `window` rows or more, dense, and no store; ring:
        (BLOCK, STORE_WINDOW) instead of the class's (see `search.ViterbiSearch`)."""
        self.converged_t = -1  # every sample ≤ this one has a single surviving entry (or was forgotten)
        self.keep_from = 0  # samples before this one are forgotten (see forget_before)
        # The lattice of the newest samples, dense: one row per sample, each node's
        # arrival (which of its incoming edges its best path came by; 1 byte a node
        # while no node has 255 incoming edges), written sequentially each step, in a
        # ring of rows. In store mode (Kelly et al. 2013, §5.1: the periodic trace-back from all live
        # nodes), when the ring is full the walk back from the live nodes moves the
        # surviving points of its oldest BLOCK rows into the survivor store; they are
        # then STORE_WINDOW samples old, by when most paths have merged (on built
        # graphs, whose clips run as long single-predecessor chains, a third of the
        # nodes still had distinct paths 32 samples back, 8 % at 128). In window mode
        # the oldest rows are dropped instead.
        most = int(np.diff(self.incoming).max(initial=0))
        dtype = next(d for d in (np.uint8, np.uint16, np.uint32) if most < np.iinfo(d).max)
        self.none = int(np.iinfo(dtype).max)  # arrival of a dead node
        if ring is not None:
            self.BLOCK, self.STORE_WINDOW = max(int(ring[0]), 1), max(int(ring[1]), 0)
        self.window = None if window is None else max(int(window), 1)
        rows = self.BLOCK + (self.STORE_WINDOW if window is None else self.window)
        self.arrivals = np.full((rows, N), self.none, dtype=dtype)
        self.first = 0  # physical row of the oldest filled row
        self.used = 0  # rows filled
        self.alive_map = np.zeros(8 * ((N + 7) // 8), dtype=np.uint8)
        small = window is not None  # window mode never appends to the store
        self.row_of = np.zeros(1 if small else N, dtype=np.int64)
        self.level_nodes = np.zeros(16 if small else N + 16, dtype=np.int32)
        self.level_start = np.zeros(self.BLOCK + 1, dtype=np.int64)
        self.store = np.zeros((N + 16 if small else 2 * N + 16, 4), dtype=np.int32)  # 16 bytes a row; doubles when full
        self.size = 0  # rows of the store in use (live or garbage)
        self.live_rows = 0  # rows alive after the last collection
        self.heads = np.full(N, -1, dtype=np.int64)
        # Store mode, while paths stay apart (see ANCESTOR_SHARE): each live path's node
        # at sample ancestor_t (one gather a node a step), so a flush walks back from
        # there instead of through the newest rows (on the built kelly6 graph that walk
        # was a quarter of a step's time: 80k of 268k nodes on distinct paths 32
        # samples back).
        self._identity = np.arange(0 if small else N, dtype=np.int32)
        self.ancestor, self._ancestor_new = self._identity.copy(), self._identity.copy()
        self._no_ancestors = np.zeros(0, dtype=np.int32)  # the kernels' "not carried"
        self.carry_ancestors = False  # decided at each flush
        self.ancestor_t = -1  # −1: not carried since the last flush
        self.peak_entries = 0
        self.peak_bytes = 0

    def _start_memory(self, allowed: np.ndarray) -> None:
        """Sample 0: a path starts at every allowed node, each a store row of its own."""
        live = np.nonzero(allowed)[0]
        self.size = len(live)
        self.store[: self.size, NODE] = live
        self.store[: self.size, EDGE] = -1
        self.store[: self.size, PARENT] = -1
        self.store[: self.size, TIME] = 0
        self.heads[:] = -1
        self.heads[live] = np.arange(self.size)
        self.live_rows = self.size
        self.first = self.used = 0
        self.carry_ancestors, self.ancestor_t = False, -1
        self.converged_t = 0 if len(live) == 1 else -1
        self.peak_entries = self.size
        self.peak_bytes = self.lattice_bytes

    def _make_room(self) -> None:
        """Before a sample: when the ring is full, move its oldest BLOCK rows into the
        store (`_flush`) or, in window mode, drop them (`_slide`)."""
        if self.used == self.arrivals.shape[0]:
            self._flush() if self.window is None else self._slide()

    def _free_row(self) -> np.ndarray:
        """The dense row the newest sample's arrivals are written into."""
        return self.arrivals[(self.first + self.used) % self.arrivals.shape[0]]

    def _ancestors(self) -> tuple[np.ndarray, np.ndarray]:
        """What a step's kernels carry the ancestors in (current, next), or empty arrays
        when they are not carried."""
        return (self.ancestor, self._ancestor_new) if self.carry_ancestors else (self._no_ancestors, self._no_ancestors)

    def _row_written(self) -> None:
        """After a sample's arrivals are written into `_free_row()`."""
        self.used += 1
        if self.carry_ancestors:
            self.ancestor, self._ancestor_new = self._ancestor_new, self.ancestor
        if self.used == self.BLOCK:  # the newest row is the next flush's newest listed one
            self._restart_ancestors()
        self.peak_bytes = max(self.peak_bytes, self.lattice_bytes)

    @property
    def lattice_bytes(self) -> int:
        """Memory held for the trace-back now: the dense rows filled and the store's rows
        in use (survivors and garbage not yet collected)."""
        return self.used * self.arrivals.shape[1] * self.arrivals.itemsize + self.size * self.store.itemsize * 4

    @property
    def compression(self) -> float:
        """The memory reduction of Kelly et al. 2013, §5.1: the full back-pointer lattice (N·T points of 4
        bytes) over the peak memory the search held for it (`lattice_bytes`)."""
        return self.N * (self.t + 1) * 4 / max(self.peak_bytes, 1)

    def _flush(self) -> None:
        """Store mode, ring full: walk back from the live nodes through every dense row
        and move the surviving points of the oldest BLOCK rows into the store (collect
        the store's garbage first when it has doubled); those rows are then free. With
        ancestors carried, the walk starts at the row of ancestor_t, from the live
        paths' nodes there; else at the newest row."""
        t_first = self.t - self.used + 1  # the sample of the oldest row
        if self.ancestor_t >= 0:
            walk, ancestor = self.ancestor_t - t_first + 1, self.ancestor  # rows walked through: to ancestor_t's
            assert self.BLOCK <= walk <= self.used, (walk, self.BLOCK, self.used)
        else:
            walk, ancestor = self.used, self._identity
        while True:  # grown on demand: the worst case (nothing merges) is used × N
            total, converged_row = _block_levels(
                self.arrivals,
                self.first,
                walk,
                self.BLOCK,
                self.incoming,
                self.edge_src,
                self.alive_map,
                self.level_nodes,
                self.level_start,
                ancestor,
                self.state,
            )
            if total >= 0:
                break
            self.level_nodes = np.zeros(2 * self.level_nodes.shape[0], dtype=np.int32)
        flush = self.BLOCK
        appended = int(self.level_start[flush])
        if self.size + appended > self.store.shape[0]:
            self._collect()
            if self.size + appended > self.store.shape[0] // 2:
                # np.empty: rows past `size` are always written before they are read
                bigger = np.empty((2 * (self.size + appended), 4), dtype=np.int32)
                bigger[: self.size] = self.store[: self.size]
                self.store = bigger
        self.size = _append_block(
            self.arrivals,
            self.first,
            flush,
            t_first,
            self.incoming,
            self.edge_src,
            self.heads,
            self.store,
            self.size,
            self.level_nodes,
            self.level_start,
            self.row_of,
        )
        self.peak_entries = max(self.peak_entries, self.live_rows + appended)
        self.peak_bytes = max(self.peak_bytes, self.lattice_bytes)
        self.first = (self.first + flush) % self.arrivals.shape[0]
        self.used -= flush
        apart = self.level_start[flush] - self.level_start[flush - 1]  # distinct nodes at the newest listed row
        self.carry_ancestors = bool(apart > self.ANCESTOR_SHARE * self.N)
        self.ancestor_t = -1
        if self.used >= self.BLOCK:  # (else when the row BLOCK − 1 is written)
            self._restart_ancestors()
        if converged_row >= 0:  # one node left at that row: everything up to it is agreed
            self.converged_t = max(self.converged_t, t_first + converged_row)

    def _restart_ancestors(self) -> None:
        """When carrying them: from now on, ancestor[n] is node n's path's node at this
        sample."""
        if self.carry_ancestors:
            self.ancestor[:] = self._identity
            self.ancestor_t = self.t

    def _slide(self) -> None:
        """Dense-window mode, ring full: note whether the live paths have come to agree
        on a sample not yet forgotten (the converged-prefix commit), then drop the
        oldest BLOCK rows."""
        t_first = self.t - self.used + 1  # the sample of the oldest row
        lowest = max(0, self.keep_from - t_first, self.converged_t + 1 - t_first)
        if lowest < self.used:
            row = _converged_row(
                self.arrivals,
                self.first,
                self.used,
                lowest,
                self.incoming,
                self.edge_src,
                self.none,
                self.alive_map,
                self._newest_nodes(),
            )
            if row >= 0:
                self.converged_t = max(self.converged_t, t_first + row)
        self.first = (self.first + self.BLOCK) % self.arrivals.shape[0]
        self.used -= self.BLOCK

    def _newest_nodes(self) -> np.ndarray:
        """The nodes alive at the newest row, ascending (int32), where the search keeps
        them (a beam search's live list); empty: `_slide` finds them in the row."""
        return np.zeros(0, dtype=np.int32)

    def forget_before(self, t: int) -> None:
        """Let the next garbage collection drop survivors of samples before t: a
        streaming decoder that has emitted them never traces back past them, and on
        graphs whose paths rarely merge they are over a third of the store. Traces must
        then start at t or later; such samples count as agreed (converged_t)."""
        self.keep_from = max(self.keep_from, min(int(t), self.t))

    def _collect(self) -> None:
        self.size = _collect(self.store, self.size, self.heads, self.keep_from)
        self.live_rows = self.size
        self.peak_entries = max(self.peak_entries, self.size)
        if self.converged_t < self.t:
            t_from = max(self.converged_t + 1, self.keep_from)
            self.converged_t = max(self.converged_t, _converged_until(self.store, self.size, t_from, self.t))

    def trace_arrivals(self, node: int, since: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Nodes (t+1−since,) at samples since..t of the path ending at `node` now and
        the edge each was entered by (−1 at sample 0). Walks back only to `since`, so
        a fixed-lag trace costs the lag, not the input length."""
        earliest = self.keep_from
        if self.window is not None and self.used < self.t:  # the window has slid past sample 0
            earliest = max(earliest, self.t - self.used + 1)
        if not earliest <= since <= self.t:
            raise InputError(
                f"cannot trace from sample {since}: the search is at sample {self.t}"
                f" and has forgotten samples before {earliest}"
            )
        return _trace(
            self.arrivals,
            self.first,
            self.used,
            self.t,
            self.heads,
            self.incoming,
            self.edge_src,
            self.store,
            int(node),
            int(since),
        )

    def trace(self, node: int, since: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Nodes (t+1−since,) at samples since..t of the path ending at `node` now,
        and the edges (t−since,) between them."""
        nodes, edges = self.trace_arrivals(node, since)
        return nodes, edges[1:]

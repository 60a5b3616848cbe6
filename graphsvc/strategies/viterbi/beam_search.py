"""A beam search's side of `search.ViterbiSearch`: its setup, the choice between a
sparse step and the exact passes with a cut (`narrow`), the sparse step over the live
paths (`beam._beam_step_py`), the cut and the bound on the live paths, and which
entries of a reused lattice row a sparse step must reset (`_init_row_resets`). The
kernels are in `beam`; the search is made of this and `survivors.SurvivorMemory`
beside its exact step.
"""

from __future__ import annotations

import numpy as np

from graphsvc.errors import InputError
from graphsvc.strategies.viterbi.beam import (
    BEAM_CHUNKS,
    _beam_prune,
    _beam_step,
    _beam_step_serial,
    _bound_live,
    _immortal,
    _reset_costs,
)
from graphsvc.strategies.viterbi.dense import _THREADED


class BeamSteps:
    """A search's beam: `_init_beam` at construction (before the lattice ring),
    `_init_row_resets` after it; `step` asks `narrow`, runs `_beam_step` or the exact
    passes then `_cut` (and `_bound` under `max_live`), and calls `_row_filled` after a
    dense pass."""

    # A beam search steps sparsely (`beam._beam_step_py`: only the nodes its live paths reach,
    # C_A only for the edges read) while at most BEAM_DENSE_SHARE of the nodes are live,
    # by the exact search's passes and then a cut (`beam._beam_prune`) while more than
    # BEAM_SPARSE_SHARE are, and in between by whichever its past steps predict to be
    # faster (`narrow`). The same survivors and states either way, but which is faster
    # depends on the graph: with a fifth of the nodes live, sparse steps took 4 times an
    # exact step on the generated G_E (random transitions, three incoming edges a node)
    # and were the faster on the built kelly6 graph (evaluation with beam 10: 418–449
    # samples/s switching at a quarter, 288–307 at 5 %, 291–330 always sparse); with
    # every node live they took 3 times an exact step on G_E.
    BEAM_DENSE_SHARE = 0.05
    BEAM_SPARSE_SHARE = 0.5
    # A sparse step resets the entries its lattice row's last beam step left set while
    # they are at most one node in ROW_RESET_SHARE, else fills the row (a fill of N
    # bytes beats scattered writes of more than about N / 64 entries).
    ROW_RESET_SHARE = 64

    def _init_beam(self, beam, gamma: int, tables: dict) -> None:
        """The beam (None: the exact search) and a beam search's arrays of N rows;
        InputError for a beam that is not a cost > 0 or with constraint sets."""
        N = self.N
        self.beam = None if beam is None else float(beam)
        if self.beam is not None:
            if not self.beam > 0:
                raise InputError(f"the beam must be a cost > 0 (or inf), got {beam}")
            if gamma:
                raise InputError("a beam search takes no constraint sets (their counts rank before the cost)")
            self._out_start, self._out_dst, self._readings = self.index.beam
            self._immortal = _immortal(tables["incoming"], self.edge_src, self.allowed)
            self._marks = np.zeros(8 * ((N + 7) // 8), dtype=np.uint8)
            self._marks_words = self._marks.view(np.uint64)
            self._sources = np.zeros(N, dtype=np.uint8)
            # live nodes ascending: at the newest sample (state's), at the one before
            # (_state_new's, whose costs a step resets to inf before writing)
            self._live, self._live_before = np.empty(N, dtype=np.int32), np.empty(N, dtype=np.int32)
            self._n_live = self._n_live_before = 0
            self._touched, self._total = np.empty(N, dtype=np.int32), np.empty(N)
            self._survives = np.empty(N, dtype=np.uint8)
            self._beam_low = np.empty((BEAM_CHUNKS, 2))
            self._no_c32 = np.zeros(0, dtype=np.float32)
            self._step_seconds = (None, None)  # sparse steps' seconds a live node, dense steps' (see `narrow`)
        # A beam search's bound on its live paths after each step (None: the beam alone):
        # the `max_live` cheapest survive the cut (`beam._bound_live`). May change between
        # steps — a streaming decoder bounds its start (`stream.FixedLagDecoder`).
        self.max_live: int | None = None

    def _init_row_resets(self) -> None:
        # For each lattice row, the nodes whose entries a beam step may have left set
        # (its survivors), or None after a dense pass (every entry written): a beam
        # step resets only those (`_beam_step`). The ring starts all `none`.
        self._row_written_nodes: list[np.ndarray | None] = [np.zeros(0, np.int32)] * self.arrivals.shape[0]
        self._no_reset = np.zeros(0, np.int32)

    def _row_filled(self) -> None:
        """The newest sample's row is being written by a dense pass (every entry)."""
        self._row_written_nodes[(self.first + self.used) % self.arrivals.shape[0]] = None

    @property
    def narrow(self) -> bool:
        """Whether the next step is a beam search's sparse one: always while few nodes are
        live, never while most are, else whichever this search's steps so far predict to
        be faster (sparse steps cost about the same per live node; the results are the
        same either way, so timing only chooses the work)."""
        if self.beam is None:
            return False
        if self._n_live <= self.BEAM_DENSE_SHARE * self.N:
            return True
        if self._n_live > self.BEAM_SPARSE_SHARE * self.N:
            return False
        per_node, dense = self._step_seconds
        if per_node is None or dense is None:
            return dense is not None  # (each kind tried once before comparing)
        return per_node * self._n_live < dense

    def _time_beam_step(self, narrow: bool, seconds: float, live_before: int) -> None:
        """Fold a beam step's time into `narrow`'s estimates (running means, recent steps
        weighted most): seconds a live node for sparse steps, a step for dense ones."""
        per_node, dense = self._step_seconds
        if narrow:
            x = seconds / max(live_before, 1)
            per_node = x if per_node is None else 0.75 * per_node + 0.25 * x
        else:
            dense = seconds if dense is None else 0.75 * dense + 0.25 * seconds
        self._step_seconds = (per_node, dense)

    def _newest_nodes(self) -> np.ndarray:
        # A beam search's live nodes are exactly those with an arrival in the newest row
        # (every other entry `none`: the beam's cut and the bound write it).
        if self.beam is None or self._n_live == 0:
            return np.zeros(0, dtype=np.int32)
        return self._live[: self._n_live]

    def _beam_step(self, wa, wp, wh, use_pos, use_head, meas_pos, meas_heading, arrivals, ancestors, pull) -> int:
        """`step`'s passes for a beam search while few nodes are live (`beam._beam_step_py`);
        returns the survivors."""
        _reset_costs(self._state_new, self._live_before, self._n_live_before)
        kernel = _beam_step if self._kernels is _THREADED else _beam_step_serial
        row = (self.first + self.used) % self.arrivals.shape[0]  # (arrivals is this row)
        written = self._row_written_nodes[row]  # (the only entries an earlier beam step left set)
        clear = written is None or written.shape[0] * self.ROW_RESET_SHARE > self.N  # (then a fill is cheaper)
        live, low = kernel(
            self._live,
            self._n_live,
            self._out_start,
            self._out_dst,
            self.allowed,
            self._immortal,
            self._marks,
            self._marks_words,
            self._sources,
            self._touched,
            self._total,
            self._survives,
            self._live_before,
            self.incoming,
            self.edge_src,
            self.edge_reading,
            self.edge_kind,
            self.edge_offset,
            self.edge_heading,
            self.edge_turn,
            self._readings,
            self._meas,
            self._mask,
            self._scale,
            wa,
            wp,
            wh,
            use_pos,
            use_head,
            meas_pos[0],
            meas_pos[1],
            meas_heading,
            self.placed,
            self.beam,
            self.state,
            self.det,
            self._state_new,
            self._det_new,
            arrivals,
            self.none,
            clear,
            self._no_reset if clear else written,
            *ancestors,
            self._beam_low,
            pull,
        )
        self._live, self._live_before = self._live_before, self._live
        self._n_live, self._n_live_before = live, self._n_live
        self._row_written_nodes[row] = self._live[:live].copy()  # (a bound may only set more of them to none)
        if live:
            self.low = low
        self._c32_stale = True
        return live

    def _cut(self, arrivals) -> int:
        """A beam search's cut after an exact step (`beam._beam_prune`); returns the survivors."""
        c32 = self.c32 if self.float32_pass else self._no_c32  # (swapped in by the step already)
        none = arrivals.dtype.type(self.none)  # (the arrivals' own type, for a select)
        live, low = _beam_prune(self._state_new, self._immortal, self.beam, arrivals, none, c32, self._live_before)
        self._live, self._live_before = self._live_before, self._live
        self._n_live, self._n_live_before = live, self._n_live
        self.low = low
        return live

    def _bound(self, arrivals) -> int:
        """The live paths cut to the `max_live` cheapest (`beam._bound_live`); returns
        their number."""
        c32 = self.c32 if self.float32_pass else self._no_c32
        none = arrivals.dtype.type(self.none)
        self._n_live = _bound_live(
            self._state_new, self._live, self._n_live, int(self.max_live), self._immortal, arrivals, none, c32
        )
        return self._n_live

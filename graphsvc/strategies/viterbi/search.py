"""The incremental Viterbi search over a motion graph (Kelly et al. 2013, §4–5):
`ViterbiSearch`, used alike by the batch search (`batch`) and the streaming decoders
(`stream`).

State = graph node. At each input sample every path advances along one edge, and each
node keeps the best path arriving there (the cost terms: `costs`; the step's passes:
`dense`, or `beam` for a beam search, driven by `beam_search.BeamSteps`).

Memory (§5.1, after Abbasfar and Yao): the back-pointers are kept as a dense ring of
the newest rows and a survivor store of what live paths still pass through, traced back
from the best node (`survivors.SurvivorMemory`, which the search is made of).

Speed: a step is bound by scattered reads of the source nodes' state, so each node's
best edge is chosen in float32 and the chosen path's cost recomputed in float64
(near-ties decided again in float64), C_A is computed once per distinct reading per
sample, the placement is carried only when position or heading counts, and edges are
visited in slot-major order. The search's memory layout and what each choice measured
are in docs/search.md.
"""

from __future__ import annotations

import time

import numpy as np

from graphsvc.errors import InputError
from graphsvc.graph.model import MotionGraph
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.sensors.orientation import normalised_rows
from graphsvc.strategies.options import Weights
from graphsvc.strategies.threads import StepTimer
from graphsvc.strategies.viterbi.beam import _best_in_list
from graphsvc.strategies.viterbi.beam_search import BeamSteps
from graphsvc.strategies.viterbi.costs import (
    COS,
    COST,
    DEAD32,
    HEADING,
    PLACED_WIDTH,
    SIN,
    UNPLACED_WIDTH,
    X,
    Z,
    _reading_costs_batch,
    _reading_costs_batch_serial,
    pull_row,
    track_pull,
)
from graphsvc.strategies.viterbi.dense import _SERIAL, _THREADED, _best_in_chunks, _best_node, _satisfied
from graphsvc.strategies.viterbi.survivors import SurvivorMemory
from graphsvc.strategies.viterbi.tables import search_index


class ViterbiSearch(BeamSteps, SurvivorMemory):
    """Incremental search: `start(first sample)`, `step(sample)` per sample, then
    `trace(best_node())`. Used by the batch search and by streaming decoders alike.

    Samples: acc (S, 3) m/s² (NaN = missing), position (2,) m or NaN, heading rad or NaN."""

    def __init__(
        self,
        graph: MotionGraph,
        weights: Weights = Weights(),
        gamma: int = 0,
        allowed: np.ndarray | None = None,
        threads: bool = True,
        placed: bool | None = None,
        window: int | None = None,
        ring: tuple[int, int] | None = None,
        beam: float | None = None,
        pull_s: float | None = None,
        oriented: bool = False,
    ):
        """allowed: (N,) bool, nodes the search may use (None: all); masked nodes are
        never entered, which is how leave-one-out evaluation hides a clip. threads:
        spread each step over numba's threads (one search at a time) or not (many
        searches in parallel, e.g. a server's streams). placed: carry each path's
        ground placement (needed for position and heading costs); default: when the
        position or heading weight is non-zero. Without it, position and heading
        measurements are ignored and a step skips the placement passes. window: keep
        only the back-pointers of the last `window` samples or more, dense, and no
        survivor store — for a fixed-lag decoder, which never traces back further
        (traces must start inside the window). It saves the store's appends and sweeps
        for (window + BLOCK) × N bytes. None: the survivor store, any trace. ring:
        (BLOCK, STORE_WINDOW) instead of the class's (a warm-up makes the rarely run
        walk-back kernels run within a few samples). beam: keep only the paths whose
        cost is within this much of the best one's after each sample (see
        `beam._beam_step_py`), and visit only the nodes they reach — faster, but the path is
        no longer always the cheapest (None: the exact search; no constraint sets; inf:
        the exact search's results by the beam's step). Weights must be finite and ≥ 0
        (InputError); the float32 pass serves searches without constraint sets whose
        weights are at most 1e6 and whose nodes have fewer than 4,096 incoming edges,
        the float64 passes the rest, with the same results. pull_s: the time constant
        (s) with which each path's placement is pulled toward the measured positions
        (`costs.track_pull`; None or 0: placed once, at the start). oriented: weigh
        measured sensor orientations (the samples' `up`) by W_R, riding in the C_A
        kernels (`costs`: C_R); needs W_R > 0 and the graph's orientation metadata
        (`graph.edge_up`), else InputError."""
        self.graph = graph
        self._timer = StepTimer()  # (whether a step that may use the threads does)
        self.threads = threads
        if not all(
            np.isfinite(w) and w >= 0 for w in (weights.acc, weights.position, weights.heading, weights.orientation)
        ):
            raise InputError(f"weights must be finite and ≥ 0, got {weights}")
        self.weights = weights
        self.oriented = bool(oriented)
        if self.oriented and not weights.orientation > 0:
            raise InputError("an oriented search needs an orientation weight > 0")
        # The weight of the per-reading value the C_A kernels compute: W_A·(C_A + (W_R/W_A)·C_R),
        # or, at W_A = 0 in an oriented search, W_R·C_R (see `measurements`).
        self.w_reading = float(weights.acc) if not self.oriented or weights.acc > 0 else float(weights.orientation)
        if pull_s is not None and not (np.isfinite(pull_s) and pull_s >= 0):
            raise InputError(f"track pull must be a finite number of seconds ≥ 0, got {pull_s!r}")
        self.pull_s = pull_s
        self.pull_alpha = track_pull(pull_s, graph.rate_hz)
        self.placed = bool(weights.position != 0 or weights.heading != 0) if placed is None else bool(placed)
        N = graph.num_nodes
        self.N = N
        self.gamma = gamma
        self.index = search_index(graph, self.oriented)  # (the graph's tables, made once and shared)
        tables = self.index.tables
        self.edge_src = tables["edge_src"]
        self.edge_kind = tables["edge_kind"]
        self.edge_offset = tables["edge_offset"]
        self.edge_heading = tables["edge_heading"]
        self.edge_turn = tables["edge_turn"]
        self.readings_t = tables["readings_t"]
        self.edge_reading = tables["edge_reading"]
        c = graph.node_contacts
        self.contact_code = c[:, 0].astype(np.int64) | (c[:, 1].astype(np.int64) << 1)
        self.label = np.ascontiguousarray(graph.node_label, dtype=np.int64)
        P = N if self.placed else 1  # unplaced searches pass a dummy row to the kernels
        width = PLACED_WIDTH if self.placed else UNPLACED_WIDTH
        self.state, self._state_new = np.zeros((N, width)), np.zeros((N, width))  # (see COST…SIN)
        self.det, self._det_new = np.zeros(N, dtype=np.int32), np.zeros(N, dtype=np.int32)  # detour counts
        self.rank, self._rank_new = np.zeros((N, gamma), dtype=np.int32), np.zeros((N, gamma), dtype=np.int32)
        self.rel = np.zeros((P, 4), dtype=np.float32)
        # The float32 pass and float64 fix-ups (see `dense._approx_select_py`) for searches
        # without constraint sets; constrained ones keep the float64 passes (rank first).
        # bits for an arrival index < max in-degree, and all ones (which none is) marking a near-tie
        label_bits = max(int(np.diff(tables["incoming"]).max(initial=0)), 1).bit_length()
        # (weights ≤ 1e6 keep every live float32 total far from overflow)
        heaviest = max(weights.acc, weights.position, weights.heading, weights.orientation if self.oriented else 0.0)
        self.float32_pass = gamma == 0 and label_bits <= 12 and heaviest <= 1e6
        self.near_ties = 0  # nodes whose choice the float64 rule settled (a check on the bound's width)
        if self.float32_pass:
            self._keep = np.uint32(0xFFFFFFFF ^ ((1 << label_bits) - 1))
            self._label_mask = np.uint32((1 << label_bits) - 1)
            self._alpha = 2.0**-20 + 2.0 ** (label_bits - 22)
            self._best32, self._second32 = np.empty(N, np.float32), np.empty(N, np.float32)
            self._best_bits = self._best32.view(np.uint32)  # pass 2 reads the labels through it
            pass1 = self.index.float32
            self.node_pos = tables["node_pos"]
            self._pass1 = tuple(
                pass1[k]
                for k in (
                    "chunk_nodes",
                    "shared_slots",
                    "shared_src",
                    "shared_arrival",
                    "shared_offset",
                    "shared_heading",
                    "own_bounds",
                    "own_src",
                    "own_reading",
                    "own_pos",
                    "own_arrival",
                    "own_offset",
                    "own_heading",
                )
            )
            # unsigned views of the index tables pass 2 reads (see `dense._approx_select_py`)
            self._unsigned = {
                "incoming": tables["incoming"].view(np.uint32),
                "edge_src": tables["edge_src"].view(np.uint32),
                "edge_reading": tables["edge_reading"].view(np.uint32),
            }
            self._chunk_nodes = pass1["chunk_nodes"]
            self._chunk_low = np.empty(len(self._chunk_nodes) - 1)
            self._chunk_high = np.empty_like(self._chunk_low)
            self.c32 = np.zeros(N if not self.placed else 1, dtype=np.float32)
            self._c32_new = np.zeros_like(self.c32)
        else:
            self.slots = tuple(
                self.index.slots[k]
                for k in (
                    "chunk_nodes",
                    "chunk_slots",
                    "slot_dst",
                    "slot_src",
                    "slot_kind",
                    "slot_edge",
                    "slot_reading",
                    "slot_offset",
                    "slot_heading",
                )
            )
            self.total = np.full(graph.num_edges + 1, np.inf)  # slot order; total[E] = inf (no candidate)
            self.best_slot = np.full(N, graph.num_edges, dtype=np.int64)
        self.low = 0.0  # lowest live cost (the float32 costs' base)
        self._chunks_t = -1  # the sample the chunks' lowest and highest costs describe (−1: none)
        self.c32_base = 0.0  # what c32 is relative to
        self.reading_cost = np.zeros(self.readings_t.shape[1], dtype=np.float32)
        self._meas = np.zeros(self.readings_t.shape[0], dtype=np.float32)
        self._mask = np.ones(self.readings_t.shape[0], dtype=np.float32)
        self._scale = np.float32(1.0)  # (see `_set_measurement`)
        self.ok = np.ones((gamma, N), dtype=bool)
        if allowed is None:
            self.allowed = np.ones(N, dtype=bool)
        else:
            self.allowed = np.ascontiguousarray(allowed, dtype=bool)
            if self.allowed.shape != (N,):
                raise InputError(f"node mask must have {N} entries, got {self.allowed.shape}")
            if not self.allowed.any():
                raise InputError("the node mask leaves no node to search")
        if self.float32_pass:
            self._allowed_pos = np.empty(N, dtype=bool)  # in the float32 pass's layout order
            self._allowed_pos[self.node_pos] = self.allowed
        self._init_beam(beam, gamma, tables)
        self._c32_stale = False  # (see `_rebase_c32`)
        self.incoming = tables["incoming"]
        self._best_edge = np.full(N, -1, dtype=np.int32)
        self._init_memory(N, window, ring)
        self._init_row_resets()
        self.t = -1

    @property
    def threads(self) -> bool:
        """Whether steps may spread over numba's threads (see __init__); those that may
        use them where they are faster (`strategies.threads.StepTimer`: not on a busy
        machine). May change between steps — a server gives them to a stream while it
        is the only one running — without changing any result: both kinds of kernel
        compute the same values."""
        return self._may_thread

    @threads.setter
    def threads(self, on: bool) -> None:
        self._may_thread = bool(on)
        self._kernels = _THREADED if on and self._timer.current else _SERIAL

    @property
    def cost(self) -> np.ndarray:
        """(N,) float64 each node's best path's cost (inf: none alive), a view."""
        return self.state[:, COST]

    @property
    def place(self) -> np.ndarray | None:
        """(N, 5) float64 each node's best path's placement (x, z m, heading rad, its
        cos, sin), a view; None when the search is not placed."""
        return self.state[:, X : SIN + 1] if self.placed else None

    @property
    def live_entries(self) -> int:
        """Store rows in use (survivors plus garbage not yet collected)."""
        return self.size

    def start(self, position=None, heading=None, kinds_t=None, values_t=None, live=None):
        """Sample 0: every node starts a path at the measured position / heading; one
        not measured yet is taken from the first sample that has it (see `_anchor`).
        live: (N,) bool, the nodes whose paths start (allowed ones; None: every allowed
        node), e.g. a beam search's `seed`."""
        starts = self.allowed if live is None else np.asarray(live, dtype=bool) & self.allowed
        if not starts.any():
            raise InputError("no allowed node to start a path at")
        self.t = 0
        self.anchor_position = None  # every path's start, once measured: (2,) m
        self.anchor_heading = None  # rad
        # Every path starts at the same placement: one row, anchored, then copied to the
        # paths' rows (a seeded start's alone: no other row is read until it is written).
        place = np.zeros((1, PLACED_WIDTH))
        place[0, COS] = 1.0
        self._anchor(position, heading, place)
        if self.placed:
            rows = slice(None) if live is None else starts
            self.state[rows, X : SIN + 1] = place[0, X : SIN + 1]
        self.state[:, COST] = np.where(starts, 0.0, np.inf)
        self.det[:] = 0
        if self.beam is not None:
            live = np.flatnonzero(starts)
            self._live[: len(live)], self._n_live, self._n_live_before = live, len(live), 0
            self._state_new[:, COST] = np.inf
        self._c32_stale = False
        self.low = self.c32_base = 0.0
        self._chunks_t = -1
        if self.float32_pass and not self.placed:
            self.c32[:] = np.where(starts, np.float32(0.0), DEAD32)
        if self.gamma:
            _satisfied(kinds_t, values_t, self.contact_code, self.label, self.ok)
            self.rank[:] = (~self.ok).T
        self._start_memory(starts)

    def seed(self, acc, most: int, up=None) -> np.ndarray:
        """(N,) bool: where a search bounded to `most` live paths starts, from the
        sample after its first (accelerations (S, 3) m/s², up as `step`'s): the sources
        of the `most` edges between allowed nodes whose readings cost least against it
        (C_A, and C_R when oriented; ties to the lower edge). Every path starts at the
        same place, so the first step's costs differ by little but these; a beam search
        so seeded visits the edges out of at most `most` nodes at its first step instead
        of every node's (the same nodes survive a first step bounded to `most` but for
        what the position and heading terms move). Every allowed source when fewer
        edges are allowed."""
        src = self.edge_src
        usable = self.allowed[src] & self.allowed[self.graph.edge_dst]
        cost = self.reading_costs(
            np.asarray(acc, dtype=np.float64)[None], up=None if up is None else np.asarray(up)[None]
        )[0][self.edge_reading]
        cost = np.where(usable, cost, np.inf)
        out = np.zeros(self.N, dtype=bool)
        if int(usable.sum()) <= most:
            out[src[usable]] = True
            return out
        cheapest = np.argpartition(cost, most - 1)[:most]
        kth = cost[cheapest].max()
        below = np.flatnonzero(cost < kth)  # (ties at the most-th cost: the lowest edges)
        ties = np.flatnonzero(cost == kth)[: most - below.size]
        out[src[below]] = True
        out[src[ties]] = True
        return out

    def _anchor(self, position, heading, place=None) -> None:
        """Until a position (a heading) has been measured, paths run from the origin
        (facing +Z) and no position (heading) term has counted, so the first one
        measured can become every path's start: all placements are turned about the
        start by the heading and moved onto the position, rigidly — the same as if the
        search had started there (as a batch search given them at sample 0 does).
        place: the placement rows to move (default: the paths', a beam search's live
        ones alone)."""
        rows = None
        if place is None and not self.placed:
            place = np.zeros((1, PLACED_WIDTH))  # (unplaced: only noted)
        elif place is None and self.beam is not None and self._n_live < self.N:
            rows = self._live[: self._n_live]
            place = self.state[rows]
        elif place is None:
            place = self.state
        self._move_placements(place, position, heading)
        if rows is not None:
            self.state[rows] = place

    def _move_placements(self, place, position, heading) -> None:
        """`_anchor`'s move of the placement rows place (n, W), in place."""
        if self.anchor_heading is None and heading is not None and np.isfinite(heading):
            self.anchor_heading = h = float(heading)
            ax, az = (0.0, 0.0) if self.anchor_position is None else self.anchor_position
            c, s = np.cos(h), np.sin(h)
            dx, dz = place[:, X] - ax, place[:, Z] - az
            place[:, X], place[:, Z] = ax + c * dx + s * dz, az - s * dx + c * dz
            cos, sin = place[:, COS].copy(), place[:, SIN].copy()
            place[:, HEADING] += h
            place[:, COS], place[:, SIN] = cos * c - sin * s, sin * c + cos * s
        if self.anchor_position is None and position is not None and np.all(np.isfinite(position)):
            self.anchor_position = p = (float(position[0]), float(position[1]))
            place[:, X] += p[0]
            place[:, Z] += p[1]

    @property
    def start_placement(self) -> tuple[np.ndarray, float]:
        """Where every path starts: ground position (2,) m and heading rad (the origin and
        +Z for what has not been measured yet)."""
        p = np.zeros(2) if self.anchor_position is None else np.asarray(self.anchor_position, dtype=np.float64)
        return p, 0.0 if self.anchor_heading is None else self.anchor_heading

    def step(self, acc, position=None, heading=None, kinds_t=None, values_t=None, reading_cost=None, up=None):
        """Advance by one sample. reading_cost: this sample's row of `reading_costs`,
        when a batch caller computed it ahead (else it is computed here). up: (S, 3)
        the sensors' measured "up" vectors (an oriented search; None or NaN: missing)."""
        if (self.anchor_position is None and position is not None) or (
            self.anchor_heading is None and heading is not None
        ):
            self._anchor(position, heading)
        self._make_room()
        self.t += 1
        arrivals = self._free_row()
        if self.gamma:
            _satisfied(kinds_t, values_t, self.contact_code, self.label, self.ok)
        w = self.weights
        wa, wp, wh = self.w_reading, float(w.position), float(w.heading)
        use_pos = self.placed and wp != 0.0 and position is not None and bool(np.all(np.isfinite(position)))
        use_head = self.placed and wh != 0.0 and heading is not None and bool(np.isfinite(heading))
        narrow = self.narrow
        if not narrow:
            self._row_filled()
        timed = self._may_thread and not narrow  # (narrow beam steps: too short to time)
        if timed:
            threaded = self._timer.choose()
            self._kernels = _THREADED if threaded else _SERIAL
            step_started = time.perf_counter()
        reading_costs, relative, edge_totals, select, advance, approx_select, finish = self._kernels
        if self.beam is not None:
            started, live_before = time.perf_counter(), self._n_live
        if narrow:
            self._set_measurement(acc, up)  # (a narrow beam step computes the C_A it reads from it)
        elif reading_cost is None:
            # Computed even at W_A = 0: the report carries each path's accelerometer cost.
            self._set_measurement(acc, up)
            if self._scale:
                reading_costs(self.readings_t, self._meas, self._mask, self._scale, self.reading_cost)
            else:
                self.reading_cost[:] = 0.0
            reading_cost = self.reading_cost
        # Placed searches read their sources' relative rows (which hold the float32 cost)
        # every sample, whether or not this sample's position or heading counts.
        rows = self.placed and (self.float32_pass or use_pos or use_head)
        meas_pos = np.asarray(position, dtype=np.float64) if use_pos else np.zeros(2)
        meas_heading = float(heading) if use_head else 0.0
        pull = pull_row(self.pull_alpha, meas_pos, use_pos)
        ancestors = self._ancestors()
        if rows and not narrow:
            relative(self.state, meas_pos, meas_heading, self.low, self.rel)
        if narrow:
            live = self._beam_step(wa, wp, wh, use_pos, use_head, meas_pos, meas_heading, arrivals, ancestors, pull)
        elif self.float32_pass:
            if self._c32_stale and not self.placed:  # (narrow beam steps leave the unplaced float32 costs behind)
                self._rebase_c32()
            u = self._unsigned
            base = self.low if rows else self.c32_base  # what the float32 costs read are relative to
            approx_select(
                *self._pass1,
                reading_cost,
                np.float32(wa),
                np.float32(wp if use_pos else 0.0),
                np.float32(wh if use_head else 0.0),
                rows,
                self.c32,
                self.rel,
                self._keep,
                self._allowed_pos,
                self._alpha,
                2.0**-48 * base + 1e-30,
                self._best32,
                self._second32,
            )
            # (unplaced: the cost column alone, 1-D — see `costs._cost_at`)
            state, state_new = (self.state, self._state_new) if self.placed else (self.cost, self._state_new[:, COST])
            live, near_ties = finish[self.placed](
                self._chunk_nodes,
                self.node_pos,
                self._best32,
                self._best_bits,
                self._label_mask,
                u["incoming"],
                u["edge_src"],
                u["edge_reading"],
                self.edge_kind,
                self.edge_offset,
                self.edge_heading,
                self.edge_turn,
                reading_cost,
                wa,
                wp,
                wh,
                use_pos,
                use_head,
                meas_pos[0],
                meas_pos[1],
                meas_heading,
                state,
                self.det,
                self.low,
                state_new,
                self._det_new,
                self._c32_new,
                arrivals,
                self.none,
                self._chunk_low,
                self._chunk_high,
                *ancestors,
                pull,
            )
            self.near_ties += near_ties
            if live:
                self.c32_base, self.low = self.low, float(self._chunk_low.min())
                self._chunks_t = self.t
                self.c32, self._c32_new = self._c32_new, self.c32
        else:
            (
                chunk_nodes,
                chunk_slots,
                slot_dst,
                slot_src,
                slot_kind,
                slot_edge,
                slot_reading,
                slot_offset,
                slot_heading,
            ) = self.slots
            edge_totals(
                slot_src,
                slot_reading,
                slot_offset,
                slot_heading,
                reading_cost,
                wa,
                wp,
                wh,
                use_pos,
                use_head,
                self.state,
                self.rel,
                self.total,
            )
            select(
                chunk_nodes,
                chunk_slots,
                slot_dst,
                slot_src,
                slot_kind,
                slot_edge,
                self.total,
                self.allowed,
                self.det,
                self.rank,
                self.best_slot,
                self._state_new,
                self._best_edge,
            )
            live = advance(
                self._best_edge,
                self.incoming,
                self.edge_src,
                self.edge_kind,
                self.edge_offset,
                self.edge_heading,
                self.edge_turn,
                self.ok,
                self.placed,
                self.state,
                self.det,
                self.rank,
                self._state_new,
                self._det_new,
                self._rank_new,
                arrivals,
                self.none,
                *ancestors,
                pull,
            )
        if self.beam is not None:
            if not narrow and live:
                live = self._cut(arrivals)
            if self.max_live is not None and live > self.max_live:
                live = self._bound(arrivals)
            self._time_beam_step(narrow, time.perf_counter() - started, live_before)
        if timed:
            self._timer.record(threaded, time.perf_counter() - step_started)
        if live == 0:
            raise InputError(f"no graph path reaches sample {self.t}: every path ran into a dead end")
        self._row_written()
        # Swap buffers: the new state becomes the previous one.
        self.state, self._state_new = self._state_new, self.state
        self.det, self._det_new = self._det_new, self.det
        self.rank, self._rank_new = self._rank_new, self.rank

    def _rebase_c32(self) -> None:
        """The unplaced float32 pass's costs from the cost column, relative to the
        lowest live cost (any base at most every live cost keeps the pass's bound)."""
        cost = self.cost
        live = np.isfinite(cost)
        self.c32[:] = DEAD32
        self.c32[live] = (cost[live] - self.low).astype(np.float32)
        self.c32_base = self.low
        self._c32_stale = False

    def measurements(self, acc, up=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Accelerations (B, S, 3) m/s² → the kernels' measurement vectors (B, 3S)
        float32 in g, masks (B, 3S) float32 and the sensors present (B,): a sensor with
        any NaN axis is left out (Kelly et al. 2013, eq. 4 averages over sensors present).
        An oriented search's also carry up (B, S, 3), the sensors' measured "up"
        vectors (normalised; None or NaN: missing), as 3S more axes (B, 6S) whose mask
        is ρ = √((W_R / W_A)·(n / n_R)), and "present" is n, the count the kernels'
        scale 1 / n divides by: n_A, the accelerometers present, or n_R where none is;
        so scale·Σ((r − m)·mask)² = C_A + (W_R / W_A)·C_R. At W_A = 0 the accelerometer
        axes are masked off and ρ = 1 (the search weighs the value by W_R: `w_reading`)."""
        meas, mask, present = self.acc_measurements(acc)
        if not self.oriented:
            return meas, mask, present
        B, S = meas.shape[0], meas.shape[1] // 3
        W = self.graph.edge_up.shape[-1]  # the graph's orientation cue (`sensors.orientation`)
        u = np.full((B, S, W), np.nan) if up is None else np.asarray(up, dtype=np.float64).reshape(B, S, W)
        u, valid = normalised_rows(u)
        n_r = valid.sum(axis=1).astype(np.float64)
        w = self.weights
        acc_on = w.acc > 0
        n = np.where(acc_on & (present > 0), present, n_r)
        rho = np.sqrt(np.where(n_r > 0, (w.orientation / self.w_reading) * n / np.maximum(n_r, 1.0), 0.0))
        meas = np.concatenate([meas, u.reshape(B, -1).astype(np.float32)], axis=1)
        mask = np.concatenate(
            [mask * np.float32(acc_on), np.repeat(valid * rho[:, None], W, axis=1).astype(np.float32)], axis=1
        )
        return meas, mask, n.astype(present.dtype)

    @staticmethod
    def acc_measurements(acc) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`measurements` of the accelerations alone: (B, 3S) in g, masks, sensors present."""
        a = np.asarray(acc, dtype=np.float32)
        a = a.reshape(len(a), -1, 3)
        valid = np.isfinite(a).all(axis=-1)
        # float32(m/s²) / g in float64, rounded once — exactly as the readings table.
        g = (a.astype(np.float64) / GRAVITY).astype(np.float32)
        meas = np.where(valid[..., None], g, np.float32(0.0)).reshape(len(a), -1)
        mask = np.repeat(valid, 3, axis=1).astype(np.float32)
        return meas, mask, mask.sum(axis=1) / 3.0

    def reading_costs(self, acc, measured=None, up=None) -> np.ndarray:
        """C_A (B, R) float32 in g² of every distinct edge reading for B samples of
        accelerations (B, S, 3) m/s² at once (see `costs._reading_costs_batch_py`);
        measured: their `measurements`, when the caller has them already."""
        meas, mask, present = self.measurements(acc, up) if measured is None else measured
        B = len(meas)
        scale = np.where(present > 0, 1.0 / np.maximum(present, 1.0), 0.0).astype(np.float32)
        out = np.empty((B, self.readings_t.shape[1]), np.float32)
        kernel = _reading_costs_batch if self._kernels is _THREADED else _reading_costs_batch_serial
        kernel(self.readings_t, meas, mask, scale, out)
        return out

    def _set_measurement(self, acc, up=None) -> None:
        """One sample's accelerations (S, 3) m/s² (and up vectors) → self._meas,
        self._mask (see `measurements`) and self._scale, float32 1 / sensors present (0: none)."""
        meas, mask, present = self.measurements(np.asarray(acc)[None], None if up is None else np.asarray(up)[None])
        self._meas[:], self._mask[:] = meas[0], mask[0]
        self._scale = np.float32(1.0 / float(present[0])) if present[0] else np.float32(0.0)

    @property
    def alive(self) -> np.ndarray:
        return np.isfinite(self.cost)

    def best_node(self) -> int:
        """The live node whose path ranks first: fewest broken constraints, then cost
        (within TIE counts as equal), then fewer non-original edges, then lower node id."""
        if self.beam is not None:
            return int(_best_in_list(self.state, self.det, self._live, self._n_live))
        if self._chunks_t == self.t:  # (the float32 pass's steps: γ = 0)
            return int(_best_in_chunks(self.state, self.det, self._chunk_nodes, self._chunk_low, self._chunk_high))
        return int(_best_node(self.state, self.rank, self.det))

"""The survivor store and the walks back through the dense lattice rows
(Kelly et al. 2013, §5.1, after Abbasfar and Yao: a memory-reduced Viterbi).

A search keeps its newest samples' lattice rows dense — one byte a node: which of its
incoming edges its best path arrived by — in a ring. When the ring is full
(`search.ViterbiSearch._flush`), `_block_levels` walks back from every live node
through all rows and `_append_block` moves the oldest rows' points that some live
path passes through into the store; `_collect` sweeps the store when it has doubled;
`_trace` reads a path back through the ring and the store. Dense-window searches (a
fixed-lag decoder) drop old rows instead and only ask `_converged_row` where the live
paths agree.
"""

from __future__ import annotations

import numba
import numpy as np

from graphsvc.strategies.viterbi.costs import COST

# Survivor store: rows of one (capacity, 4) int32 array — node, edge used to arrive,
# parent row, sample. Rows are appended a block at a time in sample order, so a parent
# always precedes its children and garbage collection is one backward sweep.
NODE, EDGE, PARENT, TIME = 0, 1, 2, 3


# The walks back list each row's nodes: its predecessors are marked in a byte map and
# listed by scanning it while they are more than 1 / SPARSE_SHARE of the nodes (or 16),
# then deduplicated as a list (the byte map only telling repeats apart) and sorted only
# where the flush lists them. On G_E a flush walks 256 rows, all but the newest few
# with 1–8 nodes: 3.1 ms against 9.5 scanning the whole map for each row while marking
# the next; on the built kelly6 graph, whose paths stay apart for longer, 0.28 against
# 0.48 ms a sample (marking in a loop of its own keeps more writes in flight). Shares
# from 1/256 to 1/16384 measured alike.
SPARSE_SHARE = 256


@numba.njit(inline="always")
def _marked(alive, alive_words, nodes):
    """The nodes marked in the byte map alive (see `_block_levels`), ascending, into
    nodes; clears the map, 8 nodes at a time where none is marked. Returns their count."""
    count = 0
    for w in range(alive_words.shape[0]):
        if alive_words[w] == 0:
            continue
        for n in range(8 * w, 8 * w + 8):
            if alive[n]:
                nodes[count] = n
                count += 1
        alive_words[w] = 0
    return count


@numba.njit(inline="always")
def _predecessors(nodes, count, arrivals, row, incoming, edge_src, alive, few, preds):
    """The distinct predecessors at physical row `row` of nodes[:count], into nodes;
    preds (N,) scratch. Many (count > few): marked in the byte map alive, then listed
    by scanning it, ascending; few: listed as first met, the map only telling repeats
    apart. The map is left clear. Returns (their count, whether ascending)."""
    if count > few:
        for i in range(count):
            n = nodes[i]
            alive[edge_src[incoming[n] + arrivals[row, n]]] = 1
        return _marked(alive, alive.view(np.uint64), nodes), True
    distinct = 0
    for i in range(count):
        n = nodes[i]
        m = edge_src[incoming[n] + arrivals[row, n]]
        if not alive[m]:
            alive[m] = 1
            preds[distinct] = m
            distinct += 1
    for i in range(distinct):
        alive[preds[i]] = 0
        nodes[i] = preds[i]
    return distinct, False


@numba.njit(cache=True, nogil=True)
def _block_levels(arrivals, first, used, flush, incoming, edge_src, alive, level_nodes, level_start, ancestor, state):
    """Walk back from logical row used − 1, one row at a time, to the oldest:
    level_nodes[level_start[k]:level_start[k+1]] are the distinct nodes, ascending,
    that logical row k's surviving paths pass through, listed for the oldest `flush`
    rows (the newer ones are only walked through). The paths alive now (state (N, W)
    with a finite cost) pass through ancestor[n] (N,) at row used − 1. arrivals (R, N)
    the dense window, a ring: logical row k is physical row (first + k) % R; each entry
    is which of the node's incoming edges its best path arrived by, so its predecessor
    is edge_src[incoming[n] + arrival]. alive (N rounded up to 8,) uint8 scratch, zero
    on entry and on return. A row's predecessors are marked in that byte map and
    listed by one sequential scan of it while they are many (the scattered writes land
    in N bytes, which stay in cache); once few (see SPARSE_SHARE), as a list.
    Returns (total, converged_row): converged_row is the highest row walked where a
    single node remains (−1 if none); total = −1 when level_nodes is too small (the
    caller grows it and asks again)."""
    R, N = arrivals.shape
    for n in range(N):
        if state[n, COST] != np.inf:
            alive[ancestor[n]] = 1
    nodes, preds = np.empty(N, np.int32), np.empty(N, np.int32)
    count, ascending = _marked(alive, alive.view(np.uint64), nodes), True
    few = max(N // SPARSE_SHARE, 16)
    end = level_nodes.shape[0]
    pos = end  # filled downwards, newest row first: rows end up in order
    counts = np.zeros(used, np.int64)
    for k in range(used - 1, -1, -1):
        row = (first + k) % R
        if k < flush:
            if pos < count:
                return -1, -1  # (the byte map is clear)
            if not ascending:
                nodes[:count].sort()
            for i in range(count - 1, -1, -1):
                pos -= 1
                level_nodes[pos] = nodes[i]
        counts[k] = count
        if k > 0:
            count, ascending = _predecessors(nodes, count, arrivals, row, incoming, edge_src, alive, few, preds)
    total = end - pos
    level_nodes[:total] = level_nodes[pos:end].copy()
    level_start[0] = 0
    for k in range(flush):
        level_start[k + 1] = level_start[k] + counts[k]
    converged_row = -1
    for k in range(used):
        if counts[k] == 1:
            converged_row = k
    return total, converged_row


@numba.njit(cache=True, nogil=True)
def _converged_row(arrivals, first, used, lowest, incoming, edge_src, none, alive, live):
    """`_block_levels` without the lists, for the dense-window mode: the highest logical
    row in [lowest, used) where the paths of every node alive at the newest row pass
    through a single node, or −1. Stops there (every older row then holds one node too).
    live: the nodes alive at the newest row, ascending, when the caller knows them (a
    beam search's live list: the walk then costs what they are, not N); empty: found by
    scanning the row."""
    R, N = arrivals.shape
    top = (first + used - 1) % R
    if live.shape[0]:
        count = live.shape[0]
        nodes, preds = live.astype(np.int32), np.empty(count, np.int32)
    else:
        nodes, preds = np.empty(N, np.int32), np.empty(N, np.int32)
        count = 0
        for n in range(N):
            if arrivals[top, n] != none:
                nodes[count] = n
                count += 1
    few = max(N // SPARSE_SHARE, 16)
    for k in range(used - 1, lowest - 1, -1):
        if count == 1:
            return k
        if k > lowest:
            count, _ = _predecessors(nodes, count, arrivals, (first + k) % R, incoming, edge_src, alive, few, preds)
    return -1


@numba.njit(cache=True, nogil=True)
def _append_block(
    arrivals, first, flush, t_first, incoming, edge_src, heads, store, size, level_nodes, level_start, row_of
):
    """Append the surviving lattice points (see `_block_levels`) of the window's
    oldest `flush` rows (samples t_first…) to the store in sample order; heads (N,):
    each node's store row at the sample before them on entry, at their last sample on
    return (−1: no surviving path passes). row_of (N,) scratch. Returns the new size."""
    R = arrivals.shape[0]
    for k in range(flush):
        row = (first + k) % R
        for i in range(level_start[k], level_start[k + 1]):
            n = level_nodes[i]
            e = incoming[n] + arrivals[row, n]
            m = edge_src[e]
            store[size, NODE] = n
            store[size, EDGE] = e
            store[size, PARENT] = heads[m] if k == 0 else row_of[m]
            store[size, TIME] = t_first + k
            size += 1
        # row_of now refers to row k (read by row k+1); a node appears once per row.
        for i in range(level_start[k], level_start[k + 1]):
            row_of[level_nodes[i]] = size - (level_start[k + 1] - i)
    heads[:] = -1
    for i in range(level_start[flush - 1], level_start[flush]):
        heads[level_nodes[i]] = row_of[level_nodes[i]]
    return size


@numba.njit(cache=True, nogil=True)
def _collect(store, size, heads, keep_from):
    """Keep only rows some live head reaches, from sample keep_from on (earlier ones
    are forgotten: a kept row whose parent is forgotten gets parent −1); renumber
    parents and heads. Returns the new size."""
    keep = np.zeros(size, np.bool_)
    for n in range(heads.shape[0]):
        if heads[n] >= 0 and store[heads[n], TIME] >= keep_from:
            keep[heads[n]] = True
    for i in range(size - 1, -1, -1):
        if keep[i] and store[i, PARENT] >= 0 and store[store[i, PARENT], TIME] >= keep_from:
            keep[store[i, PARENT]] = True
    new_row = np.empty(size, np.int32)  # store rows are int32 throughout
    j = 0
    for i in range(size):
        if keep[i]:
            new_row[i] = j
            p = store[i, PARENT]
            store[j, NODE] = store[i, NODE]
            store[j, EDGE] = store[i, EDGE]
            store[j, PARENT] = new_row[p] if p >= 0 and keep[p] else -1
            store[j, TIME] = store[i, TIME]
            j += 1
    for n in range(heads.shape[0]):
        if heads[n] >= 0:
            heads[n] = new_row[heads[n]] if keep[heads[n]] else -1
    return j


@numba.njit(cache=True, nogil=True)
def _converged_until(store, size, t_from, t_to):
    """The last sample in [t_from, t_to] up to which every sample has exactly one row
    (all survivors agree), or t_from − 1. Rows are in sample order."""
    counts = np.zeros(t_to - t_from + 1, np.int64)
    for i in range(size):
        tt = store[i, TIME]
        if t_from <= tt <= t_to:
            counts[tt - t_from] += 1
    last = t_from - 1
    for k in range(counts.shape[0]):
        if counts[k] != 1:
            break
        last = t_from + k
    return last


@numba.njit(cache=True, nogil=True)
def _trace(arrivals, first, used, t, heads, incoming, edge_src, store, node, since):
    """Nodes at samples since..t of the path ending at `node` at sample t, and the
    edge each was entered by (−1 at sample 0): through the dense window's rows (the
    newest `used` of the ring, see `_block_levels`), then the store."""
    R = arrivals.shape[0]
    count = t - since + 1
    nodes = np.empty(count, np.int64)
    edges = np.empty(count, np.int64)
    i = count - 1
    n = node
    for k in range(used - 1, -1, -1):
        if i < 0:
            break
        e = incoming[n] + arrivals[(first + k) % R, n]
        nodes[i] = n
        edges[i] = e
        n = edge_src[e]
        i -= 1
    row = heads[n] if i >= 0 else -1
    while i >= 0:
        nodes[i] = store[row, NODE]
        edges[i] = store[row, EDGE]
        row = store[row, PARENT]
        i -= 1
    return nodes, edges

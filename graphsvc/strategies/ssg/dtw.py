"""Subsequence dynamic time warping over the knowledge base, and its local cost.

Local cost (Tautges 2012, eq. 4.3): the distance between an input frame's point cloud
and a knowledge-base frame's, minimised over a rotation about +Y and a translation on
the ground — Kovar et al. 2002's alignment, which has a closed form. Each cloud holds
the markers visible in the input over a short window of frames around the frame
(`index.point_window`, Gaussian weights λ), so one marker still says how it moves.
With the input's cloud centred on its weighted mean, the minimum is

    Σλ|q|² + Σλ|k|² − |Σλk_h|² / Σλ − 2 Σλ q_y k_y − 2 √(A² + B²),
    A = Σλ (q_x k_x + q_z k_z),  B = Σλ (q_x k_z − q_z k_x),

whose sums over the points are products of the input's weighted coordinates with
every frame's (`index.window_points`): one matrix product per block of input frames
for the whole knowledge base (BLAS), then a numba pass that forms the cost. The cost
is divided by Σλ (a weighted mean squared distance, m²); a frame with no marker seen
near it costs 0 everywhere (it says nothing).

Accumulated cost (eq. 4.2): slope bounds [1/2, 2] with the steps (1, 1) and (1, 2) at
weight 1 and (2, 1) at weight 2 (it skips an input frame), any start in the first
row, no path entering a run of frames anywhere but in its first row — a row depends
on the two before it only, and no path crosses into a run, so the knowledge base is cut
at run starts into chunks that threads take whole, through every row. Ties go to the
diagonal step. `classic_dtw` is the unbounded variant (eq. 4.1) with a
Euclidean local cost computed in the loop, for comparison with other implementations.

Written here in numba rather than taken from a package: the weighted steps, the runs
of frames and the per-frame visibility are the product (dtaidistance's subsequence
search has neither; `tools/bench_ssg.py` compares the speed).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import prange

INF = np.inf
START, DIAGONAL, FAST, SLOW = 0, 1, 2, 3  # step into a cell: none, (1, 1), (1, 2), (2, 1)


# ---------------------------------------------------------------- local cost


@numba.njit(parallel=True, cache=True)
def _combine(X, Z, Y, S2, sqq, wsum, allowed, out):
    """out (nb, F) float32 local costs from the products X, Z (F, 3nb), Y, S2 (F, nb)."""
    F = X.shape[0]
    nb = Y.shape[1]
    for m in prange(F):
        for b in range(nb):
            W = wsum[b]
            if not allowed[m]:
                out[b, m] = INF
                continue
            if W <= 0.0:
                out[b, m] = 0.0
                continue
            a = X[m, b] + Z[m, nb + b]
            bb = Z[m, b] - X[m, nb + b]
            kx = X[m, 2 * nb + b]
            kz = Z[m, 2 * nb + b]
            c = sqq[b] + S2[m, b] - (kx * kx + kz * kz) / W - 2.0 * Y[m, b] - 2.0 * math.sqrt(a * a + bb * bb)
            out[b, m] = max(c, 0.0) / W


def query_points(points: np.ndarray, seen: np.ndarray, frames: np.ndarray, taus: np.ndarray, weights: np.ndarray):
    """The input's clouds for input frames `frames`: points (T, M, 3) m, seen (T, M)
    bool → weights w (nb, P), centred coordinates qx, qy, qz (nb, P), Σw|q|² (nb,) and
    Σw (nb,), with P = len(taus) · M ordered (τ, marker) as `index.window_points`."""
    T, M, _ = points.shape
    nb = frames.size
    t = frames[:, None] + np.asarray(taus)[None, :]  # (nb, len(taus))
    inside = (t >= 0) & (t < T)
    tc = np.clip(t, 0, T - 1)
    w = (weights[None, :, None] * (seen[tc] & inside[..., None])).reshape(nb, -1)  # (nb, P)
    p = np.where((seen[tc] & inside[..., None])[..., None], points[tc], 0.0).reshape(nb, -1, 3)
    W = w.sum(axis=1)
    safe = np.where(W > 0, W, 1.0)
    cx = (w * p[..., 0]).sum(axis=1) / safe
    cz = (w * p[..., 2]).sum(axis=1) / safe
    qx = np.where(w > 0, p[..., 0] - cx[:, None], 0.0)
    qy = np.where(w > 0, p[..., 1], 0.0)
    qz = np.where(w > 0, p[..., 2] - cz[:, None], 0.0)
    sqq = (w * (qx * qx + qy * qy + qz * qz)).sum(axis=1)
    return w, qx, qy, qz, sqq, W


def local_costs(kb, points: np.ndarray, seen: np.ndarray, frames: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """(nb, F) float32 local costs (m², module docstring) of input frames `frames` against
    every knowledge-base frame; kb: `index.WindowPoints`; allowed (F,) bool (a hidden
    frame costs inf)."""
    w, qx, qy, qz, sqq, W = query_points(points, seen, np.asarray(frames, dtype=np.int64), kb.taus, kb.weights)
    f32 = lambda a: np.ascontiguousarray(a.T, dtype=np.float32)  # noqa: E731  (P, cols)
    Q = f32(np.concatenate([w * qx, w * qz, w], axis=0))  # (P, 3nb)
    X = kb.x @ Q
    Z = kb.z @ Q
    Y = kb.y @ f32(w * qy)
    S2 = kb.sq @ f32(w)
    out = np.empty((frames.size, kb.x.shape[0]), dtype=np.float32)
    _combine(X, Z, Y, S2, sqq.astype(np.float64), W.astype(np.float64), np.ascontiguousarray(allowed), out)
    return out


# ---------------------------------------------------------------- accumulated cost


def run_chunks(run_start: np.ndarray, parts: int) -> np.ndarray:
    """(P + 1,) boundaries splitting the frames into about `parts` chunks of similar size,
    each starting at a run's first frame (so no warping path crosses into a chunk)."""
    F = run_start.size
    starts = np.flatnonzero(run_start)
    want = np.linspace(0, F, max(1, parts) + 1)[1:-1]
    cut = starts[np.clip(np.searchsorted(starts, want), 0, starts.size - 1)]
    return np.unique(np.concatenate([[0], cut, [F]])).astype(np.int64)


def subsequence_dtw(C, run_start, D, step, bounds=None) -> None:
    """Eq. 4.2 over local costs C (N, F) (module docstring): fills D (N, F) float64 and
    step (N, F) int8 (START, DIAGONAL, FAST, SLOW). run_start (F,) bool: a frame that
    does not follow the one before it. bounds: `run_chunks` (computed when None): each
    thread takes whole chunks through every row, so a window costs one parallel
    region, not one a row, and a chunk's last rows stay in cache."""
    if bounds is None:
        bounds = run_chunks(np.asarray(run_start, dtype=bool), 4 * numba.get_num_threads())
    _subsequence_dtw(C, run_start, bounds, D, step)


@numba.njit(parallel=True, cache=True)
def _subsequence_dtw(C, run_start, bounds, D, step):
    N = C.shape[0]
    for j in prange(bounds.size - 1):
        lo, hi = bounds[j], bounds[j + 1]
        for m in range(lo, hi):
            D[0, m] = C[0, m]
            step[0, m] = START
        for n in range(1, N):
            for m in range(lo, hi):
                c = C[n, m]
                best = INF
                s = START
                if m >= 1 and not run_start[m]:
                    v = D[n - 1, m - 1] + c
                    if v < best:
                        best = v
                        s = DIAGONAL
                    if m >= 2 and not run_start[m - 1]:
                        v = D[n - 1, m - 2] + c
                        if v < best:
                            best = v
                            s = FAST
                    if n >= 2:
                        v = D[n - 2, m - 1] + 2.0 * c
                        if v < best:
                            best = v
                            s = SLOW
                D[n, m] = best
                step[n, m] = s


@numba.njit(cache=True)
def backtrack(step, end, frames):
    """The warping path ending at (N − 1, end): frames (N,) float64 gets each input
    row's knowledge-base frame (a row a SLOW step skips: half-way between its
    neighbours' frames)."""
    n = step.shape[0] - 1
    m = end
    frames[n] = m
    while n > 0:
        s = step[n, m]
        if s == DIAGONAL:
            n -= 1
            m -= 1
        elif s == FAST:
            n -= 1
            m -= 2
        elif s == SLOW:
            frames[n - 1] = m - 0.5
            n -= 2
            m -= 1
        else:
            break
        frames[n] = m


def k_best(D: np.ndarray, step: np.ndarray, k: int, batch: int = 256) -> list[tuple[float, np.ndarray]]:
    """The k cheapest subsequences of the last row of D whose frame ranges do not overlap
    (Müller 2007, §4.4: an end is taken, the ends inside a taken range are skipped, and
    a path that overlaps a taken one — a near duplicate, shifted — is dropped), cheapest
    first: [(cost, frames (N,) float64)]."""
    last = D[-1]
    N = D.shape[0]
    taken: list[tuple[float, float]] = []
    out: list[tuple[float, np.ndarray]] = []
    finite = np.isfinite(last)
    if not finite.any():
        return out
    order_pool = np.flatnonzero(finite)
    values = last[order_pool]
    done = 0
    while len(out) < k and done < order_pool.size:
        want = min(order_pool.size, done + max(batch, 4 * k * N))
        part = np.argpartition(values, want - 1)[:want] if want < order_pool.size else np.arange(order_pool.size)
        part = part[np.lexsort((order_pool[part], values[part]))][done:]
        for p in part:
            end = int(order_pool[p])
            if any(a <= end <= b for a, b in taken):
                continue
            frames = np.empty(N)
            backtrack(step, end, frames)
            a = frames[0]
            if any(not (end < lo or a > hi) for lo, hi in taken):
                continue
            taken.append((a, end))
            out.append((float(last[end]), frames))
            if len(out) == k:
                break
        done = want
    return out


# ---------------------------------------------------------------- plain variants


@numba.njit(cache=True, inline="always")
def _sq_dist(query, n, series, m):
    c = 0.0
    for k in range(query.shape[1]):
        t = query[n, k] - series[m, k]
        c += t * t
    return c


@numba.njit(cache=True)
def classic_dtw(query, series, last):
    """Unbounded subsequence DTW (Tautges 2012, eq. 4.1: steps (1, 1) and (1, 0) at
    weight 2, (0, 1) at weight 1; the first series frame sums its column's costs at
    weight 1) with a squared Euclidean local cost computed in the loop: query (N, d),
    series (F, d) → last (F,): the cost of the best path ending at each series frame.
    Column by column, O(N) memory."""
    N = query.shape[0]
    F = series.shape[0]
    prev = np.empty(N)
    cur = np.empty(N)
    for m in range(F):
        for n in range(N):
            c = _sq_dist(query, n, series, m)
            if n == 0:
                cur[0] = c
            elif m == 0:
                cur[n] = cur[n - 1] + c
            else:
                v = prev[n - 1] + 2.0 * c
                v2 = cur[n - 1] + 2.0 * c
                v3 = prev[n] + c
                cur[n] = min(v, min(v2, v3))
        last[m] = cur[N - 1]
        prev, cur = cur, prev


@numba.njit(cache=True)
def bounded_dtw(query, series, last):
    """Eq. 4.2 with the squared Euclidean local cost computed in the loop (one run):
    query (N, d), series (F, d) → last (F,)."""
    N = query.shape[0]
    F = series.shape[0]
    D = np.full((3, F), INF)  # rows n, n − 1, n − 2 (rolling)
    for n in range(N):
        r, r1, r2 = n % 3, (n + 2) % 3, (n + 1) % 3
        for m in range(F):
            c = _sq_dist(query, n, series, m)
            if n == 0:
                D[r, m] = c
                continue
            best = INF
            if m >= 1:
                best = D[r1, m - 1] + c
                if m >= 2:
                    best = min(best, D[r1, m - 2] + c)
                if n >= 2:
                    best = min(best, D[r2, m - 1] + 2.0 * c)
            D[r, m] = best
    last[:] = D[(N - 1) % 3]

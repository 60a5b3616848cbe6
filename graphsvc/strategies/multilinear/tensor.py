"""Motion tensors: the higher-order SVD, mode products, and time alignment by DTW.

A motion tensor (Tautges 2012, "Reconstruction of Human Motions Based on Low-Dimensional
Control Signals", ch. 2, after Vasilescu & Terzopoulos and De Lathauwer et al. 2000, "A
multilinear singular value decomposition") holds the motion units of one class as
X (V, F, S, R): V values a frame (the technical DOF × joint modes, flattened), F frames
(the frame mode), S styles and R repetitions (the natural modes). The HOSVD gives
X = Φ ×₁ U₁ ×₂ U₂ ×₃ U_S ×₄ U_R, each U_k the left singular vectors of the mode-k
unfolding (numpy: four small eigenproblems, no library earns its place for that).
Truncating a natural mode keeps the fewest leading vectors whose squared singular
values hold a stated share of that unfolding's total (`kept_count`). A motion of the
class is then (eq. 2.3–2.4)

    m(x_S, x_R) = Φ_t ×_S x_S ×_R x_R,   Φ_t = X ×_S U_Sᵀ ×_R U_Rᵀ  (truncated U's),

bilinear in the two coefficient vectors; x_S = U_S[s], x_R = U_R[r] (rows of the
untruncated matrices) give back take (s, r) exactly, and its row weights — how much
of each original unit a motion holds — are (U_S x_S)[s] · (U_R x_R)[r]. (`model`
centres a tensor before its HOSVD and adds the mean unit back.)

DTW (`dtw_path`) is the plain quadratic recurrence over squared Euclidean frame
distances, in numba: a few hundred units of a few dozen frames each a class, where
a library call's overhead would dominate; `warp_onto` puts a unit on its reference's
frames along the path (each reference frame at the mean of the unit frames matched
to it, linearly interpolated).
"""

from __future__ import annotations

import numba
import numpy as np


def unfold(X: np.ndarray, mode: int) -> np.ndarray:
    """The mode-`mode` unfolding of X: (X.shape[mode], product of the others)."""
    return np.moveaxis(X, mode, 0).reshape(X.shape[mode], -1)


def mode_product(X: np.ndarray, M: np.ndarray, mode: int) -> np.ndarray:
    """X ×_mode M: every mode-`mode` vector v of X replaced by M v (M: (n, X.shape[mode]))."""
    return np.moveaxis(np.tensordot(M, X, axes=(1, mode)), 0, mode)


def mode_svd(X: np.ndarray, mode: int) -> tuple[np.ndarray, np.ndarray]:
    """Left singular vectors (d, d) and singular values (d,) of X's mode unfolding
    A (d, n), largest first: the eigenvectors of A·Aᵀ and the roots of its eigenvalues
    (every unfolding here has few rows and many columns; numpy's SVD of the wide
    matrix itself took seconds where this takes milliseconds)."""
    A = unfold(X, mode)
    w, U = np.linalg.eigh(A @ A.T)
    order = np.argsort(-w, kind="stable")
    return U[:, order], np.sqrt(np.maximum(w[order], 0.0))


def kept_count(s: np.ndarray, share: float) -> int:
    """The fewest leading singular values whose squares hold `share` of their sum (≥ 1)."""
    energy = np.asarray(s, dtype=np.float64) ** 2
    total = float(energy.sum())
    if total <= 0.0:
        return 1
    return int(min(s.size, np.searchsorted(np.cumsum(energy) / total, share - 1e-12) + 1))


def natural_core(X: np.ndarray, U_S: np.ndarray, U_R: np.ndarray) -> np.ndarray:
    """Φ_t (V, F, kS, kR): X projected on the kept style and repetition vectors — the
    core multiplied back by every technical mode's matrix."""
    return mode_product(mode_product(X, U_S.T, 2), U_R.T, 3)


def synthesize(core_t: np.ndarray, x_s: np.ndarray, x_r: np.ndarray) -> np.ndarray:
    """m(x_S, x_R) = Φ_t ×_S x_S ×_R x_R: (V, F)."""
    return np.einsum("vfij,i,j->vf", core_t, x_s, x_r, optimize=True)


@numba.njit(cache=True, nogil=True)
def _dtw(a, b):
    n, m = a.shape[0], b.shape[0]
    D = np.full((n + 1, m + 1), np.inf)
    D[0, 0] = 0.0
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            d = 0.0
            for k in range(a.shape[1]):
                e = a[i - 1, k] - b[j - 1, k]
                d += e * e
            D[i, j] = d + min(D[i - 1, j - 1], D[i - 1, j], D[i, j - 1])
    path_a = np.empty(n + m, np.int64)
    path_b = np.empty(n + m, np.int64)
    i, j, k = n, m, 0
    while i > 0 and j > 0:
        path_a[k], path_b[k] = i - 1, j - 1
        k += 1
        diag, up, left = D[i - 1, j - 1], D[i - 1, j], D[i, j - 1]
        if diag <= up and diag <= left:
            i, j = i - 1, j - 1
        elif up <= left:
            i -= 1
        else:
            j -= 1
    return path_a[:k][::-1].copy(), path_b[:k][::-1].copy(), D[n, m]


def dtw_path(reference: np.ndarray, unit: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The cheapest monotone alignment of two frame sequences (F, V) and (L, V):
    matched frame indices (K,), (K,) from (0, 0) to (F−1, L−1), and its cost."""
    return _dtw(np.ascontiguousarray(reference, np.float64), np.ascontiguousarray(unit, np.float64))


def warp_onto(ref_idx: np.ndarray, unit_idx: np.ndarray, frames: int, length: int, sigma: float = 2.0) -> np.ndarray:
    """(frames,) float: for each reference frame the time in the unit (of `length`
    frames) matched to it — the mean of its matched unit frames, Gaussian-smoothed
    (σ frames) and stretched back onto [0, length − 1]. Non-decreasing, and smooth:
    DTW's raw map stalls and jumps, and a unit played along it would jerk (its
    simulated accelerations with it)."""
    sums = np.bincount(ref_idx, weights=unit_idx.astype(np.float64), minlength=frames)
    counts = np.bincount(ref_idx, minlength=frames)
    times = np.maximum.accumulate(sums / np.maximum(counts, 1))
    if sigma > 0 and frames > 2:
        from scipy.ndimage import gaussian_filter1d

        times = gaussian_filter1d(times, sigma, mode="nearest")
        span = times[-1] - times[0]
        times = (times - times[0]) * ((length - 1) / span) if span > 0 else np.linspace(0.0, length - 1.0, frames)
    return times


def sample(values: np.ndarray, times: np.ndarray) -> np.ndarray:
    """values (L, V) linearly interpolated at fractional frame times (K,) (clamped)."""
    L = values.shape[0]
    t = np.clip(np.asarray(times, dtype=np.float64), 0.0, L - 1.0)
    lo = np.minimum(np.floor(t).astype(np.int64), max(L - 2, 0))
    w = (t - lo)[:, None]
    hi = np.minimum(lo + 1, L - 1)
    return values[lo] * (1.0 - w) + values[hi] * w

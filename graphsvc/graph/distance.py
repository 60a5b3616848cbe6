"""Frame distance of Kovar et al. (2002): windowed point clouds compared after the
best rotation about +Y and ground-plane translation, in closed form.

For frame i the cloud is the canonical joints over a window of frames centred on i,
with Gaussian-tapered weights w summing to 1. With each cloud's XZ coordinates
centred on its weighted mean and scaled by √w, the optimally aligned squared
distance between clouds a and b is

    D = |a|² + |b|² − 2·⟨a_y, b_y⟩ − 2·√(C² + S²),
    C = ⟨a_x, b_x⟩ + ⟨a_z, b_z⟩,   S = ⟨a_x, b_z⟩ − ⟨a_z, b_x⟩,

reached at the rotation θ = atan2(S, C) about +Y that takes b onto a. Every term is
a dot product of per-frame feature vectors, so a block of frame pairs is four
matrix products (BLAS) instead of a Python loop over pairs. Distances are reported
as the weighted RMS point distance in metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphsvc.errors import InputError

DEFAULT_WINDOW_S = 0.25  # Tautges 2012, §4.3.3: 15 frames at 60 Hz


@dataclass(frozen=True)
class PoseFeatures:
    """Per-frame window clouds, F frames × n = window·joints points, float32.
    x, z: centred √w-scaled ground coordinates (F, n); y: √w-scaled heights (F, n);
    norm2: (F,) squared norms; mean_xz: (F, 2) weighted cloud centres in metres."""

    x: np.ndarray
    z: np.ndarray
    y: np.ndarray
    norm2: np.ndarray
    mean_xz: np.ndarray

    @property
    def num_frames(self) -> int:
        return self.x.shape[0]


def window_frames(rate_hz: float, window_s: float = DEFAULT_WINDOW_S) -> int:
    """Odd window length in frames covering at most about `window_s` seconds (≥ 3)."""
    n = int(round(window_s * rate_hz))
    return max(3, n if n % 2 else n - 1)


def window_weights(length: int) -> np.ndarray:
    """(length,) Gaussian taper over the window (σ = a quarter of its span), sum 1."""
    half = length // 2
    offsets = np.arange(-half, half + 1, dtype=np.float64)
    sigma = max(half / 2.0, 0.5)
    w = np.exp(-0.5 * (offsets / sigma) ** 2)
    return w / w.sum()


def pose_features(positions: np.ndarray, window: int) -> PoseFeatures:
    """positions: (F, P, 3) world positions of the P canonical joints of one clip.
    Frames within half a window of either end repeat the end frame."""
    F = positions.shape[0]
    if F == 0:
        raise InputError("cannot compute pose features of zero frames")
    half = window // 2
    return window_features(positions, np.clip(np.arange(F)[:, None] + np.arange(-half, half + 1)[None, :], 0, F - 1))


def window_features(positions: np.ndarray, idx: np.ndarray) -> PoseFeatures:
    """The clouds of `pose_features` with each cloud's frames given: idx (F, W) rows of
    positions (N, P, 3), a window of W (odd) frames each (a frame's cloud is the same
    numbers whichever others are computed with it)."""
    F, window = idx.shape
    P = positions.shape[1]
    time_w = window_weights(window)
    cloud = positions[idx]  # (F, W, P, 3)
    w = np.repeat(time_w / P, P)  # (W·P,) per point, sums to 1
    cloud = cloud.reshape(F, window * P, 3)
    mean_xz = np.einsum("fnk,n->fk", cloud[..., [0, 2]], w)
    sqrt_w = np.sqrt(w)
    x = (cloud[..., 0] - mean_xz[:, :1]) * sqrt_w
    z = (cloud[..., 2] - mean_xz[:, 1:]) * sqrt_w
    y = cloud[..., 1] * sqrt_w
    norm2 = np.einsum("fn,fn->f", x, x) + np.einsum("fn,fn->f", z, z) + np.einsum("fn,fn->f", y, y)
    return PoseFeatures(
        x.astype(np.float32),
        z.astype(np.float32),
        y.astype(np.float32),
        norm2.astype(np.float64),
        mean_xz.astype(np.float64),
    )


def concat_features(parts: list[PoseFeatures]) -> PoseFeatures:
    return PoseFeatures(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("x", "z", "y", "norm2", "mean_xz")))


def take(features: PoseFeatures, frames: np.ndarray) -> PoseFeatures:
    return PoseFeatures(
        features.x[frames], features.z[frames], features.y[frames], features.norm2[frames], features.mean_xz[frames]
    )


def distance_block(a: PoseFeatures, b: PoseFeatures) -> np.ndarray:
    """(Fa, Fb) aligned RMS point distances in metres between every frame of a and b.

    Products in float64: near-zero distances lose everything to cancellation in
    float32, and this must agree with `distance_pairs` (the kd-tree search and its
    all-pairs reference rely on it)."""
    ax, az, ay = (v.astype(np.float64) for v in (a.x, a.z, a.y))
    bx, bz, by = (v.astype(np.float64) for v in (b.x, b.z, b.y))
    cos_term = ax @ bx.T + az @ bz.T
    sin_term = ax @ bz.T - az @ bx.T
    d2 = a.norm2[:, None] + b.norm2[None, :] - 2.0 * (ay @ by.T) - 2.0 * np.hypot(cos_term, sin_term)
    return np.sqrt(np.maximum(d2, 0.0))


def distance_pairs(a: PoseFeatures, ia: np.ndarray, b: PoseFeatures, ib: np.ndarray) -> np.ndarray:
    """(K,) aligned RMS distances of the frame pairs (a[ia[k]], b[ib[k]])."""
    ax, az, ay = a.x[ia].astype(np.float64), a.z[ia].astype(np.float64), a.y[ia].astype(np.float64)
    bx, bz, by = b.x[ib].astype(np.float64), b.z[ib].astype(np.float64), b.y[ib].astype(np.float64)
    cos_term = np.einsum("kn,kn->k", ax, bx) + np.einsum("kn,kn->k", az, bz)
    sin_term = np.einsum("kn,kn->k", ax, bz) - np.einsum("kn,kn->k", az, bx)
    d2 = a.norm2[ia] + b.norm2[ib] - 2.0 * np.einsum("kn,kn->k", ay, by) - 2.0 * np.hypot(cos_term, sin_term)
    return np.sqrt(np.maximum(d2, 0.0))


def alignment(a: PoseFeatures, ia: np.ndarray, b: PoseFeatures, ib: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rigid ground motion taking cloud b[ib] onto cloud a[ia]: rotation angles
    (K,) in radians about +Y and translations (K, 2) (x, z) in metres, so that
    a ≈ R_y(θ)·b + (tx, 0, tz)."""
    ax, az = a.x[ia].astype(np.float64), a.z[ia].astype(np.float64)
    bx, bz = b.x[ib].astype(np.float64), b.z[ib].astype(np.float64)
    cos_term = np.einsum("kn,kn->k", ax, bx) + np.einsum("kn,kn->k", az, bz)
    sin_term = np.einsum("kn,kn->k", ax, bz) - np.einsum("kn,kn->k", az, bx)
    theta = np.arctan2(sin_term, cos_term)
    c, s = np.cos(theta), np.sin(theta)
    mb = b.mean_xz[ib]
    # R_y(θ)·(x, z) = (c·x + s·z, −s·x + c·z)
    rotated = np.stack([c * mb[:, 0] + s * mb[:, 1], -s * mb[:, 0] + c * mb[:, 1]], axis=-1)
    return theta, a.mean_xz[ia] - rotated

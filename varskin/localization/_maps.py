"""Column statistics of the point log maps (touches x sensors) that every fit starts from.

Why a module of its own: the batch solve, the live update and the settling check all take a
robust level of each sensor's readings and its slow floor over the session, and a live
update does so every touch, so these must be fast as well as NaN-proof.
"""

from __future__ import annotations

import numpy as np


def nanmedian_cols(A: np.ndarray) -> np.ndarray:
    """``np.nanmedian(A, axis=0)`` (NaN for an all-NaN column, without a warning).

    numpy's nanmedian goes through masked arrays for small inputs, which made it one of
    the largest costs of a live update.
    """
    if A.shape[0] == 0:
        return np.full(A.shape[1], np.nan)
    B = np.sort(A, axis=0)  # NaN sorts last
    n = (~np.isnan(B)).sum(axis=0)
    cols = np.arange(A.shape[1])
    # The two middle ranks of the n finite values (the same one when n is odd).
    lo = B[np.maximum((n - 1) // 2, 0), cols]
    hi = B[n // 2 - (n == 0), cols]
    return np.where(n > 0, 0.5 * (lo + hi), np.nan)


def floor_trend(U: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Each sensor's slow floor over the session: low quantile of consecutive touches.

    Touches are binned in arrival order (bins of ~K/8, at least 10); the 20th percentile of a
    bin ignores the few touches near the sensor, and bins are joined by straight lines.
    """
    K, S = U.shape
    m = max(10, K // 8)
    if 2 * m > K:
        q = np.percentile(np.where(valid, U, np.inf), 20, axis=0, method="lower")
        return np.broadcast_to(np.where(np.isfinite(q), q, 0.0), (K, S))
    edges = np.linspace(0, K, K // m + 1).astype(int)
    centres = 0.5 * (edges[:-1] + edges[1:] - 1)
    # Invalid cells sort last (+inf), so a low quantile ignores them while they are few.
    Un = np.where(valid, U, np.inf)
    # All bins at once: pad each to the longest with +inf (sorts last), sort within bins,
    # and take each bin's own "lower" 20th-percentile rank.
    sizes = np.diff(edges)
    nb, mx = sizes.size, int(sizes.max())
    pos = np.arange(K) - np.repeat(edges[:-1], sizes)
    padded = np.full((nb, mx, S), np.inf)
    padded[np.repeat(np.arange(nb), sizes), pos] = Un
    padded.sort(axis=1)
    rank = np.floor(0.2 * (sizes - 1)).astype(int)
    q = padded[np.arange(nb), rank]
    # Bins without any valid value borrow the sensor's overall level.
    overall = nanmedian_cols(q) if np.isfinite(q).any() else np.zeros(S)
    q = np.where(np.isfinite(q), q, np.where(np.isfinite(overall), overall, 0.0)[None, :])
    k = np.arange(K)
    j = np.clip(np.searchsorted(centres, k) - 1, 0, len(centres) - 2)
    t = np.clip((k - centres[j]) / (centres[j + 1] - centres[j]), 0.0, 1.0)
    return q[j] * (1 - t)[:, None] + q[j + 1] * t[:, None]


def span_by_sensor(values: np.ndarray, cols: np.ndarray, n: int) -> np.ndarray:
    """(n,) max - min of ``values`` over each sensor's entries, 0 for a sensor with none.

    ``values`` has one entry per (touch, sensor) pair and ``cols`` its sensor, ascending
    (as ``np.nonzero`` of a (sensors, touches) mask gives them): a full board's fit windows
    hold a tenth of its touches, and a (touches x sensors) array of them all cost its live
    update 3 ms. Max and min are exact, so the spans equal the masked array's.
    """
    out = np.zeros(n)
    if values.size:
        starts = np.flatnonzero(np.r_[True, cols[1:] != cols[:-1]])
        hi = np.maximum.reduceat(values, starts)
        out[cols[starts]] = hi - np.minimum.reduceat(values, starts)
    return out

"""Column statistics of the point log maps (touches x sensors) that every fit starts from.

Why a module of its own: the batch solve, the live update and the settling check all take a
robust level of each sensor's readings and its slow floor over the session, and a live
update does so every touch, so these must be fast as well as NaN-proof. The fits gather
each sensor's touches (``packed``) from these maps every touch too.
"""

from __future__ import annotations

import functools

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
    if 2 * max(10, K // 8) > K:
        q = np.percentile(np.where(valid, U, np.inf), 20, axis=0, method="lower")
        return np.broadcast_to(np.where(np.isfinite(q), q, 0.0), (K, S))
    bin_of, pos, (nb, mx), rank, j, t = _trend_bins(K)
    # Invalid cells sort last (+inf), so a low quantile ignores them while they are few.
    # All bins at once: pad each to the longest with +inf (sorts last), sort within bins,
    # and take each bin's own "lower" 20th-percentile rank.
    padded = np.full((nb, mx, S), np.inf)
    padded[bin_of, pos] = np.where(valid, U, np.inf)
    padded.sort(axis=1)
    q = padded[np.arange(nb), rank]
    # Bins without any valid value borrow the sensor's overall level.
    empty = ~np.isfinite(q)
    if empty.any():
        overall = nanmedian_cols(q) if not empty.all() else np.zeros(S)
        q = np.where(empty, np.where(np.isfinite(overall), overall, 0.0)[None, :], q)
    return q[j] * (1 - t)[:, None] + q[j + 1] * t[:, None]


@functools.lru_cache(maxsize=8)
def _trend_bins(K: int) -> tuple:
    """``floor_trend``'s layout for K touches, which depends on K alone: each touch's bin
    and place in it, the padded shape, each bin's quantile rank, and each touch's two bins
    and weight for the interpolation. Kept: a live update asks for it every touch."""
    m = max(10, K // 8)
    edges = np.linspace(0, K, K // m + 1).astype(int)
    centres = 0.5 * (edges[:-1] + edges[1:] - 1)
    sizes = np.diff(edges)
    pos = np.arange(K) - np.repeat(edges[:-1], sizes)
    rank = np.floor(0.2 * (sizes - 1)).astype(int)
    k = np.arange(K)
    j = np.clip(np.searchsorted(centres, k) - 1, 0, len(centres) - 2)
    t = np.clip((k - centres[j]) / (centres[j + 1] - centres[j]), 0.0, 1.0)
    bin_of = np.repeat(np.arange(sizes.size), sizes)
    for a in (bin_of, pos, rank, j, t):
        a.flags.writeable = False  # shared by every call with this K
    return bin_of, pos, (sizes.size, int(sizes.max())), rank, j, t


def packed(mask: np.ndarray, axis: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Each line of the 2-D ``mask`` along ``axis`` with its True entries first: the indices
    along ``axis``, cut to M, the most True any line has (at least 1, if the lines have
    any entries), and which of them are True.

    How the fits gather each sensor's touches (and the layout prior each wire's sensors)
    into arrays padded only to the largest count. The gathered mask is the first ``count``
    entries of each line, so it is made by a comparison instead of a gather.
    """
    counts = mask.sum(axis=axis)
    M = max(int(counts.max(initial=0)), 1)
    order = np.argsort(~mask, axis=axis, kind="stable")
    # Lines with no entries at all (no touches yet) keep none: M = 0 there.
    if axis == 0:
        order = order[:M]
        return order, np.arange(order.shape[0])[:, None] < counts[None, :]
    order = order[:, :M]
    return order, np.arange(order.shape[1])[None, :] < counts[:, None]


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

"""Optional layout prior: crossings of one TX wire share nearly one x, of one RX wire one y.

Why a separate step: the per-sensor fits stay independent (fast, incremental) and this
cheap post-step pools them. It is a random-effects shrinkage, not a constraint: every
sensor's coordinate is pulled towards its wire's line by the ratio of its own variance to
the wire's scatter, and the scatter is estimated from the data, so a bent or displaced wire
weakens the prior by itself instead of being forced straight. A wire with three or more
well-measured crossings gets a straight (possibly slanted) line; with fewer, a constant.
"""

from __future__ import annotations

import numpy as np


def shrink_to_wires(
    coord: np.ndarray,
    var: np.ndarray,
    along: np.ndarray,
    groups: np.ndarray,
    usable: np.ndarray,
    min_scatter_mm: float,
    shared: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Pull ``coord`` (N,) towards each group's line in ``along`` (N,); returns (coord, var).

    ``var`` are the per-sensor variances of ``coord``; ``groups`` (N,) the wire index (-1 for
    none); only ``usable`` sensors inform a line, but every usable sensor of a group with
    at least two of them is updated.

    ``shared`` (N,) is the part of ``var`` that a sensor's wire-mates share (their errors
    move together, e.g. from the same touches' placement): the pull is weighed with the
    full variances, but the returned variance keeps the shared part, which the wire-mates
    cannot average out, and counts the own parts' of the sensor and of its mates.
    """
    out = coord.copy()
    out_var = var.copy()
    for gid in np.unique(groups[groups >= 0]):
        members = np.flatnonzero((groups == gid) & usable)
        if members.size < 2:
            continue
        c, v, t = coord[members], var[members], along[members]
        X = _design(t)
        tau2 = _scatter(c, v, X, min_scatter_mm)
        w = 1.0 / (v + tau2)
        A = np.linalg.pinv((X * w[:, None]).T @ X)
        fitted = X @ (A @ ((X * w[:, None]).T @ c))
        lev = np.clip(w * np.einsum("ip,pq,iq->i", X, A, X), 0.0, 1.0 - 1e-9)
        # Leave-one-out line: a sensor is pulled towards what its wire-mates say, not itself.
        loo = (fitted - lev * c) / (1.0 - lev)
        loo_var = lev / (w * (1.0 - lev))
        prior_var = tau2 + loo_var
        post_var = 1.0 / (1.0 / v + 1.0 / prior_var)
        out[members] = post_var * (c / v + loo / prior_var)
        if shared is None:
            out_var[members] = post_var
        else:
            # Error of lam*c + (1-lam)*loo when the shared part is common to c and loo.
            sh = np.clip(shared[members], 0.0, v)
            lam = post_var / v
            loo_own = loo_var * np.clip(1.0 - sh.mean() / np.maximum(v.mean(), 1e-300), 0, 1)
            out_var[members] = sh + lam**2 * (v - sh) + (1.0 - lam) ** 2 * (tau2 + loo_own)
    return out, out_var


def _design(t: np.ndarray) -> np.ndarray:
    # A slanted line needs enough crossings (leave-one-out keeps >= 4) to beat a constant.
    if t.size >= 5 and np.ptp(t) > 0:
        return np.column_stack([np.ones_like(t), t - t.mean()])
    return np.ones((t.size, 1))


def _scatter(c, v, X, floor_mm: float) -> float:
    """Empirical-Bayes scatter of the crossings around their wire's line, >= the floor."""
    tau2 = floor_mm**2
    for _ in range(4):
        w = 1.0 / (v + tau2)
        beta = np.linalg.lstsq(X * np.sqrt(w)[:, None], c * np.sqrt(w), rcond=None)[0]
        resid = c - X @ beta
        dof = max(c.size - X.shape[1], 1)
        tau2 = max(floor_mm**2, float((resid**2).sum() / dof - v.mean()))
    return tau2

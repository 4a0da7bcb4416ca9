"""Optional layout prior: crossings of one TX wire share nearly one x, of one RX wire one y.

Why a separate step: the per-sensor fits stay independent (fast, incremental) and this
cheap post-step pools them. It is a random-effects shrinkage, not a constraint: every
sensor's coordinate is pulled towards its wire's line by the ratio of its own variance to
the wire's scatter, and the scatter is estimated from the data, so a bent or displaced wire
weakens the prior by itself instead of being forced straight. A wire with five or more
well-measured crossings gets a straight (possibly slanted) line; with fewer, a constant.

When the patch's design is known, each wire's line also gets a prior at its design
coordinate, after an affine map from design to fitted coordinates (registration offset and
scale) estimated over all wires, with the wires' displacement from the design estimated
from the data too. That is what pins a wire whose every crossing lies at the probes' edge
(its wire-mates are as uncertain as itself); a patch built far from its design simply gets
a weak design prior.
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
    design: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Pull ``coord`` (N,) towards each group's line in ``along`` (N,); returns (coord, var).

    ``var`` are the per-sensor variances of ``coord``; ``groups`` (N,) the wire index (-1 for
    none); only ``usable`` sensors inform a line, but every usable sensor of a group with
    at least two of them is updated.

    ``shared`` (N,) is the part of ``var`` that a sensor's wire-mates share (their errors
    move together, e.g. from the same touches' placement): the pull is weighed with the
    full variances, but the returned variance keeps the shared part, which the wire-mates
    cannot average out, and counts the own parts of the sensor and of its mates.

    ``design`` (N,) is each sensor's wire's design coordinate (NaN: unknown); see the module
    docstring.
    """
    out = coord.copy()
    out_var = var.copy()
    prior = _design_prior(coord, var, groups, usable, design, min_scatter_mm)
    for gid in np.unique(groups[groups >= 0]):
        members = np.flatnonzero((groups == gid) & usable)
        has_prior = gid in prior
        if members.size < (1 if has_prior else 2):
            continue
        c, v, t = coord[members], var[members], along[members]
        X = _design(t)
        tau2 = _scatter(c, v, X, min_scatter_mm)
        w = 1.0 / (v + tau2)
        # The design is a pseudo-observation of the line's level at the wire's centre; it is
        # never left out, so a lone crossing is still pulled towards it.
        Pm = np.zeros((X.shape[1], X.shape[1]))
        pb = np.zeros(X.shape[1])
        if has_prior:
            mu, s2 = prior[gid]
            Pm[0, 0] = 1.0 / s2
            pb[0] = mu / s2
        A = np.linalg.pinv((X * w[:, None]).T @ X + Pm)
        fitted = X @ (A @ ((X * w[:, None]).T @ c + pb))
        lev = np.clip(w * np.einsum("ip,pq,iq->i", X, A, X), 0.0, 1.0 - 1e-9)
        # Leave-one-out line: a sensor is pulled towards what its wire-mates (and the design)
        # say, not itself.
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


def _design_prior(coord, var, groups, usable, design, floor_mm: float) -> dict:
    """{wire: (mean, variance)} of each wire's level from its design coordinate.

    Each wire's own level (weighted mean of its usable crossings) is compared with its
    design coordinate over all wires: an affine map (offset, and scale with >= 5 wires)
    absorbs registration, the scatter of the wires around it is their displacement from
    the design (empirical Bayes, >= the floor). Needs >= 3 measured wires.
    """
    if design is None:
        return {}
    gids, level, level_var, dz = [], [], [], []
    for gid in np.unique(groups[groups >= 0]):
        members = np.flatnonzero((groups == gid) & usable)
        d = design[groups == gid]
        if members.size == 0 or not np.isfinite(d).all():
            continue
        w = 1.0 / np.maximum(var[members], 1e-12)
        gids.append(gid)
        level.append(float((w * coord[members]).sum() / w.sum()))
        level_var.append(float(1.0 / w.sum()))
        dz.append(float(d[0]))
    if len(gids) < 3:
        return {}
    level, level_var, dz = np.array(level), np.array(level_var), np.array(dz)
    X = _design(dz)
    s2 = _scatter(level, level_var, X, floor_mm, iterations=6)
    # Each wire's prior comes from the map fitted to the other wires (its own crossings
    # must not vouch for themselves), plus that map's own uncertainty at the wire.
    w = 1.0 / (level_var + s2)
    out = {}
    for j, g in enumerate(gids):
        keep = np.arange(dz.size) != j
        Xk, wk = X[keep], w[keep]
        cov = np.linalg.pinv((Xk * wk[:, None]).T @ Xk)
        b = cov @ ((Xk * wk[:, None]).T @ level[keep])
        out[g] = (float(X[j] @ b), float(s2 + X[j] @ cov @ X[j]))
    return out


def _design(t: np.ndarray) -> np.ndarray:
    # A slanted line needs enough crossings (leave-one-out keeps >= 4) to beat a constant.
    if t.size >= 5 and np.ptp(t) > 0:
        return np.column_stack([np.ones_like(t), t - t.mean()])
    return np.ones((t.size, 1))


def _scatter(c, v, X, floor_mm: float, iterations: int = 4) -> float:
    """Empirical-Bayes scatter of values ``c`` (variances ``v``) around the fit ``X``,
    >= the floor: the crossings around their wire's line, or the wires around the design."""
    tau2 = floor_mm**2
    if c.size <= X.shape[1]:
        return tau2
    for _ in range(iterations):
        w = 1.0 / (v + tau2)
        beta = np.linalg.lstsq(X * np.sqrt(w)[:, None], c * np.sqrt(w), rcond=None)[0]
        resid = c - X @ beta
        dof = max(c.size - X.shape[1], 1)
        tau2 = max(floor_mm**2, float((resid**2).sum() / dof - v.mean()))
    return tau2

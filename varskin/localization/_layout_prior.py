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

A crossing whose own fit lies far off the line its wire-mates and the design draw without
it (a fit gone astray where the touches left a hole, or a footprint longer than the patch
is wide) keeps the position the prior gives it, but its error bar takes in the distance.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from varskin.localization._maps import packed

# How far (in sds of the prediction) a crossing may lie from the line its wire-mates draw
# before its variance takes in that distance.
OFF_LINE_Z = 4.0
# The fewest wires of a family (TX or RX) that get a map from design to fitted coordinates:
# with fewer, that axis has no design prior.
DESIGN_MAP_MIN_WIRES = 3


def shrink_to_wires(
    coord: np.ndarray,
    var: np.ndarray,
    along: np.ndarray,
    groups: np.ndarray,
    usable: np.ndarray,
    min_scatter_mm: float,
    shared: np.ndarray | None = None,
    design: np.ndarray | None = None,
    family: np.ndarray | None = None,
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
    docstring. ``family`` (N,) says which wires share one map from design to fitted
    coordinates (default: all); ``shrink_to_layout`` passes both axes at once that way.
    """
    out = coord.copy()
    out_var = var.copy()
    # All wires at once, padded to (G, M): a live update calls this twice per touch, and a
    # Python loop of tiny numpy calls per wire cost more than the arithmetic.
    if not (usable & (groups >= 0)).any():
        return out, out_var
    in_group, member = _wire_members(groups, usable)
    fam = np.zeros(coord.size, int) if family is None else np.asarray(family)
    mu, s2 = _design_prior(coord, var, in_group, member, design, fam, min_scatter_mm)
    has_prior = np.isfinite(mu)
    count = member.sum(axis=1)
    keep = count >= np.where(has_prior, 1, 2)
    if not keep.any():
        return out, out_var
    member, count, has_prior = member[keep], count[keep], has_prior[keep]
    mu, s2 = mu[keep], s2[keep]
    order, mask = packed(member, axis=1)  # (G, M) sensor indices
    c = np.where(mask, coord[order], 0.0)
    v = np.where(mask, var[order], 1.0)
    t = np.where(mask, along[order], 0.0)
    # A slanted line needs enough crossings (leave-one-out keeps >= 4) to beat a constant;
    # otherwise the slope column is zero and its normal equation pins the slope at zero.
    t_mean = (t * mask).sum(axis=1) / count
    t_lo = np.where(mask, t, np.inf).min(axis=1)
    t_hi = np.where(mask, t, -np.inf).max(axis=1)
    slanted = (count >= 5) & (t_hi > t_lo)
    tc = np.where(mask & slanted[:, None], t - t_mean[:, None], 0.0)
    n_cols = np.where(slanted, 2, 1)
    tau2 = _scatter_rows(c, v, tc, mask, count, n_cols, min_scatter_mm)
    w = np.where(mask, 1.0 / (v + tau2[:, None]), 0.0)
    # The design is a pseudo-observation of the line's level at the wire's centre; it is
    # never left out, so a lone crossing is still pulled towards it.
    p0 = np.where(has_prior, 1.0 / np.where(has_prior, s2, 1.0), 0.0)
    pb = np.where(has_prior, mu, 0.0) * p0
    beta0, beta1, (i00, i01, i11) = _weighted_lines(c, w, tc, slanted, p0, pb)
    fitted = beta0[:, None] + beta1[:, None] * tc
    quad = i00[:, None] + 2.0 * i01[:, None] * tc + i11[:, None] * tc * tc
    lev = np.clip(w * quad, 0.0, 1.0 - 1e-9)
    # Leave-one-out line: a sensor is pulled towards what its wire-mates (and the design)
    # say, not itself.
    loo = (fitted - lev * c) / (1.0 - lev)
    loo_var = lev / (np.where(mask, w, 1.0) * (1.0 - lev))
    prior_var = tau2[:, None] + loo_var
    post_var = 1.0 / (1.0 / v + 1.0 / prior_var)
    new = post_var * (c / v + loo / prior_var)
    if shared is None:
        new_var = post_var
    else:
        # Error of lam*c + (1-lam)*loo when the shared part is common to c and loo.
        sh = np.where(mask, np.clip(shared[order], 0.0, v), 0.0)
        lam = post_var / v
        v_mean = (v * mask).sum(axis=1) / count
        sh_mean = sh.sum(axis=1) / count
        own = np.clip(1.0 - sh_mean / np.maximum(v_mean, 1e-300), 0.0, 1.0)
        loo_own = loo_var * own[:, None]
        new_var = sh + lam**2 * (v - sh) + (1.0 - lam) ** 2 * (tau2[:, None] + loo_own)
    # A crossing far off the line its wire-mates (and the design) draw without it: its own
    # fit or its wire is wrong, and nothing here tells which, so the error bar spans both.
    # The mates' scatter is estimated without it too: with it, one crossing 6 mm off a
    # wire of ten widened that wire's scatter to 2 mm and vouched for itself.
    # Only on wires with a crossing 3/4 that far from the line drawn at the full scatter
    # (counting the floor scatter alone): the check costs a live update 0.3-0.5 ms on
    # Patch B where every wire takes it, and almost no wire needs it.
    far = mask & (np.abs(c - loo) > 0.75 * OFF_LINE_Z * np.sqrt(v + min_scatter_mm**2))
    gi = np.flatnonzero(far.any(axis=1))
    if gi.size:
        pred, z = _off_line(
            c[gi], v[gi], tc[gi], mask[gi], slanted[gi], p0[gi], pb[gi], min_scatter_mm
        )
        off = mask[gi] & (np.abs(z) > OFF_LINE_Z)
        new_var[gi] = np.where(off, new_var[gi] + (new[gi] - pred) ** 2, new_var[gi])
    out[order[mask]] = new[mask]
    out_var[order[mask]] = new_var[mask]
    return out, out_var


def _off_line(c, v, tc, mask, slanted, p0, pb, min_scatter_mm):
    """(G, M) where each crossing's wire-mates alone (and the design) put its line, and how
    far it lies from that, in sds of the prediction: its own variance, the mates' scatter
    about their line (estimated without it) and the line's own variance at it."""
    G, M = c.shape
    rows = (mask[:, None, :] & ~np.eye(M, dtype=bool)[None]).reshape(G * M, M)
    cc = np.repeat(c, M, axis=0)
    vv = np.repeat(v, M, axis=0)
    sl = np.repeat(slanted, M)
    tt = np.repeat(tc, M, axis=0)  # zero already where the wire's line is a constant
    count = rows.sum(axis=1)
    tau2 = _scatter_rows(cc, vv, tt, rows, count, np.where(sl, 2, 1), min_scatter_mm)
    w = np.where(rows, 1.0 / (vv + tau2[:, None]), 0.0)
    q0 = np.repeat(p0, M)
    b0, b1, (i00, i01, i11) = _weighted_lines(cc, w, tt, sl, q0, np.repeat(pb, M))
    t_own = tc.reshape(G * M)
    pred = b0 + t_own * b1
    pvar = i00 + 2.0 * i01 * t_own + i11 * t_own * t_own
    informed = (count > 0) | (q0 > 0)
    total = v.reshape(G * M) + tau2 + pvar
    z = np.where(informed, (c.reshape(G * M) - pred) / np.sqrt(total), 0.0)
    return pred.reshape(G, M), z.reshape(G, M)


def _weighted_lines(c, w, tc, slanted, p0, pb):
    """One weighted least-squares line ``c ~ b0 + b1 tc`` per row of (G, M) values ``c`` with
    weights ``w`` (the slope pinned at 0 where not ``slanted``), the design a pseudo-
    observation of b0 with precision ``p0`` (``pb``: its value times ``p0``): (G,) b0, b1 and
    the inverse normal matrix (i00, i01, i11)."""
    a11 = (w * tc * tc).sum(axis=1) + np.where(slanted, 0.0, 1.0)
    i00, i01, i11 = _inv_sym2(w.sum(axis=1) + p0, (w * tc).sum(axis=1), a11)
    r0 = (w * c).sum(axis=1) + pb
    r1 = (w * tc * c).sum(axis=1)
    return i00 * r0 + i01 * r1, i01 * r0 + i11 * r1, (i00, i01, i11)


def shrink_to_layout(
    xy: np.ndarray,
    var: np.ndarray,
    tx: np.ndarray,
    rx: np.ndarray,
    usable: np.ndarray,
    min_scatter_mm: float,
    shared_xy: tuple[np.ndarray, np.ndarray] | None = None,
    design_xy: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Both axes in one pass: x towards the TX wires' lines, y towards the RX wires'.

    ``xy`` (N, 2), ``var`` (N,) per-axis variance, ``tx``/``rx`` (N,) wire indices (-1:
    none); ``shared_xy`` and ``design_xy`` are ``shrink_to_wires``' ``shared`` and
    ``design`` for x and for y. Returns the new xy and the x and y variances. One call
    instead of one per axis: a live update runs this every touch.
    """
    n = len(var)
    coord, var2, usable2, design, family = _stack_axes(xy, var, usable, design_xy)
    out, out_var = shrink_to_wires(
        coord,
        var2,
        np.concatenate([xy[:, 1], xy[:, 0]]),
        both_axes(tx, rx),
        usable2,
        min_scatter_mm,
        None if shared_xy is None else np.concatenate(shared_xy),
        design,
        family,
    )
    return np.column_stack([out[:n], out[n:]]), out_var[:n], out_var[n:]


def _stack_axes(xy, var, usable, design_xy):
    """Every sensor's x then its y as one (2N,) coordinate, with its variance, usability,
    wire design (None: none) and family (0: x, 1: y), as ``both_axes`` numbers the wires."""
    design = None if design_xy is None else np.concatenate(design_xy)
    family = np.repeat([0, 1], len(var))
    both = np.concatenate
    return both([xy[:, 0], xy[:, 1]]), both([var, var]), both([usable, usable]), design, family


def _wire_members(groups: np.ndarray, usable: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(G, N) which sensors cross each wire (one row per wire id >= 0, ascending), and which
    of those are usable."""
    gids = np.unique(groups[groups >= 0])
    in_group = groups[None, :] == gids[:, None]
    return in_group, in_group & usable[None, :]


def both_axes(tx: np.ndarray, rx: np.ndarray) -> np.ndarray:
    """(2N,) wire ids of every sensor's x (its TX wire) then its y (its RX wire), the RX ids
    numbered after the TX ones (-1: none): both axes as one set of groups."""
    offset = max(int(tx.max(initial=-1)), -1) + 1
    return np.concatenate([tx, np.where(rx >= 0, rx + offset, -1)])


def _design_prior(coord, var, in_group, member, design, family, floor_mm: float):
    """(G,) mean and variance of each wire's level from its design coordinate (NaN: none).

    ``in_group`` (G, N) says which sensors cross each wire, ``member`` which of those are
    usable; ``family`` (N,) which wires are mapped together (one family per axis).

    Each wire's own level (weighted mean of its usable crossings) is compared with its
    design coordinate over all wires of its family: an affine map (offset, and scale with
    >= 5 wires) absorbs registration, the scatter of the wires around it is their
    displacement from the design (empirical Bayes, >= the floor). Needs >= 3 measured wires.
    """
    mean = np.full(in_group.shape[0], np.nan)
    spread = mean.copy()
    fitted = _design_map(coord, var, in_group, member, design, family, floor_mm)
    if fitted is None:
        return mean, spread
    order, mask, lv, lvar, x1, by_offset, slanted, s2, _ = fitted
    # Each wire's prior comes from the map fitted to the other wires (its own crossings
    # must not vouch for themselves), plus that map's own uncertainty at the wire: the
    # normal equations of all wires minus wire j's own term, for every j at once.
    w = np.where(mask, 1.0 / (lvar + s2[:, None]), 0.0)
    a00 = w.sum(axis=1)[:, None] - w
    a01 = (w * x1).sum(axis=1)[:, None] - w * x1
    a11 = (w * x1 * x1).sum(axis=1)[:, None] - w * x1 * x1 + np.where(slanted, 0.0, 1.0)[:, None]
    r0 = (w * lv).sum(axis=1)[:, None] - w * lv
    r1 = (w * x1 * lv).sum(axis=1)[:, None] - w * x1 * lv
    i00, i01, i11 = _inv_sym2(a00, a01, a11)
    at = order[mask]
    mean[at] = ((i00 * r0 + i01 * r1) + x1 * (i01 * r0 + i11 * r1) + by_offset)[mask]
    spread[at] = (s2[:, None] + i00 + 2.0 * i01 * x1 + i11 * x1 * x1)[mask]
    return mean, spread


def design_scatter_mm(
    xy: np.ndarray,
    var: np.ndarray,
    tx: np.ndarray,
    rx: np.ndarray,
    usable: np.ndarray,
    design_xy: tuple[np.ndarray, np.ndarray],
    min_scatter_mm: float,
) -> np.ndarray:
    """How far the wires lie off the design map, in mm (sd), for x (the TX wires) and y
    (the RX wires): the scatter the design prior is weighed with (>= ``min_scatter_mm``);
    NaN for an axis without a design map (fewer than DESIGN_MAP_MIN_WIRES measured wires).
    Arguments as ``shrink_to_layout``'s."""
    coord, var2, usable2, design, family = _stack_axes(xy, var, usable, design_xy)
    in_group, member = _wire_members(both_axes(tx, rx), usable2)
    fitted = _design_map(coord, var2, in_group, member, design, family, min_scatter_mm)
    out = np.full(2, np.nan)
    if fitted is not None:
        mapped = fitted.mask.any(axis=1)
        out[fitted.families[mapped]] = np.sqrt(fitted.scatter2[mapped])
    return out


class _DesignMap(NamedTuple):
    """Every family's wires against their design, rows padded to (F, W)."""

    order: np.ndarray  # (F, W) the wires, by index
    mask: np.ndarray  # (F, W) which entries are wires
    levels: np.ndarray  # (F, W) the wires' fitted levels (minus the design, offset-only maps)
    level_var: np.ndarray  # (F, W) their variances
    x1: np.ndarray  # (F, W) the centred design where the map has a scale, else 0
    by_offset: np.ndarray  # (F, W) the design where the map is an offset alone, else 0
    slanted: np.ndarray  # (F,) which families' maps have a scale
    scatter2: np.ndarray  # (F,) the wires' scatter about the map (variance, mm^2)
    families: np.ndarray  # (F,) which family (0: TX, x; 1: RX, y) each row is


def _design_map(coord, var, in_group, member, design, family, floor_mm: float) -> _DesignMap | None:
    """Every family's wires against their design map; None where no family has
    DESIGN_MAP_MIN_WIRES measured wires."""
    if design is None:
        return None
    designed = np.where(in_group, np.isfinite(design)[None, :], True).all(axis=1)
    keep = member.any(axis=1) & designed
    first = in_group.argmax(axis=1)  # each wire's first sensor: its design and family
    wire_family = family[first]
    fams = np.unique(wire_family)
    rows = (wire_family[None, :] == fams[:, None]) & keep[None, :]  # (F, G)
    rows &= (rows.sum(axis=1) >= DESIGN_MAP_MIN_WIRES)[:, None]
    if not rows.any():
        return None
    wm = np.where(member, 1.0 / np.maximum(var, 1e-12)[None, :], 0.0)
    wsum = np.maximum(wm.sum(axis=1), 1e-300)  # wires without members are not kept
    # Sensors outside a wire may have no coordinate at all (NaN): mask, never multiply by 0.
    level = (wm * np.where(member, coord[None, :], 0.0)).sum(axis=1) / wsum
    level_var = 1.0 / wsum
    order, mask = packed(rows, axis=1)
    count = mask.sum(axis=1)
    lv = np.where(mask, level[order], 0.0)
    lvar = np.where(mask, level_var[order], 1.0)
    dz = np.where(mask, design[first][order], 0.0)
    # An affine map (offset and scale) needs >= 5 wires; with fewer, an offset alone.
    span = np.where(mask, dz, -np.inf).max(axis=1) - np.where(mask, dz, np.inf).min(axis=1)
    slanted = (count >= 5) & (span > 0)
    dz_mean = dz.sum(axis=1) / np.maximum(count, 1)
    x1 = np.where(mask & slanted[:, None], dz - dz_mean[:, None], 0.0)
    # With an offset alone the wires' displacements from the design (level - design) share
    # one level; the affine map regresses the levels on the design instead.
    by_offset = np.where(mask & ~slanted[:, None], dz, 0.0)
    lv = lv - by_offset
    s2 = _scatter_rows(lv, lvar, x1, mask, count, np.where(slanted, 2, 1), floor_mm, 6)
    return _DesignMap(order, mask, lv, lvar, x1, by_offset, slanted, s2, fams)


def _scatter_rows(c, v, tc, mask, count, n_cols, floor_mm: float, iterations: int = 4):
    """Empirical-Bayes scatter (variance) of values around their line, >= the floor, one per
    row: the crossings around their wire's line, or the wires around the design.

    Rows of (G, M) values ``c`` with variances ``v`` padded under ``mask``; ``tc`` is the
    centred coordinate along the line (all zero where the line is a constant, ``n_cols`` 1).
    """
    tau2 = np.full(c.shape[0], floor_mm**2)
    fits = count > n_cols
    if not fits.any():
        return tau2
    flat = (n_cols == 1).astype(float)
    dof = np.maximum(count - n_cols, 1)
    v_mean = (v * mask).sum(axis=1) / np.maximum(count, 1)
    # The weighted sums of every iteration as one product: (G, M, 5) terms of the normal
    # equations (a live update runs up to ten of these iterations per touch).
    terms = np.stack([np.ones_like(c), tc, tc * tc, c, tc * c], axis=-1)
    for _ in range(iterations):
        w = np.where(mask, 1.0 / (v + tau2[:, None]), 0.0)
        sw, swt, swtt, swc, swtc = np.einsum("gm,gmf->fg", w, terms)
        i00, i01, i11 = _inv_sym2(sw, swt, swtt + flat)
        b0, b1 = i00 * swc + i01 * swtc, i01 * swc + i11 * swtc
        resid = np.where(mask, c - b0[:, None] - b1[:, None] * tc, 0.0)
        new = np.maximum(floor_mm**2, np.einsum("gm,gm->g", resid, resid) / dof - v_mean)
        new = np.where(fits, new, tau2)
        # A fixed point (most often every wire at the floor scatter) stays one: the
        # remaining iterations would repeat this one exactly.
        if np.array_equal(new, tau2):
            break
        tau2 = new
    return tau2


def _inv_sym2(a00, a01, a11):
    """Elementwise inverse of symmetric 2x2 matrices [[a00, a01], [a01, a11]] (0 if singular)."""
    det = a00 * a11 - a01 * a01
    ok = np.abs(det) > 1e-12 * (np.abs(a00 * a11) + a01 * a01)
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    return a11 * inv, -a01 * inv, a00 * inv

"""Which sensors share a wire, inferred from their fitted positions when nobody said.

Why it exists: the layout prior needs each sensor's TX and RX wire. A session knows them
from its patch; a point-log CSV given to ``varskin localize`` without ``--patch`` does not,
and without the prior the sensors at the probes' edge are extrapolated (Patch B finger
scenes: a sensor above 2 mm on 27 of 60 fresh seeds, against 1 with the patch given).
Every sensor of a mutual-capacitance skin is the crossing of one TX and one RX wire, so on
a flat patch the fitted positions fall into rows (shared y) and columns (shared x). This
looks for a split into rows and columns that forms a grid, one sensor per crossing, and
answers only when it is clear and unique; a wrong grouping would pull sensors to the wrong
wire, where no answer leaves them as they were.

* The sensor count is rows x columns (a full grid); every factorization is tried, and
  exactly one must pass.
* Rows: the located sensors sorted by y are cut at the widest gaps, measured in the two
  neighbours' sds; every cut at least CUT_SDS, every other gap under JOIN_SDS, every sensor
  within REACH_SDS of its row's centre. Failing the gaps, rows that slant apart may still
  be clear as straight lines. A sensor loose in y can bridge two rows, so the loosest are
  set aside until the rows are clear (none loose left: no grid).
* Columns: within each complete row the sensors are ranked along x. A column is clear if
  its centre is CUT_SDS typical sds from its neighbours' and its sensors are within
  REACH_SDS of it; an unclear column's sensors keep only their row.
* Loose sensors (set aside, on an incomplete row, or too loose to be located) join the
  one row or column within JOIN_SDS of them, if every other is beyond REACH_SDS and the
  odds for it against the next nearest are at least JOIN_ODDS to 1. A row they complete
  is then ranked along x as the complete rows were. One still without a row may join a
  column on x alone, then the one row free in that column.
* Refused: a located sensor out of reach of every row (a row was missed), a row with more
  sensors than columns, or complete rows that leave most sensors in unclear columns (rows
  that merge two wires rank the sensors of one column apart).

Ranking within rows is what places the extrapolated sensors, the ones the prior is for:
fitted 2-4 mm beyond the last probe column with a sd near 3 mm along x, they are still the
last of their rows. ``benchmarks/wire_inference.py`` checks the groups against the
simulator's wires; several of the rules above came from the wrong groupings it found, and
the comments below name those scenes.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

CUT_SDS = 4.0  # a gap between wires is at least this many sds of the sensors' positions
JOIN_SDS = 2.5  # neighbours on one wire (or a loose sensor and its wire) are closer, in sds
REACH_SDS = 3.0  # every sensor of a wire lies within this many sds of its centre
PRECISE_FACTOR = 2.0  # loose: sd above this multiple of the typical (median) sd
# A loose sensor joins a wire only at these odds against the next nearest (Gaussian in its
# sd). Between two wires they ask more than the reach rules (2.5 against 3 sds is 4 to 1);
# beyond the outermost wire they bound how loose a sensor may be (sd up to ~0.7 of the
# gap, at JOIN_SDS beyond). They replace "sd under half the gap": between two wires the
# reach rules already keep the sd under a third of it, so that rule refused, in effect,
# only sensors beyond the outermost wire, the ones the prior is for (Patch B finger, seed
# 338: S1 3.1 mm sd, 5 mm beyond the last row, 3.97 mm off; joined, 0.67 mm).
JOIN_ODDS = 100.0


class _Family(NamedTuple):
    """One family of wires, the rows or the columns: where each lies, how surely, and which
    may take a sensor that joins by reach (an unclear one is a candidate, never the answer).
    Rows may slant: each lies at ``centre + slope * (u - at)``, ``u`` the sensor's x."""

    centre: np.ndarray  # (k,) mm
    sd: np.ndarray  # (k,) sd of each centre
    clear: np.ndarray  # (k,) bool
    slope: np.ndarray | None = None  # (k,) mm per mm along the other axis; None: level
    at: float = 0.0  # where along the other axis ``centre`` lies

    def line(self, u) -> np.ndarray:
        """Each wire's coordinate at ``u`` along the other axis: (k,), or (k, n) for n."""
        u = np.asarray(u, float)
        shape = (-1,) + (1,) * u.ndim
        slope = np.zeros_like(self.centre) if self.slope is None else self.slope
        return self.centre.reshape(shape) + slope.reshape(shape) * (u - self.at)

    def reaches(self, v: float, sd_v: float, u: float = 0.0) -> np.ndarray:
        """(k,) is each wire within REACH_SDS of a sensor at ``v`` with sd ``sd_v``?"""
        return np.abs(self.line(u) - v) <= REACH_SDS * np.hypot(sd_v, self.sd)

    def holds(
        self, v: np.ndarray, sd_v: np.ndarray, j: np.ndarray, u: np.ndarray | None = None
    ) -> np.ndarray:
        """Is each sensor (at ``v``, sd ``sd_v``) within REACH_SDS of its own wire ``j``?"""
        at = self.centre[j] if u is None else self.line(u)[j, np.arange(len(j))]
        return np.abs(v - at) <= REACH_SDS * np.hypot(sd_v, self.sd[j])

    def join(self, v: float, sd_v: float, taken: np.ndarray | None = None, u: float = 0.0) -> int:
        """The wire a sensor at ``v`` joins, or -1: the one within JOIN_SDS while every other
        (but the ``taken``) is beyond REACH_SDS, at JOIN_ODDS against the next nearest."""
        z = np.abs(self.line(u) - v) / np.hypot(sd_v, self.sd)
        if taken is not None:
            z[taken] = np.inf
        near = np.flatnonzero(z <= REACH_SDS)
        if near.size != 1 or z[near[0]] >= JOIN_SDS:
            return -1
        j = int(near[0])
        others = np.delete(z, j)
        if others.size and others.min() ** 2 - z[j] ** 2 < 2.0 * math.log(JOIN_ODDS):
            return -1
        return j if self.clear[j] else -1


def infer_wires(
    xy: np.ndarray,
    sd: np.ndarray,
    located: np.ndarray,
    loose: np.ndarray,
    scatter_mm: float,
) -> tuple[np.ndarray, np.ndarray] | None:
    """(tx, rx) wire indices per sensor (-1: unknown), or None if no clear grid.

    ``xy`` (N, 2) fitted positions (mm), ``sd`` (N, 2) their sd along x and y; ``located``
    (N,) the sensors whose fits shape the grid, ``loose`` (N,) those too loose to be
    located by themselves, which only join the wires within their reach; ``scatter_mm``
    how far crossings lie from their wire's line (jitter, a gentle bend), added to each
    sd: a robot's 0.1 mm fits would otherwise split a wire.
    """
    n = len(xy)
    sd = np.hypot(sd, scatter_mm)
    finite = np.isfinite(xy).all(axis=1) & np.isfinite(sd).all(axis=1) & (sd > 0).all(axis=1)
    ok = located & finite
    if ok.sum() < 4:
        return None
    idx = np.flatnonzero(ok)
    ref = np.median(sd[idx], axis=0)  # typical sd along x and along y
    found = []
    for rows in range(2, n // 2 + 1):
        if n % rows:
            continue
        r = _rows(xy[:, 1], sd[:, 1], idx, rows, float(ref[1]), xy[:, 0])
        # No row may hold more sensors than there are columns.
        if r is None or np.bincount(r[0][r[0] >= 0], minlength=rows).max() > n // rows:
            continue
        gy, row_family = r
        gx, col_family = _columns(xy[:, 0], sd[:, 0], idx, gy, n // rows, rows, float(ref[0]))
        # Rows that merge two wires rank sensors of one column apart: columns then come out
        # unclear. A grid whose complete rows give mostly unclear columns is not this one.
        if col_family is not None and (gx[idx] >= 0).sum() < 0.5 * idx.size:
            continue
        found.append((gx, gy, row_family, col_family))
    if len(found) != 1:
        return None
    gx, gy, row_family, col_family = found[0]
    for i in np.flatnonzero(loose & finite & ~located):
        gy[i] = row_family.join(xy[i, 1], sd[i, 1], u=xy[i, 0])
        if gy[i] >= 0 and col_family is not None:
            held = gx[(gy == gy[i]) & (gx >= 0)]  # one sensor per crossing
            gx[i] = col_family.join(xy[i, 0], sd[i, 0], held)
    if col_family is not None:
        _rank_completed_rows(xy[:, 0], sd[:, 0], finite, gx, gy, col_family)
        _row_from_column(xy, sd, finite, gx, gy, row_family, col_family)
    return gx, gy


def _rank_completed_rows(
    x: np.ndarray,
    sd: np.ndarray,
    finite: np.ndarray,
    gx: np.ndarray,
    gy: np.ndarray,
    col_family: _Family,
) -> None:
    """Rank a row that its loose sensors completed, as the complete rows were, in place.

    A sensor of an incomplete row joins a column alone, at clear odds; two neighbours that
    are each unsure then both stay without one, though the row leaves them just the two
    columns. Patch B finger, seed 540 (cell centres): S28, beyond the last probe column
    (fitted 4 mm beyond, sd 3.5 mm along x), was too loose to be located, so its row was
    incomplete; S25, 0.7 mm from its column's centre and 1.4 mm from the next with a 1.3 mm
    sd, joined neither, and S28 reached both: no TX wire for either, and S28 4.0 mm off.
    Once the loose sensors have joined, a row with a sensor for every column is ranked along
    x, if the ranks agree with every column its sensors already hold, each column it gives
    is clear, and each sensor lies within reach of its column's centre.
    """
    cols = col_family.centre.size
    for r in np.unique(gy[finite & (gy >= 0)]):
        m = np.flatnonzero(finite & (gy == r))
        if m.size != cols or (gx[m] >= 0).all():
            continue
        m = m[np.argsort(x[m], kind="stable")]
        rank = np.arange(cols)
        held = gx[m] >= 0
        if (gx[m][held] != rank[held]).any() or not col_family.clear[rank[~held]].all():
            continue
        new = m[~held]
        if col_family.holds(x[new], sd[new], rank[~held]).all():
            gx[new] = rank[~held]


def _row_from_column(
    xy: np.ndarray,
    sd: np.ndarray,
    finite: np.ndarray,
    gx: np.ndarray,
    gy: np.ndarray,
    row_family: _Family,
    col_family: _Family,
) -> None:
    """Place a sensor no row takes by reach through its column, in place.

    A sensor loose along y reaches two rows, so it joins none, and a sensor without a row
    gets no column either: both its wires are lost, though its x is sharp. It joins a
    column on x alone, at the usual odds (not by elimination: a fit flung far off in x is
    no evidence of where it belongs); then, one sensor per crossing, the rows its
    column-mates hold are taken, and it joins the free row within its reach. Patch B
    finger, plan grid, seed 469: S1 fitted 3.6 mm beyond its row with a 9.5 mm sd along y
    reached two rows and kept no wire, 3.65 mm off; its column's other two rows were held.
    """
    rows = row_family.centre.size
    for i in np.flatnonzero(finite & (gy < 0) & (gx < 0)):
        c = col_family.join(xy[i, 0], sd[i, 0])
        held = gy[(gx == c) & (gy >= 0)]
        if c < 0 or held.size >= rows:
            continue
        gx[i] = c
        gy[i] = row_family.join(xy[i, 1], sd[i, 1], held, xy[i, 0])


def _rows(y: np.ndarray, sd: np.ndarray, idx: np.ndarray, k: int, ref: float, x: np.ndarray):
    """Rows 0..k-1 along y (labels, -1: none) and the rows as a family, or None if the
    rows are not clear.

    Gaps between neighbours in y are measured in their sds. The k-1 widest are the cuts;
    the rows are clear if every cut is at least CUT_SDS and every other gap under JOIN_SDS,
    or, failing that, if the rows are clear as slanted lines (_slanted_rows). A sensor
    whose fit is loose in y can bridge two rows, so while the rows are not clear the
    loosest sensor (sd above PRECISE_FACTOR x ``ref``) is set aside; those join the one row
    within their reach afterwards, if only one is (else -1). ``x`` (N,): where each sensor
    lies along the rows."""
    keep = idx[np.argsort(y[idx], kind="stable")]
    while keep.size >= k:
        ys, ss = y[keep], sd[keep]
        z = np.diff(ys) / np.hypot(ss[:-1], ss[1:])
        cuts = np.sort(np.argsort(z)[::-1][: k - 1])
        inner = np.delete(z, cuts)
        step = np.zeros(keep.size, int)
        step[cuts + 1] = 1
        lab = np.cumsum(step)
        if z[cuts].min() >= CUT_SDS and (inner.size == 0 or inner.max() < JOIN_SDS):
            family = _level_rows(ys, ss, lab, k)
            break
        family = _slanted_rows(x[keep], ys, ss, lab, k)
        if family is not None:
            break
        loosest = int(np.argmax(ss))
        if ss[loosest] <= PRECISE_FACTOR * ref:
            return None
        keep = np.delete(keep, loosest)
    else:
        return None
    labels = np.full(y.size, -1)
    labels[keep] = lab
    # A row is one wire: each of its sensors within reach of its centre. A chain of
    # sensors each close to the next can span two wires (Patch B 12 x 3 finger, seed 354:
    # 9 mm), which the gaps alone do not see.
    if not family.holds(y[keep], sd[keep], lab, x[keep]).all():
        return None
    # Every loose sensor, kept or set aside, by reach alone: where it fell in the sorted
    # order is no evidence (Patch B 12 x 3 robot, seed 317: one 11 mm sd in y, 20 mm off).
    # A sensor no row reaches refutes this many rows (a row of loose sensors was left
    # out, and its sensors would be pulled to a neighbour: Patch B 12 x 3 robot, seed 323).
    for i in idx[sd[idx] > PRECISE_FACTOR * ref]:
        if not family.reaches(y[i], sd[i], x[i]).any():
            return None
        labels[i] = family.join(y[i], sd[i], u=x[i])
    return labels, family


def _level_rows(y: np.ndarray, sd: np.ndarray, lab: np.ndarray, k: int) -> _Family:
    """Rows ``lab`` (0..k-1) of the sensors at ``y`` as level lines: weighted means."""
    w = 1.0 / sd**2
    wsum = np.bincount(lab, weights=w, minlength=k)
    centre = np.bincount(lab, weights=w * y, minlength=k) / wsum
    return _Family(centre, 1.0 / np.sqrt(wsum), np.ones(k, bool))


def _slanted_rows(
    x: np.ndarray, y: np.ndarray, sd: np.ndarray, lab: np.ndarray, k: int
) -> _Family | None:
    """Rows ``lab`` as slanted lines, if that makes them clear; else None.

    A wire that is displaced at one end and bent can come within 3 mm of its neighbour
    there, while sorted by y alone its crossings at the far end interleave with the
    neighbour's gap: Patch B finger, plan grid, seed 403, rows 3.3 mm apart at x = 6 and
    4.4 mm at x = 148 gave no clear cut, so no wires, and S1 at the corner stayed 2.4 mm
    off. Each row of three or more sensors gets a weighted straight line (the layout
    prior's own model of a wire); the rows are clear if every sensor lies within JOIN_SDS
    of its own row's line and at least CUT_SDS from every other row's, at its x.
    """
    # Weighted least squares for every row at once: the full board tries many row counts,
    # each a few times, inside a live update.
    w = 1.0 / sd**2
    at = float(np.average(x, weights=w))
    wsum = np.bincount(lab, weights=w, minlength=k)
    x0 = np.bincount(lab, weights=w * x, minlength=k) / wsum
    y0 = np.bincount(lab, weights=w * y, minlength=k) / wsum
    dx = x - x0[lab]
    sxx = np.bincount(lab, weights=w * dx**2, minlength=k)
    sxy = np.bincount(lab, weights=w * dx * (y - y0[lab]), minlength=k)
    sloped = (np.bincount(lab, minlength=k) >= 3) & (sxx > 0)
    slope = np.where(sloped, sxy / np.where(sloped, sxx, 1.0), 0.0)
    centre = y0 + slope * (at - x0)
    csd = 1.0 / np.sqrt(wsum)
    family = _Family(centre, csd, np.ones(k, bool), slope, at)
    z = np.abs(family.line(x) - y[None, :]) / sd[None, :]  # (k, n)
    own = z[lab, np.arange(lab.size)]
    z[lab, np.arange(lab.size)] = np.inf
    if own.max() < JOIN_SDS and z.min() >= CUT_SDS:
        return family
    return None


def _columns(x, sd, idx, gy, cols: int, rows: int, ref: float):
    """Columns by rank of x within each complete row, the other sensors at the one free
    column within their reach; -1 for every sensor of a column that is not clear (see the
    module docstring). Also the columns as a family (None: no complete row to rank)."""
    gx = np.full(len(x), -1)
    members = [idx[gy[idx] == r] for r in range(rows)]
    full = [m[np.argsort(x[m], kind="stable")] for m in members if m.size == cols]
    if not full:
        return gx, None
    for m in full:
        gx[m] = np.arange(cols)
    w = 1.0 / sd**2
    ranked = np.array(full)  # (F, cols) sensor indices
    wsum = w[ranked].sum(axis=0)
    # Each centre's sd: a column known from one loose sensor is no yardstick.
    family = _Family(
        (x[ranked] * w[ranked]).sum(axis=0) / wsum, 1.0 / np.sqrt(wsum), np.ones(cols, bool)
    )
    for m in members:
        if m.size == cols:
            continue
        # A sensor of an incomplete row takes a column only if that is the one free column
        # within its reach; nearest is not enough (Patch B 12 x 3 finger, seed 332: a
        # sensor 3.4 mm sd between the last two columns took the wrong one).
        for i in m[np.argsort(sd[m])]:  # the surest first
            gx[i] = family.join(x[i], sd[i], gx[m[gx[m] >= 0]])
    # Columns that cannot be told apart keep no wire: two whose centres are closer than
    # CUT_SDS typical sd (their sensors may have swapped ranks), and any column with a
    # sensor out of reach of its centre, with its neighbours (the rank may be off by one).
    unclear = np.zeros(cols, bool)
    close = np.diff(family.centre) <= CUT_SDS * ref
    unclear[:-1] |= close
    unclear[1:] |= close
    placed = idx[gx[idx] >= 0]
    far = gx[placed][~family.holds(x[placed], sd[placed], gx[placed])]
    for c in far:
        unclear[max(c - 1, 0) : c + 2] = True
    gx[(gx >= 0) & unclear[np.maximum(gx, 0)]] = -1
    return gx, family._replace(clear=~unclear)

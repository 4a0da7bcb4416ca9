"""Peaks no touch came near: placed by their tails alone, where the response shapes differ.

Why a module of its own: a sensor between two touches far apart (a sparse or adaptive plan's
gap) is fitted from the flanks of its bump, and its peak's place then depends on how the
bump's tail falls, which is the response shape's least certain part. The fit's covariance
assumes the shape is right. So a batch solve fits each such sensor again at the model's
other shapes and keeps how far that moves it (``shape_spread``), and the sensor's error bar
holds that distance (_statuses.judge). On an adaptive plan's coarse pass a sensor 6 mm from
the nearest touch was fitted 2 mm off with a 0.48 mm sigma, and the planner, taking it for
located, never came back to it (docs/benchmarks.md, "Peaks no touch came near").
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from varskin.localization import _peak_model as pm

if TYPE_CHECKING:
    from varskin.localization.peakfit import Localizer

# A peak is unseen when no touch saw this fraction of its fitted top: the nearest touch lies
# beyond the bump's half width (in its own widths and shape). On the 20 x 5 grids of the
# benchmarks every located sensor's nearest touch saw 0.62 or more.
UNSEEN_FRACTION = 0.5


def seen_height(
    loc: Localizer,
    theta: np.ndarray,
    cols: np.ndarray | None = None,
    rows: np.ndarray | None = None,
) -> np.ndarray:
    """How much of each fitted peak a touch has seen: the bump's height at its nearest touch
    (in the bump's own widths and shape) over its top, for sensors ``cols`` (default all),
    among touches ``rows`` (default all). A clipped reading counts (it saw the top
    saturate); a missed touch or a non-finite reading does not. ``theta`` holds the
    sensors' parameters, one row per sensor of ``cols``."""
    cols = np.arange(len(loc.sensors)) if cols is None else cols
    # All touches as a slice: a full board's (K, N) readings are not copied for a few columns.
    rows = slice(0, loc.n_logs) if rows is None else rows
    P = loc._P[rows] + loc._dxy[rows]
    if len(P) == 0:
        return np.zeros(cols.size)
    q = (P[:, 0:1] - theta[None, :, pm.SX]) ** 2 * np.exp(-2.0 * theta[None, :, pm.LW])
    q += (P[:, 1:2] - theta[None, :, pm.SY]) ** 2 * np.exp(-2.0 * theta[None, :, pm.LWY])
    V = loc._V[rows, cols] if isinstance(rows, slice) else loc._V[rows][:, cols]
    q[~np.isfinite(V) | loc._missed[rows, None]] = np.inf
    with np.errstate(invalid="ignore"):
        return np.nan_to_num(pm.profile(q.min(axis=0), 0.0, loc.settings.shape))


def shape_spread(loc: Localizer) -> None:
    """For every fitted sensor whose peak is unseen, how far the model's other response
    shapes move its fit (mm, the largest of them), into ``loc._shape_shift``.

    Each is fitted again warm, with the touches' nuisances held; the fits are put back
    afterwards, so no position changes here.
    """
    f = loc.fit
    cols = np.flatnonzero(f.has_model())
    cols = cols[seen_height(loc, f.theta[cols], cols) < UNSEEN_FRACTION]
    if cols.size == 0:
        return
    kept = f.copy_of(cols)
    current = loc.settings.shape
    moved = np.zeros(cols.size)
    try:
        for shape in pm.SHAPES:
            if shape == current:
                continue
            loc.settings = replace(loc.settings, shape=shape)
            loc._refit_warm(cols)
            d = np.hypot(*(f.theta[cols, :2] - kept["theta"][:, :2]).T)
            moved = np.maximum(moved, np.where(np.isfinite(d), d, 0.0))
            f.put(kept, cols)
    finally:
        loc.settings = replace(loc.settings, shape=current)
        f.put(kept, cols)
    loc._shape_shift[cols] = moved

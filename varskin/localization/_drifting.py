"""Sensors whose offset was still settling under their own touches: judged in millimetres,
re-fitted from the touches after the probe came back, and corrected where they pass.

Why a module of its own: the board's settling (_settling.py) is read from the sensors far
from each touch, in peak heights. Here the batch solve asks what it costs each fit: taking
the settling out of a sensor's readings and fitting again says whether the fit moved by
more than its error bar (a `drifting` reason), and a `drifting` sensor that the probe left
and came back to is fitted again from its later touches alone, where the floor was steady.
Last, a located sensor whose fit left part of the settling unfollowed is fitted again from
its readings with that settling taken out (``take_out_settling``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from varskin.localization import _peak_model as pm
from varskin.localization._maps import nanmedian_cols
from varskin.localization._settling import board_settling
from varskin.localization._statuses import (
    DRIFTING,
    drift_measures,
    drifting_during_own_touches,
    window_members,
)
from varskin.predictions import OK, R95_PER_AXIS_SD

if TYPE_CHECKING:
    from varskin.localization.peakfit import Localizer

# A `drifting` sensor probed again after the probe was away for more than this many
# touches' time is re-fitted from the touches since it came back (refit_after_settling).
REPROBE_AWAY_TOUCHES = 4
# The board's settling, taken out of a sensor's readings (moved_by_settling), must move its
# fit by more than this many of its first-order sigmas and this many mm for `drifting`;
# only sensors with more than SETTLING_CHECK_FRACTION of their peak unfollowed are re-fitted
# to see. Session 38 tried it at 2 sigma and no floor in mm: on Patch B robot it flagged 24
# of 158 re-fitted sensors, 3 of them beyond 2 sigma. With the floor, results are identical
# on Patch A and B, robot and finger, seeds 300-329, patch given (and Patch B finger
# without); on board seeds 0-7 (robot 50 x 20, no patch) seed 1's S1 (2.20 mm off at 5.5
# sigma) is flagged and re-placed from the scan's next pass, 0.46 mm off; the stress table
# locates 10 fewer of 15,214 (docs/benchmarks.md, "Settling measured in millimetres").
SETTLING_MOVE_SIGMAS = 3.0
SETTLING_MOVE_MM = 1.0
SETTLING_CHECK_FRACTION = 0.05
# take_out_settling smooths the board's settling course over this many touches (a running
# median in time): the course's per-touch noise, times a level of up to ~120 counts, would
# otherwise become noise in every corrected reading.
COURSE_MEDIAN_TOUCHES = 5


def settling_of(loc: Localizer) -> tuple[np.ndarray, np.ndarray] | None:
    """The board's settling from the fits as they stand (_settling.py); None where the
    values are not relative to a measured rest (no baseline: no settling to speak of)."""
    if loc.rest is None:
        return None
    K, f = loc._k, loc.fit
    V = np.where(loc._missed[:K, None], np.nan, loc._V[:K] * loc._sign)
    w = pm.half_width(f.theta)
    usable = f.has_model()
    with np.errstate(all="ignore"):
        noise = nanmedian_cols(loc._noise[:K])
    if loc.rest_sd is not None:  # logs without sample sds: the baseline's
        noise = np.where(np.isfinite(noise), noise, loc.rest_sd)
    P = loc._P[:K] + loc._dxy[:K]

    def bump(rows: np.ndarray) -> np.ndarray:
        # The fitted models less their floors, at those touches, in the readings' units
        # (asked for only where some touch has no far sensor).
        zero = np.zeros((rows.size, f.theta.shape[0]))
        gain, rho = np.exp(loc._lg[rows]), loc._ridge_width(f.theta)
        with np.errstate(all="ignore"):
            u = pm.model(P[rows], zero, f.theta, gain, rho, loc.settings.shape)
            u = u - pm.floor(zero, f.theta)
        return np.where(usable, u * f.amp, np.nan)

    return board_settling(V, P, loc._tau(), f.theta[:, :2], w, usable, noise, bump)


def moved_by_settling(loc: Localizer, inside: np.ndarray) -> np.ndarray:
    """(N,) bool: the sensors whose fit, warm re-fitted with the board's settling (as
    ``settling_of`` read it) taken out of their readings, moves by more than
    SETTLING_MOVE_SIGMAS of its own first-order sigma and SETTLING_MOVE_MM; ``inside``
    the touches in each fit's window (``window_members``).

    The settling the fit did not follow is judged in peak heights (``unfollowed``), and
    a small fraction can still cost millimetres: on a full board's robot grid (6 x 10
    mm) the corner sensor probed first was 2.2 mm off at 5.5 sigma with only 0.13 of
    its peak unfollowed. The re-fit says it in millimetres. It judges; it does not
    correct: on a 30-sensor patch the settling is read from few far sensors, and there
    a re-fit that moved a sensor 2.4 mm took it to 5.8 mm off (docs/benchmarks.md,
    "Settling measured in millimetres").
    """
    n = len(loc.sensors)
    out = np.zeros(n, bool)
    if loc._settling is None:
        return out
    K, f = loc._k, loc.fit
    course, level = loc._settling
    with np.errstate(all="ignore"):
        _, unfollowed = drift_measures(loc, inside)
    cols = np.flatnonzero(f.has_model() & (unfollowed > SETTLING_CHECK_FRACTION))
    if cols.size == 0:
        return out
    settled = np.nan_to_num(level[cols][None, :] * course[:K, None])  # peak-up units
    kept = f.copy_of(cols)
    before = f.theta[cols, :2].copy()
    sd = np.sqrt(np.maximum(np.trace(f.cov_xy[cols], axis1=1, axis2=2) / 2.0, 0.0))
    try:
        _refit_without(loc, cols, settled, loc._refit_warm)
        moved = np.hypot(*(f.theta[cols, :2] - before).T)
    finally:
        f.put(kept, cols)
    sigma = sd * R95_PER_AXIS_SD / 2.0
    out[cols] = (moved > SETTLING_MOVE_SIGMAS * sigma) & (moved > SETTLING_MOVE_MM)
    return out


def refit_after_settling(loc: Localizer, inside: np.ndarray) -> None:
    """Re-fit each `drifting` sensor from the touches since the probe came back to it
    (``inside``: the touches in each fit's window, ``window_members``).

    A sensor probed first while its offset still settled is `drifting` however often it
    is probed again: its first touches stay in its window, and the slow floor model
    cannot follow them. Its later touches, once re-probed, see a steady floor and place
    it alone. The re-fit is kept only where it passes every check (`drifting` included,
    judged on the touches it used); otherwise the sensor keeps its fit and its status.
    """
    f = loc.fit
    with np.errstate(all="ignore"):
        drifting = drifting_during_own_touches(loc, inside)
    cols = np.flatnonzero(f.fitted & drifting)
    if cols.size == 0:
        return
    tau = loc._tau()
    inside = inside[:, cols]
    # The probe must have left and come back: a pass that merely went on over the
    # sensor (a serpentine grid's next columns) is the same settling, seen from one side.
    away = REPROBE_AWAY_TOUCHES * float(np.median(np.diff(tau))) if tau.size > 1 else 0.0
    for j, c in enumerate(cols):
        t = np.sort(tau[inside[:, j]])
        back = np.flatnonzero(np.diff(t) > away)
        if away > 0 and back.size:
            loc._t_from[c] = t[back[0] + 1]
    cols = cols[np.isfinite(loc._t_from[cols])]
    if cols.size == 0:
        return
    kept = loc._refit(cols)
    # The settling check judged the touches the re-fit no longer uses.
    moved = loc._moved_by_settling[cols].copy()
    loc._moved_by_settling[cols] = False
    failed = loc._statuses()[cols] != OK
    if failed.any():
        loc._restore(cols, kept, failed)
        loc._t_from[cols[failed]] = -np.inf
        loc._moved_by_settling[cols[failed]] = moved[failed]


def smoothed_course(course: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """The settling's time course (``course``, (K,), NaN where no far sensor told) at every
    touch: interpolated in session time ``tau`` over the gaps, then a running median over
    COURSE_MEDIAN_TOUCHES touches in time order; zeros where fewer than two touches tell."""
    known = np.isfinite(course)
    if known.sum() < 2:
        return np.zeros_like(course)
    order = np.argsort(tau, kind="stable")
    t, c = tau[order], course[order]
    filled = np.interp(t, t[known[order]], c[known[order]])
    half = COURSE_MEDIAN_TOUCHES // 2
    # The window shrinks at the session's ends rather than repeating the first touch.
    smooth = np.array([np.median(filled[max(0, k - half) : k + half + 1]) for k in range(t.size)])
    out = np.empty_like(smooth)
    out[order] = smooth
    return out


def take_out_settling(loc: Localizer) -> None:
    """Fit again, from a cold start, each located sensor whose fit left more than
    SETTLING_CHECK_FRACTION of its peak of the board's settling unfollowed, from its
    readings with that settling (level x smoothed course) taken out.

    Sensors `ok` or `drifting` are corrected; a `drifting` one stays `drifting` (without
    that, Patch B finger seed 494's S3 went to `ok` at 3.31 mm), but its corrected fit
    still places its wire for the others (Patch A finger seed 490: S2 2.71 -> 1.42 mm with
    S1 corrected, 2.46 mm without). A re-fit that fails a check is judged like any fit.
    The readings are put back as logged: a live update adds its raw touches to them (kept
    corrected, the next touch stood a whole settled level off the older ones, and the live
    view of Patch B robot seeds 0-15 ended up to 4.9 mm from the batch). The settling the
    judge sees for the corrected sensors is nil; how far the re-fit moved each of them is
    kept (``_settling_shift``) for its error bar (_statuses.SETTLING_SHIFT_RMS).

    Each sensor is fitted afresh: two warm polish rounds of every sensor and touch on the
    corrected readings took seed 490's S2 to 3.34 mm instead (docs/benchmarks.md, "The
    board's settling taken out of the readings").
    """
    if loc._settling is None or loc._k < 3:
        return
    f = loc.fit
    course, level = loc._settling
    inside = window_members(loc, f.theta[:, :2], pm.half_width(f.theta), loc.spacing())
    with np.errstate(all="ignore"):
        _, unf = drift_measures(loc, inside)
    status = loc._statuses()
    passing = (status == OK) | (status == DRIFTING)
    # A sensor re-fitted from its later touches (refit_after_settling) already left the
    # settling behind: taken out again, two re-probed weak sensors of the hard cases went
    # from within 2 sigma to just beyond it.
    fresh = ~np.isfinite(loc._t_from)
    cols = np.flatnonzero(f.has_model() & passing & fresh & (unf > SETTLING_CHECK_FRACTION))
    cols = cols[np.isfinite(level[cols])]
    if cols.size == 0:
        return
    loc._held_drifting[cols] = status[cols] == DRIFTING
    settled = level[cols][None, :] * smoothed_course(course, loc._tau())[:, None]
    before = f.theta[cols, :2].copy()
    _refit_without(loc, cols, settled, loc._refit)
    moved = np.hypot(*(f.theta[cols, :2] - before).T)
    loc._settling_shift[cols] = np.where(np.isfinite(moved), moved, 0.0)
    level = level.copy()
    level[cols] = 0.0
    loc._settling = (course, level)


def _refit_without(loc: Localizer, cols: np.ndarray, settled: np.ndarray, refit) -> None:
    """``refit(cols)`` on sensors ``cols``' readings less ``settled`` ((K, len(cols)), peak-up
    units); the readings are as logged again afterwards, whatever the re-fit did."""
    K = loc._k
    V = loc._V[:K, cols].copy()
    try:
        loc._V[:K, cols] = V - settled * loc._sign
        refit(cols)
    finally:
        loc._V[:K, cols] = V

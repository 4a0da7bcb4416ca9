"""One touch into a live session: the sensors it informs re-fitted, fast and local.

Why a module of its own: a live update must cost milliseconds (issue 3: <= 5 ms for 30
sensors and 100 logs, <= 20 ms for a full board), so it re-fits only the sensors near the
new touch, warm-started and for a few iterations, plus any sensor whose map the touch shows
to peak elsewhere; the batch solve (``Localizer.result()``) re-solves from the data alone.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from varskin.localization import _peak_model as pm
from varskin.localization._design_reach import touch_added
from varskin.localization._maps import nanmedian_cols
from varskin.localization._statuses import SPARSE, judge
from varskin.localization._unseen import UNSEEN_FRACTION, seen_height
from varskin.pointlogs import PointLog
from varskin.predictions import OK, Predictions

if TYPE_CHECKING:
    from varskin.localization.peakfit import Localizer

# LM iterations of a live update's re-fit (warm-started): 3 is the fewest the fit's stop
# rule runs. Against 4, on Patch B seeds 0-15, robot and finger, updates 50-100: the live
# RMS of the `ok` sensors is lower (median 0.22-0.27 against 0.24-0.34 mm robot, 0.80
# against 0.82-0.87 mm finger), 0.3-0.5 fewer of ~17 sensors are `ok`, and the last
# update's largest gap to the batch is about the same (1.1-1.6 sigma either way).
UPDATE_ITERATIONS = 3
# A reading this far above a sensor's last RECENT_TOUCHES readings, beyond what its model's
# bump predicts at a touch outside its window (in the map's heights, and in residual
# sigmas), makes a live update restart that sensor from its map's top.
UNEXPLAINED_HEIGHT = 0.5
UNEXPLAINED_SIGMAS = 5.0
RECENT_TOUCHES = 6
# The new touch's gain and placement stop iterating once a step is under this many of
# their priors' sds. A robot's touch (placed to ~0.05 mm) is often there after two steps
# (19 of 30 on Patch B seed 0, within 4e-4 sd of three), which saves the third; a
# finger's nearly always takes all three.
NUISANCE_STEP_TOL = 0.01


def update(loc: Localizer, log: PointLog) -> Predictions:
    """Add one touch and return the updated estimates of every sensor (fast, local).

    The sensors near the new touch are re-fitted, warm-started; then the touch's own
    gain and placement are estimated from those models, and the sensors whose view of
    the touch that changes are re-fitted with the next touch. Every time the session doubles,
    everything is re-solved from scratch. The estimates call a fit `sparse` while no touch
    has seen half of its peak (``live_judge``). ``result()`` gives the batch solve.
    """
    if not loc._append(log):
        return loc._current()
    loc._dirty = True
    k = loc._k - 1
    sign = loc._detect_sign()
    h = loc.spacing()
    f = loc.fit
    shape = loc.settings.shape
    if (
        sign != loc._sign
        or loc._spacing_used is None
        or abs(h - loc._spacing_used) > 0.1 * loc._spacing_used
        or loc._k >= loc._next_full
    ):
        # Re-solve everything when the session has doubled (or its scale changed): the
        # shared footprint and the touch nuisances settle, and the cost stays amortized.
        loc._next_full = max(2 * loc._k, 8)
        loc.solve_all(final=False)
        return loc._current()
    p = loc._P[k]  # the touch's own placement offset is estimated below
    w = pm.half_width(f.theta)
    radius = np.maximum(loc.settings.window_widths * w, loc.settings.window_spacings * h) * 1.5
    near = np.hypot(f.theta[:, pm.SX] - p[0], f.theta[:, pm.SY] - p[1]) < radius
    # A new maximum of the map far from the current estimate that the model cannot
    # explain: the peak may be elsewhere, so that sensor restarts from its map's top.
    v_new = loc._V[k] * loc._sign
    with np.errstate(invalid="ignore"):
        before = np.nanmax(loc._V[:k] * loc._sign, axis=0) if k else np.full_like(v_new, -np.inf)
    u_new = (v_new - f.floor) / f.amp
    above_fit = u_new > f.theta[:, pm.B0] + f.theta[:, pm.AMP]
    new_top = np.isfinite(v_new) & (v_new > before) & above_fit & ~near
    # ... or a reading that rises above the sensor's last few readings (its floor
    # here and now: the probe was elsewhere) by more than half the map's height where
    # its model has no bump: a peak the model does not have. Without this, a fit that
    # put its peak beyond the probes early on, from a drifting floor, was never
    # re-fitted when the probe later passed over the sensor, whose readings stayed
    # under the session's first ones (Patch B finger seed 7: S15 ended 98 mm off, ok).
    # The model's own floor is no reference far from its window: it is a polynomial
    # in time fitted to the touches near the sensor only.
    if k:
        recent = nanmedian_cols(loc._V[max(0, k - RECENT_TOUCHES) : k] * loc._sign)
        ridge = loc._ridge_width(f.theta)
        zero = np.zeros((1, len(loc.sensors)))
        bump = pm.model(p[None], zero, f.theta, None, ridge, shape)[0] - pm.floor(zero, f.theta)[0]
        rise = (v_new - recent) / f.amp - bump
        new_top |= (
            np.isfinite(rise)
            & (rise > UNEXPLAINED_HEIGHT)
            & (rise > UNEXPLAINED_SIGMAS * f.scale)
            & ~near
            & f.fitted
        )
    # One pass over both, and over the sensors the last touch's gain and placement left
    # for this one (below): a restarted sensor begins at its map's top (a good start) and
    # the following updates refine it, so a few iterations suffice here too.
    todo = np.flatnonzero(near | new_top | loc._refit_next)
    # The last batch solve's settling verdict judged maps these sensors have outgrown.
    loc._moved_by_settling[todo] = False
    if todo.size:
        loc._solve(todo, ~new_top[todo], max_iter=UPDATE_ITERATIONS, live=True)
    # The new touch's own gain and placement come from the models it has just updated
    # (judged by models that had not seen it, a first touch near a sensor would be
    # "explained" by a wrong offset).
    loc._touch_nuisances(np.array([k]), step_tol=NUISANCE_STEP_TOL)
    # Where they change what the touch says (a robot's placement is good to ~0.05 mm:
    # usually nowhere), the sensor is re-fitted with the next touch rather than in a
    # second pass now: that pass cost a whole fit on most of a finger's updates, and
    # waiting one touch leaves the live view as good (docs/benchmarks.md, session 57).
    th = f.theta[todo]
    rho = loc._ridge_width(th)
    zero = np.zeros((1, todo.size))
    m0 = pm.model(loc._P[k : k + 1], zero, th, None, rho, shape)[0]
    m1 = pm.model(
        loc._P[k : k + 1] + loc._dxy[k], zero, th, np.exp(loc._lg[k : k + 1]), rho, shape
    )[0]
    loc._refit_next[:] = False
    loc._refit_next[todo] = np.abs(m1 - m0) > np.maximum(f.scale[todo], 1e-12)
    # How much of each peak its nearest touch saw: the re-fitted sensors' afresh, and for
    # the others, whose fits and earlier touches did not move, the new touch may be nearer.
    seen = seen_height(loc, f.theta[todo], todo) if todo.size else None
    if loc._live_seen is not None:
        np.maximum(
            loc._live_seen, seen_height(loc, f.theta, rows=np.array([k])), out=loc._live_seen
        )
        if todo.size:
            loc._live_seen[todo] = seen
    # A peak this touch came near is seen now; one still unseen keeps the spread the last
    # batch solve measured for it (_unseen.py).
    if todo.size and loc._shape_shift[todo].any():
        loc._shape_shift[todo] *= seen < UNSEEN_FRACTION
    # The reported verdict's distances from the design positions: this touch may be nearer.
    touch_added(loc, k)
    return loc._current()


def live_judge(loc: Localizer) -> tuple:
    """``judge`` for the live view: an `ok` sensor whose fitted peak no touch has seen half
    of yet (_unseen.seen_height under UNSEEN_FRACTION) is `sparse` there.

    Mid-session, a sensor on a part of the patch not yet probed has only its RX wire's
    ridge in its map, and a bump between two probed columns fits that as well as a peak
    does: the live view called such sensors `ok` many millimetres off. The batch solve
    (``result()``, which the planner and the session's result use) keeps them, with the
    response shapes' spread in their error bars: a sparse plan needs them located.
    """
    status, xy, sigma, snr, params = judge(loc)
    if loc._live_seen is None:
        loc._live_seen = seen_height(loc, loc.fit.theta)
    status[(status == OK) & (loc._live_seen < UNSEEN_FRACTION)] = SPARSE
    return status, xy, sigma, snr, params

"""How wide each sigma must be, measured by re-running the solve on sessions simulated from
the fit itself (a parametric bootstrap).

Why a module of its own: a sensor's sigma is its fit's covariance plus the touches'
placement and gain scatter propagated to first order, with the placement scatter the
solver's EM estimate. That is the right shape but not the right size, and the error runs
both ways: on dense 20 x 5 grids the EM scale is 1.25-1.5x what is left of the touches'
offsets after they are estimated, so 2 sigma covered 98-99% of sensors; on sparse 12 x 3
finger grids the sensors absorb the offsets, EM sees a third of the true scatter, and 2
sigma covered 83-88% (benchmarks/localizer_coverage.py). No first-order formula sees how
much of the placement error the sensors absorb, but the solver itself can be asked.

The check builds sessions whose truth is known: the sensors are the fitted models, the
touches land at the estimated points plus fresh placement errors of the estimated scale
and press with fresh gains, and each reading in a fit's window gets back its real residual
from the fit, the residuals of one touch all with one random sign (a wild bootstrap, by
touch). The same solve runs on them (without this check), and the errors of its ``ok``
sensors against the models they came from, in units of their own sigmas, say how far off
the sigmas are. Every sigma is then scaled by one factor per solve, so the ranking of
sensors by uncertainty stays the solver's own; positions do not change (but for the wires
a settled solve infers without a patch, _statuses._inferred_wires). Deterministic
(seeded by the session's readings), so a batch solve and the live session's ``result()``
agree exactly. On 20 x 5 and 12 x 3 grids, 2 sigma then covers 0.95-0.98 of ``ok`` sensors
(benchmarks/localizer_coverage.py, docs/benchmarks.md).
"""

from __future__ import annotations

import copy
import math
import zlib
from typing import TYPE_CHECKING

import numpy as np

from varskin.localization import _peak_model as pm
from varskin.localization._statuses import judge
from varskin.predictions import OK, R95_PER_AXIS_SD

if TYPE_CHECKING:
    from varskin.localization.peakfit import Localizer

# Enough (error / sigma) samples for the scale factor to be good to ~7%: replicates are
# added until this many ok sensors were checked, up to MAX_REPLICATES.
TARGET_SAMPLES = 60
MAX_REPLICATES = 2
MIN_SAMPLES = 20  # fewer checked sensors than this: the factor would be noise; left at 1
# Sessions with this many modelled sensors check a band of about BAND_SENSORS of them
# (checked_part): twice TARGET_SAMPLES, so that the band's cut sides, where touches lost
# the sensors beyond, are a small part of it; below, the band would save little.
BAND_FROM = 180
BAND_SENSORS = 2 * TARGET_SAMPLES
CUT_SEARCH = BAND_SENSORS // 8  # how far (in sensors) a band's end may move to a wider gap
# E|e/sigma|^2 for a calibrated sigma: e is 2-D Gaussian with per-axis sd s and
# sigma = s R95_PER_AXIS_SD / 2, so E|e|^2 / sigma^2 = 2 / (R95_PER_AXIS_SD / 2)^2.
CALIBRATED_Z2 = 2.0 / (R95_PER_AXIS_SD / 2.0) ** 2
# One wild sensor in a small session must not set everyone's error bar: ratios are
# winsorized at 4 (beyond the 99.9th percentile of a calibrated sigma's).
Z_CAP = 4.0
# The factor a solve may apply. Up to 3x: a check on a simulation is not a licence to
# rewrite the propagation. Down to 0.8 only: the check's truth is the fit's own model, so
# it cannot see the error of a response shape the model lacks, which the wider
# first-order sigma partly covers. On 20 x 5 grids the check asks for 0.74-0.80; let down
# that far, the scenes with another response shape (tests/test_localizer.py MISMATCH) lost
# up to 0.10 of their coverage (finger, Gaussian shape: 0.92 at 0.8, 0.83 unfloored;
# 30 seeds per 20 x 5 row, one per mismatch scene and patch, in a one-off sweep).
SCALE_RANGE = (0.8, 3.0)
# A settled finger solve (peakfit.SETTLE_ROUNDS) has estimated its touches' offsets nearly
# as far as they go, and the placement scatter its first-order sigma still propagates whole
# is then wider than what is left: the check asks for 0.60-0.64 on 20 x 5 finger grids.
# Floored at 0.8 they covered 0.992-0.994; floored at 0.6, 0.946-0.955, and over every
# variant of benchmarks/localizer_stress.py the finger rows cover 0.88-0.98, the Gaussian
# and exponential shapes included (docs/benchmarks.md, "Settling finger solves").
SETTLED_FLOOR = 0.6
# ... and a settled solve that kept its joint rounds (peakfit.JOINT_SETTLE_ROUNDS) is nearer
# the model's optimum still: its check asks for 0.49-0.68 (Patch A finger scenes with
# another response shape, tests/test_localizer.py MISMATCH), and at the 0.6 floor 8 finger
# rows of the stress variants solved without a patch covered 0.981-0.987 (seeds 500-509; 7
# rows at 0.981-0.995 on 510-519). At 0.5 none is above 0.98 on either seed set, and two
# fall below 0.90 on 510-519 (0.872, 0.898; docs/benchmarks.md, "Joint rounds where the
# design pins one axis only").
JOINT_KEPT_FLOOR = 0.5


def simulated_session(loc: Localizer, rng: np.random.Generator) -> tuple[Localizer, np.ndarray]:
    """A copy of ``loc`` whose readings are simulated from its own fits; and which sensors
    were simulated (the others keep their real readings: they have no model to draw from)."""
    f = loc.fit
    K = loc.n_logs
    model_ok = f.has_model()
    cols = np.flatnonzero(model_ok)
    sim = copy.deepcopy(loc)
    if cols.size == 0:
        return sim, model_ok
    th = f.theta[cols]
    rho = loc._ridge_width(th)
    t = loc._tau()
    tau = t[:, None] - f.tc[cols][None, :]
    at = loc._P[:K] + loc._dxy[:K]
    real = loc._V[:K, cols] * loc._sign
    # What the models leave of the real readings, touch by touch: noise, the part of each
    # touch's landing error its offset did not catch, and whatever of the response the
    # model lacks (a wrong shape). Each touch's residuals keep their pattern across the
    # sensors and get one random sign: a landing error stays a possible landing error and
    # noise stays noise, while a wrong shape weighs as much as it does in the real data
    # (on the scenes with another response shape, an earlier version of this check with
    # Gaussian noise of the residuals' size gave 67-86% coverage with the robot; these
    # residuals give 85-96%, one-off runs).
    shape = loc.settings.shape
    fitted = pm.model(at, tau, th, np.exp(loc._lg[:K]), rho, shape)
    resid = np.nan_to_num((real - f.floor[cols]) / f.amp[cols] - fitted)
    # A fit's residuals are smaller than its noise: its N_PARAMS parameters took up part of
    # it. Scaled back as the residual variance's own degrees of freedom say.
    n_eff = np.maximum(f.n_eff[cols], 2.0 * pm.N_PARAMS)
    resid *= np.sqrt(n_eff / (n_eff - pm.N_PARAMS))[None, :]
    flip = rng.choice([-1.0, 1.0], size=(K, 1))
    landed = at + rng.normal(0.0, loc.place_sd_mm, (K, 2))
    gains = np.exp(rng.normal(0.0, loc.gain_sd, K))
    u = pm.model(landed, tau, th, gains, rho, shape) + flip * resid
    values = (f.floor[cols] + f.amp[cols] * u) * loc._sign
    # Only what a fit saw can be simulated from it: beyond its window the model's floor is
    # a quadratic in time extrapolated over the whole session, and mirrored residuals
    # there were swings of many heights, which sent fits wide and cost 3x the real solve.
    # There the readings stay as measured (a bump moved by its new landing is nil there).
    min_radius = loc.settings.window_spacings * loc.spacing()
    seen = pm.window(at, th, min_radius, loc.settings) > 0
    seen &= t[:, None] >= loc._t_from[cols][None, :]
    # A touch judged missed had no contact, and a missing reading stays missing: those real
    # values stay, and the copy judges them again.
    keep = ~seen | loc._missed[:K, None] | ~np.isfinite(real)
    sim._V[:K, cols] = np.where(keep, loc._V[:K, cols], values)
    return sim, model_ok


def checked_part(loc: Localizer, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray] | None:
    """The sensors and the touches a large session's check re-solves (increasing indices),
    or None: all of them.

    A board's replicate is a second batch solve of every sensor, nearly half the batch
    solve's time, though ~60 checked sensors size the factor. Where at least BAND_FROM
    sensors have a model, the check re-solves a band of about BAND_SENSORS of them, across
    the patch and contiguous along its longer axis (by fitted position), from a random
    place along it and wrapping round its end, so that every sensor is as likely to be
    checked, the patch's edges included. Its ends are cut at the widest gaps between the
    sorted positions near them, on a grid between two wires. With the band go the touches
    whose nearest modelled sensor is in it, as if the session had probed the band alone:
    the touches beyond inform none of its fits but, kept, hold the EM estimates of the
    touches' scatter nearer their priors (robot board, seed 0: 0.155 mm placement scatter
    with the touches inside the band's fit windows, 0.128 mm with those it owns, 0.117 mm
    in the whole solve). On robot-probed boards the band asked for 0.98x the whole check's
    factor on average over 12 seeds (0.86-1.11x each); on finger-probed ones 0.88x (6
    seeds; the band's errors and sigmas 11-15% above the whole solve's on the same
    sensors, seeds 0 and 1), so a settled (finger-like) solve checks the whole
    (docs/benchmarks.md, "A board's error-bar check on a band").
    """
    model_ok = np.flatnonzero(loc.fit.has_model())
    n = model_ok.size
    if n < BAND_FROM or loc._settled:
        return None
    xy = loc.fit.theta[model_ok, :2]
    axis = int(np.ptp(xy[:, 1]) > np.ptp(xy[:, 0]))
    sort = np.argsort(xy[:, axis], kind="stable")
    gap = np.empty(n)
    gap[1:] = np.diff(xy[sort, axis])
    gap[0] = np.inf  # the wrap, from the last sensor back to the first: the patch's edges

    def cut_near(i: int) -> int:
        near = (i + np.arange(-CUT_SEARCH, CUT_SEARCH + 1)) % n
        return int(near[np.argmax(gap[near])])

    first = cut_near(int(rng.integers(0, n)))
    size = (cut_near(first + BAND_SENSORS) - first) % n
    if size == 0:
        return None
    cols = np.sort(model_ok[sort[(first + np.arange(size)) % n]])
    P = loc._P[: loc.n_logs]
    d2 = (P[:, None, 0] - xy[None, :, 0]) ** 2 + (P[:, None, 1] - xy[None, :, 1]) ** 2
    rows = np.flatnonzero(np.isin(model_ok[np.argmin(d2, axis=1)], cols))
    return cols, rows


def band_session(loc: Localizer, sim: Localizer, part: tuple[np.ndarray, np.ndarray]) -> Localizer:
    """``sim`` cut to ``part`` (checked_part), its verdict to use the wires ``loc``'s last
    verdict used (none, if it found none). A band that cuts a grid's wires short is no
    full grid, and its own inference (which wants one) found no wires in it."""
    cols, rows = part
    sub = sim._subset(cols, rows)
    wires = loc._verdict_wires
    if wires is None:
        sub.params = {**sub.params, "infer_wires": False}
    else:
        sub.groups = (wires[0][cols], wires[1][cols])
    return sub


def _seed(loc: Localizer) -> int:
    """A seed drawn from the session's own readings: the same logs give the same sigmas,
    and different sessions get independent simulations (one fixed seed would give every
    session the same draws, and so the same error in its factor)."""
    K = loc.n_logs
    data = np.ascontiguousarray(np.nan_to_num(loc._V[:K], nan=0.0, posinf=0.0, neginf=0.0))
    return zlib.crc32(data.tobytes()) ^ zlib.crc32(np.ascontiguousarray(loc._P[:K]).tobytes())


def sigma_scale(loc: Localizer, final: bool = True) -> float:
    """The factor by which ``loc``'s sigmas must grow (> 1) or shrink to be honest, as
    measured on sessions simulated from its fits; 1 where too few sensors can be checked.
    ``final``: the kind of solve ``loc`` took (solve_all), which the simulated ones repeat."""
    n_ok = int(np.sum(judge(loc)[0] == OK))
    if n_ok == 0:
        return 1.0
    replicates = min(MAX_REPLICATES, max(1, math.ceil(TARGET_SAMPLES / n_ok)))
    rng = np.random.default_rng(_seed(loc))
    part = checked_part(loc, rng)
    truth = loc.fit.theta[:, :2].copy()
    if part is not None:
        truth = truth[part[0]]
    z2: list[np.ndarray] = []
    for _ in range(replicates):
        sim, simulated = simulated_session(loc, rng)
        if part is not None:
            sim, simulated = band_session(loc, sim, part), simulated[part[0]]
        sim.solve_all(calibrate=False, final=final)
        status, xy, sigma, _, _ = judge(sim)
        ok = (status == OK) & simulated & np.isfinite(xy).all(axis=1) & (sigma > 0)
        z = np.linalg.norm(xy[ok] - truth[ok], axis=1) / sigma[ok]
        z2.append(np.minimum(z, Z_CAP) ** 2)
    z2_all = np.concatenate(z2)
    if z2_all.size < MIN_SAMPLES:
        return 1.0
    factor = math.sqrt(float(np.mean(z2_all)) / CALIBRATED_Z2)
    low = SCALE_RANGE[0]
    if loc._settled:
        low = JOINT_KEPT_FLOOR if loc._joint_kept else SETTLED_FLOOR
    return float(np.clip(factor, low, SCALE_RANGE[1]))

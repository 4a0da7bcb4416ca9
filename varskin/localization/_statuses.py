"""From the fits to what the user gets: each sensor's status, position and sigma.

Why a module of its own: the solver (peakfit.py) fits a peak to every sensor's map; whether
that fit is a position worth reporting is a separate set of judgements, made in one place
and in a fixed order: too few touches, clipped, collinear probes, dead, beyond the probes'
hull, a fit that failed its sanity checks, too loose; then weak and drifting. The hull
prior and the wires' layout prior move the positions and set the error bars here too,
because they decide which loose fits may still be placed. docs/localizer.md lists the
statuses.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from varskin.localization import _peak_model as pm
from varskin.localization._hull import HULL_PRIOR, hull_distance, pull_into_hull
from varskin.localization._layout_prior import both_axes, shrink_to_layout
from varskin.localization._maps import packed, span_by_sensor
from varskin.localization._settling import unfollowed
from varskin.localization._wire_inference import infer_wires
from varskin.predictions import OK, R95_PER_AXIS_SD
from varskin.scene import ADC_MAX

if TYPE_CHECKING:
    from varskin.localization.peakfit import Localizer

# Statuses (one word each; see docs/localizer.md)
DEAD = "dead"  # no response above the noise
SATURATED = "saturated"  # the sensor's readings sit at the ADC limit
SPARSE = "sparse"  # too few usable touches near the sensor (or in total)
COLLINEAR = "collinear"  # the probes lie on a line: one coordinate is unobservable
OUTSIDE = "outside"  # the peak lies beyond the probed area: extrapolation refused
UNCERTAIN = "uncertain"  # the fit is too loose to trust (sigma above max_sigma_mm)
# The peak fit failed its sanity checks (not converged, footprint out of range, wandered
# from the map's top, residuals too large for a single peak): no position is reported. A
# centroid fallback was tried and rejected: on such maps its error is unbounded.
IRREGULAR = "irregular"
WEAK = "weak"  # peak far below the other sensors': not probed near it, or damaged
# The sensor's offset moved by more than DRIFT_FRACTION of its peak during its own touches:
# the floor model (a slow quadratic) cannot follow a settling that fast, and the part it
# misses shifts the peak by up to ~2.7 mm with a sigma of ~0.5 mm (a weak sensor probed
# first while the board settles). Re-probe near it once the offsets are steady.
DRIFTING = "drifting"
DRIFT_FRACTION = 0.5
# ... or the board's settling, as the sensors far from its touches saw it, moved its floor
# during its own touches by more than this fraction of its peak beyond what its fitted floor
# followed (_settling.py). On 160 default finger scenes (Patch B seeds 360-459, Patch A
# 360-419, cell centres, no patch) a prototype of the check at 0.35 flagged 2 of 4,308
# located sensors, one of them the only sensor above 2 mm (2.38 mm at 5.2 sigma); 0.3
# flagged 5 and 0.2 flagged 24. As committed it flags 3 of Patch B's 2,996 there (fitted
# peaks 0.58, 1.75 and 2.78 mm off; docs/benchmarks.md, "Settling the fit did not follow").
UNFOLLOWED_FRACTION = 0.35
# ... or taking that settling out of its readings moves its fit too far for its error bar
# (_drifting.moved_by_settling, judged in each batch solve).
WEAK_FRACTION = 0.35  # real sensors' peaks span ~0.5x-3.5x their median
# ... or its map rises above its slow floor less than this fraction of the located sensors'
# rises (their upper decile): no touch came near it, and what was fitted is the ridge its
# wire leaves where the probe crossed it (~4 % of a peak), or noise. Mid-session the
# fitted-peak test above cannot see these: most `ok` calls are such fits then, and the
# median it compares with is theirs (docs/benchmarks.md, "A partial session's far-off `ok`
# calls"). The rise is taken above the floor's trend, not its median: a sensor probed first
# while its offset settled rose only 0.07 of the upper decile above its median.
WEAK_RISE = 0.1
# The error of the settling taken out of a sensor's readings (_drifting.take_out_settling),
# RMS over both axes, as a multiple of how far taking it out moved the sensor's fit. At 1,
# 2 sigma covers 0.957 of the corrected `ok` robot sensors of benchmarks/localizer_stress.py
# (0.907 without it; finger 0.960 and 0.954). The sessions the error-bar check simulates
# are not corrected, so its factor cannot see this error (docs/benchmarks.md, "The
# settling taken out, in the error bar").
SETTLING_SHIFT_RMS = 1.0


def judge(loc: Localizer) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
    """Every sensor's status, position (N, 2), sigma (N,) and SNR (N,), and the result's
    params, from ``loc``'s last solve."""
    n = len(loc.sensors)
    f = loc.fit
    K = loc.n_logs
    params = {k: v for k, v in loc.params.items() if k not in ("patch", "wires") and v is not None}
    params["n_logs"] = K
    # The solver's own estimates of how the touches scattered (per axis, mm) and how their
    # pressing gain varied (log sd): a diagnostic of the session (docs/localizer.md).
    params["touch_placement_sd_mm"] = float(loc.place_sd_mm)
    params["touch_gain_sd"] = float(loc.gain_sd)
    # The error-bar check's factor on every sigma (1: not run, or nothing to change).
    params["sigma_scale"] = float(loc._sigma_scale)
    # The bump's profile the fits used, and the paired z of the best other one (the more
    # negative, the more the maps favoured it; absent: not tested).
    params["response_shape"] = loc.settings.shape
    if loc._shape_z is not None:
        params["response_shape_z"] = loc._shape_z
    # A settled solve's joint rounds: the placement scatter they implied over the one they
    # were held to, and whether they were kept (peakfit.JOINT_SETTLE_GUARD).
    if loc._joint_ratio is not None:
        params["joint_settle_ratio"] = loc._joint_ratio
        params["joint_settle_kept"] = loc._joint_kept
    status = np.array([OK] * n, dtype=object)
    snr = _snr(loc)
    if K < 3 or loc._n_distinct < 3:
        status[:] = SPARSE
        return status, np.zeros((n, 2)), np.zeros(n), snr, params
    th = f.theta
    xy = th[:, :2].copy()
    h = loc.spacing()
    w = pm.half_width(th)
    margin = np.maximum(0.5 * h, 0.5 * w)
    dist_out, normal, collinear = hull_distance(loc._probe_hull(), xy)
    # Judged on the fit itself: beyond the hull by more than the margin AND by more than
    # 1.5 sd of the fit along the edge's normal. A one-sided fit that merely ran away (its
    # sd along the normal dwarfs the distance) is not evidence of a peak outside; the hull
    # prior then brings it back to where the data put it, with the sigma that implies.
    xy, var, sd_out = pull_into_hull(xy, f.cov_xy, dist_out, normal, HULL_PRIOR * margin)
    outside = (dist_out > margin) & (dist_out > 1.5 * sd_out)
    finite = np.isfinite(th).all(axis=1) & np.isfinite(var)
    valid_counts = np.isfinite(loc._V[:K]).sum(axis=0)
    snr_fit = th[:, pm.AMP] / np.maximum(f.noise, 1e-12)
    weak_model = f.scale > 0.35 * np.maximum(th[:, pm.AMP], 1e-12)
    # Per-axis sd: the fit's covariance (scaled by its residuals, so model mismatch counts)
    # plus the touches' placement and gain scatter propagated through the fit.
    sd = np.sqrt(var)
    sd = np.hypot(sd, 0.002 * h)
    # What the last batch solve measured its error bars to be off by (_error_bar.py). It
    # may widen them, and then max_sigma_mm judges the wider sigma; a narrowing is not
    # applied to the verdict: the check measures the sensors that behave, and a lone fit
    # that went astray (sigma 5.9 mm, 90 mm off, in a test) must stay `uncertain` rather
    # than pass at 0.8x.
    to_sigma = loc._sigma_scale * R95_PER_AXIS_SD / 2.0
    judged = max(loc._sigma_scale, 1.0) * R95_PER_AXIS_SD / 2.0
    moved = np.hypot(xy[:, 0] - f.start[:, 0], xy[:, 1] - f.start[:, 1])
    sane = (
        finite
        & f.converged
        & (f.n_eff >= pm.MIN_FIT_TOUCHES)
        & ~weak_model
        & (moved <= np.maximum(2.0 * w, 2.0 * h))
        & (w > 0.1 * h)
        & (w < 20.0 * h)
    )
    at_fit = window_members(loc, th[:, :2], w, h)
    # The first reason that holds, in this order (a sensor gets one status).
    reasons = [
        (~f.fitted | (valid_counts < 3), SPARSE),
        (_rest_saturated(loc) | (K - f.n_clipped < 3), SATURATED),
        (np.full(n, collinear), COLLINEAR),
        (~finite | (snr_fit < loc.params["min_snr"]) | (th[:, pm.AMP] <= 0), DEAD),
        (outside, OUTSIDE),
        (~sane | loc._two_peaks, IRREGULAR),
        (sd * judged > loc.params["max_sigma_mm"], UNCERTAIN),
    ]
    for cond, reason in reversed(reasons):
        status[cond] = reason
    # A clipped sensor that could not be located from its unclipped flanks: clipping is why.
    status[(status != OK) & (status != SPARSE) & (f.n_clipped > 0)] = SATURATED
    # A "peak" far weaker than the other sensors' is a wire ridge or crosstalk, not the
    # sensor's own peak (not probed near it yet, or a damaged sensor).
    raw_amp = th[:, pm.AMP] * f.amp
    ok = status == OK
    if ok.sum() >= 3:
        ref = WEAK_FRACTION * np.median(raw_amp[ok])
        weak = ok & (raw_amp < ref)
        status[weak] = WEAK
    # Judged after `weak`: a sensor not yet probed near, whose "peak" is a wire ridge,
    # says so first.
    drifting = drifting_during_own_touches(loc, at_fit)
    status[(status == OK) & drifting] = DRIFTING
    ok = status == OK
    # A sensor whose own fit is too loose in one coordinate (beyond the last probe column,
    # only one flank seen) but passed every other check may be placed by its wires.
    loose = status == UNCERTAIN
    floor = float(loc.params["wire_scatter_mm"])
    # Where the layout prior's wires come from, also told to the user ("none": no clear
    # grid in the fits).
    groups, params["wires"] = loc.groups, "patch" if loc.params["patch"] is not None else "given"
    if not loc.params["layout_prior"]:
        groups, params["wires"] = None, "off"
    elif groups is None:
        params["wires"] = "none"
        if loc.params["infer_wires"]:
            # Inferred afresh every time, the live updates too: in a trial, wires kept from
            # the last re-solve put a full board's last update up to 0.87 mm from the batch
            # (0.08). Per axis: a sensor beyond the last probe column is loose along x only.
            axes = np.maximum(np.diagonal(f.cov_xy, axis1=1, axis2=2), 0.0)
            with np.errstate(invalid="ignore", divide="ignore"):
                axes = axes * (sd**2 / np.maximum(axes.mean(axis=1), 1e-300))[:, None]
            groups = _inferred_wires(loc, xy, np.sqrt(axes), ok, loose, floor)
            if groups is not None:
                params["wires"] = "inferred"
    loc._verdict_wires = groups
    if groups is not None and ok.sum() >= 2:
        tx, rx = groups
        # Sensors on one wire see largely the same touches, so the part of their error that
        # comes from where those touches landed moves them together: pooling the wire's
        # crossings averages only their own parts; the shared part stays in the error bar.
        # How much they share is how many touches their fit windows have in common.
        touch_part = np.clip(np.nan_to_num(f.var_touch), 0.0, sd**2)
        # The windows at the reported positions: those at the fits, except for the sensors
        # the hull prior moved (a full board's live update cannot afford a second pass).
        inside = at_fit.copy()
        moved = np.flatnonzero((xy != th[:, :2]).any(axis=1))
        if moved.size:
            inside[:, moved] = window_members(loc, xy[moved], w[moved], h, moved)
        use = ok | loose  # a loose sensor informs its wire's line only with its own weight
        # Both wire families in one call: a live update runs this.
        overlap = _mean_overlap(
            np.hstack([inside, inside]), both_axes(tx, rx), np.concatenate([use, use])
        )
        shared_x = touch_part * overlap[: len(use)]
        shared_y = touch_part * overlap[len(use) :]
        xy, vx, vy = shrink_to_layout(
            xy, sd**2, tx, rx, use, floor, (shared_x, shared_y), loc.design
        )
        sd = np.where(use, np.sqrt((vx + vy) / 2.0), sd)
        # Judged again after the prior: placed within max_sigma_mm and not weak, it is ok.
        placed = loose & ~drifting & (sd * judged <= loc.params["max_sigma_mm"])
        if ok.sum() >= 3:
            placed &= raw_amp >= WEAK_FRACTION * np.median(raw_amp[ok])
        status[placed] = OK
    # `drifting` before the settling was taken out of its readings: its corrected fit
    # places its wires above, like an `ok` one, but it is not reported
    # (_drifting.take_out_settling).
    status[(status == OK) & loc._held_drifting] = DRIFTING
    # The settling taken out of a sensor's readings was itself an estimate; its error joins
    # the error bar but weighs in no position (_drifting.take_out_settling).
    shift = loc._settling_shift
    sd = np.sqrt(sd**2 + (SETTLING_SHIFT_RMS * shift) ** 2 / 2.0)
    # A peak no touch came near: its place hangs on the response's tail, and the model's
    # other shapes moved it by _shape_shift (_unseen.py). That much RMS joins its error
    # bar, after the layout prior (weighed by it, the wires pulled robot sensors that their
    # flanks had placed well: docs/benchmarks.md, "Peaks no touch came near"); one it
    # takes beyond max_sigma_mm is `uncertain`.
    sd = np.sqrt(sd**2 + loc._shape_shift**2 / 2.0)
    too_loose = (loc._shape_shift > 0) & (sd * judged > loc.params["max_sigma_mm"])
    status[(status == OK) & too_loose] = UNCERTAIN
    for key, mm, which in (
        ("settling_taken_out_mm", shift, shift > 0),
        ("shape_spread_mm", loc._shape_shift, (loc._shape_shift > 0) & (status == OK)),
    ):
        if which.any():
            params[key] = {loc.sensors[i]: round(float(mm[i]), 4) for i in np.flatnonzero(which)}
    sigma = sd * to_sigma
    return status, xy, sigma, snr, params


def unrisen_weak(loc: Localizer, status: np.ndarray) -> np.ndarray:
    """The reported verdict's last check: an `ok` sensor whose map rose above its slow floor
    less than WEAK_RISE of the `ok` sensors' rises (their upper decile) is `weak`.

    Only what the user gets: the solve's own uses of the verdict (the error-bar check, the
    second-peak and settling re-fits, the layout prior's wires) see ``judge`` as before. Let
    into ``judge``, the check changed those, and on partial sessions the layout prior then
    placed loose sensors of wires no touch had crossed, `ok` and ~100 mm off
    (docs/benchmarks.md, "A partial session's far-off `ok` calls").
    """
    ok = status == OK
    if ok.sum() < 3:
        return status
    rise = loc.fit.rise
    return np.where(ok & (rise < WEAK_RISE * np.quantile(rise[ok], 0.9)), WEAK, status)


def _inferred_wires(
    loc: Localizer,
    xy: np.ndarray,
    sd: np.ndarray,
    ok: np.ndarray,
    loose: np.ndarray,
    floor: float,
) -> tuple[np.ndarray, np.ndarray] | None:
    """``infer_wires`` for a settled solve at the sds the error-bar check measured, if it
    narrowed them; else, or if no grid is clear there, at the first-order sds ``sd``.

    A settled finger solve's first-order sds are up to 1.7x its errors (_error_bar.py's
    factor is 0.6-0.75 on Patch B finger scenes), and rows 6 mm apart blurred at them:
    Patch B finger 20 x 5 scenes declined 13 of 60, and 4 kept a sensor above 2 mm. At the
    measured sds (and with the join odds of _wire_inference), 1 declines and none keeps one
    (benchmarks/wire_inference.py, localizer_seeds.py). The wider sds stay the fallback:
    their reach rules let a sensor that one factor under-sizes (a corner) stay on its wire.
    Not for a robot solve: narrowed by its 0.8 factor, its scattered touches on Patch B
    gave 3 wrong groupings in 60 scenes instead of 1. A live update judges with the last
    batch solve's factor, as its sigmas do."""
    groups = None
    if loc._settled and loc._sigma_scale < 1.0:
        groups = infer_wires(xy, sd * loc._sigma_scale, ok, loose, floor)
    if groups is None:
        groups = infer_wires(xy, sd, ok, loose, floor)
    return groups


def drift_measures(loc: Localizer, inside: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two (N,) measures, in fitted peak heights, of how far each sensor's floor moved across
    the touches in its own fit window (``inside``, (K, N) from ``window_members`` at the
    fitted peaks): its fitted floor's span (inf where there is no peak), and how far the
    board's settling moved it beyond what that floor followed (0 where the last batch solve
    saw no settling; _settling.py)."""
    f = loc.fit
    n = inside.shape[1]
    # Only the touches in each window count: their (touch, sensor) pairs, sensor by sensor.
    cols, rows = np.nonzero(inside.T)
    fl = pm.floor(loc._tau()[rows] - f.tc[cols], f.theta[cols])  # in the map's units
    span = span_by_sensor(fl, cols, n)
    amp = f.theta[:, pm.AMP]
    with np.errstate(all="ignore"):
        own = np.where(amp > 0, span / np.where(amp > 0, amp, 1.0), np.inf)
    if loc._settling is None:
        return own, np.zeros(n)
    course, level = loc._settling
    fitted_floor = fl * f.amp[cols] + f.floor[cols]
    return own, unfollowed(course, level, fitted_floor, rows, cols, amp * f.amp)


def drifting_during_own_touches(loc: Localizer, inside: np.ndarray) -> np.ndarray:
    """(N,) bool: the sensor's offset settled during its own touches faster than its fit
    followed, by either of ``drift_measures`` (DRIFT_FRACTION, UNFOLLOWED_FRACTION), or the
    last batch solve found that settling moves its fit too far (``_drifting.moved_by_settling``)."""
    own, missed = drift_measures(loc, inside)
    return (
        (np.isfinite(own) & (own > DRIFT_FRACTION))
        | (missed > UNFOLLOWED_FRACTION)
        | loc._moved_by_settling
    )


def window_members(
    loc: Localizer, xy: np.ndarray, w: np.ndarray, h: float, cols: np.ndarray | None = None
) -> np.ndarray:
    """(K, N) bool: the touches inside each sensor's fit window (``cols``: which sensors
    ``xy`` and ``w`` are, if not all)."""
    s = loc.settings
    radius = np.maximum(s.window_widths * w, s.window_spacings * h)
    P = loc._P[: loc.n_logs] + loc._dxy[: loc.n_logs]
    dx = P[:, 0:1] - xy[None, :, 0]
    dy = P[:, 1:2] - xy[None, :, 1]
    inside = dx * dx + dy * dy <= (radius * radius)[None, :]
    t_from = loc._t_from if cols is None else loc._t_from[cols]
    if np.isfinite(t_from).any():  # re-fitted after settling: only the later touches
        inside &= loc._tau()[:, None] >= t_from[None, :]
    return inside


def _mean_overlap(inside: np.ndarray, groups: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """(N,) for each sensor, the mean fraction of touches it shares with its usable
    wire-mates (|A and B| / sqrt(|A| |B|)); 1 where it has none (nothing to average)."""
    n = inside.shape[1]
    out = np.ones(n)
    gids = np.unique(groups[groups >= 0])
    member = (groups[None, :] == gids[:, None]) & usable[None, :]  # (G, N)
    member &= (member.sum(axis=1) >= 2)[:, None]
    if not member.any():
        return out
    # Every wire at once, padded to (G, M) like the layout prior: a live update calls
    # this every touch.
    order, mask = packed(member, axis=1)
    M = order.shape[1]
    # Counts of shared touches: float32 holds them exactly (a session of up to 2^24
    # touches), at half the memory traffic of float64, and the float64 result is the same.
    A = (inside[:, order] & mask[None]).astype(np.float32).transpose(1, 2, 0)  # (G, M, K)
    common = (A @ A.transpose(0, 2, 1)).astype(float)
    counts = inside.sum(axis=0).astype(float)[order]
    norm = np.sqrt(counts[:, :, None] * counts[:, None, :])
    frac = np.where(norm > 0, common / np.maximum(norm, 1e-12), 0.0)
    mates = mask[:, :, None] & mask[:, None, :] & ~np.eye(M, dtype=bool)[None]
    mean = (frac * mates).sum(axis=2) / np.maximum(mates.sum(axis=2), 1)
    out[order[mask]] = mean[mask]
    return out


def _rest_saturated(loc: Localizer) -> np.ndarray:
    """(N,) sensors whose no-contact reading already sits at the ADC limit."""
    n = len(loc.sensors)
    if loc.rest is None or not loc._raw_counts():
        return np.zeros(n, bool)
    sd = loc.rest_sd if loc.rest_sd is not None else np.ones(n)
    margin = np.maximum(3.0 * np.where(np.isfinite(sd), sd, 1.0), 1.0)
    with np.errstate(invalid="ignore"):
        return (loc.rest >= ADC_MAX - margin) | (loc.rest <= margin)


def _snr(loc: Localizer) -> np.ndarray:
    """SNR_i = 20 log10((max_k mean S_ik - S_i0) / sigma_i0), the paper's equation."""
    n = len(loc.sensors)
    out = np.full(n, np.nan)
    if loc.rest_sd is None or loc.n_logs == 0:
        return out
    with np.errstate(all="ignore"):
        peak = np.nanmax(loc._V[: loc.n_logs] * loc._sign, axis=0)
        out = 20.0 * np.log10(peak / loc.rest_sd)
    return out

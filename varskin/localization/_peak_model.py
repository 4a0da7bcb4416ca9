"""Batched robust fit of a peak to many sensors' point log maps at once.

Why a private module: the fit is the numerical core of the ``peakfit`` localizer and is
shared by its batch solve and its live updates.

The model of one sensor's map, in that sensor's normalized units, is

    m(p, t) = b0 + b1 tau + b2 tau^2
              + G (a / (1 + (x - sx)^2 / wx^2 + (y - sy)^2 / wy^2) + c_rx R(y - sy) + c_tx R(x - sx))

a bump at the sensor position ``s`` of height ``a`` and half widths ``wx``, ``wy`` along the
wires (a crossing's footprint is not round), narrow ridges ``R`` where the probe
couples along the sensor's own RX and TX wires, ``G`` the touch's pressing gain, over a
floor that may drift smoothly in session time (``tau`` in minutes from the sensor's peak
time, so weak priors on slope and curvature keep drift from mimicking a shift of the peak
when the probe scans in order and time runs along x). Only the neighbourhood
of the peak is fitted (a compact window of radius ~2.5 w), so the far tails, whose shape the
model does not know, never matter; residuals get Cauchy weights so missed touches, outliers
and a wrong shape cannot drag the estimate. All sensors are solved together with a
vectorized Levenberg-Marquardt (numpy, no per-sensor Python loop), which keeps a full board
fast.

The bump shown is the Lorentzian, ``phi(q) = 1 / (1 + q)`` of the squared normalized distance
``q``. ``FitSettings.shape`` swaps in a Gaussian, ``2^-q``, or an exponential in distance,
``2^-sqrt(q)`` (rounded off within 5% of the half width so the fit has a gradient at the
top): every one is at half height at ``q = 1``, so the half widths, and the window built
from them, mean the same in all three.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass

import numpy as np

from varskin.localization._maps import packed

SHAPES = ("lorentzian", "gaussian", "exponential")
_LN2 = float(np.log(2.0))
_TIP = 0.05  # the exponential's rounded top, in half widths
_TIP_NORM = float(np.sqrt(1.0 + _TIP**2) - _TIP)
N_PARAMS = 10  # sx, sy, log wx, log wy, a, b0, b1, b2, ridge along RX (y = sy), along TX
SX, SY, LW, LWY, AMP, B0, B1, B2, CRX, CTX = range(N_PARAMS)
WIDTHS = slice(LW, LWY + 1)  # both log widths, as a view
# Effective touches (window weights) a fit needs to be judged at all: fewer, and a fit
# with this many parameters follows the touches it has, whatever the peak is.
MIN_FIT_TOUCHES = 6.0
MIN_WIDTH_SPACINGS = 0.3  # a footprint much narrower than the probe spacing is unresolvable
MAX_WIDTH_SPACINGS = 15.0
# A touch's nuisances stay within these: its log pressing gain, and its placement offset
# per axis (offset_limit, which also bounds one step of the offset's estimate).
LOG_GAIN_RANGE = (-3.0, 1.0)
RIDGE_FRACTION = 0.35  # a wire ridge's width across the wire, in footprint half widths
# From this many points on, ``window`` takes the cosine only where the taper is between 0
# and 1. Below it the masks cost more than the cosines they save: a third more at 400
# points (a live update's fit), a quarter less at 3,000 (a one-off micro-benchmark).
_TAPER_ONLY_SIZE = 2048
# A fit's sensors are split into at most this many groups of similar neighbourhood size, a
# group's call overhead counted as this many (touch, sensor) points of array work
# (_reach_groups; docs/benchmarks.md, "The fit's sensors in groups").
GROUPS_MAX = 4
GROUP_COST = 4000
GROUP_CUTS = 256  # where the groups may be cut: exactly up to this many sensors


def offset_limit(place_sd_mm: float) -> float:
    """How far (mm, per axis) a touch's estimated offset may lie: 4 placement sds."""
    return 4.0 * place_sd_mm + 0.1


@dataclass(frozen=True)
class FitSettings:
    """Knobs of the fit; defaults are chosen for robustness, not tuned to one scene."""

    window_widths: float = 2.5  # fit radius in peak half-widths (response >= ~14% of the peak)
    window_spacings: float = 2.0  # ... but never less than this many probe spacings
    cauchy_c: float = 3.0  # residuals beyond ~c robust sigmas lose weight quickly
    drift_prior_sd: float = 0.2  # floor slope prior, peak heights per minute (weak)
    drift_curve_prior_sd: float = 0.03  # floor curvature prior, peak heights per minute^2
    drift_prior_tail: float = 2.0  # the slope prior is Cauchy: Gaussian-like within ~2 sd
    width_prior_sd: float = 1.0  # log-width prior around the starting width (weak)
    aspect_prior_sd: float = 0.4  # prior on log(wx / wy): footprints are roughly round
    shared_width_sd: float = 0.25  # log-width spread of sensors around the shared footprint
    ridge_prior_sd: float = 0.1  # wire-ridge height prior, in peak heights
    max_iter: int = 100
    step_tol_mm: float = 2e-4
    # The error bars (and n_eff) from the last iteration's normal equations, at the fit
    # before its last step, instead of from one more pass at the fit's end: for a live
    # update's three warm iterations, where that pass was about 5 % of the update. The fit
    # itself is the same. A re-fit the live view reports `ok` has converged, its last step
    # under 0.02 spacings (~0.1 mm; or none taken); one still moving is `irregular` there
    # (docs/benchmarks.md, "A live update's fixed costs, and its re-fits' error bars from
    # the last iteration"). Used only where every sensor took the last iteration.
    cov_at_last_iteration: bool = False
    shape: str = "lorentzian"  # the bump's profile, one of SHAPES


def _xy(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Probe x, y broadcastable against (., S): P is (K,2) shared or (M,S,2) per sensor."""
    if P.ndim == 2:
        return P[:, 0:1], P[:, 1:2]
    return P[..., 0], P[..., 1]


def _per_touch(G: np.ndarray) -> np.ndarray:
    return G[:, None] if G.ndim == 1 else G


def profile(rx: np.ndarray, ry: np.ndarray, shape: str = "lorentzian") -> np.ndarray:
    """The bump's height at squared normalized distance ``q = rx + ry``: 1 at the top, 1/2
    at q = 1."""
    if shape == "lorentzian":
        return 1.0 / (1.0 + rx + ry)
    if shape == "gaussian":
        return np.exp(-_LN2 * (rx + ry))
    return np.exp(-_LN2 * (np.sqrt(rx + ry + _TIP * _TIP) - _TIP) / _TIP_NORM)


def fall(g: np.ndarray, rx: np.ndarray, ry: np.ndarray, shape: str) -> np.ndarray:
    """How fast the bump ``g = profile(rx, ry, shape)`` falls with q: -d phi / d q."""
    if shape == "lorentzian":
        return g * g
    if shape == "gaussian":
        return _LN2 * g
    return (0.5 * _LN2 / _TIP_NORM) * g / np.sqrt(rx + ry + _TIP * _TIP)


def bump(P: np.ndarray, theta: np.ndarray, shape: str = "lorentzian"):
    """Shape g, the x and y parts of the squared normalized distance, inverse widths^2,
    and the signed distances from the peak (which the Jacobian and the ridges reuse).

    Shapes broadcast: theta (S,P) against probes (K,2) gives (K,S); theta (R,M,P) (sensors
    gathered per touch) against probes (R,2) gives (R,M).
    """
    iwx = np.exp(-2.0 * theta[..., LW])
    iwy = np.exp(-2.0 * theta[..., LWY])
    X, Y = _xy(P)
    dx = X - theta[..., SX]
    dy = Y - theta[..., SY]
    rx = dx * dx * iwx
    ry = dy * dy * iwy
    return profile(rx, ry, shape), (rx, ry), (iwx, iwy), (dx, dy)


def half_width(theta: np.ndarray) -> np.ndarray:
    """The footprint's half width (mm) of each fit in ``theta`` (..., N_PARAMS): the
    geometric mean of its x and y half widths."""
    return np.exp(0.5 * (theta[..., LW] + theta[..., LWY]))


def window(P: np.ndarray, theta: np.ndarray, min_radius: float, s: FitSettings) -> np.ndarray:
    """Compact fit window (K,S): 1 inside R, cosine taper to 0 at 1.5 R, exactly 0 beyond."""
    w = half_width(theta)
    radius = np.maximum(s.window_widths * w, min_radius)
    X, Y = _xy(P)
    dx, dy = X - theta[..., SX], Y - theta[..., SY]
    if dx.size < _TAPER_ONLY_SIZE:
        return _taper(np.hypot(dx, dy), radius)
    # Most of a full board's (M, S) points lie well inside R or well beyond 1.5 R, where the
    # taper is exactly 1 or 0 (cos 0 = 1 and cos pi = -1 in floating point too), and the
    # squared distance, with a margin far above its rounding error, says which: the
    # distance and the cosine only for the others give the same values, bit for bit.
    q = dx * dx + dy * dy
    r2 = radius * radius
    inner = q < r2 * (1.0 - 1e-9)
    mid = ~inner & ~(q > r2 * (2.25 * (1.0 + 1e-9)))  # NaN too: it stays NaN
    out = inner.astype(float)
    out[mid] = _taper(np.hypot(dx[mid], dy[mid]), np.broadcast_to(radius, q.shape)[mid])
    return out


def clamp(x, lo, hi):
    """``np.clip(x, lo, hi)``: the same values (NaN stays NaN) at a fraction of its call
    overhead, which counts in the fits' loops and a live update's."""
    return np.minimum(np.maximum(x, lo), hi)


def _taper(d: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """The window's weight at distances ``d`` from the peak: 1 up to ``radius`` R, a cosine
    down to 0 at 1.5 R, 0 beyond."""
    u = clamp((d / radius - 1.0) * 2.0, 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * u))


def ridges(P, theta, rho, d=None):
    """Coupling along the sensor's own wires: narrow ridges at y = sy (RX) and x = sx (TX).

    ``rho`` (S,) is the ridge width; ``d`` the signed distances (dx, dy) if already known;
    returns the two profiles and their signed distances.
    """
    if d is None:
        X, Y = _xy(P)
        dx, dy = X - theta[..., SX], Y - theta[..., SY]
    else:
        dx, dy = d
    r2 = 1.0 / (rho * rho)
    return np.exp(-0.5 * dy * dy * r2), np.exp(-0.5 * dx * dx * r2), dx, dy, r2


def model(P, tau, theta, G=None, rho=None, shape="lorentzian"):
    """Model values (K,S); ``G`` (K,) is each touch's relative pressing gain (default 1)."""
    g, _, _, dxy = bump(P, theta, shape)
    if G is not None:
        g = g * _per_touch(G)
    m = floor(tau, theta) + theta[..., AMP] * g
    if rho is not None:
        ry, rx, _, _, _ = ridges(P, theta, rho, dxy)
        gg = 1.0 if G is None else _per_touch(G)
        m = m + gg * (theta[..., CRX] * ry + theta[..., CTX] * rx)
    return m


def floor(tau, theta):
    """The sensor's floor over session time: offset, slope and curvature.

    ``tau`` (K,S) is each touch's time in minutes relative to the sensor's own peak time, so
    the priors on slope and curvature mean the same for early and late sensors.
    """
    return theta[..., B0] + (theta[..., B1] + theta[..., B2] * tau) * tau


def jacobian(
    P, tau, theta, G=None, rho=None, shape="lorentzian", sensor_major: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Model (K,S) and its Jacobian (K,S,N_PARAMS).

    ``sensor_major``: the Jacobian's memory is laid out (S, N_PARAMS, K), the order
    ``normal_equations`` reads, which then needs no transposing copy of it (for (K,S)
    shapes only; the values are the same).
    """
    g, (rx, ry), (iwx, iwy), dxy = bump(P, theta, shape)
    a = theta[..., AMP]
    # The Lorentzian's product in its own order: the same floating-point result as before
    # the other shapes came, so the benchmarks of it still hold to the last bit.
    k2 = 2.0 * a * g * g if shape == "lorentzian" else 2.0 * a * fall(g, rx, ry, shape)
    if G is not None:
        k2 = k2 * _per_touch(G)
        g = g * _per_touch(G)
    if sensor_major:
        J = np.empty((g.shape[1], N_PARAMS, g.shape[0])).transpose(2, 0, 1)
    else:
        J = np.empty(g.shape + (N_PARAMS,))
    J[..., SX] = k2 * dxy[0] * iwx
    J[..., SY] = k2 * dxy[1] * iwy
    J[..., LW] = k2 * rx
    J[..., LWY] = k2 * ry
    J[..., AMP] = g
    J[..., B0] = 1.0
    J[..., B1] = tau
    J[..., B2] = tau * tau
    m = floor(tau, theta) + a * g
    J[..., CRX] = 0.0
    J[..., CTX] = 0.0
    if rho is not None:
        ry, rx, dx, dy, r2 = ridges(P, theta, rho, dxy)
        gg = 1.0 if G is None else _per_touch(G)
        cy, cx = theta[..., CRX], theta[..., CTX]
        J[..., CRX] = gg * ry
        J[..., CTX] = gg * rx
        J[..., SY] += gg * cy * ry * dy * r2
        J[..., SX] += gg * cx * rx * dx * r2
        m = m + gg * (cy * ry + cx * rx)
    return m, J


def normal_equations(w: np.ndarray, J: np.ndarray, r: np.ndarray):
    """J^T W J (S,P,P) and J^T W r (S,P) for every sensor, as batched matrix products."""
    Jt = np.ascontiguousarray(J.transpose(1, 2, 0))  # (S, P, M)
    Jw = Jt * w.T[:, None, :]
    return Jw @ Jt.transpose(0, 2, 1), (Jw * r.T[:, None, :]).sum(axis=2)


def sensor_priors(
    S: int, s: FitSettings, width_mean: np.ndarray | None, lw_start: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian priors of every sensor's parameters: precision Q (S,P,P) and mean (S,P).

    Drift curvature ~ 0, wire ridges small, log widths near ``width_mean`` (the probe's
    footprint, shared by all sensors) or, without it, weakly near ``lw_start``. The floor
    slope's prior is heavy-tailed (Cauchy) and lives in ``prior_cost_of`` and
    ``prior_hessian_of``: a gentle drift is shrunk towards none, but a sensor whose data
    clearly show a fast drift (probed first while its offset still settles) is not forced to
    explain it by moving its peak. The curvature keeps a Gaussian prior: a free curved floor
    could form a hump in time that stands in for the peak.
    """
    Q = np.zeros((S, N_PARAMS, N_PARAMS))
    Q[:, B2, B2] = 1.0 / s.drift_curve_prior_sd**2
    Q[:, CRX, CRX] = Q[:, CTX, CTX] = 1.0 / s.ridge_prior_sd**2
    mu = np.zeros((S, N_PARAMS))
    if width_mean is None:
        mean_w = np.zeros(N_PARAMS)
        mean_w[[LW, LWY]] = 0.5
        aspect = np.zeros(N_PARAMS)
        aspect[LW], aspect[LWY] = 1.0, -1.0
        Q += (
            np.outer(mean_w, mean_w) / s.width_prior_sd**2
            + np.outer(aspect, aspect) / s.aspect_prior_sd**2
        )[None]
        mu[:, LW] = lw_start
        mu[:, LWY] = lw_start
    else:
        Q[:, LW, LW] = Q[:, LWY, LWY] = 1.0 / s.shared_width_sd**2
        mu[:, LW] = width_mean[:, 0]
        mu[:, LWY] = width_mean[:, 1]
    return Q, mu


def _drift_z(th: np.ndarray, s: FitSettings) -> np.ndarray:
    return th[:, B1] / (s.drift_prior_sd * s.drift_prior_tail)


def prior_cost_of(th: np.ndarray, Q: np.ndarray, mu: np.ndarray, s: FitSettings) -> np.ndarray:
    """Prior cost per sensor (S,): the Gaussian part plus the Cauchy floor-slope tail."""
    d = th - mu
    tail = s.drift_prior_tail**2 * np.log1p(_drift_z(th, s) ** 2)
    return np.einsum("sp,spq,sq->s", d, Q, d) + tail


def prior_hessian_of(th: np.ndarray, Q: np.ndarray, s: FitSettings) -> np.ndarray:
    """IRLS form of the priors: the Cauchy slope prior as a Gaussian weighted at ``th``."""
    Qi = Q.copy()
    Qi[:, B1, B1] = 1.0 / (1.0 + _drift_z(th, s) ** 2) / s.drift_prior_sd**2
    return Qi


@dataclass
class FitResult:
    theta: np.ndarray  # (S, N_PARAMS)
    cov_xy: np.ndarray  # (S, 2, 2) in mm^2, scaled by the residual variance
    scale: np.ndarray  # (S,) robust residual sigma (normalized units)
    n_eff: np.ndarray  # (S,) effective number of points that carried the fit
    converged: np.ndarray  # (S,) bool
    last_step: np.ndarray  # (S,) mm moved in the last iteration (small: nearly converged)
    # (S,) per-axis variance (mm^2) that comes from the touches' placement and gain: shared
    # by the sensors that see the same touches, so pooling sensors does not average it out.
    var_touch: np.ndarray


def fit(
    P: np.ndarray,
    tau: np.ndarray,
    U: np.ndarray,
    valid: np.ndarray,
    theta0: np.ndarray,
    min_radius: float,
    noise_floor: np.ndarray,
    settings: FitSettings = FitSettings(),
    gain: np.ndarray | None = None,
    width_mean: np.ndarray | None = None,
    ridge_width: np.ndarray | None = None,
    touch_var: tuple[np.ndarray, np.ndarray] | None = None,
    scale0: np.ndarray | None = None,
    hold_window: bool = False,
) -> FitResult:
    """Robust windowed Levenberg-Marquardt for S sensors at once.

    P (K,2) probe mm, tau (K,S) minutes from each sensor's peak time, U (K,S) normalized values (peak up, floor ~0),
    valid (K,S) bool, theta0 (S,6) start, noise_floor (S,) smallest residual sigma allowed.

    Each sensor's fit is its own: the sensors are solved in a few groups of similar
    neighbourhood size (``_reach_groups``), so that a group's arrays are not padded to the
    largest neighbourhood of all. ``hold_window``: each fit's window stays where its start
    puts it, instead of following the fit (peakfit.Localizer._hold_stuck).
    """
    s = settings
    theta = theta0.astype(float).copy()
    theta[:, WIDTHS] = np.clip(theta[:, WIDTHS], *_width_range(min_radius, s))
    # Only the touches within reach can carry weight (the window is compact).
    reach = _reach(theta, min_radius, s)
    dist = np.hypot(P[:, 0:1] - theta[..., SX], P[:, 1:2] - theta[..., SY])
    inside = (dist <= reach[None, :]) & valid
    groups = _reach_groups(inside.sum(axis=0))
    parts = [
        _fit_group(
            P,
            tau[:, g],
            U[:, g],
            theta[g],
            0.5 * (theta0[g, LW] + theta0[g, LWY]),
            reach[g],
            min_radius,
            noise_floor[g],
            s,
            gain,
            None if width_mean is None else width_mean[g],
            None if ridge_width is None else ridge_width[g],
            touch_var,
            None if scale0 is None else scale0[g],
            inside[:, g],
            hold_window,
        )
        for g in ([slice(None)] if len(groups) == 1 else groups)
    ]
    if len(parts) == 1:
        return parts[0]
    # The groups' sensors back in their own order.
    back = np.argsort(np.concatenate(groups))
    return FitResult(
        **{
            field.name: np.concatenate([getattr(part, field.name) for part in parts])[back]
            for field in dataclasses.fields(FitResult)
        }
    )


def _width_range(min_radius: float, s: FitSettings) -> tuple[float, float]:
    """The log half widths a fit may take: from MIN to MAX_WIDTH_SPACINGS probe spacings."""
    spacing = min_radius / s.window_spacings
    return np.log(MIN_WIDTH_SPACINGS * spacing), np.log(MAX_WIDTH_SPACINGS * spacing)


def _reach(theta: np.ndarray, min_radius: float, s: FitSettings) -> np.ndarray:
    """How far (mm) from its start a fit can need touches: the window (1.5 R) of a
    footprint up to 1.4x wider than the start, plus room to move."""
    w0 = half_width(theta)
    return 1.5 * np.maximum(s.window_widths * w0 * 1.4, min_radius) + 0.5 * np.maximum(
        s.window_widths * w0, min_radius
    )


def _reach_groups(counts: np.ndarray) -> list[np.ndarray]:
    """Split the sensors into at most GROUPS_MAX groups whose padded (touches x sensors)
    arrays, plus GROUP_COST points for each group's own call overhead, are the fewest.

    ``counts`` (S,) is each sensor's number of touches within reach. One group pads every
    sensor to the largest count: on a full board's robot grid that is 150 touches for a
    median of 84, and 380 for 142 at the cold start (docs/benchmarks.md, "The fit's
    sensors in groups"). The groups are contiguous runs of the sensors sorted by count
    (the best split has that form), chosen by dynamic programming: exactly up to
    GROUP_CUTS sensors, and among cuts at GROUP_CUTS quantiles beyond, so that the table
    stays small on any board.
    """
    S = counts.size
    if S < 2:
        return [np.arange(S)]
    c = np.sort(counts)
    if S * int(c[-1]) - int(c.sum()) <= GROUP_COST:
        return [np.arange(S)]
    order = np.argsort(counts, kind="stable")
    cuts = np.unique(np.linspace(0, S, min(S, GROUP_CUTS) + 1).astype(int))  # 0 .. S
    B = cuts.size
    i, j = cuts[:, None], cuts[None, :]
    # cost[p, q]: the sorted sensors cuts[p] .. cuts[q]-1 as one group, padded to the
    # largest, c[cuts[q]-1]. An empty group costs infinitely much, so none is chosen.
    cost = np.where(j > i, (j - i) * c[np.maximum(j - 1, 0)] + GROUP_COST, np.inf)
    best = [cost[0]]  # best[g][q]: the sensors before cuts[q] in g + 1 groups
    split = []
    for _ in range(1, GROUPS_MAX):
        total = best[-1][:, None] + cost
        arg = np.argmin(total, axis=0)
        split.append(arg)
        best.append(total[arg, np.arange(B)])
    n = int(np.argmin([b[-1] for b in best]))
    ends = [B - 1]
    for g in range(n, 0, -1):
        ends.append(int(split[g - 1][ends[-1]]))
    ends.append(0)
    return [np.sort(order[cuts[a] : cuts[b]]) for a, b in itertools.pairwise(ends[::-1])]


def _fit_group(
    P: np.ndarray,
    tau: np.ndarray,
    U: np.ndarray,
    theta: np.ndarray,
    lw_prior: np.ndarray,
    reach: np.ndarray,
    min_radius: float,
    noise_floor: np.ndarray,
    s: FitSettings,
    gain: np.ndarray | None,
    width_mean: np.ndarray | None,
    ridge_width: np.ndarray | None,
    touch_var: tuple[np.ndarray, np.ndarray] | None,
    scale0: np.ndarray | None,
    inside: np.ndarray,
    hold_window: bool = False,
) -> FitResult:
    """``fit`` of one group of sensors from ``theta`` (S, N_PARAMS), the start with its
    widths in range (it is updated in place), the log width ``lw_prior`` of the
    unclipped start, and its touches within ``reach`` (S,), ``inside`` (K, S)."""
    S = U.shape[1]
    lw_lo, lw_hi = _width_range(min_radius, s)
    K = U.shape[0]
    G_all = np.ones(K) if gain is None else gain
    # Gather each sensor's touches within reach into (M, S) arrays so a full board costs
    # what its neighbourhoods cost.
    order, sel = packed(inside)  # (M, S) touch indices
    start_xy = theta[:, :2].copy()
    Pg = P[order]  # (M, S, 2)
    cols = np.arange(S)
    tau = tau[order, cols]
    Uz = np.where(sel, U[order, cols], 0.0)
    vf = sel.astype(float)
    gain = G_all[order]
    P = Pg
    lam = np.full(S, 1e-3)
    last = None
    warm_scale = scale0 is not None
    scale = np.maximum(np.full(S, 0.3) if scale0 is None else scale0, noise_floor)
    active = np.ones(S, bool)
    converged = np.zeros(S, bool)
    last_step = np.full(S, np.inf)
    diag = np.arange(N_PARAMS)
    rho = ridge_width
    Q, mu = sensor_priors(S, s, width_mean, lw_prior)

    def prior_cost(th, cols):
        return prior_cost_of(th, Q[cols], mu[cols], s)

    def prior_hessian(th, cols):
        return prior_hessian_of(th, Q[cols], s)

    held = theta.copy() if hold_window else None

    def fit_window(th, cols):
        if held is not None:
            th = held[cols]
        return window(P[:, cols], th, min_radius, s) * vf[:, cols]

    def robust_weights(win, res, sc):
        z = res / (s.cauchy_c * sc[None, :])
        return win / (1.0 + z * z)

    def cost(th, sc, cols, win, r=None):
        # The window stays where the iteration started: moving the peak away from the data
        # must not make the cost vanish. ``r``: the residuals at ``th`` if already known.
        if r is None:
            r = Uz[:, cols] - model(
                P[:, cols],
                tau[:, cols],
                th,
                gain[:, cols],
                None if rho is None else rho[cols],
                s.shape,
            )
        z2 = (r / (s.cauchy_c * sc[None, :])) ** 2
        # Cauchy loss over the window: bounded influence of any single touch.
        c = (win * np.log1p(z2)).sum(axis=0) * (s.cauchy_c * sc) ** 2
        return c + prior_cost(th, cols) * sc**2

    for it in range(s.max_iter):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        # While every sensor is active (a live update's few iterations), slices are views.
        sub_all = slice(None) if idx.size == S else idx
        th = theta[idx]
        m, J = jacobian(
            P[:, sub_all],
            tau[:, sub_all],
            th,
            gain[:, sub_all],
            None if rho is None else rho[idx],
            s.shape,
            sensor_major=True,
        )
        res = Uz[:, sub_all] - m
        win = fit_window(th, sub_all)
        wts = robust_weights(win, res, scale[idx])
        # M-estimate of the residual scale over the window, floored by the measured noise.
        wsum = np.maximum(win.sum(axis=0), 1e-12)
        sc_new = np.sqrt((wts * res * res).sum(axis=0) / wsum) * 1.3
        early = it < 2 and not warm_scale
        sc = np.maximum(np.maximum(sc_new, scale[idx]) if early else sc_new, noise_floor[idx])
        # The scale settles in a few iterations; freezing it then lets LM converge fast.
        sc = np.where(it < 8, sc, scale[idx])
        scale[idx] = sc
        wts = robust_weights(win, res, sc)
        H, g = normal_equations(wts, J, res)
        # Weak priors keep the floor slope and the width sane when few points carry the fit.
        sc2 = (sc * sc)[:, None, None]
        Qi = prior_hessian(th, idx)
        g -= np.einsum("spq,sq->sp", Qi, th - mu[idx]) * sc2[:, :, 0]
        H = H + Qi * sc2
        c0 = cost(th, sc, idx, win, res)
        accepted = np.zeros(idx.size, bool)
        step = np.zeros_like(th)
        lam_i = lam[idx]
        for _ in range(6):
            todo = ~accepted
            if not todo.any():
                break
            Hd = H[todo]
            Hd[:, diag, diag] += lam_i[todo, None] * (Hd[:, diag, diag] + 1e-9)
            try:
                d = np.linalg.solve(Hd, g[todo][..., None])[..., 0]
            except np.linalg.LinAlgError:
                d = np.stack(
                    [
                        np.linalg.lstsq(h, gg, rcond=None)[0]
                        for h, gg in zip(Hd, g[todo], strict=False)
                    ]
                )
            d[:, WIDTHS] = clamp(d[:, WIDTHS], -0.5, 0.5)
            d[:, :2] = clamp(d[:, :2], -0.5 * min_radius, 0.5 * min_radius)
            cand = th[todo] + d
            cand[:, AMP] = np.maximum(cand[:, AMP], 1e-6)
            cand[:, WIDTHS] = clamp(cand[:, WIDTHS], lw_lo, lw_hi)
            all_todo = todo.all()
            cols = sub_all if all_todo else idx[todo]
            ok = cost(cand, sc[todo], cols, win if all_todo else win[:, todo]) <= c0[todo] * (
                1 + 1e-12
            )
            ok &= np.isfinite(cand).all(axis=1)
            sub = np.flatnonzero(todo)
            step[sub[ok]] = cand[ok] - th[sub[ok]]
            accepted[sub[ok]] = True
            lam_i[sub[ok]] *= 0.3
            lam_i[sub[~ok]] *= 8.0
        lam[idx] = clamp(lam_i, 1e-9, 1e9)
        if s.cov_at_last_iteration:  # kept only when asked for: a board's J is large
            last = (m, J, res, win, wts, H) if idx.size == S else None
        theta[idx] = th + step
        moved = np.hypot(step[:, SX], step[:, SY])
        last_step[idx] = np.where(accepted, moved, last_step[idx])
        done = (
            accepted & (moved < s.step_tol_mm) & (np.abs(step[:, [LW, LWY]]).max(axis=1) < 1e-4)
        ) | ~accepted
        done &= it >= 2
        converged[idx[done & accepted]] = True
        converged[idx[done & ~accepted]] = True  # no better point nearby: a local minimum
        active[idx[done]] = False
    # Final weights and covariance at the solution.
    if last is not None:
        m, J, res, win, wts, H = last
    else:
        m, J = jacobian(P, tau, theta, gain, rho, s.shape)
        res = Uz - m
        win = fit_window(theta, np.arange(S))
        wts = robust_weights(win, res, scale)
        H, _ = normal_equations(wts, J, res)
        H = H + prior_hessian(theta, np.arange(S)) * (scale * scale)[:, None, None]
    # Residual variance of the fit (robustly weighted), with the dof the window leaves.
    n_eff = wts.sum(axis=0)
    rss = (wts * res * res).sum(axis=0)
    var = rss / np.maximum(n_eff - N_PARAMS, 1.0)
    var = np.maximum(var, noise_floor**2)
    try:
        Hinv = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        Hinv = np.linalg.pinv(H)
    cov_xy = Hinv[:, :2, :2] * var[:, None, None]
    var_touch = np.zeros(S)
    if touch_var is not None:
        # Where each touch landed and how hard it pressed are only known to their posterior
        # variance; propagate that through the fit (first order: d theta / d touch).
        v_lg, v_d = touch_var[0][order].T, touch_var[1][order].T  # (S, M)
        Mi = Hinv[:, :2, :] @ (J * wts[..., None]).transpose(1, 2, 0)  # (S, 2, M)
        bump = (m - floor(tau, theta)).T  # (S, M)
        jx, jy = J[..., SX].T, J[..., SY].T
        for ax in (0, 1):
            Ma = Mi[:, ax, :]
            part = (Ma * Ma * (v_d * (jx * jx + jy * jy) + v_lg * bump * bump)).sum(axis=1)
            cov_xy[:, ax, ax] += part
            var_touch += 0.5 * part
    # A sensor that wandered beyond the gathered touches would miss data: not converged.
    strayed = np.hypot(*(theta[:, :2] - start_xy).T) > reach - 1.5 * np.maximum(
        s.window_widths * half_width(theta), min_radius
    )
    converged &= ~strayed
    return FitResult(
        theta, cov_xy, scale, n_eff, converged, np.where(strayed, np.inf, last_step), var_touch
    )

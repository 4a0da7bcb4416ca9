"""``peakfit``: robust per-sensor peak fit with honest error bars, batch or incremental.

Why it exists: the paper's threshold-centroid has a large error that is not noise (the
coarse grid aliases the peak, the threshold depends on each sensor's floor, the centroid is
pulled inwards at the edge). This method fits each sensor's point log map with a Lorentzian
bump over its own (drifting) floor, only near the peak and with a robust loss, solving all
sensors at once in numpy. A ``Localizer`` takes one point log at a time and re-fits only the
sensors the new touch informs, warm-started, so a live session sees estimates as it goes;
``localize`` is the same machinery fed with every log at once. The steps around the solve
(the live update, the shape screen, second peaks, the settling check, statuses, the layout
prior, the error-bar check) are modules of their own beside this one. See docs/localizer.md.
"""

from __future__ import annotations

import math
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, replace

import numpy as np

from varskin.errors import InputError
from varskin.localization import _peak_model as pm
from varskin.localization._design_reach import unreached_sparse
from varskin.localization._drifting import (
    moved_by_settling,
    refit_after_settling,
    settling_of,
    take_out_settling,
)
from varskin.localization._error_bar import sigma_scale
from varskin.localization._hull import ProbeHull
from varskin.localization._joint import joint_step
from varskin.localization._layout_prior import design_scatter_mm
from varskin.localization._live_update import live_judge, update
from varskin.localization._maps import floor_trend, nanmedian_cols, packed
from varskin.localization._second_peaks import SEED_RADIUS_SPACINGS, second_peaks
from varskin.localization._shape_screen import favoured_shape
from varskin.localization._statuses import DEAD, judge, unrisen_weak, window_members
from varskin.localization._unseen import UNSEEN_FRACTION, seen_height, shape_spread
from varskin.patch import Patch
from varskin.pointlogs import MAX_TIME_S, PointLog, PointLogs
from varskin.predictions import OK, Predictions, SensorEstimate
from varskin.scene import ADC_MAX

NAME = "peakfit"

POLISH_ROUNDS = 4  # alternations of touch nuisances and sensor fits in a batch solve
# Rounds of a batch solve per solver; a joint round also takes JOINT_STEPS joint steps.
SOLVER_ROUNDS = {"joint": 8, "alternate": POLISH_ROUNDS}
# A finger's touches land a millimetre or so off, and each alternation moves the touches'
# offsets and the sensors that share them only part of the way: edge sensors, which see
# few touches, follow their touches' offsets slowly. In the fourth round sensors of
# Patch B finger scenes still moved by up to 0.2-0.9 mm (seeds 303, 319, 350). So a solve whose
# estimated placement scatter is finger-like takes SETTLE_ROUNDS more, each offset step
# over-relaxed by SETTLE_RELAX (x2.5 diverged; x1.5 and x1.8 gave the same errors). After
# four rounds a robot's estimate is at most 0.22 mm (median per benchmarks/localizer_stress.py
# row, wrong response shapes included; its true 0.05 mm), a finger's 0.54-1.05 mm on dense
# and scattered plans (0.33-0.37 on 12 x 3 grids, which mostly do not settle). Robot solves
# keep the four rounds: more barely lower their errors and shrink the placement estimate
# until the error-bar check under-sizes sigma (docs/benchmarks.md, "Settling finger solves").
SETTLE_ROUNDS = 12
SETTLE_RELAX = 1.5
FINGER_LIKE_MM = 0.4
# A settled finger solve then tries JOINT_SETTLE_ROUNDS joint rounds (joint_step): the
# alternation's fixed point is still short of the model's optimum where few sensors pin a
# touch. On Patch B's outermost TX wires, three sensors are all that see the first two probe
# columns, and the touches' offsets there absorbed what those sensors' fits got wrong
# (docs/benchmarks.md, "Joint rounds after settling"). The rounds hold the placement scale
# the alternation estimated. Where the response model is wrong (wire coupling x3, or noise
# so low that the model's own misfit dominates), the offsets the joint rounds reach fit that
# scale badly: the scatter they imply is 1.12-1.30x it (median per stress row), against
# 1.04-1.15x on 200 default Patch B scenes. Above JOINT_SETTLE_GUARD the rounds are undone.
# Not where a patch's design prior is in use on both axes: it pins those same edge sensors
# after the solve, and there the rounds gained little (200 Patch B plan scenes: median RMS
# 0.499 -> 0.484 mm, none above 2 mm either way) for 1.65x the solve's time, while they
# moved the batch further from the live view than its stated tolerance (test_live_update_
# restarts_a_sensor_whose_peak_turns_up_away_from_its_fit: 2.59 sigma) and cost the design
# prior's pull on off-design patches (docs/benchmarks.md, "Joint rounds after settling").
# A wire family too small for a design map (Patch A's two RX wires) leaves its axis
# unpinned, and there the rounds are taken: Patch A finger, seeds 300-359 and 360-559,
# median RMS 0.453 -> 0.407 and 0.400 mm, worst ratio to the paper method 0.64 -> 0.47
# (docs/benchmarks.md, "Joint rounds where the design pins one axis only").
JOINT_SETTLE_ROUNDS = 8
# ... unless the patch lies so far off its design that the design prior no longer pins
# those sensors: its wires scatter about the design map by more than DESIGN_LOOSE_MM (the
# simulator's default displacement is 0.6 mm sd). Then the solve takes the rounds as it
# would without the patch (docs/benchmarks.md, "A patch far off its design").
DESIGN_LOOSE_MM = 1.0
JOINT_SETTLE_GUARD = 1.15
JOINT_STEPS = 2
# Where fewer than 3 sensors have 2 * N_PARAMS effective touches (a sparse grid: 24-40
# touches for 30 sensors), the probe's footprint is taken from the peaks a touch has seen
# half of instead, held this loosely (log-width sd; pm.FitSettings.shared_width_sd is the
# spread around a well-measured footprint). Without it every width was free there, and a
# peak between two probe columns was fitted a quarter as wide as the seen ones, `ok` up to
# 8 mm off. Looser than 0.25 because such widths come out 1.1-1.5x wide on 8 x 3 grids
# (median per scene against the 20 x 5 grid's; log 0.1-0.4), and at 0.25 the whole patch
# was held to that bias: 2 sigma covered 0.84-0.89 on four sparse rows. At 0.5, on
# `varskin calibrate`'s 8 x 3, 10 x 4 and 12 x 3 grids (seeds 0-17), every row covers
# 0.91-0.98, more sensors are located on 11 of 12 and the RMS of the `ok` falls on 10
# (docs/benchmarks.md, "The footprint from the seen peaks on sparse grids").
SEEN_FOOTPRINT_SD = 0.5
# LM iterations per sensor in a polish round (warm-started). Located sensors converge in a
# few; a sensor not yet probed near (mid-session) never does and would cost the full 100.
POLISH_MAX_ITER: int | None = 25

DEFAULTS: dict = {
    "inverted": None,  # None: detect from the maps; True/False: the bench's sign
    "patch": None,  # a Patch: enables the wire layout prior (sensor names -> tx/rx wires)
    "wires": None,  # or {sensor: (tx, rx)} for the same purpose
    "layout_prior": True,  # use the wire prior when wires are known
    # Without a patch or wires: infer the wires from the fitted positions when they form a
    # clear grid (_wire_inference.py), for the layout prior (without the design's part).
    "infer_wires": True,
    "wire_scatter_mm": 0.25,  # smallest scatter of crossings around their wire's line
    "min_snr": 8.0,  # fitted peak / per-touch noise below this: "dead"
    "max_sigma_mm": 5.0,  # larger uncertainty than this: "uncertain"
    "spacing_mm": None,  # typical probe spacing; None: median nearest-neighbour distance
    "window_widths": pm.FitSettings.window_widths,
    "cauchy_c": pm.FitSettings.cauchy_c,
    # "joint": sensors and touch nuisances take joint Gauss-Newton steps (converges);
    # "alternate": block coordinate descent between them only (the default).
    "solver": "alternate",
    # Rounds a finger-like `alternate` solve takes to settle (SETTLE_ROUNDS); 0: none. More
    # reach nearer the alternation's fixed point at the cost of time (docs/benchmarks.md,
    # "How far finger solves settle").
    "settle_rounds": SETTLE_ROUNDS,
    # Joint rounds a settled solve then tries; 0: none. None: JOINT_SETTLE_ROUNDS unless a
    # patch's design prior pins both axes (and the patch is near its design), then none.
    "joint_settle_rounds": None,
    # Per-axis scatter (mm) of where the probe really lands, if known (a finger ~1, a robot
    # ~0.05): a floor for the scatter estimated from the data, which sparse plans
    # underestimate (docs/localizer.md, Known limits). None: estimated only.
    "placement_sd_mm": None,
    # Scale every sigma by what the same solve gets wrong on sessions simulated from its own
    # fits (_error_bar.py); False: the first-order propagation alone (1.3-3x faster batch).
    # The `joint` solver always reports the first-order sigma.
    "calibrate_sigma": True,
    # The bump's profile (pm.SHAPES: "lorentzian", "gaussian", "exponential"), or "auto": the
    # Lorentzian unless the maps favour another (_shape_screen.py).
    "response_shape": "auto",
}

# Probes whose rms distance from their best line is below this lie on a line ("collinear").
COLLINEAR_RMS_MM = 0.25


@contextmanager
def _quiet():
    """All-NaN columns are expected (dead or missing sensors) and become statuses."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        with np.errstate(all="ignore"):
            yield


def check_params(params: dict) -> dict:
    unknown = set(params) - set(DEFAULTS)
    if unknown:
        raise InputError(
            f"{NAME}: unknown parameter(s) {', '.join(sorted(unknown))}; "
            f"known: {', '.join(DEFAULTS)}"
        )
    out = {**DEFAULTS, **params}
    optional = ("spacing_mm", "placement_sd_mm")  # None: estimated from the data
    for key in (
        "wire_scatter_mm",
        "min_snr",
        "max_sigma_mm",
        "window_widths",
        "cauchy_c",
        *optional,
    ):
        v = out[key]
        if v is None and key in optional:
            continue
        if (
            isinstance(v, bool)
            or not isinstance(v, (int, float))
            or not v > 0
            or not math.isfinite(v)
        ):
            raise InputError(f"{NAME}: {key} must be a positive number, got {v!r}")
    for key in ("layout_prior", "infer_wires", "calibrate_sigma"):
        if not isinstance(out[key], bool):
            raise InputError(f"{NAME}: {key} must be true or false, got {out[key]!r}")
    if out["inverted"] not in (None, True, False):
        raise InputError(f"{NAME}: inverted must be true, false or unset, got {out['inverted']!r}")
    for key in ("settle_rounds", "joint_settle_rounds"):
        rounds = out[key]
        if key == "joint_settle_rounds" and rounds is None:
            continue
        if isinstance(rounds, bool) or not isinstance(rounds, (int, np.integer)) or rounds < 0:
            unset = " or unset" if key == "joint_settle_rounds" else ""
            raise InputError(f"{NAME}: {key} must be a whole number >= 0{unset}, got {rounds!r}")
    if out["response_shape"] != "auto" and out["response_shape"] not in pm.SHAPES:
        raise InputError(
            f"{NAME}: response_shape must be auto or one of {', '.join(pm.SHAPES)}, "
            f"got {out['response_shape']!r}"
        )
    if out["solver"] not in SOLVER_ROUNDS:
        raise InputError(
            f"{NAME}: solver must be one of {', '.join(SOLVER_ROUNDS)}, got {out['solver']!r}"
        )
    if out["patch"] is not None and not isinstance(out["patch"], Patch):
        raise InputError(f"{NAME}: patch must be a varskin.patch.Patch")
    return out


def _wire_groups(
    sensors: tuple[str, ...], patch: Patch | None, wires
) -> tuple[np.ndarray, np.ndarray] | None:
    table: dict[str, tuple[int, int]] = {}
    if patch is not None:
        table = {s.name: (s.tx, s.rx) for s in patch.sensors}
    if wires is not None:
        try:
            table = {str(k): (int(v[0]), int(v[1])) for k, v in dict(wires).items()}
        except (TypeError, ValueError, IndexError):
            raise InputError(f"{NAME}: wires must map sensor name -> (tx, rx)") from None
    if not table:
        return None
    tx = np.array([table.get(s, (-1, -1))[0] for s in sensors])
    rx = np.array([table.get(s, (-1, -1))[1] for s in sensors])
    return tx, rx


def _wire_design(
    sensors: tuple[str, ...], patch: Patch | None, groups
) -> tuple[np.ndarray, np.ndarray] | None:
    """Design x of each sensor's TX wire and design y of its RX wire (NaN: unknown)."""
    if patch is None or groups is None:
        return None
    tx, rx = groups
    tx_x = np.array(patch.tx_x_mm, float)
    rx_y = np.array(patch.rx_y_mm, float)
    dx = np.where((tx >= 0) & (tx < tx_x.size), tx_x[np.clip(tx, 0, tx_x.size - 1)], np.nan)
    dy = np.where((rx >= 0) & (rx < rx_y.size), rx_y[np.clip(rx, 0, rx_y.size - 1)], np.nan)
    return dx, dy


@dataclass
class _SensorFit:
    """What the last solve left for every sensor (arrays over sensors)."""

    theta: np.ndarray  # (N, 6) normalized units
    floor: np.ndarray  # (N,) normalization: value = floor + amp * u
    amp: np.ndarray
    cov_xy: np.ndarray  # (N, 2, 2)
    var_touch: np.ndarray  # (N,) per-axis part of cov_xy due to the touches' nuisances
    scale: np.ndarray  # residual sigma, normalized
    noise: np.ndarray  # per-touch noise, normalized
    n_eff: np.ndarray
    converged: np.ndarray
    fitted: np.ndarray  # (N,) bool: a fit exists
    start: np.ndarray  # (N, 2) where the fit started (top of the map)
    n_clipped: np.ndarray  # (N,) touches excluded as clipped
    tc: np.ndarray  # (N,) session time (min) of the sensor's largest reading: drift origin
    # (N,) how far the map rose above its slow floor trend (counts): the top of the
    # detrended map, so that a floor still settling does not hide or fake a rise
    rise: np.ndarray

    def has_model(self) -> np.ndarray:
        """(N,) bool: a fit with finite parameters and a positive peak, a model to predict
        from."""
        return self.fitted & np.isfinite(self.theta).all(axis=1) & (self.theta[:, pm.AMP] > 0)

    def copy_of(self, cols=slice(None)) -> dict:
        """Every field's values for the sensors ``cols`` (default all), for ``put``."""
        return {name: getattr(self, name)[cols].copy() for name in self.__dataclass_fields__}

    def put(self, kept: dict, cols=slice(None)) -> None:
        """Write back what ``copy_of`` took, for the sensors ``cols``."""
        for name, v in kept.items():
            getattr(self, name)[cols] = v


class Localizer:
    """Incremental localizer: ``update(point_log)`` after each touch, ``result()`` any time.

    ``Localizer(sensors, rest=None, rest_sd=None, **params)``; values of each ``PointLog`` are
    relative to rest (as in ``PointLogs``). ``rest``/``rest_sd`` (raw counts) enable the SNR
    and ADC-clipping checks.
    """

    def __init__(self, sensors, rest=None, rest_sd=None, **params) -> None:
        self.params = check_params(params)
        self.sensors = tuple(str(s) for s in sensors)
        n = len(self.sensors)
        if n == 0:
            raise InputError(f"{NAME}: no sensors")
        self.rest = _finite_or_none(rest, n, "rest")
        self.rest_sd = _finite_or_none(rest_sd, n, "rest_sd")
        self._raw: bool | None = None
        shape = self.params["response_shape"]
        self._fixed_shape = None if shape == "auto" else shape
        self.settings = pm.FitSettings(
            window_widths=float(self.params["window_widths"]),
            cauchy_c=float(self.params["cauchy_c"]),
            shape=self._fixed_shape or pm.SHAPES[0],
        )
        self._shape_z: float | None = None
        self.groups = _wire_groups(self.sensors, self.params["patch"], self.params["wires"])
        # The (tx, rx) wires the last verdict's layout prior used: given, or inferred from
        # the fits (None: no prior); _error_bar.band_session gives them to a board's band.
        self._verdict_wires: tuple[np.ndarray, np.ndarray] | None = None
        self.design = _wire_design(self.sensors, self.params["patch"], self.groups)
        cap = 64
        self._k = 0
        self._P = np.zeros((cap, 2))
        self._V = np.zeros((cap, n))
        self._noise = np.full((cap, n), np.nan)
        self._t = np.zeros(cap)
        self._has_time = True
        self._t0: float | None = None
        self._nn = np.zeros(cap)  # each probe point's distance to its nearest distinct neighbour
        # Distinct probe points (exactly equal ones count once), their mean and scatter
        # matrix (Welford): whether the probes lie on a line, without re-reading them all.
        self._n_distinct = 0
        self._p_mean = np.zeros(2)
        self._p_scatter = np.zeros((2, 2))
        self._spacing_at: tuple[int, float] | None = None  # (log count, spacing there)
        self._hull = ProbeHull()
        # Per-touch nuisances shared by all sensors: log pressing gain and placement offset
        # (where the probe really landed minus where the log says), plus missed touches.
        self._lg = np.zeros(cap)
        self._dxy = np.zeros((cap, 2))
        self._missed = np.zeros(cap, bool)
        self._v_lg = np.zeros(cap)  # posterior variances of the touch nuisances
        self._v_d = np.zeros(cap)
        self.gain_sd = 0.2  # prior scale of log gain, re-estimated from the data (EM)
        # Prior scale of placement error per axis, re-estimated, never below a known one.
        self._place_floor = float(self.params["placement_sd_mm"] or 0.02)
        self.place_sd_mm = max(0.5, self._place_floor)
        # Factor on every reported sigma, from the last batch solve (_error_bar.py).
        self._sigma_scale = 1.0
        self._settled = False  # the last batch solve took the finger's settle_rounds
        # ... and its joint rounds: the placement scatter they implied over the one they
        # were held to (None: not tried), and whether they were kept.
        self._joint_ratio: float | None = None
        self._joint_kept = False
        # Touches added since the last full polish, or a live re-solve left fits that the
        # final solve holds (solve_all's ``final``): result() solves again.
        self._dirty = False
        self._next_full = 8  # the live view re-solves everything when the session doubles
        self.shared_lw: np.ndarray | None = None  # (2,) log footprint widths of the probe
        self._sign = 1.0
        self._spacing_used: float | None = None
        # Per sensor, the session time (min) of the first touch its fit may use: -inf, or
        # later for a sensor whose offset was still settling during its first touches.
        self._t_from = np.full(n, -np.inf)
        # Per sensor, the touch near which its fit must start (-1: the map's top), and
        # whether its map has two peaks that fit equally well (see _second_peaks.py).
        self._seed_k = np.full(n, -1)
        self._two_peaks = np.zeros(n, bool)
        # The board's offset settling as the last batch solve saw it (_settling.py): its
        # time course over the touches then, and each sensor's settled level; None: unknown.
        self._settling: tuple[np.ndarray, np.ndarray] | None = None
        # Per sensor: taking that settling out of its readings moved its fit too far for
        # its error bar (_drifting.py; one of the `drifting` reasons).
        self._moved_by_settling = np.zeros(n, bool)
        # Per sensor: `drifting` before that settling was taken out of its readings, and so
        # still `drifting` after (_drifting.take_out_settling).
        self._held_drifting = np.zeros(n, bool)
        # Per sensor: how far taking that settling out of its readings moved its fit (mm;
        # _drifting.take_out_settling), a part of its error bar.
        self._settling_shift = np.zeros(n)
        # Per sensor whose peak no touch came near: how far the model's other response
        # shapes move its fit (mm; _unseen.shape_spread), a part of its error bar.
        self._shape_shift = np.zeros(n)
        # Per sensor: how much of its fitted peak its nearest touch saw (_unseen.seen_height),
        # kept by the live updates for the live view's verdict (_live_update.live_judge);
        # None: to compute afresh (a batch solve moved every fit).
        self._live_seen: np.ndarray | None = None
        # Per sensor: mm from its design position to the nearest touch that made contact
        # (_design_reach.design_gap), kept by the live updates; None: to compute afresh (a
        # batch solve may have called other touches missed).
        self._design_gap: np.ndarray | None = None
        # Per sensor: the last live update's estimate of its touch's gain and placement
        # changed what that touch says to this sensor's model, so the next update re-fits
        # it too (_live_update.update).
        self._refit_next = np.zeros(n, bool)
        self.fit = _SensorFit(
            theta=np.zeros((n, pm.N_PARAMS)),
            floor=np.zeros(n),
            amp=np.ones(n),
            cov_xy=np.zeros((n, 2, 2)),
            var_touch=np.zeros(n),
            scale=np.ones(n),
            noise=np.zeros(n),
            n_eff=np.zeros(n),
            converged=np.zeros(n, bool),
            fitted=np.zeros(n, bool),
            start=np.zeros((n, 2)),
            n_clipped=np.zeros(n, int),
            tc=np.zeros(n),
            rise=np.zeros(n),
        )

    # --- data intake -------------------------------------------------------------------

    def _grow(self) -> None:
        cap = 2 * len(self._t)
        for name in ("_P", "_V", "_noise"):
            a = getattr(self, name)
            b = np.full((cap,) + a.shape[1:], np.nan if name == "_noise" else 0.0)
            b[: self._k] = a[: self._k]
            setattr(self, name, b)
        for name in ("_t", "_nn", "_lg", "_dxy", "_missed", "_v_lg", "_v_d"):
            a = getattr(self, name)
            b = np.zeros((cap,) + a.shape[1:], a.dtype)
            b[: self._k] = a[: self._k]
            setattr(self, name, b)

    def _subset(self, cols: np.ndarray, rows: np.ndarray) -> Localizer:
        """A localizer of the sensors ``cols`` and the touches ``rows`` alone (both
        increasing), with the same response shape, not yet solved: the session as if only
        those touches had been recorded, with only those sensors (for _error_bar.py's check
        of boards too large to re-solve whole). The touches go through the intake again,
        at their own session times."""
        cols, rows = np.asarray(cols, int), np.asarray(rows, int)

        def pick(a):
            return None if a is None else a[cols].copy()

        sub = type(self)(
            [self.sensors[i] for i in cols], pick(self.rest), pick(self.rest_sd), **self.params
        )
        sub.settings = self.settings
        sub._raw = self._raw
        for k in rows:
            # A session without times had ~7.5 s per touch (_tau); given as times, the kept
            # touches keep theirs, gaps included.
            t = self._t[k] if self._has_time else float(k) * 7.5
            log = PointLog(
                touch=int(k),
                x_mm=self._P[k, 0],
                y_mm=self._P[k, 1],
                values=self._V[k, cols],
                sample_sd=self._noise[k, cols],
                t_s=t,
            )
            sub._append(log)
        sub._t0 = self._t0 if self._has_time else 0.0
        return sub

    def _append(self, log: PointLog) -> bool:
        """Store one log; False if it carries no usable position."""
        x, y = float(log.x_mm), float(log.y_mm)
        if not (math.isfinite(x) and math.isfinite(y)):
            return False
        v = np.asarray(log.values, dtype=float).reshape(-1)
        if v.size != len(self.sensors):
            raise InputError(
                f"{NAME}: point log {log.touch} has {v.size} values for {len(self.sensors)} sensors"
            )
        if self._k == len(self._t):
            self._grow()
        k = self._k
        self._P[k] = (x, y)
        self._V[k] = np.where(np.isfinite(v), v, np.nan)
        if log.sample_sd is not None:
            sd = np.asarray(log.sample_sd, float).reshape(-1)
            with np.errstate(invalid="ignore", divide="ignore"):
                self._noise[k] = sd / math.sqrt(max(int(log.n_samples), 1))
        if log.t_s is None or not abs(float(log.t_s)) <= MAX_TIME_S:  # NaN too
            self._has_time = False
        t = float(log.t_s) if self._has_time and log.t_s is not None else float(k) * 7.5
        if self._t0 is None:
            self._t0 = t
        self._t[k] = t
        # Keep nearest-neighbour distances current: the probe spacing sets the window floor.
        distinct = True
        if k:
            d = np.hypot(self._P[:k, 0] - x, self._P[:k, 1] - y)
            distinct = not (d == 0.0).any()  # exactly equal points only
            d = np.where(d > 1e-6, d, np.inf)
            self._nn[k] = d.min()
            self._nn[:k] = np.minimum(self._nn[:k], d)
        else:
            self._nn[k] = np.inf
        if distinct:
            self._n_distinct += 1
            delta = self._P[k] - self._p_mean
            self._p_mean += delta / self._n_distinct
            self._p_scatter += np.outer(delta, self._P[k] - self._p_mean)
        self._k += 1
        return True

    # --- views of the stored data ------------------------------------------------------

    @property
    def n_logs(self) -> int:
        return self._k

    def _tau(self) -> np.ndarray:
        # Session time in minutes from the first log; without times, ~7.5 s per touch.
        if self._has_time:
            return (self._t[: self._k] - (self._t0 or 0.0)) / 60.0
        return np.arange(self._k) * 7.5 / 60.0

    def spacing(self) -> float:
        if self.params["spacing_mm"] is not None:
            return float(self.params["spacing_mm"])
        # Kept per log count: one update asks for it a few times.
        if self._spacing_at is None or self._spacing_at[0] != self._k:
            nn = self._nn[: self._k]
            nn = nn[np.isfinite(nn)]
            self._spacing_at = (self._k, float(np.median(nn)) if nn.size else 1.0)
        return self._spacing_at[1]

    def _probe_hull(self) -> np.ndarray | None:
        """(E, 3) edges n.x + c <= 0 (n unit, outward) of the probes' convex hull; None
        when the probes are (nearly) collinear."""
        # Probes on (nearly) one line cannot tell the two sides of that line apart.
        if self._n_distinct < 3:
            return None
        small = np.linalg.eigvalsh(self._p_scatter)[0]
        if math.sqrt(max(small, 0.0) / self._n_distinct) < COLLINEAR_RMS_MM:
            return None
        return self._hull.edges(self._P[: self._k])

    def _detect_sign(self) -> float:
        if self.params["inverted"] is not None:
            return -1.0 if self.params["inverted"] else 1.0
        V = self._V[: self._k]
        if self._k < 3 or not np.isfinite(V).any():
            return self._sign
        with np.errstate(all="ignore"):
            med = nanmedian_cols(V)
            up = np.nanmax(V, axis=0) - med
            down = med - np.nanmin(V, axis=0)
        # The bench decides the sign for every sensor: a majority of the sensors that are clear.
        n_up = int(np.sum(up > 1.5 * down))
        n_down = int(np.sum(down > 1.5 * up))
        if n_down > n_up:
            return -1.0
        if n_up > n_down:
            return 1.0
        return self._sign

    def _clipped(self, cols: np.ndarray) -> np.ndarray:
        """(K, len(cols)) touches whose raw reading sat at the ADC limit (censored, not data)."""
        K = self._k
        if self.rest is None:
            return np.zeros((K, cols.size), bool)
        rest = self.rest[cols]
        sd = self.rest_sd[cols] if self.rest_sd is not None else np.ones(cols.size)
        margin = np.maximum(3.0 * sd, 1.0)
        # Only raw board counts can clip; rescaled data (rest beyond the ADC range) cannot.
        raw_like = np.full(cols.size, self._raw_counts())
        raw = rest[None, :] + self._V[:K][:, cols]
        clip = (raw >= ADC_MAX - margin[None, :]) | (raw <= margin[None, :])
        return clip & raw_like[None, :]

    def _maps(self, cols: np.ndarray, clipped: np.ndarray):
        """Sensors ``cols``' maps as fitted: (U, D, valid, floor, amp), each (K, S) or (S,).

        U is each map in its own units (median 0, top 1); D is U less its slow floor trend,
        so that a drift as large as the peak does not put the map's top at the session's
        first or last touches.
        """
        K = self._k
        tau = self._tau()
        V = self._V[:K][:, cols] * self._sign
        valid = np.isfinite(V) & ~clipped & ~self._missed[:K, None]
        valid &= tau[:, None] >= self._t_from[cols][None, :]
        Vv = np.where(valid, V, np.nan)
        with np.errstate(all="ignore"):
            floor = nanmedian_cols(Vv)
            top = np.nanmax(Vv, axis=0)
        floor = np.where(np.isfinite(floor), floor, 0.0)
        amp = top - floor
        amp = np.where(np.isfinite(amp) & (amp > 0), amp, 1.0)
        U = (np.where(valid, V, 0.0) - floor[None, :]) / amp[None, :]
        return U, U - floor_trend(U, valid), valid, floor, amp

    def _raw_counts(self) -> bool:
        """Do rest values look like Muca ADC counts (so ADC clipping can be judged)?"""
        if self._raw is None:
            if self.rest is None or not np.isfinite(self.rest).any():
                self._raw = False
            else:
                self._raw = bool(100.0 <= float(np.nanmedian(self.rest)) <= ADC_MAX)
        return self._raw

    # --- solving -----------------------------------------------------------------------

    def _solve(
        self,
        cols: np.ndarray,
        warm: np.ndarray,
        max_iter: int | None = None,
        hold_window: bool = False,
        live: bool = False,
    ) -> None:
        """(Re)fit sensors ``cols``; ``warm`` (bool per col) starts from the previous fit;
        ``live``: a live update's re-fit (its error bars from the last iteration)."""
        K = self._k
        if cols.size == 0 or K == 0:
            return
        P = self._P[:K] + self._dxy[:K]
        tau = self._tau()
        clipped = self._clipped(cols)
        U, D, valid, floor, amp = self._maps(cols, clipped)
        with np.errstate(all="ignore"):
            noise = nanmedian_cols(self._noise[:K][:, cols]) / amp
        noise = np.where(np.isfinite(noise) & (noise > 0), noise, 0.0)
        f = self.fit
        h = self.spacing()
        min_radius = self.settings.window_spacings * h
        # The start: the top of the detrended map D, or near the touch a second-peak check
        # chose (_second_peaks.py).
        near = valid.copy()
        seeded = self._seed_k[cols] >= 0
        if seeded.any():
            pk = P[self._seed_k[cols][seeded]]
            d = np.hypot(P[:, 0:1] - pk[None, :, 0], P[:, 1:2] - pk[None, :, 1])
            near[:, seeded] &= d <= SEED_RADIUS_SPACINGS * h
            lost = ~near.any(axis=0)  # nothing valid near the seed any more: the map's top
            near[:, lost] = valid[:, lost]
        theta0 = self._initial(P, D, near, h, need=np.zeros(cols.size, bool))
        kmax = np.argmax(np.where(near, D, -np.inf), axis=0)
        tc = tau[kmax]
        tau = tau[:, None] - tc[None, :]
        start = theta0[:, :2].copy()
        # A previous fit far from where the data now peak is no start: begin afresh there,
        # exactly as a batch solve would.
        w_old = pm.half_width(f.theta[cols])
        far = np.hypot(*(f.theta[cols, :2] - start).T) > np.maximum(2.0 * w_old, 2.0 * h)
        warm = warm & f.fitted[cols] & ~far & np.isfinite(f.theta[cols]).all(axis=1)
        if (~warm).any():
            theta0[~warm] = self._initial_shape(P, D[:, ~warm], valid[:, ~warm], h, theta0[~warm])
        at_top = (kmax, np.arange(cols.size))
        theta0[:, pm.B0] += U[at_top] - D[at_top]
        if warm.any():
            # Re-express the previous fit in the new normalization and peak time, start there.
            c = cols[warm]
            old = f.theta[c].copy()
            ra = f.amp[c] / amp[warm]
            old[:, [pm.AMP, pm.B1, pm.B2, pm.CRX, pm.CTX]] *= ra[:, None]
            old[:, pm.B0] = (old[:, pm.B0] * f.amp[c] + f.floor[c] - floor[warm]) / amp[warm]
            dt = tc[warm] - f.tc[c]
            b1, b2 = old[:, pm.B1].copy(), old[:, pm.B2].copy()
            old[:, pm.B0] += b1 * dt + b2 * dt * dt
            old[:, pm.B1] = b1 + 2.0 * b2 * dt
            theta0[warm] = old
        settings = self.settings
        if max_iter is not None or live:
            settings = replace(
                settings,
                max_iter=settings.max_iter if max_iter is None else max_iter,
                cov_at_last_iteration=live,
            )
        res = pm.fit(
            P,
            tau,
            U,
            valid,
            theta0,
            min_radius,
            np.maximum(noise, 1e-9),
            settings,
            gain=np.exp(self._lg[:K]),
            width_mean=None if self.shared_lw is None else np.tile(self.shared_lw, (cols.size, 1)),
            ridge_width=self._ridge_width(theta0),
            touch_var=(np.full(K, self.gain_sd**2), np.full(K, self.place_sd_mm**2)),
            scale0=np.where(warm, f.scale[cols] * f.amp[cols] / amp, 0.3) if warm.any() else None,
            hold_window=hold_window,
        )
        f.theta[cols] = res.theta
        f.floor[cols] = floor
        f.amp[cols] = amp
        f.cov_xy[cols] = res.cov_xy
        f.var_touch[cols] = res.var_touch
        f.scale[cols] = res.scale
        f.noise[cols] = noise
        f.n_eff[cols] = res.n_eff
        # A live update stops after a few iterations: nearly still counts as converged.
        f.converged[cols] = res.converged | (res.last_step < 0.02 * h)
        f.fitted[cols] = True
        f.start[cols] = start
        f.n_clipped[cols] = clipped.sum(axis=0)
        f.tc[cols] = tc
        top = np.max(np.where(valid, D, -np.inf), axis=0)
        f.rise[cols] = np.where(np.isfinite(top), top * amp, 0.0)

    def _initial(self, P, U, valid, h, need: np.ndarray | None = None) -> np.ndarray:
        """Cold start: centre of the map's top, width by a small search, floor and height.

        The centre is computed for every column (it also tells whether a warm start is still
        near the data); the width search only for the columns in ``need`` (default: all).
        """
        S = U.shape[1]
        Um = np.where(valid, U, -np.inf)
        kmax = np.argmax(Um, axis=0)
        pk = P[kmax]  # (S, 2)
        d = np.hypot(P[:, 0:1] - pk[None, :, 0], P[:, 1:2] - pk[None, :, 1])
        # Floor-subtracted weighted centroid of the top half near the maximum.
        wts = np.clip(np.where(valid, U, 0.0) - 0.5, 0.0, None) * (d <= 2.0 * h)
        wsum = wts.sum(axis=0)
        cx = np.where(wsum > 0, (wts * P[:, 0:1]).sum(axis=0) / np.maximum(wsum, 1e-12), pk[:, 0])
        cy = np.where(wsum > 0, (wts * P[:, 1:2]).sum(axis=0) / np.maximum(wsum, 1e-12), pk[:, 1])
        theta = np.zeros((S, pm.N_PARAMS))
        theta[:, pm.SX], theta[:, pm.SY] = cx, cy
        theta[:, pm.LW] = theta[:, pm.LWY] = np.log(h)
        theta[:, pm.AMP] = 1.0
        if need is None:
            need = np.ones(S, bool)
        if need.any():
            theta[need] = self._initial_shape(P, U[:, need], valid[:, need], h, theta[need])
        return theta

    def _initial_shape(self, P, U, valid, h, theta) -> np.ndarray:
        """Width by a small search, then floor and height by linear least squares."""
        S = U.shape[1]
        theta = theta.copy()
        best = np.full(S, np.inf)
        best_enough = np.zeros(S, bool)
        Uz = np.where(valid, U, 0.0)
        vf = valid.astype(float)
        for wc in (0.6 * h, 1.0 * h, 1.6 * h, 2.5 * h):
            th = theta.copy()
            th[:, pm.LW] = th[:, pm.LWY] = np.log(wc)
            g = pm.bump(P, th, self.settings.shape)[0]
            win = pm.window(P, th, self.settings.window_spacings * h, self.settings) * vf
            # Weighted linear least squares for height and floor at this width.
            s0, s1, s2 = win.sum(0), (win * g).sum(0), (win * g * g).sum(0)
            t0, t1 = (win * Uz).sum(0), (win * g * Uz).sum(0)
            det = s0 * s2 - s1 * s1
            ok = np.abs(det) > 1e-12
            a = np.where(ok, (s0 * t1 - s1 * t0) / np.where(ok, det, 1), 1.0)
            b = np.where(ok, (s2 * t0 - s1 * t1) / np.where(ok, det, 1), 0.0)
            r = Uz - b[None, :] - a[None, :] * g
            sse = (win * r * r).sum(0) / np.maximum(s0, 1e-12)
            # A window holding fewer touches than a sane fit needs fits any width (two
            # touches, two unknowns: no residual at all), so among scattered probes, where
            # the nearest-neighbour spacing leaves one or two touches within two spacings,
            # the narrowest width won and the fits collapsed onto single touches (a
            # scattered 100-touch Patch B finger session: 3 of 30 sensors located). Such
            # a width wins only where no window holds enough (early in a sparse session).
            enough = s0 >= pm.MIN_FIT_TOUCHES
            better = (a > 0) & ((enough & ~best_enough) | ((enough == best_enough) & (sse < best)))
            best = np.where(better, sse, best)
            best_enough |= better & enough
            theta[better, pm.LW] = theta[better, pm.LWY] = np.log(wc)
            theta[better, pm.AMP] = a[better]
            theta[better, pm.B0] = b[better]
        unset = ~np.isfinite(best)
        theta[unset, pm.LW] = theta[unset, pm.LWY] = np.log(h)
        theta[unset, pm.AMP] = 1.0
        theta[unset, pm.B0] = 0.0
        return theta

    def _touch_nuisances(
        self, rows: np.ndarray, relax: float = 1.0, step_tol: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Re-estimate gain and placement offset of touches ``rows`` from the sensor models.

        Every sensor that sees a touch says something about how hard and where it landed;
        pooled over sensors (Gauss-Newton with Gaussian priors of the current scales) they
        pin the touch down; ``relax`` > 1 stretches the step from their previous estimate;
        the iterations stop early once every step is under ``step_tol`` prior sds.
        Returns the posterior variances (log gain, mean axis mm^2).
        """
        f = self.fit
        cols = np.flatnonzero(f.has_model())
        R = rows.size
        if cols.size == 0 or R == 0:
            return np.zeros(R), np.zeros(R)
        P0 = self._P[rows]
        min_radius = self.settings.window_spacings * self.spacing()
        # Only the sensors whose fit window can contain a touch say anything about it:
        # gather them per touch, (R, M) with M the most any touch has.
        thc = f.theta[cols]
        wc = pm.half_width(thc)
        reach = (
            1.5 * np.maximum(self.settings.window_widths * wc, min_radius) + 4.0 * self.place_sd_mm
        )
        dist = np.hypot(P0[:, 0:1] - thc[None, :, pm.SX], P0[:, 1:2] - thc[None, :, pm.SY])
        inside = dist <= reach[None, :]
        order, near = packed(inside, axis=1)  # (R, M) into cols
        sel = cols[order]  # (R, M) sensor indices
        th = f.theta[sel]  # (R, M, P)
        tau = self._tau()[rows][:, None] - f.tc[sel]
        V = self._V[rows[:, None], sel] * self._sign
        U = (V - f.floor[sel]) / f.amp[sel]
        valid = np.isfinite(U) & near
        if self.rest is not None and self._raw_counts():
            rest = self.rest[sel]
            sd = self.rest_sd[sel] if self.rest_sd is not None else np.ones_like(rest)
            margin = np.maximum(3.0 * sd, 1.0)
            raw = rest + V * self._sign
            valid &= ~((raw >= ADC_MAX - margin) | (raw <= margin))
        U = np.where(valid, U, 0.0)
        scale = np.maximum(f.scale[sel], 1e-9)
        lg = self._lg[rows].copy()
        d = self._dxy[rows].copy()
        rho = self._ridge_width(thc)[order]
        prior = np.array(
            [1.0 / self.gain_sd**2, 1.0 / self.place_sd_mm**2, 1.0 / self.place_sd_mm**2]
        )
        H = np.zeros((R, 3, 3))
        for _ in range(3):
            Pe = P0 + d
            G = np.exp(lg)
            m, J = pm.jacobian(Pe, tau, th, G, rho, self.settings.shape)
            res = U - m
            win = pm.window(Pe, th, min_radius, self.settings) * valid
            z = res / (self.settings.cauchy_c * scale)
            w = win / (1.0 + z * z) / (scale * scale)
            bump = m - pm.floor(tau, th)
            Jt = np.stack([bump, -J[..., pm.SX], -J[..., pm.SY]], axis=-1)  # (R, M, 3)
            Jw = Jt * w[..., None]
            H = Jw.transpose(0, 2, 1) @ Jt + np.diag(prior)[None]
            cur = np.column_stack([lg, d])
            g = (Jw * res[..., None]).sum(axis=1) - prior[None, :] * cur
            try:
                step = np.linalg.solve(H, g[..., None])[..., 0]
            except np.linalg.LinAlgError:
                # A sensor fitted exactly (a handful of touches, no residual left) weighs
                # its touches by ~1/1e-18, and H is singular to working precision (found by
                # fuzzing with random maps); least squares still gives a step.
                step = np.stack(
                    [np.linalg.lstsq(h, gg, rcond=None)[0] for h, gg in zip(H, g, strict=True)]
                )
            lg = pm.clamp(lg + pm.clamp(step[:, 0], -1.0, 1.0), *pm.LOG_GAIN_RANGE)
            lim = pm.offset_limit(self.place_sd_mm)
            d = pm.clamp(d + pm.clamp(step[:, 1:], -lim, lim), -lim, lim)
            if step_tol and (np.abs(step) < step_tol * np.sqrt(1.0 / prior)).all():
                break
        try:
            cov = np.linalg.inv(H)
        except np.linalg.LinAlgError:
            cov = np.linalg.pinv(H)
        self._v_lg[rows] = cov[:, 0, 0]
        self._v_d[rows] = 0.5 * (cov[:, 1, 1] + cov[:, 2, 2])
        if relax != 1.0:
            # Settling (SETTLE_RELAX): each touch's step from where it was, stretched, within
            # the same bounds. The missed-touch verdict below is judged at the plain estimate.
            lg0, d0 = self._lg[rows], self._dxy[rows]
            self._lg[rows] = np.clip(lg0 + relax * (lg - lg0), *pm.LOG_GAIN_RANGE)
            self._dxy[rows] = np.clip(d0 + relax * (d - d0), -lim, lim)
        else:
            self._lg[rows] = lg
            self._dxy[rows] = d
        # A touch that the models say should have lit sensors up but did not: no contact.
        # Judged without the robust weights (which would hide exactly this touch): the
        # touch's response relative to the models' prediction, over the windows it is in.
        Pe = P0 + d
        m = pm.model(Pe, tau, th, None, rho, self.settings.shape)
        fl = pm.floor(tau, th)
        bump = m - fl
        win = pm.window(Pe, th, min_radius, self.settings) * valid / (scale * scale)
        expected = (win * bump * bump).sum(axis=1)
        ratio = (win * bump * (U - fl)).sum(axis=1) / np.maximum(expected, 1e-300)
        # The models must predict a clear response (>= ~10 sigma summed) for a verdict.
        self._missed[rows] = (expected > 100.0) & (ratio < 0.3)
        return cov[:, 0, 0], 0.5 * (cov[:, 1, 1] + cov[:, 2, 2])

    def _polish(
        self,
        rounds: int,
        relax: float = 1.0,
        joint: bool | None = None,
        em: bool = True,
        cols: np.ndarray | None = None,
    ) -> None:
        """Alternate: touch nuisances given the sensors, then the sensors given the touches.

        ``relax`` > 1 over-relaxes each round's step of the touches' nuisances; ``joint``
        (default: whether the solver is `joint`) adds joint steps to each round; ``em``
        False holds the touches' prior scales where they are; ``cols`` the sensors re-fitted
        (default all).
        """
        K = self._k
        if cols is None:
            cols = np.arange(len(self.sensors))
        if joint is None:
            joint = self.params["solver"] == "joint"
        for _ in range(rounds):
            self._shared_width()
            rows = np.arange(K)
            self._missed[:K] = False
            v_lg, v_d = self._touch_nuisances(rows, relax)
            if joint:
                for _ in range(JOINT_STEPS):
                    joint_step(self)
            use = ~self._missed[:K]
            if use.sum() >= 3:
                # Gain and placement are relative: the sensors' heights and positions carry the
                # absolute level, so the touches' nuisances are centred on zero.
                self._lg[:K][use] -= self._lg[:K][use].mean()
                self._dxy[:K][use] -= self._dxy[:K][use].mean(axis=0)
            if use.sum() >= 3 and em:
                # EM update of the prior scales from the posterior moments.
                self.gain_sd = float(
                    np.clip(np.sqrt(np.mean(self._lg[:K][use] ** 2 + v_lg[use])), 0.01, 0.5)
                )
                msq = np.mean(self._dxy[:K][use] ** 2, axis=1) + v_d[use]
                self.place_sd_mm = float(np.clip(np.sqrt(np.mean(msq)), self._place_floor, 3.0))
            self._refit_warm(cols)
        self._dirty = False

    def _footprint_width(self, theta: np.ndarray) -> np.ndarray:
        """The half width (mm) a bump is taken to have, one per row of ``theta`` (a fit per
        sensor): the probe's footprint where the solve has one (``shared_lw``), else each
        fit's own."""
        if self.shared_lw is None:
            return pm.half_width(theta)
        return np.full(len(theta), float(np.exp(self.shared_lw.mean())))

    def _ridge_width(self, theta: np.ndarray) -> np.ndarray:
        return pm.RIDGE_FRACTION * self._footprint_width(theta)

    def _shared_width(self) -> None:
        """The probe's footprint: median fitted widths over the well-determined sensors,
        or, where fewer than 3 are, over the seen peaks, held looser (SEEN_FOOTPRINT_SD)."""
        f = self.fit
        fitted = f.fitted & f.converged & (f.theta[:, pm.AMP] > 0)
        fitted &= np.isfinite(f.theta).all(axis=1)
        good = fitted & (f.n_eff >= 2 * pm.N_PARAMS)
        sd = pm.FitSettings.shared_width_sd
        if good.sum() < 3:
            idx = np.flatnonzero(fitted)
            good = np.zeros_like(fitted)
            good[idx] = seen_height(self, f.theta[idx], idx) >= UNSEEN_FRACTION
            sd = SEEN_FOOTPRINT_SD
        # The footprint and its sd are set together: the sd only counts where there is a
        # footprint (pm.sensor_priors), so nothing resets it when a solve starts afresh.
        if good.sum() >= 3:
            self.shared_lw = np.median(f.theta[good][:, [pm.LW, pm.LWY]], axis=0)
            self.settings = replace(self.settings, shared_width_sd=sd)

    def solve_all(self, calibrate: bool = True, final: bool = True) -> None:
        """Cold-start fit of every sensor, then the touch nuisances (the batch solve).

        ``final`` False: the live view's re-solve of a partial session, which leaves the
        fits that did not converge as they stand (``_hold_stuck``) and, if it left any,
        keeps the session dirty, so that ``result()`` solves again.

        ``calibrate``: then choose the response shape (``response_shape`` "auto") and size
        the sigmas as ``_error_bar`` measures (if the ``calibrate_sigma`` parameter allows).
        The sessions it simulates solve without either: they keep the shape their readings
        were drawn from. With ``calibrate``, the `alternate` solver also takes the board's
        settling out of the readings of the sensors whose fits did not follow it, and fits
        those again (_drifting.take_out_settling); and, unless the shape was given, it
        measures how far the other shapes move the peaks no touch came near
        (_unseen.shape_spread).
        """
        self._sigma_scale = 1.0
        self._shape_z = None
        if calibrate:
            self.settings = replace(self.settings, shape=self._fixed_shape or pm.SHAPES[0])
        left_unheld = self._solve_once(calibrate and self._fixed_shape is None, final)
        # Not for `joint`: there the check narrowed the robot's error bars to 2-sigma
        # coverage 0.88-0.92 (docs/localizer.md, "Two batch solvers").
        if (
            calibrate
            and self._k >= 3
            and self.params["calibrate_sigma"]
            and self.params["solver"] == "alternate"
        ):
            self._sigma_scale = sigma_scale(self, final)
        # After the error bar's factor, which is measured on sessions simulated from the
        # uncorrected fits (they solve with calibrate False, and so without this). Measured
        # for the default solver only (docs/benchmarks.md, "The board's settling taken out
        # of the readings").
        if calibrate and self.params["solver"] == "alternate":
            take_out_settling(self)
        # Last, on the fits as reported. Not where the user fixed the shape, nor in the
        # sessions the error-bar check simulates: both know their shape.
        if calibrate and self._fixed_shape is None:
            shape_spread(self)
        self._live_seen = None
        self._design_gap = None
        self._refit_next[:] = False
        self._dirty = left_unheld

    def _solve_once(self, screen: bool, final: bool = True) -> bool:
        """The batch solve from a cold start, at the current response shape or, with
        ``screen``, at the one the maps favour; ``final``: with its last step,
        ``_hold_stuck``. Returns whether it left fits for that step (``final`` False).

        The screen comes before the joint rounds: from their end the current shape's
        touch offsets fit it better than a short solve can re-fit them for another shape,
        and without a patch the exponential finger scenes of benchmarks/localizer_stress.py
        kept the Lorentzian in 6 of 10 (docs/benchmarks.md, "The shape screen before the
        joint rounds").
        """
        self._fit_and_settle()
        if self._k < 3:
            return False
        if screen:
            shape, self._shape_z = favoured_shape(self)
            if shape != self.settings.shape:
                self.settings = replace(self.settings, shape=shape)
                self._fit_and_settle()
        if self._settled:
            self._try_joint_settle()
        second_peaks(self)
        self._settling = settling_of(self)
        # Both judge the fits as they stand here (the settling check puts its re-fit back).
        inside = window_members(
            self, self.fit.theta[:, :2], pm.half_width(self.fit.theta), self.spacing()
        )
        self._moved_by_settling = moved_by_settling(self, inside)
        refit_after_settling(self, inside)
        if not final:
            return bool(self._unconverged().size)
        self._hold_stuck()
        return False

    def _unconverged(self) -> np.ndarray:
        """The sensors with a model whose fit did not converge."""
        return np.flatnonzero(self.fit.has_model() & ~self.fit.converged)

    def _hold_stuck(self) -> None:
        """Fit once more, with their windows held where they stand, the sensors whose fits
        did not converge: the solve's last step before the error-bar check.

        A fit's window moves with it at every LM iteration, and so does the cost it
        descends: at the probes' edge a fit can cycle instead of settling, and so be
        `irregular`. A run of the README's main job had two such sensors (steps of
        0.08-0.52 mm at the end of each refit); held, the window's cost is fixed, LM
        converges, and they are `ok` (docs/localizer.md, "A fit that cycles with its
        window"). Not in the live view's re-solves of a partial session (solve_all's
        ``final`` False): there the fits that have not converged are mostly the sensors no touch
        has come near yet, and windows held in every solve cost the live view its
        coverage (docs/benchmarks.md, session 64).
        """
        stuck = self._unconverged()
        if stuck.size:
            self._solve(stuck, np.ones(stuck.size, bool), hold_window=True)

    def _fit_and_settle(self) -> None:
        """Every sensor fitted from a cold start, then the alternation's rounds, and the
        settling rounds if the touches land finger-like."""
        K = self._k
        self._settled = False
        self._joint_ratio, self._joint_kept = None, False
        self._lg[:K] = 0.0
        self._dxy[:K] = 0.0
        self._missed[:K] = False
        self._v_lg[:K] = 0.0
        self._v_d[:K] = 0.0
        self.gain_sd, self.place_sd_mm, self.shared_lw = 0.2, max(0.5, self._place_floor), None
        self.fit.fitted[:] = False
        self._t_from[:] = -np.inf
        self._seed_k[:] = -1
        self._two_peaks[:] = False
        self._settling = None
        self._moved_by_settling[:] = False
        self._held_drifting[:] = False
        self._settling_shift[:] = 0.0
        self._shape_shift[:] = 0.0
        self._sign = self._detect_sign()
        self._spacing_used = self.spacing()
        n = len(self.sensors)
        if not self._k:
            return
        self._solve(np.arange(n), np.zeros(n, bool))
        if self._k < 3:
            return
        self._polish(SOLVER_ROUNDS[self.params["solver"]])
        settle = int(self.params["settle_rounds"])
        if (
            self.params["solver"] == "alternate"
            and self.place_sd_mm > FINGER_LIKE_MM
            and settle > 0
        ):
            self._polish(settle, SETTLE_RELAX)
            self._settled = True

    def _try_joint_settle(self) -> None:
        """From the settled alternation, joint rounds at its placement scale; kept only if
        the offsets they reach still fit that scale (JOINT_SETTLE_GUARD)."""
        rounds = self.params["joint_settle_rounds"]
        if rounds is None:
            rounds = 0 if self._design_pins_both_axes() else JOINT_SETTLE_ROUNDS
        if rounds <= 0:
            return
        K = self._k
        kept = self._touch_and_fit_state()
        sd0 = self.place_sd_mm
        self._polish(rounds, joint=True, em=False)
        use = ~self._missed[:K]
        if use.sum() < 3:
            self._set_touch_and_fit_state(kept)
            return
        msq = np.mean(self._dxy[:K][use] ** 2, axis=1) + self._v_d[:K][use]
        self._joint_ratio = float(np.sqrt(np.mean(msq))) / sd0
        self._joint_kept = self._joint_ratio <= JOINT_SETTLE_GUARD
        if not self._joint_kept:
            self._set_touch_and_fit_state(kept)

    def _design_pins_both_axes(self) -> bool:
        """Whether the patch's design prior holds the fits' wires on both axes: each wire
        family has a design map (DESIGN_MAP_MIN_WIRES measured wires or more; Patch A's two
        RX wires have none, so nothing from the design holds its sensors' y), and the wires
        scatter about it by at most DESIGN_LOOSE_MM (a patch built or laid far off its
        design is not held)."""
        if self.design is None or not self.params["layout_prior"]:
            return False
        f = self.fit
        var = np.diagonal(f.cov_xy, axis1=1, axis2=2).mean(axis=1)
        usable = f.has_model() & f.converged & (f.n_eff >= pm.MIN_FIT_TOUCHES) & np.isfinite(var)
        tx, rx = self.groups
        floor = float(self.params["wire_scatter_mm"])
        sd = design_scatter_mm(f.theta[:, :2], var, tx, rx, usable, self.design, floor)
        return bool(np.isfinite(sd).all() and sd.max() <= DESIGN_LOOSE_MM)

    def _touch_and_fit_state(self) -> dict:
        """What a polish changes, to put back with _set_touch_and_fit_state."""
        K = self._k
        lw = None if self.shared_lw is None else self.shared_lw.copy()
        return {
            "fit": self.fit.copy_of(),
            "touch": [a[:K].copy() for a in self._touch_arrays()],
            "scales": (self.gain_sd, self.place_sd_mm, lw, self.settings.shared_width_sd),
        }

    def _set_touch_and_fit_state(self, state: dict) -> None:
        K = self._k
        self.fit.put(state["fit"])
        for a, v in zip(self._touch_arrays(), state["touch"], strict=True):
            a[:K] = v
        self.gain_sd, self.place_sd_mm, self.shared_lw, sd = state["scales"]
        self.settings = replace(self.settings, shared_width_sd=sd)

    def _touch_arrays(self) -> tuple[np.ndarray, ...]:
        """The per-touch nuisance arrays a polish writes (rows 0..K-1)."""
        return (self._lg, self._dxy, self._missed, self._v_lg, self._v_d)

    def _statuses(self) -> np.ndarray:
        """(N,) every sensor's status as the current fits give it, for the solve's own
        re-fits: ``judge``'s, without the reported verdict's last check (_reported)."""
        return np.array([e.status for e in _build(self, *judge(self))], dtype=object)

    def _refit_warm(self, cols: np.ndarray) -> None:
        """Fit sensors ``cols`` again from where their fits stand, as a polish round does."""
        self._solve(cols, np.ones(cols.size, bool), max_iter=POLISH_MAX_ITER)

    def _refit(self, cols: np.ndarray, short: bool = False) -> dict:
        """Fit sensors ``cols`` afresh, then polish; return the fits they had, for _restore.
        ``short``: the cold start too stops at POLISH_MAX_ITER iterations."""
        kept = self.fit.copy_of(cols)
        self._solve(cols, np.zeros(cols.size, bool), max_iter=POLISH_MAX_ITER if short else None)
        self._refit_warm(cols)
        return kept

    def _restore(self, cols: np.ndarray, kept: dict, mask: np.ndarray) -> None:
        """Put back the fits _refit replaced, for the sensors ``cols[mask]``."""
        self.fit.put({name: v[mask] for name, v in kept.items()}, cols[mask])

    def update(self, log: PointLog) -> Predictions:
        """Add one touch; the estimates of every sensor, fast and local (_live_update.py).

        ``result()`` gives the converged estimates (the batch solve).
        """
        with _quiet():
            return update(self, log)

    def add(self, log: PointLog) -> None:
        """Add one touch without re-fitting anything, for a caller that takes ``result()``
        after it: a live update's re-fits, and its re-solves as the session doubles, would
        be thrown away. The next ``update()`` re-solves everything first."""
        if self._append(log):
            self._dirty = True
            self._next_full = 0

    def _current(self) -> Predictions:
        return _build(self, *_reported(self, live_judge(self)))

    # --- results -----------------------------------------------------------------------

    def result(self) -> Predictions:
        """The converged estimates: the batch solve of every log so far (cached).

        ``update`` gives fast provisional estimates that depend on the order the logs came
        in; ``result`` re-solves from the data alone, so it equals ``localize`` on the same
        logs exactly, whatever the order and whatever the live updates did.
        """
        with _quiet():
            if self._dirty:
                self.solve_all()
            return _predictions(self)


def _finite_or_none(a, n: int, name: str) -> np.ndarray | None:
    if a is None:
        return None
    a = np.asarray(a, dtype=float).reshape(-1)
    if a.size != n:
        raise InputError(f"{NAME}: {name} has {a.size} values for {n} sensors")
    return np.where(np.isfinite(a), a, np.nan)


def _predictions(loc: Localizer) -> Predictions:
    return _build(loc, *_reported(loc, judge(loc)))


def _reported(loc: Localizer, verdict: tuple) -> tuple:
    """A verdict as the user gets it (_design_reach.unreached_sparse, then
    _statuses.unrisen_weak over the `ok` calls left)."""
    status, *rest = verdict
    return (unrisen_weak(loc, unreached_sparse(loc, status)), *rest)


def _build(loc, status, xy, sigma, snr, params) -> Predictions:
    # Plain Python floats in one conversion each (a live update builds this every touch).
    has_xy = ((status == OK) & np.isfinite(xy).all(axis=1)).tolist()
    sig_ok = np.isfinite(sigma).tolist()
    snr_ok = np.isfinite(snr).tolist()
    xs, ys = xy[:, 0].tolist(), xy[:, 1].tolist()
    sigmas, snrs, statuses = sigma.tolist(), snr.tolist(), status.tolist()
    est = [
        SensorEstimate(
            sensor=name,
            x_mm=xs[i] if has_xy[i] else None,
            y_mm=ys[i] if has_xy[i] else None,
            sigma_mm=sigmas[i] if has_xy[i] and sig_ok[i] else None,
            snr_db=snrs[i] if snr_ok[i] else None,
            status=str(statuses[i]) if (has_xy[i] or statuses[i] != OK) else DEAD,
        )
        for i, name in enumerate(loc.sensors)
    ]
    return Predictions(NAME, est, params)


def solved(logs: PointLogs, **params) -> Localizer:
    """A localizer that has batch-solved every log at once, from a cold start (its state,
    for diagnostics; ``localize`` gives its result)."""
    if not isinstance(logs, PointLogs):
        raise InputError(f"{NAME}: expected PointLogs, got {type(logs).__name__}")
    loc = Localizer(logs.sensors, rest=logs.rest, rest_sd=logs.rest_sd, **params)
    for log in logs.logs():
        loc._append(log)
    with _quiet():
        loc.solve_all()
    return loc


def localize(logs: PointLogs, **params) -> Predictions:
    """Batch solve: every log at once, cold start (equals the incremental result; see tests)."""
    return solved(logs, **params).result()

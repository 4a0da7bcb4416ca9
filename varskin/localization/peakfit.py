"""``peakfit``: robust per-sensor peak fit with honest error bars, batch or incremental.

Why it exists: the paper's threshold-centroid has a large error that is not noise (the
coarse grid aliases the peak, the threshold depends on each sensor's floor, the centroid is
pulled inwards at the edge). This method fits each sensor's point log map with a Lorentzian
bump over its own (drifting) floor, only near the peak and with a robust loss, solving all
sensors at once in numpy. A ``Localizer`` takes one point log at a time and re-fits only the
sensors the new touch informs, warm-started, so a live session sees estimates as it goes;
``localize`` is the same machinery fed with every log at once. See docs/localizer.md.
"""

from __future__ import annotations

import math
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, replace

import numpy as np

from varskin.errors import InputError
from varskin.localization import _peak_model as pm
from varskin.localization._error_bar import sigma_scale
from varskin.localization._hull import ProbeHull
from varskin.localization._joint import joint_step
from varskin.localization._layout_prior import design_scatter_mm
from varskin.localization._settling import board_settling
from varskin.localization._statuses import (
    DEAD,
    DRIFTING,
    IRREGULAR,
    UNCERTAIN,
    drift_measures,
    drifting_during_own_touches,
    judge,
    window_members,
)
from varskin.patch import Patch
from varskin.pointlogs import MAX_TIME_S, PointLog, PointLogs
from varskin.predictions import OK, R95_PER_AXIS_SD, Predictions, SensorEstimate
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
# Not where a patch's design prior is in use: it pins those same edge sensors after the
# solve, and there the rounds gained little (200 Patch B plan scenes: median RMS 0.499 ->
# 0.484 mm, none above 2 mm either way) for 1.65x the solve's time, while they moved the
# batch further from the live view than its stated tolerance (test_live_update_restarts_a_
# sensor_whose_peak_turns_up_away_from_its_fit: 2.59 sigma) and cost the design prior's
# pull on off-design patches (docs/benchmarks.md, "Joint rounds after settling").
JOINT_SETTLE_ROUNDS = 8
# ... unless the patch lies so far off its design that the design prior no longer pins
# those sensors: its wires scatter about the design map by more than DESIGN_LOOSE_MM (the
# simulator's default displacement is 0.6 mm sd). Then the solve takes the rounds as it
# would without the patch (docs/benchmarks.md, "A patch far off its design").
DESIGN_LOOSE_MM = 1.0
JOINT_SETTLE_GUARD = 1.15
JOINT_STEPS = 2
# The response shape (``response_shape`` "auto"): another of pm.SHAPES replaces the
# Lorentzian only if the paired test over sensors favours it beyond SHAPE_Z standard errors,
# with at least SHAPE_MIN_SENSORS sensors to test on (_favoured_shape).
SHAPE_Z = 3.0
SHAPE_MIN_SENSORS = 8
SHAPE_SCREEN_ROUNDS = 2
# A larger patch screens on the SHAPE_SCREEN_SENSORS sensors nearest its middle, the touches
# their windows hold, and no others: the screen's cost then stays that of a 64-sensor patch
# (the full board's batch solve took 2.1-2.3 s with every sensor screened, against its 2 s
# budget), while its paired test keeps twice the sensors of Patch B.
SHAPE_SCREEN_SENSORS = 64
# LM iterations per sensor in a polish round (warm-started). Located sensors converge in a
# few; a sensor not yet probed near (mid-session) never does and would cost the full 100.
POLISH_MAX_ITER: int | None = 25
# LM iterations of a live update's re-fit (warm-started): 3 is the fewest the fit's stop
# rule runs. Against 4, on Patch B seeds 0-15, robot and finger, updates 50-100: the live
# RMS of the `ok` sensors is lower (median 0.22-0.27 against 0.24-0.34 mm robot, 0.80
# against 0.82-0.87 mm finger), 0.3-0.5 fewer of ~17 sensors are `ok`, and the last
# update's largest gap to the batch is about the same (1.1-1.6 sigma either way).
UPDATE_ITERATIONS = 3
# ... and of the second, shorter pass after the touch's own gain and placement are known:
# it starts from the first pass's fit and moves it by a fraction of a millimetre.
REFIT_ITERATIONS = 2
# A reading this far above a sensor's last RECENT_TOUCHES readings, beyond what its model's
# bump predicts at a touch outside its window (in the map's heights, and in residual
# sigmas), makes a live update restart that sensor from its map's top.
UNEXPLAINED_HEIGHT = 0.5
UNEXPLAINED_SIGMAS = 5.0
RECENT_TOUCHES = 6

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
    # patch's design prior is in use, then none.
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
    # Lorentzian unless the maps favour another (_favoured_shape).
    "response_shape": "auto",
}

# A `drifting` sensor probed again after the probe was away for more than this many
# touches' time is re-fitted from the touches since it came back (_refit_after_settling).
REPROBE_AWAY_TOUCHES = 4
# The board's settling, taken out of a sensor's readings (_settling_moved), must move its
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
# A second peak of a map (_second_peaks): its detrended height relative to the fitted
# peak's, the radius (probe spacings) of its backing touch and of the start search around
# it, and by how much one peak's effective touch count must beat the other's to win.
SECOND_PEAK_FRACTION = 0.6
SEED_RADIUS_SPACINGS = 1.5
SECOND_PEAK_RATIO = 1.5
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
        self._dirty = False  # touches added since the last full polish
        self._next_full = 8  # the live view re-solves everything when the session doubles
        self.shared_lw: np.ndarray | None = None  # (2,) log footprint widths of the probe
        self._sign = 1.0
        self._spacing_used: float | None = None
        # Per sensor, the session time (min) of the first touch its fit may use: -inf, or
        # later for a sensor whose offset was still settling during its first touches.
        self._t_from = np.full(n, -np.inf)
        # Per sensor, the touch near which its fit must start (-1: the map's top), and
        # whether its map has two peaks that fit equally well (see _second_peaks).
        self._seed_k = np.full(n, -1)
        self._two_peaks = np.zeros(n, bool)
        # The board's offset settling as the last batch solve saw it (_settling.py): its
        # time course over the touches then, and each sensor's settled level; None: unknown.
        self._settling: tuple[np.ndarray, np.ndarray] | None = None
        # Per sensor: taking that settling out of its readings moved its fit too far for
        # its error bar (_settling_moved; one of the `drifting` reasons).
        self._moved_by_settling = np.zeros(n, bool)
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
            med = _nanmedian_cols(V)
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
            floor = _nanmedian_cols(Vv)
            top = np.nanmax(Vv, axis=0)
        floor = np.where(np.isfinite(floor), floor, 0.0)
        amp = top - floor
        amp = np.where(np.isfinite(amp) & (amp > 0), amp, 1.0)
        U = (np.where(valid, V, 0.0) - floor[None, :]) / amp[None, :]
        return U, U - _floor_trend(U, valid), valid, floor, amp

    def _raw_counts(self) -> bool:
        """Do rest values look like Muca ADC counts (so ADC clipping can be judged)?"""
        if self._raw is None:
            if self.rest is None or not np.isfinite(self.rest).any():
                self._raw = False
            else:
                self._raw = bool(100.0 <= float(np.nanmedian(self.rest)) <= ADC_MAX)
        return self._raw

    # --- solving -----------------------------------------------------------------------

    def _map_inputs(self, cols: np.ndarray) -> tuple:
        """What a fit of sensors ``cols`` takes from their maps: (clipped, U, D, valid,
        floor, amp, noise), every array with one column (or entry) per sensor."""
        K = self._k
        clipped = self._clipped(cols)
        U, D, valid, floor, amp = self._maps(cols, clipped)
        with np.errstate(all="ignore"):
            noise = _nanmedian_cols(self._noise[:K][:, cols]) / amp
        noise = np.where(np.isfinite(noise) & (noise > 0), noise, 0.0)
        return clipped, U, D, valid, floor, amp, noise

    def _solve(
        self,
        cols: np.ndarray,
        warm: np.ndarray,
        max_iter: int | None = None,
        inputs: tuple | None = None,
    ) -> tuple | None:
        """(Re)fit sensors ``cols``; ``warm`` (bool per col) starts from the previous fit.

        ``inputs``: ``_map_inputs(cols)`` if the caller already has them (the second pass of
        a live update fits a subset of the first's sensors on the same maps). Returns the
        inputs used.
        """
        K = self._k
        if cols.size == 0 or K == 0:
            return None
        P = self._P[:K] + self._dxy[:K]
        tau = self._tau()
        if inputs is None:
            inputs = self._map_inputs(cols)
        clipped, U, D, valid, floor, amp, noise = inputs
        f = self.fit
        h = self.spacing()
        min_radius = self.settings.window_spacings * h
        # The start: the top of the detrended map D, or near the touch a second-peak check
        # chose (_second_peaks).
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
        theta0[:, pm.B0] += np.take_along_axis(U - D, kmax[None, :], axis=0)[0]
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
        res = pm.fit(
            P,
            tau,
            U,
            valid,
            theta0,
            min_radius,
            np.maximum(noise, 1e-9),
            self.settings if max_iter is None else replace(self.settings, max_iter=max_iter),
            gain=np.exp(self._lg[:K]),
            width_mean=None if self.shared_lw is None else np.tile(self.shared_lw, (cols.size, 1)),
            ridge_width=self._ridge_width(cols.size, theta0),
            touch_var=(np.full(K, self.gain_sd**2), np.full(K, self.place_sd_mm**2)),
            scale0=np.where(warm, f.scale[cols] * f.amp[cols] / amp, 0.3) if warm.any() else None,
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
        return inputs

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
        self, rows: np.ndarray, relax: float = 1.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Re-estimate gain and placement offset of touches ``rows`` from the sensor models.

        Every sensor that sees a touch says something about how hard and where it landed;
        pooled over sensors (Gauss-Newton with Gaussian priors of the current scales) they
        pin the touch down; ``relax`` > 1 stretches the step from their previous estimate.
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
        M = max(int(inside.sum(axis=1).max()), 1)
        order = np.argsort(~inside, axis=1, kind="stable")[:, :M]  # (R, M) into cols
        near = np.take_along_axis(inside, order, axis=1)
        sel = cols[order]  # (R, M) sensor indices
        th = f.theta[sel]  # (R, M, P)
        tau = self._tau()[rows][:, None] - f.tc[sel]
        V = np.take_along_axis(self._V[rows], sel, axis=1) * self._sign
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
        rho = self._ridge_width(cols.size, thc)[order]
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
            lg = np.clip(lg + np.clip(step[:, 0], -1.0, 1.0), *pm.LOG_GAIN_RANGE)
            lim = pm.offset_limit(self.place_sd_mm)
            d = np.clip(d + np.clip(step[:, 1:], -lim, lim), -lim, lim)
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
            self._solve(cols, np.ones(cols.size, bool), max_iter=POLISH_MAX_ITER)
        self._dirty = False

    def _ridge_width(self, n: int, theta: np.ndarray) -> np.ndarray:
        lw = self.shared_lw if self.shared_lw is not None else None
        w = pm.half_width(theta) if lw is None else np.full(n, float(np.exp(lw.mean())))
        return pm.RIDGE_FRACTION * w

    def _shared_width(self) -> None:
        """The probe's footprint: median fitted widths over the well-determined sensors."""
        f = self.fit
        good = f.fitted & f.converged & (f.n_eff >= 2 * pm.N_PARAMS) & (f.theta[:, pm.AMP] > 0)
        good &= np.isfinite(f.theta).all(axis=1)
        if good.sum() >= 3:
            self.shared_lw = np.median(f.theta[good][:, [pm.LW, pm.LWY]], axis=0)

    def solve_all(self, calibrate: bool = True) -> None:
        """Cold-start fit of every sensor, then the touch nuisances (the batch solve).

        ``calibrate``: then choose the response shape (``response_shape`` "auto") and size
        the sigmas as ``_error_bar`` measures (if the ``calibrate_sigma`` parameter allows).
        The sessions it simulates solve without either: they keep the shape their readings
        were drawn from.
        """
        self._sigma_scale = 1.0
        self._shape_z = None
        if calibrate:
            self.settings = replace(self.settings, shape=self._fixed_shape or pm.SHAPES[0])
        self._solve_once()
        if calibrate and self._fixed_shape is None and self._k >= 3:
            shape, self._shape_z = self._favoured_shape()
            if shape != self.settings.shape:
                self.settings = replace(self.settings, shape=shape)
                self._solve_once()
        # Not for `joint`: there the check narrowed the robot's error bars to 2-sigma
        # coverage 0.88-0.92 (docs/localizer.md, "Two batch solvers").
        if (
            calibrate
            and self._k >= 3
            and self.params["calibrate_sigma"]
            and self.params["solver"] == "alternate"
        ):
            self._sigma_scale = sigma_scale(self)
        self._dirty = False

    def _solve_once(self) -> None:
        """The batch solve at the current response shape, from a cold start."""
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
            self._try_joint_settle()
        self._second_peaks()
        self._settling = self._board_settling()
        # Both judge the fits as they stand here (the settling check puts its re-fit back).
        inside = window_members(
            self, self.fit.theta[:, :2], pm.half_width(self.fit.theta), self.spacing()
        )
        self._moved_by_settling = self._settling_moved(inside)
        self._refit_after_settling(inside)

    def _favoured_shape(self) -> tuple[str, float | None]:
        """The response shape the maps favour, and its paired z (None: not tested).

        Every shape gets a short solve from this solve's state: the sensors fitted
        again, warm-started, then SHAPE_SCREEN_ROUNDS rounds of the touches' nuisances and
        the sensors (those absorb part of a shape's misfit, so the shape must have its own).
        The current shape gets the same short solve: the full solve's own residual scale
        is no reference (on a scattered finger plan a short solve from its end, at its own
        shape, lowered it by 0.47 in log on average, and the comparison with it chose a
        shape the scene did not have). A shape wins only if it lowers the converged sensors'
        robust residual scale across the patch, by a paired test over sensors (log scale
        ratio, mean over its standard error) below -SHAPE_Z: every sensor of a patch answers
        the same probe, so they share one shape, where one sensor alone cannot tell the
        shapes apart from noise. The state is put back afterwards (docs/localizer.md,
        "Robustness to a wrong response model").
        """
        f = self.fit
        cols = np.flatnonzero(f.has_model() & f.converged)
        current = self.settings.shape
        if cols.size < SHAPE_MIN_SENSORS:
            return current, None
        kept = self._touch_and_fit_state()
        block = self._screened(cols)
        sub = block.size < cols.size
        hidden = np.setdiff1d(np.arange(len(self.sensors)), block) if sub else block[:0]
        polished = block if sub else None
        scales = {}
        for shape in pm.SHAPES:
            # Sensors outside the screen's block have no model while it runs: the touches'
            # nuisances and the shared footprint come from the block alone.
            f.fitted[hidden] = False
            # The touches' gains and offsets and the shared footprint absorb part of a
            # wrong shape's misfit: each shape gets its own, as a short solve would.
            self.settings = replace(self.settings, shape=shape)
            self._solve(block, np.ones(block.size, bool), max_iter=POLISH_MAX_ITER)
            self._polish(SHAPE_SCREEN_ROUNDS, cols=polished)
            scales[shape] = np.log(np.maximum(f.scale[block], 1e-300))
            self._set_touch_and_fit_state(kept)
        best, best_z, best_gain = current, None, 0.0
        for shape, scale in scales.items():
            if shape == current:
                continue
            d = scale - scales[current]
            d = d[np.isfinite(d)]
            sd = float(np.std(d, ddof=1)) if d.size >= SHAPE_MIN_SENSORS else 0.0
            if sd <= 0.0:
                continue
            z = float(np.mean(d)) / (sd / math.sqrt(d.size))
            if best_z is None or z < best_z:
                best_z = z
            if z < -SHAPE_Z and float(np.mean(d)) < best_gain:
                best, best_gain = shape, float(np.mean(d))
        self.settings = replace(self.settings, shape=current)
        return best, best_z

    def _screened(self, cols: np.ndarray) -> np.ndarray:
        """The sensors of ``cols`` the shape screen fits: all of them, or on a larger patch
        the SHAPE_SCREEN_SENSORS nearest the middle of their fitted positions (a block, so
        the touches inside it keep every sensor that sees them)."""
        if cols.size <= SHAPE_SCREEN_SENSORS:
            return cols
        xy = self.fit.theta[cols][:, [pm.SX, pm.SY]]
        d = np.hypot(*(xy - np.median(xy, axis=0)).T)
        return np.sort(cols[np.argsort(d, kind="stable")[:SHAPE_SCREEN_SENSORS]])

    def _board_settling(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The board's settling from the fits as they stand (_settling.py); None where the
        values are not relative to a measured rest (no baseline: no settling to speak of)."""
        if self.rest is None:
            return None
        K, f = self._k, self.fit
        V = np.where(self._missed[:K, None], np.nan, self._V[:K] * self._sign)
        w = pm.half_width(f.theta)
        usable = f.has_model()
        with np.errstate(all="ignore"):
            noise = _nanmedian_cols(self._noise[:K])
        if self.rest_sd is not None:  # logs without sample sds: the baseline's
            noise = np.where(np.isfinite(noise), noise, self.rest_sd)
        P = self._P[:K] + self._dxy[:K]
        return board_settling(V, P, self._tau(), f.theta[:, :2], w, usable, noise)

    def _settling_moved(self, inside: np.ndarray) -> np.ndarray:
        """(N,) bool: the sensors whose fit, warm re-fitted with the board's settling (as
        ``_board_settling`` read it) taken out of their readings, moves by more than
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
        n = len(self.sensors)
        out = np.zeros(n, bool)
        if self._settling is None:
            return out
        K, f = self._k, self.fit
        course, level = self._settling
        with np.errstate(all="ignore"):
            _, unfollowed = drift_measures(self, inside)
        cols = np.flatnonzero(f.has_model() & (unfollowed > SETTLING_CHECK_FRACTION))
        if cols.size == 0:
            return out
        settled = np.nan_to_num(level[cols][None, :] * course[:K, None])  # peak-up units
        kept = f.copy_of(cols)
        before = f.theta[cols, :2].copy()
        sd = np.sqrt(np.maximum(np.trace(f.cov_xy[cols], axis1=1, axis2=2) / 2.0, 0.0))
        V = self._V[:K, cols].copy()
        try:
            self._V[:K, cols] = V - settled * self._sign
            self._solve(cols, np.ones(cols.size, bool), max_iter=POLISH_MAX_ITER)
            moved = np.hypot(*(f.theta[cols, :2] - before).T)
        finally:
            self._V[:K, cols] = V
            f.put(kept, cols)
        sigma = sd * R95_PER_AXIS_SD / 2.0
        out[cols] = (moved > SETTLING_MOVE_SIGMAS * sigma) & (moved > SETTLING_MOVE_MM)
        return out

    def _try_joint_settle(self) -> None:
        """From the settled alternation, joint rounds at its placement scale; kept only if
        the offsets they reach still fit that scale (JOINT_SETTLE_GUARD)."""
        rounds = self.params["joint_settle_rounds"]
        if rounds is None:
            design_prior = self.design is not None and self.params["layout_prior"]
            rounds = 0 if design_prior and not self._off_design() else JOINT_SETTLE_ROUNDS
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

    def _off_design(self) -> bool:
        """Whether the fits' wires scatter about the patch's design map by more than
        DESIGN_LOOSE_MM: a patch built (or laid) that far off its design."""
        f = self.fit
        var = np.diagonal(f.cov_xy, axis1=1, axis2=2).mean(axis=1)
        usable = f.has_model() & f.converged & (f.n_eff >= pm.MIN_FIT_TOUCHES) & np.isfinite(var)
        tx, rx = self.groups
        floor = float(self.params["wire_scatter_mm"])
        scatter = design_scatter_mm(f.theta[:, :2], var, tx, rx, usable, self.design, floor)
        return scatter > DESIGN_LOOSE_MM

    def _touch_and_fit_state(self) -> dict:
        """What a polish changes, to put back with _set_touch_and_fit_state."""
        K = self._k
        lw = None if self.shared_lw is None else self.shared_lw.copy()
        return {
            "fit": self.fit.copy_of(),
            "touch": [a[:K].copy() for a in self._touch_arrays()],
            "scales": (self.gain_sd, self.place_sd_mm, lw),
        }

    def _set_touch_and_fit_state(self, state: dict) -> None:
        K = self._k
        self.fit.put(state["fit"])
        for a, v in zip(self._touch_arrays(), state["touch"], strict=True):
            a[:K] = v
        self.gain_sd, self.place_sd_mm, self.shared_lw = state["scales"]

    def _touch_arrays(self) -> tuple[np.ndarray, ...]:
        """The per-touch nuisance arrays a polish writes (rows 0..K-1)."""
        return (self._lg, self._dxy, self._missed, self._v_lg, self._v_d)

    def _statuses(self) -> np.ndarray:
        """(N,) every sensor's status as the current fits give it."""
        return np.array([e.status for e in _predictions(self)], dtype=object)

    def _refit(self, cols: np.ndarray, cold_iter: int | None = None) -> dict:
        """Fit sensors ``cols`` afresh, then polish; return the fits they had, for _restore."""
        kept = self.fit.copy_of(cols)
        self._solve(cols, np.zeros(cols.size, bool), max_iter=cold_iter)
        self._solve(cols, np.ones(cols.size, bool), max_iter=POLISH_MAX_ITER)
        return kept

    def _restore(self, cols: np.ndarray, kept: dict, mask: np.ndarray) -> None:
        """Put back the fits _refit replaced, for the sensors ``cols[mask]``."""
        self.fit.put({name: v[mask] for name, v in kept.items()}, cols[mask])

    def _refit_after_settling(self, inside: np.ndarray) -> None:
        """Re-fit each `drifting` sensor from the touches since the probe came back to it
        (``inside``: the touches in each fit's window, ``window_members``).

        A sensor probed first while its offset still settled is `drifting` however often it
        is probed again: its first touches stay in its window, and the slow floor model
        cannot follow them. Its later touches, once re-probed, see a steady floor and place
        it alone. The re-fit is kept only where it passes every check (`drifting` included,
        judged on the touches it used); otherwise the sensor keeps its fit and its status.
        """
        f = self.fit
        with np.errstate(all="ignore"):
            drifting = drifting_during_own_touches(self, inside)
        cols = np.flatnonzero(f.fitted & drifting)
        if cols.size == 0:
            return
        tau = self._tau()
        inside = inside[:, cols]
        # The probe must have left and come back: a pass that merely went on over the
        # sensor (a serpentine grid's next columns) is the same settling, seen from one side.
        away = REPROBE_AWAY_TOUCHES * float(np.median(np.diff(tau))) if tau.size > 1 else 0.0
        for j, c in enumerate(cols):
            t = np.sort(tau[inside[:, j]])
            back = np.flatnonzero(np.diff(t) > away)
            if away > 0 and back.size:
                self._t_from[c] = t[back[0] + 1]
        cols = cols[np.isfinite(self._t_from[cols])]
        if cols.size == 0:
            return
        kept = self._refit(cols)
        # The settling check judged the touches the re-fit no longer uses.
        moved = self._moved_by_settling[cols].copy()
        self._moved_by_settling[cols] = False
        failed = self._statuses()[cols] != OK
        if failed.any():
            self._restore(cols, kept, failed)
            self._t_from[cols[failed]] = -np.inf
            self._moved_by_settling[cols[failed]] = moved[failed]

    def _second_peaks(self) -> None:
        """Fit again from a second peak of a map, where one stands far from the fitted one.

        The model assumes one bump per map. An offset that settles by more than the peak
        while the session starts leaves a false top at the first touches, and the fit may
        take it: `ok`, 100 mm off, sigma 3-5 mm, while the real bump stands elsewhere
        (benchmarks/localizer_stress.py, drift 1-2x the peak). A map's highest detrended
        reading outside the fit's window (at the probe's shared footprint), at least
        SECOND_PEAK_FRACTION of the highest inside and backed by a neighbouring touch, is a
        second peak; the sensor is fitted again from there. The peak that more touches
        agree with (effective count, SECOND_PEAK_RATIO) wins, whatever its status: a real
        bump that is `drifting` beats a confident fit to a settling offset. Only a bump is
        a rival: a fit that ran off beyond the probes or failed its checks is "backed" by
        touches that merely show no bump. Two `ok` peaks about equally backed make the
        sensor `irregular`: the map does not say which one is the sensor. Only `ok`,
        `uncertain` and (fits that failed their sanity checks) `irregular` sensors are
        checked: the others already say why they have no position.
        """
        f = self.fit
        K = self._k
        n = len(self.sensors)
        cols = np.flatnonzero(f.fitted & np.isfinite(f.theta).all(axis=1))
        if cols.size == 0:
            return
        h = self.spacing()
        P = self._P[:K] + self._dxy[:K]
        _, D, valid, _, _ = self._maps(cols, self._clipped(cols))
        # At the shared footprint: a fit whose own width collapsed must not take its
        # bump's other flank for a second peak.
        lw = f.theta[:, [pm.LW, pm.LWY]] if self.shared_lw is None else self.shared_lw[None, :]
        w = np.broadcast_to(np.exp(0.5 * lw.sum(axis=1)), (n,))
        inside = window_members(self, f.theta[:, :2], w, h)[:, cols]
        Dv = np.where(valid, D, -np.inf)
        top_in = np.where(inside, Dv, -np.inf).max(axis=0)
        out = np.where(inside, -np.inf, Dv)
        k2 = np.argmax(out, axis=0)
        d2 = out[k2, np.arange(cols.size)]
        d = np.hypot(P[:, 0:1] - P[k2][None, :, 0], P[:, 1:2] - P[k2][None, :, 1])
        near = (d > 0) & (d <= SEED_RADIUS_SPACINGS * h)
        backed = (near & (Dv >= 0.5 * d2[None, :])).any(axis=0)
        cand = np.isfinite(d2) & (d2 > 0) & (d2 >= SECOND_PEAK_FRACTION * top_in) & backed
        if not cand.any():
            return
        # An `ok` call can be silently wrong, an `uncertain` one may be the false top's
        # loose fit, and so may an `irregular` one that failed the fit's sanity checks
        # (hard case: Patch B S14, seed 3, once the joint rounds moved the touches); the
        # others already say why they have no position.
        before = self._statuses()[cols]
        insane = (before == IRREGULAR) & ~self._two_peaks[cols]
        cand &= (before == OK) | (before == UNCERTAIN) | insane
        if not cand.any():
            return
        c = cols[cand]
        self._seed_k[c] = k2[cand]
        kept = self._refit(c, cold_iter=POLISH_MAX_ITER)
        after = self._statuses()[c]
        radius = np.maximum(self.settings.window_widths * w[c], self.settings.window_spacings * h)
        # A fit from the second peak that came back to the first is no second opinion.
        apart = np.hypot(*(f.theta[c, :2] - kept["theta"][:, :2]).T) > radius
        rival = apart & ((after == OK) | (after == DRIFTING))
        n_old, n_new = kept["n_eff"], f.n_eff[c]
        new_wins = rival & (n_new >= SECOND_PEAK_RATIO * n_old)
        tie = rival & ~new_wins & (n_old < SECOND_PEAK_RATIO * n_new)
        restore = ~new_wins
        self._restore(c, kept, restore)
        self._seed_k[c[restore]] = -1
        self._two_peaks[c[tie & (after == OK) & (before[cand] == OK)]] = True

    def update(self, log: PointLog) -> Predictions:
        """Add one touch; the estimates of every sensor, fast and local (see ``_update``).

        ``result()`` gives the converged estimates (the batch solve).
        """
        with _quiet():
            return self._update(log)

    def _update(self, log: PointLog) -> Predictions:
        """Add one touch and return the updated estimates of every sensor (fast, local).

        The sensors near the new touch are re-fitted, warm-started; then the touch's own
        gain and placement are estimated from those models, and the sensors whose view of
        the touch that changes are re-fitted once more. Every time the session doubles,
        everything is re-solved from scratch. ``result()`` gives the batch solve.
        """
        if not self._append(log):
            return self._current()
        self._dirty = True
        k = self._k - 1
        sign = self._detect_sign()
        h = self.spacing()
        f = self.fit
        if (
            sign != self._sign
            or self._spacing_used is None
            or abs(h - self._spacing_used) > 0.1 * self._spacing_used
            or self._k >= self._next_full
        ):
            # Re-solve everything when the session has doubled (or its scale changed): the
            # shared footprint and the touch nuisances settle, and the cost stays amortized.
            self._next_full = max(2 * self._k, 8)
            self.solve_all()
            self._dirty = False
            return self._current()
        p = self._P[k]  # the touch's own placement offset is estimated below
        w = pm.half_width(f.theta)
        radius = (
            np.maximum(self.settings.window_widths * w, self.settings.window_spacings * h) * 1.5
        )
        near = np.hypot(f.theta[:, pm.SX] - p[0], f.theta[:, pm.SY] - p[1]) < radius
        # A new maximum of the map far from the current estimate that the model cannot
        # explain: the peak may be elsewhere, so that sensor restarts from its map's top.
        v_new = self._V[k] * self._sign
        with np.errstate(invalid="ignore"):
            before = (
                np.nanmax(self._V[:k] * self._sign, axis=0) if k else np.full_like(v_new, -np.inf)
            )
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
            recent = _nanmedian_cols(self._V[max(0, k - RECENT_TOUCHES) : k] * self._sign)
            ridge = self._ridge_width(len(self.sensors), f.theta)
            zero = np.zeros((1, len(self.sensors)))
            shape = self.settings.shape
            bump = (
                pm.model(p[None], zero, f.theta, None, ridge, shape)[0] - pm.floor(zero, f.theta)[0]
            )
            rise = (v_new - recent) / f.amp - bump
            new_top |= (
                np.isfinite(rise)
                & (rise > UNEXPLAINED_HEIGHT)
                & (rise > UNEXPLAINED_SIGMAS * f.scale)
                & ~near
                & f.fitted
            )
        # One pass over both: a restarted sensor begins at its map's top (a good start) and
        # the following updates refine it, so a few iterations suffice here too.
        todo = np.flatnonzero(near | new_top)
        # The last batch solve's settling verdict judged maps these sensors have outgrown.
        self._moved_by_settling[todo] = False
        first = None
        if todo.size:
            first = self._solve(todo, ~new_top[todo], max_iter=UPDATE_ITERATIONS)
        # The new touch's own gain and placement come from the models it has just updated
        # (judged by models that had not seen it, a first touch near a sensor would be
        # "explained" by a wrong offset), then those sensors take one more short pass.
        self._touch_nuisances(np.array([k]))
        cand = todo
        # Only where the estimated gain and placement change what the touch says (a robot's
        # placement is good to ~0.05 mm: usually nowhere) is the second pass worth its cost.
        th = f.theta[cand]
        rho = self._ridge_width(cand.size, th)
        zero = np.zeros((1, cand.size))
        shape = self.settings.shape
        m0 = pm.model(self._P[k : k + 1], zero, th, None, rho, shape)[0]
        m1 = pm.model(
            self._P[k : k + 1] + self._dxy[k], zero, th, np.exp(self._lg[k : k + 1]), rho, shape
        )[0]
        pick = np.abs(m1 - m0) > np.maximum(f.scale[cand], 1e-12)
        redo = cand[pick]
        if redo.size:
            # The same maps as the first pass, unless the touch was just judged missed
            # (which changes what is valid); per-sensor columns, so a subset is a slice.
            inputs = None
            if first is not None and not self._missed[k]:
                sub = np.flatnonzero(pick)
                inputs = tuple(a[sub] if a.ndim == 1 else a[:, sub] for a in first)
            self._solve(redo, np.ones(redo.size, bool), max_iter=REFIT_ITERATIONS, inputs=inputs)
        return self._current()

    def _current(self) -> Predictions:
        return _predictions(self)

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


def _nanmedian_cols(A: np.ndarray) -> np.ndarray:
    """``np.nanmedian(A, axis=0)`` (NaN for an all-NaN column, without a warning).

    numpy's nanmedian goes through masked arrays for small inputs, which made it one of
    the largest costs of a live update.
    """
    if A.shape[0] == 0:
        return np.full(A.shape[1], np.nan)
    B = np.sort(A, axis=0)  # NaN sorts last
    n = (~np.isnan(B)).sum(axis=0)
    cols = np.arange(A.shape[1])
    # The two middle ranks of the n finite values (the same one when n is odd).
    lo = B[np.maximum((n - 1) // 2, 0), cols]
    hi = B[n // 2 - (n == 0), cols]
    return np.where(n > 0, 0.5 * (lo + hi), np.nan)


def _floor_trend(U: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Each sensor's slow floor over the session: low quantile of consecutive touches.

    Touches are binned in arrival order (bins of ~K/8, at least 10); the 20th percentile of a
    bin ignores the few touches near the sensor, and bins are joined by straight lines.
    """
    K, S = U.shape
    m = max(10, K // 8)
    if 2 * m > K:
        q = np.percentile(np.where(valid, U, np.inf), 20, axis=0, method="lower")
        return np.broadcast_to(np.where(np.isfinite(q), q, 0.0), (K, S))
    edges = np.linspace(0, K, K // m + 1).astype(int)
    centres = 0.5 * (edges[:-1] + edges[1:] - 1)
    # Invalid cells sort last (+inf), so a low quantile ignores them while they are few.
    Un = np.where(valid, U, np.inf)
    # All bins at once: pad each to the longest with +inf (sorts last), sort within bins,
    # and take each bin's own "lower" 20th-percentile rank.
    sizes = np.diff(edges)
    nb, mx = sizes.size, int(sizes.max())
    pos = np.arange(K) - np.repeat(edges[:-1], sizes)
    padded = np.full((nb, mx, S), np.inf)
    padded[np.repeat(np.arange(nb), sizes), pos] = Un
    padded.sort(axis=1)
    rank = np.floor(0.2 * (sizes - 1)).astype(int)
    q = padded[np.arange(nb), rank]
    # Bins without any valid value borrow the sensor's overall level.
    overall = _nanmedian_cols(q) if np.isfinite(q).any() else np.zeros(S)
    q = np.where(np.isfinite(q), q, np.where(np.isfinite(overall), overall, 0.0)[None, :])
    k = np.arange(K)
    j = np.clip(np.searchsorted(centres, k) - 1, 0, len(centres) - 2)
    t = np.clip((k - centres[j]) / (centres[j + 1] - centres[j]), 0.0, 1.0)
    return q[j] * (1 - t)[:, None] + q[j + 1] * t[:, None]


def _predictions(loc: Localizer) -> Predictions:
    return _build(loc, *judge(loc))


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

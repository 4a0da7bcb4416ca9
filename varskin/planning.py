"""Where to touch next: the uniform grid, and an adaptive plan driven by the localizer.

Why it exists: a calibration session spends its time on touches (seconds each on the
rig). The paper's 20 x 5 grid spends them evenly, also far from every sensor. The adaptive
planner spends a small coarse pass, then puts each next touch where it shrinks the
localizer's per-sensor uncertainty most, and stops as soon as every sensor is located
within a target. Both planners are generators that receive each touch's outcome, so a
session drives any plan the same way, and a resumed session re-feeds its stored outcomes
to get back to the same state (the plans are deterministic functions of the outcomes).

Everything here is in patch-frame millimetres; the robot side converts.

Protocol::

    gen = planner.plan()
    touch = next(gen)
    while True:
        outcome = ...  # do the touch, localize, build a TouchOutcome
        try:
            touch = gen.send(outcome)
        except StopIteration:
            break
"""

from __future__ import annotations

import math
from collections.abc import Generator
from dataclasses import dataclass, field

import numpy as np

from varskin.patch import Patch
from varskin.pointlogs import touch_spacing_mm
from varskin.predictions import OK, R95_PER_AXIS_SD, Predictions

UNIFORM = "uniform"
COARSE = "coarse"
ADAPTIVE = "adaptive"
GIVEN = "given"  # a touch fixed in advance: a refined session's stored ones

# Stop reasons of the adaptive plan (``AdaptivePlanner.stop_reason``).
TARGET = "target"  # every sensor located with sigma_mm <= target
BUDGET = "budget"  # the touch budget is spent
EXHAUSTED = "exhausted"  # no allowed candidate is left (all excluded after failures)

# The Fisher model's parameters per sensor: position, log footprint width, height, floor.
_N = 5


@dataclass(frozen=True)
class PlannedTouch:
    index: int  # 0, 1, 2 ... in plan order
    x_mm: float
    y_mm: float
    phase: str  # "uniform", "coarse", "given" or "adaptive"


@dataclass(frozen=True)
class TouchOutcome:
    touch: PlannedTouch
    ok: bool  # False: the touch failed after retries (no point log)
    predictions: Predictions | None  # the localizer's result after this touch's log


PlanGenerator = Generator[PlannedTouch, "TouchOutcome | None", None]


def _check_box(patch: Patch, margin_mm: float) -> None:
    if not (math.isfinite(margin_mm) and margin_mm >= 0):
        raise ValueError(f"margin_mm must be >= 0, got {margin_mm!r}")
    if 2 * margin_mm >= min(patch.length_mm, patch.width_mm):
        raise ValueError(f"margin_mm ({margin_mm:g} mm) leaves no room on patch {patch.name!r}")


# The uniform plan's touch orders. "sweep": serpentine, the shortest travel. "shuffled": one
# fixed random order. "auto": shuffled on a patch whose longer side is at most
# SHUFFLE_UP_TO_MM, else sweep. The board's offsets settle after the baseline, and a sweep
# makes time run along x: on a patch so small that every touch lies in every sensor's fit
# window, that settling reads as position. On the 20 mm patch with the robot (calibrate's
# grid, seeds 0-19, the patch given) the shuffle took the median scene RMS from 0.422 to
# 0.234 mm and 2-sigma coverage from 0.712 to 0.899; on the 40 and 50 mm patches it
# helped less, and most with the finger. On Patch A and B (152 mm), where a sweep makes
# each fit window's touches within about a minute of each other, it cost the robot
# 0.023-0.050 mm and Patch A's finger 0.085 mm (Patch B's finger gained 0.025 mm;
# benchmarks/plan_order.py). End to end on the simulated rig, whose touches are further
# apart, the 20 mm patch gained less: median RMS 0.253 -> 0.230 mm over 10 seeds
# (docs/benchmarks.md, "The touch order on small patches").
AUTO, SWEEP, SHUFFLED = "auto", "sweep", "shuffled"
ORDERS = (AUTO, SWEEP, SHUFFLED)
SHUFFLE_UP_TO_MM = 50.0
_SHUFFLE_SEED = 0


def is_small_patch(patch: Patch) -> bool:
    """Whether ``patch``'s longer side is at most ``SHUFFLE_UP_TO_MM``: so small that every
    touch lies in every sensor's fit window. Such a patch is shuffled (``touch_order``) and
    its point logs keep each touch's baseline (``touch_window.reference_for``)."""
    return max(patch.length_mm, patch.width_mm) <= SHUFFLE_UP_TO_MM


def touch_order(patch: Patch, order: str = AUTO) -> str:
    """The order ``order`` means on ``patch``: "sweep" or "shuffled" ("auto" resolved)."""
    if order not in ORDERS:
        raise ValueError(f"touch order must be one of {', '.join(ORDERS)}, got {order!r}")
    if order != AUTO:
        return order
    return SHUFFLED if is_small_patch(patch) else SWEEP


def in_order(points: np.ndarray, order: str) -> np.ndarray:
    """``points`` (serpentine) in the resolved ``order``: as they are for "sweep", in one
    fixed random order for "shuffled" (the same every time, so a resumed plan is the same)."""
    if order == SWEEP:
        return points
    if order != SHUFFLED:
        raise ValueError(f"resolved touch order must be sweep or shuffled, got {order!r}")
    return points[np.random.default_rng(_SHUFFLE_SEED).permutation(len(points))]


def uniform_points(patch: Patch, nx: int = 20, ny: int = 5, margin_mm: float = 3.0) -> np.ndarray:
    """(nx*ny, 2) grid from ``margin_mm`` to the far edges minus it, in serpentine order.

    ``nx`` points along the length (x), ``ny`` across (y). Column i runs up in y when i is
    even and down when odd, so consecutive touches are one grid step apart: the robot's
    travel is the shortest of the simple orders. The single source of the uniform grid:
    ``robot.launch.PlanConfig.points_mm`` returns these points, in the plan's order
    (``in_order``).
    """
    if isinstance(nx, bool) or isinstance(ny, bool) or int(nx) != nx or int(ny) != ny:
        raise ValueError(f"grid must be whole numbers, got {nx!r} x {ny!r}")
    if nx < 1 or ny < 1:
        raise ValueError(f"grid needs at least one row and one column, got {nx} x {ny}")
    _check_box(patch, margin_mm)
    xs = np.linspace(margin_mm, patch.length_mm - margin_mm, int(nx))
    ys = np.linspace(margin_mm, patch.width_mm - margin_mm, int(ny))
    gx = np.repeat(xs, int(ny))
    gy = np.concatenate([ys if i % 2 == 0 else ys[::-1] for i in range(int(nx))])
    return np.column_stack([gx, gy])


@dataclass
class UniformPlanner:
    """The fixed grid as a plan: every point once, in serpentine order or shuffled
    (``order``: "sweep" or "shuffled", as ``touch_order`` resolves it).

    Outcomes are accepted and ignored: a failed touch leaves its hole (the session has
    already retried it) and the grid goes on.
    """

    patch: Patch
    nx: int = 20
    ny: int = 5
    margin_mm: float = 3.0
    order: str = SWEEP

    def points(self) -> np.ndarray:
        return in_order(uniform_points(self.patch, self.nx, self.ny, self.margin_mm), self.order)

    def plan(self) -> PlanGenerator:
        points = self.points()  # validates before the first touch is asked for
        return self._plan(points)

    def _plan(self, points: np.ndarray) -> PlanGenerator:
        for i, (x, y) in enumerate(points):
            touch = PlannedTouch(i, float(x), float(y), UNIFORM)
            _check_outcome((yield touch), touch)


def _check_outcome(outcome: TouchOutcome | None, touch: PlannedTouch) -> None:
    if outcome is None:
        return
    if not isinstance(outcome, TouchOutcome):
        raise TypeError(f"send a TouchOutcome (or None), got {type(outcome).__name__}")
    if outcome.touch.index != touch.index:
        raise ValueError(
            f"outcome of touch {outcome.touch.index} sent while touch {touch.index} was planned"
        )


def _quantize(v: float) -> float:
    """The value as the predictions CSV stores it (4 decimals), so that a session resumed
    from stored predictions makes exactly the same choices as the live one did."""
    return float(f"{v:.4f}")


@dataclass
class AdaptivePlanner:
    """Coarse serpentine pass, then each touch where it shrinks the sensors' errors most.

    After the coarse pass, the next point is chosen on a grid of candidates (``candidate_
    step_mm`` apart, inside the margins) by the expected reduction of the summed per-sensor
    position variance. Each sensor is modelled as the localizer fits it: a Lorentzian bump
    of half width ``probe_width_mm`` over a floor, seen only within a compact window
    around it. The Fisher information of the touches made so far, evaluated at the
    sensor's current estimate, gives the *shape* of its uncertainty (which directions are
    already probed); the localizer's own sigma gives its *size*. A sensor that is not
    located (no ``ok`` estimate yet) sits at its design position, shifted like its
    wire-mates that are located, with sigma ``unlocated_sigma_mm``: it dominates the sum
    until it is located. Only the part of a reduction that brings a sensor towards
    ``target_sigma_mm`` counts, so touches go where they are still needed.

    The plan stops when every sensor is ``ok`` with ``sigma_mm <= target_sigma_mm`` (checked
    from the end of the coarse pass on) or after ``budget`` touches. Every proposed touch
    counts against the budget, failed ones too (they took rig time), so the plan always
    ends. A failed touch's neighbourhood (``exclusion_mm``) is never proposed again: the
    point may be unreachable, and retrying is the session's job, bounded there.
    ``stop_reason`` says why the last plan ended.

    ``first_points`` replaces the coarse pass with touches already chosen (phase "given"):
    refining a finished session (``varskin calibrate --resume --refine``) re-proposes its
    stored touches, in their order, then goes on adaptively from all they measured.

    Feed it the batch estimates (``Localizer.result()``, ~0.1 s for 30 sensors): the live
    ``update()``'s statuses are provisional and flip between touches, which misleads both
    the choice and the stop (benchmarks/adaptive_plan.py, docs/benchmarks.md). Defaults
    (coarse 8 x 3, target 0.6 mm) were chosen on that benchmark's simulated Patch B.
    """

    patch: Patch
    coarse: tuple[int, int] | None = (8, 3)
    budget: int = 100
    target_sigma_mm: float = 0.6
    margin_mm: float = 3.0
    probe_width_mm: float = 6.5
    candidate_step_mm: float = 1.0
    unlocated_sigma_mm: float = 5.0
    relative_noise: float = 0.1  # per-touch noise over the peak height (sets the priors' weight)
    window_widths: float = 2.5  # the localizer's fit window, in footprint half widths
    exclusion_mm: float = 1.0
    first_points: np.ndarray | None = None  # (K, 2) mm: touches made instead of the coarse pass
    stop_reason: str | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        _check_box(self.patch, self.margin_mm)
        if self.coarse is not None:
            nx, ny = self.coarse
            uniform_points(self.patch, nx, ny, self.margin_mm)  # validates the grid
        if self.first_points is not None:
            if self.coarse is not None:
                raise ValueError("give either coarse or first_points, not both")
            pts = np.asarray(self.first_points, dtype=float)
            if pts.ndim != 2 or pts.shape[1] != 2 or not np.isfinite(pts).all():
                raise ValueError(f"first_points must be finite (K, 2) mm, got shape {pts.shape}")
            self.first_points = pts
        if isinstance(self.budget, bool) or int(self.budget) != self.budget or self.budget < 1:
            raise ValueError(f"budget must be a whole number >= 1, got {self.budget!r}")
        for name in (
            "target_sigma_mm",
            "probe_width_mm",
            "candidate_step_mm",
            "unlocated_sigma_mm",
            "relative_noise",
            "window_widths",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if not (math.isfinite(self.exclusion_mm) and self.exclusion_mm >= 0):
            raise ValueError(f"exclusion_mm must be >= 0, got {self.exclusion_mm!r}")
        self._names = tuple(self.patch.names)
        self._design = self.patch.design_xy
        self._tx = np.array([s.tx for s in self.patch.sensors])
        self._rx = np.array([s.rx for s in self.patch.sensors])
        m = self.margin_mm
        nx = int(math.floor((self.patch.length_mm - 2 * m) / self.candidate_step_mm)) + 1
        ny = int(math.floor((self.patch.width_mm - 2 * m) / self.candidate_step_mm)) + 1
        # linspace, not arange: the last candidate is exactly on the far margin, never past it.
        xs = np.linspace(m, self.patch.length_mm - m, max(nx, 2))
        ys = np.linspace(m, self.patch.width_mm - m, max(ny, 2))
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        self._candidates = np.column_stack([gx.ravel(), gy.ravel()])

    @property
    def candidates(self) -> np.ndarray:
        """(M, 2) the points the adaptive phase chooses from."""
        return self._candidates.copy()

    def plan(self) -> PlanGenerator:
        self.stop_reason = None
        return self._plan()

    # --- the generator -----------------------------------------------------------------

    def _plan(self) -> PlanGenerator:
        done: list[tuple[float, float]] = []  # touches that gave a point log
        failed: list[tuple[float, float]] = []
        latest: Predictions | None = None
        index = 0
        if self.first_points is not None:
            first, phase = self.first_points, GIVEN
        elif self.coarse is not None:
            first, phase = uniform_points(self.patch, *self.coarse, self.margin_mm), COARSE
        else:
            first, phase = np.zeros((0, 2)), COARSE
        for x, y in first[: self.budget]:
            touch = PlannedTouch(index, float(x), float(y), phase)
            outcome = yield touch
            latest = self._record(outcome, touch, done, failed, latest)
            index += 1
        while True:
            if latest is not None and self._on_target(latest):
                self.stop_reason = TARGET
                return
            if index >= self.budget:
                self.stop_reason = BUDGET
                return
            xy = self.choose(np.array(done).reshape(-1, 2), latest, np.array(failed).reshape(-1, 2))
            if xy is None:
                self.stop_reason = EXHAUSTED
                return
            touch = PlannedTouch(index, float(xy[0]), float(xy[1]), ADAPTIVE)
            outcome = yield touch
            latest = self._record(outcome, touch, done, failed, latest)
            index += 1

    @staticmethod
    def _record(
        outcome: TouchOutcome | None,
        touch: PlannedTouch,
        done: list[tuple[float, float]],
        failed: list[tuple[float, float]],
        latest: Predictions | None,
    ) -> Predictions | None:
        """Book one touch's outcome; returns the newest predictions."""
        _check_outcome(outcome, touch)
        if outcome is not None and not outcome.ok:
            failed.append((touch.x_mm, touch.y_mm))
            return latest
        # No outcome at all (plain next()): the touch is assumed made, with no new estimate.
        done.append((touch.x_mm, touch.y_mm))
        if outcome is not None and outcome.predictions is not None:
            return outcome.predictions
        return latest

    def _on_target(self, pred: Predictions) -> bool:
        by = pred.by_name()
        for name in self._names:
            e = by.get(name)
            if e is None or e.status != OK or e.sigma_mm is None:
                return False
            if _quantize(e.sigma_mm) > self.target_sigma_mm:
                return False
        return True

    # --- the choice --------------------------------------------------------------------

    def sensor_state(self, pred: Predictions | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each sensor's assumed position (N, 2), sigma_mm (N,) and located? (N,) bool."""
        n = len(self._names)
        xy = self._design.copy()
        sigma = np.full(n, float(self.unlocated_sigma_mm))
        located = np.zeros(n, bool)
        by = pred.by_name() if pred is not None else {}
        for i, name in enumerate(self._names):
            e = by.get(name)
            if e is not None and e.status == OK and e.x_mm is not None and e.y_mm is not None:
                xy[i] = (_quantize(e.x_mm), _quantize(e.y_mm))
                # A located sensor without an error bar is treated as not yet good enough.
                s = _quantize(e.sigma_mm) if e.sigma_mm is not None else self.unlocated_sigma_mm
                sigma[i] = min(max(s, 1e-3), self.unlocated_sigma_mm)
                located[i] = True
        if located.any() and not located.all():
            # The design is off by the registration and by each wire's displacement: an
            # unlocated sensor is shifted as its located wire-mates are (x along its TX
            # wire, y along its RX wire), else as the located sensors are on median.
            off = xy[located] - self._design[located]
            glob = np.median(off, axis=0)
            for i in np.flatnonzero(~located):
                tx_mates = located & (self._tx == self._tx[i])
                rx_mates = located & (self._rx == self._rx[i])
                dx = (
                    np.median(xy[tx_mates, 0] - self._design[tx_mates, 0])
                    if tx_mates.any()
                    else glob[0]
                )
                dy = (
                    np.median(xy[rx_mates, 1] - self._design[rx_mates, 1])
                    if rx_mates.any()
                    else glob[1]
                )
                xy[i] = self._design[i] + (dx, dy)
        return xy, sigma, located

    def scores(
        self, done: np.ndarray, pred: Predictions | None, candidates: np.ndarray | None = None
    ) -> np.ndarray:
        """(M,) each candidate's expected reduction of the summed per-axis position variance
        (mm^2), counting for each sensor only what it still lacks to reach the target."""
        cand = self._candidates if candidates is None else np.asarray(candidates, float)
        done = np.asarray(done, float).reshape(-1, 2)
        mu, sigma, _ = self.sensor_state(pred)
        w = self.probe_width_mm
        # The localizer's window: a few footprints, but never under two probe spacings.
        radius = max(self.window_widths * w, 2.0 * touch_spacing_mm(done))
        noise2 = self.relative_noise**2
        # Weak priors in the sensor's normalized units (height 1): position, log width (the
        # probe's footprint is known to ~25%), height and floor.
        prior = np.diag([self.unlocated_sigma_mm**-2] * 2 + [0.25**-2, 0.5**-2, 1.0])
        H = np.broadcast_to(prior, (len(mu), _N, _N)).copy()
        if len(done):
            J, win = _jacobian(done, mu, w, radius)  # (N, K, 5), (N, K)
            H += np.swapaxes(J * (win / noise2)[..., None], 1, 2) @ J
        C = np.linalg.inv(H)
        # Shape from the model, size from the localizer: scale each sensor's covariance
        # (equivalently its noise and prior) so the model's per-axis variance is the
        # localizer's. Directions already probed stay small, whatever sigma says.
        var_model = 0.5 * (C[:, 0, 0] + C[:, 1, 1])
        var_loc = (sigma / R95_PER_AXIS_SD) ** 2
        lam = var_loc / np.maximum(var_model, 1e-300)
        C *= lam[:, None, None]
        noise = noise2 * lam
        target = (self.target_sigma_mm / R95_PER_AXIS_SD) ** 2
        room = np.maximum(var_loc - target, 0.0)  # what each sensor still lacks, per axis
        # One more touch at each candidate: a rank-one update of every sensor's information.
        # A sensor sees only the candidates within its window (1.5 radius), a band of x:
        # with the candidates sorted by x, each sensor takes one run of them (all runs as
        # long as the longest, so the work stays one batch), a third of the full product.
        order = np.argsort(cand[:, 0], kind="stable")
        xs = cand[order, 0]
        reach = 1.5 * radius
        lo = np.searchsorted(xs, mu[:, 0] - reach, side="left")
        hi = np.searchsorted(xs, mu[:, 0] + reach, side="right")
        band = max(int((hi - lo).max()), 1)
        start = np.clip(lo, 0, max(len(xs) - band, 0))
        rows = order[np.minimum(start[:, None] + np.arange(band)[None, :], len(xs) - 1)]
        J, win = _jacobian(cand[rows], mu, w, radius)  # (N, B, 5), (N, B)
        if band > len(xs):  # fewer candidates than one band: the repeats must not count
            win[:, len(xs) :] = 0.0
        CJ = J @ C  # C is symmetric
        quad = (J * CJ).sum(axis=2)
        gain = CJ[..., 0] ** 2 + CJ[..., 1] ** 2
        reduction = 0.5 * win * gain / (noise[:, None] + win * quad)
        part = np.minimum(reduction, room[:, None])
        return np.bincount(rows.ravel(), weights=part.ravel(), minlength=len(cand))

    def choose(
        self, done: np.ndarray, pred: Predictions | None, failed: np.ndarray | None = None
    ) -> np.ndarray | None:
        """The next point: the best-scoring allowed candidate (first on ties), or None when
        every candidate lies within ``exclusion_mm`` of a failed touch."""
        allowed = np.ones(len(self._candidates), bool)
        if failed is not None and len(failed):
            failed = np.asarray(failed, float).reshape(-1, 2)
            d = np.hypot(
                self._candidates[:, None, 0] - failed[None, :, 0],
                self._candidates[:, None, 1] - failed[None, :, 1],
            )
            allowed &= (d > self.exclusion_mm).all(axis=1)
        if not allowed.any():
            return None
        s = np.where(allowed, self.scores(done, pred), -np.inf)
        return self._candidates[int(np.argmax(s))].copy()


def _jacobian(P: np.ndarray, mu: np.ndarray, w: float, radius: float):
    """Sensitivity of a unit Lorentzian bump at each sensor ``mu`` (N, 2) to its position,
    log width, height and floor, for touches ``P`` ((M, 2) shared or (N, M, 2) per sensor):
    (N, M, 5); and the fit window's weight (N, M): 1 within ``radius``, a cosine taper to 0
    at 1.5 radius (the localizer's).
    """
    P = np.broadcast_to(P, (len(mu),) + P.shape[-2:])
    dx = P[..., 0] - mu[:, None, 0]
    dy = P[..., 1] - mu[:, None, 1]
    r2 = (dx * dx + dy * dy) / (w * w)
    g = 1.0 / (1.0 + r2)
    g2 = g * g
    J = np.empty(dx.shape + (_N,))
    J[..., 0] = (2.0 / (w * w)) * g2 * dx
    J[..., 1] = (2.0 / (w * w)) * g2 * dy
    J[..., 2] = 2.0 * g2 * r2
    J[..., 3] = g
    J[..., 4] = 1.0
    u = (np.sqrt(r2) * (w / radius) - 1.0) * 2.0
    win = (u <= 0.0).astype(float)
    taper = (u > 0.0) & (u < 1.0)  # cosines only where they are needed: they cost
    win[taper] = 0.5 * (1.0 + np.cos(np.pi * u[taper]))
    return J, win

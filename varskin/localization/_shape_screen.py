"""Which response shape a patch's maps favour: the Lorentzian, or another of the model's.

Why a module of its own: a wrong bump profile biases every fit the same way, and one
sensor's map cannot tell the shapes apart from noise, while every sensor of a patch answers
the same probe. So the batch solve (``response_shape`` "auto") screens the shapes once over
all sensors, by a paired test, and re-solves at the winner (docs/localizer.md, "Robustness
to a wrong response model").
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from varskin.localization import _peak_model as pm

if TYPE_CHECKING:
    from varskin.localization.peakfit import Localizer

# The response shape (``response_shape`` "auto"): another of pm.SHAPES replaces the
# Lorentzian only if the paired test over sensors favours it beyond SHAPE_Z standard errors,
# with at least SHAPE_MIN_SENSORS sensors to test on (favoured_shape).
SHAPE_Z = 3.0
SHAPE_MIN_SENSORS = 8
# Each shape's short solve takes SHAPE_SCREEN_ROUNDS rounds of the touches' nuisances and the
# sensors, or SETTLED_SCREEN_ROUNDS after a finger's settling rounds (peakfit.SETTLE_ROUNDS).
# With two, a finger's offsets, settled for the current shape, had not moved far enough for
# another: exponential Patch A finger scenes without a patch kept the Lorentzian on 2 of
# seeds 300-305 (z -2.5 and -2.2; RMS 0.78-0.79 mm, against 0.32 and 0.37 mm at the
# exponential). With four every one of those scenes, and of the same seeds on Patch B and
# with the Gaussian, chose its own shape, and no Lorentzian scene left it. A robot's
# offsets are a tenth as large: four rounds there cost its batch solve 16 % more time (Patch
# B, localizer_scale.py) for one more exponential robot scene of 20 in each stress table
# (docs/benchmarks.md, "The shape screen before the joint rounds").
SHAPE_SCREEN_ROUNDS = 2
SETTLED_SCREEN_ROUNDS = 4
# A larger patch screens on the SHAPE_SCREEN_SENSORS sensors nearest its middle, the touches
# their windows hold, and no others: the screen's cost then stays that of a 64-sensor patch
# (the full board's batch solve took 2.1-2.3 s with every sensor screened, against its 2 s
# budget), while its paired test keeps twice the sensors of Patch B.
SHAPE_SCREEN_SENSORS = 64


def favoured_shape(loc: Localizer) -> tuple[str, float | None]:
    """The response shape the maps favour, and its paired z (None: not tested).

    Every shape gets a short solve from this solve's state: the sensors fitted
    again, warm-started, then SHAPE_SCREEN_ROUNDS (settled: SETTLED_SCREEN_ROUNDS) rounds
    of the touches' nuisances and the sensors (those absorb part of a shape's misfit, so
    the shape must have its own).
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
    f = loc.fit
    cols = np.flatnonzero(f.has_model() & f.converged)
    current = loc.settings.shape
    if cols.size < SHAPE_MIN_SENSORS:
        return current, None
    kept = loc._touch_and_fit_state()
    rounds = SETTLED_SCREEN_ROUNDS if loc._settled else SHAPE_SCREEN_ROUNDS
    block = screened(loc, cols)
    sub = block.size < cols.size
    hidden = np.setdiff1d(np.arange(len(loc.sensors)), block) if sub else block[:0]
    polished = block if sub else None
    scales = {}
    for shape in pm.SHAPES:
        # Sensors outside the screen's block have no model while it runs: the touches'
        # nuisances and the shared footprint come from the block alone.
        f.fitted[hidden] = False
        # The touches' gains and offsets and the shared footprint absorb part of a
        # wrong shape's misfit: each shape gets its own, as a short solve would.
        loc.settings = replace(loc.settings, shape=shape)
        loc._refit_warm(block)
        loc._polish(rounds, cols=polished)
        scales[shape] = np.log(np.maximum(f.scale[block], 1e-300))
        loc._set_touch_and_fit_state(kept)
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
    loc.settings = replace(loc.settings, shape=current)
    return best, best_z


def screened(loc: Localizer, cols: np.ndarray) -> np.ndarray:
    """The sensors of ``cols`` the shape screen fits: all of them, or on a larger patch
    the SHAPE_SCREEN_SENSORS nearest the middle of their fitted positions (a block, so
    the touches inside it keep every sensor that sees them)."""
    if cols.size <= SHAPE_SCREEN_SENSORS:
        return cols
    xy = loc.fit.theta[cols][:, [pm.SX, pm.SY]]
    d = np.hypot(*(xy - np.median(xy, axis=0)).T)
    return np.sort(cols[np.argsort(d, kind="stable")[:SHAPE_SCREEN_SENSORS]])

"""The board's offset settling as the sensors far from each touch saw it, and how much of it
each sensor's own fit did not follow.

Why a module of its own: after the no-contact baseline the offsets settle (real recordings
drift by up to +-120 counts between the baseline and the touches), and the simulator has
them settle within about a minute. A sensor probed only during that minute cannot tell its
floor's rise from its own peak: with a finger's footprint every touch then lies on its bump,
so its fitted floor rises only as far as the floor priors allow and the rest moves the peak.
A weak sensor (peak ~90 counts) at Patch B's first TX wire ended 2.4 and 3.7 mm off at a
sigma of 0.5-0.6 mm that way (docs/benchmarks.md, "Settling the fit did not follow"). The
sensors far from those touches see their own floors settle at the same times. Assuming the
settling keeps one time course across the board (each sensor its own size and sign), their
far touches give that course, and each sensor's far touches late in the session give its
size. On a patch only a few footprints long some touches have no far sensor; there the
flanks tell, with the fitted bumps taken off (FLANK_WIDTHS). A sensor whose floor moved
during its own touches by far more than its fit followed is `drifting`, with the reason,
and a re-probe near it once the offsets are steady places it; one that left less
unfollowed is fitted again with the settling taken out of its readings
(_drifting.take_out_settling).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from varskin.localization._maps import span_by_sensor

# A touch is "far" from a sensor beyond this many fitted half widths (bump <= 6% of peak).
FAR_WIDTHS = 4.0
# Where no sensor is far from some touch (a patch not much longer than a few footprints),
# the sensors beyond this many half widths tell there instead, with their fitted bump
# (<= 20% of peak for a Lorentzian) taken off their readings, and they give the levels the
# far touches could not. On a 40 x 20 mm patch of 8 x 4 sensors at 4.5 mm, robot
# 20 x 5 grid, no sensor was far from any of the first 40 touches, the settling went
# unseen there, and 2 sigma covered 0.63-0.67 of the `ok` sensors (0.93-0.94 read from
# the flanks; docs/benchmarks.md, "A small dense patch: the settling from the flanks").
FLANK_WIDTHS = 2.0
# A sensor's settled level is the median of its far touches in the session's second half;
# it needs this many of them.
MIN_LATE_TOUCHES = 5
# Only sensors whose settled level stands this many per-touch noise sds clear of rest say
# when the board settled; the others' ratios are noise.
MIN_LEVEL_SDS = 5.0


def board_settling(
    V: np.ndarray,
    P: np.ndarray,
    tau: np.ndarray,
    xy: np.ndarray,
    w: np.ndarray,
    usable: np.ndarray,
    noise: np.ndarray,
    bump: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The settling's time course and each sensor's settled level.

    ``V`` (K, N) values relative to rest (peak up, NaN where invalid), ``P`` (K, 2) where the
    touches landed, ``tau`` (K,) session time, ``xy`` (N, 2) and ``w`` (N,) the fitted peaks
    and half widths, ``usable`` (N,) which fits to trust, ``noise`` (N,) per-touch noise sd.
    Returns ``course`` (K,): the fraction of its settled level a sensor's floor had reached
    at each touch (0 at rest, NaN where no sensor tells), and ``level`` (N,): each
    sensor's settled floor (NaN where unknown), both in the values' units.

    ``bump(rows)`` gives the fitted models' bumps at touches ``rows`` ((len(rows), N), the
    values' units, NaN where no model). With it, a session with touches that no sensor is
    far from is read from the flanks too (FLANK_WIDTHS), where the far touches told
    nothing: the course at those touches, and the levels of the sensors with too few late
    far touches. Elsewhere the result is the far touches' alone.
    """
    K, N = V.shape
    course, level = np.full(K, np.nan), np.full(N, np.nan)
    if K < 2 * MIN_LATE_TOUCHES or not usable.any():
        return course, level
    d = np.hypot(P[:, 0:1] - xy[None, :, 0], P[:, 1:2] - xy[None, :, 1])
    late = tau >= np.median(tau)
    far = (d > FAR_WIDTHS * w[None, :]) & np.isfinite(V) & usable[None, :]
    _levels(level, V, far & late[:, None])
    _course(course, V, far, level, noise)
    if bump is None or not np.isnan(course).any():
        return course, level
    # The flanks, only where the far touches told nothing: the course at the touches no
    # sensor is far from, and the levels of the sensors without enough late far touches.
    unknown = np.isnan(level) & usable
    flank = (d > FLANK_WIDTHS * w[None, :]) & np.isfinite(V) & usable[None, :]
    need = np.isnan(course) | (late & unknown.any())
    rows = np.flatnonzero(flank.any(axis=1) & need)
    if rows.size == 0:
        return course, level
    Vf = np.full_like(V, np.nan)
    Vf[rows] = V[rows] - bump(rows)
    flank &= np.isfinite(Vf)
    _levels(level, Vf, flank & late[:, None], unknown)
    _course(course, Vf, flank, level, noise, np.isnan(course))
    return course, level


def _levels(level, V, late, which=None) -> None:
    """Each sensor's settled level (the median of its ``late`` readings), in place, for the
    sensors ``which`` (default all) that have MIN_LATE_TOUCHES of them."""
    enough = late.sum(axis=0) >= MIN_LATE_TOUCHES
    if which is not None:
        enough &= which
    if enough.any():
        with np.errstate(all="ignore"):
            level[enough] = np.nanmedian(np.where(late, V, np.nan)[:, enough], axis=0)


def _course(course, V, far, level, noise, which=None) -> None:
    """The settling's course at each touch ``which`` (default all), in place: the median
    fraction of their levels the readings of the sensors ``far`` from it had reached, over
    the sensors whose level stands clear of their noise."""
    tells = np.isfinite(level) & (
        np.abs(level) > MIN_LEVEL_SDS * np.where(np.isfinite(noise), noise, np.inf)
    )
    if not tells.any():
        return
    with np.errstate(all="ignore"):
        ratio = np.where(far[:, tells], V[:, tells] / level[tells][None, :], np.nan)
    has = np.isfinite(ratio).any(axis=1)
    if which is not None:
        has &= which
    if has.any():
        with np.errstate(all="ignore"):
            course[has] = np.nanmedian(ratio[has], axis=1)


def unfollowed(
    course: np.ndarray,
    level: np.ndarray,
    fitted_floor: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    peak: np.ndarray,
) -> np.ndarray:
    """(N,) how far each sensor's floor moved during its own touches beyond what its fitted
    floor followed, in its fitted ``peak`` heights; 0 where the settling is unknown.

    The touches are the (touch ``rows``, sensor ``cols``) pairs of the sensors' fit windows,
    sensor by sensor; ``fitted_floor`` is the fitted floor at each pair, in the values'
    units.
    """
    keep = rows < len(course)
    gap = level[cols[keep]] * course[rows[keep]] - fitted_floor[keep]
    use = np.isfinite(gap)
    span = span_by_sensor(gap[use], cols[keep][use], len(peak))
    with np.errstate(all="ignore"):
        out = np.where(peak > 0, span / np.where(peak > 0, peak, 1.0), 0.0)
    return np.where(np.isfinite(out), out, 0.0)

"""A map with a second peak far from its fit: which of the two is the sensor.

Why a module of its own: the model assumes one bump per map, and an offset that settles by
more than the peak early in a session leaves a false top at the first touches, which a fit
may take with confidence. After the batch solve each map's highest reading outside its fit's
window gets a fit of its own, and the peak more touches agree with wins (docs/localizer.md,
"A map with a second peak").
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from varskin.localization import _peak_model as pm
from varskin.localization._statuses import DRIFTING, IRREGULAR, UNCERTAIN, window_members
from varskin.predictions import OK

if TYPE_CHECKING:
    from varskin.localization.peakfit import Localizer

# A second peak of a map (second_peaks): its detrended height relative to the fitted
# peak's, the radius (probe spacings) of its backing touch and of the start search around
# it, and by how much one peak's effective touch count must beat the other's to win.
SECOND_PEAK_FRACTION = 0.6
SEED_RADIUS_SPACINGS = 1.5
SECOND_PEAK_RATIO = 1.5


def second_peaks(loc: Localizer) -> None:
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
    f = loc.fit
    K = loc._k
    n = len(loc.sensors)
    cols = np.flatnonzero(f.fitted & np.isfinite(f.theta).all(axis=1))
    if cols.size == 0:
        return
    h = loc.spacing()
    P = loc._P[:K] + loc._dxy[:K]
    _, D, valid, _, _ = loc._maps(cols, loc._clipped(cols))
    # At the shared footprint: a fit whose own width collapsed must not take its
    # bump's other flank for a second peak.
    lw = f.theta[:, [pm.LW, pm.LWY]] if loc.shared_lw is None else loc.shared_lw[None, :]
    w = np.broadcast_to(np.exp(0.5 * lw.sum(axis=1)), (n,))
    inside = window_members(loc, f.theta[:, :2], w, h)[:, cols]
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
    before = loc._statuses()[cols]
    insane = (before == IRREGULAR) & ~loc._two_peaks[cols]
    cand &= (before == OK) | (before == UNCERTAIN) | insane
    if not cand.any():
        return
    c = cols[cand]
    loc._seed_k[c] = k2[cand]
    kept = loc._refit(c, short=True)
    after = loc._statuses()[c]
    radius = np.maximum(loc.settings.window_widths * w[c], loc.settings.window_spacings * h)
    # A fit from the second peak that came back to the first is no second opinion.
    apart = np.hypot(*(f.theta[c, :2] - kept["theta"][:, :2]).T) > radius
    rival = apart & ((after == OK) | (after == DRIFTING))
    n_old, n_new = kept["n_eff"], f.n_eff[c]
    new_wins = rival & (n_new >= SECOND_PEAK_RATIO * n_old)
    tie = rival & ~new_wins & (n_old < SECOND_PEAK_RATIO * n_new)
    restore = ~new_wins
    loc._restore(c, kept, restore)
    loc._seed_k[c[restore]] = -1
    loc._two_peaks[c[tie & (after == OK) & (before[cand] == OK)]] = True

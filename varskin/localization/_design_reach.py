"""Sensors no touch has come near yet, by where the patch's design puts them.

Why a module of its own: mid-session, a sensor on a part of the patch not yet probed has
only its wire's ridge (~4 % of a peak) and its bump's far tail in its map, and a bump
beside the probed columns fits those as well as a peak does. Neither the live view's
seen-peak rule (a touch saw half of the bump fitted there) nor the rise check
(_statuses.unrisen_weak: its map rose with the ridge) can tell. With the patch given, the
design says where the sensor is to within millimetres, so the verdict the user gets
(``result()`` and every ``update()``) calls such an `ok` fit `sparse` until a touch has
come near its design position. Like the rise check, the solve's own uses of the verdict
(the error-bar check, the re-fits, the wires the layout prior pools) do not see it: no
fit, position or sigma changes, only which `ok` calls are reported `sparse`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from varskin.localization._statuses import SPARSE
from varskin.predictions import OK

if TYPE_CHECKING:
    from varskin.localization.peakfit import Localizer

# An `ok` fit is reported `sparse` while no touch has come within this many half widths
# (``Localizer._footprint_width``) of the sensor's design position: the touches then saw at most a tenth
# of its peak (the Lorentzian at 3 half widths), about what its wire's ridge and tail give.
# That is 18-45 mm on Patch B (footprints of 6-15 mm), far more than a 2 % stretch, a 0.5
# degree turn or wires 1.5 mm off their design move a sensor. On the live sessions and
# partial solves measured, every `ok` call within 5 mm of the truth had a touch within 1.3
# half widths of its design position, and none was held back (docs/benchmarks.md, "The
# patch's design in the reported verdict").
DESIGN_REACH_WIDTHS = 3.0


def design_gap(loc: Localizer, rows: np.ndarray | None = None) -> np.ndarray:
    """(N,) mm from where the patch's design puts each sensor to the nearest touch that
    made contact, among ``rows`` (default all); along the one known axis where the design
    gives only a sensor's TX or RX wire; 0 where it gives neither, or with no patch."""
    n = len(loc.sensors)
    if loc.design is None:
        return np.zeros(n)
    rows = np.flatnonzero(~loc._missed[: loc.n_logs]) if rows is None else rows
    if rows.size == 0:
        return np.full(n, np.inf)
    # The commanded positions: the design is known to millimetres, not to a touch's offset.
    P = loc._P[rows]
    d2 = np.zeros((rows.size, n))
    for axis, at in enumerate(loc.design):
        d = P[:, axis : axis + 1] - at[None, :]
        d2 += np.where(np.isfinite(d), d * d, 0.0)
    return np.sqrt(d2.min(axis=0))


def unreached_sparse(loc: Localizer, status: np.ndarray) -> np.ndarray:
    """``status`` with every `ok` sensor no touch has come within DESIGN_REACH_WIDTHS half
    widths of its design position `sparse` (with the patch given; else unchanged).

    The distances are kept in ``loc._design_gap`` (None: computed afresh here); a live
    update lowers them with its touch (``touch_added``)."""
    if loc.design is None:
        return status
    if loc._design_gap is None:
        loc._design_gap = design_gap(loc)
    # The probe's footprint where the solve has one, not each fit's own width: a fit to a
    # ridge and a tail can come out wide, which would stretch the reach just where it must
    # not; the sensors' true widths scatter about the footprint by about a tenth.
    w = loc._footprint_width(loc.fit.theta)
    far = loc._design_gap > DESIGN_REACH_WIDTHS * w
    return np.where((status == OK) & far, SPARSE, status)


def touch_added(loc: Localizer, k: int) -> None:
    """A live update's touch ``k``: the kept distances, if any, may now be shorter."""
    if loc._design_gap is not None and not loc._missed[k]:
        np.minimum(loc._design_gap, design_gap(loc, np.array([k])), out=loc._design_gap)

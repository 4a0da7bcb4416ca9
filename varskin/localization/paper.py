"""The published VARSkin localization method, reproduced as the paper describes it.

It is the reference every other localizer is measured against, so it does exactly what the
paper says and nothing more, sensor by sensor:

1. *point log map*: the sensor's mean response at each distinct probe location minus its
   rest value S0 (touches at the same location are averaged);
2. *interpolation*: a piecewise cubic interpolant (Clough-Tocher, via
   ``scipy.interpolate.griddata(method="cubic")``) evaluated on a pixel grid of pitch
   10/ppcm mm over the area; outside the probes' convex hull there is no data (NaN), not
   zeros;
3. *filtering*: keep the pixels whose value exceeds eta times the map's maximum; the
   prediction is the unweighted mean of their coordinates.

SNR follows the paper's equation, SNR_i = 20 log10((max_k mean S_ik - S_i0) / sigma_i0),
which needs the no-contact baseline (the authors' released code computes something else).
The method gives no uncertainty, so ``sigma_mm`` stays empty. Where it cannot answer, the
status says why: ``flat`` (no touch raised the sensor above rest, so there is no hill to
threshold) or ``nodata`` (fewer than 3 valid probes, or no pixel of the area inside their
hull).
"""

from __future__ import annotations

import math
from numbers import Real

import numpy as np
from scipy.interpolate import griddata
from scipy.spatial import Delaunay, QhullError

from varskin.errors import InputError
from varskin.pointlogs import PointLogs
from varskin.predictions import OK, Predictions, SensorEstimate

NAME = "paper"
DEFAULT_ETA = 0.65
DEFAULT_PPCM = 128.0
MAX_PIXELS = 50_000_000  # one float64 map of this size is 400 MB: refuse rather than swap


def localize(
    logs: PointLogs,
    eta: float = DEFAULT_ETA,
    ppcm: float = DEFAULT_PPCM,
    area=None,
    **unknown,
) -> Predictions:
    """Localize every sensor of ``logs`` with the paper's three steps (see module doc)."""
    if unknown:
        raise InputError(
            f"method {NAME!r} takes eta, ppcm and area; unknown parameter(s): {', '.join(sorted(unknown))}"
        )
    eta = _check_eta(eta)
    ppcm = _check_ppcm(ppcm)
    locations, maps = point_log_map(logs)
    _check_locations(locations)
    area = _check_area(area) if area is not None else bounding_box(locations)
    gx, gy = pixel_grid(area, ppcm)

    estimates = []
    for j, sensor in enumerate(logs.sensors):
        snr = snr_db(logs, j)
        column = maps[:, j]
        finite = np.isfinite(column)
        if finite.sum() < 3:
            estimates.append(SensorEstimate(sensor, None, None, None, snr, "nodata"))
            continue
        if column[finite].max() <= 0:
            # No touch raised this sensor above rest: any peak would be interpolation overshoot.
            estimates.append(SensorEstimate(sensor, None, None, None, snr, "flat"))
            continue
        try:
            image = interpolate(locations[finite], column[finite], gx, gy)
        except QhullError:
            estimates.append(SensorEstimate(sensor, None, None, None, snr, "nodata"))
            continue
        x, y, status = threshold_mean(image, gx, gy, eta)
        estimates.append(SensorEstimate(sensor, x, y, None, snr, status))
    params = {"eta": eta, "ppcm": ppcm, "area": [float(v) for v in area]}
    return Predictions(NAME, estimates, params)


# --- the three steps, public so plots can show them ---------------------------------------


def point_log_map(logs: PointLogs) -> tuple[np.ndarray, np.ndarray]:
    """Distinct probe locations (L, 2) and every sensor's mean response there (L, N).

    ``logs.values`` are already relative to rest (S0 subtracted) when a baseline was known.
    Non-finite values are left out of a location's mean; a location with none stays NaN.
    A log without a finite position is left out (as peakfit does): it says nothing of where.
    """
    xy = np.asarray(logs.xy_mm, float)
    values = np.asarray(logs.values, float)
    placed = np.isfinite(xy).all(axis=1)
    xy, values = xy[placed], values[placed]
    if len(xy) == 0:
        return np.zeros((0, 2)), np.zeros((0, logs.n_sensors))
    locations, inverse = np.unique(xy, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    finite = np.isfinite(values)
    sums = np.zeros((len(locations), values.shape[1]))
    counts = np.zeros_like(sums)
    np.add.at(sums, inverse, np.where(finite, values, 0.0))
    np.add.at(counts, inverse, finite)
    with np.errstate(invalid="ignore", divide="ignore"):
        maps = sums / counts
    return locations, maps


def bounding_box(locations: np.ndarray) -> tuple[float, float, float, float]:
    lo = locations.min(axis=0)
    hi = locations.max(axis=0)
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def pixel_grid(area, ppcm: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (mm) along x and y: from the area's corner, every 10/ppcm mm."""
    x0, y0, x1, y1 = area
    pitch = 10.0 / ppcm
    # The tolerance keeps the far edge when the span is a whole number of pixels.
    nx = int(math.floor((x1 - x0) / pitch + 1e-9)) + 1
    ny = int(math.floor((y1 - y0) / pitch + 1e-9)) + 1
    if nx * ny > MAX_PIXELS:
        raise InputError(
            f"a {nx} x {ny} pixel grid is too large; lower ppcm ({ppcm:g}) or shrink the area"
        )
    return x0 + pitch * np.arange(nx), y0 + pitch * np.arange(ny)


def interpolate(locations: np.ndarray, values: np.ndarray, gx: np.ndarray, gy: np.ndarray):
    """Piecewise cubic (Clough-Tocher) map on the pixel grid, shape (ny, nx); NaN outside the hull."""
    mx, my = np.meshgrid(gx, gy)
    return griddata(locations, values, (mx, my), method="cubic")


def threshold_mean(image: np.ndarray, gx: np.ndarray, gy: np.ndarray, eta: float):
    """Mean coordinates of the pixels above eta * max: (x, y, status)."""
    if not np.isfinite(image).any():
        return None, None, "nodata"
    peak = float(np.nanmax(image))
    if peak <= 0:
        return None, None, "flat"
    with np.errstate(invalid="ignore"):
        iy, ix = np.nonzero(image > eta * peak)
    return float(gx[ix].mean()), float(gy[iy].mean()), OK


def snr_db(logs: PointLogs, j: int) -> float | None:
    """The paper's SNR of sensor j, or None without a baseline or a positive signal."""
    if logs.rest is None or logs.rest_sd is None:
        return None
    column = np.asarray(logs.values, float)[:, j]
    column = column[np.isfinite(column)]
    sigma0 = float(logs.rest_sd[j])
    if column.size == 0 or not math.isfinite(sigma0) or sigma0 <= 0:
        return None
    signal = float(column.max())  # values are mean S_ik minus S_i0 already
    if signal <= 0:
        return None
    return 20.0 * math.log10(signal / sigma0)


# --- parameter checks -------------------------------------------------------------------


def _number(name: str, v) -> float:
    if isinstance(v, bool) or not isinstance(v, Real) or not math.isfinite(float(v)):
        raise InputError(f"{name} must be a finite number, got {v!r}")
    return float(v)


def _check_eta(eta) -> float:
    eta = _number("eta", eta)
    if not 0.0 < eta < 1.0:
        raise InputError(f"eta must be between 0 and 1 (exclusive), got {eta:g}")
    return eta


def _check_ppcm(ppcm) -> float:
    ppcm = _number("ppcm", ppcm)
    if ppcm <= 0:
        raise InputError(f"ppcm (pixels per cm) must be > 0, got {ppcm:g}")
    return ppcm


def _check_area(area) -> tuple[float, float, float, float]:
    if isinstance(area, str):
        area = area.split(",")
    try:
        parts = list(area)
    except TypeError:
        raise InputError(f"area must be x0,y0,x1,y1 in mm, got {area!r}") from None
    if len(parts) != 4:
        raise InputError(f"area must be 4 numbers x0,y0,x1,y1 in mm, got {len(parts)}")
    vals = []
    for p in parts:
        try:
            v = float(p)
        except (TypeError, ValueError):
            raise InputError(f"area must be x0,y0,x1,y1 in mm, got {p!r}") from None
        if not math.isfinite(v):
            raise InputError(f"area must be finite, got {p!r}")
        vals.append(v)
    x0, y0, x1, y1 = vals
    if x1 <= x0 or y1 <= y0:
        raise InputError(
            f"area x0,y0,x1,y1 needs x1 > x0 and y1 > y0, got {x0:g},{y0:g},{x1:g},{y1:g}"
        )
    return x0, y0, x1, y1


def _check_locations(locations: np.ndarray) -> None:
    if len(locations) < 3:
        raise InputError(
            f"{len(locations)} distinct probe location(s): the paper method needs at least 3"
        )
    try:
        Delaunay(locations)
    except QhullError:
        raise InputError(
            f"the {len(locations)} probe locations lie on one line: piecewise cubic "
            "interpolation needs them to span an area"
        ) from None

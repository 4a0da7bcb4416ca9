"""PNG figures a user would rather look at than read: the method's steps and the result map.

* ``plot_point_log_map``: one sensor's point log map as the raw grid, the interpolated map
  and the thresholded peak with its prediction (the paper's three-step figure);
* ``plot_point_log_maps``: every sensor's map as a tile of one mosaic, estimates marked;
* ``plot_predictions``: every prediction versus the truth over the patch outline, with the
  probe locations and, where a method gives one, the 1-sigma error circle;
* ``plot_off_design``: each located sensor's displacement from the patch's design, the
  layout's shift, turn and stretch taken out (``varskin.design_fit``), magnified.

Figures are drawn with matplotlib's object API on the Agg canvas, so nothing here touches
the global pyplot state or needs a display; localizers never import this module.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PatchCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Rectangle
from scipy.spatial import QhullError

from varskin.localization import paper
from varskin.pointlogs import PointLogs, touch_spacing_mm
from varskin.predictions import OK, Predictions

if TYPE_CHECKING:
    from varskin.design_fit import DesignFit


def _save(fig: Figure, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=110)
    return path


def _save_patch_view(fig: Figure, ax, path: str | Path) -> Path:
    """A view over the patch in mm, to scale, its legend beside it, saved."""
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=7)
    ax.autoscale_view()
    return _save(fig, path)


def plot_point_log_map(
    logs: PointLogs,
    sensor: str,
    path: str | Path,
    eta: float = paper.DEFAULT_ETA,
    ppcm: float = paper.DEFAULT_PPCM,
    area=None,
    truth_xy: tuple[float, float] | None = None,
) -> Path:
    """The paper's three steps for one sensor: raw point log map, interpolated, thresholded."""
    if sensor not in logs.sensors:
        raise KeyError(sensor)
    j = logs.sensors.index(sensor)
    locations, maps = paper.point_log_map(logs)
    column = maps[:, j]
    area = tuple(area) if area is not None else paper.bounding_box(locations)
    gx, gy = paper.pixel_grid(area, ppcm)
    finite = np.isfinite(column)
    try:
        image = paper.interpolate(locations[finite], column[finite], gx, gy)
    except (QhullError, ValueError):
        # Too few or collinear valid probes for this sensor: show the raw map and no surface.
        image = np.full((len(gy), len(gx)), np.nan)
    x, y, status = paper.threshold_mean(image, gx, gy, eta)
    extent = (gx[0], gx[-1], gy[0], gy[-1])
    vmin, vmax = (
        (float(np.nanmin(column)), float(np.nanmax(column))) if finite.any() else (0.0, 1.0)
    )

    fig = Figure(figsize=(9, 6), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    ax = axes[0]
    sc = ax.scatter(
        locations[:, 0],
        locations[:, 1],
        c=column,
        marker="s",
        s=90,
        cmap="viridis",
        vmin=vmin,
        vmax=vmax,
    )
    ax.set_title(f"{sensor}: a) point log map ({len(locations)} probe locations)")
    fig.colorbar(sc, ax=ax, label="counts above rest")

    # Both pixel panels share one colour scale, so the threshold step reads against the map.
    pixels = dict(
        origin="lower",
        extent=extent,
        cmap="viridis",
        vmin=vmin,
        vmax=vmax,
        aspect="equal",
        interpolation="nearest",
    )
    ax = axes[1]
    im = ax.imshow(image, **pixels)
    ax.set_title(
        f"b) piecewise cubic interpolation, {ppcm:g} pixels/cm (blank: outside the probes' hull)"
    )
    fig.colorbar(im, ax=ax, label="counts above rest")

    ax = axes[2]
    peak = np.nanmax(image) if np.isfinite(image).any() else np.nan
    with np.errstate(invalid="ignore"):
        kept = np.where(image > eta * peak, image, np.nan)
    im = ax.imshow(kept, **pixels)
    title = f"c) pixels above {eta:g} x max, averaged"
    if status == OK:
        ax.plot([x], [y], "rx", ms=10, mew=2, label=f"prediction ({x:.2f}, {y:.2f})")
    else:
        title += f": {status}"
    if truth_xy is not None:
        ax.plot([truth_xy[0]], [truth_xy[1]], "w+", ms=12, mew=2, label="truth")
    if status == OK or truth_xy is not None:
        ax.legend(loc="upper right", fontsize=8)
    ax.set_title(title)
    fig.colorbar(im, ax=ax, label="counts above rest")
    for ax in axes:
        ax.set_aspect("equal")
        ax.set_xlim(area[0], area[2])
        ax.set_ylim(area[1], area[3])
        ax.set_ylabel("y (mm)")
    axes[-1].set_xlabel("x (mm)")
    return _save(fig, path)


def plot_predictions(
    predictions: Predictions,
    path: str | Path,
    probes_xy: np.ndarray | None = None,
    truth: dict[str, tuple[float, float]] | None = None,
    outline_mm: tuple[float, float] | None = None,
    title: str | None = None,
) -> Path:
    """All predictions (and truths, error circles, probes) over the patch outline.

    ``outline_mm`` is the patch (length, width); without it the probes' bounding box is drawn.
    """
    fig = Figure(figsize=(12, 3.0), layout="constrained")
    ax = fig.subplots()
    if outline_mm is not None:
        ax.add_patch(
            Rectangle(
                (0, 0),
                outline_mm[0],
                outline_mm[1],
                fill=False,
                lw=1.5,
                ec="black",
                label="patch outline",
            )
        )
    elif probes_xy is not None and len(probes_xy):
        lo, hi = np.min(probes_xy, axis=0), np.max(probes_xy, axis=0)
        ax.add_patch(Rectangle(lo, *(hi - lo), fill=False, ls="--", ec="grey", label="probed area"))
    if probes_xy is not None and len(probes_xy):
        ax.plot(probes_xy[:, 0], probes_xy[:, 1], ".", color="0.6", ms=4, label="probe locations")
    truth = truth or {}
    first_circle = True
    for e in predictions:
        t = truth.get(e.sensor)
        if t is not None:
            ax.plot([t[0]], [t[1]], "k+", ms=8)
            ax.annotate(e.sensor, t, textcoords="offset points", xytext=(2, 3), fontsize=6)
        if e.status != OK:
            continue
        if t is not None:
            ax.plot([t[0], e.x_mm], [t[1], e.y_mm], "-", color="tab:red", lw=0.8)
        ax.plot([e.x_mm], [e.y_mm], "o", color="tab:blue", ms=4)
        if e.sigma_mm is not None:
            ax.add_patch(
                Circle(
                    (e.x_mm, e.y_mm),
                    e.sigma_mm,
                    fill=False,
                    ec="tab:blue",
                    lw=0.7,
                    label="1-sigma" if first_circle else None,
                )
            )
            first_circle = False
    ax.plot([], [], "o", color="tab:blue", ms=4, label=f"prediction ({predictions.method})")
    if truth:
        ax.plot([], [], "k+", ms=8, label="truth")
    failed = [e.sensor for e in predictions if e.status != OK]
    ax.set_title(
        title
        or f"{predictions.method}: predicted sensor positions"
        + (f" (not localized: {', '.join(failed)})" if failed else "")
    )
    return _save_patch_view(fig, ax, path)


def plot_off_design(
    predictions: Predictions,
    fit: DesignFit,
    path: str | Path,
    outline_mm: tuple[float, float] | None = None,
) -> Path:
    """Each located sensor's displacement from the patch's design (once the layout's
    shift, turn and stretch are taken out: ``design_fit``), as arrows magnified to be seen,
    each with its 2-sigma circle magnified alike: an arrow that leaves its circle is a
    crossing built off its design; arrows that agree along a line are a displaced wire.
    The fit's summary is the title's second line."""
    fig = Figure(figsize=(12, 3.2), layout="constrained")
    ax = fig.subplots()
    if outline_mm is not None:
        ax.add_patch(
            Rectangle((0, 0), *outline_mm, fill=False, lw=1.5, ec="black", label="patch outline")
        )
    est = {e.sensor: e for e in predictions if e.status == OK}
    off_design_mm = fit.off_design_mm
    names = [n for n in off_design_mm if n in est]
    at = np.array([[est[n].x_mm, est[n].y_mm] for n in names]).reshape(-1, 2)
    d = np.array([off_design_mm[n] for n in names], float).reshape(-1, 2)
    extent = float(np.ptp(at, axis=0).max()) if len(at) > 1 else 1.0
    largest = float(np.hypot(*d.T).max()) if len(d) else 0.0
    gain = _nice_gain(0.06 * extent / largest) if largest > 0 else 1.0
    base = at - d  # where the shifted, turned and stretched design puts each sensor
    ax.plot(base[:, 0], base[:, 1], "x", color="0.5", ms=4, label="design, fitted as a whole")
    for (bx, by), (dx, dy), n in zip(base, d, names, strict=True):
        ax.annotate(
            "", (bx + gain * dx, by + gain * dy), (bx, by),
            arrowprops={"arrowstyle": "->", "color": "tab:red", "lw": 0.9},
        )  # fmt: skip
        sigma = est[n].sigma_mm
        if sigma is not None:
            ax.add_patch(
                Circle((bx + gain * dx, by + gain * dy), gain * 2 * sigma, fill=False,
                       ec="tab:blue", lw=0.5)
            )  # fmt: skip
        ax.annotate(n, (bx, by), textcoords="offset points", xytext=(2, -8), fontsize=6)
    ax.plot([], [], "-", color="tab:red", label=f"located - design, x{gain:g}")
    ax.plot([], [], "o", mfc="none", mec="tab:blue", label=f"2 sigma, x{gain:g}")
    head = "located sensors against the patch's design"
    ax.set_title(f"{head}\n{fit.summary()}", fontsize=9)
    return _save_patch_view(fig, ax, path)


def _nice_gain(g: float) -> float:
    """The largest of 1, 2, 5, 10, 20, 50, ... not above ``g`` (at least 1)."""
    best = 1.0
    for k in range(0, 6):
        for m in (1.0, 2.0, 5.0):
            if m * 10**k <= g:
                best = m * 10**k
    return best


def plot_point_log_maps(
    logs: PointLogs,
    path: str | Path,
    predictions: Predictions | None = None,
    outline_mm: tuple[float, float] | None = None,
    columns: int | None = None,
) -> Path:
    """Every sensor's point log map at a glance: probe points coloured by its response,
    with its estimate marked; a sensor whose map has no peak stands out at once."""
    return _save(point_log_mosaic(logs, predictions, outline_mm, columns), path)


# Width of the whole mosaic (inches), and of one tile at most.
MOSAIC_WIDTH_IN = 16.0
TILE_WIDTH_IN = 3.2


def point_log_mosaic(
    logs: PointLogs,
    predictions: Predictions | None = None,
    outline_mm: tuple[float, float] | None = None,
    columns: int | None = None,
) -> Figure:
    """The figure of ``plot_point_log_maps``: one tile per sensor, all on one Axes.

    One Axes, not one per sensor: a full Muca board's 252 subplots took 40 s to draw (each
    Axes has its own layout and artists); offset tiles in a single scatter take about one.
    Each tile is the patch outline (or the probes' box) with the probes coloured by that
    sensor's own response, from its smallest reading (dark) to its largest (yellow).
    """
    n = logs.n_sensors
    xy = np.asarray(logs.xy_mm, float)
    spacing = touch_spacing_mm(xy)
    if outline_mm is not None:
        x0, y0, w, h = 0.0, 0.0, float(outline_mm[0]), float(outline_mm[1])
    elif len(xy):
        # The probes' box with half a spacing around it: the edge probes' squares fit.
        pad = max(spacing, 1.0) / 2
        (x0, y0), (x1, y1) = xy.min(axis=0) - pad, xy.max(axis=0) + pad
        w, h = x1 - x0, y1 - y0
    else:
        x0, y0, w, h = 0.0, 0.0, 1.0, 1.0
    if columns is None:
        # About as many tiles across as down the page, and at least 5.
        columns = max(5, int(np.ceil(np.sqrt(n * h / w))))
    columns = max(1, min(columns, n))
    rows = max(1, -(-n // columns))
    tile_in = min(TILE_WIDTH_IN, MOSAIC_WIDTH_IN / columns)
    gap_x, gap_y = 0.08 * w, 0.25 * h  # the gap above a tile holds its label
    fig = Figure(figsize=(tile_in * columns + 0.4, tile_in * (h + gap_y) / w * rows + 0.8))
    ax = fig.add_axes((0.01, 0.01, 0.98, 1 - 0.45 / fig.get_figheight()))
    left = np.arange(n) % columns * (w + gap_x)  # each sensor's tile, lower left corner
    bottom = -(np.arange(n) // columns) * (h + gap_y)
    dx, dy = left - x0, bottom - y0  # from patch mm to the tile's

    values = np.asarray(logs.values, float)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN column: left blank
        lo, hi = np.nanmin(values, axis=0), np.nanmax(values, axis=0)
        shade = (values - lo) / np.where(hi > lo, hi - lo, 1.0)
    # Squares as wide as the probes' typical spacing, so a grid's map reads as an image.
    spacing = spacing or w
    marker = (0.9 * min(spacing, w / 4) * 72.0 * tile_in / w) ** 2
    if len(xy):
        ax.scatter(
            (xy[:, 0:1] + dx).ravel(),
            (xy[:, 1:2] + dy).ravel(),
            c=shade.ravel(),
            s=marker,
            marker="s",
            cmap="viridis",
            vmin=0.0,
            vmax=1.0,
            linewidths=0,
        )
    ax.add_collection(
        PatchCollection(
            [Rectangle((left[j], bottom[j]), w, h) for j in range(n)],
            facecolor="none",
            edgecolor="0.6",
            linewidth=0.5,
        )
    )
    est = predictions.by_name() if predictions is not None else {}
    located = [
        (dx[j] + e.x_mm, dy[j] + e.y_mm)
        for j, name in enumerate(logs.sensors)
        if (e := est.get(name)) is not None and e.status == OK
    ]
    if located:
        ax.plot(*np.array(located).T, "r+", ms=8 * tile_in / TILE_WIDTH_IN)
    size = max(5.0, 8.0 * tile_in / TILE_WIDTH_IN)
    for j, name in enumerate(logs.sensors):
        e = est.get(name)
        label = name if e is None or e.status == OK else f"{name} ({e.status})"
        color = "black" if e is None or e.status == OK else "tab:red"
        ax.text(left[j], bottom[j] + 1.05 * h, label, fontsize=size, color=color)
    ax.set_xlim(-gap_x / 2, left[columns - 1] + w + gap_x / 2)
    ax.set_ylim(bottom[-1] - gap_y / 2, h + gap_y)
    ax.set_aspect("equal")
    ax.set_anchor("N")  # the spare height goes below the tiles, not between them and the title
    ax.set_axis_off()
    fig.suptitle(
        f"point log maps ({len(logs)} touches; each tile {w:.0f} x {h:.0f} mm, colour from "
        "the sensor's lowest to highest reading); + = estimate",
        fontsize=10,
    )
    return fig


def plot_uncertainty_vs_touches(
    n_logs: np.ndarray,
    sigma_median: np.ndarray,
    sigma_max: np.ndarray,
    located: np.ndarray,
    n_sensors: int,
    path: str | Path,
    rms_mm: np.ndarray | None = None,
) -> Path:
    """How the live estimate converged: sigma (median, worst) and sensors located per touch."""
    fig = Figure(figsize=(8, 4), layout="constrained")
    ax = fig.subplots()
    ax.plot(n_logs, sigma_median, "-", label="median sigma")
    ax.plot(n_logs, sigma_max, "-", label="largest sigma")
    if rms_mm is not None:
        ax.plot(n_logs, rms_mm, "k--", lw=1, label="RMS error vs truth (simulated rig)")
    ax.set_yscale("log")
    ax.set_xlabel("point logs")
    ax.set_ylabel("mm")
    ax.grid(True, which="both", alpha=0.3)
    ax2 = ax.twinx()
    ax2.step(n_logs, located, where="post", color="tab:green", alpha=0.6, label="located")
    ax2.set_ylim(0, n_sensors + 1)
    ax2.set_ylabel("sensors located", color="tab:green")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title("live estimate versus touches")
    return _save(fig, path)

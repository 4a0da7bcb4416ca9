"""The end of a session, written for people: predictions as CSV and JSON, and the plots.

Called by ``varskin calibrate`` when a session completes and by ``varskin replay``; it reads
everything from the session store, so a report can be rebuilt from any session file.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from varskin.design_fit import DesignFit, fit_design
from varskin.patch import Patch
from varskin.plots import (
    plot_off_design,
    plot_point_log_maps,
    plot_predictions,
    plot_uncertainty_vs_touches,
)
from varskin.predictions import OK, Predictions
from varskin.session import rms_error_mm
from varskin.store import SessionStore


@dataclass(frozen=True)
class ReportFiles:
    predictions_csv: Path
    predictions_json: Path
    plots: tuple[Path, ...]
    design_fit: DesignFit | None  # the located sensors against the design (None: too few)


def convergence(store: SessionStore, truth_xy: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per stored live estimate: median and largest sigma, sensors located, RMS vs truth."""
    live = store.estimates("live")
    n = np.array(sorted(live), int)
    med, worst, located, rms = [], [], [], []
    for k in n:
        p = live[int(k)]
        sig = [e.sigma_mm for e in p.estimates if e.status == OK and e.sigma_mm is not None]
        med.append(np.median(sig) if sig else np.nan)
        worst.append(max(sig) if sig else np.nan)
        located.append(sum(e.status == OK for e in p.estimates))
        if truth_xy is not None:
            rms.append(rms_error_mm(p, truth_xy)[0])
    out = {
        "n_logs": n,
        "sigma_median": np.array(med, float),
        "sigma_max": np.array(worst, float),
        "located": np.array(located, int),
    }
    if truth_xy is not None:
        out["rms_mm"] = np.array(rms, float)
    return out


def write_report(
    out_dir: str | Path,
    store: SessionStore,
    predictions: Predictions,
    patch: Patch,
    truth_xy: np.ndarray | None = None,
) -> ReportFiles:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path, json_path = out / "predictions.csv", out / "predictions.json"
    predictions.to_csv(csv_path)
    predictions.to_json(json_path)
    logs = store.point_logs()
    outline = (patch.length_mm, patch.width_mm)
    truth = (
        {s: (float(x), float(y)) for s, (x, y) in zip(patch.names, truth_xy, strict=True)}
        if truth_xy is not None
        else None
    )
    plots = [
        plot_point_log_maps(logs, out / "point_log_maps.png", predictions, outline),
        plot_predictions(
            predictions, out / "predictions.png", logs.xy_mm, truth, outline_mm=outline
        ),
    ]
    fit = fit_design(predictions, patch)
    if fit is not None:
        plots.append(plot_off_design(predictions, fit, out / "off_design.png", outline))
    conv = convergence(store, truth_xy)
    if len(conv["n_logs"]):
        plots.append(
            plot_uncertainty_vs_touches(
                conv["n_logs"],
                conv["sigma_median"],
                conv["sigma_max"],
                conv["located"],
                len(patch.names),
                out / "uncertainty_vs_touches.png",
                conv.get("rms_mm"),
            )
        )
    return ReportFiles(csv_path, json_path, tuple(plots), fit)

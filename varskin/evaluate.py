"""Scoring predictions against known sensor positions, the way the paper reports it.

The paper's headline number is the spread of the prediction errors,
RMS = sqrt(sum e_i^2 / (N - 1)) over the N localized sensors; mean and max go beside it.
Sensors are matched by name; one without a prediction or without a truth is listed with
a status instead of breaking the evaluation.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from varskin.errors import InputError
from varskin.predictions import OK, Predictions, SensorEstimate
from varskin.table_csv import finite_cell, read_table

PREDICTION_COLUMNS = ("sensor", "x_mm", "y_mm", "sigma_mm", "snr_db", "status")


@dataclass(frozen=True)
class SensorError:
    sensor: str
    x_mm: float | None
    y_mm: float | None
    true_x_mm: float | None
    true_y_mm: float | None
    error_mm: float | None
    sigma_mm: float | None
    status: str  # the prediction's status, or "nopred" / "notruth"


@dataclass
class Evaluation:
    method: str
    rows: list[SensorError]
    n_ok: int
    rms_mm: float | None  # sqrt(sum e^2 / (N - 1)); None below 2 sensors
    mean_mm: float | None
    max_mm: float | None
    not_ok: list[str] = field(default_factory=list)

    def table(self) -> str:
        lines = [
            f"{'sensor':<8} {'pred x':>8} {'pred y':>8} {'true x':>8} {'true y':>8} "
            f"{'err mm':>7} {'status':<8}"
        ]
        for r in self.rows:
            lines.append(
                f"{r.sensor:<8} {_f(r.x_mm):>8} {_f(r.y_mm):>8} {_f(r.true_x_mm):>8} "
                f"{_f(r.true_y_mm):>8} {_f(r.error_mm):>7} {r.status:<8}"
            )
        return "\n".join(lines)

    def summary(self) -> str:
        text = (
            f"{self.method}: {self.n_ok}/{len(self.rows)} sensors localized; "
            f"RMS (N-1) {_f(self.rms_mm, 3)} mm, mean {_f(self.mean_mm, 3)} mm, "
            f"max {_f(self.max_mm, 3)} mm"
        )
        if self.not_ok:
            text += f"; not scored: {', '.join(self.not_ok)}"
        return text

    def to_dict(self) -> dict:
        return {
            "method": self.method,
            "n_sensors": len(self.rows),
            "n_ok": self.n_ok,
            "rms_mm": self.rms_mm,
            "mean_mm": self.mean_mm,
            "max_mm": self.max_mm,
            "not_ok": list(self.not_ok),
            "sensors": [asdict(r) for r in self.rows],
        }


def _f(v: float | None, digits: int = 2) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def rms_n_minus_1(errors) -> float | None:
    """The paper's summary: sqrt(sum e^2 / (N - 1)); None when N < 2."""
    e = np.asarray(list(errors), float)
    if len(e) < 2:
        return None
    return float(math.sqrt(float((e**2).sum()) / (len(e) - 1)))


def evaluate(predictions: Predictions, truth: dict[str, tuple[float, float]]) -> Evaluation:
    """Per-sensor error and the summary; prediction order first, then truth-only sensors."""
    rows: list[SensorError] = []
    seen = set()
    for e in predictions.estimates:
        seen.add(e.sensor)
        t = truth.get(e.sensor)
        tx, ty = (None, None) if t is None else (float(t[0]), float(t[1]))
        err = None
        status = e.status
        if t is None:
            status = "notruth"
        elif e.status == OK:
            err = float(math.hypot(e.x_mm - tx, e.y_mm - ty))
        rows.append(SensorError(e.sensor, e.x_mm, e.y_mm, tx, ty, err, e.sigma_mm, status))
    for name, (tx, ty) in truth.items():
        if name not in seen:
            rows.append(SensorError(name, None, None, float(tx), float(ty), None, None, "nopred"))
    errors = [r.error_mm for r in rows if r.error_mm is not None]
    return Evaluation(
        method=predictions.method,
        rows=rows,
        n_ok=len(errors),
        rms_mm=rms_n_minus_1(errors),
        mean_mm=float(np.mean(errors)) if errors else None,
        max_mm=float(np.max(errors)) if errors else None,
        not_ok=[f"{r.sensor}({r.status})" for r in rows if r.error_mm is None],
    )


def read_predictions_csv(path: str | Path, method: str = "file") -> Predictions:
    """Read the ``sensor,x_mm,y_mm,sigma_mm,snr_db,status`` file that ``localize`` writes."""
    estimates = []
    names = set()
    for ln, row in read_table(path, PREDICTION_COLUMNS):
        sensor, status = row[0], row[5]
        if not sensor or sensor in names:
            raise InputError(f"{path}:{ln}:1: sensor name {sensor!r} is empty or repeated")
        names.add(sensor)
        nums = [
            finite_cell(path, ln, col, PREDICTION_COLUMNS[col], row[col], empty_ok=True)
            for col in range(1, 5)
        ]
        try:
            estimates.append(SensorEstimate(sensor, *nums, status=status or "missing"))
        except ValueError as e:
            raise InputError(f"{path}:{ln}:6: {e}") from None
    return Predictions(method, estimates)

"""Scoring predictions against known sensor positions, the way the paper reports it.

The paper's headline number is the spread of the prediction errors,
RMS = sqrt(sum e_i^2 / (N - 1)) over the N localized sensors; mean and max go beside it.
Sensors are matched by name; one without a prediction or without a truth is listed with
a status instead of breaking the evaluation.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from varskin.errors import InputError
from varskin.predictions import OK, Predictions, SensorEstimate

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
    name = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{name}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or not any(c.strip() for c in rows[0]):
        raise InputError(
            f"{name}:1:1: empty file: expected a header {','.join(PREDICTION_COLUMNS)}"
        )
    header = [c.strip() for c in rows[0]]
    for i, want in enumerate(PREDICTION_COLUMNS):
        if i >= len(header) or header[i] != want:
            found = repr(header[i]) if i < len(header) else "nothing"
            raise InputError(
                f"{name}:1:{i + 1}: header column {i + 1} must be {want!r}, found {found}"
            )
    estimates = []
    names = set()
    for ln, row in enumerate(rows[1:], start=2):
        if not any(c.strip() for c in row):
            continue
        if len(row) != len(header):
            col = min(len(row), len(header)) + 1
            raise InputError(f"{name}:{ln}:{col}: {len(row)} fields, the header has {len(header)}")
        sensor, status = row[0].strip(), row[5].strip()
        if not sensor or sensor in names:
            raise InputError(f"{name}:{ln}:1: sensor name {sensor!r} is empty or repeated")
        names.add(sensor)
        nums = []
        for col in range(1, 5):
            cell = row[col].strip()
            if not cell:
                nums.append(None)
                continue
            try:
                v = float(cell)
            except ValueError:
                v = float("nan")
            if not math.isfinite(v):
                raise InputError(
                    f"{name}:{ln}:{col + 1}: {header[col]} must be a finite number or empty, found {cell!r}"
                )
            nums.append(v)
        try:
            estimates.append(SensorEstimate(sensor, *nums, status=status or "missing"))
        except ValueError as e:
            raise InputError(f"{name}:{ln}:6: {e}") from None
    return Predictions(method, estimates)

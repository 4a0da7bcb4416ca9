"""Localization results: one estimate per sensor, with its error bar and status.

Every localizer returns ``Predictions``; the CLI writes them as the CSV
``sensor,x_mm,y_mm,sigma_mm,snr_db,status`` or as JSON. A sensor that cannot be
localized has a one-word status saying why and no coordinates: never NaN.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

OK = "ok"
# sigma_mm is defined so that the circle of radius 2 sigma around the estimate holds the true
# position with 95% probability for a 2-D Gaussian error of per-axis sd s:
# r95 = s * sqrt(2 ln 20), so sigma_mm = s * sqrt(2 ln 20) / 2 (about 1.22 s).
R95_PER_AXIS_SD = math.sqrt(2.0 * math.log(20.0))


@dataclass(frozen=True)
class SensorEstimate:
    sensor: str
    x_mm: float | None
    y_mm: float | None
    sigma_mm: float | None = None  # half the 95% error radius (R95_PER_AXIS_SD); None: none
    snr_db: float | None = None
    status: str = OK  # "ok" or one word: dead, saturated, flat, outside, ...

    def __post_init__(self) -> None:
        for name in ("x_mm", "y_mm", "sigma_mm", "snr_db"):
            v = getattr(self, name)
            if v is not None and not math.isfinite(v):
                raise ValueError(f"{self.sensor}: {name} is {v}; use a status instead of NaN/inf")
        if self.status == OK and (self.x_mm is None or self.y_mm is None):
            raise ValueError(f"{self.sensor}: status ok needs coordinates")
        if " " in self.status or not self.status:
            raise ValueError(f"{self.sensor}: status must be one word, got {self.status!r}")


@dataclass
class Predictions:
    method: str
    estimates: list[SensorEstimate]
    params: dict = field(default_factory=dict)

    def __iter__(self):
        return iter(self.estimates)

    def __len__(self) -> int:
        return len(self.estimates)

    def by_name(self) -> dict[str, SensorEstimate]:
        return {e.sensor: e for e in self.estimates}

    def xy(self) -> np.ndarray:
        """(N, 2) coordinates with NaN rows for sensors that are not ok (for array maths)."""
        return np.array(
            [[e.x_mm, e.y_mm] if e.status == OK else [np.nan, np.nan] for e in self.estimates],
            float,
        ).reshape(len(self.estimates), 2)

    def to_csv(self, path: str | Path) -> None:
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["sensor", "x_mm", "y_mm", "sigma_mm", "snr_db", "status"])
            for e in self.estimates:
                w.writerow(
                    [
                        e.sensor,
                        _fmt(e.x_mm),
                        _fmt(e.y_mm),
                        _fmt(e.sigma_mm),
                        _fmt(e.snr_db, 2),
                        e.status,
                    ]
                )

    def to_dict(self) -> dict:
        return {
            "method": self.method,
            "params": self.params,
            "sensors": [asdict(e) for e in self.estimates],
        }

    def to_json(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")


def _fmt(v: float | None, digits: int = 4) -> str:
    return "" if v is None else f"{v:.{digits}f}"

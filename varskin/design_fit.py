"""How the located sensors sit against their patch's design: shifted, turned, stretched.

Why a module: bringing up a patch, a lab wants two answers besides the positions. Does the
skin lie where the registration put it (a shift or turn of the whole layout)? And how far
was each sensor built off its design, once that is taken out? The localizer's layout
prior maps the design onto the fits per axis (an offset, and a scale with five or more
wires), never turns it, and reports neither. This fits one similarity transform (shift,
turn, stretch) from the design to the `ok` sensors and reports it. A turn or shift beyond
what a registration leaves, and beyond what the sensors' own build could make of it, gets
a warning: the registration is off, and the plan's touches sit off the patch by as much.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from varskin.patch import Patch
from varskin.predictions import OK, R95_PER_AXIS_SD, Predictions

# A turn beyond this is not what a registration leaves: the ArUco registration's worst on
# noisy images is 0.62 degrees (docs/benchmarks.md, "Patch registration from ArUco
# markers"). On 160 unturned simulated scenes, whose wires are built off their design,
# the fitted turn stayed within 0.74 degrees (benchmarks/design_fit.py).
TURN_WARN_DEG = 1.0
# A shift of the whole layout beyond this: a wire is built about 0.6 mm off its design
# (the simulator's default), and on those scenes the fitted shift stayed within 1.05 mm.
SHIFT_WARN_MM = 2.0
# ... and each only where it is also more than this many of its sds: on a patch a few
# wire pitches across, the crossings' build alone turns the layout by degrees (20 mm, 3 x
# 3 crossings: sd 1.6 degrees).
WARN_SDS = 3.0
# How far a sensor is built off its design beyond the similarity, at least (mm sd): the
# layout prior's floor for the wires' scatter (peakfit's `wire_scatter_mm`).
BUILD_SCATTER_FLOOR_MM = 0.25
MIN_SENSORS = 3


@dataclass(frozen=True)
class DesignFit:
    """The similarity from a patch's design to its located sensors (patch frame, mm)."""

    n_sensors: int  # `ok` sensors it was fitted to
    shift_mm: tuple[float, float]  # where the design's (weighted) centre landed, minus it
    turn_deg: float  # anticlockwise
    stretch: float  # relative: 0.01 is 1 % larger than the design
    # sds of the shift (x, y) and of the turn: a wire's crossings are built off together,
    # so each is the larger of the first-order sd (every sensor independent) and the
    # sandwich sd that takes each wire's residuals as one. On Patch A and B the fitted
    # turns scatter 0.7-1.7x their sds and the shifts 1.5-2.8x (benchmarks/design_fit.py):
    # a family of 2-3 RX wires gives the sandwich little to go on.
    shift_sd_mm: tuple[float, float]
    turn_sd_deg: float
    # Each fitted sensor's (dx, dy) mm off the transformed design: its wires' build.
    off_design_mm: dict[str, tuple[float, float]]

    @property
    def off_design_rms_mm(self) -> float:
        """The sensors' distance from the transformed design, RMS (mm)."""
        return float(
            np.sqrt(np.mean([dx * dx + dy * dy for dx, dy in self.off_design_mm.values()]))
        )

    @property
    def largest(self) -> tuple[str, float]:
        """The sensor furthest off the transformed design, and how far (mm)."""
        name = max(self.off_design_mm, key=lambda n: np.hypot(*self.off_design_mm[n]))
        return name, float(np.hypot(*self.off_design_mm[name]))

    def summary(self) -> str:
        dx, dy = self.shift_mm
        sx, sy = self.shift_sd_mm
        name, far = self.largest
        return (
            f"against the design ({self.n_sensors} located sensors): shifted "
            f"({dx:+.2f}, {dy:+.2f}) mm (sd {sx:.2f}, {sy:.2f}), turned "
            f"{self.turn_deg:+.2f} deg (sd {self.turn_sd_deg:.2f}), stretched "
            f"{100 * self.stretch:+.2f} %; then off it by {self.off_design_rms_mm:.2f} mm RMS "
            f"(largest {name}, {far:.2f} mm)"
        )

    def warnings(self) -> list[str]:
        out = []
        if abs(self.turn_deg) > max(TURN_WARN_DEG, WARN_SDS * self.turn_sd_deg):
            out.append(
                f"the located sensors lie turned {self.turn_deg:+.2f} deg against the patch's "
                f"design (a registration leaves under {TURN_WARN_DEG:g} deg): check the "
                "registration before the next session"
            )
        z = np.abs(self.shift_mm) / np.maximum(self.shift_sd_mm, 1e-12)
        if float(np.hypot(*self.shift_mm)) > SHIFT_WARN_MM and z.max() > WARN_SDS:
            dx, dy = self.shift_mm
            out.append(
                f"the located sensors lie shifted ({dx:+.2f}, {dy:+.2f}) mm from the patch's "
                f"design (more than {SHIFT_WARN_MM:g} mm): check the registration before "
                "the next session"
            )
        return out

    def as_dict(self) -> dict:
        name, far = self.largest
        return {
            "n_sensors": self.n_sensors,
            "shift_mm": list(self.shift_mm),
            "turn_deg": self.turn_deg,
            "stretch": self.stretch,
            "shift_sd_mm": list(self.shift_sd_mm),
            "turn_sd_deg": self.turn_sd_deg,
            "off_design_rms_mm": self.off_design_rms_mm,
            "largest": {"sensor": name, "mm": far},
            "off_design_mm": {name: list(d) for name, d in self.off_design_mm.items()},
        }


def fit_design(predictions: Predictions, patch: Patch) -> DesignFit | None:
    """The design-to-sensors similarity over the `ok` sensors the patch names, or None with
    fewer than MIN_SENSORS of them (or all at one design position).

    Weighted least squares in complex form (z = x + iy): the located z ~ a + b * design z,
    with b = (1 + stretch) e^(i turn). Each sensor weighs 1 / (sd^2 + s^2), with sd its
    per-axis error (from ``sigma_mm``) and s the sensors' build scatter about the
    transform, estimated from the residuals (empirical Bayes, at least
    BUILD_SCATTER_FLOOR_MM), so a few well-measured sensors do not speak for the patch.
    """
    design = {s.name: complex(s.x_mm, s.y_mm) for s in patch.sensors}
    wires = {s.name: (s.tx, s.rx) for s in patch.sensors}
    names, z, d, var = [], [], [], []
    for e in predictions:
        if e.status != OK or e.sensor not in design or e.sigma_mm is None:
            continue
        if not (np.isfinite(e.x_mm) and np.isfinite(e.y_mm) and np.isfinite(e.sigma_mm)):
            continue
        names.append(e.sensor)
        z.append(complex(e.x_mm, e.y_mm))
        d.append(design[e.sensor])
        var.append((2.0 * e.sigma_mm / R95_PER_AXIS_SD) ** 2)  # per axis
    if len(names) < MIN_SENSORS:
        return None
    z, d, var = np.array(z), np.array(d), np.array(var)
    build2 = BUILD_SCATTER_FLOOR_MM**2
    # Two coordinates per sensor, four parameters (shift, turn, stretch).
    dof = max(2 * len(z) - 4, 1)
    for _ in range(20):
        w = 1.0 / (var + build2)
        dc = np.sum(w * d) / w.sum()
        zc = np.sum(w * z) / w.sum()
        spread = np.sum(w * np.abs(d - dc) ** 2)
        if spread <= 0.0:
            return None
        b = np.sum(w * (z - zc) * np.conj(d - dc)) / spread
        resid = z - (zc + b * (d - dc))
        new = max(BUILD_SCATTER_FLOOR_MM**2, np.sum(np.abs(resid) ** 2) / dof - np.mean(var))
        if abs(new - build2) <= 1e-9 * build2:
            break
        build2 = new
    shift = zc - dc
    cov = _sandwich(d - dc, resid, w, [wires[n] for n in names])
    first = np.array([1.0 / w.sum(), 1.0 / w.sum(), 1.0 / spread, 1.0 / spread])
    sd = np.sqrt(np.maximum(first, np.diag(cov)))
    return DesignFit(
        n_sensors=len(z),
        shift_mm=(float(shift.real), float(shift.imag)),
        turn_deg=float(np.degrees(np.angle(b))),
        stretch=float(abs(b) - 1.0),
        shift_sd_mm=(float(sd[0]), float(sd[1])),
        turn_sd_deg=float(np.degrees(sd[3] / abs(b))),
        off_design_mm={
            n: (float(r.real), float(r.imag)) for n, r in zip(names, resid, strict=True)
        },
    )


def _sandwich(dd: np.ndarray, resid: np.ndarray, w: np.ndarray, wires: list) -> np.ndarray:
    """Covariance (4, 4) of (centre x, centre y, Re b, Im b) with each TX wire's x
    residuals and each RX wire's y residuals summed as one (the crossings of a wire are
    built off together), scaled by G / (G - 1) for the G wires.

    The real form of the fit: x - xc = Re(b) Re(dd) - Im(b) Im(dd), y - yc = Re(b) Im(dd)
    + Im(b) Re(dd), each row weighed by w; ``dd`` the centred design, ``resid`` the fit's.
    A first-order sd takes every crossing as independent: on Patch A and B it claimed a
    third of the shift's spread (benchmarks/design_fit.py).
    """
    one, zero = np.ones_like(w), np.zeros_like(w)
    gx = np.stack([one, zero, dd.real, -dd.imag], axis=1)  # (N, 4)
    gy = np.stack([zero, one, dd.imag, dd.real], axis=1)
    A = (
        w[:, None, None] * (gx[:, :, None] * gx[:, None, :] + gy[:, :, None] * gy[:, None, :])
    ).sum(axis=0)
    sx = w[:, None] * gx * resid.real[:, None]  # each row's score
    sy = w[:, None] * gy * resid.imag[:, None]
    clusters: dict = {}
    for i, (tx, rx) in enumerate(wires):
        clusters.setdefault(("tx", tx if tx >= 0 else -1 - i), []).append(sx[i])
        clusters.setdefault(("rx", rx if rx >= 0 else -1 - i), []).append(sy[i])
    scores = np.array([np.sum(rows, axis=0) for rows in clusters.values()])  # (G, 4)
    G = len(scores)
    B = scores.T @ scores * (G / max(G - 1, 1))
    try:
        inv = np.linalg.inv(A)
    except np.linalg.LinAlgError:
        inv = np.linalg.pinv(A)
    return inv @ B @ inv

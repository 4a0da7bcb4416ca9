"""The physics of a simulated skin: what every sensor reads for a probe at a point.

One model serves every fake in the project: ``varskin simulate`` (point-log CSVs), the
simulated Muca board (frames over a pty) and the simulated UR controller (contact force).
It models only what calibration scenes need: a hidden layout, response versus distance,
pressing force, noise, offset drift and saturation. Defaults come from public recordings
of the real patches (Muca board, human finger):

* rest values 7,400-11,500 counts; noise std 3.6-6.9 counts (median 4.9);
* touch peaks 86-587 counts above rest (median 170): real SNR 26-40 dB;
* offsets move by up to +-120 counts between the no-contact baseline and the touches;
* a finger's footprint is 18-21 mm wide at half maximum, a/(1+(d/w)^2) with w ~ 9 mm;
  a small grounded metal probe is narrower;
* 40-50 samples per touch; a finger lands within ~+-2 mm, a robot within ~0.05 mm.

All randomness comes from one seeded ``numpy.random.Generator``.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field, replace

import numpy as np

from varskin.patch import Patch

ADC_MAX = 65535  # the Muca sends unsigned 16-bit values


@dataclass(frozen=True)
class ProbeModel:
    """What touches the skin and how well it is placed."""

    kind: str  # "finger" or "robot"
    width_mm: float  # w in a / (1 + (d / w)^2): half width at half maximum
    placement_sd_mm: float  # per-axis standard deviation of where it really lands
    gain_sd: float  # relative touch-to-touch variation of pressing force
    nominal_force_n: float

    @staticmethod
    def named(kind: str) -> ProbeModel:
        if kind == "finger":
            # A human places the finger to about +-2 mm (taken as ~2 sigma) and presses unevenly.
            return ProbeModel("finger", 9.0, 1.0, 0.15, 2.0)
        if kind == "robot":
            return ProbeModel("robot", 6.5, 0.05, 0.03, 2.0)
        raise ValueError(f"unknown probe {kind!r}: use 'finger' or 'robot'")


@dataclass(frozen=True)
class SceneParams:
    """Knobs of the simulated skin; defaults follow the public recordings above."""

    rest_range: tuple[float, float] = (7400.0, 11500.0)
    noise_median: float = 4.9
    noise_range: tuple[float, float] = (3.6, 6.9)
    peak_median: float = 170.0
    peak_range: tuple[float, float] = (86.0, 587.0)
    drift_max: float = 120.0  # largest offset change from baseline to the touches, counts
    drift_sd: float = 45.0  # typical offset change (normal, clipped at drift_max)
    drift_tau_s: float = 60.0  # how fast that change builds up
    samples_per_touch: tuple[int, int] = (40, 50)
    # Hidden layout: each wire is displaced and slightly bent, each crossing jitters a little.
    wire_offset_sd_mm: float = 0.6
    wire_bend_sd_mm: float = 0.25
    crossing_jitter_sd_mm: float = 0.15
    width_spread: float = 0.12  # per-sensor relative spread of footprint width
    anisotropy_spread: float = 0.10  # per-sensor relative difference between x and y width
    wire_coupling: float = 0.04  # fraction of the peak picked up along the TX and RX wires
    wire_coupling_width_mm: float = 2.5
    inverted: bool = False  # a touch lowers the value on some benches
    hidden_layout: bool = True  # False: the truth is the published design layout
    # A silicone patch laid on the bench may lie stretched (> 0) or shrunk (< 0) by this
    # fraction about its centre, in both axes; the probes' frame is not (rigid registration).
    stretch: float = 0.0
    # The registration's residual rotation: the layout lies turned by this angle (degrees,
    # anticlockwise) about the patch's centre in the probes' frame.
    rotation_deg: float = 0.0
    force_exponent: float = 0.5  # response ~ (F / F_nominal) ** exponent, saturating
    # Response versus distance, all with half maximum at d = w: "lorentzian" 1/(1+(d/w)^2)
    # (fitted to the public recordings), "gaussian" 2^-(d/w)^2 and "exponential" 2^-(d/w)
    # make scenes whose shape a localizer's model does not know (robustness tests).
    shape: str = "lorentzian"


SHAPES = ("lorentzian", "gaussian", "exponential")


def _profile(shape: str, d2: np.ndarray) -> np.ndarray:
    """Response at squared normalized distance d2 = (d/w)^2; each is 1/2 at d = w."""
    if shape == "gaussian":
        return np.exp2(-d2)
    if shape == "exponential":
        return np.exp2(-np.sqrt(d2))
    return 1.0 / (1.0 + d2)


@dataclass
class Scene:
    """A concrete simulated patch: the true layout and every sensor's constants."""

    patch: Patch
    params: SceneParams
    true_xy: np.ndarray  # (N, 2) mm
    rest: np.ndarray  # (N,) counts
    noise_sd: np.ndarray  # (N,)
    peak: np.ndarray  # (N,) counts above rest for the nominal press, finger-sized footprint
    width_scale: np.ndarray  # (N, 2) relative footprint width along x and y
    drift: np.ndarray  # (N,) offset change reached after a long session, counts
    dead: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    @classmethod
    def create(cls, patch: Patch, seed: int = 0, params: SceneParams | None = None) -> Scene:
        params = params or SceneParams()
        if params.shape not in SHAPES:
            raise ValueError(f"unknown shape {params.shape!r}: use one of {', '.join(SHAPES)}")
        rng = np.random.default_rng(seed)
        n = len(patch.sensors)
        design = patch.design_xy
        if params.stretch or params.rotation_deg:
            centre = np.array([patch.length_mm, patch.width_mm]) / 2
            a = np.radians(params.rotation_deg)
            turn = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
            design = centre + (design - centre) @ turn.T * (1.0 + params.stretch)
        if params.hidden_layout:
            tx = np.array([s.tx for s in patch.sensors])
            rx = np.array([s.rx for s in patch.sensors])
            tx_off = rng.normal(0, params.wire_offset_sd_mm, len(patch.tx_x_mm))
            rx_off = rng.normal(0, params.wire_offset_sd_mm, len(patch.rx_y_mm))
            # A bent wire moves its crossings smoothly: a slope along the other axis.
            tx_bend = rng.normal(0, params.wire_bend_sd_mm, len(patch.tx_x_mm)) / patch.width_mm
            rx_bend = rng.normal(0, params.wire_bend_sd_mm, len(patch.rx_y_mm)) / patch.length_mm
            cy, cx = patch.width_mm / 2, patch.length_mm / 2
            dx = tx_off[tx] + tx_bend[tx] * (design[:, 1] - cy) * 2
            dy = rx_off[rx] + rx_bend[rx] * (design[:, 0] - cx) * 2
            jitter = rng.normal(0, params.crossing_jitter_sd_mm, (n, 2))
            true_xy = design + np.column_stack([dx, dy]) + jitter
            margin = 0.5
            true_xy[:, 0] = np.clip(true_xy[:, 0], margin, patch.length_mm - margin)
            true_xy[:, 1] = np.clip(true_xy[:, 1], margin, patch.width_mm - margin)
        else:
            true_xy = design.copy()
        lo, hi = params.rest_range
        rest = rng.uniform(lo, hi, n)
        noise = np.clip(params.noise_median * np.exp(rng.normal(0, 0.2, n)), *params.noise_range)
        peak = np.clip(params.peak_median * np.exp(rng.normal(0, 0.45, n)), *params.peak_range)
        width = np.exp(rng.normal(0, params.width_spread, (n, 1)))
        aniso = np.exp(rng.normal(0, params.anisotropy_spread, (n, 1)) * np.array([[1, -1]]))
        drift = np.clip(rng.normal(0, params.drift_sd, n), -params.drift_max, params.drift_max)
        return cls(
            patch, params, true_xy, rest, noise, peak, width * aniso, drift, np.zeros(n, bool)
        )

    def with_params(self, **changes) -> Scene:
        return replace(self, params=replace(self.params, **changes))

    # --- physics -----------------------------------------------------------------------

    def offset(self, t_s: float | np.ndarray) -> np.ndarray:
        """Each sensor's offset from its rest value at session time t (drift), counts."""
        t = np.asarray(t_s, float)[..., None]
        return self.drift * (1.0 - np.exp(-t / self.params.drift_tau_s))

    def response(self, x_mm: float, y_mm: float, force_n: float, probe: ProbeModel) -> np.ndarray:
        """Noise-free change of every sensor (counts, positive = touch) for one press."""
        if force_n <= 0:
            return np.zeros(len(self.rest))
        # Force beyond nominal gives less and less: the contact area saturates.
        f = force_n / probe.nominal_force_n
        gain = f**self.params.force_exponent / (1 + 0.1 * max(f - 1, 0))
        w = probe.width_mm * self.width_scale  # (N, 2)
        d = (np.array([x_mm, y_mm]) - self.true_xy) / w
        core = _profile(self.params.shape, (d**2).sum(axis=1))
        # Mutual capacitance also couples along the TX wire (constant x) and RX wire.
        cw = self.params.wire_coupling_width_mm
        along = np.exp(-0.5 * ((x_mm - self.true_xy[:, 0]) / cw) ** 2) + np.exp(
            -0.5 * ((y_mm - self.true_xy[:, 1]) / cw) ** 2
        )
        # A narrower probe couples less charge than a fingertip.
        area = (probe.width_mm / 9.0) ** 0.5
        out = self.peak * area * gain * (core + self.params.wire_coupling * along)
        out[self.dead] = 0.0
        return out

    def sample(
        self,
        x_mm: float | None,
        y_mm: float | None,
        force_n: float,
        probe: ProbeModel,
        t_s: float | np.ndarray,
        rng: np.random.Generator,
    ) -> np.ndarray:
        """Raw board counts at time(s) t: rest + drift + touch response + noise, clipped.

        ``t_s`` may be an array of frame times; the result is then (len(t), N). ``x_mm`` None
        means no contact.
        """
        t = np.atleast_1d(np.asarray(t_s, float))
        resp = (
            np.zeros(len(self.rest))
            if x_mm is None or y_mm is None
            else self.response(x_mm, y_mm, force_n, probe)
        )
        sign = -1.0 if self.params.inverted else 1.0
        values = (
            self.rest
            + self.offset(t)
            + sign * resp
            + rng.normal(0, 1, (len(t), len(self.rest))) * self.noise_sd
        )
        values = np.clip(np.rint(values), 0, ADC_MAX)
        return values if np.ndim(t_s) else values[0]


class ProbeState:
    """Where the probe is and how hard it presses, shared between simulated devices.

    The simulated UR controller writes it as its TCP moves; the simulated board reads it at
    every frame. Coordinates are patch-frame mm (the simulated rig knows the true patch
    pose), force in N; ``None`` position means the probe is off the skin.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._x: float | None = None
        self._y: float | None = None
        self._force = 0.0

    def set(self, x_mm: float | None, y_mm: float | None, force_n: float) -> None:
        with self._lock:
            self._x, self._y, self._force = x_mm, y_mm, max(force_n, 0.0)

    def get(self) -> tuple[float | None, float | None, float]:
        with self._lock:
            return self._x, self._y, self._force

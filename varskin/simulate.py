"""Simulated calibration sessions: a probe touching a hidden-layout scene on a grid.

``simulate_session`` produces what a real session records, frame by frame (a no-contact
baseline, then each touch's samples with its time and force), so the same averaging and
the same localizers run on simulated and recorded data. ``varskin simulate`` writes it as
the point-log CSV with a truth file beside it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from varskin.patch import Patch
from varskin.pointlogs import PointLog, PointLogs, average_samples
from varskin.scene import ProbeModel, Scene, SceneParams

FRAME_RATE_HZ = 8.0  # a Muca board sending ASCII at 115200 baud manages 7-9 frames/s
BASELINE_SAMPLES = 50  # the paper's no-contact calibration sample size


def uniform_grid(patch: Patch, nx: int, ny: int) -> np.ndarray:
    """(nx*ny, 2) probe points at the centres of an nx x ny grid of equal cells (mm)."""
    if nx < 1 or ny < 1:
        raise ValueError("grid needs at least one row and one column")
    xs = (np.arange(nx) + 0.5) * patch.length_mm / nx
    ys = (np.arange(ny) + 0.5) * patch.width_mm / ny
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.column_stack([gx.ravel(), gy.ravel()])


@dataclass
class SimulatedSession:
    scene: Scene
    probe: ProbeModel
    baseline: np.ndarray  # (B, N) raw counts, no contact
    baseline_t: np.ndarray  # (B,) s
    touch: np.ndarray  # (M,) touch id of each frame
    xy_mm: np.ndarray  # (M, 2) commanded (believed) probe point of each frame
    samples: np.ndarray  # (M, N) raw counts
    t_s: np.ndarray  # (M,)
    force_n: np.ndarray  # (M,)

    @property
    def truth(self) -> np.ndarray:
        return self.scene.true_xy

    @property
    def sensors(self) -> tuple[str, ...]:
        return tuple(self.scene.patch.names)

    def point_logs(self) -> PointLogs:
        return average_samples(
            self.sensors,
            self.touch,
            self.xy_mm,
            self.samples,
            baseline=self.baseline,
            t_s=self.t_s,
            force_n=self.force_n,
            source="<simulated>",
        )


def simulate_session(
    patch: Patch,
    points_mm: np.ndarray,
    probe: str | ProbeModel = "finger",
    seed: int = 0,
    params: SceneParams | None = None,
    scene: Scene | None = None,
    samples_per_touch: int | None = None,
) -> SimulatedSession:
    """Touch ``points_mm`` in order on a seeded scene and record every frame.

    The probe lands with the probe's placement error and presses with its touch-to-touch
    force variation; the log records the commanded point, as a real session would.
    """
    probe = probe if isinstance(probe, ProbeModel) else ProbeModel.named(probe)
    scene = scene or Scene.create(patch, seed, params)
    rng = np.random.default_rng([seed, 1])
    dt = 1.0 / FRAME_RATE_HZ
    baseline_t = np.arange(BASELINE_SAMPLES) * dt
    baseline = scene.sample(None, None, 0.0, probe, baseline_t, rng)
    lo, hi = scene.params.samples_per_touch
    t = baseline_t[-1] + 2.0
    touch, xy, rows, times, forces = [], [], [], [], []
    for k, (x, y) in enumerate(np.asarray(points_mm, float)):
        n = samples_per_touch or int(rng.integers(lo, hi + 1))
        px, py = np.array([x, y]) + rng.normal(0, probe.placement_sd_mm, 2)
        force = probe.nominal_force_n * float(np.exp(rng.normal(0, probe.gain_sd)))
        ft = t + np.arange(n) * dt
        rows.append(scene.sample(px, py, force, probe, ft, rng))
        touch.append(np.full(n, k + 1))
        xy.append(np.tile([x, y], (n, 1)))
        times.append(ft)
        forces.append(np.full(n, force))
        t = ft[-1] + 1.5  # move to the next point
    return SimulatedSession(
        scene=scene,
        probe=probe,
        baseline=baseline,
        baseline_t=baseline_t,
        touch=np.concatenate(touch),
        xy_mm=np.concatenate(xy),
        samples=np.concatenate(rows),
        t_s=np.concatenate(times),
        force_n=np.concatenate(forces),
    )


def simulate_touch(
    scene: Scene,
    probe: ProbeModel,
    x_mm: float,
    y_mm: float,
    t_s: float,
    rng: np.random.Generator,
    n_samples: int = 8,
    touch: int = 1,
    rest: np.ndarray | None = None,
) -> PointLog:
    """One touch at the commanded point, averaged into its point log.

    For sessions planned touch by touch (the next point depends on the last result), where
    ``simulate_session``'s fixed list of points does not fit. The physics and the draws
    are ``simulate_session``'s: the probe lands with its placement error and presses with
    its force variation; ``n_samples`` frames at ``FRAME_RATE_HZ`` start at ``t_s``. The
    log records the commanded point; values are relative to ``rest`` when it is given
    (the mean of a no-contact baseline, as ``average_samples`` does).
    """
    px, py = np.array([x_mm, y_mm], float) + rng.normal(0, probe.placement_sd_mm, 2)
    force = probe.nominal_force_n * float(np.exp(rng.normal(0, probe.gain_sd)))
    ft = t_s + np.arange(n_samples) / FRAME_RATE_HZ
    frames = scene.sample(px, py, force, probe, ft, rng)
    values = frames.mean(axis=0)
    return PointLog(
        touch=touch,
        x_mm=float(x_mm),
        y_mm=float(y_mm),
        values=values if rest is None else values - rest,
        n_samples=n_samples,
        sample_sd=frames.std(axis=0, ddof=1) if n_samples > 1 else None,
        t_s=float(ft.mean()),
        force_n=force,
    )

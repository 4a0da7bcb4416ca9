"""Where the error bar's coverage comes from: issue 3 point 2, taken apart.

A sensor's sigma is its fit's own covariance plus the touches' placement and gain scatter
propagated through the fit (``_peak_model.fit``, first order), then scaled by one factor
per solve that the bootstrap check (``_error_bar.py``) measures on sessions simulated from
the fit. This script shows what each part does, on 20 x 5 grids (or ``--grid``).

Only a simulation knows where each touch really landed. For every scene it records the
landing points, so it knows each touch's real placement error and what is left of it after
the solver's estimate of the offset (centred, as the solver centres its offsets). The
sensors are then refitted, touches held where the solve left them, with a different
per-touch placement variance in the propagation, and without the check's factor:

* ``first order``: the solver's EM estimate of the placement scatter, no factor (what
  ``calibrate_sigma=False`` reports);
* ``actual``: the real mean square of what is left of the offsets after the estimate (an
  oracle: no real session has it);
* ``v_d``: the mean of the offsets' posterior variances with the sensors held fixed (what
  the data alone say, ignoring that the sensors are uncertain too).

``reported`` is the default: the first-order sigma times the check's factor (its mean is
printed). Per row: the probe's true placement sd, the three per-axis scales (mm), the mean
factor, then per mode the coverage, the median and 95th percentile of error / sigma, and
the RMS error. A calibrated sigma (half the 95% radius) has coverage 0.95, median 0.96 and
95th percentile 2.0.

Run as ``python benchmarks/localizer_coverage.py`` (seeds 300-359, two processes); it reads
the localizer's internals, as a diagnostic may.
"""

from __future__ import annotations

import argparse
from multiprocessing import Pool

import numpy as np

from varskin.localization.peakfit import _predictions, _quiet, solved
from varskin.patch import builtin_patch
from varskin.scene import ProbeModel, Scene
from varskin.simulate import simulate_session, uniform_grid

MODES = ("reported", "first order", "actual", "v_d")


def one(job: tuple[str, str, int, tuple[int, int]]) -> dict:
    pname, probe, seed, grid = job
    p = builtin_patch(pname)
    scene = Scene.create(p, seed, None)
    landed: list[tuple[float, float]] = []
    sample = scene.sample

    def recording(x_mm, y_mm, *args, **kwargs):
        if x_mm is not None:
            landed.append((x_mm, y_mm))
        return sample(x_mm, y_mm, *args, **kwargs)

    scene.sample = recording
    points = uniform_grid(p, *grid)
    s = simulate_session(p, points, probe, seed, scene=scene)
    loc = solved(s.point_logs(), patch=p)
    K, n = loc._k, len(loc.sensors)
    real = np.array(landed) - points
    left = (real - real.mean(axis=0)) - loc._dxy[:K]
    scales = {
        "first order": loc.place_sd_mm,
        "actual": float(np.sqrt(np.mean(left**2))),
        "v_d": float(np.sqrt(np.mean(loc._v_d[:K]))),
    }
    out = {"scales": scales, "factor": loc._sigma_scale}
    out["reported"] = errors_and_sigmas(loc, s.truth)
    loc._sigma_scale = 1.0
    for mode, scale in scales.items():
        loc.place_sd_mm = scale
        with _quiet():
            loc._solve(np.arange(n), np.ones(n, bool))
        out[mode] = errors_and_sigmas(loc, s.truth)
    return out


def errors_and_sigmas(loc, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pr = _predictions(loc)
    ok = np.array([e.status == "ok" for e in pr.estimates])
    err = np.linalg.norm(pr.xy() - truth, axis=1)[ok]
    sig = np.array([e.sigma_mm for e in pr.estimates], dtype=float)[ok]
    return err, sig


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="300-359", help="first-last scene seeds (default 300-359)")
    ap.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    ap.add_argument(
        "--grid", default="20x5", help="probe grid, columns x rows (default 20x5; sparse: 12x3)"
    )
    a = ap.parse_args(argv)
    lo, hi = map(int, a.seeds.split("-"))
    grid = tuple(map(int, a.grid.lower().split("x")))
    print(
        "scene | true sd | first order / actual / v_d sd | factor "
        "| coverage, z50, z95, RMS per mode"
    )
    with Pool(a.jobs) as pool:
        for pname in ("patch_a", "patch_b"):
            for probe in ("robot", "finger"):
                jobs = [(pname, probe, seed, grid) for seed in range(lo, hi + 1)]
                R = pool.map(one, jobs)
                sd = {m: np.mean([r["scales"][m] for r in R]) for m in MODES[1:]}
                factor = np.mean([r["factor"] for r in R])
                parts = []
                for m in MODES:
                    e = np.concatenate([r[m][0] for r in R])
                    sg = np.concatenate([r[m][1] for r in R])
                    z = e / sg
                    parts.append(
                        f"{m} {np.mean(e <= 2 * sg):.3f}, {np.median(z):.2f}, "
                        f"{np.quantile(z, 0.95):.2f}, {np.sqrt(np.mean(e**2)):.3f}"
                    )
                true_sd = ProbeModel.named(probe).placement_sd_mm
                print(
                    f"{pname} {probe} | {true_sd:.2f} | "
                    + " / ".join(f"{sd[m]:.3f}" for m in MODES[1:])
                    + f" | {factor:.2f} | "
                    + " | ".join(parts),
                    flush=True,
                )


if __name__ == "__main__":
    main()

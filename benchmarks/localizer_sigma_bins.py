"""Does a sensor's sigma rank its error? Coverage and RMS error per band of sigma.

Why it exists: issue 3 asks that every `ok` sensor's sigma_mm "means something". The
coverage benchmarks pool all sensors of a scene type, and a pooled 0.95 can hide sigmas
that are too small on some sensors and too large on others, as long as the two balance.
This one sorts the `ok` sensors by their sigma into six bands (quintiles, the top one split
at the 95th percentile), separately for the outermost TX wires (whose maps are one-sided at
the probes' hull) and the rest, and prints per band the RMS error beside what calibrated
sigmas of that band would give (sqrt(mean(2 s^2)), s = sigma / 1.22 per axis), the 2-sigma
coverage and the largest error. It also counts the sensors above 2 mm against the number
the sigmas predict (the sum over sensors of P(|e| > 2 mm) for a 2-D Gaussian error).

Then, per outermost TX wire, how much of its sensors' x error they share: the RMS over
scenes of the wire's mean x error beside the sd within the wire, the sensors beyond 1.5
and 2 mm along x, and how many beyond 2 mm a Gaussian of the wire's RMS x error expects
(docs/benchmarks.md, "Why point 1's last misses stay open").

Run as ``python benchmarks/localizer_sigma_bins.py [--patch patch_b] [--probe finger]
[--seeds 360-559] [--jobs 2]`` (Patch B finger, seeds 360-559, cell centres of the 20 x 5
grid, with and without the patch: about two minutes on the 2-core VM).
"""

from __future__ import annotations

import _one_core  # noqa: F401  (first: pins BLAS to one thread before numpy loads)

# isort: split
import argparse
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from localizer_live import seed_range
from scipy.stats import norm

from varskin.localization import localize
from varskin.patch import builtin_patch
from varskin.predictions import OK, R95_PER_AXIS_SD
from varskin.simulate import simulate_session, uniform_grid


def one_scene(job: tuple[str, str, int, bool]) -> list[tuple[float, float, int, float, int]]:
    """(error mm, sigma mm, TX wire, signed x error mm, seed) of every `ok` sensor of one
    scene."""
    pname, probe, seed, prior = job
    p = builtin_patch(pname)
    s = simulate_session(p, uniform_grid(p, 20, 5), probe, seed)
    pr = localize(s.point_logs(), **({"patch": p} if prior else {}))
    d = pr.xy() - s.truth
    err = np.linalg.norm(d, axis=1)
    return [
        (float(e), est.sigma_mm, sensor.tx, float(dx), seed)
        for est, e, dx, sensor in zip(pr, err, d[:, 0], p.sensors, strict=True)
        if est.status == OK
    ]


def bands(sigma: np.ndarray) -> list[tuple[float, float]]:
    """Six bands of sigma: quintiles, the top one split at the 95th percentile."""
    q = np.percentile(sigma, [0, 20, 40, 60, 80, 95, 100])
    return list(zip(q[:-1], q[1:], strict=True))


def report(label: str, e: np.ndarray, sigma: np.ndarray, n_scenes: int) -> None:
    s = sigma / (R95_PER_AXIS_SD / 2.0)  # per-axis sd the sigma stands for
    p_over = np.exp(-4.0 / (2.0 * s * s))  # P(|e| > 2 mm), 2-D Gaussian
    print(
        f"{label}: {e.size} ok sensors of {n_scenes} scenes; 2-sigma coverage "
        f"{np.mean(e <= 2 * sigma):.3f}; above 2 mm {int(np.sum(e > 2))}, the sigmas "
        f"predict {p_over.sum():.1f}"
    )
    edges = bands(sigma)
    for i, (lo, hi) in enumerate(edges):
        b = (sigma >= lo) & ((sigma < hi) | (i == len(edges) - 1))
        calibrated = np.sqrt(np.mean(2.0 * s[b] ** 2))
        print(
            f"  sigma {lo:.2f}-{hi:.2f} mm, {b.sum():4d} sensors: RMS error "
            f"{np.sqrt(np.mean(e[b] ** 2)):.2f} mm (calibrated {calibrated:.2f}), "
            f"2-sigma coverage {np.mean(e[b] <= 2 * sigma[b]):.3f}, max {e[b].max():.2f} mm"
        )


def wire_report(tx: np.ndarray, ex: np.ndarray, seed: np.ndarray, last: int) -> None:
    """The outermost wires' x error: what a wire's sensors share, and its tail."""
    inner = (tx > 0) & (tx < last)
    print(f"  inner wires: x error RMS {np.sqrt(np.mean(ex[inner] ** 2)):.3f} mm")
    for wire in (0, last):
        m = tx == wire
        scenes = np.unique(seed[m])
        by = [ex[m & (seed == sd)] for sd in scenes]
        means = np.array([b.mean() for b in by])
        within = np.sqrt(np.mean([b.var(ddof=1) for b in by if b.size > 1]))
        rms = np.sqrt(np.mean(ex[m] ** 2))
        shared = np.sqrt(np.mean(means**2))
        beyond = [int(np.sum(np.abs(ex[m]) > t)) for t in (1.5, 2.0)]
        print(
            f"  TX{wire}: {scenes.size} wires, RMS of a wire's mean x error {shared:.3f} mm, "
            f"sd within a wire {within:.3f} mm; |x error| > 1.5 mm: {beyond[0]}, > 2 mm: "
            f"{beyond[1]} of {m.sum()} sensors, a Gaussian of RMS {rms:.3f} mm expects "
            f"{m.sum() * 2 * norm.sf(2 / rms):.2f}"
        )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--patch", choices=("patch_a", "patch_b"), default="patch_b", help="default patch_b"
    )
    ap.add_argument("--probe", choices=("robot", "finger"), default="finger", help="default finger")
    ap.add_argument("--seeds", type=seed_range, default=range(360, 560), help="default 360-559")
    ap.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    a = ap.parse_args(argv)
    last = len(builtin_patch(a.patch).tx_x_mm) - 1
    with ProcessPoolExecutor(a.jobs) as ex:
        for prior in (True, False):
            jobs = [(a.patch, a.probe, seed, prior) for seed in a.seeds]
            rows = np.array([r for scene in ex.map(one_scene, jobs) for r in scene])
            e, sigma, ex_mm = rows[:, 0], rows[:, 1], rows[:, 3]
            tx, scene = rows[:, 2].astype(int), rows[:, 4].astype(int)
            edge = (tx == 0) | (tx == last)
            given = "patch given" if prior else "no patch"
            for where, m in (("outermost TX wires", edge), ("other wires", ~edge)):
                report(f"{a.patch} {a.probe}, {given}, {where}", e[m], sigma[m], len(a.seeds))
            wire_report(tx, ex_mm, scene, last)


if __name__ == "__main__":
    main()

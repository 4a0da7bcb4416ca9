"""peakfit's two batch solvers, ``alternate`` (the default) and ``joint``, seed by seed.

Why it exists: the alternate solver stops after 4 alternations that have not settled; the
joint solver takes joint Gauss-Newton steps over sensors and touches. This compares both on
the issue's per-scene targets (robot RMS <= 0.3 mm, finger RMS <= 0.6 x the paper method's,
no sensor above 2 mm), 2-sigma coverage, and time against the paper method timed in the same
run. Scenes: simulated Patch A and B, 20 x 5 grid, robot and finger, with the layout prior
(as ``varskin localize --patch`` and the demo use it).

Run as ``python benchmarks/localizer_solver.py [--seeds N] [--convergence] [--board]`` (one core: BLAS threads are
pinned to 1). The paper method's accuracy reference runs at ppcm 16 (within 0.02 mm of
ppcm 128 on these scenes, docs/benchmarks.md); its time at ppcm 128 on the first 5 seeds.
"""

from __future__ import annotations

import _one_core  # noqa: F401  (first: pins BLAS to one thread before numpy loads)

# isort: split
import argparse
import time

import numpy as np

from varskin.evaluate import rms_n_minus_1 as rms  # the paper's sqrt(sum e^2 / (N - 1))
from varskin.localization import localize, peakfit
from varskin.patch import builtin_patch
from varskin.predictions import OK
from varskin.simulate import simulate_session, uniform_grid

SOLVERS = ("alternate", "joint")


def timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, (time.perf_counter() - t0) * 1000.0


def convergence(rounds_far: int = 40) -> None:
    """How far each solver's default rounds stop from where many more rounds go (mm)."""
    patch = builtin_patch("patch_b")
    for probe in ("robot", "finger"):
        for seed in (0, 1):
            logs = simulate_session(patch, uniform_grid(patch, 20, 5), probe, seed).point_logs()
            parts = []
            for solver in SOLVERS:
                default = peakfit.SOLVER_ROUNDS[solver]
                near = localize(logs, patch=patch, solver=solver)
                peakfit.SOLVER_ROUNDS[solver] = rounds_far
                far = localize(logs, patch=patch, solver=solver)
                peakfit.SOLVER_ROUNDS[solver] = default
                d = np.hypot(*(near.xy() - far.xy()).T)
                d = d[np.isfinite(d)]
                parts.append(
                    f"{solver} {default} rounds: median {np.median(d):.3f}, max {d.max():.3f} mm"
                )
            print(f"Patch B {probe} seed {seed}, from {rounds_far} rounds: " + "; ".join(parts))


def board(repeats: int = 2) -> None:
    """The full board scene of ``localizer_scale.py``: batch time of both solvers."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from localizer_scale import full_board

    patch = full_board()
    sc = simulate_session(patch, uniform_grid(patch, 50, 20), probe="robot", seed=0)
    logs = sc.point_logs()
    for solver in SOLVERS:
        runs = [timed(localize, logs, solver=solver) for _ in range(repeats)]
        e = np.linalg.norm(runs[-1][0].xy() - sc.truth, axis=1)
        print(
            f"full board, {solver}: batch median {np.median([r[1] for r in runs]) / 1000:.2f} s "
            f"over {repeats}; {int(np.isfinite(e).sum())} located, median error "
            f"{np.nanmedian(e):.2f} mm"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=60, help="seeds from 300; default 60")
    ap.add_argument(
        "--convergence",
        action="store_true",
        help="instead: distance of each solver's result from 40 rounds (Patch B, seeds 0-1)",
    )
    ap.add_argument(
        "--board", action="store_true", help="instead: full-board batch time of both solvers"
    )
    args = ap.parse_args()
    if args.board:
        board()
        return
    if args.convergence:
        convergence()
        return
    seeds = range(300, 300 + args.seeds)
    print(
        "| scene | solver | RMS median | worst RMS | seeds at target | seeds with a sensor > 2 mm "
        "| unlocated | 2-sigma coverage | time median | time / paper (ppcm 128) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for pname in ("patch_a", "patch_b"):
        patch = builtin_patch(pname)
        for probe in ("robot", "finger"):
            rows = {
                s: {"rms": [], "ratio": [], "over2": 0, "lost": 0, "cov": [], "ms": []}
                for s in SOLVERS
            }
            paper_ms = []
            for i, seed in enumerate(seeds):
                sc = simulate_session(patch, uniform_grid(patch, 20, 5), probe, seed)
                logs = sc.point_logs()
                ep = np.linalg.norm(localize(logs, method="paper", ppcm=16).xy() - sc.truth, axis=1)
                ref = rms(ep[np.isfinite(ep)])
                if i < 5:
                    paper_ms.append(timed(localize, logs, method="paper", ppcm=128)[1])
                for solver in SOLVERS:
                    pred, ms = timed(localize, logs, patch=patch, solver=solver)
                    e = np.linalg.norm(pred.xy() - sc.truth, axis=1)
                    sig = np.array([p.sigma_mm if p.status == OK else np.nan for p in pred])
                    ok = np.isfinite(e)
                    r = rows[solver]
                    r["rms"].append(rms(e[ok]))
                    r["ratio"].append(rms(e[ok]) / ref)
                    r["over2"] += int(e[ok].max() > 2.0)
                    r["lost"] += int((~ok).sum())
                    r["cov"] += list(e[ok] <= 2.0 * sig[ok])
                    r["ms"].append(ms)
            for solver in SOLVERS:
                r = rows[solver]
                rm = np.array(r["rms"])
                if probe == "robot":
                    target = f"{(rm <= 0.3).sum()}/{len(rm)} (RMS <= 0.3 mm)"
                else:
                    ra = np.array(r["ratio"])
                    target = (
                        f"{(ra <= 0.6).sum()}/{len(ra)} (<= 0.6x paper; median {np.median(ra):.2f},"
                        f" worst {ra.max():.2f})"
                    )
                med_ms = float(np.median(r["ms"]))
                print(
                    f"| {pname} {probe} | {solver} | {np.median(rm):.3f} mm | {rm.max():.3f} mm "
                    f"| {target} | {r['over2']}/{len(rm)} | {r['lost']} | {np.mean(r['cov']):.3f} "
                    f"| {med_ms:.0f} ms | {med_ms / float(np.median(paper_ms)):.3f}x |",
                    flush=True,
                )


if __name__ == "__main__":
    main()

"""How long the paper's method takes: 30 sensors x 100 point logs (Patch B, 20x5, finger).

This is the yardstick the next localizer must beat. For each resolution (pixels per cm)
it prints the median of repeated runs of ``localize(logs, method="paper", ppcm=...)`` and
the RMS error against the simulated truth.

    python benchmarks/paper_speed.py [--runs 5] [--ppcm 4 16 64 128]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from varskin.evaluate import rms_n_minus_1
from varskin.localization import localize
from varskin.patch import builtin_patch
from varskin.simulate import simulate_session, uniform_grid


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="timed runs per resolution; default 5")
    ap.add_argument("--ppcm", type=float, nargs="+", default=[4, 16, 64, 128])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    patch = builtin_patch("patch_b")
    session = simulate_session(patch, uniform_grid(patch, 20, 5), "finger", args.seed)
    logs = session.point_logs()
    print(
        f"paper method, {logs.n_sensors} sensors x {len(logs)} point logs, eta 0.65, seed {args.seed}"
    )
    print(f"{'ppcm':>6} {'pixels':>9} {'median s':>9} {'min s':>7} {'RMS mm':>7}")
    for ppcm in args.ppcm:
        times = []
        for _ in range(args.runs):
            t0 = time.perf_counter()
            predictions = localize(logs, method="paper", ppcm=ppcm)
            times.append(time.perf_counter() - t0)
        errors = np.hypot(*(predictions.xy() - session.truth).T)
        x0, y0, x1, y1 = predictions.params["area"]
        pixels = (int((x1 - x0) * ppcm / 10 + 1e-9) + 1) * (int((y1 - y0) * ppcm / 10 + 1e-9) + 1)
        print(
            f"{ppcm:>6g} {pixels:>9d} {statistics.median(times):>9.3f} {min(times):>7.3f} "
            f"{rms_n_minus_1(errors):>7.3f}"
        )


if __name__ == "__main__":
    main()

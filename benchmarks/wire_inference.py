"""How often peakfit infers the wires right when no patch is given, and how often it declines.

Why it exists: the layout prior without a patch rests on ``_wire_inference.infer_wires``.
A wrong grouping would pull sensors towards the wrong wire, so the inference must decline
rather than guess. This runs the default no-patch batch solve on fresh seeds, keeps the
groups it inferred (its last call of ``infer_wires``), and compares them with the
simulator's wires: "right" when every pair of sensors with a wire is together exactly
when the truth says so, "wrong" otherwise, "declined" when no grid was clear; plus the
share of sensors given a TX and an RX wire.

Run as ``python benchmarks/wire_inference.py [--seeds 300:360] [--grids 20x5,12x3,scatter]``
(about a minute).
"""

from __future__ import annotations

import _one_core  # noqa: F401  (first: pins BLAS to one thread before numpy loads)

# isort: split
import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from varskin.localization import _statuses, localize
from varskin.localization._wire_inference import infer_wires
from varskin.patch import builtin_patch
from varskin.simulate import simulate_session, uniform_grid


def same_partition(found: np.ndarray, truth: np.ndarray) -> bool:
    m = found >= 0
    return bool(
        ((found[m][:, None] == found[m][None, :]) == (truth[m][:, None] == truth[m][None, :])).all()
    )


def _spy(seen: list):
    """``infer_wires`` as the default solve calls it, keeping each answer."""

    def spy(*args):
        seen.append(infer_wires(*args))
        return seen[-1]

    return spy


def _points(patch, grid: str, seed: int) -> np.ndarray:
    """A grid "NXxNY", or "scatter": 100 uniform random touches 3 mm inside the patch."""
    if grid == "scatter":
        rng = np.random.default_rng([seed, 7])
        lo, hi = (3.0, 3.0), (patch.length_mm - 3.0, patch.width_mm - 3.0)
        return rng.uniform(lo, hi, (100, 2))
    nx, ny = (int(v) for v in grid.split("x"))
    return uniform_grid(patch, nx, ny)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="300:360", help="first:end (end excluded), default 300:360")
    ap.add_argument(
        "--grids",
        default="20x5,12x3,scatter",
        help="probe grids NXxNY or scatter (100 random touches), default 20x5,12x3,scatter",
    )
    args = ap.parse_args()
    a, b = (int(v) for v in args.seeds.split(":"))
    print("| grid | patch | probe | right | wrong | declined | with a TX wire | with an RX wire |")
    print("|---|---|---|---|---|---|---|---|")
    for grid in args.grids.split(","):
        for pname in ("patch_a", "patch_b"):
            patch = builtin_patch(pname)
            tx = np.array([s.tx for s in patch.sensors])
            rx = np.array([s.rx for s in patch.sensors])
            for probe in ("robot", "finger"):
                count = {"right": 0, "wrong": 0, "declined": 0}
                share_x, share_y = [], []
                for seed in range(a, b):
                    s = simulate_session(patch, _points(patch, grid, seed), probe, seed)
                    seen = []
                    _statuses.infer_wires = _spy(seen)
                    try:
                        localize(s.point_logs())
                    finally:
                        _statuses.infer_wires = infer_wires
                    found = seen[-1]
                    if found is None:
                        count["declined"] += 1
                        continue
                    gx, gy = found
                    right = same_partition(gx, tx) and same_partition(gy, rx)
                    count["right" if right else "wrong"] += 1
                    share_x.append((gx >= 0).mean())
                    share_y.append((gy >= 0).mean())
                sx = f"{np.median(share_x):.2f} (min {min(share_x):.2f})" if share_x else "-"
                sy = f"{np.median(share_y):.2f} (min {min(share_y):.2f})" if share_y else "-"
                print(
                    f"| {grid} | {pname[-1].upper()} | {probe} | {count['right']} | {count['wrong']} "
                    f"| {count['declined']} | {sx} | {sy} |",
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())

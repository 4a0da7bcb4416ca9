"""How long the session report's point-log mosaic takes to draw, Patch B and a full board.

``varskin calibrate`` writes ``point_log_maps.png`` at the end of every session (and
``varskin report`` again), so its cost is paid per session, and on a full Muca board
(252 sensors, 1,000 robot touches, the scale of issue 3 point 4) it was the slowest step
of the finish. Median of ``--repeat`` draws (PNG written to a temporary folder).

Run as ``python benchmarks/report_plots.py``.
"""

import _one_core  # noqa: F401  (first: pins BLAS to one thread before numpy loads)

# isort: split
import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from localizer_scale import full_board

from varskin.localization import localize
from varskin.patch import builtin_patch
from varskin.plots import plot_point_log_maps
from varskin.simulate import simulate_session, uniform_grid


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="draws per case (default 3)")
    a = ap.parse_args(argv)
    cases = [
        ("Patch B, 30 sensors x 100 finger touches", builtin_patch("patch_b"), (20, 5), "finger"),
        ("full board, 252 sensors x 1000 robot touches", full_board(), (50, 20), "robot"),
    ]
    with tempfile.TemporaryDirectory() as tmp:
        for label, patch, grid, probe in cases:
            logs = simulate_session(patch, uniform_grid(patch, *grid), probe, seed=0).point_logs()
            pred = localize(logs)
            times = []
            for _ in range(a.repeat):
                t0 = time.perf_counter()
                out = plot_point_log_maps(
                    logs, Path(tmp) / "maps.png", pred, (patch.length_mm, patch.width_mm)
                )
                times.append(time.perf_counter() - t0)
            print(
                f"{label}: median {np.median(times):.2f} s over {a.repeat} "
                f"({out.stat().st_size / 1e6:.1f} MB PNG)",
                flush=True,
            )


if __name__ == "__main__":
    main()

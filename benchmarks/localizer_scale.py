"""Scale of the default localizer: a full Muca board and a live session.

Run as ``python benchmarks/localizer_scale.py [--repeats N]``. One core: BLAS threads are
pinned to 1 before numpy loads. Reports medians of repeated runs:

* full board (21 TX x 12 RX = 252 sensors) with 1,000 point logs (a 50 x 20 robot grid on
  a 300 x 200 mm patch): batch solve time (target <= 2 s; also without the error-bar
  check, ``calibrate_sigma=False``, timed in the same run), peak memory (target <= 500
  MB: the max RSS of ``varskin localize`` run on the board's point-log CSV in a child
  process, interpreter and imports included, and the peak Python heap of the solve alone,
  by tracemalloc), and the time of one live ``Localizer.update`` after 1,000 logs (target
  <= 20 ms);
* Patch B (30 sensors) with 100 point logs, robot and finger, with the layout prior as
  ``varskin calibrate`` runs it: one ``update`` (target <= 5 ms) and the batch solve, and
  the paper method (eta 0.65, 128 ppcm) on the same logs in the same run, so that each
  run says how fast its machine was (this VM's speed varies from day to day);
* a whole live session (board and Patch B): every update timed from the first log, the
  periodic full re-solves included (median, amortized mean, max), and the distance of the
  last update's own estimates from the batch solve.
"""

from __future__ import annotations

import _one_core  # noqa: F401  (first: pins BLAS to one thread before numpy loads)

# isort: split
import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from varskin.localization import paper, peakfit
from varskin.patch import builtin_patch, patch_from_dict
from varskin.pointlog_csv import write_point_logs_csv
from varskin.predictions import OK
from varskin.simulate import simulate_session, uniform_grid


def full_board():
    tx = [7.0 + 13.6 * i for i in range(21)]
    rx = [8.0 + 16.7 * j for j in range(12)]
    return patch_from_dict(
        {"name": "muca_full", "size_mm": [300.0, 200.0], "tx_x_mm": tx, "rx_y_mm": rx},
        "<full board>",
    )


# Runs the CLI and then prints the process's own peak RSS (kB). VmHWM, not ru_maxrss: on
# Linux ru_maxrss carries over the forking parent's RSS across exec.
_PEAK_RSS_CHILD = """
import runpy, sys
sys.argv = ["varskin", *sys.argv[1:]]
try:
    runpy.run_module("varskin", run_name="__main__")
finally:
    with open("/proc/self/status") as f:
        print(next(x for x in f if x.startswith("VmHWM:")).split()[1], file=sys.stderr)
"""


def localize_cli_rss_mb(logs) -> float:
    """Peak RSS (MB) of ``varskin localize`` on ``logs`` written as a point-log CSV: what a
    user's batch solve of this recording costs, apart from this script's simulation."""
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "board.csv"
        write_point_logs_csv(csv, logs)
        out = subprocess.run(
            [sys.executable, "-c", _PEAK_RSS_CHILD, "localize", str(csv), "-o", str(csv) + ".p"],
            check=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            # This checkout's varskin, as for this script (a worktree, or no install).
            env={**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path[1:]])},
        )
    return int(out.stderr.split()[-1]) / 1024.0


def batch_times(logs, repeats: int, **params) -> tuple:
    """The default batch solve's result and times (s), and the times without the error-bar
    check (``calibrate_sigma=False``), interleaved so both see the same machine."""
    checked, first = [], []
    pred = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        pred = peakfit.localize(logs, **params)
        checked.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        peakfit.localize(logs, calibrate_sigma=False, **params)
        first.append(time.perf_counter() - t0)
    return pred, checked, first


def paper_times(logs, repeats: int) -> list[float]:
    """The paper method's batch solve times (s) on the same logs: the reference."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        paper.localize(logs)
        times.append(time.perf_counter() - t0)
    return times


def live_update_ms(logs, n_warm: int, n_timed: int, **params) -> list[float]:
    """Feed the first logs, then time each of the following updates."""
    loc = peakfit.Localizer(logs.sensors, rest=logs.rest, rest_sd=logs.rest_sd, **params)
    all_logs = list(logs.logs())
    for log in all_logs[:n_warm]:
        loc.update(log)
    # Bring the live state to the doubling checkpoint first, as a session would have.
    loc.result()
    loc._next_full = 10 * len(all_logs)
    times = []
    for log in all_logs[n_warm : n_warm + n_timed]:
        t0 = time.perf_counter()
        loc.update(log)
        times.append((time.perf_counter() - t0) * 1000.0)
    return times


def live_session(logs, **params) -> tuple[list[float], float, float]:
    """A whole live session from the first log: every update timed, the periodic full
    re-solves (at 8, 16, 32, ... logs) included; then how far the last update's own
    estimates are from the batch solve (median and max over sensors located by both, mm)."""
    loc = peakfit.Localizer(logs.sensors, rest=logs.rest, rest_sd=logs.rest_sd, **params)
    times = []
    live = None
    for log in logs.logs():
        t0 = time.perf_counter()
        live = loc.update(log)
        times.append((time.perf_counter() - t0) * 1000.0)
    batch = peakfit.localize(logs, **params)
    d = np.hypot(*(live.xy() - batch.xy()).T)
    d = d[np.isfinite(d)]
    return times, float(np.median(d)), float(np.max(d))


def print_session(label: str, times: list[float], med_d: float, max_d: float) -> None:
    print(
        f"{label}: whole live session of {len(times)} updates: median {statistics.median(times):.1f} ms, "
        f"mean incl. re-solves {statistics.fmean(times):.1f} ms (amortized), max {max(times):.0f} ms; "
        f"last update vs batch: median {med_d:.3f} mm, max {max_d:.3f} mm"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="batch repeats; default 3")
    args = ap.parse_args()

    board = full_board()
    s = simulate_session(board, uniform_grid(board, 50, 20), probe="robot", seed=0)
    logs = s.point_logs()
    print(f"full board: {logs.n_sensors} sensors x {len(logs)} point logs")
    pred, times, first = batch_times(logs, args.repeats)
    e = np.hypot(*(pred.xy() - s.truth).T)
    n_ok = sum(p.status == OK for p in pred)
    print(
        f"  batch solve: median {statistics.median(times):.2f} s over {args.repeats} "
        f"(target <= 2 s); without the error-bar check {statistics.median(first):.2f} s "
        f"({statistics.median(times) / statistics.median(first):.1f}x)"
    )
    print(
        f"  accuracy: {n_ok}/{logs.n_sensors} ok, median error {np.nanmedian(e):.2f} mm, "
        f"max {np.nanmax(e):.2f} mm"
    )
    tracemalloc.start()
    peakfit.localize(logs)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    print(
        f"  peak memory of `varskin localize` on the board's CSV (child process, max RSS): "
        f"{localize_cli_rss_mb(logs):.0f} MB (target <= 500 MB); peak heap of the solve "
        f"alone: {peak / 1e6:.0f} MB"
    )
    upd = live_update_ms(logs, 990, 10)
    print(
        f"  live update after 990 logs: median {statistics.median(upd):.1f} ms, "
        f"max {max(upd):.1f} ms over {len(upd)} (target <= 20 ms)"
    )

    print_session("  full board", *live_session(logs))

    # Patch B as `varskin calibrate` runs it: the patch's wires and design feed the layout
    # prior, which every update re-applies.
    patch = builtin_patch("patch_b")
    for probe in ("robot", "finger"):
        s = simulate_session(patch, uniform_grid(patch, 20, 5), probe=probe, seed=0)
        logs = s.point_logs()
        upd = []
        for _ in range(args.repeats):
            upd += live_update_ms(logs, 80, 20, patch=patch)
        _, t, first = batch_times(logs, args.repeats, patch=patch)
        ref = paper_times(logs, args.repeats)
        print(
            f"Patch B {probe}: 30 sensors x 100 point logs, layout prior: live update "
            f"median {statistics.median(upd):.1f} ms, max {max(upd):.1f} ms over {len(upd)} "
            f"(target <= 5 ms); batch solve median {1000 * statistics.median(t):.0f} ms, "
            f"without the error-bar check {1000 * statistics.median(first):.0f} ms "
            f"({statistics.median(t) / statistics.median(first):.1f}x)"
        )
        print(
            f"  the paper method on the same logs: median {1000 * statistics.median(ref):.0f} "
            f"ms; one update is {statistics.median(upd) / (1000 * statistics.median(ref)):.4f}x "
            f"that, the batch solve {statistics.median(t) / statistics.median(ref):.2f}x"
        )
        print_session(f"Patch B {probe}", *live_session(logs, patch=patch))
    return 0


if __name__ == "__main__":
    sys.exit(main())

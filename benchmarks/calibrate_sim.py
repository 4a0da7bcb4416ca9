"""The main job, measured: `varskin calibrate` on the simulated rig, end to end.

Each repeat runs the command in a fresh process (controller start-up, board, 100 touches,
live updates, final solve, report), then reads the session file: wall time, the rig-time
estimate, retries, and the error of the final estimate against the simulated rig's hidden
layout. The paper's method is run on the same session's point logs and both final solves
are timed here, in this process, one after the other.

    python benchmarks/calibrate_sim.py --repeats 3
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from varskin.session import final_estimate, rms_error_mm
from varskin.store import SessionStore


def _timed(fn, *args, repeats: int = 3):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn(*args)
        times.append(time.perf_counter() - t0)
    return out, statistics.median(times)


def one_run(tmp: Path, i: int, launch: str | None) -> dict:
    db = tmp / f"run{i}.db"
    cmd = [sys.executable, "-m", "varskin", "calibrate", "-o", str(db)]
    if launch:
        cmd.insert(4, launch)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    with SessionStore.open(db) as store:
        meta = store.meta()
        logs = store.point_logs()
        attempts = store.attempts()
        patch = store.patch()
    truth = np.asarray(meta["truth_xy"], float)
    peak, t_peak = _timed(final_estimate, logs, "peakfit", patch)
    paper, t_paper = _timed(final_estimate, logs, "paper", patch)
    rms_peak, n_peak = rms_error_mm(peak, truth)
    rms_paper, n_paper = rms_error_mm(paper, truth)
    return {
        "wall_s": wall,
        "session_s": float(meta["wall_s"]),
        "rig_s": float(meta["rig_time_estimate_s"]),
        "logs": len(logs),
        "retries": len(attempts) - len(logs),
        "rms_peakfit": rms_peak,
        "located_peakfit": n_peak,
        "rms_paper": rms_paper,
        "located_paper": n_paper,
        "t_peakfit": t_peak,
        "t_paper": t_paper,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="fresh runs (default: 3)")
    ap.add_argument("--launch", help="launch file (default: launch/sim.yaml)")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeats):
            r = one_run(Path(tmp), i, args.launch)
            rows.append(r)
            print(
                f"run {i}: wall {r['wall_s']:.1f} s (session {r['session_s']:.1f} s), rig estimate "
                f"{r['rig_s'] / 60:.2f} min, {r['logs']} logs, {r['retries']} retries; RMS peakfit "
                f"{r['rms_peakfit']:.3f} mm ({r['located_peakfit']}/30) in {r['t_peakfit']:.3f} s, "
                f"paper {r['rms_paper']:.3f} mm ({r['located_paper']}/30) in {r['t_paper']:.3f} s",
                flush=True,
            )
    med = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
    print(
        f"median of {len(rows)}: wall {med['wall_s']:.1f} s, rig estimate {med['rig_s'] / 60:.2f} "
        f"min, retries {med['retries']:g}; RMS peakfit {med['rms_peakfit']:.3f} mm vs paper "
        f"{med['rms_paper']:.3f} mm ({med['rms_peakfit'] / med['rms_paper']:.2f}x); final solve "
        f"peakfit {med['t_peakfit']:.3f} s vs paper {med['t_paper']:.3f} s "
        f"({med['t_peakfit'] / med['t_paper']:.2f}x)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The main job, measured: `varskin calibrate` on the simulated rig, end to end.

Each run is the command in a fresh process (controller start-up, board, 100 touches, live
updates, final solve, report); then the session file is read: wall time, the rig-time
estimate, retries, and the error of the final estimate against the simulated rig's hidden
layout, with its 2-sigma coverage. The paper's method is run on the same session's point
logs, and both final solves are timed here, in this process, one after the other. The same
stored frames are also cut again as sessions before 2026-11-29 cut them, each touch against
its own baseline window instead of the session's rest (``touch_window``), and localized the
same way: what that choice costs, on the very same touches.

    python benchmarks/calibrate_sim.py --repeats 3           # launch/sim.yaml (sim seed 0)
    python benchmarks/calibrate_sim.py --seeds 1-10 --jobs 2 # one scene per sim seed
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import yaml
from localizer_live import seed_range

from varskin.pointlogs import PointLogs
from varskin.predictions import OK
from varskin.replay import recut_logs
from varskin.session import final_estimate, rms_error_mm, window_config
from varskin.store import SessionStore
from varskin.touch_window import BASELINE

REPO = Path(__file__).resolve().parents[1]


def _timed(fn, *args, repeats: int = 3):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn(*args)
        times.append(time.perf_counter() - t0)
    return out, statistics.median(times)


def launch_for_seed(tmp: Path, seed: int) -> str:
    """launch/sim.yaml with another simulated scene (``sim.seed``), as a file in ``tmp``."""
    data = yaml.safe_load((REPO / "launch" / "sim.yaml").read_text())
    data["patch"] = str((REPO / "launch" / data["patch"]).resolve())
    data["sim"]["seed"] = seed
    path = tmp / f"sim_seed{seed}.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def coverage(pred, truth: np.ndarray) -> tuple[int, int]:
    """(`ok` sensors within 2 sigma of the truth, `ok` sensors)."""
    hits = n = 0
    for est, xy in zip(pred, truth, strict=True):
        if est.status == OK:
            n += 1
            hits += bool(np.hypot(est.x_mm - xy[0], est.y_mm - xy[1]) <= 2 * est.sigma_mm)
    return hits, n


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
        old = dataclasses.replace(window_config(store), reference=BASELINE)
        recut = recut_logs(store, patch, old)
    if recut is None:
        raise RuntimeError(f"{db}: its point logs cannot be cut again from its frames")
    truth = np.asarray(meta["truth_xy"], float)
    peak, t_peak = _timed(final_estimate, logs, "peakfit", patch)
    paper, t_paper = _timed(final_estimate, logs, "paper", patch)
    old_logs = PointLogs.from_logs(
        logs.sensors, [log for _, log, _ in recut], rest=logs.rest, rest_sd=logs.rest_sd
    )
    base = final_estimate(old_logs, "peakfit", patch)
    rms_peak, n_peak = rms_error_mm(peak, truth)
    rms_paper, n_paper = rms_error_mm(paper, truth)
    rms_base, n_base = rms_error_mm(base, truth)
    return {
        "wall_s": wall,
        "session_s": float(meta["wall_s"]),
        "rig_s": float(meta["rig_time_estimate_s"]),
        "logs": len(logs),
        "retries": len(attempts) - len(logs),
        "rms_peakfit": rms_peak,
        "located_peakfit": n_peak,
        "cover_peakfit": coverage(peak, truth),
        "rms_baseline": rms_base,
        "located_baseline": n_base,
        "cover_baseline": coverage(base, truth),
        "rms_paper": rms_paper,
        "located_paper": n_paper,
        "t_peakfit": t_peak,
        "t_paper": t_paper,
    }


def _run(job: tuple[str, int, int | None, str | None]) -> dict:
    tmp, i, seed, launch = job
    if seed is not None:
        launch = launch_for_seed(Path(tmp), seed)
    return one_run(Path(tmp), i, launch)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="fresh runs (default: 3)")
    ap.add_argument("--launch", help="launch file (default: launch/sim.yaml)")
    ap.add_argument(
        "--seeds",
        type=seed_range,
        help="one run of launch/sim.yaml per simulated scene (sim.seed), e.g. 1-10, "
        "instead of --repeats runs of one launch file",
    )
    ap.add_argument(
        "--jobs", type=int, default=1, help="runs side by side (default: 1; times are then shared)"
    )
    args = ap.parse_args(argv)
    if args.seeds is not None and args.launch:
        ap.error("--seeds runs launch/sim.yaml; give no --launch")
    with tempfile.TemporaryDirectory() as tmp:
        if args.seeds is None:
            jobs = [(tmp, i, None, args.launch) for i in range(args.repeats)]
        else:
            jobs = [(tmp, i, seed, None) for i, seed in enumerate(args.seeds)]
        with ProcessPoolExecutor(args.jobs) as pool:
            rows = list(pool.map(_run, jobs))
    for (_, i, seed, _), r in zip(jobs, rows, strict=True):
        name = f"run {i}" if seed is None else f"seed {seed}"
        print(
            f"{name}: wall {r['wall_s']:.1f} s (session {r['session_s']:.1f} s), rig estimate "
            f"{r['rig_s'] / 60:.2f} min, {r['logs']} logs, {r['retries']} retries; RMS peakfit "
            f"{r['rms_peakfit']:.3f} mm ({r['located_peakfit']}/30) in {r['t_peakfit']:.3f} s, "
            f"against baselines {r['rms_baseline']:.3f} mm ({r['located_baseline']}/30), "
            f"paper {r['rms_paper']:.3f} mm ({r['located_paper']}/30) in {r['t_paper']:.3f} s",
        )
    med = {k: statistics.median(r[k] for r in rows) for k in rows[0] if "cover" not in k}
    worst = {k: max(r[k] for r in rows) for k in ("rms_peakfit", "rms_baseline")}
    over = {k: sum(r[k] > 0.3 for r in rows) for k in ("rms_peakfit", "rms_baseline")}
    cover = {
        k: sum(r[k][0] for r in rows) / max(sum(r[k][1] for r in rows), 1)
        for k in ("cover_peakfit", "cover_baseline")
    }
    print(
        f"median of {len(rows)}: wall {med['wall_s']:.1f} s, rig estimate {med['rig_s'] / 60:.2f} "
        f"min, retries {med['retries']:g}; RMS peakfit {med['rms_peakfit']:.3f} mm (worst "
        f"{worst['rms_peakfit']:.3f}, {over['rms_peakfit']} above 0.3 mm, 2 sigma covers "
        f"{cover['cover_peakfit']:.3f}) vs paper {med['rms_paper']:.3f} mm "
        f"({med['rms_peakfit'] / med['rms_paper']:.2f}x); final solve peakfit "
        f"{med['t_peakfit']:.3f} s vs paper {med['t_paper']:.3f} s "
        f"({med['t_peakfit'] / med['t_paper']:.2f}x)"
    )
    print(
        f"the same frames, each touch against its own baseline (before 2026-11-29): RMS "
        f"{med['rms_baseline']:.3f} mm (worst {worst['rms_baseline']:.3f}, "
        f"{over['rms_baseline']} above 0.3 mm, 2 sigma covers {cover['cover_baseline']:.3f})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""How long reading a large point-log CSV takes: 100,000 frame rows x 30 sensors.

The file is a simulated Patch B session (baseline + ~2,200 touches of 40-50 frames each,
with t_s and force_n), written by ``write_samples_csv``. Prints rows, file size and the
median of 5 loads.

    python benchmarks/csv_load.py [--rows 100000] [--runs 5]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from varskin.patch import builtin_patch
from varskin.pointlog_csv import read_point_logs, write_samples_csv
from varskin.simulate import simulate_session


def make_file(path: Path, rows: int, seed: int = 0) -> int:
    patch = builtin_patch("patch_b")
    rng = np.random.default_rng(seed)
    touches = rows // 45 + 1
    points = np.column_stack(
        [rng.uniform(0, patch.length_mm, touches), rng.uniform(0, patch.width_mm, touches)]
    )
    session = simulate_session(patch, points, "robot", seed)
    keep = rows - len(session.baseline)
    session.touch, session.xy_mm = session.touch[:keep], session.xy_mm[:keep]
    session.samples, session.t_s = session.samples[:keep], session.t_s[:keep]
    session.force_n = session.force_n[:keep]
    write_samples_csv(path, session)
    return len(session.baseline) + keep


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--rows", type=int, default=100_000, help="data rows in the file; default 100000"
    )
    ap.add_argument("--runs", type=int, default=5, help="timed loads; default 5")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "big.csv"
        rows = make_file(path, args.rows)
        times = []
        for _ in range(args.runs):
            t0 = time.perf_counter()
            logs = read_point_logs(path)
            times.append(time.perf_counter() - t0)
        size_mb = path.stat().st_size / 1e6
    print(f"rows {rows}  sensors {logs.n_sensors}  touches {len(logs)}  file {size_mb:.1f} MB")
    print(
        f"read_point_logs: median {statistics.median(times):.3f} s over {args.runs} runs "
        f"(min {min(times):.3f}, max {max(times):.3f})"
    )


if __name__ == "__main__":
    main()

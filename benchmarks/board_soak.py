"""Soak: record the simulated board through a pty at 100 frames/s and count lost frames
(target 0). The board writes its own frame number into the unwired cell (20, 11); any hole
in that sequence is a lost frame. The board runs in a separate process.

    python benchmarks/board_soak.py --minutes 10 [--rate 100]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _board_simproc import SimProcess

from varskin.board.recorder import Recorder
from varskin.board.simboard import STAMP_CELL
from varskin.progress import Progress


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=100.0, help="simulated frames/s")
    args = ap.parse_args()
    stamps: list[int] = []
    times: list[float] = []

    def keep(event) -> None:
        if hasattr(event, "cells"):
            stamps.append(int(event.cells[STAMP_CELL]))
            times.append(event.t)

    seconds = args.minutes * 60
    with SimProcess(args.rate) as sim:
        rec = Recorder(sim.path)
        rec.subscribe(keep)
        with rec:
            rec.wait_for_frame(5.0)
            t0 = time.monotonic()
            with Progress(int(seconds), "soak") as bar:
                while (elapsed := time.monotonic() - t0) < seconds:
                    time.sleep(min(1.0, seconds - elapsed))
                    s = rec.stats()
                    bar.update(
                        int(time.monotonic() - t0) - bar.done,
                        f"{s.frames} frames {s.frames_per_s:.1f}/s",
                    )
        stats = rec.stats()
    s = np.array(stamps, dtype=np.int64)
    # The stamp wraps at 65536 (~11 min at 100 frames/s): unwrap before counting holes.
    steps = np.diff(s) % 65536
    lost = int((steps - 1).sum())
    dt = np.diff(np.array(times))
    print(
        f"soak {args.minutes:g} min at {args.rate:g} frames/s: received {len(s)} frames, "
        f"lost {lost}, repeated/out-of-order {int((steps == 0).sum() + (steps > 32768).sum())}, "
        f"dropped lines {stats.drops}, gaps {len(stats.gaps)}; "
        f"inter-frame time median {1000 * np.median(dt):.2f} ms, max {1000 * dt.max():.1f} ms; "
        f"reader thread CPU {100 * stats.thread_cpu_s / (times[-1] - times[0]):.2f} %; "
        f"longest reader pause {1000 * stats.max_read_interval_s:.0f} ms; "
        f"inter-frame gaps > 100 ms: {int((dt > 0.1).sum())}"
    )
    print(f"sim board: {sim.summary}")


if __name__ == "__main__":
    main()

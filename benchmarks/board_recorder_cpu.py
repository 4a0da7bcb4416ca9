"""Recorder CPU use at 100 frames/s through a pty (target <= 10 % of one core).

The simulated board runs in its own process (``varskin board sim``) so only the recorder's
work is measured: the reader thread's own CPU time (``time.thread_time`` inside the thread)
and, as a cross-check, this whole process's CPU (``resource.getrusage``), both divided by
wall time. Prints the median of repeated runs.

    python benchmarks/board_recorder_cpu.py [--seconds 15] [--repeats 3] [--rate 100]
"""

from __future__ import annotations

import argparse
import resource
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _board_simproc import SimProcess

from varskin.board.recorder import Recorder


def process_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def run_once(seconds: float, rate: float) -> tuple[float, float, float]:
    with SimProcess(rate) as sim:
        frames = []
        rec = Recorder(sim.path)
        rec.subscribe(frames.append)
        with rec:
            rec.wait_for_frame(5.0)
            time.sleep(0.5)  # settle
            s0, c0, w0 = rec.stats(), process_cpu(), time.monotonic()
            time.sleep(seconds)
            s1, c1, w1 = rec.stats(), process_cpu(), time.monotonic()
    wall = w1 - w0
    return (
        100 * (s1.thread_cpu_s - s0.thread_cpu_s) / wall,
        100 * (c1 - c0) / wall,
        (s1.frames - s0.frames) / wall,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rate", type=float, default=100.0, help="simulated frames/s")
    args = ap.parse_args()
    runs = [run_once(args.seconds, args.rate) for _ in range(args.repeats)]
    thread_pct = statistics.median(r[0] for r in runs)
    proc_pct = statistics.median(r[1] for r in runs)
    rate = statistics.median(r[2] for r in runs)
    print(
        f"recorder CPU at {rate:.1f} frames/s: reader thread median {thread_pct:.2f} % of a core "
        f"(runs: {', '.join(f'{r[0]:.2f}' for r in runs)}); whole recording process "
        f"{proc_pct:.2f} %; {args.repeats} runs x {args.seconds:g} s"
    )


if __name__ == "__main__":
    main()

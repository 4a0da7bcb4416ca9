"""Muca ASCII parser throughput on one core (target >= 7,500 frames/s).

Realistic frames: 252 values at the rest levels of the real patches (4-5 digits, about
1.3-1.4 kB a line), fed in 4 kB chunks as a serial read delivers them. Prints the median
of repeated runs for the plain format and for the empty-field variant.

    python benchmarks/board_parser.py [--frames 5000] [--repeats 7]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from varskin.board.protocol import AsciiFrameParser, format_frame


def make_stream(n: int, empty_zero: bool, seed: int = 0) -> bytes:
    rng = np.random.default_rng(seed)
    rest = rng.uniform(7400, 11500, (21, 12))
    lines = []
    for _ in range(n):
        cells = np.rint(rest + rng.normal(0, 5, rest.shape)).astype(np.int64)
        if empty_zero:
            cells[rng.random(cells.shape) < 0.2] = 0
        lines.append(format_frame(cells, empty_zero=empty_zero))
    return b"".join(lines)


def run_once(stream: bytes, chunk: int) -> tuple[float, int]:
    parser = AsciiFrameParser(synced=True)
    frames = 0
    t0 = time.perf_counter()
    for i in range(0, len(stream), chunk):
        frames += len(parser.feed(stream[i : i + chunk], 0.0))
    return time.perf_counter() - t0, frames


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=5000)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--chunk", type=int, default=4096, help="bytes per feed() call")
    args = ap.parse_args()
    for empty_zero in (False, True):
        stream = make_stream(args.frames, empty_zero)
        rates = []
        for _ in range(args.repeats):
            dt, n = run_once(stream, args.chunk)
            assert n == args.frames, (n, args.frames)
            rates.append(n / dt)
        label = "empty-field variant" if empty_zero else "plain ASCII"
        print(
            f"parser {label}: median {statistics.median(rates):,.0f} frames/s "
            f"(min {min(rates):,.0f}, max {max(rates):,.0f}; {args.repeats} runs x {args.frames} "
            f"frames, {len(stream) / args.frames:,.0f} B/frame, {args.chunk} B chunks)"
        )


if __name__ == "__main__":
    main()

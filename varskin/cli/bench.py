"""``varskin bench``: speed versus error of every localization method on simulated patches."""

from __future__ import annotations

import sys
from pathlib import Path

from varskin.cli._args import seed


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "bench",
        help="speed versus error of the localization methods on simulated patches",
        description="Run every localization method over seeded simulated Patch A and B sessions "
        "(finger and robot probing): the paper method over eta 0.50-0.80 x ppcm {4,16,64,128} "
        "and every method over 20-100 point logs. Prints a table (RMS/mean/max error in mm, "
        "median time in ms, ratios to the paper method timed in the same run) and writes "
        "pareto.png, error_vs_logs.png, eta_ppcm_map.png and results.md.",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="a small run (Patch B, ppcm {4,16}, 3 etas, 20/60/100 logs, one seed): < 30 s",
    )
    p.add_argument(
        "--out", metavar="DIR", default="bench_results", help="output folder; default bench_results"
    )
    p.add_argument(
        "--repeats",
        type=int,
        metavar="N",
        help="timed repeats per run, the median is reported; default 3 (1 with --quick)",
    )
    p.add_argument(
        "--seeds",
        type=seed,
        nargs="+",
        metavar="SEED",
        help="scene seeds; default 100 101 (100 with --quick)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from varskin.bench import BenchConfig, format_table, run_bench, table_rows, write_outputs
    from varskin.errors import InputError

    if args.repeats is not None and args.repeats < 1:
        raise InputError(f"--repeats must be >= 1, got {args.repeats}")
    if args.quick:
        cfg = BenchConfig.quick(
            seeds=tuple(args.seeds) if args.seeds else (100,), repeats=args.repeats or 1
        )
    else:
        cfg = BenchConfig(
            seeds=tuple(args.seeds) if args.seeds else BenchConfig().seeds,
            repeats=args.repeats or 3,
        )
    runs = run_bench(cfg)
    print(format_table(table_rows(runs, cfg)))
    command = "varskin " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["bench"] else "varskin bench"
    for path in write_outputs(runs, cfg, Path(args.out), command):
        print(f"wrote {path}")
    return 0

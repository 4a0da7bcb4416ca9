"""``varskin simulate``: a calibration session on a simulated patch, written as a point-log CSV.

It gives every other command data with a known answer: the samples go to the point-log
CSV (baseline frames first, then every frame of every touch) and the hidden sensor
positions to a truth CSV with the same sensor names.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from varskin.cli._args import seed
from varskin.patch import resolve_patch


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "simulate",
        help="simulate a calibration session and write its point-log CSV and truth CSV",
        description="Touch a simulated patch (hidden layout, finger or robot probe) on a uniform "
        "grid of probe points and write every board frame as a point-log CSV.",
    )
    p.add_argument(
        "--patch",
        default="patch_b",
        help="patch YAML file, or a builtin name (patch_a, patch_b); default patch_b",
    )
    p.add_argument(
        "--grid",
        type=parse_grid,
        default=(20, 5),
        metavar="NXxNY",
        help="probe grid as COLUMNSxROWS: NX points along the length (x) by NY across (y), "
        "at the centres of equal cells; default 20x5 (the paper's 100 point logs)",
    )
    p.add_argument(
        "--probe",
        choices=("finger", "robot"),
        default="finger",
        help="finger: ~9 mm footprint, placed to about +-2 mm; robot: narrow metal probe "
        "placed to ~0.05 mm; default finger",
    )
    p.add_argument(
        "--seed", type=seed, default=0, help="seed of the scene and the noise; default 0"
    )
    p.add_argument(
        "-o", "--output", required=True, help="point-log CSV to write (one row per frame)"
    )
    p.add_argument(
        "--truth",
        help="truth CSV to write (sensor,x_mm,y_mm); default <OUTPUT stem>_truth.csv beside it",
    )
    p.set_defaults(func=run)


def parse_grid(text: str) -> tuple[int, int]:
    parts = text.lower().split("x")
    try:
        nx, ny = (int(v) for v in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"grid must look like 20x5, got {text!r}") from None
    if nx < 1 or ny < 1 or nx * ny < 3:
        raise argparse.ArgumentTypeError(f"grid {text!r} needs at least 3 points, each side >= 1")
    return nx, ny


def run(args) -> int:
    from varskin.cli.localize import writing
    from varskin.pointlog_csv import write_samples_csv, write_truth_csv
    from varskin.simulate import simulate_session, uniform_grid

    patch = resolve_patch(args.patch)
    nx, ny = args.grid
    session = simulate_session(patch, uniform_grid(patch, nx, ny), args.probe, args.seed)
    out = Path(args.output)
    truth = Path(args.truth) if args.truth else out.with_name(f"{out.stem}_truth.csv")
    with writing():
        write_samples_csv(out, session)
        write_truth_csv(truth, session.sensors, session.truth)
    print(
        f"{patch.name}: {nx * ny} touches ({len(session.samples)} frames + "
        f"{len(session.baseline)} baseline) with the {args.probe} -> {out}; truth -> {truth}"
    )
    return 0

"""``varskin demo``: the main job end to end on a simulated Patch B, in a few seconds.

It simulates the paper's session (Patch B, 20 x 5 grid, human finger), writes it in the
point-log interchange format, reads it back like any user file, localizes it with the
default method and with the published one, and prints and plots how far each is from the
truth, so a new user sees the whole pipeline and both numbers at once.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from varskin import localization as registry
from varskin.cli._args import seed

DEMO_SENSOR = "S14"  # the sensor the paper's figures show


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "demo",
        help="simulate Patch B, localize it (default and paper method), print errors, write plots",
        description="Simulate a calibration of Patch B (20x5 probe grid), write logs.csv and "
        "truth.csv, localize with the default method and the paper's method, print the error "
        "tables and write predictions and PNG plots into the output folder.",
    )
    p.add_argument("--out", default="varskin-demo", help="output folder; default ./varskin-demo")
    p.add_argument("--seed", type=seed, default=0, help="seed of the simulated scene; default 0")
    p.add_argument(
        "--probe", choices=("finger", "robot"), default="finger", help="probe; default finger"
    )
    p.add_argument(
        "--method",
        choices=["default", *registry.METHODS],
        default="default",
        help="method compared with the paper's; default the project default "
        f"({registry.DEFAULT_METHOD})",
    )
    p.add_argument(
        "--ppcm",
        type=float,
        help="paper method's interpolation resolution, pixels per cm; default 128 (published)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from varskin.cli.localize import writing

    with writing():  # an unwritable --out folder is a user's mistake, not a crash
        return _run(args)


def _run(args) -> int:
    from varskin.cli.localize import print_warnings, write_plots
    from varskin.evaluate import evaluate
    from varskin.localization import localize
    from varskin.patch import builtin_patch
    from varskin.pointlog_csv import (
        read_point_logs,
        read_truth_csv,
        write_samples_csv,
        write_truth_csv,
    )
    from varskin.simulate import simulate_session, uniform_grid

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    patch = builtin_patch("patch_b")
    session = simulate_session(patch, uniform_grid(patch, 20, 5), args.probe, args.seed)
    logs_path, truth_path = out / "logs.csv", out / "truth.csv"
    write_samples_csv(logs_path, session)
    write_truth_csv(truth_path, session.sensors, session.truth)
    print(
        f"simulated {patch.name}, 20x5 grid, {args.probe}, seed {args.seed}: {logs_path}, {truth_path}"
    )

    logs = read_point_logs(logs_path)
    print_warnings(logs)
    truth = read_truth_csv(truth_path)
    method = registry.DEFAULT_METHOD if args.method == "default" else args.method
    methods = [method] if method == "paper" else [method, "paper"]
    summaries = []
    for name in methods:
        params = {"ppcm": args.ppcm} if name == "paper" and args.ppcm is not None else {}
        # The wiring is known from the patch config, so the new method gets its layout prior.
        extra = {} if name == "paper" else {"patch": patch}
        predictions = localize(logs, method=name, **params, **extra)
        result = evaluate(predictions, truth)
        stem = f"pred_{name}"
        predictions.to_csv(out / f"{stem}.csv")
        predictions.to_json(out / f"{stem}.json")
        (out / f"eval_{name}.json").write_text(json.dumps(result.to_dict(), indent=2) + "\n")
        plot_dir = out / f"plots_{name}"
        write_plots(
            plot_dir,
            logs,
            predictions,
            [DEMO_SENSOR] if name == "paper" else [],
            params,
            truth=truth,
            outline=(patch.length_mm, patch.width_mm),
        )
        print(f"\n== {name} ==")
        print(result.table())
        summaries.append(result.summary())
    print("\nsummary")
    for s in summaries:
        print("  " + s)
    print(f"predictions, evaluations and plots in {out}/", file=sys.stderr)
    return 0

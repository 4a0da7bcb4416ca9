"""``varskin evaluate``: score a predictions CSV against the true sensor positions.

Prints the per-sensor error table and the paper's summary, RMS = sqrt(sum e^2 / (N-1)),
with mean and max; ``--json`` keeps the same for scripts.
"""

from __future__ import annotations

import json
from pathlib import Path


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "evaluate",
        help="per-sensor error of predictions against a truth CSV, and the RMS summary",
        description="Match predictions to true positions by sensor name and report the error "
        "of each sensor (mm) and the paper's RMS = sqrt(sum e^2 / (N-1)), mean and max.",
    )
    p.add_argument(
        "predictions", metavar="PRED.csv", help="sensor,x_mm,y_mm,sigma_mm,snr_db,status"
    )
    p.add_argument("--truth", required=True, metavar="TRUTH.csv", help="sensor,x_mm,y_mm")
    p.add_argument("--json", metavar="OUT.json", help="also write the evaluation as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    from varskin.cli.localize import writing
    from varskin.evaluate import evaluate, read_predictions_csv
    from varskin.pointlog_csv import read_truth_csv

    predictions = read_predictions_csv(args.predictions, method=Path(args.predictions).stem)
    truth = read_truth_csv(args.truth)
    result = evaluate(predictions, truth)
    print(result.table())
    print(result.summary())
    if args.json:
        with writing():
            Path(args.json).write_text(json.dumps(result.to_dict(), indent=2) + "\n")
    return 0

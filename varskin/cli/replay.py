"""``varskin replay SESSION.db [--method M]``: re-run a recorded session without hardware.

Re-cuts every point log from the stored frames, re-runs the live localizer over them in
order and batch-solves them, then says how each stage compares with what the live session
stored (identical, or the largest difference). With ``--method`` any localizer can be tried
on old data; ``-o`` writes a fresh report.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from varskin.localization import METHODS


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "replay",
        help="re-run localization on a recorded session (no hardware) and compare with the live run",
        description="Re-cut the point logs from SESSION.db's raw frames, replay the live "
        "localizer and batch-solve with --method (default: the session's method); report how "
        "each compares with the stored live run.",
    )
    p.add_argument("session", metavar="SESSION.db", help="a session file of varskin calibrate")
    p.add_argument(
        "--method",
        choices=list(METHODS),
        help="localization method of the batch estimate (default: the session's own)",
    )
    p.add_argument(
        "-o", "--output", metavar="DIR", help="write predictions CSV/JSON and plots into DIR"
    )
    p.set_defaults(func=run)


def _same(diff: float | None, mismatches: int) -> str:
    if diff is None:
        return "not stored for this method"
    if diff == 0.0 and mismatches == 0:
        return "identical (bit for bit)"
    return f"differs: largest difference {diff:.3g}, {mismatches} status mismatch(es)"


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from varskin.errors import StoreError
    from varskin.replay import replay
    from varskin.report import write_report
    from varskin.session import rms_error_mm
    from varskin.store import SessionStore

    with SessionStore.open(args.session) as store:
        meta = store.meta()
        patch = store.patch()
        r = replay(store, patch, args.method)
        print(f"{args.session}: {r.n_logs} point logs, method {r.predictions.method}")
        recut = (
            "identical (bit for bit)"
            if r.recut_max_diff == 0
            else f"differs by {r.recut_max_diff:.3g} counts"
            if np.isfinite(r.recut_max_diff)
            else "not possible for every touch (frames or attempt records missing or damaged)"
        )
        print(f"point logs re-cut from raw frames: {recut}")
        print(f"live estimates: {_same(r.live_max_diff_mm, r.live_status_mismatches)}")
        print(f"final estimate: {_same(r.final_max_diff_mm, r.final_status_mismatches)}")
        truth = meta.get("truth_xy")
        if truth is not None:
            try:
                truth = np.asarray(truth, float).reshape(len(patch.sensors), 2)
            except (TypeError, ValueError):
                raise StoreError(
                    f"{args.session}: damaged session file (its truth_xy is not one x, y per sensor)"
                ) from None
            rms, n = rms_error_mm(r.predictions, truth)
            if n:
                print(
                    f"error vs the simulated rig's hidden layout: RMS {rms:.3f} mm over {n} sensors"
                )
        if args.output:
            files = write_report(Path(args.output), store, r.predictions, patch, truth)
            print(f"report: {files.predictions_csv.parent}/", file=sys.stderr)
    return 0

"""``varskin export SESSION.db -o logs.csv``: a session's point logs as the core CSV format.

The session file is the complete record; the CSV is what other tools (and ``varskin
localize``) read, so any session can be localized, shared or plotted without SQLite.
"""

from __future__ import annotations

import argparse
import sys


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export",
        help="write a session's point logs as a point-log CSV",
        description="Write every point log of SESSION.db, in plan order, as the point-log CSV "
        "(touch,x_mm,y_mm,<sensors>; values in counts above rest, positions in patch mm).",
    )
    p.add_argument("session", metavar="SESSION.db", help="a session file of varskin calibrate")
    p.add_argument("-o", "--output", required=True, metavar="LOGS.csv", help="CSV to write")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from varskin.pointlog_csv import write_point_logs_csv
    from varskin.store import SessionStore

    with SessionStore.open(args.session) as store:
        logs = store.point_logs()
    write_point_logs_csv(args.output, logs)
    print(f"{len(logs)} point logs x {logs.n_sensors} sensors -> {args.output}", file=sys.stderr)
    return 0

"""The ``varskin`` command: one subcommand group per module in this package.

Each module exposes ``register(subparsers)``, which adds its subcommands and sets
``func`` on them. A ``VarskinError`` (a user's mistake or a device fault) becomes one line
on stderr and exit status 2; anything else is a bug and keeps its traceback. SIGTERM (a
service manager, ``kill``) takes the Ctrl-C path, so every ``finally`` runs: the arm
retracts, the session file closes, simulated devices stop.
"""

from __future__ import annotations

import argparse
import importlib
import signal
import sys
import threading

from varskin.errors import VarskinError

COMMAND_MODULES = (
    "calibrate",
    "replay",
    "export",
    "demo",
    "simulate",
    "localize",
    "evaluate",
    "bench",
    "board",
    "robot",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="varskin",
        description="Calibrate capacitive tactile skins: simulate, record, localize, evaluate.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(f"varskin.cli.{name}")
        except ModuleNotFoundError as e:
            # While a command group is being built its module may not exist yet.
            if e.name != f"varskin.cli.{name}":
                raise
            continue
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    previous = _interrupt_on_sigterm()
    try:
        return int(args.func(args) or 0)
    except VarskinError as e:
        print(f"varskin: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        # A file the user named cannot be written or read (a folder missing, a file where a
        # folder should be, no permission, a full disk): their environment, not a bug, so
        # one line that names the file. Each command turns the errors it expects into
        # clearer messages; this catches the rest (found by fuzzing the CLI's arguments).
        where = f"{e.filename}: " if e.filename else ""
        print(f"varskin: error: {where}{e.strerror or e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("varskin: interrupted", file=sys.stderr)
        return 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _interrupt_on_sigterm():
    """Raise KeyboardInterrupt on SIGTERM (Python's default would end the process without
    running a single ``finally``: no retract, a simulated controller left orphaned). Returns
    the handler to restore, None where signals cannot be set (not the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        return None

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    return signal.signal(signal.SIGTERM, interrupt)


if __name__ == "__main__":
    sys.exit(main())

"""``varskin board``: run the simulated Muca board, or record frames from a real one.

``board sim`` gives anyone without hardware a device path that behaves like a plugged-in
board; ``board record`` is the smallest useful client of the recorder: frames to CSV with
a live rate and drop counter, and a summary a user can trust (frames, rate, drops, gaps).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from varskin.cli._args import positive, seed
from varskin.errors import ConfigError
from varskin.patch import resolve_patch


def register(subparsers) -> None:
    board = subparsers.add_parser("board", help="Muca board: simulated board and frame recording")
    sub = board.add_subparsers(dest="board_command", metavar="SUBCOMMAND")

    sim = sub.add_parser(
        "sim",
        help="start a simulated Muca board on a pseudo-terminal and print its device path",
    )
    sim.add_argument(
        "--patch", default="patch_b", help="patch YAML path or built-in name; default patch_b"
    )
    sim.add_argument(
        "--rate",
        type=positive,
        default=None,
        help="frame rate, frames/s; default as fast as --baud allows (~8/s at 115200)",
    )
    sim.add_argument(
        "--baud",
        type=int,
        default=115200,
        help="paced line rate, bit/s (0: no limit; a pty itself ignores baud); default 115200",
    )
    sim.add_argument(
        "--touch-demo",
        action="store_true",
        help="press each sensor in turn (1.5 s on, 1 s off) instead of staying idle",
    )
    sim.add_argument("--seed", type=seed, default=0, help="scene and noise seed; default 0")
    sim.add_argument(
        "--reverse-tx",
        action="store_true",
        help="send TX lines in reverse order (Muca library since late 2022)",
    )
    sim.add_argument(
        "--empty-zero",
        action="store_true",
        help="print zero values as empty fields, like sketches that print only values > 0",
    )
    sim.add_argument(
        "--stamp-seq",
        action="store_true",
        help="write the board's frame number (mod 65536) into unwired cell (20, 11), for loss tests",
    )
    sim.add_argument(
        "--fault-rate",
        type=float,
        default=0.0,
        help="chance per frame of one injected fault (garbage, truncated, log or I2C line)",
    )
    sim.add_argument(
        "--link",
        default=None,
        help="stable device path to publish; default a link in a new temporary directory",
    )
    sim.add_argument(
        "--seconds",
        type=positive,
        default=None,
        help="stop after this long, s; default run until Ctrl-C",
    )
    sim.set_defaults(func=cmd_sim)

    rec = sub.add_parser(
        "record",
        help="record frames from a Muca board to CSV",
    )
    rec.add_argument(
        "--port",
        required=True,
        help="serial device or pyserial URL (/dev/ttyACM0, a pty path, loop://)",
    )
    rec.add_argument(
        "--patch",
        default=None,
        help="patch YAML path or built-in name; without it all 252 cells are written",
    )
    rec.add_argument("--seconds", type=positive, required=True, help="how long to record, s")
    rec.add_argument("-o", "--output", required=True, help="frames CSV to write")
    rec.add_argument(
        "--baud", type=int, default=115200, help="serial baud rate, bit/s; default 115200"
    )
    rec.add_argument(
        "--frame-timeout",
        type=positive,
        default=5.0,
        help="give up if no valid frame arrives within this long, s; default 5",
    )
    rec.set_defaults(func=cmd_record)
    board.set_defaults(func=lambda args: board.print_help() or 0)


def cmd_sim(args) -> int:
    from varskin.board.simboard import SimBoard

    patch = resolve_patch(args.patch)
    try:
        board = SimBoard(
            patch,
            rate_hz=args.rate,
            baud=args.baud,
            reverse_tx=True if args.reverse_tx else None,
            empty_zero=args.empty_zero,
            seed=args.seed,
            touch_demo=args.touch_demo,
            stamp_seq=args.stamp_seq,
            fault_rate=args.fault_rate,
            link_path=args.link,
        )
    except ValueError as e:
        raise ConfigError(f"board sim: {e}") from None
    board.start()  # SIGTERM ends it as Ctrl-C does (varskin.cli.main): pty and link cleaned up
    try:
        print(board.path, flush=True)
        print(
            f"simulated Muca board ({patch.name}) on {board.pty_name}; Ctrl-C to stop",
            file=sys.stderr,
            flush=True,
        )
        deadline = None if args.seconds is None else time.monotonic() + args.seconds
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.1 if deadline is None else min(0.1, max(deadline - time.monotonic(), 0)))
    except KeyboardInterrupt:
        pass
    finally:
        board.stop()
        print(
            f"frames_made={board.frames_made} frames_written={board.frames_written} "
            f"frames_skipped={board.frames_skipped} "
            f"faults={board.faults_injected}",
            file=sys.stderr,
            flush=True,
        )
    return 0


def cmd_record(args) -> int:
    from varskin.board.cellmap import CellMap
    from varskin.board.csvsink import FrameCsvSink
    from varskin.board.recorder import Recorder

    cellmap = CellMap.from_patch(resolve_patch(args.patch)) if args.patch else None
    recorder = Recorder(args.port, baudrate=args.baud)
    t0 = time.monotonic()
    sink = FrameCsvSink(args.output, cellmap, t0=t0)
    recorder.subscribe(sink)
    try:
        recorder.start()  # BoardError naming the port if it cannot be opened
    except BaseException:
        sink.close()
        Path(args.output).unlink(missing_ok=True)  # nothing was recorded
        raise
    live = sys.stderr.isatty()
    interrupted = False
    try:
        recorder.wait_for_frame(args.frame_timeout)
        next_status = 0.0
        try:
            while (now := time.monotonic()) - t0 < args.seconds:
                if now >= next_status:
                    _status(recorder, now - t0, args.seconds, live)
                    next_status = now + (0.5 if live else 5.0)
                time.sleep(min(0.1, max(args.seconds - (now - t0), 0)))
        except KeyboardInterrupt:
            interrupted = True  # keep what was recorded and still print the summary
    finally:
        recorder.stop()
        sink.close()
    stats = recorder.stats()
    elapsed = time.monotonic() - t0
    if live:
        sys.stderr.write("\n")
    drops = ", ".join(f"{k}={v}" for k, v in sorted(stats.drops.items())) or "none"
    gap_s = sum(g.duration_s for g in stats.gaps)
    print(
        f"wrote {args.output}: {sink.rows} frames in {elapsed:.1f} s "
        f"({sink.rows / elapsed:.1f} frames/s)"
    )
    print(f"dropped lines: {drops}")
    print(f"gaps: {len(stats.gaps)} ({gap_s:.2f} s without a device)")
    if interrupted:
        print("varskin: interrupted; the CSV holds every frame up to then", file=sys.stderr)
        return 130
    return 0


def _status(recorder, elapsed: float, total: float, live: bool) -> None:
    s = recorder.stats()
    dropped = sum(s.drops.values())
    text = (
        f"recording {elapsed:5.1f}/{total:g} s  frames {s.frames}  "
        f"{s.frames_per_s:5.1f} frames/s  dropped {dropped}  gaps {len(s.gaps)}"
        f"{'' if s.connected else '  (reconnecting)'}"
    )
    sys.stderr.write(("\r" + text) if live else (text + "\n"))
    sys.stderr.flush()

"""``varskin board record`` and ``varskin board sim`` end to end on a real pty."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
import time

import numpy as np

from varskin.board.simboard import SimBoard
from varskin.cli import main


def read_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], np.array(rows[1:], dtype=float)


def test_record_writes_patch_sensors_to_csv(tmp_path, patch_b, capsys):
    out = tmp_path / "frames.csv"
    with SimBoard(patch_b, rate_hz=100, baud=None, seed=2) as board:
        rc = main(
            [
                "board",
                "record",
                "--port",
                board.path,
                "--patch",
                "patch_b",
                "--seconds",
                "1",
                "-o",
                str(out),
            ]
        )
        rest = board.scene.rest
    assert rc == 0
    header, data = read_csv(out)
    assert header == ["t_s", "seq"] + [f"S{i}" for i in range(1, 31)]
    assert len(data) >= 50
    assert np.all(np.diff(data[:, 0]) >= 0) and data[0, 0] >= 0
    assert data[:, 1].tolist() == list(range(len(data)))
    # Idle board: every sensor sits near its simulated rest value.
    assert np.all(np.abs(np.median(data[:, 2:], axis=0) - rest) < 40)
    printed = capsys.readouterr().out
    assert f"{len(data)} frames" in printed and "gaps: 0" in printed


def test_record_all_cells_without_a_patch(tmp_path, patch_b, capsys):
    out = tmp_path / "cells.csv"
    with SimBoard(patch_b, rate_hz=50, baud=None, stamp_seq=True) as board:
        assert (
            main(["board", "record", "--port", board.path, "--seconds", "0.5", "-o", str(out)]) == 0
        )
    header, data = read_csv(out)
    assert len(header) == 2 + 252 and header[-1] == "c20_11"
    assert np.all(np.diff(data[:, -1]) == 1)  # the stamp cell counts up: nothing lost


def test_bad_port_exits_2_with_one_line(tmp_path, capsys):
    out = tmp_path / "x.csv"
    rc = main(
        ["board", "record", "--port", str(tmp_path / "ttyACM7"), "--seconds", "1", "-o", str(out)]
    )
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1 and "ttyACM7" in err and err.startswith("varskin: error:")
    assert not out.exists()


def test_no_frames_exits_2_naming_the_port(tmp_path, capsys):
    rc = main(
        [
            "board",
            "record",
            "--port",
            "loop://",
            "--seconds",
            "1",
            "--frame-timeout",
            "0.2",
            "-o",
            str(tmp_path / "x.csv"),
        ]
    )
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "loop://" in err and len(err.splitlines()) == 1


def test_unknown_patch_exits_2(tmp_path, capsys):
    rc = main(
        [
            "board",
            "record",
            "--port",
            "loop://",
            "--patch",
            "patch_z",
            "--seconds",
            "1",
            "-o",
            str(tmp_path / "x.csv"),
        ]
    )
    assert rc == 2 and "patch_z" in capsys.readouterr().err


def test_board_sim_command_prints_a_device_path_that_records(tmp_path):
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "varskin",
            "board",
            "sim",
            "--rate",
            "50",
            "--baud",
            "0",
            "--touch-demo",
            "--seconds",
            "8",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        path = proc.stdout.readline().strip()
        assert path.endswith("ttyMUCA0")
        out = tmp_path / "demo.csv"
        assert (
            main(
                [
                    "board",
                    "record",
                    "--port",
                    path,
                    "--patch",
                    "patch_b",
                    "--seconds",
                    "3",
                    "-o",
                    str(out),
                ]
            )
            == 0
        )
        _, data = read_csv(out)
        # The touch demo presses S1, S2, ... in turn (1.5 s on, 1 s off): some sensor rises
        # far above its own quiet level (noise is ~5 counts).
        sensors = data[:, 2:]
        rise = sensors.max(axis=0) - np.percentile(sensors, 5, axis=0)
        assert rise.max() > 80
    finally:
        proc.terminate()
        proc.wait(10)
        proc.stdout.close()
        proc.stderr.close()
    assert not os.path.lexists(path)  # SIGTERM cleans up like Ctrl-C


def test_killed_recording_keeps_what_it_had(tmp_path, patch_b):
    """kill -9 mid-recording: every frame received up to ~0.25 s before the kill is on disk."""
    out = tmp_path / "frames.csv"
    with SimBoard(patch_b, rate_hz=8, baud=None, seed=3, stamp_seq=True) as board:
        # No --patch: all 252 cells are written, including the board's frame-number stamp.
        proc = subprocess.Popen(
            [sys.executable, "-m", "varskin", "board", "record", "--port", board.path]
            + ["--seconds", "60", "-o", str(out)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline:
                if out.exists() and out.read_text().count("\n") >= 3:
                    break
                time.sleep(0.05)
            time.sleep(2.0)
            sent = board.frames_written  # frames on the line when the recorder is killed
            proc.kill()
            proc.wait(10)
        finally:
            if proc.poll() is None:
                proc.kill()
    lines = out.read_text().splitlines()
    header = lines[0].split(",")
    complete = [r.split(",") for r in lines[1:] if r.count(",") == len(header) - 1]
    stamp = header.index("c20_11")
    last_on_disk = int(complete[-1][stamp])
    # At 8 frames/s, 0.25 s of unflushed rows plus one frame in transit is at most 3 frames;
    # a count- or buffer-size-based flush would leave up to ~40 frames (5 s) behind.
    assert sent - 1 - last_on_disk <= 3, (sent, last_on_disk)
    stamps = [int(r[stamp]) for r in complete]
    assert stamps == list(range(stamps[0], stamps[0] + len(stamps)))  # whole frames, in order

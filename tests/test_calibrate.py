"""End to end: ``varskin calibrate`` on the simulated rig, with every real part in the loop
(the real ur-rtde client against the simulated controller on loopback, the simulated board
on a pseudo-terminal read by the real recorder, a real SQLite file), plus its faults: a
kill -9 and --resume, a board unplugged mid-touch, a protective stop, bad configs.

The plans are small (42 touches; 15 for the faults) so the module stays within CI's budget; the 100-touch
default run is measured in docs/benchmarks.md.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from robot.launch import load_launch
from varskin.cli import main
from varskin.cli.calibrate import make_planner, stored_plan
from varskin.design_fit import fit_design
from varskin.localization.peakfit import Localizer
from varskin.patch import config_dir, patch_from_dict
from varskin.planning import UniformPlanner, touch_order, uniform_points
from varskin.pointlog_csv import read_point_logs
from varskin.replay import recut_logs
from varskin.rig import open_rig
from varskin.session import CalibrationSession, SessionEvent, SessionSettings, rms_error_mm
from varskin.store import SessionStore
from varskin.touch_window import BASELINE, REST, stored_window

REPO = config_dir().parent
GRID = (14, 3)  # about the sparsest grid on which nearly all of Patch B's sensors locate
N_TOUCHES = GRID[0] * GRID[1]
FAULT_GRID = (5, 3)  # the fault tests check the record, not the accuracy
FAULT_N = FAULT_GRID[0] * FAULT_GRID[1]


def write_launch(path: Path, grid: tuple[int, int] = GRID, **changes) -> Path:
    """launch/sim.yaml with a small grid and an absolute patch path, plus ``changes``
    (dotted keys)."""
    data = yaml.safe_load((REPO / "launch" / "sim.yaml").read_text())
    data["patch"] = str(config_dir() / "patch_b.yaml")
    data["plan"]["grid"] = f"{grid[0]}x{grid[1]}"
    for key, value in changes.items():
        node = data
        *parents, leaf = key.split(".")
        for p in parents:
            node = node[p]
        node[leaf] = value
    path.write_text(yaml.safe_dump(data))
    return path


def n_logs_in(db: Path) -> int:
    try:
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1.0) as c:
            return int(c.execute("SELECT COUNT(*) FROM point_logs").fetchone()[0])
    except sqlite3.Error:
        return 0


@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    """One uninterrupted small calibration through the CLI."""
    tmp = tmp_path_factory.mktemp("full")
    launch = write_launch(tmp / "sim_small.yaml")
    db = tmp / "full.db"
    assert main(["calibrate", str(launch), "-o", str(db)]) == 0
    return launch, db


def _as_killed_after(db: Path, cut: int) -> None:
    """Leave ``db`` as a kill after plan touch ``cut - 1``'s commit would: the session
    commits each touch whole, so nothing of the later touches, and still running."""
    with sqlite3.connect(db) as c:
        for table in ("outcomes", "point_logs", "attempts"):
            c.execute(f"DELETE FROM {table} WHERE plan_index >= ?", (cut,))
        c.execute("DELETE FROM estimates WHERE n_logs > ?", (cut,))
        c.execute("UPDATE meta SET value = ? WHERE key = 'status'", ('"running"',))


def test_calibrate_runs_the_plan_stores_and_reports(full_run, capsys):
    launch, db = full_run
    with SessionStore.open(db) as store:
        meta = store.meta()
        logs = store.point_logs()
        outcomes = store.outcomes()
        finals = store.estimates("final", "peakfit")
        attempts = store.attempts()
        n_frames = store.n_frames()
    assert meta["status"] == "complete"
    assert [o.plan_index for o in outcomes] == list(range(N_TOUCHES))
    assert len(logs) == N_TOUCHES and all(o.ok for o in outcomes)
    # Patch B is longer than SHUFFLE_UP_TO_MM: the grid is swept
    assert meta["plan"]["order"] == "sweep"
    # the logs sit where the plan put them, and every touch has a real response
    plan = UniformPlanner(load_launch(launch).patch, *GRID, 3.0).points()
    np.testing.assert_array_equal(logs.xy_mm, plan)
    assert np.all(logs.values.max(axis=1) > 20)  # counts above rest at the touched sensor
    assert np.all(logs.n_samples >= 3)
    # one ok attempt per touch; a host that starves the board thread can force a retry
    assert sorted(a.plan_index for a in attempts if a.status == "ok") == list(range(N_TOUCHES))
    assert {a.status for a in attempts} <= {"ok", "board_gap"}
    assert n_frames > N_TOUCHES * 8  # raw frames are all there, not only the windows
    final = finals[N_TOUCHES]
    truth = np.asarray(meta["truth_xy"])
    rms, located = rms_error_mm(final, truth)
    assert located >= 24
    # 42 touches for 30 sensors are coarse (100 give ~0.2 mm). The frames each window holds
    # depend on host timing, so the RMS varies run to run: 0.52-0.56 mm in 4 runs with the
    # logs against the rest (0.57-1.01 mm in 8 against each touch's baseline), the largest
    # error 1.21-1.34 mm and the median 0.31-0.40 mm (2026-11-29).
    assert rms < 1.5 and median_error_mm(final, truth) < 0.8
    # The located sensors against the design, stored with the session: the simulated rig's
    # registration is exact, so the layout lies as the design within the wires' build.
    fit = fit_design(final, load_launch(launch).patch)
    assert meta["design_fit"] == fit.as_dict() and fit.n_sensors == located
    assert abs(fit.turn_deg) < 1.0 and np.hypot(*fit.shift_mm) < 2.0 and not fit.warnings()
    report = db.with_suffix("")
    for name in ("predictions.csv", "predictions.json", "point_log_maps.png", "predictions.png",
                 "off_design.png", "uncertainty_vs_touches.png"):  # fmt: skip
        assert (report / name).stat().st_size > 0, name
    assert meta["rig_time_estimate_s"] > meta["wall_s"]  # the scaled sim ran faster than a rig


def test_replay_is_bit_identical_and_export_round_trips(full_run, tmp_path, capsys):
    _, db = full_run
    capsys.readouterr()
    assert main(["replay", str(db)]) == 0
    out = capsys.readouterr().out
    assert "point logs re-cut from raw frames: identical (bit for bit)" in out
    assert "live estimates: identical (bit for bit)" in out
    assert "final estimate: identical (bit for bit)" in out
    assert main(["replay", str(db), "--method", "paper", "-o", str(tmp_path / "paper")]) == 0
    assert "final estimate: not stored for this method" in capsys.readouterr().out
    assert (tmp_path / "paper" / "predictions.csv").exists()

    csv = tmp_path / "logs.csv"
    assert main(["export", str(db), "-o", str(csv)]) == 0
    back = read_point_logs(csv)
    with SessionStore.open(db) as store:
        logs = store.point_logs()
    np.testing.assert_array_equal(back.xy_mm, logs.xy_mm)
    np.testing.assert_allclose(back.values, logs.values, rtol=0, atol=1e-9)


def test_replay_of_a_damaged_session_says_what_it_could_not_check(full_run, tmp_path, capsys):
    """Frames lost for one touch: replay still runs and says the re-cut was not possible;
    a damaged meta value: one line naming the file (both once tracebacks, found by fuzzing
    session files)."""
    _, db = full_run
    lost = tmp_path / "lost.db"
    shutil.copy(db, lost)
    with sqlite3.connect(lost) as conn:
        # The frames of an attempt a point log came from: under load a first attempt may
        # have failed and been retried, and losing its frames costs the re-cut nothing.
        first, last = conn.execute(
            "SELECT a.seq_first, a.seq_last FROM attempts a JOIN point_logs p "
            "ON p.attempt_id = a.id ORDER BY p.plan_index LIMIT 1"
        ).fetchone()
        conn.execute("DELETE FROM frames WHERE seq BETWEEN ? AND ?", (first, last))
    capsys.readouterr()
    assert main(["replay", str(lost)]) == 0
    assert "re-cut from raw frames: not possible for every touch" in capsys.readouterr().out
    bad = tmp_path / "bad.db"
    shutil.copy(db, bad)
    with sqlite3.connect(bad) as conn:
        conn.execute("UPDATE meta SET value = '{\"a\": 1}' WHERE key = 'truth_xy'")
    assert main(["replay", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.db: damaged session file" in err[0]
    odd = tmp_path / "odd.db"
    shutil.copy(db, odd)
    with sqlite3.connect(odd) as conn:
        conn.execute(
            "UPDATE meta SET value = json_set(value, '$.reference', 'touch') WHERE key = 'window'"
        )
    assert main(["replay", str(odd)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "odd.db: damaged session file (its touch window is" in err[0]


def _calibrating(launch: Path, db: Path, until_logs: int) -> subprocess.Popen:
    """``varskin calibrate`` in a child process of its own group (its simulated controller
    joins it), returned once ``db`` holds ``until_logs`` point logs."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "varskin", "calibrate", str(launch), "-o", str(db)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,
        # A killed session cannot remove its simulated board's device directory: keep it
        # under the test's own tmp_path instead of leaving one in /tmp per run.
        env={**os.environ, "TMPDIR": str(db.parent)},
    )
    try:
        deadline = time.monotonic() + 90
        while n_logs_in(db) < until_logs:
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline, "the session made no progress"
            time.sleep(0.05)
    except BaseException:
        os.killpg(proc.pid, signal.SIGKILL)
        raise
    return proc


def test_kill_9_then_resume_loses_and_duplicates_nothing(full_run, tmp_path):
    launch, full_db = full_run
    db = tmp_path / "killed.db"
    proc = _calibrating(launch, db, until_logs=10)
    try:
        os.kill(proc.pid, signal.SIGKILL)  # the session process only: its controller orphaned
        proc.wait(10)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    with SessionStore.open(db) as store:
        before = {s.plan_index: s.log.values.copy() for s in store.stored_logs()}
    assert 10 <= len(before) < N_TOUCHES

    assert main(["calibrate", "--resume", str(db)]) == 0
    with SessionStore.open(db) as store:
        stored = store.stored_logs()
        outcomes = store.outcomes()
        final = store.estimates("final", "peakfit")[N_TOUCHES]
        truth = np.asarray(store.meta()["truth_xy"])
        assert store.meta()["status"] == "complete"
    assert [s.plan_index for s in stored] == list(range(N_TOUCHES))  # none lost, none twice
    assert [o.plan_index for o in outcomes] == list(range(N_TOUCHES))
    for i, values in before.items():  # what was stored before the kill is untouched
        np.testing.assert_array_equal(stored[i].log.values, values)
    with SessionStore.open(full_db) as store:
        full = store.estimates("final", "peakfit")[N_TOUCHES]
    _, n_resumed = rms_error_mm(final, truth)
    _, n_full = rms_error_mm(full, truth)
    # the resumed run measured its second part anew (other noise), so: close, not equal.
    # The median, not the RMS: a few edge sensors 1-2 mm off make the RMS swing by 0.4 mm
    # between uninterrupted runs alone. The median swings too: 0.38-0.73 mm over 12
    # uninterrupted runs of this launch (2026-11-22; a full suite failed at 0.30 with
    # 0.35 resumed against 0.73 uninterrupted).
    assert abs(n_resumed - n_full) <= 4
    assert abs(median_error_mm(final, truth) - median_error_mm(full, truth)) < 0.45
    # sensor by sensor, the two answers agree within their own error bars
    a, b = final.by_name(), full.by_name()
    outside = 0
    for name, ea in a.items():
        eb = b[name]
        if ea.status == "ok" and eb.status == "ok":
            sd = np.hypot(ea.sigma_mm, eb.sigma_mm)  # per axis, of the difference
            outside += np.hypot(ea.x_mm - eb.x_mm, ea.y_mm - eb.y_mm) > 3 * sd
    assert outside <= 2  # P(r > 3 sd) is about 1 % per sensor


def median_error_mm(predictions, truth_xy: np.ndarray) -> float:
    """Median distance of the located sensors from the truth."""
    ok = np.array([e.status == "ok" for e in predictions.estimates])
    d = predictions.xy()[ok] - np.asarray(truth_xy)[ok]
    return float(np.median(np.hypot(d[:, 0], d[:, 1])))


def _running_in_group(pgid: int) -> list[int]:
    """Processes of a process group that still run (zombies, dead but not yet reaped by
    init, do not count)."""
    running = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            fields = stat.rsplit(")", 1)[1].split()  # after "pid (comm)": state, ppid, pgrp
            if int(fields[2]) == pgid and fields[0] != "Z":
                running.append(int(entry))
    return running


def test_sigterm_stops_the_session_as_ctrl_c_does(full_run, tmp_path):
    """A service manager's SIGTERM: the session ends through its ``finally`` blocks (the
    simulated controller it started is stopped, not orphaned), says how to resume, and the
    file resumes. With Python's default SIGTERM, none of that ran."""
    launch, _ = full_run
    db = tmp_path / "termed.db"
    proc = _calibrating(launch, db, until_logs=3)
    try:
        os.kill(proc.pid, signal.SIGTERM)
        assert proc.wait(30) == 130
        err = proc.stderr.read().decode()
        assert (
            f"interrupted; the session is saved: continue it with varskin calibrate --resume {db}"
            in err
        )
        deadline = time.monotonic() + 10
        while _running_in_group(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _running_in_group(proc.pid)  # no controller or board left orphaned
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    with SessionStore.open(db) as store:
        assert 3 <= store.n_point_logs() < N_TOUCHES
        assert store.meta()["status"] != "complete"


def _run_session(launch_path: Path, db: Path, fault, on_event):
    """A session driven from Python so a test can inject faults into the rig while it runs."""
    launch = load_launch(launch_path)
    with open_rig(launch) as rig:
        store = SessionStore.create(
            db, {"sensors": list(launch.patch.names), "method": "peakfit", "plan": {}}
        )
        planner = UniformPlanner(launch.patch, *FAULT_GRID, launch.plan.margin_mm).plan()
        session = CalibrationSession(rig, store, planner, SessionSettings(), on_event)
        stop = threading.Event()
        injector = threading.Thread(target=fault, args=(rig, store, stop), daemon=True)
        injector.start()
        try:
            result = session.run()
        finally:
            stop.set()
            injector.join(10)
            store.close()
    return result


def _wait_for_contact(rig, n_logs_at_least: int, stop: threading.Event, db: Path) -> bool:
    while not stop.is_set():
        if n_logs_in(db) >= n_logs_at_least and rig.controller.probe_state.get()[2] > 1.0:
            return True
        time.sleep(0.002)
    return False


def _dashboard(host: str, command: str) -> str:
    with socket.create_connection((host, 29999), timeout=5) as s:
        f = s.makefile("rwb")
        f.readline()  # welcome
        f.write(command.encode() + b"\n")
        f.flush()
        return f.readline().decode().strip()


def test_board_unplug_and_protective_stop_mid_touch(tmp_path):
    """One session, two faults while the probe presses: the board's USB cable comes out
    (that touch is retried), and later the arm protective-stops (the session pauses until
    someone unlocks it on the pendant, then retries the touch). Nothing is lost."""
    db = tmp_path / "faults.db"
    launch = write_launch(tmp_path / "sim_small.yaml", FAULT_GRID)
    unlocked_at: list[float] = []

    def faults(rig, store, stop):
        if _wait_for_contact(rig, 3, stop, db):
            rig.board.unplug()
            time.sleep(0.3)
            rig.board.replug()
        if _wait_for_contact(rig, 9, stop, db):
            rig.controller.inject_protective_stop()
            time.sleep(1.0)  # someone walks to the pendant
            unlocked_at.append(time.monotonic())
            _dashboard(rig.controller.host, "unlock protective stop")

    events: list[tuple[float, SessionEvent]] = []
    result = _run_session(launch, db, faults, lambda e: events.append((time.monotonic(), e)))
    with SessionStore.open(db) as store:
        attempts = store.attempts()
        gaps = store.gaps()
        stored = store.stored_logs()
    assert [s.plan_index for s in stored] == list(range(FAULT_N))  # every touch has its log
    assert result.n_failed == 0

    unplugged = [a for a in attempts if a.status == "board_gap" and "link down" in a.message]
    assert len(unplugged) == 1 and len(gaps) == 1
    retried = [a.status for a in attempts if a.plan_index == unplugged[0].plan_index]
    assert retried[0] == "board_gap" and retried[-1] == "ok"

    stopped = [a for a in attempts if a.status == "protective_stop"]
    assert len(stopped) == 1
    again = [a.status for a in attempts if a.plan_index == stopped[0].plan_index]
    assert again[0] == "protective_stop" and again[-1] == "ok"
    t_pause = next(t for t, e in events if e.kind == "pause")
    t_resume = next(t for t, e in events if e.kind == "resume")
    assert t_pause < unlocked_at[0] <= t_resume  # it waited for the unlock, not for a timer


def test_malformed_config_fails_before_anything_starts(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    started = []
    monkeypatch.setattr("varskin.rig.open_rig", lambda *a, **k: started.append(a))
    bad = write_launch(tmp_path / "bad.yaml", **{"touch.max_force_n": "lots"})
    assert main(["calibrate", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"varskin: error: {bad}: 'touch.max_force_n' is 'lots', not a number"]
    typo = write_launch(tmp_path / "typo.yaml", **{"plan.gird": "20x5"})
    assert main(["calibrate", str(typo)]) == 2
    assert "unknown key 'plan.gird'" in capsys.readouterr().err
    # a plan that reaches outside the safety envelope is refused before anything moves
    unsafe = write_launch(tmp_path / "unsafe.yaml", **{"envelope.depth_mm": 2.0})
    assert main(["calibrate", str(unsafe)]) == 2
    assert "varskin: error:" in capsys.readouterr().err
    assert started == [] and not (tmp_path / "sessions").exists()


def test_a_real_rig_needs_the_explicit_flag(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    started = []
    monkeypatch.setattr("varskin.rig.open_rig", lambda *a, **k: started.append(a))
    assert main(["calibrate", str(REPO / "launch" / "ur5e_muca.yaml")]) == 2
    assert "pass --real" in capsys.readouterr().err
    assert started == []


def test_resume_refuses_a_changed_launch_file(full_run, tmp_path, capsys):
    launch, db = full_run
    copy = tmp_path / "copy.db"
    copy.write_bytes(db.read_bytes())
    original = launch.read_text()
    try:
        launch.write_text(original + "\n# edited\n")
        assert main(["calibrate", "--resume", str(copy)]) == 2
        assert "changed since the session started" in capsys.readouterr().err
    finally:
        launch.write_text(original)


@pytest.mark.parametrize(
    "damage,words",
    [
        ("DELETE FROM point_logs WHERE plan_index = 3", "point logs do not match"),
        ("UPDATE point_logs SET y_mm = y_mm + 7.5 WHERE plan_index = 3", "point log 3 is at"),
        ("UPDATE outcomes SET x_mm = 'abc' WHERE plan_index = 3", "outcome 3: x_mm is 'abc'"),
        ("UPDATE meta SET value = '\"oops\"' WHERE key = 'wall_s'", "its wall_s is 'oops'"),
        ("DROP TABLE gaps", "no such table: gaps"),
        ("UPDATE meta SET value = 'null' WHERE key = 'method'", "its method is None"),
        (
            "UPDATE meta SET value = json_replace(value, '$[0]', 'S2', '$[1]', 'S1') "
            "WHERE key = 'sensors'",
            "its sensors are not its patch's",
        ),
        ("UPDATE point_logs SET t_s = 1e200 WHERE plan_index = 5", "point log 5: t_s"),
        (
            "UPDATE meta SET value = json_set(value, '$.order', 'zigzag') WHERE key = 'plan'",
            "damaged session file (its plan is",
        ),
    ],
)
def test_resume_refuses_a_damaged_file_before_anything_starts(
    full_run, tmp_path, capsys, monkeypatch, damage, words
):
    """Damage found by fuzzing ``calibrate --resume`` (each was a traceback, some after the
    rig had started): one line naming the file, exit 2, the file as it was."""
    started = []
    monkeypatch.setattr("varskin.rig.open_rig", lambda *a, **k: started.append(a))
    _, db = full_run
    copy = tmp_path / "damaged.db"
    shutil.copy(db, copy)
    with sqlite3.connect(copy) as c:
        c.execute(damage)
    before = copy.read_bytes()
    capsys.readouterr()
    assert main(["calibrate", "--resume", str(copy)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(copy) in err[0] and words in err[0], err
    assert started == [] and copy.read_bytes() == before


def test_a_uniform_plan_keeps_the_order_its_session_stored(tmp_path):
    """A small patch's plan is shuffled (``plan.order`` auto), and the order is stored with
    the plan, so a resumed session touches as it began; a session stored before plans had
    an order was swept, and resumes swept."""
    launch = load_launch(write_launch(tmp_path / "sim.yaml"))
    small = replace(
        launch,
        patch=patch_from_dict(
            {"name": "small", "size_mm": [48, 20], "tx_x_mm": [6, 24, 42], "rx_y_mm": [5, 15]},
            "<small>",
        ),
    )

    def touched(settings: dict) -> np.ndarray:
        return np.array([(t.x_mm, t.y_mm) for t in make_planner(small, stored_plan(settings))])

    stored = {"planner": "uniform", "budget": 100, "target_sigma_mm": None}
    swept = uniform_points(small.patch, *GRID, 3.0)
    np.testing.assert_array_equal(touched(stored), swept)
    shuffled = touched({**stored, "order": touch_order(small.patch, small.plan.order)})
    assert small.plan.order == "auto" and not np.array_equal(shuffled, swept)
    np.testing.assert_array_equal(shuffled, small.plan.points_mm(small.patch))


def test_a_session_stored_before_plans_had_an_order_resumes_swept(full_run, tmp_path, capsys):
    launch, db = full_run
    old = tmp_path / "old.db"
    shutil.copy(db, old)
    cut = N_TOUCHES - 3
    _as_killed_after(old, cut)
    with sqlite3.connect(old) as c:
        c.execute("UPDATE meta SET value = json_remove(value, '$.order') WHERE key = 'plan'")
    capsys.readouterr()
    assert main(["calibrate", "--resume", str(old)]) == 0
    err = capsys.readouterr().err
    assert "planner uniform (sweep order)" in err and f"resumed after {cut} plan touches" in err
    with SessionStore.open(old) as store:
        assert "order" not in store.meta()["plan"]
        xy = store.point_logs().xy_mm
    np.testing.assert_array_equal(
        xy, UniformPlanner(load_launch(launch).patch, *GRID, 3.0).points()
    )


def test_a_session_stored_before_logs_had_a_reference_resumes_against_its_baselines(
    full_run, tmp_path, capsys
):
    """Before 2026-11-29 a point log was the touch window minus the touch's own baseline
    window; such a session's window has no ``reference``. Resumed, its new logs are cut the
    same way, and replay re-cuts every log bit for bit, which it could not if the new ones
    were relative to the rest (the two differ by the drift and the baseline's noise)."""
    launch, db = full_run
    old = tmp_path / "old.db"
    shutil.copy(db, old)
    cut = N_TOUCHES - 3
    with SessionStore.open(old) as store:
        window = store.meta()["window"]
        assert window["reference"] == REST  # a new session's logs are relative to the rest
        before = replace(stored_window(window), reference=BASELINE)
        recut = recut_logs(store, load_launch(launch).patch, before)
    baseline_logs = {s.plan_index: log.values for s, log, _ in recut[:cut]}
    del window["reference"]
    _as_killed_after(old, cut)
    with sqlite3.connect(old) as c:
        c.execute("DELETE FROM estimates")  # made from the logs against the rest
        for i, values in baseline_logs.items():
            c.execute(
                "UPDATE point_logs SET value_blob = ? WHERE plan_index = ?",
                (np.ascontiguousarray(values, "<f8").tobytes(), i),
            )
        c.execute("UPDATE meta SET value = ? WHERE key = 'window'", (json.dumps(window),))
    assert main(["calibrate", "--resume", str(old)]) == 0
    with SessionStore.open(old) as store:
        assert store.meta()["window"]["reference"] == BASELINE
        assert len(store.point_logs()) == N_TOUCHES
    capsys.readouterr()
    assert main(["replay", str(old)]) == 0
    assert "point logs re-cut from raw frames: identical (bit for bit)" in capsys.readouterr().out


def test_a_small_patch_s_logs_are_taken_against_each_touch_s_baseline(tmp_path, capsys):
    """On a patch at most 50 mm long (its plan is shuffled) each sensor's own touches span
    the session, so against the rest the board's settling would flag sensors `drifting`:
    its logs are cut against each touch's baseline window, and replay re-cuts them so."""
    small = tmp_path / "small.yaml"
    small.write_text(
        yaml.safe_dump(
            {"name": "small", "size_mm": [40, 20], "tx_x_mm": [8, 20, 32], "rx_y_mm": [6, 14]}
        )
    )
    launch = write_launch(tmp_path / "sim.yaml", grid=(4, 2), patch=str(small))
    db = tmp_path / "small.db"
    assert main(["calibrate", str(launch), "-o", str(db)]) == 0
    with SessionStore.open(db) as store:
        assert store.meta()["window"]["reference"] == BASELINE
        assert store.meta()["plan"]["order"] == "shuffled"
    capsys.readouterr()
    assert main(["replay", str(db)]) == 0
    assert "point logs re-cut from raw frames: identical (bit for bit)" in capsys.readouterr().out


def test_adaptive_session_resumes_to_the_same_plan(tmp_path, capsys, monkeypatch):
    """An adaptive plan depends on every estimate so far; resuming a session re-feeds the
    stored point logs to the localizer and must land on exactly the stored touches (else the
    resume refuses). The planner gets the batch solves the session stored, not solved again:
    the only one the resume computes is the final estimate, and any stored one missing. A
    complete session resumes to its end without a new touch."""
    launch = write_launch(tmp_path / "sim_adaptive.yaml", **{"plan.mode": "adaptive"})
    db = tmp_path / "adaptive.db"
    # Every touch's estimate is the batch solve: no fast update is made only to be dropped.
    monkeypatch.setattr(Localizer, "update", lambda self, log: pytest.fail("update() called"))
    assert main(["calibrate", str(launch), "-o", str(db), "--budget", "28"]) == 0
    with SessionStore.open(db) as store:
        outcomes = store.outcomes()
        n_attempts = len(store.attempts())
        n_frames = store.n_frames()
    phases = [o.phase for o in outcomes]
    assert len(outcomes) <= 28 and phases[0] == "coarse" and "adaptive" in phases
    adaptive_xy = {(o.x_mm, o.y_mm) for o in outcomes if o.phase == "adaptive"}
    coarse_xy = {(o.x_mm, o.y_mm) for o in outcomes if o.phase == "coarse"}
    assert not adaptive_xy & coarse_xy  # off the coarse grid: chosen, not a grid
    capsys.readouterr()
    solved_from = []
    result = Localizer.result

    def counted(self):
        solved_from.append(self.n_logs)
        return result(self)

    monkeypatch.setattr(Localizer, "result", counted)
    assert main(["calibrate", "--resume", str(db)]) == 0
    assert f"resumed after {len(outcomes)} plan touches" in capsys.readouterr().err
    n_logs = sum(o.ok for o in outcomes)
    assert solved_from == [n_logs]  # the final estimate alone
    with SessionStore.open(db) as store:
        assert len(store.attempts()) == n_attempts  # the robot touched nothing more
        assert len(store.outcomes()) == len(outcomes)
        assert store.n_frames() >= n_frames
    # A stored estimate missing (a file from before they were read back) is solved again.
    with sqlite3.connect(db) as c:
        c.execute("DELETE FROM estimates WHERE stage = 'live' AND n_logs = 5")
    solved_from.clear()
    assert main(["calibrate", "--resume", str(db)]) == 0
    assert solved_from == [5, n_logs]


def _replays_bit_for_bit(db: Path, capsys) -> bool:
    capsys.readouterr()
    assert main(["replay", str(db)]) == 0
    out = capsys.readouterr().out
    return all(
        f"{stage}: identical (bit for bit)" in out
        for stage in ("point logs re-cut from raw frames", "live estimates", "final estimate")
    )


def test_refine_adds_touches_where_sensors_are_missing_and_resumes_as_a_refinement(
    tmp_path, capsys
):
    """``--resume --refine N`` on a finished session: its touches stay as they were, up to N
    adaptive ones follow where sensors are not yet located, replay still matches bit for bit,
    and a refinement stopped part way resumes to the same next touch."""
    launch = write_launch(tmp_path / "sim_sparse.yaml", grid=FAULT_GRID)
    db = tmp_path / "refine.db"
    assert main(["calibrate", str(launch), "-o", str(db)]) == 0
    with SessionStore.open(db) as store:
        first = store.outcomes()
        first_logs = {s.plan_index: s.log.values.copy() for s in store.stored_logs()}
        truth = np.asarray(store.meta()["truth_xy"])
        _, n_before = rms_error_mm(store.estimates("final", "peakfit")[FAULT_N], truth)
    assert n_before < 20  # a grid this sparse leaves sensors for the refinement

    capsys.readouterr()
    assert main(["calibrate", "--refine", "10"]) == 2
    assert "give --resume" in capsys.readouterr().err
    assert main(["calibrate", "--resume", str(db), "--target-sigma", "0.4"]) == 2
    assert "needs --refine" in capsys.readouterr().err
    unfinished = tmp_path / "unfinished.db"
    shutil.copy(db, unfinished)
    with sqlite3.connect(unfinished) as c:
        c.execute("UPDATE meta SET value = ? WHERE key = 'status'", ('"running"',))
    assert main(["calibrate", "--resume", str(unfinished), "--refine", "10"]) == 2
    assert "has not finished its plan" in capsys.readouterr().err
    assert main(["calibrate", "--resume", str(db), "--refine", "10"]) == 0
    with SessionStore.open(db) as store:
        outcomes = store.outcomes()
        stored = store.stored_logs()
        n_logs = len(stored)
        final = store.estimates("final", "peakfit")[n_logs]
        assert store.meta()["plan"]["planner"] == "refine"
        assert store.meta()["status"] == "complete"
    assert FAULT_N < len(outcomes) <= FAULT_N + 10
    assert outcomes[:FAULT_N] == first
    assert {o.phase for o in outcomes[FAULT_N:]} == {"adaptive"}
    for s in stored[:FAULT_N]:
        np.testing.assert_array_equal(s.log.values, first_logs[s.plan_index])
    _, n_after = rms_error_mm(final, truth)
    # 25 touches in all locate about 20 sensors; those at the edges, with sigmas of 1-3 mm,
    # are up to 6 mm off, so their RMS swings with host timing (1.1-1.7 mm in 6 runs) while
    # the median error stays at 0.7-1.0 mm
    median = median_error_mm(final, truth)
    assert n_after >= n_before + 8 and median < 1.5, (n_before, n_after, median)
    assert _replays_bit_for_bit(db, capsys)

    # Killed after three refinement touches: what a kill leaves is the store as it was
    # after that touch's commit (the session commits each touch whole).
    cut = FAULT_N + 3
    _as_killed_after(db, cut)
    capsys.readouterr()
    assert main(["calibrate", "--resume", str(db)]) == 0
    assert f"resumed after {cut} plan touches" in capsys.readouterr().err
    with SessionStore.open(db) as store:
        again = store.outcomes()
        assert [s.plan_index for s in store.stored_logs()] == list(range(len(again)))
    assert [o.plan_index for o in again] == list(range(len(again)))
    assert FAULT_N + 10 >= len(again) > cut
    assert again[: cut + 1] == outcomes[: cut + 1]  # the same next touch: nothing drifted
    assert _replays_bit_for_bit(db, capsys)


def test_live_view_draws_in_place_on_a_terminal_and_lines_in_a_log():
    import io

    from varskin.live_view import LiveView
    from varskin.predictions import Predictions, SensorEstimate

    p = Predictions(
        "peakfit",
        [SensorEstimate("S1", 1.0, 2.0, 0.2), SensorEstimate("S2", None, None, None, None, "weak")],
    )
    tty = io.StringIO()
    view = LiveView(4, tty, tty=True)
    for i in range(2):
        view(SessionEvent("point_log", plan_index=i, n_logs=i + 1, predictions=p))
    text = tty.getvalue()
    assert text.count("\x1b[3F") == 1  # the second drawing went back over the first
    assert "2/4" in text and "located 1/2, sigma median 0.20 max 0.20 mm" in text
    assert "weak" in text and "S1    1.0   2.0  0.20" in text

    log = io.StringIO()
    view = LiveView(4, log, tty=False, every=2)
    for i in range(4):
        view(SessionEvent("point_log", plan_index=i, n_logs=i + 1, predictions=p))
    view(SessionEvent("pause", "PAUSED at touch 3: protective stop"))
    lines = log.getvalue().splitlines()
    assert "\x1b" not in log.getvalue()
    assert len(lines) == 3 and "2/4" in lines[0] and "4/4" in lines[1]
    assert lines[2] == "PAUSED at touch 3: protective stop"


def test_a_session_stopped_by_a_fault_says_how_to_resume(tmp_path, capsys, monkeypatch):
    """The CLI's wiring: a fault that ends the session is one line naming the fault, and
    the same line says how to continue; the session file is left ready for --resume."""
    import contextlib
    import types

    from varskin.errors import ConnectionLost

    @contextlib.contextmanager
    def fake_rig(launch, allow_real=False):
        yield types.SimpleNamespace(time_scale=8.0, truth_xy=None, frame_latency_s=0.0)

    def lost(self):
        raise ConnectionLost("UR 127.0.0.9: connection lost during descent")

    monkeypatch.setattr("varskin.rig.open_rig", fake_rig)
    monkeypatch.setattr("varskin.session.CalibrationSession.__init__", lambda self, *a, **k: None)
    monkeypatch.setattr("varskin.session.CalibrationSession.run", lost)
    db = tmp_path / "stopped.db"
    assert main(["calibrate", str(write_launch(tmp_path / "l.yaml")), "-o", str(db)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (
        "varskin: error: UR 127.0.0.9: connection lost during descent; the session is saved: "
        f"continue it with varskin calibrate --resume {db}"
    )
    with SessionStore.open(db) as store:
        assert store.meta()["status"] == "running" and store.n_point_logs() == 0

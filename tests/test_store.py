"""The session store: a real SQLite file, bit-exact round trips, no duplicate point logs,
and nothing half-written after a killed process."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from varskin.board.frame import Frame, Gap
from varskin.errors import StoreError
from varskin.pointlogs import PointLog
from varskin.predictions import Predictions, SensorEstimate
from varskin.store import Attempt, Outcome, SessionStore, StoredLog

SENSORS = ["S1", "S2", "S3"]


def _store(tmp_path):
    return SessionStore.create(tmp_path / "s.db", {"sensors": SENSORS, "method": "peakfit"})


def _log(i: int, rng) -> PointLog:
    return PointLog(i, 1.0 + i, 2.0, rng.normal(0, 50, 3), 8, rng.random(3), 0.1 * i, 2.0)


def _preds(x: float) -> Predictions:
    return Predictions(
        "peakfit",
        [
            SensorEstimate("S1", x, 1.0, 0.1, 20.0),
            SensorEstimate("S2", None, None, None, None, "sparse"),
            SensorEstimate("S3", 3.0, x / 3, 0.2, None),
        ],
    )


def _touch(store: SessionStore, i: int, rng, ok: bool = True) -> PointLog:
    log = _log(i, rng)
    aid = store.add_attempt(
        Attempt(i, 1, log.x_mm, log.y_mm, "uniform", "ok" if ok else "no_contact")
    )
    store.commit_touch(
        Outcome(i, log.x_mm, log.y_mm, "uniform", ok),
        StoredLog(i, aid, 5, log) if ok else None,
        _preds(0.1 * i + 1 / 3) if ok else None,
    )
    return log


def test_round_trip_is_bit_exact(tmp_path):
    rng = np.random.default_rng(0)
    store = _store(tmp_path)
    cells = rng.integers(0, 65536, (21, 12)).astype(np.uint16)
    store.add_frames([Frame(0, 12.5, cells), Frame(1, 12.625, cells[::-1].copy())])
    store.add_gaps([Gap(13.0, 14.5, "unplugged", 12.625)])
    store.write_baseline(
        SENSORS, np.array([9000.5, 8000.25, 7000.0]), np.array([4.0, 5.0, 6.0]), 50
    )
    logs = [_touch(store, i, rng) for i in range(3)]
    store.close()

    again = SessionStore.open(tmp_path / "s.db")
    frames = list(again.frames())
    assert [f.seq for f in frames] == [0, 1]
    assert np.array_equal(frames[0].cells, cells) and frames[0].t == 12.5
    assert again.gaps()[0].reason == "unplugged"
    stored = again.stored_logs()
    for s, g in zip(stored, logs, strict=True):
        assert np.array_equal(s.log.values, g.values)  # exact, not approximately
        assert np.array_equal(s.log.sample_sd, g.sample_sd)
        assert s.n_baseline == 5
    pl = again.point_logs()
    assert pl.rest.tolist() == [9000.5, 8000.25, 7000.0]
    live = again.estimates("live")
    assert sorted(live) == [1, 2, 3]
    assert live[3].estimates[0].x_mm == 0.2 + 1 / 3  # float64 survives SQLite REAL
    assert live[3].estimates[1].status == "sparse" and live[3].estimates[1].x_mm is None
    assert again.meta()["sensors"] == SENSORS


def test_a_plan_index_is_stored_once(tmp_path):
    rng = np.random.default_rng(1)
    store = _store(tmp_path)
    _touch(store, 0, rng)
    with pytest.raises(StoreError, match="already stored"):
        _touch(store, 0, rng)
    # the failed commit rolled back its own rows and left the first one intact
    assert store.n_point_logs() == 1
    assert len(store.attempts()) == 1


def test_failed_touch_has_outcome_but_no_log(tmp_path):
    rng = np.random.default_rng(2)
    store = _store(tmp_path)
    _touch(store, 0, rng, ok=False)
    _touch(store, 1, rng)
    assert [o.ok for o in store.outcomes()] == [False, True]
    assert [s.plan_index for s in store.stored_logs()] == [1]


def test_create_refuses_existing_and_open_refuses_garbage(tmp_path):
    _store(tmp_path).close()
    with pytest.raises(StoreError, match="already exists"):
        _store(tmp_path)
    junk = tmp_path / "junk.db"
    junk.write_text("not sqlite at all\n" * 100)
    with pytest.raises(StoreError, match="not a varskin session"):
        SessionStore.open(junk)
    with pytest.raises(StoreError, match="no such session"):
        SessionStore.open(tmp_path / "missing.db")
    other = tmp_path / "other.db"
    sqlite3.connect(other).execute("CREATE TABLE t (a)").connection.commit()
    with pytest.raises(StoreError, match="not a varskin session"):
        SessionStore.open(other)


# A damaged file (found by fuzzing session files): each mutation, then the read that meets
# it, must end in one StoreError naming the file and saying what is wrong, not a traceback.
DAMAGE = [
    ("UPDATE meta SET value = 'garbage' WHERE key = 'method'", lambda s: s.meta(), "damaged"),
    ("DELETE FROM meta WHERE key = 'method'", lambda s: s.meta()["method"], "no 'method'"),
    ("UPDATE frames SET cells = x'00'", lambda s: list(s.frames()), "damaged"),
    ("UPDATE point_logs SET value_blob = x'01'", lambda s: s.point_logs(), "damaged"),
    ("DROP TABLE estimates", lambda s: s.estimates("live"), "damaged.*no such table"),
    ("UPDATE estimates SET status = 'two words'", lambda s: s.estimates("live"), "damaged"),
    ("DROP TABLE attempts", lambda s: s.attempt(1), "damaged"),
    # Wrong types in cells (SQLite keeps them): found by fuzzing ``calibrate --resume``,
    # where they met the resume as tracebacks.
    ("UPDATE outcomes SET x_mm = 'abc'", lambda s: s.outcomes(), "outcome 0: x_mm is 'abc'"),
    ("UPDATE point_logs SET t_s = 'abc'", lambda s: s.stored_logs(), "point log 0: t_s"),
    ("UPDATE point_logs SET y_mm = 9e18", lambda s: s.stored_logs(), "point log 0: y_mm"),
    ("UPDATE point_logs SET t_s = 1e200", lambda s: s.stored_logs(), "point log 0: t_s"),
    ("UPDATE baseline SET idx = 2 - idx", lambda s: s.baseline(), "baseline's sensors"),
    ("UPDATE baseline SET rest = 'x' WHERE idx = 1", lambda s: s.baseline(), "S2: rest"),
    ("UPDATE attempts SET t_settled = x'00'", lambda s: s.attempts(), "attempt 1: a time"),
    ("UPDATE frames SET seq = 9223372036854775807", lambda s: s.max_frame_seq(), "last frame"),
    # What only a resume checks (SessionStore.check): the plan's record and SQLite's own.
    ("DELETE FROM point_logs", lambda s: s.check(), "point logs do not match"),
    (
        "INSERT INTO outcomes VALUES (7, 1.0, 2.0, 'uniform', 0)",
        lambda s: s.check(),
        "plan touches are not 0, 1, 2",
    ),
    (
        "PRAGMA writable_schema=ON; DELETE FROM sqlite_master WHERE name='sqlite_autoindex_gaps_1'",
        lambda s: s.check(),
        "damaged session file",
    ),
    # Damage that keeps every type valid (left by the resume fuzzing): a point log no longer
    # agrees with its own touch, its attempt, or what a mean of counts can be.
    (
        "UPDATE point_logs SET x_mm = x_mm + 7.5",
        lambda s: s.check(),
        r"point log 0 is at \(8.5, 2\)",
    ),
    ("UPDATE attempts SET status = 'board_gap'", lambda s: s.check(), "names attempt 1, not its"),
    ("UPDATE point_logs SET attempt_id = 9", lambda s: s.check(), "names attempt 9, not its"),
    (
        f"UPDATE point_logs SET value_blob = x'{'000000000000f87f' * 3}'",
        lambda s: s.check(),
        "point log 0 holds values that are not finite",
    ),
    ("UPDATE point_logs SET n_samples = 0", lambda s: s.check(), "no samples"),
]


@pytest.mark.parametrize("mutation,read,words", DAMAGE)
def test_a_damaged_session_file_is_one_clear_error(tmp_path, mutation, read, words):
    rng = np.random.default_rng(4)
    store = _store(tmp_path)
    store.add_frames([Frame(0, 1.0, np.zeros((21, 12), np.uint16))])
    store.write_baseline(SENSORS, np.array([5000.0, 6000.0, 7000.0]), np.ones(3), 50)
    _touch(store, 0, rng)
    store.close()
    with sqlite3.connect(tmp_path / "s.db") as conn:
        conn.executescript(mutation)
    store = SessionStore.open(tmp_path / "s.db")
    with pytest.raises(StoreError, match=words) as caught:
        read(store)
    assert str(tmp_path / "s.db") in str(caught.value) and "\n" not in str(caught.value)
    store.close()


def test_a_write_the_file_cannot_take_is_one_clear_error(tmp_path):
    """A table gone under a resume: its next write says so, naming the file (a traceback
    before, found by fuzzing ``calibrate --resume``); what was committed stays."""
    rng = np.random.default_rng(5)
    store = _store(tmp_path)
    _touch(store, 0, rng)
    store.close()
    with sqlite3.connect(tmp_path / "s.db") as conn:
        conn.execute("DROP TABLE gaps")
    store = SessionStore.open(tmp_path / "s.db")
    with pytest.raises(StoreError, match="cannot write to the session file.*no such table"):
        store.add_gaps([Gap(1.0, 2.0, "timeout")])
    assert [s.plan_index for s in store.stored_logs()] == [0]
    store.close()


def test_a_damaged_schema_version_is_refused(tmp_path):
    _store(tmp_path).close()
    with sqlite3.connect(tmp_path / "s.db") as conn:
        conn.execute("UPDATE meta SET value = '{' WHERE key = 'schema_version'")
    with pytest.raises(StoreError, match="unsupported session file version"):
        SessionStore.open(tmp_path / "s.db")


def test_killed_writer_leaves_only_committed_touches(tmp_path):
    """A process killed with SIGKILL in the middle of a touch: the file opens, holds every
    committed touch, and nothing of the one in flight."""
    path = tmp_path / "k.db"
    script = textwrap.dedent(
        f"""
        import os, signal, numpy as np
        from varskin.board.frame import Frame
        from varskin.pointlogs import PointLog
        from varskin.store import Attempt, Outcome, SessionStore, StoredLog
        s = SessionStore.create({str(path)!r}, {{"sensors": ["S1", "S2", "S3"]}})
        for i in range(4):
            s.add_frames([Frame(i, float(i), np.full((21, 12), i, np.uint16))])
            aid = s.add_attempt(Attempt(i, 1, 1.0, 2.0, "uniform", "ok"))
            if i == 3:
                os.kill(os.getpid(), signal.SIGKILL)  # mid-touch: attempt and frame not committed
            log = PointLog(i, 1.0, 2.0, np.arange(3.0) + i, 8, np.ones(3), float(i), 2.0)
            s.commit_touch(Outcome(i, 1.0, 2.0, "uniform", True), StoredLog(i, aid, 4, log), None)
        """
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, timeout=60)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()
    assert os.path.exists(str(path) + "-wal")  # WAL mode: the log was never checkpointed
    store = SessionStore.open(path)
    assert [s.plan_index for s in store.stored_logs()] == [0, 1, 2]
    assert store.n_frames() == 3
    assert len(store.attempts()) == 3
    assert np.array_equal(store.stored_logs()[2].log.values, [2.0, 3.0, 4.0])

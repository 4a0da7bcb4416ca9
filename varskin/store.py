"""One SQLite file per calibration session, written so that a crash loses nothing.

A session runs unattended for many minutes on hardware that can fail at any moment (a
knocked cable, a protective stop, a killed process). Everything it learns goes into one
file: the launch and patch it ran with, every raw frame and link gap the recorder saw, every
touch attempt, the point logs cut from them and the estimates after each. The file is in WAL
mode and every touch is committed as one transaction (its frames, its attempt records, its
point log and the live estimates after it), so after ``kill -9`` the file holds exactly the
touches that finished, and ``--resume`` carries on from the first plan index without a point
log. Point logs are keyed by plan index, so one can never be stored twice.

Arrays are stored as little-endian blobs (``uint16`` frames, ``float64`` values), so what is
read back is bit for bit what was computed: replay depends on that.
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import json
import math
import re
import sqlite3
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from varskin.board.frame import N_RX, N_TX, Frame, Gap
from varskin.errors import StoreError
from varskin.patch import Patch, patch_from_dict
from varskin.pointlogs import MAX_COORD_MM, MAX_TIME_S, PointLog, PointLogs
from varskin.predictions import Predictions, SensorEstimate

SCHEMA_VERSION = 1

_SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE frames (seq INTEGER PRIMARY KEY, t REAL NOT NULL, cells BLOB NOT NULL);
CREATE TABLE gaps (start REAL NOT NULL, end REAL NOT NULL, reason TEXT NOT NULL,
                   PRIMARY KEY (start, end));
CREATE TABLE baseline (sensor TEXT PRIMARY KEY, idx INTEGER NOT NULL, rest REAL NOT NULL,
                       rest_sd REAL NOT NULL, n INTEGER NOT NULL);
CREATE TABLE attempts (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    plan_index INTEGER NOT NULL, attempt INTEGER NOT NULL,
    x_mm REAL NOT NULL, y_mm REAL NOT NULL, phase TEXT NOT NULL,
    status TEXT NOT NULL, message TEXT NOT NULL DEFAULT '',
    t_start REAL, t_contact REAL, t_settled REAL, t_release REAL, t_end REAL,
    peak_force_n REAL, mean_force_n REAL, seq_first INTEGER, seq_last INTEGER);
CREATE TABLE outcomes (plan_index INTEGER PRIMARY KEY, x_mm REAL NOT NULL, y_mm REAL NOT NULL,
                       phase TEXT NOT NULL, ok INTEGER NOT NULL);
CREATE TABLE point_logs (
    plan_index INTEGER PRIMARY KEY REFERENCES outcomes(plan_index),
    attempt_id INTEGER NOT NULL REFERENCES attempts(id),
    x_mm REAL NOT NULL, y_mm REAL NOT NULL, t_s REAL NOT NULL, force_n REAL NOT NULL,
    n_samples INTEGER NOT NULL, n_baseline INTEGER NOT NULL,
    value_blob BLOB NOT NULL, sd_blob BLOB NOT NULL);
CREATE TABLE estimates (
    stage TEXT NOT NULL, n_logs INTEGER NOT NULL, method TEXT NOT NULL, sensor TEXT NOT NULL,
    x_mm REAL, y_mm REAL, sigma_mm REAL, snr_db REAL, status TEXT NOT NULL,
    PRIMARY KEY (stage, n_logs, method, sensor));
"""


@dataclass(frozen=True)
class Attempt:
    """One try at one plan touch, as the session saw it (host monotonic times, s)."""

    plan_index: int
    attempt: int
    x_mm: float
    y_mm: float
    phase: str
    status: str  # "ok", "no_contact", "board_gap", "protective_stop", "force_limit", ...
    message: str = ""
    t_start: float | None = None
    t_contact: float | None = None
    t_settled: float | None = None
    t_release: float | None = None
    t_end: float | None = None
    peak_force_n: float | None = None
    mean_force_n: float | None = None
    seq_first: int | None = None  # the frames the attempt saw (host clocks restart on reboot;
    seq_last: int | None = None  # frame numbers in the store never do)
    id: int | None = None  # assigned by the store


@dataclass(frozen=True)
class StoredLog:
    """A point log with the bookkeeping that ties it to its plan touch and its attempt."""

    plan_index: int
    attempt_id: int
    n_baseline: int
    log: PointLog


@dataclass(frozen=True)
class Outcome:
    plan_index: int
    x_mm: float
    y_mm: float
    phase: str
    ok: bool


_SELECT_ATTEMPTS = (
    "SELECT plan_index, attempt, x_mm, y_mm, phase, status, message, t_start, t_contact, "
    "t_settled, t_release, t_end, peak_force_n, mean_force_n, seq_first, seq_last, id "
    "FROM attempts"
)  # in the field order of ``Attempt``


def _attempt(row: tuple) -> Attempt:
    i, n, x, y, ph, st, msg, *times, seq_first, seq_last, aid = row
    what = f"attempt {aid!r}"
    return Attempt(
        _whole(i, f"{what}: plan index"),
        _whole(n, f"{what}: number"),
        _real(x, f"{what}: x_mm", MAX_COORD_MM),
        _real(y, f"{what}: y_mm", MAX_COORD_MM),
        _text(ph, f"{what}: phase"),
        _text(st, f"{what}: status"),
        _text(msg, f"{what}: message"),
        *(_opt_real(t, f"{what}: a time or force") for t in times),
        _opt_whole(seq_first, f"{what}: first frame"),
        _opt_whole(seq_last, f"{what}: last frame"),
        _whole(aid, "an attempt's id"),
    )


def _frame(seq: int, t: float, cells: bytes) -> Frame:
    return Frame(int(seq), float(t), np.frombuffer(cells, "<u2").reshape(N_TX, N_RX).copy())


def _f64(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype="<f8").tobytes()


def _u16(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype="<u2").tobytes()


class _Meta(dict):
    """The session's meta values; a missing one is a damaged (or foreign) file, said so."""

    def __init__(self, path: Path, items: Iterable[tuple[str, object]]) -> None:
        super().__init__(items)
        self.path = path

    def __missing__(self, key: str):
        raise StoreError(f"{self.path}: damaged session file (no {key!r} in its meta)")


def _first_line(e: Exception) -> str:
    """What an error says, in one line for a one-line message."""
    return str(e).splitlines()[0] if str(e) else type(e).__name__


@contextlib.contextmanager
def _damaged_file(path: Path):
    """A read of a damaged file (a page overwritten, a table gone, a blob of the wrong size,
    a meta value that is not JSON) says so in one line naming the file, not a traceback:
    found by fuzzing session files for ``varskin replay`` and ``export``."""
    try:
        yield
    except (sqlite3.DatabaseError, ValueError, TypeError) as e:
        raise StoreError(f"{path}: damaged session file ({_first_line(e)})") from None


def _real(v: object, what: str, limit: float = math.inf) -> float:
    """A stored number that must be one (SQLite keeps whatever a damaged file holds), within
    ``limit`` in size (touch places and times: pointlogs.MAX_COORD_MM, MAX_TIME_S)."""
    number = isinstance(v, (int, float)) and not isinstance(v, bool)
    if not (number and math.isfinite(v) and abs(v) <= limit):
        raise ValueError(f"{what} is {v!r}")
    return float(v)


def _opt_real(v: object, what: str) -> float | None:
    return None if v is None else _real(v, what)


def _whole(v: object, what: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise ValueError(f"{what} is {v!r}")
    return v


def _opt_whole(v: object, what: str) -> int | None:
    return None if v is None else _whole(v, what)


def _text(v: object, what: str) -> str:
    if not isinstance(v, str):
        raise ValueError(f"{what} is {v!r}")
    return v


def _writes(fn: Callable) -> Callable:
    """``fn``, a write to the store: a file that cannot take it (a table gone, read-only,
    the disk full) says so in one line naming the file; what was committed stays."""

    @functools.wraps(fn)
    def write(self, *args, **kwargs):
        try:
            return fn(self, *args, **kwargs)
        except sqlite3.DatabaseError as e:
            raise StoreError(
                f"{self.path}: cannot write to the session file ({_first_line(e)})"
            ) from None

    return write


def _reads(fn: Callable) -> Callable:
    """``fn``, a read of the store, under ``_damaged_file`` (a generator for all it yields)."""
    if inspect.isgeneratorfunction(fn):

        @functools.wraps(fn)
        def each(self, *args, **kwargs):
            with _damaged_file(self.path):
                yield from fn(self, *args, **kwargs)

        return each

    @functools.wraps(fn)
    def read(self, *args, **kwargs):
        with _damaged_file(self.path):
            return fn(self, *args, **kwargs)

    return read


class SessionStore:
    """``SessionStore.create(path, meta)`` for a new session, ``SessionStore.open(path)`` to
    resume or read one. Use from one thread: the session drains the recorder's frames into
    it; the recorder thread never touches the connection."""

    def __init__(self, path: Path, conn: sqlite3.Connection) -> None:
        self.path = path
        self._conn = conn

    # --- opening ------------------------------------------------------------------------

    @classmethod
    def create(cls, path: str | Path, meta: dict[str, object]) -> SessionStore:
        path = Path(path)
        if path.exists():
            raise StoreError(
                f"{path}: already exists; resume it with --resume {path} or choose another -o"
            )
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            conn = cls._connect(path)
        except (OSError, sqlite3.Error) as e:
            raise StoreError(f"{path}: cannot create session store ({e})") from None
        try:
            with conn:
                conn.executescript(_SCHEMA)
                rows = {"schema_version": SCHEMA_VERSION, **meta}
                conn.executemany(
                    "INSERT INTO meta VALUES (?, ?)",
                    [(k, json.dumps(v)) for k, v in rows.items()],
                )
        except sqlite3.Error as e:
            conn.close()
            raise StoreError(f"{path}: cannot create session store ({e})") from None
        return cls(path, conn)

    @classmethod
    def open(cls, path: str | Path) -> SessionStore:
        path = Path(path)
        if not path.is_file():
            raise StoreError(f"{path}: no such session file")
        try:
            conn = cls._connect(path)
            version = conn.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
        except sqlite3.Error as e:
            raise StoreError(f"{path}: not a varskin session file ({e})") from None
        try:
            supported = version is not None and json.loads(version[0]) == SCHEMA_VERSION
        except ValueError:
            supported = False
        if not supported:
            conn.close()
            raise StoreError(f"{path}: unsupported session file version {version}")
        return cls(path, conn)

    @staticmethod
    def _connect(path: Path) -> sqlite3.Connection:
        conn = sqlite3.connect(path, timeout=10.0, isolation_level="DEFERRED")
        conn.execute("PRAGMA journal_mode=WAL")
        # NORMAL survives a killed process (the WAL is in the OS's hands after each commit);
        # only a power cut can lose the last transactions, never corrupt the file.
        conn.execute("PRAGMA synchronous=NORMAL")
        conn.execute("PRAGMA foreign_keys=ON")
        return conn

    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> SessionStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @_reads
    def check(self) -> None:
        """What a resume checks before it writes to the file: SQLite's own check of the
        pages and indexes (a file damaged below the tables' level can still answer every
        query), the schema's tables, and the plan's record, each point log included."""
        rows = self._conn.execute("PRAGMA quick_check").fetchall()
        if [r[0] for r in rows] != ["ok"]:
            raise StoreError(f"{self.path}: damaged session file ({rows[0][0]})")
        have = {
            r[0] for r in self._conn.execute("SELECT name FROM sqlite_master WHERE type='table'")
        }
        missing = sorted(set(re.findall(r"CREATE TABLE (\w+)", _SCHEMA)) - have)
        if missing:
            raise StoreError(f"{self.path}: damaged session file (no such table: {missing[0]})")
        # The plan's record: touches 0, 1, 2, ... closed in order, a point log for exactly
        # the ones that succeeded (a resume re-feeds them in that order).
        outcomes = self.outcomes()
        if [o.plan_index for o in outcomes] != list(range(len(outcomes))):
            raise StoreError(
                f"{self.path}: damaged session file (its plan touches are not 0, 1, 2, ...)"
            )
        stored = self.stored_logs()
        if [s.plan_index for s in stored] != [o.plan_index for o in outcomes if o.ok]:
            raise StoreError(
                f"{self.path}: damaged session file (its point logs do not match the touches "
                f"that succeeded)"
            )
        # Each point log is written with its outcome, from the same touch and the attempt
        # that made it, so its copies of them must agree exactly; its values are a mean of
        # whole counts. Damage that keeps every type valid shows here, if anywhere.
        attempts = {a.id: a for a in self.attempts()}
        for s in stored:
            o, g = outcomes[s.plan_index], s.log
            where = f"{self.path}: damaged session file (point log {s.plan_index}"
            if (g.x_mm, g.y_mm) != (o.x_mm, o.y_mm):
                raise StoreError(f"{where} is at ({g.x_mm:g}, {g.y_mm:g}) mm, its touch at "
                                 f"({o.x_mm:g}, {o.y_mm:g}) mm)")  # fmt: skip
            a = attempts.get(s.attempt_id)
            own = (s.plan_index, "ok", o.x_mm, o.y_mm)
            if a is None or (a.plan_index, a.status, a.x_mm, a.y_mm) != own:
                raise StoreError(f"{where} names attempt {s.attempt_id}, not its own ok one)")
            if not (np.isfinite(g.values).all() and np.isfinite(g.sample_sd).all()):
                raise StoreError(f"{where} holds values that are not finite)")
            if (g.sample_sd < 0).any() or g.n_samples < 1 or s.n_baseline < 1:
                raise StoreError(f"{where} holds a negative spread or no samples)")

    # --- metadata -----------------------------------------------------------------------

    @_reads
    def meta(self) -> dict[str, object]:
        rows = self._conn.execute("SELECT key, value FROM meta").fetchall()
        return _Meta(self.path, ((k, json.loads(v)) for k, v in rows))

    @_writes
    def set_meta(self, key: str, value: object) -> None:
        with self._conn:
            self._conn.execute(
                "INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, json.dumps(value))
            )

    # --- writing ------------------------------------------------------------------------

    @_writes
    def write_baseline(self, sensors: Iterable[str], rest: np.ndarray, rest_sd: np.ndarray, n: int):
        with self._conn:
            self._conn.executemany(
                "INSERT INTO baseline VALUES (?, ?, ?, ?, ?)",
                [
                    (s, i, float(r), float(sd), int(n))
                    for i, (s, r, sd) in enumerate(zip(sensors, rest, rest_sd, strict=True))
                ],
            )

    @_writes
    def add_frames(self, frames: Iterable[Frame]) -> None:
        """Insert frames (not committed: the next ``commit_touch`` or ``commit`` does it)."""
        self._conn.executemany(
            "INSERT OR IGNORE INTO frames VALUES (?, ?, ?)",
            [(f.seq, f.t, _u16(f.cells)) for f in frames],
        )

    @_writes
    def add_gaps(self, gaps: Iterable[Gap]) -> None:
        self._conn.executemany(
            "INSERT OR IGNORE INTO gaps VALUES (?, ?, ?)",
            [(g.start, g.end, g.reason) for g in gaps],
        )

    @_writes
    def add_attempt(self, a: Attempt) -> int:
        """Insert an attempt record (not committed) and return its id."""
        cur = self._conn.execute(
            "INSERT INTO attempts (plan_index, attempt, x_mm, y_mm, phase, status, message, "
            "t_start, t_contact, t_settled, t_release, t_end, peak_force_n, mean_force_n, "
            "seq_first, seq_last) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (
                a.plan_index, a.attempt, a.x_mm, a.y_mm, a.phase, a.status, a.message,
                a.t_start, a.t_contact, a.t_settled, a.t_release, a.t_end,
                a.peak_force_n, a.mean_force_n, a.seq_first, a.seq_last,
            ),
        )  # fmt: skip
        return int(cur.lastrowid)

    @_writes
    def commit_touch(
        self,
        outcome: Outcome,
        stored: StoredLog | None,
        estimates: Predictions | None,
    ) -> None:
        """Close one plan touch: its outcome, its point log (if it succeeded) and the live
        estimates after it, committed together with everything added since the last commit.
        A plan index already closed is an error: it would duplicate a point log."""
        try:
            self._conn.execute(
                "INSERT INTO outcomes VALUES (?, ?, ?, ?, ?)",
                (outcome.plan_index, outcome.x_mm, outcome.y_mm, outcome.phase, int(outcome.ok)),
            )
            if stored is not None:
                g = stored.log
                self._conn.execute(
                    "INSERT INTO point_logs VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    (
                        stored.plan_index, stored.attempt_id, g.x_mm, g.y_mm, g.t_s, g.force_n,
                        g.n_samples, stored.n_baseline, _f64(g.values), _f64(g.sample_sd),
                    ),
                )  # fmt: skip
            if estimates is not None:
                self._insert_estimates("live", self.n_point_logs(), estimates)
        except sqlite3.IntegrityError as e:
            self._conn.rollback()
            raise StoreError(
                f"{self.path}: plan touch {outcome.plan_index} is already stored ({e})"
            ) from None
        self._conn.commit()

    @_writes
    def write_final(self, predictions: Predictions) -> None:
        with self._conn:
            self._conn.execute(
                "DELETE FROM estimates WHERE stage='final' AND method=?", (predictions.method,)
            )
            self._insert_estimates("final", self.n_point_logs(), predictions)

    @_writes
    def commit(self) -> None:
        self._conn.commit()

    def rollback(self) -> None:
        self._conn.rollback()

    def _insert_estimates(self, stage: str, n_logs: int, p: Predictions) -> None:
        self._conn.executemany(
            "INSERT INTO estimates VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            [
                (stage, n_logs, p.method, e.sensor, e.x_mm, e.y_mm, e.sigma_mm, e.snr_db, e.status)
                for e in p.estimates
            ],
        )

    # --- reading ------------------------------------------------------------------------

    @_reads
    def sensors(self) -> tuple[str, ...]:
        return tuple(self.meta()["sensors"])  # type: ignore[arg-type]

    @_reads
    def patch(self) -> Patch:
        """The patch exactly as the session ran it (its YAML is kept in the file), so a
        session replays without the checkout it was recorded with."""
        meta = self.meta()
        if "patch_yaml" not in meta:
            raise StoreError(f"{self.path}: the session file holds no patch")
        patch = patch_from_dict(yaml.safe_load(str(meta["patch_yaml"])), f"{self.path}:patch")
        if tuple(patch.names) != tuple(meta["sensors"]):  # type: ignore[arg-type]
            raise StoreError(f"{self.path}: its stored patch does not list the session's sensors")
        return patch

    @_reads
    def baseline(self) -> tuple[np.ndarray, np.ndarray, int] | None:
        rows = self._conn.execute(
            "SELECT sensor, rest, rest_sd, n FROM baseline ORDER BY idx"
        ).fetchall()
        if not rows:
            return None
        if tuple(r[0] for r in rows) != self.sensors():
            raise ValueError("its baseline's sensors are not the session's, in order")
        rest = [_real(r[1], f"baseline of {r[0]}: rest") for r in rows]
        sd = [_real(r[2], f"baseline of {r[0]}: rest_sd") for r in rows]
        n = {_whole(r[3], f"baseline of {r[0]}: frames") for r in rows}
        if min(sd) < 0 or len(n) != 1 or min(n) < 1:
            raise ValueError("its baseline's spreads or frame counts are not valid")
        return np.array(rest), np.array(sd), n.pop()

    @_reads
    def n_point_logs(self) -> int:
        return int(self._conn.execute("SELECT COUNT(*) FROM point_logs").fetchone()[0])

    @_reads
    def outcomes(self) -> list[Outcome]:
        out = []
        for i, x, y, ph, ok in self._conn.execute(
            "SELECT plan_index, x_mm, y_mm, phase, ok FROM outcomes ORDER BY plan_index"
        ):
            what = f"outcome {i!r}"
            if ok not in (0, 1):
                raise ValueError(f"{what}: ok is {ok!r}")
            out.append(
                Outcome(
                    _whole(i, "an outcome's plan index"),
                    _real(x, f"{what}: x_mm", MAX_COORD_MM),
                    _real(y, f"{what}: y_mm", MAX_COORD_MM),
                    _text(ph, f"{what}: phase"),
                    bool(ok),
                )
            )
        return out

    @_reads
    def stored_logs(self) -> list[StoredLog]:
        n = len(self.sensors())
        out = []
        for row in self._conn.execute(
            "SELECT plan_index, attempt_id, x_mm, y_mm, t_s, force_n, n_samples, n_baseline, "
            "value_blob, sd_blob FROM point_logs ORDER BY plan_index"
        ):
            i, aid, x, y, t, f, ns, nb, vb, sb = row
            what = f"point log {i!r}"
            i = _whole(i, "a point log's plan index")
            values = np.frombuffer(vb, "<f8").astype(np.float64)
            sd = np.frombuffer(sb, "<f8").astype(np.float64)
            if len(values) != n or len(sd) != n:
                raise StoreError(f"{self.path}: point log {i} has {len(values)} values, not {n}")
            log = PointLog(
                i,
                _real(x, f"{what}: x_mm", MAX_COORD_MM),
                _real(y, f"{what}: y_mm", MAX_COORD_MM),
                values,
                _whole(ns, f"{what}: n_samples"),
                sd,
                _real(t, f"{what}: t_s", MAX_TIME_S),  # a session times every touch
                _opt_real(f, f"{what}: force_n"),
            )
            out.append(
                StoredLog(
                    i, _whole(aid, f"{what}: attempt"), _whole(nb, f"{what}: n_baseline"), log
                )
            )
        return out

    @_reads
    def point_logs(self) -> PointLogs:
        """Every stored point log, in plan order, with the session's rest values."""
        base = self.baseline()
        rest, rest_sd = (base[0], base[1]) if base else (None, None)
        return PointLogs.from_logs(
            self.sensors(),
            [s.log for s in self.stored_logs()],
            rest=rest,
            rest_sd=rest_sd,
            source=str(self.path),
        )

    @_reads
    def attempts(self, plan_index: int | None = None) -> list[Attempt]:
        sql = _SELECT_ATTEMPTS
        args: tuple = ()
        if plan_index is not None:
            sql += " WHERE plan_index=?"
            args = (plan_index,)
        return [_attempt(row) for row in self._conn.execute(sql + " ORDER BY id", args)]

    @_reads
    def attempt(self, attempt_id: int) -> Attempt:
        row = self._conn.execute(_SELECT_ATTEMPTS + " WHERE id=?", (attempt_id,)).fetchone()
        if row is None:
            raise StoreError(f"{self.path}: no attempt {attempt_id}")
        return _attempt(row)

    @_reads
    def frames_by_seq(self, first: int, last: int) -> list[Frame]:
        rows = self._conn.execute(
            "SELECT seq, t, cells FROM frames WHERE seq >= ? AND seq <= ? ORDER BY seq",
            (first, last),
        )
        return [_frame(*row) for row in rows]

    @_reads
    def frames(self) -> Iterator[Frame]:
        for row in self._conn.execute("SELECT seq, t, cells FROM frames ORDER BY seq"):
            yield _frame(*row)

    @_reads
    def n_frames(self) -> int:
        return int(self._conn.execute("SELECT COUNT(*) FROM frames").fetchone()[0])

    @_reads
    def max_frame_seq(self) -> int:
        row = self._conn.execute("SELECT MAX(seq) FROM frames").fetchone()
        if row[0] is None:
            return -1
        # Frames are numbered from 0 at ~10 per second: 2**53 is beyond any session (the
        # next frame's number must still fit SQLite's integer).
        if _whole(row[0], "the last frame's number") >= 2**53:
            raise ValueError(f"the last frame's number is {row[0]}")
        return row[0]

    @_reads
    def gaps(self) -> list[Gap]:
        return [
            Gap(s, e, r)
            for s, e, r in self._conn.execute("SELECT start, end, reason FROM gaps ORDER BY start")
        ]

    @_reads
    def estimates(
        self, stage: str, method: str | None = None, after_logs: int | None = None
    ) -> dict[int, Predictions]:
        """Stored estimates of a stage ("live" or "final"), keyed by the number of point logs
        they were computed from; with ``after_logs``, only those from more logs than that."""
        sql = "SELECT n_logs, method, sensor, x_mm, y_mm, sigma_mm, snr_db, status FROM estimates"
        sql += " WHERE stage=?" + (" AND method=?" if method else "")
        args: tuple = (stage, method) if method else (stage,)
        if after_logs is not None:
            sql += " AND n_logs > ?"
            args += (after_logs,)
        order = {s: i for i, s in enumerate(self.sensors())}
        by_n: dict[int, Predictions] = {}
        for n, m, s, x, y, sig, snr, st in self._conn.execute(sql, args):
            p = by_n.setdefault(int(n), Predictions(m, []))
            p.estimates.append(SensorEstimate(s, x, y, sig, snr, st))
        for p in by_n.values():
            p.estimates.sort(key=lambda e: order.get(e.sensor, 0))
        return dict(sorted(by_n.items()))

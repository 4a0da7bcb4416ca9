"""The point-log CSV: the interchange format every tool of the project reads and writes.

Users share recordings as plain CSV, so this module is the one place that knows the format:

* header ``touch,x_mm,y_mm[,t_s][,force_n],<sensor>,<sensor>,...``;
* one row per board frame; rows sharing an integer ``touch`` id are samples of one touch
  at (``x_mm``, ``y_mm``) and are averaged into one point log;
* rows whose ``touch`` is ``baseline`` (x and y empty) are no-contact frames: their mean is
  each sensor's rest value S0 and their standard deviation sigma0; without them the values
  are taken as already relative to rest (and SNR cannot be computed).

Recordings reach 100,000 rows, so a file is validated with cheap whole-file checks and
parsed numerically in bulk; only when that fails does a slow row-by-row pass run, to name
the first bad cell as ``FILE:LINE:COLUMN: what is wrong``.
"""

from __future__ import annotations

import csv
import io
import re
import warnings as _warnings
from pathlib import Path

import numpy as np

from varskin.errors import InputError, PointLogFormatError
from varskin.pointlogs import MAX_COORD_MM, MAX_TIME_S, PointLogs, average_samples
from varskin.table_csv import finite_cell, read_table

KEY_COLUMNS = ("touch", "x_mm", "y_mm")
RESERVED_COLUMNS = ("t_s", "force_n")
BASELINE = "baseline"
MIN_LOCATIONS = 3  # a 2-D interpolant needs a triangle of distinct probe points


class _Layout:
    """Where each kind of column sits in one file's header (0-based indices)."""

    def __init__(self, path: str, header: list[str]) -> None:
        self.path = path
        self.names = header
        for i, want in enumerate(KEY_COLUMNS):
            got = header[i] if i < len(header) else None
            if got != want:
                found = "nothing" if got is None else repr(got)
                raise _error(
                    path, 1, i + 1, f"header column {i + 1} must be {want!r}, found {found}"
                )
        self.reserved: dict[str, int] = {}
        col = len(KEY_COLUMNS)
        while col < len(header) and header[col] in RESERVED_COLUMNS:
            if header[col] in self.reserved:
                raise _error(path, 1, col + 1, f"column {header[col]!r} appears twice")
            self.reserved[header[col]] = col
            col += 1
        self.sensor_cols = list(range(col, len(header)))
        if not self.sensor_cols:
            raise _error(path, 1, len(header) + 1, "no sensor columns after the key columns")
        seen: dict[str, int] = {}
        for c in self.sensor_cols:
            name = header[c]
            if not name:
                raise _error(path, 1, c + 1, "empty sensor name")
            if name in KEY_COLUMNS or name in RESERVED_COLUMNS:
                raise _error(
                    path,
                    1,
                    c + 1,
                    f"reserved column {name!r} among the sensors "
                    "(t_s and force_n must directly follow y_mm)",
                )
            if name in seen:
                raise _error(
                    path,
                    1,
                    c + 1,
                    f"duplicate sensor name {name!r} (first in column {seen[name] + 1})",
                )
            seen[name] = c
        self.sensors = tuple(header[c] for c in self.sensor_cols)
        self.n_fields = len(header)

    def column_name(self, col: int) -> str:
        return self.names[col]


def _error(path: str, line: int, column: int, what: str) -> PointLogFormatError:
    return PointLogFormatError(f"{path}:{line}:{column}: {what}")


# --- reading ----------------------------------------------------------------------------


def read_point_logs(path: str | Path) -> PointLogs:
    """Load a point-log CSV: average each touch's samples and subtract the baseline.

    Warnings (skipped non-finite samples, dropped touches) are in ``PointLogs.warnings``;
    every format mistake raises ``PointLogFormatError`` naming file, line and column.
    """
    name = str(path)
    try:
        raw = Path(path).read_bytes()
    except OSError as e:
        raise PointLogFormatError(f"{name}: cannot read ({e.strerror or e})") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise _error(name, line, 1, "not UTF-8 text") from None
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise _error(name, 1, 1, "empty file: expected a header touch,x_mm,y_mm,<sensor>,...")
    header = [h.strip() for h in next(csv.reader([lines[0]]))]
    layout = _Layout(name, header)

    # Body lines (blank lines tolerated) with their 1-based line numbers.
    rows = lines[1:]
    line_no = np.arange(2, len(rows) + 2, dtype=np.int64)
    blank = [not r or r.isspace() for r in rows]
    if any(blank):
        keep = ~np.array(blank)
        rows = [r for r, b in zip(rows, blank, strict=True) if not b]
        line_no = line_no[keep]
    if not rows:
        raise _error(name, 2, 1, "no data rows after the header")

    try:
        parsed = _parse_fast(layout, rows, line_no)
    except ValueError as e:
        _locate_error(layout, rows, line_no, e)  # raises PointLogFormatError
        raise  # pragma: no cover - _locate_error always raises
    touch, xy, samples, t_s, force_n, baseline, touch_lines = parsed

    if len(touch) == 0:
        raise _error(name, int(line_no[-1]), 1, "no touch rows (only baseline rows)")
    _check_positions(layout, touch, xy, touch_lines)

    warnings: list[str] = []
    if baseline is not None:
        bad = ~np.isfinite(baseline)
        if bad.any():
            warnings.append(f"{name}: skipped {int(bad.sum())} non-finite baseline sample(s)")
            empty = bad.all(axis=0)
            if empty.any():
                c = layout.sensor_cols[int(np.argmax(empty))]
                raise _error(
                    name,
                    int(line_no[-1]),
                    c + 1,
                    f"sensor {layout.names[c]!r} has no finite baseline sample",
                )

        lonely = (np.isfinite(baseline).sum(axis=0) < 2).sum()
        if lonely:
            warnings.append(
                f"{name}: {int(lonely)} sensor(s) have fewer than 2 finite baseline samples: "
                "sigma0 unknown, SNR left empty"
            )
    with _warnings.catch_warnings():
        # numpy's "degrees of freedom" warning for a one-row baseline is reported above.
        _warnings.simplefilter("ignore", RuntimeWarning)
        logs = average_samples(
            layout.sensors,
            touch,
            xy,
            samples,
            baseline=baseline,
            t_s=t_s,
            force_n=force_n,
            source=name,
        )
    logs.warnings[:0] = warnings
    n_locations = len(np.unique(logs.xy_mm, axis=0)) if len(logs) else 0
    if n_locations < MIN_LOCATIONS:
        raise _error(
            name,
            int(line_no[-1]),
            2,
            f"only {n_locations} distinct probe location(s) with valid samples; "
            f"localization needs at least {MIN_LOCATIONS}",
        )
    return logs


def _parse_fast(layout: _Layout, rows: list[str], line_no: np.ndarray):
    """Bulk parse; any ValueError sends the caller to the slow pass that names the cell."""
    commas = layout.n_fields - 1
    if any(r.count(",") != commas for r in rows):
        raise ValueError("field count")
    # Cells may carry spaces around them (the slow pass strips them too).
    firsts = [r.partition(",")[0] for r in rows]
    is_base = [f.strip() == BASELINE for f in firsts]
    if any(is_base):
        base_rows = [r for r, b in zip(rows, is_base, strict=True) if b]
        touch_rows = [r for r, b in zip(rows, is_base, strict=True) if not b]
        touch_firsts = [f for f, b in zip(firsts, is_base, strict=True) if not b]
    else:
        base_rows, touch_rows, touch_firsts = [], rows, firsts
    if any(r.split(",", 3)[1].strip() or r.split(",", 3)[2].strip() for r in base_rows):
        raise ValueError("baseline position")

    baseline = None
    if base_rows:
        baseline = np.loadtxt(
            base_rows, delimiter=",", comments=None, ndmin=2, usecols=layout.sensor_cols
        )
        for col in layout.reserved.values():
            # Reserved cells of baseline rows may be empty or numbers; nothing else.
            cells = [r.split(",", col + 1)[col].strip() for r in base_rows]
            filled = [c for c in cells if c]
            if filled:
                np.array(filled, dtype=np.str_).astype(float)

    k = len(touch_rows)
    if k:
        touch = np.array(touch_firsts).astype(np.int64)
        data = np.loadtxt(
            touch_rows, delimiter=",", comments=None, ndmin=2, usecols=range(1, layout.n_fields)
        )
    else:
        touch = np.zeros(0, np.int64)
        data = np.zeros((0, layout.n_fields - 1))
    xy = data[:, 0:2]
    t_s = data[:, layout.reserved["t_s"] - 1] if "t_s" in layout.reserved else None
    force_n = data[:, layout.reserved["force_n"] - 1] if "force_n" in layout.reserved else None
    for a in (xy, t_s, force_n):
        if a is not None and not np.isfinite(a).all():
            raise ValueError("non-finite key")
    if (np.abs(xy) > MAX_COORD_MM).any():
        raise ValueError("coordinate beyond range")
    if t_s is not None and (np.abs(t_s) > MAX_TIME_S).any():
        raise ValueError("time beyond range")
    samples = data[:, [c - 1 for c in layout.sensor_cols]]
    touch_lines = line_no[~np.array(is_base, dtype=bool)]
    return touch, xy, samples, t_s, force_n, baseline, touch_lines


def _locate_error(layout: _Layout, rows: list[str], line_no: np.ndarray, cause: Exception):
    """Walk the rows one by one and raise the first format mistake, with its place."""
    path = layout.path
    n = layout.n_fields
    reserved_cols = set(layout.reserved.values())
    for row, line in zip(rows, line_no.tolist(), strict=True):
        fields = row.split(",")
        if len(fields) != n:
            col = min(len(fields), n) + 1
            raise _error(path, line, col, f"{len(fields)} fields, the header has {n}")
        first = fields[0].strip()
        base = first == BASELINE
        if not base:
            try:
                int(first)
            except ValueError:
                raise _error(
                    path, line, 1, f"touch {first!r} is neither an integer nor {BASELINE!r}"
                ) from None
        for col, cell in enumerate(fields[1:], start=1):
            name = layout.names[col]
            cell = cell.strip()
            key = col in (1, 2) or col in reserved_cols
            if base and col in (1, 2):
                if cell:
                    raise _error(
                        path, line, col + 1, f"baseline rows leave {name} empty, found {cell!r}"
                    )
                continue
            if base and key and not cell:
                continue
            try:
                value = float(cell)
            except ValueError:
                what = "empty cell" if not cell else f"{cell!r} is not a number"
                raise _error(path, line, col + 1, f"{what} in column {name!r}") from None
            if key and not np.isfinite(value):
                raise _error(path, line, col + 1, f"{name} must be a finite number, found {cell!r}")
            if col == layout.reserved.get("t_s") and abs(value) > MAX_TIME_S:
                raise _error(path, line, col + 1, f"t_s {cell} is beyond {MAX_TIME_S:g} s")
            if col in (1, 2) and abs(value) > MAX_COORD_MM:
                raise _error(
                    path, line, col + 1,
                    f"{name} {cell} is beyond {MAX_COORD_MM:g} mm (coordinates are mm in the "
                    f"patch frame)",
                )  # fmt: skip
    # The bulk parser refused something the cell-by-cell rules accept (an exotic number
    # spelling, say): report the place numpy names.
    m = re.search(r"row (\d+), column (\d+)", str(cause))
    if m:
        r = min(int(m.group(1)), len(rows) - 1)
        raise _error(path, int(line_no[r]), int(m.group(2)) + 1, f"cannot parse: {cause}")
    raise PointLogFormatError(f"{path}: cannot parse: {cause}")


def _check_positions(layout: _Layout, touch, xy, touch_lines) -> None:
    """One touch id means one probe position; a second position is a recording mistake."""
    _, first, inverse = np.unique(touch, return_index=True, return_inverse=True)
    expected = xy[first][inverse]
    differs = expected != xy
    bad = differs.any(axis=1)
    if bad.any():
        r = int(np.argmax(bad))
        col = 2 if differs[r, 0] else 3
        f = int(first[inverse[r]])
        raise _error(
            layout.path,
            int(touch_lines[r]),
            col,
            f"touch {int(touch[r])} is at ({xy[r, 0]:g}, {xy[r, 1]:g}) here but at "
            f"({xy[f, 0]:g}, {xy[f, 1]:g}) on line {int(touch_lines[f])}",
        )


# --- writing ----------------------------------------------------------------------------


def _cells(a: np.ndarray) -> list[list[str]]:
    """Text cells: integers where the data are whole counts, else shortest exact floats."""
    a = np.asarray(a, float)
    if a.size and np.isfinite(a).all() and (a == np.round(a)).all() and np.abs(a).max() < 2**53:
        return [[str(v) for v in row] for row in a.astype(np.int64).tolist()]
    return [[str(v) for v in row] for row in a.tolist()]


def write_samples_csv(path: str | Path, session) -> None:
    """Write a ``SimulatedSession`` frame by frame: baseline rows first, then every touch frame."""
    sensors = session.sensors
    header = ["touch", "x_mm", "y_mm", "t_s", "force_n", *sensors]
    base = _cells(session.baseline)
    frames = _cells(session.samples)
    out = io.StringIO()
    out.write(",".join(header) + "\n")
    for t, cells in zip(np.asarray(session.baseline_t).tolist(), base, strict=True):
        out.write(f"{BASELINE},,,{t},0," + ",".join(cells) + "\n")
    rows = zip(
        np.asarray(session.touch).tolist(),
        np.asarray(session.xy_mm).tolist(),
        np.asarray(session.t_s).tolist(),
        np.asarray(session.force_n).tolist(),
        frames,
        strict=True,
    )
    for k, (x, y), t, f, cells in rows:
        out.write(f"{k},{x},{y},{t},{f}," + ",".join(cells) + "\n")
    Path(path).write_text(out.getvalue())


def write_point_logs_csv(path: str | Path, logs: PointLogs) -> None:
    """Write one averaged row per touch (values relative to rest; no baseline rows)."""
    header = ["touch", "x_mm", "y_mm"]
    extra = []
    if logs.t_s is not None:
        header.append("t_s")
        extra.append(np.asarray(logs.t_s, float))
    if logs.force_n is not None:
        header.append("force_n")
        extra.append(np.asarray(logs.force_n, float))
    header.extend(logs.sensors)
    values = [[str(v) for v in row] for row in np.asarray(logs.values, float).tolist()]
    keys = np.column_stack([np.asarray(logs.xy_mm, float), *extra]).tolist()
    out = io.StringIO()
    out.write(",".join(header) + "\n")
    for k, key, cells in zip(np.asarray(logs.touch).tolist(), keys, values, strict=True):
        out.write(f"{k}," + ",".join(str(v) for v in key) + "," + ",".join(cells) + "\n")
    Path(path).write_text(out.getvalue())


# --- truth ------------------------------------------------------------------------------


def write_truth_csv(path: str | Path, sensors, xy_mm: np.ndarray) -> None:
    """The true sensor positions, ``sensor,x_mm,y_mm``, named as in the point logs."""
    xy = np.asarray(xy_mm, float)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["sensor", "x_mm", "y_mm"])
        for name, (x, y) in zip(sensors, xy.tolist(), strict=True):
            w.writerow([name, f"{x:.4f}", f"{y:.4f}"])


def read_truth_csv(path: str | Path) -> dict[str, tuple[float, float]]:
    """Read ``sensor,x_mm,y_mm`` into {sensor: (x, y)} in file order."""
    columns = ("sensor", "x_mm", "y_mm")
    truth: dict[str, tuple[float, float]] = {}
    first_line: dict[str, int] = {}
    for ln, row in read_table(path, columns):
        sensor = row[0]
        if not sensor:
            raise InputError(f"{path}:{ln}:1: empty sensor name")
        if sensor in truth:
            raise InputError(
                f"{path}:{ln}:1: sensor {sensor!r} repeated (first on line {first_line[sensor]})"
            )
        x, y = (finite_cell(path, ln, col, columns[col], row[col]) for col in (1, 2))
        truth[sensor] = (x, y)
        first_line[sensor] = ln
    if not truth:
        raise InputError(f"{path}:2:1: no sensors after the header")
    return truth

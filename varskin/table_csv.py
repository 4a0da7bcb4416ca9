"""Small header-checked CSV tables (truth and prediction files) with located errors.

The point-log CSV has its own fast reader; the per-sensor tables are a few dozen rows, so
clarity wins: every mistake is an ``InputError`` naming the file, line and column.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterator
from pathlib import Path

from varskin.errors import InputError


def read_table(path: str | Path, columns: tuple[str, ...]) -> Iterator[tuple[int, list[str]]]:
    """Yield ``(line number, stripped cells)`` of every non-blank data row.

    The header must start with ``columns``; every row must have the header's field count.
    """
    name = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{name}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or not any(c.strip() for c in rows[0]):
        raise InputError(f"{name}:1:1: empty file: expected a header {','.join(columns)}")
    header = [c.strip() for c in rows[0]]
    for i, want in enumerate(columns):
        if i >= len(header) or header[i] != want:
            found = repr(header[i]) if i < len(header) else "nothing"
            raise InputError(
                f"{name}:1:{i + 1}: header column {i + 1} must be {want!r}, found {found}"
            )
    for ln, row in enumerate(rows[1:], start=2):
        if not any(c.strip() for c in row):
            continue
        if len(row) != len(header):
            col = min(len(row), len(header)) + 1
            raise InputError(f"{name}:{ln}:{col}: {len(row)} fields, the header has {len(header)}")
        yield ln, [c.strip() for c in row]


def finite_cell(
    path: str | Path, line: int, col: int, column: str, cell: str, empty_ok: bool = False
) -> float | None:
    """The cell as a finite float (``col`` is 0-based); empty gives None where allowed."""
    if not cell and empty_ok:
        return None
    try:
        v = float(cell)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        allowed = "a finite number or empty" if empty_ok else "a finite number"
        raise InputError(f"{path}:{line}:{col + 1}: {column} must be {allowed}, found {cell!r}")
    return v

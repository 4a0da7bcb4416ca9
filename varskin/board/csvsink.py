"""Writes recorded frames to CSV, the plain-text record ``varskin board record`` leaves.

One row per frame: ``t_s`` (seconds since the sink was created, host monotonic clock),
``seq`` and either the patch's sensors (raw counts as sent, in patch sensor order) or all
252 cells (``c<row>_<col>`` in the order sent). Rows reach the file at least every
``flush_interval_s`` (0.25 s), so a killed recording loses at most that much; at the real
board's 8 frames/s a count-based flush would have risked seconds of data.
"""

from __future__ import annotations

import csv
import time
from pathlib import Path

from varskin.board.cellmap import CellMap
from varskin.board.frame import N_RX, N_TX, Frame, Gap
from varskin.errors import InputError


class FrameCsvSink:
    def __init__(
        self,
        path: str | Path,
        cellmap: CellMap | None = None,
        t0: float | None = None,
        flush_interval_s: float = 0.25,
    ):
        self.path = Path(path)
        self.cellmap = cellmap
        self.t0 = time.monotonic() if t0 is None else t0
        self.flush_interval_s = flush_interval_s
        self._last_flush = time.monotonic()
        self.rows = 0
        self.gaps: list[Gap] = []
        try:
            self._f = self.path.open("w", newline="")
        except OSError as e:
            raise InputError(f"{self.path}: cannot write ({e.strerror or e})") from None
        self._w = csv.writer(self._f)
        if cellmap is not None:
            names = list(cellmap.names)
        else:
            names = [f"c{r}_{c}" for r in range(N_TX) for c in range(N_RX)]
        self._w.writerow(["t_s", "seq", *names])

    def __call__(self, event: Frame | Gap) -> None:
        if isinstance(event, Gap):
            self.gaps.append(event)
            return
        values = self.cellmap.raw(event) if self.cellmap is not None else event.cells.reshape(-1)
        self._w.writerow([f"{event.t - self.t0:.6f}", event.seq, *values.tolist()])
        self.rows += 1
        now = time.monotonic()
        if now - self._last_flush >= self.flush_interval_s:
            self._f.flush()
            self._last_flush = now

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()

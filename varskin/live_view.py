"""What an operator watches during a calibration: a progress bar and a per-sensor table.

It is a plain consumer of the session's ``SessionEvent`` stream. On a terminal it redraws
the table in place after every point log (estimate, sigma and status of every sensor); into
a pipe or a log file it writes one line per notable event and a summary line every few
touches, so CI logs stay readable. Pauses and failures are always printed in full.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

import numpy as np

from varskin.predictions import OK, Predictions
from varskin.session import SessionEvent


def sensor_table(p: Predictions, columns: int = 3) -> list[str]:
    """The per-sensor table as text lines, several sensors per line to fit a terminal."""
    cells = []
    for e in p.estimates:
        if e.status == OK:
            sig = f"{e.sigma_mm:5.2f}" if e.sigma_mm is not None else "    -"
            cells.append(f"{e.sensor:>4} {e.x_mm:6.1f} {e.y_mm:5.1f} {sig}   ok       ")
        else:
            cells.append(f"{e.sensor:>4}      -     -     -   {e.status:<9}")
    head = "sens  x mm  y mm  sd mm status   "
    rows = [" | ".join([head] * min(columns, max(len(cells), 1)))]
    for i in range(0, len(cells), columns):
        rows.append(" | ".join(cells[i : i + columns]))
    return rows


def summary(p: Predictions) -> str:
    ok = [e for e in p.estimates if e.status == OK]
    sig = [e.sigma_mm for e in ok if e.sigma_mm is not None]
    med = f", sigma median {np.median(sig):.2f} max {max(sig):.2f} mm" if sig else ""
    return f"located {len(ok)}/{len(p.estimates)}{med}"


class LiveView:
    def __init__(
        self, total: int, stream: TextIO | None = None, tty: bool | None = None, every: int = 10
    ) -> None:
        self.total = max(int(total), 1)
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty() if tty is None else tty
        self.every = every
        self._drawn = 0  # lines of the last in-place drawing
        self._t0 = time.monotonic()
        self._last: Predictions | None = None

    def __call__(self, ev: SessionEvent) -> None:
        if ev.kind == "point_log" and ev.predictions is not None:
            self._last = ev.predictions
            if self.tty:
                self._redraw(ev)
            elif ev.n_logs % self.every == 0:
                self._line(f"{self._bar_text(ev)}  {summary(ev.predictions)}")
        elif ev.kind in ("pause", "resume", "failed", "attempt", "baseline"):
            self._line(ev.message)
        elif ev.kind == "final" and ev.predictions is not None:
            self._drawn = 0
            self._line("final estimate (batch solve of every point log):")
            for row in sensor_table(ev.predictions):
                self._line(row)
            self._line(summary(ev.predictions))

    def _bar_text(self, ev: SessionEvent) -> str:
        done = (ev.plan_index or 0) + 1
        frac = min(done / self.total, 1.0)
        bar = "#" * int(30 * frac)
        return f"touch [{bar:<30}] {done}/{self.total} {time.monotonic() - self._t0:6.1f} s"

    def _redraw(self, ev: SessionEvent) -> None:
        lines = [self._bar_text(ev) + f"  {summary(ev.predictions)}"]
        lines += sensor_table(ev.predictions)
        out = self.stream
        if self._drawn:
            out.write(f"\x1b[{self._drawn}F")  # back to the top of the last drawing
        for line in lines:
            out.write("\x1b[2K" + line + "\n")
        out.flush()
        self._drawn = len(lines)

    def _line(self, text: str) -> None:
        self._drawn = 0  # anything printed below the drawing ends in-place redrawing
        self.stream.write(text + "\n")
        self.stream.flush()

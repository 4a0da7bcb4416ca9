"""A dependency-free progress bar for long work (benchmarks, calibration sessions).

Draws on stderr only when it is a terminal, so logs and CI output stay clean.
"""

from __future__ import annotations

import sys
import time


class Progress:
    def __init__(self, total: int, label: str = "", stream=None, enabled: bool | None = None):
        self.total = max(int(total), 1)
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self.done = 0
        self.suffix = ""
        self._t0 = time.monotonic()

    def update(self, n: int = 1, suffix: str | None = None) -> None:
        self.done = min(self.done + n, self.total)
        if suffix is not None:
            self.suffix = suffix
        if self.enabled:
            frac = self.done / self.total
            bar = "#" * int(30 * frac)
            elapsed = time.monotonic() - self._t0
            self.stream.write(
                f"\r{self.label} [{bar:<30}] {self.done}/{self.total} {elapsed:5.1f}s {self.suffix}"
            )
            self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

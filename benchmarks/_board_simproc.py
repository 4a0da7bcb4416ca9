"""Runs ``varskin board sim`` in a subprocess so its CPU is not counted with the recorder's."""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path


class SimProcess:
    def __init__(self, rate_hz: float, patch: str = "patch_b", extra: tuple[str, ...] = ()):
        self._dir = tempfile.TemporaryDirectory(prefix="varskin-bench-")
        self.path = str(Path(self._dir.name) / "ttyMUCA0")
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "varskin",
                "board",
                "sim",
                "--patch",
                patch,
                "--rate",
                str(rate_hz),
                "--baud",
                "0",
                "--stamp-seq",
                "--link",
                self.path,
                *extra,
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        line = self.proc.stdout.readline().strip()
        if line != self.path:
            self.close()
            raise RuntimeError(f"board sim did not start: {line!r}")
        self.summary = ""

    def close(self) -> str:
        if self.proc.poll() is None:
            self.proc.send_signal(subprocess.signal.SIGINT)
        try:
            _, err = self.proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
        self._dir.cleanup()
        self.summary = err.strip().splitlines()[-1] if err.strip() else ""
        return self.summary

    def __enter__(self) -> SimProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

"""The suite's own safety rules: a test that needs real hardware runs only with --hardware,
and then in this one process, never beside other workers (pyproject runs the suite with
one pytest-xdist worker per core)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
REAL_ARM_TEST = (
    "tests/test_ur_arm.py::test_real_arm_reports_status_and_zeroes_its_force_sensor_without_moving"
)


def _pytest(*args: str) -> str:
    # No robot address: the hardware test must skip, whatever this machine's environment
    # says; and the options are pyproject's and the arguments' alone.
    env = {k: v for k, v in os.environ.items() if k not in ("VARSKIN_UR_HOST", "PYTEST_ADDOPTS")}
    out = subprocess.run(
        [sys.executable, "-m", "pytest", "-v", "-p", "no:cacheprovider", *args, REAL_ARM_TEST],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    return out.stdout


def test_without_the_flag_the_hardware_test_is_skipped_in_a_worker():
    out = _pytest()
    assert "needs --hardware" in out
    assert "[gw" in out  # the default run is spread over workers (gw0, gw1, ...)


@pytest.mark.parametrize("workers", [[], ["-n", "2"]])
def test_with_the_flag_the_hardware_test_runs_in_one_process(workers):
    out = _pytest("--hardware", *workers)
    assert "set VARSKIN_UR_HOST" in out  # it ran, and stopped at the missing address
    assert "[gw" not in out  # no worker: --hardware overrides -n

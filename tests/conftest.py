"""Shared fixtures, the opt-in markers for hardware and long-running tests, and how the
suite shares the machine's cores."""

from __future__ import annotations

import os

# Each pytest-xdist worker (pyproject's `-n auto`) takes one core. Set before numpy loads
# here; the workers and any session a test starts inherit it. With OpenBLAS's own thread
# pool in every worker the two cores were oversubscribed: the suite took 266 s instead of
# 233 s (docs/benchmarks.md, "The test suite's time").
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import pytest  # noqa: E402

from varskin.patch import builtin_patch, patch_from_dict  # noqa: E402


def pytest_addoption(parser):
    parser.addoption(
        "--hardware", action="store_true", help="run tests that need a real UR arm or Muca board"
    )
    parser.addoption("--slow", action="store_true", help="run long soaks and benchmark-sized tests")


@pytest.hookimpl(tryfirst=True)
def pytest_cmdline_main(config):
    # Real hardware is driven by one process at a time, and its tests do not share the CPU
    # with the localizer's: --hardware runs the whole selection in this one process.
    if config.getoption("--hardware"):
        config.option.numprocesses = 0


def pytest_collection_modifyitems(config, items):
    for marker, flag in (("hardware", "--hardware"), ("slow", "--slow")):
        if config.getoption(flag):
            continue
        skip = pytest.mark.skip(reason=f"needs {flag}")
        for item in items:
            if marker in item.keywords:
                item.add_marker(skip)


@pytest.fixture(scope="session")
def patch_b():
    return builtin_patch("patch_b")


@pytest.fixture(scope="session")
def patch_a():
    return builtin_patch("patch_a")


@pytest.fixture(scope="session")
def full_board():
    """A full Muca board: 21 TX x 12 RX wires, 252 sensors on 300 x 200 mm (as
    benchmarks/localizer_scale.py's)."""
    return patch_from_dict(
        {
            "name": "muca_full",
            "size_mm": [300.0, 200.0],
            "tx_x_mm": [7.0 + 13.6 * i for i in range(21)],
            "rx_y_mm": [8.0 + 16.7 * j for j in range(12)],
        },
        "<full board>",
    )

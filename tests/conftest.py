"""Shared fixtures and the opt-in markers for hardware and long-running tests."""

from __future__ import annotations

import pytest

from varskin.patch import builtin_patch


def pytest_addoption(parser):
    parser.addoption(
        "--hardware", action="store_true", help="run tests that need a real UR arm or Muca board"
    )
    parser.addoption("--slow", action="store_true", help="run long soaks and benchmark-sized tests")


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

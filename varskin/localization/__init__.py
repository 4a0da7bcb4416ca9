"""Localization methods behind one call: ``localize(logs, method=..., **params)``.

Each method lives in its own module exposing ``localize(logs, **params) -> Predictions``;
this registry imports it on first use so a CLI call loads only what it runs.
"""

from __future__ import annotations

import importlib

from varskin.errors import InputError
from varskin.pointlogs import PointLogs
from varskin.predictions import Predictions

# name -> module path; the first entry of DEFAULT_METHOD is what users get without --method.
METHODS: dict[str, str] = {
    "peakfit": "varskin.localization.peakfit",
    "paper": "varskin.localization.paper",
}
DEFAULT_METHOD = "peakfit"


def localize(logs: PointLogs, method: str | None = None, **params) -> Predictions:
    """Localize every sensor of ``logs`` with the named method (default: the best one)."""
    method = method or DEFAULT_METHOD
    if method not in METHODS:
        raise InputError(f"unknown method {method!r}: choose one of {', '.join(METHODS)}")
    module = importlib.import_module(METHODS[method])
    return module.localize(logs, **params)

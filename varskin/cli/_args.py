"""Argument types that several commands share, so they refuse bad values the same way:
with argparse's one-line usage error, before anything runs."""

from __future__ import annotations

import argparse
import math


def _whole(text: str, lowest: int, what: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = lowest - 1
    if value < lowest:
        raise argparse.ArgumentTypeError(f"{what} must be an integer >= {lowest}, got {text!r}")
    return value


def seed(text: str) -> int:
    """A random seed: an integer >= 0 (numpy refuses negative ones deep inside a run)."""
    return _whole(text, 0, "seed")


def positive(text: str) -> float:
    """A duration, rate or size: a finite number > 0 ("nan" and "-1" parse as floats)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def count(text: str) -> int:
    """A number of things to do: an integer >= 1."""
    return _whole(text, 1, "N")

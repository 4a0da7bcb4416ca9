"""Argument types that several commands share, so they refuse bad values the same way:
with argparse's one-line usage error, before anything runs."""

from __future__ import annotations

import argparse
import math


def seed(text: str) -> int:
    """A random seed: an integer >= 0 (numpy refuses negative ones deep inside a run)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"seed must be an integer >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"seed must be an integer >= 0, got {text!r}")
    return value


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
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return value

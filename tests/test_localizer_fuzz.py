"""Degenerate inputs through the Python API: a status or an InputError, never a crash.

The hard cases (test_localizer_hard_cases.py) each pin one scene; this throws seeded
random ones at both methods and at live updates: noise maps from a few touches, probes on
a line or stacked on one point, constant or extreme values (1e-12 to 1e30), NaN and inf
cells, a log without a position, float32, baselines at the ADC's ends, zero sample sds.
Fuzzing like this found a singular touch step in peakfit and qhull's ValueError in the
paper method.
"""

from __future__ import annotations

import contextlib

import numpy as np
import pytest

from varskin.errors import VarskinError
from varskin.localization import localize
from varskin.localization.peakfit import Localizer
from varskin.pointlogs import PointLogs
from varskin.predictions import OK

OPTIONS = [{}, {"solver": "joint"}, {"inverted": True}, {"spacing_mm": 0.01}]


def random_logs(rng: np.random.Generator) -> PointLogs:
    k, n = int(rng.integers(0, 20)), int(rng.integers(1, 6))
    xy = rng.uniform(0.0, 50.0, (k, 2))
    kind = int(rng.integers(0, 5))
    if kind == 0:  # noise
        values = rng.normal(0.0, 1.0, (k, n))
    elif kind == 1:  # probes on a line, some on one point
        xy = np.column_stack([rng.integers(0, 3, k) * 5.0, np.zeros(k)])
        values = rng.normal(0.0, 100.0, (k, n))
    elif kind == 2:  # constant
        values = np.full((k, n), float(rng.choice([0.0, 1.0, -5.0])))
    elif kind == 3:  # extreme scales
        values = rng.normal(0.0, 1.0, (k, n)) * float(rng.choice([1e-12, 1e12, 1e30]))
    else:  # a bump with NaN and inf cells
        values = 300.0 / (1.0 + ((xy[:, :1] - 25.0) ** 2 + (xy[:, 1:] - 25.0) ** 2) / 81.0)
        values = values + rng.normal(0.0, 5.0, (k, n))
        bad = rng.random((k, n)) < 0.3
        values[bad] = rng.choice([np.nan, np.inf, -np.inf], int(bad.sum()))
    if k and rng.random() < 0.2:
        xy[rng.integers(0, k)] = np.nan
    extra = {}
    if rng.random() < 0.4:
        extra["rest"] = float(rng.choice([0.0, 5000.0, 65535.0])) + rng.normal(0.0, 10.0, n)
        extra["rest_sd"] = np.abs(rng.normal(0.0, float(rng.choice([0.0, 1.0, 100.0])), n))
    if rng.random() < 0.3:
        extra["sample_sd"] = np.abs(rng.normal(0.0, float(rng.choice([0.0, 1.0])), (k, n)))
    dtype = np.float32 if kind != 3 and rng.random() < 0.3 else np.float64
    return PointLogs(
        tuple(f"S{i + 1}" for i in range(n)),
        np.arange(k),
        xy,
        values.astype(dtype),
        np.ones(k, int),
        **extra,
    )


def valid(pred, n: int) -> None:
    assert len(pred) == n
    for e in pred:  # SensorEstimate itself refuses NaN and inf
        assert e.status and " " not in e.status
        assert (e.x_mm is not None) == (e.status == OK)


@pytest.mark.parametrize("block", range(4))
def test_random_degenerate_inputs_give_statuses_or_input_errors(block):
    rng = np.random.default_rng(1000 + block)
    for _ in range(12):
        logs = random_logs(rng)
        options = OPTIONS[int(rng.integers(0, len(OPTIONS)))]
        for method, params in (("peakfit", options), ("paper", {})):
            with contextlib.suppress(VarskinError):
                valid(localize(logs, method=method, **params), logs.n_sensors)
        with contextlib.suppress(VarskinError):
            loc = Localizer(logs.sensors, rest=logs.rest, rest_sd=logs.rest_sd, **options)
            for log in logs.logs():
                valid(loc.update(log), logs.n_sensors)


def test_a_probe_absurdly_far_from_the_others_gives_statuses_not_a_crash():
    """One probe at 9.2e18 mm (a damaged session file's point log): the probes' scatter
    looks two-dimensional but qhull finds them flat; that was a QhullError from peakfit's
    hull (found by fuzzing ``calibrate --resume``)."""
    gx, gy = np.meshgrid(np.linspace(3, 47, 5), np.linspace(3, 22, 3))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    values = 300.0 / (1.0 + ((xy[:, :1] - 25.0) ** 2 + (xy[:, 1:] - 12.0) ** 2) / 81.0)
    xy[1, 1] = 9.223372036854776e18
    logs = PointLogs(("S1",), np.arange(len(xy)), xy, values, np.ones(len(xy), int))
    for method in ("peakfit", "paper"):
        with contextlib.suppress(VarskinError):
            valid(localize(logs, method=method), 1)
    loc = Localizer(logs.sensors)
    for log in logs.logs():
        valid(loc.update(log), 1)
    valid(loc.result(), 1)


def test_a_touch_time_no_session_has_is_taken_as_untimed():
    """A t_s of 1e200 s (finite, so not caught as NaN): the drift model over such times was
    singular, a LinAlgError from the fit (found by fuzzing ``calibrate --resume``)."""
    import dataclasses

    from varskin.patch import builtin_patch
    from varskin.simulate import simulate_session, uniform_grid

    patch = builtin_patch("patch_b")
    s = simulate_session(patch, uniform_grid(patch, 5, 3), probe="robot", seed=0)
    logs = s.point_logs()
    changed = [dataclasses.replace(g, t_s=1e200) if g.touch == 3 else g for g in logs.logs()]
    logs = PointLogs.from_logs(logs.sensors, changed, logs.rest, logs.rest_sd)
    valid(localize(logs), logs.n_sensors)
    loc = Localizer(logs.sensors, rest=logs.rest, rest_sd=logs.rest_sd)
    for log in logs.logs():
        valid(loc.update(log), logs.n_sensors)

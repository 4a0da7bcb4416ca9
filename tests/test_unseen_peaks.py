"""Peaks no touch came near: how much of a peak the touches saw, and the response shapes'
spread in the error bar of the ones they did not (varskin/localization/_unseen.py)."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest

from varskin.localization import _design_reach, _live_update, _unseen, localize, peakfit
from varskin.localization import _peak_model as pm
from varskin.localization._statuses import SPARSE, WEAK, judge
from varskin.patch import patch_from_dict
from varskin.planning import uniform_points
from varskin.pointlogs import PointLog
from varskin.predictions import OK
from varskin.simulate import simulate_session, simulate_touch, uniform_grid


def _localizer_with_touches(points, values):
    """A Localizer holding one sensor's readings at ``points`` (no solve)."""
    loc = peakfit.Localizer(["S1"])
    for k, ((x, y), v) in enumerate(zip(points, values, strict=True)):
        loc._append(PointLog(touch=k + 1, x_mm=x, y_mm=y, values=np.array([v])))
    return loc


def _theta(x, y, half_width):
    th = np.zeros((1, pm.N_PARAMS))
    th[0, [pm.SX, pm.SY]] = x, y
    th[0, [pm.LW, pm.LWY]] = np.log(half_width)
    th[0, pm.AMP] = 1.0
    return th


@pytest.mark.parametrize("shape", ["lorentzian", "gaussian"])
def test_seen_height_is_the_bump_at_the_nearest_usable_touch(shape):
    loc = _localizer_with_touches([(0.0, 0.0), (10.0, 0.0), (30.0, 0.0)], [5.0, 5.0, 5.0])
    loc.settings = replace(loc.settings, shape=shape)
    # On a touch: all of it. One half width from the nearest touch: half of it, whatever
    # the shape (the profile's definition).
    assert _unseen.seen_height(loc, _theta(10.0, 0.0, 3.0))[0] == pytest.approx(1.0)
    assert _unseen.seen_height(loc, _theta(13.0, 0.0, 3.0))[0] == pytest.approx(0.5)
    # A touch whose reading is missing saw nothing; nor did a touch judged missed.
    loc._V[1, 0] = np.nan
    far = _unseen.seen_height(loc, _theta(13.0, 0.0, 3.0))[0]
    assert far == pytest.approx(float(pm.profile(np.array(13.0**2 / 3.0**2), 0.0, shape)))
    assert far < _unseen.UNSEEN_FRACTION
    loc._V[1, 0] = 5.0
    loc._missed[1] = True
    assert _unseen.seen_height(loc, _theta(13.0, 0.0, 3.0))[0] == pytest.approx(far)


def test_on_a_dense_grid_every_located_peak_is_seen(patch_b):
    """The 20 x 5 grids the accuracy targets are set on: nothing to add to any sigma."""
    for probe in ("robot", "finger"):
        s = simulate_session(patch_b, uniform_grid(patch_b, 20, 5), probe, 3)
        pred = localize(s.point_logs(), patch=patch_b)
        named = pred.params.get("shape_spread_mm", {})
        assert not [e.sensor for e in pred if e.status == OK and e.sensor in named]


def test_where_no_sensor_has_enough_touches_the_seen_peaks_give_the_footprint(patch_b):
    """A 10 x 4 finger grid of cell centres over Patch B (seed 1, no patch): no sensor's fit
    has the 2 x N_PARAMS effective touches the shared footprint is taken from. With every
    width free, four `ok` peaks no touch saw a quarter of were fitted 0.25-0.37 as wide as
    the median, between two columns; `ok` calls were up to 8.1 mm and 6.6 sigma off. The
    footprint then comes from the peaks a touch saw half of, held looser than a
    well-measured one."""
    s = simulate_session(patch_b, uniform_grid(patch_b, 10, 4), "finger", 1)
    loc = peakfit.solved(s.point_logs())
    pred = loc.result()
    assert loc.fit.n_eff.max() < 2 * pm.N_PARAMS
    assert loc.shared_lw is not None
    assert loc.settings.shared_width_sd == peakfit.SEEN_FOOTPRINT_SD
    ok = np.array([e.status == OK for e in pred])
    assert ok.sum() >= 20
    width = pm.half_width(loc.fit.theta)[ok]
    assert width.min() > 0.4 * np.median(width)
    assert _unseen.seen_height(loc, loc.fit.theta)[ok].min() > 0.4
    assert np.hypot(*(pred.xy()[ok] - s.truth[ok]).T).max() < 5.0


def test_a_peak_between_far_touches_holds_the_shapes_spread_in_its_error_bar(patch_b, monkeypatch):
    """An 8 x 3 plan (the adaptive planner's coarse pass) leaves 21 mm between columns. The
    sensors whose peaks no touch came near are named with their spread and their sigmas
    grow by it, and their errors fall within 2 sigma more often than without it. No
    position moves, and the sensors whose peaks were seen keep their sigmas."""
    grid = uniform_points(patch_b, 8, 3)
    inside = {True: [], False: []}
    for seed in range(6):
        s = simulate_session(patch_b, grid, "robot", seed)
        with_spread = localize(s.point_logs(), patch=patch_b)
        with monkeypatch.context() as m:
            m.setattr(_unseen, "UNSEEN_FRACTION", 0.0)
            without = localize(s.point_logs(), patch=patch_b)
        assert "shape_spread_mm" not in without.params
        np.testing.assert_array_equal(with_spread.xy(), without.xy())
        named = with_spread.params.get("shape_spread_mm", {})
        for a, b, t in zip(with_spread, without, s.truth, strict=True):
            if a.status != OK:
                continue
            if a.sensor not in named:
                assert a.sigma_mm == b.sigma_mm
                continue
            assert named[a.sensor] > 0.0 and a.sigma_mm > b.sigma_mm
            err = float(np.hypot(a.x_mm - t[0], a.y_mm - t[1]))
            inside[True].append(err <= 2.0 * a.sigma_mm)
            inside[False].append(err <= 2.0 * b.sigma_mm)
    assert len(inside[True]) >= 5
    assert sum(inside[True]) > sum(inside[False])
    assert all(inside[True])


def test_a_touch_on_an_unseen_peak_takes_its_spread_out_of_the_live_error_bar(patch_b):
    """On an 8 x 3 plan, a touch on the true position of the sensor with the largest spread:
    the live update drops its term, and so does the next batch solve. That sensor (S22)
    lies 2 mm below the plan's last row, so its y still hangs on the flank below it: its
    error bar narrows (1.82 -> 1.07 mm) and still holds its error, but no further."""
    grid = uniform_points(patch_b, 8, 3)
    s = simulate_session(patch_b, grid, "robot", 2)
    logs = s.point_logs()
    loc = peakfit.Localizer(logs.sensors, rest=logs.rest, rest_sd=logs.rest_sd, patch=patch_b)
    for log in logs.logs():
        loc.update(log)
    named = loc.result().params.get("shape_spread_mm", {})
    assert named
    name = max(named, key=named.get)
    i = logs.sensors.index(name)
    before = loc.result().by_name()[name]
    # The live view does not call it located until a touch has seen its peak.
    assert loc._current().by_name()[name].status == SPARSE
    # The next touch lands on that sensor's true position: its peak is seen now.
    x, y = s.truth[i]
    rng = np.random.default_rng(0)
    log = simulate_touch(
        s.scene, s.probe, x, y, float(s.t_s[-1]) + 1.5, rng, touch=len(grid) + 1, rest=logs.rest
    )
    after = loc.update(log)
    assert loc._shape_shift[i] == 0.0
    assert loc._live_seen[i] >= _unseen.UNSEEN_FRACTION
    assert name not in after.params.get("shape_spread_mm", {})
    # The batch solve of those touches places it from its peak, with a narrower error bar.
    batch = loc.result()
    assert name not in batch.params.get("shape_spread_mm", {})
    now = batch.by_name()[name]
    assert before.status == OK and now.status == OK
    assert now.sigma_mm < 0.75 * before.sigma_mm
    assert np.hypot(now.x_mm - x, now.y_mm - y) <= 2.0 * now.sigma_mm


def _first_touches_live(patch, seeds=range(3), touches=30):
    """Per seed: the robot's serpentine 20 x 5 session on ``patch``, a live Localizer given
    the patch, and the session's first ``touches`` point logs, for it to update with."""
    for seed in seeds:
        s = simulate_session(patch, uniform_grid(patch, 20, 5), "robot", seed)
        logs = s.point_logs()
        loc = peakfit.Localizer(logs.sensors, rest=logs.rest, rest_sd=logs.rest_sd, patch=patch)
        yield s, loc, list(logs.logs())[:touches]


def test_the_live_view_locates_a_sensor_once_a_touch_has_seen_its_peak(patch_b):
    """Mid-session on a serpentine 20 x 5 plan, a sensor on the part of the patch not yet
    probed has only its RX wire's ridge in its map, which a bump between the probed columns
    fits as well as a peak. Over the first 30 touches (robot, seeds 0-2) the live view
    calls `sparse` most of the `ok` calls of the plain verdict on the same fits that are
    more than 5 mm off, and keeps nearly all of those within 5 mm; nothing else of the
    estimates changes. The seen heights the updates keep equal ones computed afresh, and
    the batch solve is the plain verdict (both with the reported verdict's checks)."""
    far = {"live": 0, "plain": 0}
    near = {"live": 0, "plain": 0}
    for s, loc, logs in _first_touches_live(patch_b):
        for log in logs:
            live = loc.update(log)
            with peakfit._quiet():
                status, xy, sigma, _, _ = judge(loc)
            np.testing.assert_array_equal(loc._live_seen, _unseen.seen_height(loc, loc.fit.theta))
            ok = {"live": np.array([e.status == OK for e in live]), "plain": status == OK}
            demoted = ok["plain"] & ~ok["live"]
            assert (ok["live"] <= ok["plain"]).all()
            # `weak`: the reported verdict's rise check (_statuses.unrisen_weak).
            assert all(live.estimates[i].status in (SPARSE, WEAK) for i in np.flatnonzero(demoted))
            np.testing.assert_array_equal(live.xy()[ok["live"]], xy[ok["live"]])
            err = np.hypot(*(xy - s.truth).T)
            for view, located in ok.items():
                far[view] += int((located & (err > 5.0)).sum())
                near[view] += int((located & (err <= 5.0)).sum())
        batch = loc.result()
        with peakfit._quiet():
            plain = judge(loc)[0]
        assert [e.status for e in batch] == peakfit._reported(loc, (plain,))[0].tolist()
    assert far["plain"] >= 100
    assert far["live"] <= 0.4 * far["plain"], far
    assert near["live"] >= 0.95 * near["plain"], near


def _without_the_design_check(loc, verdict):
    """The verdict the user would get from the same fits without _design_reach's check."""
    with pytest.MonkeyPatch.context() as m, peakfit._quiet():
        m.setattr(_design_reach, "DESIGN_REACH_WIDTHS", np.inf)
        return peakfit._build(loc, *peakfit._reported(loc, verdict))


def _far_and_near(pred, truth) -> tuple[int, int]:
    """`ok` calls more than 5 mm off, and within 5 mm."""
    ok = np.array([e.status == OK for e in pred])
    err = np.hypot(*(pred.xy() - truth).T)
    return int((ok & (err > 5.0)).sum()), int((ok & (err <= 5.0)).sum())


def test_with_the_patch_the_live_view_waits_for_a_touch_near_each_design_position(patch_b):
    """A wire's ridge fitted beside the probed columns can count as seen (a touch saw half
    of the bump fitted there). With the patch given, the reported verdict also waits for a
    touch within DESIGN_REACH_WIDTHS half widths of its bump (Localizer._footprint_width)
    of where the design puts the sensor. Over the first 30 live updates of the serpentine
    20 x 5 plan (robot, seeds 0-2) that takes 41 `ok` calls more than 5 mm off to 2 and
    holds back no call within 5 mm; only `ok` and `weak` calls change, to `sparse`. The
    distances the updates keep equal ones computed afresh."""
    far = {"with": 0, "without": 0}
    near = {"with": 0, "without": 0}
    for s, loc, logs in _first_touches_live(patch_b):
        for log in logs:
            live = loc.update(log)
            np.testing.assert_array_equal(loc._design_gap, _design_reach.design_gap(loc))
            with peakfit._quiet():
                plain = _without_the_design_check(loc, _live_update.live_judge(loc))
            for view, pred in (("with", live), ("without", plain)):
                n_far, n_near = _far_and_near(pred, s.truth)
                far[view] += n_far
                near[view] += n_near
            changed = [(a.status, b.status) for a, b in zip(plain, live, strict=True)]
            # `weak` too: the design's check comes before the rise check (unrisen_weak).
            assert {pair for pair in changed if pair[0] != pair[1]} <= {
                (OK, SPARSE),
                (WEAK, SPARSE),
            }
            np.testing.assert_array_equal(
                live.xy()[[a == b == OK for a, b in changed]],
                plain.xy()[[a == b == OK for a, b in changed]],
            )
    assert far["without"] >= 30, far
    assert far["with"] <= 0.2 * far["without"], far
    assert near["with"] == near["without"], near


def test_a_partial_session_s_result_waits_for_a_touch_near_each_design_position(patch_b):
    """The batch solve of a session cut short after 10 touches (two columns of the 20 x 5
    plan; robot and finger, seeds 0-2): its 15 `ok` calls more than 5 mm off become `sparse`,
    none within 5 mm does. A whole plan has a touch near every sensor: nothing changes
    (seed 0)."""
    far = {"with": 0, "without": 0}
    near = {"with": 0, "without": 0}
    for probe, seed in itertools.product(("robot", "finger"), range(3)):
        s = simulate_session(patch_b, uniform_points(patch_b, 20, 5), probe, seed)
        logs = s.point_logs()
        # The whole plan's solve on one seed per probe (each takes about a second).
        for touches in (10, 100) if seed == 0 else (10,):
            loc = peakfit.solved(logs.subset(np.arange(touches)), patch=patch_b)
            result = loc.result()
            with peakfit._quiet():
                plain = _without_the_design_check(loc, judge(loc))
            if touches == 100:
                assert [e.status for e in result] == [e.status for e in plain]
                continue
            for view, pred in (("with", result), ("without", plain)):
                n_far, n_near = _far_and_near(pred, s.truth)
                far[view] += n_far
                near[view] += n_near
    assert far["without"] >= 10, far
    assert far["with"] <= 0.2 * far["without"], far
    assert near["with"] == near["without"], near


def test_the_design_gap_counts_touches_that_made_contact_along_the_known_axes():
    """mm from each sensor's design position to the nearest touch: a touch that missed does
    not count; where the design gives one wire only, the distance runs along that axis; where
    it gives none, or without a patch, nothing is measured (0)."""
    patch = patch_from_dict(
        {
            "name": "two_by_one",
            "size_mm": [40.0, 20.0],
            "tx_x_mm": [10.0, 30.0],
            "rx_y_mm": [10.0],
            "sensors": [{"name": "A", "tx": 0, "rx": 0}, {"name": "B", "tx": 1, "rx": 0}],
        },
        "<test>",
    )
    # C is on no wire of the patch; B's RX wire (5) is not in it.
    wires = {"A": (0, 0), "B": (1, 5), "C": (-1, -1)}
    loc = peakfit.Localizer(["A", "B", "C"], patch=patch, wires=wires)
    for k, (x, y) in enumerate([(10.0, 13.0), (30.0, 18.0), (14.0, 10.0)]):
        loc._append(PointLog(touch=k + 1, x_mm=x, y_mm=y, values=np.zeros(3)))
    gap = _design_reach.design_gap
    np.testing.assert_allclose(gap(loc), [3.0, 0.0, 0.0])
    loc._missed[1] = True  # the touch on B's TX wire made no contact
    np.testing.assert_allclose(gap(loc), [3.0, 16.0, 0.0])
    np.testing.assert_allclose(gap(loc, np.array([0])), [3.0, 20.0, 0.0])
    assert not gap(peakfit.Localizer(["A", "B"])).any()

"""Hard cases for the default localizer: each is right within a stated tolerance or flagged.

Every case also checks the invariants: one estimate per sensor, no NaN/inf anywhere
(``SensorEstimate`` refuses them), a one-word status, and ``ok`` estimates have a sigma.
"""

from __future__ import annotations

import numpy as np
import pytest

from varskin.localization import _drifting, _statuses, peakfit
from varskin.localization._settling import board_settling
from varskin.localization._statuses import DRIFTING
from varskin.pointlogs import PointLogs
from varskin.predictions import OK
from varskin.scene import ADC_MAX, Scene, SceneParams
from varskin.simulate import simulate_session, uniform_grid

TOL_MM = 2.0  # "right" for a hard case: within 2 mm of the truth (the paper's error band)


def check(pred, n):
    assert len(pred) == n
    for p in pred:
        assert p.status and " " not in p.status
        if p.status == OK:
            assert p.x_mm is not None and p.sigma_mm is not None and p.sigma_mm > 0
        else:  # the spec: a non-ok status says why there is no position, and there is none
            assert p.x_mm is None and p.y_mm is None and p.sigma_mm is None, p
    return pred


def err(pred, truth, i) -> float:
    e = pred.estimates[i]
    return float(np.hypot(e.x_mm - truth[i, 0], e.y_mm - truth[i, 1]))


def _without_correction(monkeypatch) -> None:
    """The batch solve without taking the board's settling out of any readings."""
    monkeypatch.setattr(peakfit, "take_out_settling", lambda loc: None)


def ok_errors(pred, truth) -> np.ndarray:
    e = np.hypot(*(pred.xy() - truth).T)
    return e[np.isfinite(e)]


@pytest.fixture(scope="module")
def grid(patch_b):
    return uniform_grid(patch_b, 20, 5)


def test_dead_sensor_is_flagged_dead(patch_b, grid):
    scene = Scene.create(patch_b, 1)
    scene.dead[4] = True
    s = simulate_session(patch_b, grid, probe="robot", seed=1, scene=scene)
    pred = check(peakfit.localize(s.point_logs()), 30)
    assert pred.estimates[4].status == "dead"
    assert ok_errors(pred, s.truth).max() <= TOL_MM


@pytest.mark.parametrize("headroom", [0.6, 0.25])
def test_clipped_peak_is_censored_and_located_or_flagged(patch_b, grid, headroom):
    scene = Scene.create(patch_b, 1)
    scene.drift[7] = 0.0
    scene.rest[7] = ADC_MAX - headroom * scene.peak[7]  # the peak's top clips at the ADC
    s = simulate_session(patch_b, grid, probe="robot", seed=1, scene=scene)
    logs = s.point_logs()
    assert (logs.rest[7] + logs.values[:, 7] >= ADC_MAX - 1).sum() >= 1
    pred = check(peakfit.localize(logs), 30)
    est = pred.estimates[7]
    if headroom > 0.5:  # a clipped tip: the flanks locate it
        assert est.status == OK and err(pred, s.truth, 7) <= 0.5
    else:  # most of the peak clipped: located within its error bar, or flagged saturated
        assert est.status == "saturated" or err(pred, s.truth, 7) <= max(0.5, 2 * est.sigma_mm)


def test_sensor_resting_at_the_adc_limit_is_saturated(patch_b, grid):
    scene = Scene.create(patch_b, 1)
    scene.rest[7] = ADC_MAX
    s = simulate_session(patch_b, grid, probe="robot", seed=1, scene=scene)
    pred = check(peakfit.localize(s.point_logs()), 30)
    assert pred.estimates[7].status == "saturated"


def test_sensor_in_the_corner_and_outside_the_probes_hull(patch_b, grid):
    scene = Scene.create(patch_b, 1)
    scene.true_xy[0] = (1.0, 24.4)  # corner: beyond the outermost probe row and column
    s = simulate_session(patch_b, grid, probe="robot", seed=1, scene=scene)
    logs = s.point_logs()
    pred = check(peakfit.localize(logs), 30)
    corner = pred.estimates[0]
    assert corner.status == OK and err(pred, s.truth, 0) <= TOL_MM
    assert err(pred, s.truth, 0) <= 3 * corner.sigma_mm
    # Probes only over x < 120 mm: the sensors beyond are never reported as located.
    part = check(peakfit.localize(logs.subset(logs.xy_mm[:, 0] < 120)), 30)
    beyond = [p for p, t in zip(part, s.truth, strict=False) if t[0] > 128]
    assert beyond and all(p.status != OK for p in beyond), [p.status for p in beyond]
    assert ok_errors(part, s.truth).max() <= TOL_MM


def test_a_corner_crossing_with_its_wires_is_located_or_flagged(patch_b, grid):
    """The corner as a real skin has it: the crossing's TX wire moved to x = 1 mm and its
    RX wire to y = 24.4 mm, so its wire-mates move with it (no patch: wires inferred)."""
    scene = Scene.create(patch_b, 1)
    tx = np.array([q.tx for q in patch_b.sensors])
    rx = np.array([q.rx for q in patch_b.sensors])
    scene.true_xy[tx == 0, 0] = 1.0
    scene.true_xy[rx == 0, 1] = 24.4
    s = simulate_session(patch_b, grid, probe="robot", seed=1, scene=scene)
    pred = check(peakfit.localize(s.point_logs()), 30)
    corner = pred.estimates[0]
    if corner.status == OK:
        assert err(pred, s.truth, 0) <= min(TOL_MM, 3 * corner.sigma_mm)
    else:
        assert corner.status in ("uncertain", "outside"), corner.status
    assert ok_errors(pred, s.truth).max() <= TOL_MM  # its wire-mates are not dragged off


def test_two_sensors_3_mm_apart_are_both_located(patch_b, grid):
    scene = Scene.create(patch_b, 1)
    scene.true_xy[13] = scene.true_xy[12] + (3.0, 0.0)
    s = simulate_session(patch_b, grid, probe="robot", seed=1, scene=scene)
    pred = check(peakfit.localize(s.point_logs()), 30)
    for i in (12, 13):
        assert pred.estimates[i].status == OK and err(pred, s.truth, i) <= 0.5
    d = np.hypot(*(pred.xy()[13] - pred.xy()[12]))
    assert d == pytest.approx(3.0, abs=0.6)


@pytest.mark.parametrize("inverted", [None, True])
def test_inverted_response_detected_or_configured(patch_b, grid, inverted):
    s = simulate_session(patch_b, grid, probe="robot", seed=1, params=SceneParams(inverted=True))
    pred = check(peakfit.localize(s.point_logs(), inverted=inverted), 30)
    assert all(p.status == OK for p in pred)
    assert ok_errors(pred, s.truth).max() <= TOL_MM


def test_offset_drift_over_the_session(patch_b, grid):
    # Every sensor's offset moves by the full +-120 counts observed on real patches.
    scene = Scene.create(patch_b, 2)
    scene.drift = np.where(np.random.default_rng(2).random(30) < 0.5, -120.0, 120.0)
    s = simulate_session(patch_b, grid, probe="robot", seed=2, scene=scene)
    pred = check(peakfit.localize(s.point_logs()), 30)
    e = ok_errors(pred, s.truth)
    assert len(e) >= 27 and e.max() <= TOL_MM


def test_missed_touches_are_detected_and_ignored(patch_b, grid):
    s = simulate_session(patch_b, grid, probe="robot", seed=1)
    logs = s.point_logs()
    rng = np.random.default_rng(1)
    missed = rng.choice(len(logs), 8, replace=False)
    # No contact: every sensor reads its (drifting) rest, plus noise.
    logs.values[missed] = s.scene.offset(logs.t_s[missed]) + rng.normal(0, 1, (8, 30))
    loc = peakfit.solved(logs)
    assert set(np.flatnonzero(loc._missed[: loc.n_logs])) == set(missed)
    pred = check(loc.result(), 30)
    for i, p in enumerate(pred):
        if p.status == OK:
            assert err(pred, s.truth, i) <= max(TOL_MM, 3 * p.sigma_mm)


def test_nan_and_inf_samples(patch_b, grid):
    s = simulate_session(patch_b, grid, probe="robot", seed=1)
    logs = s.point_logs()
    logs.values[3, 5] = np.nan
    logs.values[40, 10] = np.inf
    logs.values[41, :] = np.nan
    logs.xy_mm[42] = (np.nan, 5.0)
    pred = check(peakfit.localize(logs), 30)
    assert all(p.status == OK for p in pred)
    assert ok_errors(pred, s.truth).max() <= TOL_MM
    logs.values[:, 6] = np.nan
    assert check(peakfit.localize(logs), 30).estimates[6].status == "sparse"


def test_duplicate_probe_locations(patch_b, grid):
    s = simulate_session(patch_b, np.concatenate([grid, grid[:40]]), probe="robot", seed=1)
    pred = check(peakfit.localize(s.point_logs()), 30)
    assert all(p.status == OK for p in pred)
    assert ok_errors(pred, s.truth).max() <= TOL_MM


def test_collinear_probes_are_flagged(patch_b):
    s = simulate_session(patch_b, uniform_grid(patch_b, 40, 1), probe="robot", seed=1)
    pred = check(peakfit.localize(s.point_logs()), 30)
    assert {p.status for p in pred} == {"collinear"}


@pytest.mark.parametrize("k", [0, 1, 2])
def test_fewer_than_three_probes(patch_b, grid, k):
    logs = simulate_session(patch_b, grid, probe="robot", seed=1).point_logs().subset(np.arange(k))
    pred = check(peakfit.localize(logs), 30)
    assert {p.status for p in pred} == {"sparse"}


@pytest.mark.parametrize("factor", [1e-9, 1e9])
def test_values_scaled_by_huge_factors(patch_b, grid, factor):
    s = simulate_session(patch_b, grid, probe="robot", seed=1)
    logs = s.point_logs()
    base = peakfit.localize(logs).xy()
    logs.values = logs.values * factor
    logs.rest, logs.rest_sd = logs.rest * factor, logs.rest_sd * factor
    logs.sample_sd = logs.sample_sd * factor
    pred = check(peakfit.localize(logs), 30)
    assert all(p.status == OK for p in pred)
    assert np.nanmax(np.abs(pred.xy() - base)) <= 1e-3


def test_float32_input(patch_b, grid):
    s = simulate_session(patch_b, grid, probe="robot", seed=1)
    logs = s.point_logs()
    base = peakfit.localize(logs).xy()
    logs.values = logs.values.astype(np.float32)
    logs.xy_mm = logs.xy_mm.astype(np.float32)
    pred = check(peakfit.localize(logs), 30)
    assert np.nanmax(np.abs(pred.xy() - base)) <= 0.05


@pytest.mark.parametrize("probe", ["robot", "finger"])
def test_scattered_non_grid_probes(patch_b, probe):
    rng = np.random.default_rng(5)
    pts = np.column_stack([rng.uniform(0, 152.4, 150), rng.uniform(0, 25.4, 150)])
    s = simulate_session(patch_b, pts, probe=probe, seed=1)
    pred = check(peakfit.localize(s.point_logs()), 30)
    e = ok_errors(pred, s.truth)
    assert len(e) >= 28
    assert np.sqrt((e**2).sum() / (len(e) - 1)) <= (0.4 if probe == "robot" else 1.2)


def test_sparse_scattered_touches_do_not_collapse_the_fits_onto_single_touches(patch_b):
    """100 touches scattered over Patch B lie about 2.2 mm from their nearest neighbour but
    far more from most others. A starting width was judged in a window of two such
    spacings, which held one or two touches and fitted any width exactly, so the narrowest
    won: on this session 25 of 30 fits collapsed onto single touches (`irregular`) and one
    was `ok` 5.0 mm off at sigma 0.61 mm (benchmarks/localizer_stress.py, scatter 100)."""
    rng = np.random.default_rng([509, 7])
    pts = np.column_stack([rng.uniform(3.0, 149.4, 100), rng.uniform(3.0, 22.4, 100)])
    s = simulate_session(patch_b, pts, probe="finger", seed=509)
    pred = check(peakfit.localize(s.point_logs(), patch=patch_b), 30)
    e = ok_errors(pred, s.truth)
    assert len(e) >= 27
    assert np.sqrt(np.mean(e**2)) <= 1.0
    assert e.max() <= 2.0


def test_no_sensor_data_at_all():
    logs = PointLogs(
        sensors=("A", "B"),
        touch=np.arange(5),
        xy_mm=np.column_stack([np.arange(5.0), np.arange(5.0) % 2]),
        values=np.zeros((5, 2)),
        n_samples=np.ones(5, int),
    )
    pred = check(peakfit.localize(logs), 2)
    assert all(p.status != OK for p in pred)


@pytest.mark.parametrize("seed", range(4))
def test_maps_of_pure_noise_from_a_few_touches_give_statuses_not_a_crash(seed):
    """A handful of touches whose readings are noise: a sensor's fit can then go through
    every point, leaving no residual, and its touches' weights reach ~1e18. That once made
    the touches' gain-and-placement step singular and raised numpy's LinAlgError from
    ``localize`` and from a live update (found by fuzzing)."""
    rng = np.random.default_rng(seed)
    k, n = 10, 2
    logs = PointLogs(
        sensors=("A", "B"),
        touch=np.arange(k),
        xy_mm=rng.uniform(0.0, 50.0, (k, 2)),
        values=rng.normal(0.0, 1.0, (k, n)),
        n_samples=np.ones(k, int),
    )
    check(peakfit.localize(logs), n)
    loc = peakfit.Localizer(logs.sensors)
    for log in logs.logs():
        check(loc.update(log), n)


@pytest.mark.parametrize("jump", [0.3, 0.6])
def test_sensor_whose_readings_jump_between_touches(patch_b, grid, jump):
    """Touch-to-touch jumps of 30% or 60% of the peak (interference the per-touch sample sd
    does not show): located within its own error bar, or flagged without a position
    (``irregular``: the fit failed its sanity checks; no centroid guess is reported)."""
    statuses = []
    for seed in (1, 2, 3):
        s = simulate_session(patch_b, grid, probe="robot", seed=seed)
        logs = s.point_logs()
        v = logs.values[:, 12]
        logs.values[:, 12] = v + np.random.default_rng(seed).normal(0, jump * v.max(), len(v))
        pred = check(peakfit.localize(logs), 30)
        est = pred.estimates[12]
        statuses.append(est.status)
        if est.status == OK:
            assert err(pred, s.truth, 12) <= 2.0 * est.sigma_mm
        # The other sensors are not disturbed.
        others = np.delete(np.hypot(*(pred.xy() - s.truth).T), 12)
        assert np.nanmax(others) <= TOL_MM
    if jump > 0.5:
        assert all(st != OK for st in statuses), statuses
        assert "irregular" in statuses


def _probed_first_while_drifting(patch, seed, drift, i=0, peak=90.0):
    """A sensor (by default weak: peak 90 counts) in the first probe column whose offset
    moves by ``drift`` counts with the simulator's 60 s time constant: most of the drift
    happens during its own touches."""
    scene = Scene.create(patch, seed)
    scene.drift[i], scene.peak[i] = drift, peak
    s = simulate_session(patch, uniform_grid(patch, 20, 5), probe="robot", seed=seed, scene=scene)
    pred = check(peakfit.localize(s.point_logs()), len(patch.sensors))
    est = pred.estimates[i]
    return est, err(pred, s.truth, i) if est.status == OK else None


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
@pytest.mark.parametrize(("drift", "i"), [(120.0, 0), (-120.0, 1)], ids=["rises", "falls"])
def test_sensor_probed_first_while_its_offset_settles(patch_a, seed, drift, i):
    """An offset that moves by more than the sensor's own peak during its touches: the slow
    floor model cannot follow it (the part it misses moved the peak 0.5-2.7 mm with a sigma
    of 0.2-0.5 mm), so the sensor is flagged ``drifting``; located, it must be right."""
    est, e = _probed_first_while_drifting(patch_a, seed, drift, i)
    if est.status == OK:
        assert e <= min(TOL_MM, 2.0 * est.sigma_mm), (e, est.sigma_mm)
    else:
        assert est.status == DRIFTING, est.status


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
@pytest.mark.parametrize(("drift", "i"), [(120.0, 0), (-120.0, 1)], ids=["rises", "falls"])
def test_a_drifting_sensor_probed_again_once_settled_is_located(patch_a, seed, drift, i):
    """The same sensor, with the first three columns probed again after the grid (as the
    `drifting` status advises): its later touches see a steady floor and place it, although
    its first touches, still in its window, moved its floor by about its peak."""
    scene = Scene.create(patch_a, seed)
    scene.drift[i], scene.peak[i] = drift, 90.0
    grid = uniform_grid(patch_a, 20, 5)
    s = simulate_session(
        patch_a, np.vstack([grid, grid[:15]]), probe="robot", seed=seed, scene=scene
    )
    pred = check(peakfit.localize(s.point_logs()), len(patch_a.sensors))
    est = pred.estimates[i]
    assert est.status == OK, est.status
    assert err(pred, s.truth, i) <= min(1.0, 2.0 * est.sigma_mm), (err(pred, s.truth, i), est)


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_a_typical_drift_during_its_own_touches_is_located(patch_a, seed):
    """A typical sensor (170 counts) whose offset moves by a typical 45 counts, most of it
    during its own touches, is fitted as drift and located: the flag is for the extreme."""
    drift = 45.0 if seed % 2 else -45.0
    est, e = _probed_first_while_drifting(patch_a, seed, drift, peak=170.0)
    assert est.status == OK, est.status
    assert e <= min(TOL_MM, 2.0 * est.sigma_mm)


@pytest.mark.parametrize("mode", ["flagged", "corrected-without-the-check", "without-either"])
def test_a_finger_fit_that_did_not_follow_the_settling_is_drifting(
    patch_b, grid, monkeypatch, mode
):
    """Seed 410, finger: S3 (peak 87 counts, the weakest a scene draws) on the first TX wire
    is probed only while its offset settles by 90 counts. Its fitted floor follows less
    than half of that, which the older check (the fitted floor's own span) passes, and the
    rest moved its peak 2.4 mm at a sigma of 0.46 mm. The other sensors' far touches show
    the settling its fit missed: `drifting`. No other sensor of the scene is flagged.
    Below the check's fraction, the same settling taken out of its readings places it
    (_drifting.take_out_settling)."""
    if mode != "flagged":
        monkeypatch.setattr("varskin.localization._statuses.UNFOLLOWED_FRACTION", np.inf)
    if mode == "without-either":  # shows the scene is one the check must catch
        _without_correction(monkeypatch)
    s = simulate_session(patch_b, grid, probe="finger", seed=410)
    pred = check(peakfit.localize(s.point_logs()), 30)
    statuses = [e.status for e in pred]
    if mode == "flagged":
        assert statuses[2] == DRIFTING
        assert statuses.count(DRIFTING) == 1, statuses
    elif mode == "corrected-without-the-check":
        assert statuses[2] == OK
        assert err(pred, s.truth, 2) <= min(1.0, 2.0 * pred.estimates[2].sigma_mm)
    else:
        assert statuses[2] == OK and err(pred, s.truth, 2) > 2.0
        assert err(pred, s.truth, 2) > 4.0 * pred.estimates[2].sigma_mm


@pytest.mark.parametrize("mode", ["re-fitted", "corrected-without-the-check", "without-either"])
def test_a_board_corner_the_settling_moved_is_placed_by_its_later_touches(
    monkeypatch, mode, full_board
):
    """A full Muca board (21 x 12 sensors, 300 x 200 mm), robot on a 50 x 20 grid, seed 1:
    S1 is the corner the scan starts at, probed while the offsets settle. Only 0.13 of its
    peak went unfollowed (under UNFOLLOWED_FRACTION), but that moved it 2.2 mm at 5.5
    sigma. With the settling taken out of its readings its fit moves 2 mm, so it is
    `drifting`; the scan's next pass over it places it (_drifting.refit_after_settling).
    No `ok` sensor of the board is then more than 2 mm and 3 sigma off. Without the check,
    the settling taken out of its readings places it too (_drifting.take_out_settling)."""
    guard = mode == "re-fitted"
    if not guard:
        monkeypatch.setattr(_drifting, "SETTLING_MOVE_MM", np.inf)
    if mode == "without-either":  # shows the scene is one the check must catch
        _without_correction(monkeypatch)
    board = full_board
    s = simulate_session(board, uniform_grid(board, 50, 20), probe="robot", seed=1)
    loc = peakfit.solved(s.point_logs())
    pred = check(loc.result(), 252)
    s1 = pred.estimates[0]
    assert s1.status == OK
    if guard:
        assert np.isfinite(loc._t_from[0])  # re-fitted from the touches of the later pass
        assert err(pred, s.truth, 0) <= min(1.0, 2.0 * s1.sigma_mm)
        e = np.hypot(*(pred.xy() - s.truth).T)
        sigma = np.array([np.nan if p.sigma_mm is None else p.sigma_mm for p in pred])
        assert not np.any(np.isfinite(e) & (e > 2.0) & (e > 3.0 * sigma))
    elif mode == "corrected-without-the-check":
        assert err(pred, s.truth, 0) <= min(1.0, 2.0 * s1.sigma_mm)
    else:
        assert err(pred, s.truth, 0) > 2.0
        assert err(pred, s.truth, 0) > 4.0 * s1.sigma_mm


def _settling_readings(rng, tau, P, xy, w, peak):
    """Readings of sensors at ``xy`` (half widths ``w``) touched at ``P``, each settling
    with the course 1 - exp(-tau) to its own level of 30-120 counts either way, plus a
    Lorentzian bump of ``peak`` counts and noise of sd 2: (V, course, level, bump)."""
    N = len(xy)
    level = rng.choice([-1, 1], N) * rng.uniform(30, 120, N)
    course = 1 - np.exp(-tau)
    d = np.hypot(P[:, 0:1] - xy[:, 0], P[:, 1:2] - xy[:, 1])
    bump = peak / (1 + (d / w) ** 2)
    V = level * course[:, None] + bump + rng.normal(0, 2.0, bump.shape)
    return V, course, level, bump


def test_the_board_settling_is_read_from_the_far_touches():
    """Every sensor's floor settles with one time course (each by its own level): the
    course comes back from the touches far from each sensor's peak, the levels too; with no
    sensor settling clear of its noise there is no course to judge by."""
    rng = np.random.default_rng(0)
    K, N = 100, 12
    tau = np.arange(K) * 0.15  # minutes
    P = np.column_stack([np.repeat(np.arange(20) * 7.6, 5), np.tile(np.arange(5) * 5.0, 20)])
    xy = np.column_stack([np.linspace(5, 145, N), np.tile([5.0, 15.0], N // 2)])
    w = np.full(N, 8.0)
    V, course, level, bump = _settling_readings(rng, tau, P, xy, w, 150.0)
    got, lv = board_settling(V, P, tau, xy, w, np.ones(N, bool), np.full(N, 2.0))
    assert np.nanmax(np.abs(got - course)) < 0.08
    assert np.isfinite(got).all()
    # Far is beyond 4 half widths, where the bump is still up to 6% of its 150 counts.
    assert np.allclose(lv, level, rtol=0, atol=0.06 * 150 + 3.0)
    quiet, _ = board_settling(
        bump + rng.normal(0, 2.0, (K, N)), P, tau, xy, w, np.ones(N, bool), np.full(N, 2.0)
    )
    assert np.isnan(quiet).all()


def test_where_no_sensor_is_far_the_settling_is_read_from_the_flanks():
    """A patch only a few footprints long: no sensor is far from the first touches, so the
    far touches alone leave the course unknown there and the late-probed sensors' levels
    unknown. With the fitted bumps taken off, the flanks give both; where the far touches
    told, their values stand."""
    rng = np.random.default_rng(1)
    K, N = 100, 16
    tau = np.arange(K) * 0.12  # minutes
    P = np.column_stack(
        [np.repeat(np.arange(20) * 2.0 + 1.0, 5), np.tile(np.arange(5) * 4.0 + 2, 20)]
    )
    xy = np.column_stack([np.repeat(np.arange(8) * 4.5 + 4.25, 2), np.tile([6.0, 14.0], 8)])
    w = np.full(N, 6.5)
    V, course, level, bump = _settling_readings(rng, tau, P, xy, w, 170.0)
    args = (V, P, tau, xy, w, np.ones(N, bool), np.full(N, 2.0))
    far_course, far_level = board_settling(*args)
    assert np.isnan(far_course[:30]).all() and np.isnan(far_level).any()
    got, lv = board_settling(*args, bump=lambda rows: bump[rows])
    told = np.isfinite(far_course)
    assert np.array_equal(got[told], far_course[told])
    assert np.array_equal(lv[np.isfinite(far_level)], far_level[np.isfinite(far_level)])
    assert np.isfinite(got).all() and np.isfinite(lv).all()
    assert np.abs(got[:30] - course[:30]).max() < 0.1
    assert np.allclose(lv, level, rtol=0, atol=0.06 * 170 + 3.0)
    # The flanks are read only where a touch had no far sensor: on a patch four times as
    # long every touch has one, and the bumps are not even asked for.
    long_course, _ = board_settling(*args[:3], xy * [4, 1], *args[4:], bump=lambda rows: 1 / 0)
    assert np.isfinite(long_course).all()


def test_a_small_dense_patch_s_sensors_probed_while_it_settles_are_placed():
    """8 x 4 sensors 4.5 mm apart on 40 x 20 mm, robot, 20 x 5 grid: no sensor is far from
    the first 40 touches, during which the offsets settle (up to 120 counts). Read from
    the far touches alone, the settling went unseen there, and seed 0's S2 (55 counts of
    settling under a 135-count peak) ended 1.07 mm off at 7.3 sigma, S12 0.91 mm off.
    From the flanks it is taken out of their readings."""
    from varskin.patch import patch_from_dict

    # A sensor at every crossing, named as the paper does (S1, S2, ... y fastest).
    tx, rx = np.arange(8) * 4.5 + 4.25, np.arange(4) * 4.5 + 3.25
    patch = patch_from_dict(
        {"name": "dense", "size_mm": [40, 20], "tx_x_mm": list(tx), "rx_y_mm": list(rx)},
        "dense",
    )
    s = simulate_session(patch, uniform_grid(patch, 20, 5), "robot", 0)
    pred = check(peakfit.localize(s.point_logs(), patch=patch), 32)
    e = np.linalg.norm(pred.xy() - s.truth, axis=1)
    sigma = np.array([np.nan if p.sigma_mm is None else p.sigma_mm for p in pred])
    ok = np.isfinite(e)
    assert ok.sum() >= 30
    assert e[ok].max() < 0.5
    assert (e[ok] <= 3.0 * sigma[ok]).all()
    assert {"S2", "S12"} <= set(pred.params["settling_taken_out_mm"])


def test_the_settling_course_is_filled_in_time_and_smoothed():
    """Touches no far sensor told get the course interpolated in session time, and one
    touch's outlier does not become a correction (a running median over 5 touches)."""
    tau = np.arange(12.0)
    course = np.clip(tau / 8.0, 0.0, 1.0)
    told = course.copy()
    told[[3, 4]] = np.nan  # no far sensor then
    told[9] = 3.0  # one touch's noise
    got = _drifting.smoothed_course(told, tau)
    assert np.isfinite(got).all()
    assert np.allclose(got, course, atol=0.13)
    assert got[9] <= 1.0
    # In time order, whatever order the logs came in.
    order = np.random.default_rng(0).permutation(12)
    assert np.allclose(_drifting.smoothed_course(told[order], tau[order]), got[order])
    assert not _drifting.smoothed_course(np.full(12, np.nan), tau).any()


@pytest.mark.parametrize("correct", [True, False], ids=["corrected", "without-the-correction"])
def test_a_weak_sensor_the_settling_moved_is_fitted_again_without_it(patch_a, monkeypatch, correct):
    """Patch A, robot, seed 455, no patch: S2 (97 counts) is probed while its offset moves
    by 78 counts, and its fit leaves 0.22 of its peak of that unfollowed (under
    UNFOLLOWED_FRACTION): `ok`, 1.78 mm off at a sigma of 0.39 mm. Fitted again from its
    readings with the board's settling taken out, it is within 0.6 mm and 2 sigma."""
    if not correct:  # shows the scene is one the correction must mend
        _without_correction(monkeypatch)
    s = simulate_session(patch_a, uniform_grid(patch_a, 20, 5), probe="robot", seed=455)
    pred = check(peakfit.localize(s.point_logs()), len(patch_a.sensors))
    s2 = pred.estimates[1]
    assert s2.status == OK
    if correct:
        assert err(pred, s.truth, 1) <= min(0.6, 2.0 * s2.sigma_mm)
    else:
        assert err(pred, s.truth, 1) > 1.5
        assert err(pred, s.truth, 1) > 4.0 * s2.sigma_mm


@pytest.mark.parametrize("correct", [True, False], ids=["corrected", "without-the-correction"])
def test_a_drifting_sensor_corrected_places_its_wire_but_stays_drifting(
    patch_a, monkeypatch, correct
):
    """Patch A, finger, seed 490, no patch: S1 and S2 share the first TX wire and were
    both probed while their offsets settled. S1 is `drifting`; S2 passed, 2.71 mm off at
    3.1 sigma. Both are fitted again without the settling; S1 stays `drifting`, and its
    corrected fit, placing the wire's line, brings S2 within 1.5 mm."""
    if not correct:
        _without_correction(monkeypatch)
    s = simulate_session(patch_a, uniform_grid(patch_a, 20, 5), probe="finger", seed=490)
    pred = check(peakfit.localize(s.point_logs()), len(patch_a.sensors))
    assert pred.estimates[0].status == DRIFTING
    assert pred.estimates[1].status == OK
    if correct:
        assert err(pred, s.truth, 1) <= min(1.5, 2.0 * pred.estimates[1].sigma_mm)
    else:
        assert err(pred, s.truth, 1) > 2.5


def test_the_readings_are_put_back_as_logged_after_the_correction(patch_a):
    """The settling is taken out of a copy of some sensors' readings for their re-fit only:
    the localizer keeps the readings as logged (a live update adds its raw touches to
    them), and solving again gives the same answer (taken out twice, it would not)."""
    s = simulate_session(patch_a, uniform_grid(patch_a, 20, 5), probe="robot", seed=455)
    logs = s.point_logs()
    loc = peakfit.solved(logs)
    first = loc.result()
    course, level = loc._settling
    assert level[1] == 0.0  # S2 was corrected
    assert np.array_equal(loc._V[: loc.n_logs], np.asarray(logs.values, float), equal_nan=True)
    loc.solve_all()
    again = loc.result()
    assert np.array_equal(again.xy(), first.xy(), equal_nan=True)
    assert [e.status for e in again] == [e.status for e in first]


def test_the_settling_taken_out_is_in_the_corrected_sensors_error_bars(patch_a, monkeypatch):
    """Patch A, robot, 30 x 8 grid, patch given, seeds 504-506: the board's settling is
    taken out of 15 `ok` sensors' readings, and the result names them. Their fits' own
    sigmas cover 9 within 2 sigma; with the correction's error in the error bar (as large
    as the move it made in the fit, _statuses.SETTLING_SHIFT_RMS), every one. No position
    and no status changes, and no other sensor's sigma."""
    covered = {1.0: 0, 0.0: 0}
    corrected = 0
    for seed in (504, 505, 506):
        s = simulate_session(patch_a, uniform_grid(patch_a, 30, 8), probe="robot", seed=seed)
        loc = peakfit.solved(s.point_logs(), patch=patch_a)
        with_it = check(loc.result(), len(patch_a.sensors))
        monkeypatch.setattr(_statuses, "SETTLING_SHIFT_RMS", 0.0)
        without = check(loc.result(), len(patch_a.sensors))
        monkeypatch.undo()
        assert np.array_equal(with_it.xy(), without.xy(), equal_nan=True)
        assert [e.status for e in with_it] == [e.status for e in without]
        taken = with_it.params["settling_taken_out_mm"]
        assert all(v > 0 for v in taken.values())
        for i, (a, b) in enumerate(zip(with_it, without, strict=True)):
            if a.sensor not in taken:
                assert a.sigma_mm == b.sigma_mm
            elif a.status == OK:
                corrected += 1
                assert a.sigma_mm > b.sigma_mm
                covered[1.0] += err(with_it, s.truth, i) <= 2.0 * a.sigma_mm
                covered[0.0] += err(with_it, s.truth, i) <= 2.0 * b.sigma_mm
    assert corrected == 15
    assert covered == {1.0: 15, 0.0: 9}


@pytest.mark.parametrize("use_patch", [True, False])
@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize(("patch_name", "i"), [("patch_a", 19), ("patch_b", 13)])
def test_an_offset_settling_faster_than_its_peak_is_not_taken_for_the_peak(
    request, patch_name, i, seed, use_patch
):
    """A weak sensor far from where the session starts (86 counts) whose offset falls by
    140 counts with a 20 s time constant: its map's top is at the session's first touches,
    where the offset was still high. A fit that takes that top is `ok` 100-130 mm off with
    a sigma of 3-5 mm (seen with the second-peak check disabled); the sensor's real bump,
    backed by more touches, must win. Without the patch (joint rounds), Patch B seed 3's
    false-top fit failed its sanity checks: `irregular`, until the second-peak check also
    looked at such fits."""
    patch = request.getfixturevalue(patch_name)
    scene = Scene.create(patch, seed, SceneParams(drift_tau_s=20.0))
    scene.drift[i], scene.peak[i] = -140.0, 86.0
    s = simulate_session(patch, uniform_grid(patch, 20, 5), probe="finger", seed=seed, scene=scene)
    given = {"patch": patch} if use_patch else {}
    pred = check(peakfit.localize(s.point_logs(), **given), len(patch.sensors))
    est = pred.estimates[i]
    assert est.status == OK, est.status
    assert err(pred, s.truth, i) <= min(1.0, 2.0 * est.sigma_mm), (err(pred, s.truth, i), est)


def test_a_map_with_two_equal_bumps_far_apart_is_irregular_not_one_of_them(patch_b, grid):
    """Sensor S5's map plus S23's, scaled to the same height (a short between two sensors'
    lines): two peaks that explain the data equally well. Neither is the answer."""
    s = simulate_session(patch_b, grid, probe="robot", seed=1)
    logs = s.point_logs()
    v = logs.values
    v[:, 4] = v[:, 4] + v[:, 22] * (v[:, 4].max() / v[:, 22].max())
    pred = check(peakfit.localize(logs), 30)
    assert pred.estimates[4].status == "irregular"
    assert ok_errors(pred, s.truth).max() <= TOL_MM

"""Touch planning (issue 6): the uniform grid, the generator protocol, the adaptive plan.

Most tests drive the planners with made-up predictions (fast, and the planner's reaction
to a given sensor state is what they check); one runs the real localizer on a simulated
Patch B touch by touch, as a session would.
"""

from __future__ import annotations

import numpy as np
import pytest

from robot.launch import PlanConfig
from varskin.localization.peakfit import Localizer
from varskin.patch import patch_from_dict
from varskin.planning import (
    ADAPTIVE,
    BUDGET,
    COARSE,
    EXHAUSTED,
    GIVEN,
    TARGET,
    UNIFORM,
    AdaptivePlanner,
    PlannedTouch,
    TouchOutcome,
    UniformPlanner,
    touch_order,
    uniform_points,
)
from varskin.predictions import OK, Predictions, SensorEstimate
from varskin.scene import ProbeModel, Scene
from varskin.simulate import BASELINE_SAMPLES, FRAME_RATE_HZ, simulate_touch


def predictions(patch, sigma=0.3, unlocated=(), offset=(0.0, 0.0)) -> Predictions:
    """Every sensor ok at its design position (+ offset) with ``sigma`` (scalar or per
    sensor name), except the ``unlocated`` ones."""
    est = []
    for s in patch.sensors:
        if s.name in unlocated:
            est.append(SensorEstimate(s.name, None, None, None, None, "irregular"))
            continue
        sg = sigma.get(s.name, 0.3) if isinstance(sigma, dict) else sigma
        est.append(SensorEstimate(s.name, s.x_mm + offset[0], s.y_mm + offset[1], sg))
    return Predictions("peakfit", est)


def drive(planner, respond, limit=500):
    """Run a plan to its end; ``respond(touch, made_so_far)`` returns the TouchOutcome."""
    gen = planner.plan()
    touches = []
    outcomes = []
    touch = next(gen)
    while True:
        touches.append(touch)
        outcome = respond(touch, touches)
        outcomes.append(outcome)
        assert len(touches) <= limit, "the plan does not end"
        try:
            touch = gen.send(outcome)
        except StopIteration:
            return touches, outcomes


def in_box(patch, touches, margin):
    xy = np.array([[t.x_mm, t.y_mm] for t in touches])
    return (
        (xy[:, 0] >= margin).all()
        and (xy[:, 0] <= patch.length_mm - margin).all()
        and (xy[:, 1] >= margin).all()
        and (xy[:, 1] <= patch.width_mm - margin).all()
    )


# --- the uniform grid -------------------------------------------------------------------


def test_uniform_points_cover_the_margins_in_serpentine_order(patch_b):
    pts = uniform_points(patch_b, nx=20, ny=5, margin_mm=3.0)
    assert pts.shape == (100, 2)
    assert pts[:, 0].min() == 3.0 and pts[:, 0].max() == pytest.approx(patch_b.length_mm - 3.0)
    assert pts[:, 1].min() == 3.0 and pts[:, 1].max() == pytest.approx(patch_b.width_mm - 3.0)
    assert len(np.unique(pts, axis=0)) == 100
    dx = (patch_b.length_mm - 6.0) / 19
    dy = (patch_b.width_mm - 6.0) / 4
    # Column by column along x; up in y, then down: every move is one grid step.
    steps = np.abs(np.diff(pts, axis=0))
    along_y = np.isclose(steps[:, 0], 0.0) & np.isclose(steps[:, 1], dy)
    next_col = np.isclose(steps[:, 0], dx) & np.isclose(steps[:, 1], 0.0)
    assert (along_y | next_col).all()
    assert next_col.sum() == 19
    assert (np.diff(pts[:5, 1]) > 0).all() and (np.diff(pts[5:10, 1]) < 0).all()


@pytest.mark.parametrize("grid", [(20, 5, 3.0), (8, 3, 3.0), (1, 1, 2.0), (7, 2, 0.0)])
def test_uniform_points_are_the_launch_plans_grid(patch_b, patch_a, grid):
    nx, ny, margin = grid
    for patch in (patch_a, patch_b):
        ours = uniform_points(patch, nx, ny, margin)
        assert np.array_equal(ours, PlanConfig(nx, ny, margin).points_mm(patch))


def test_a_shuffled_plan_is_one_fixed_order_and_auto_shuffles_only_small_patches(patch_b):
    small = patch_from_dict(
        {"name": "small", "size_mm": [50, 20], "tx_x_mm": [5, 25, 45], "rx_y_mm": [5, 15]},
        "<small>",
    )
    wider = patch_from_dict(
        {"name": "wider", "size_mm": [50.5, 20], "tx_x_mm": [5, 25, 45], "rx_y_mm": [5, 15]},
        "<wider>",
    )
    assert touch_order(small) == "shuffled" and touch_order(wider) == "sweep"
    assert touch_order(patch_b) == "sweep" and touch_order(patch_b, "shuffled") == "shuffled"
    assert touch_order(small, "sweep") == "sweep"
    with pytest.raises(ValueError, match="zigzag"):
        touch_order(small, "zigzag")
    grid = uniform_points(small, 10, 4)
    first = UniformPlanner(small, 10, 4, order="shuffled").points()
    # Every grid point once, not in the sweep's order, and the same order every time (a
    # resumed session rebuilds its plan).
    assert sorted(map(tuple, first)) == sorted(map(tuple, grid))
    assert not np.array_equal(first, grid)
    assert np.array_equal(first, UniformPlanner(small, 10, 4, order="shuffled").points())
    assert np.array_equal(UniformPlanner(small, 10, 4).points(), grid)
    # The launch's plan touches in the order it resolves to.
    assert np.array_equal(PlanConfig(10, 4, 3.0).points_mm(small), first)
    assert np.array_equal(PlanConfig(10, 4, 3.0, order="sweep").points_mm(small), grid)
    # A sweep moves one grid step at a time; the shuffle spreads the first touches over
    # the patch, so the offsets' early settling does not fall on one end of it.
    assert np.ptp(first[:10, 0]) > 0.5 * np.ptp(grid[:, 0])
    assert np.ptp(grid[:10, 0]) < 0.25 * np.ptp(grid[:, 0])


def test_uniform_points_reject_impossible_grids(patch_b):
    with pytest.raises(ValueError, match="at least one"):
        uniform_points(patch_b, 0, 5)
    with pytest.raises(ValueError, match="no room"):
        uniform_points(patch_b, 20, 5, margin_mm=13.0)
    with pytest.raises(ValueError):
        uniform_points(patch_b, 2.5, 5)


def test_uniform_planner_follows_the_grid_whatever_the_outcomes(patch_b):
    planner = UniformPlanner(patch_b, nx=4, ny=3, margin_mm=3.0)
    fail_every_other = lambda t, _: TouchOutcome(t, t.index % 2 == 0, None)  # noqa: E731
    touches, _ = drive(planner, fail_every_other)
    assert [t.index for t in touches] == list(range(12))
    assert {t.phase for t in touches} == {UNIFORM}
    xy = np.array([[t.x_mm, t.y_mm] for t in touches])
    assert np.array_equal(xy, uniform_points(patch_b, 4, 3, 3.0))


def test_generators_reject_an_outcome_of_another_touch(patch_b):
    for planner in (UniformPlanner(patch_b, 4, 3), AdaptivePlanner(patch_b, coarse=(4, 3))):
        gen = planner.plan()
        first = next(gen)
        second = gen.send(TouchOutcome(first, True, None))
        with pytest.raises(ValueError, match="touch 0"):
            gen.send(TouchOutcome(first, True, None))
        assert second.index == 1


# --- the adaptive plan ------------------------------------------------------------------


def test_adaptive_plan_starts_with_the_coarse_serpentine_and_stays_inside(patch_b):
    planner = AdaptivePlanner(patch_b, coarse=(4, 2), budget=20, margin_mm=4.0)
    pred = predictions(patch_b, sigma=2.0)
    touches, _ = drive(planner, lambda t, _: TouchOutcome(t, True, pred))
    assert [t.index for t in touches] == list(range(20))
    assert [t.phase for t in touches[:8]] == [COARSE] * 8
    assert {t.phase for t in touches[8:]} == {ADAPTIVE}
    coarse = np.array([[t.x_mm, t.y_mm] for t in touches[:8]])
    assert np.array_equal(coarse, uniform_points(patch_b, 4, 2, 4.0))
    assert in_box(patch_b, touches, 4.0)
    assert in_box(patch_b, [PlannedTouch(0, x, y, "") for x, y in planner.candidates], 4.0)
    assert planner.stop_reason == BUDGET


@pytest.mark.parametrize("sensor", ["S14", "S1", "S29"])
def test_next_touch_goes_to_the_sensor_that_is_not_located(patch_b, sensor):
    planner = AdaptivePlanner(patch_b, coarse=(8, 3))
    done = uniform_points(patch_b, 8, 3)
    xy = planner.choose(done, predictions(patch_b, sigma=0.3, unlocated={sensor}))
    target = np.array([patch_b.sensor(sensor).x_mm, patch_b.sensor(sensor).y_mm])
    assert np.hypot(*(xy - target)) < 6.5, xy  # within one footprint of its design position


def test_an_unlocated_sensor_comes_before_a_loose_located_one(patch_b):
    planner = AdaptivePlanner(patch_b, coarse=(8, 3))
    done = uniform_points(patch_b, 8, 3)
    pred = predictions(patch_b, sigma={"S5": 1.5}, unlocated={"S20"})
    xy = planner.choose(done, pred)
    s20 = np.array([patch_b.sensor("S20").x_mm, patch_b.sensor("S20").y_mm])
    assert np.hypot(*(xy - s20)) < 6.5
    # Once S20 is located, the loose S5 is next.
    xy = planner.choose(np.vstack([done, xy]), predictions(patch_b, sigma={"S5": 1.5}))
    s5 = np.array([patch_b.sensor("S5").x_mm, patch_b.sensor("S5").y_mm])
    assert np.hypot(*(xy - s5)) < 6.5


def test_an_unlocated_sensor_moves_with_its_located_wire_mates(patch_b):
    planner = AdaptivePlanner(patch_b)
    # Every located sensor sits 2 mm right of and 1 mm below its design position.
    pred = predictions(patch_b, unlocated={"S14"}, offset=(2.0, -1.0))
    xy, sigma, located = planner.sensor_state(pred)
    i = patch_b.names.index("S14")
    assert not located[i] and located.sum() == 29
    assert xy[i] == pytest.approx(patch_b.design_xy[i] + (2.0, -1.0))
    assert sigma[i] == planner.unlocated_sigma_mm


def test_repeated_touches_near_one_sensor_spread_around_it(patch_b):
    # The same (isotropic) sigma after every touch: the model's shape must still move the
    # next touch to a direction not probed yet, not repeat the best point.
    planner = AdaptivePlanner(patch_b, coarse=(8, 3))
    done = uniform_points(patch_b, 8, 3)
    pred = predictions(patch_b, sigma={"S14": 2.0})
    chosen = []
    for _ in range(4):
        xy = planner.choose(done, pred)
        chosen.append(xy)
        done = np.vstack([done, xy])
    chosen = np.array(chosen)
    assert len(np.unique(chosen, axis=0)) == 4
    s14 = np.array([patch_b.sensor("S14").x_mm, patch_b.sensor("S14").y_mm])
    assert (np.hypot(*(chosen - s14).T) < 8.0).all()
    # On more than one side of the sensor.
    assert np.ptp(np.sign(chosen[:, 0] - s14[0])) > 0 or np.ptp(np.sign(chosen[:, 1] - s14[1])) > 0


def test_plan_stops_once_every_sigma_is_under_target(patch_b):
    planner = AdaptivePlanner(patch_b, coarse=(4, 2), target_sigma_mm=0.5)
    state = {"k": 0}

    def respond(t, touches):
        # Sensors reach the target after the 12th touch.
        state["k"] += 1
        return TouchOutcome(t, True, predictions(patch_b, 0.45 if state["k"] >= 12 else 0.9))

    touches, _ = drive(planner, respond)
    assert len(touches) == 12
    assert planner.stop_reason == TARGET
    # Good enough from the start: the coarse pass is still completed, then the plan ends.
    touches, _ = drive(planner, lambda t, _: TouchOutcome(t, True, predictions(patch_b, 0.3)))
    assert len(touches) == 8 and planner.stop_reason == TARGET


def test_plan_stops_at_the_budget_and_a_small_budget_cuts_the_coarse_pass(patch_b):
    pred = predictions(patch_b, 0.3, unlocated={"S3"})
    planner = AdaptivePlanner(patch_b, coarse=(4, 3), budget=17)
    touches, _ = drive(planner, lambda t, _: TouchOutcome(t, True, pred))
    assert len(touches) == 17 and planner.stop_reason == BUDGET
    planner = AdaptivePlanner(patch_b, coarse=(4, 3), budget=5)
    touches, _ = drive(planner, lambda t, _: TouchOutcome(t, True, pred))
    assert [t.phase for t in touches] == [COARSE] * 5


def test_failed_touches_are_never_proposed_again_and_the_plan_still_ends(patch_b):
    pred = predictions(patch_b, 0.3, unlocated={"S14"})
    planner = AdaptivePlanner(patch_b, coarse=(4, 2), budget=40, exclusion_mm=1.5)

    def respond(t, _):
        # Every touch near the unlocated sensor fails (say the skin is torn there).
        ok = t.phase == COARSE or np.hypot(t.x_mm - 100.8, t.y_mm - 13.5) > 10.0
        return TouchOutcome(t, ok, pred if ok else None)

    touches, outcomes = drive(planner, respond)
    assert len(touches) == 40
    failed = np.array(
        [[t.x_mm, t.y_mm] for t, o in zip(touches, outcomes, strict=True) if not o.ok]
    )
    assert len(failed) >= 2
    for k, t in enumerate(touches):
        earlier = [
            (u.x_mm, u.y_mm) for u, o in zip(touches[:k], outcomes[:k], strict=True) if not o.ok
        ]
        if earlier:
            assert np.hypot(*(np.array(earlier) - (t.x_mm, t.y_mm)).T).min() > 1.5
    # Without an exclusion radius a failed point is still never proposed twice.
    planner = AdaptivePlanner(patch_b, coarse=None, budget=12, exclusion_mm=0.0)
    touches, _ = drive(planner, lambda t, _: TouchOutcome(t, False, None))
    assert len({(t.x_mm, t.y_mm) for t in touches}) == 12


def test_a_plan_with_every_candidate_excluded_ends(patch_b):
    planner = AdaptivePlanner(patch_b, coarse=None, budget=1000, exclusion_mm=200.0)
    touches, _ = drive(planner, lambda t, _: TouchOutcome(t, False, None))
    assert len(touches) == 1 and planner.stop_reason == EXHAUSTED


def _fake_localizer(patch):
    """Deterministic stand-in: a sensor is located after 3 touches within 10 mm of it and
    its sigma shrinks with every such touch."""
    design = patch.design_xy

    def respond(t, touches):
        if t.index % 7 == 3:
            return TouchOutcome(t, False, None)
        made = np.array([[u.x_mm, u.y_mm] for u in touches])
        near = (np.hypot(*(made[:, None, :] - design[None]).transpose(2, 0, 1)) < 10.0).sum(0)
        est = []
        for s, n in zip(patch.sensors, near, strict=True):
            if n < 3:
                est.append(SensorEstimate(s.name, None, None, None, None, "sparse"))
            else:
                est.append(SensorEstimate(s.name, s.x_mm + 0.1234567, s.y_mm, 2.0 / np.sqrt(n)))
        return TouchOutcome(t, True, Predictions("peakfit", est))

    return respond


def test_replaying_stored_outcomes_reaches_the_same_plan(patch_b):
    planner = AdaptivePlanner(patch_b, coarse=(6, 2), budget=80, target_sigma_mm=1.0)
    touches, outcomes = drive(planner, _fake_localizer(patch_b))
    assert planner.stop_reason == TARGET and any(t.phase == ADAPTIVE for t in touches)

    # A resumed session re-feeds what it stored: predictions as the CSV keeps them (4
    # decimals) and touches rebuilt from their records. Same choices, to the bit.
    def stored(o: TouchOutcome) -> TouchOutcome:
        if o.predictions is None:
            return o
        est = [
            SensorEstimate(
                e.sensor,
                None if e.x_mm is None else float(f"{e.x_mm:.4f}"),
                None if e.y_mm is None else float(f"{e.y_mm:.4f}"),
                None if e.sigma_mm is None else float(f"{e.sigma_mm:.4f}"),
                None,
                e.status,
            )
            for e in o.predictions
        ]
        return TouchOutcome(o.touch, o.ok, Predictions("peakfit", est))

    replay = AdaptivePlanner(patch_b, coarse=(6, 2), budget=80, target_sigma_mm=1.0)
    gen = replay.plan()
    touch = next(gen)
    for old, outcome in zip(touches, outcomes, strict=True):
        assert touch == old
        try:
            touch = gen.send(stored(outcome))
        except StopIteration:
            touch = None
    assert touch is None and replay.stop_reason == TARGET


def test_given_first_points_are_proposed_in_order_then_the_sensors_still_missing(patch_b):
    """A refinement (``calibrate --resume --refine``) re-proposes a session's touches, failed
    ones too, then touches where sensors are still missing, never where one failed."""
    first = uniform_points(patch_b, 5, 3)
    planner = AdaptivePlanner(patch_b, coarse=None, first_points=first, budget=len(first) + 3)
    pred = predictions(patch_b, sigma=0.3, unlocated={"S14"})
    failed_at = 7

    def respond(t, _):
        return TouchOutcome(t, t.index != failed_at, pred)

    touches, _ = drive(planner, respond)
    assert [t.index for t in touches] == list(range(len(first) + 3))
    assert [t.phase for t in touches[: len(first)]] == [GIVEN] * len(first)
    assert np.array_equal([[t.x_mm, t.y_mm] for t in touches[: len(first)]], first)
    s14 = np.array([patch_b.sensor("S14").x_mm, patch_b.sensor("S14").y_mm])
    for t in touches[len(first) :]:
        assert t.phase == ADAPTIVE
        # around the missing sensor: within about a footprint (6.5 mm), spreading out
        assert np.hypot(t.x_mm - s14[0], t.y_mm - s14[1]) < 10.0
        assert np.hypot(*(np.array([t.x_mm, t.y_mm]) - first[failed_at])) > planner.exclusion_mm
    assert planner.stop_reason == BUDGET
    # Every sensor already within the target: nothing to add.
    done = AdaptivePlanner(patch_b, coarse=None, first_points=first, budget=len(first) + 3)
    touches, _ = drive(done, lambda t, _: TouchOutcome(t, True, predictions(patch_b, 0.3)))
    assert len(touches) == len(first) and done.stop_reason == TARGET


def test_plain_next_counts_the_touch_as_made(patch_b):
    planner = AdaptivePlanner(patch_b, coarse=(2, 2), budget=6)
    touches = list(planner.plan())
    assert len(touches) == 6 and [t.index for t in touches] == list(range(6))
    assert planner.stop_reason == BUDGET


def test_bad_parameters_are_refused(patch_b):
    for kwargs in (
        {"budget": 0},
        {"target_sigma_mm": 0.0},
        {"candidate_step_mm": -1.0},
        {"margin_mm": 20.0},
        {"coarse": (0, 3)},
        {"exclusion_mm": -1.0},
        {"first_points": [[1.0, 2.0]]},  # with the default coarse pass
        {"coarse": None, "first_points": [1.0, 2.0]},
        {"coarse": None, "first_points": [[1.0, np.nan]]},
    ):
        with pytest.raises(ValueError):
            AdaptivePlanner(patch_b, **kwargs)


# --- with the real localizer ------------------------------------------------------------


def test_adaptive_session_on_simulated_patch_b_reaches_half_a_millimetre(patch_b):
    """A session as the benchmark runs it (benchmarks/adaptive_plan.py), on one seed: the
    plan must stop by itself with every sensor located and RMS <= 0.5 mm, in fewer touches
    than the 20 x 5 grid's 100."""
    seed = 3
    scene = Scene.create(patch_b, seed)
    probe = ProbeModel.named("robot")
    rng = np.random.default_rng([seed, 1])
    base = scene.sample(None, None, 0.0, probe, np.arange(BASELINE_SAMPLES) / FRAME_RATE_HZ, rng)
    rest, rest_sd = base.mean(axis=0), base.std(axis=0, ddof=1)
    loc = Localizer(patch_b.names, rest, rest_sd, patch=patch_b)
    clock = {"t": BASELINE_SAMPLES / FRAME_RATE_HZ + 2.0}

    def respond(t, _):
        log = simulate_touch(scene, probe, t.x_mm, t.y_mm, clock["t"], rng, 8, t.index + 1, rest)
        clock["t"] += 4.0
        loc.update(log)
        return TouchOutcome(t, True, loc.result())

    planner = AdaptivePlanner(patch_b, budget=70)
    touches, outcomes = drive(planner, respond)
    final = outcomes[-1].predictions
    assert planner.stop_reason == TARGET, len(touches)
    assert all(e.status == OK for e in final)
    assert in_box(patch_b, touches, planner.margin_mm)
    err = np.hypot(*(final.xy() - scene.true_xy).T)
    assert np.sqrt((err**2).sum() / (len(err) - 1)) <= 0.5
    assert len(touches) <= 60

"""The located sensors against the patch's design: shift, turn and stretch, and the
warning when the whole layout lies turned or shifted beyond what a registration leaves."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from varskin.cli import main
from varskin.design_fit import fit_design
from varskin.localization import localize
from varskin.patch import builtin_patch, patch_from_dict
from varskin.pointlog_csv import write_point_logs_csv
from varskin.predictions import Predictions, SensorEstimate
from varskin.scene import SceneParams
from varskin.simulate import simulate_session, uniform_grid

PATCH_B = builtin_patch("patch_b")


def placed(xy, statuses=None, sigma=0.1, patch=PATCH_B) -> Predictions:
    statuses = statuses or ["ok"] * len(xy)
    return Predictions(
        "test",
        [
            SensorEstimate(s.name, float(x), float(y), sigma, 30.0, st)
            for s, (x, y), st in zip(patch.sensors, xy, statuses, strict=True)
        ],
        {},
    )


def moved(design, shift, turn_deg, stretch):
    a = np.radians(turn_deg)
    turn = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    centre = design.mean(axis=0)
    return centre + np.asarray(shift) + (design - centre) @ turn.T * (1.0 + stretch)


@pytest.mark.parametrize(
    "shift,turn_deg,stretch,warned",
    [
        ((0.0, 0.0), 0.0, 0.0, set()),
        ((0.4, -0.3), 0.5, 0.01, set()),
        ((0.0, 0.0), -2.5, -0.02, {"turned"}),
        ((2.5, 0.5), 0.0, 0.0, {"shifted"}),
    ],
)
def test_a_layout_moved_as_a_whole_is_measured_exactly(shift, turn_deg, stretch, warned):
    design = PATCH_B.design_xy
    fit = fit_design(placed(moved(design, shift, turn_deg, stretch)), PATCH_B)
    assert fit.n_sensors == 30
    # Equal sigmas: the weighted centre is the plain one, so the shift is exactly `shift`.
    np.testing.assert_allclose(fit.shift_mm, shift, atol=1e-9)
    assert fit.turn_deg == pytest.approx(turn_deg, abs=1e-9)
    assert fit.stretch == pytest.approx(stretch, abs=1e-12)
    assert fit.off_design_rms_mm < 1e-9
    said = {w.split()[4] for w in fit.warnings()}  # "the located sensors lie <word> ..."
    assert said == warned
    for w in fit.warnings():
        assert "check the registration" in w and "\n" not in w
    assert f"turned {turn_deg:+.2f} deg" in fit.summary()


def test_only_located_sensors_count_and_too_few_give_no_fit():
    design = PATCH_B.design_xy
    xy = moved(design, (0.0, 0.0), 1.5, 0.0)
    statuses = ["ok"] * 30
    # A sensor that is not `ok` (here wildly off) must not move the fit.
    xy[4] = (500.0, -300.0)
    statuses[4] = "irregular"
    fit = fit_design(placed(xy, statuses), PATCH_B)
    assert fit.n_sensors == 29 and fit.turn_deg == pytest.approx(1.5, abs=1e-9)
    # One sensor built 1 mm off: the rest still give the transform, and it is the largest.
    xy[7] += (1.0, 0.0)
    fit = fit_design(placed(xy, statuses), PATCH_B)
    assert fit.largest[0] == PATCH_B.sensors[7].name and 0.8 < fit.largest[1] < 1.05
    dx, dy = fit.off_design_mm[PATCH_B.sensors[7].name]
    assert 0.8 < dx < 1.05 and abs(dy) < 0.05 and len(fit.off_design_mm) == 29
    assert abs(fit.turn_deg - 1.5) < 0.05
    few = ["ok", "ok"] + ["dead"] * 28
    assert fit_design(placed(xy, few), PATCH_B) is None
    # Sensors the patch does not name are left out, as if not located.
    renamed = Predictions("test", [replace(e, sensor=f"X{e.sensor}") for e in placed(xy)], {})
    assert fit_design(renamed, PATCH_B) is None


def test_a_turn_is_warned_about_only_where_the_layout_can_show_it():
    """The same 1.5-degree turn and the same 0.4 mm build jitter of each crossing: on Patch
    B (152 mm long) the turn stands out; on a 20 mm patch of 3 x 3 crossings the jitter
    alone turns the layout by about as much, so no warning (its sd says why)."""
    tiny = patch_from_dict(
        {"name": "tiny", "size_mm": [20, 20], "tx_x_mm": [4, 10, 16], "rx_y_mm": [4, 10, 16]},
        "tiny",
    )
    rng = np.random.default_rng(3)
    for patch, warned in ((PATCH_B, True), (tiny, False)):
        design = patch.design_xy
        xy = moved(design, (0.0, 0.0), 1.5, 0.0) + rng.normal(0.0, 0.4, design.shape)
        fit = fit_design(placed(xy, patch=patch), patch)
        assert abs(fit.turn_deg) > 1.0  # beyond TURN_WARN_DEG either way
        assert any("turned" in w for w in fit.warnings()) == warned
        assert (fit.turn_sd_deg < 0.3) == warned  # about 0.1 on Patch B, degrees on tiny


def test_a_localized_turned_scene_shows_its_turn_and_an_unturned_one_none():
    """On simulated scenes whose built layout is itself off its design (wire offsets and
    bends), the fit to the located sensors follows the fit to the hidden truth."""
    grid = uniform_grid(PATCH_B, 20, 5)
    for turn_deg, warned in ((0.0, False), (2.0, True)):
        session = simulate_session(
            PATCH_B, grid, "robot", 0, replace(SceneParams(), rotation_deg=turn_deg)
        )
        fit = fit_design(localize(session.point_logs(), patch=PATCH_B), PATCH_B)
        truth = fit_design(placed(session.truth), PATCH_B)
        assert fit.n_sensors >= 28
        assert abs(fit.turn_deg - truth.turn_deg) < 0.15
        assert abs(fit.stretch - truth.stretch) < 0.005
        assert abs(truth.turn_deg - turn_deg) < 0.5
        assert any("turned" in w for w in fit.warnings()) == warned


def test_localize_with_the_patch_prints_the_fit_and_warns_on_a_turn(tmp_path, capsys):
    session = simulate_session(
        PATCH_B, uniform_grid(PATCH_B, 20, 5), "robot", 1, replace(SceneParams(), rotation_deg=3)
    )
    logs = tmp_path / "turned.csv"
    write_point_logs_csv(logs, session.point_logs())
    plots = tmp_path / "plots"
    args = ["localize", str(logs), "-o", str(tmp_path / "p.csv"), "--plots", str(plots)]
    args += ["--plot-sensors", "S1"]  # one map: the others would take most of the test's time
    assert main([*args, "--patch", "patch_b"]) == 0
    out, err = capsys.readouterr()
    # The displacements from the design, magnified, beside the predictions.
    assert (plots / "off_design.png").stat().st_size > 5000
    assert "against the design (" in out and "turned +" in out
    warning = [line for line in err.splitlines() if "turned" in line]
    assert len(warning) == 1 and warning[0].startswith("varskin: warning: the located sensors")
    assert "check the registration" in warning[0]
    # Without the patch there is no design to hold the sensors against.
    (plots / "off_design.png").unlink()
    assert main(args) == 0
    out, err = capsys.readouterr()
    assert "against the design" not in out and "turned" not in err
    assert not (plots / "off_design.png").exists() and (plots / "predictions.png").exists()

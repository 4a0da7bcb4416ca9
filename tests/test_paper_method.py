"""The published method: exact on a symmetric peak, in the published error band on Patch B."""

from __future__ import annotations

import math

import numpy as np
import pytest

import varskin
from varskin.errors import InputError
from varskin.localization import paper
from varskin.pointlogs import PointLogs
from varskin.simulate import simulate_session, uniform_grid


def make_logs(xy, values, rest_sd=None):
    xy = np.asarray(xy, float)
    values = np.asarray(values, float).reshape(len(xy), -1)
    names = tuple(f"S{j + 1}" for j in range(values.shape[1]))
    rest = None if rest_sd is None else np.zeros(values.shape[1])
    sd = None if rest_sd is None else np.asarray(rest_sd, float)
    return PointLogs(
        names, np.arange(1, len(xy) + 1), xy, values, np.ones(len(xy), int), rest=rest, rest_sd=sd
    )


def square_grid(n=9, pitch=5.0):
    g = np.arange(n) * pitch
    gx, gy = np.meshgrid(g, g, indexing="ij")
    return np.column_stack([gx.ravel(), gy.ravel()])


def peak(xy, centre, width=9.0, height=300.0):
    d2 = (((np.asarray(xy) - centre) / width) ** 2).sum(axis=1)
    return height / (1.0 + d2)


@pytest.mark.parametrize("centre", [(20.0, 20.0), (15.0, 20.0), (25.0, 15.0)])
def test_symmetric_peak_on_a_grid_node_is_recovered(centre):
    xy = square_grid()
    logs = make_logs(xy, peak(xy, np.array(centre)))
    e = paper.localize(logs, ppcm=32).estimates[0]
    assert e.status == "ok"
    assert math.hypot(e.x_mm - centre[0], e.y_mm - centre[1]) < 0.1


def test_symmetric_peak_on_the_patch_b_grid_is_recovered(patch_b):
    xy = uniform_grid(patch_b, 20, 5)
    centre = xy[52]  # a node in the middle of the paper's 20x5 grid
    logs = make_logs(xy, peak(xy, centre))
    e = varskin.localize(logs, method="paper", ppcm=32).estimates[0]
    assert math.hypot(e.x_mm - centre[0], e.y_mm - centre[1]) < 0.1


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_patch_b_finger_lands_in_the_published_band(patch_b, seed):
    session = simulate_session(patch_b, uniform_grid(patch_b, 20, 5), "finger", seed)
    predictions = varskin.localize(session.point_logs(), method="paper", ppcm=32)
    assert predictions.method == "paper"
    assert all(e.status == "ok" for e in predictions)
    errors = np.hypot(*(predictions.xy() - session.truth).T)
    rms = math.sqrt((errors**2).sum() / (len(errors) - 1))
    assert 1.0 <= rms <= 2.5, rms
    # The simulated SNR sits near the real recordings (26-40 dB), well below the paper's 61-65.
    snr = [e.snr_db for e in predictions]
    assert all(s is not None for s in snr)
    assert 20 < np.median(snr) < 45
    assert all(e.sigma_mm is None for e in predictions)


def test_snr_follows_the_paper_equation():
    xy = square_grid(3)
    values = np.zeros((9, 3))
    values[4] = [200.0, -5.0, 50.0]
    values[0] = [20.0, -1.0, 10.0]
    logs = make_logs(xy, values, rest_sd=[2.0, 3.0, 0.0])
    est = paper.localize(logs, ppcm=16).estimates
    assert est[0].snr_db == pytest.approx(40.0)  # 20 log10(200 / 2)
    assert est[1].snr_db is None  # no positive signal: the log is undefined
    assert est[2].snr_db is None  # sigma0 of zero: undefined, not infinite
    assert est[1].status == "flat" and est[1].x_mm is None


def test_no_baseline_means_no_snr():
    xy = square_grid(3)
    logs = make_logs(xy, peak(xy, np.array([5.0, 5.0])))
    assert paper.localize(logs, ppcm=16).estimates[0].snr_db is None


def test_statuses_instead_of_nan(tmp_path):
    xy = square_grid(5)
    values = np.column_stack(
        [peak(xy, np.array([10.0, 10.0])), -peak(xy, np.array([5.0, 5.0])), np.zeros(25)]
    )
    logs = make_logs(xy, values)
    predictions = paper.localize(logs, ppcm=16)
    assert [e.status for e in predictions] == ["ok", "flat", "flat"]
    # An area entirely outside the probes' hull has no data at all.
    far = paper.localize(logs, ppcm=16, area=(100, 100, 110, 110))
    assert far.estimates[0].status == "nodata"
    out = tmp_path / "pred.csv"
    predictions.to_csv(out)
    predictions.to_json(tmp_path / "pred.json")
    assert "nan" not in out.read_text().lower()
    assert "nan" not in (tmp_path / "pred.json").read_text().lower()


def test_outside_the_hull_is_nan_not_zero():
    xy = square_grid(5)  # hull is [0, 20] x [0, 20]
    values = peak(xy, np.array([10.0, 10.0]))
    gx, gy = paper.pixel_grid((-5.0, -5.0, 25.0, 25.0), 16)
    image = paper.interpolate(xy, values, gx, gy)
    outside = (gx[None, :] < 0) | (gx[None, :] > 20) | (gy[:, None] < 0) | (gy[:, None] > 20)
    inside = (
        ~outside
        & (gx[None, :] > 0.1)
        & (gx[None, :] < 19.9)
        & (gy[:, None] > 0.1)
        & (gy[:, None] < 19.9)
    )
    assert np.isnan(image[outside]).all()
    assert np.isfinite(image[inside]).all()
    # The larger area adds no pixels to the peak, so the prediction barely moves.
    logs = make_logs(xy, values)
    a = paper.localize(logs, ppcm=16).estimates[0]
    b = paper.localize(logs, ppcm=16, area=(-5.0, -5.0, 25.0, 25.0)).estimates[0]
    assert math.hypot(a.x_mm - b.x_mm, a.y_mm - b.y_mm) < 10 / 16


def test_threshold_keeps_pixels_above_eta_times_max():
    # A ramp along x: the pixels above eta * max are those with x > eta * x_max.
    xy = square_grid(5)
    logs = make_logs(xy, xy[:, 0] + 0.0)
    for eta in (0.52, 0.81):  # thresholds between pixels: no ties
        e = paper.localize(logs, eta=eta, ppcm=20).estimates[0]
        gx = paper.pixel_grid((0, 0, 20, 20), 20)[0]
        assert e.x_mm == pytest.approx(gx[gx > eta * 20].mean(), abs=1e-6)
        assert e.y_mm == pytest.approx(10.0, abs=1e-6)


def test_pixel_pitch_is_ten_over_ppcm():
    gx, gy = paper.pixel_grid((0.0, 0.0, 10.0, 5.0), 128)
    assert np.diff(gx) == pytest.approx(np.full(len(gx) - 1, 10 / 128))
    assert len(gx) == 129 and len(gy) == 65
    assert gx[0] == 0.0 and gx[-1] == pytest.approx(10.0)


def test_duplicate_locations_are_averaged():
    xy = square_grid(4)
    values = peak(xy, np.array([7.0, 8.0]))
    once = paper.localize(make_logs(xy, values), ppcm=16).estimates[0]
    twice_xy = np.vstack([xy, xy[:3]])
    twice_values = np.concatenate([values, values[:3]])
    twice_values[:3] += 40.0
    twice_values[-3:] -= 40.0
    twice = paper.localize(make_logs(twice_xy, twice_values), ppcm=16).estimates[0]
    assert (twice.x_mm, twice.y_mm) == pytest.approx((once.x_mm, once.y_mm))


def test_a_log_without_a_position_is_left_out():
    """Through the Python API a log may carry a NaN position (the CSV reader refuses one);
    like peakfit, the paper method leaves it out instead of raising qhull's ValueError."""
    xy = square_grid(4)
    values = peak(xy, np.array([7.0, 8.0]))
    clean = paper.localize(make_logs(xy, values), ppcm=16).estimates[0]
    with_nan = paper.localize(
        make_logs(np.vstack([xy, [np.nan, 3.0]]), np.append(values, 999.0)), ppcm=16
    ).estimates[0]
    assert (with_nan.x_mm, with_nan.y_mm, with_nan.status) == (clean.x_mm, clean.y_mm, "ok")


@pytest.mark.parametrize(
    "params,words",
    [
        ({"eta": 0.0}, "eta"),
        ({"eta": 1.0}, "eta"),
        ({"eta": -0.2}, "eta"),
        ({"eta": float("nan")}, "eta"),
        ({"eta": "high"}, "eta"),
        ({"ppcm": 0}, "ppcm"),
        ({"ppcm": -16}, "ppcm"),
        ({"ppcm": True}, "ppcm"),
        ({"ppcm": 1e9}, "too large"),
        ({"area": (0, 0, 10)}, "4 numbers"),
        ({"area": (10, 0, 0, 10)}, "x1 > x0"),
        ({"area": (0, 5, 10, 5)}, "y1 > y0"),
        ({"area": (0, 0, "a", 1)}, "area"),
        ({"area": (0, 0, float("inf"), 1)}, "finite"),
        ({"sigma": 2.0}, "unknown parameter"),
    ],
)
def test_bad_parameters_are_input_errors(params, words):
    xy = square_grid(4)
    with pytest.raises(InputError, match=words):
        paper.localize(make_logs(xy, peak(xy, np.array([7.0, 8.0]))), **params)


def test_area_accepts_text():
    xy = square_grid(4)
    logs = make_logs(xy, peak(xy, np.array([7.0, 8.0])))
    predictions = paper.localize(logs, ppcm=16, area="0,0,15,15")
    assert predictions.params["area"] == [0.0, 0.0, 15.0, 15.0]


def test_collinear_or_too_few_probes_are_explained():
    line = np.column_stack([np.arange(6.0), np.zeros(6)])
    with pytest.raises(InputError, match="one line"):
        paper.localize(make_logs(line, np.arange(6.0)), ppcm=16)
    two = np.array([[0.0, 0.0], [1.0, 1.0], [1.0, 1.0]])
    with pytest.raises(InputError, match="at least 3"):
        paper.localize(make_logs(two, [1.0, 2.0, 3.0]), ppcm=16)


def test_unknown_method_is_an_input_error():
    xy = square_grid(3)
    with pytest.raises(InputError, match="unknown method"):
        varskin.localize(make_logs(xy, np.ones(9)), method="magic")

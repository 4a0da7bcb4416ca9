"""Scoring against truth: the paper's RMS divides by N - 1; gaps are reported, not fatal."""

from __future__ import annotations

import math

import pytest

from varskin.errors import InputError
from varskin.evaluate import evaluate, read_predictions_csv, rms_n_minus_1
from varskin.predictions import Predictions, SensorEstimate


def test_rms_divides_by_n_minus_1():
    assert rms_n_minus_1([3.0, 4.0]) == pytest.approx(5.0)  # sqrt(25 / 1), not sqrt(25 / 2)
    assert rms_n_minus_1([1.0, 1.0, 1.0, 1.0, 1.0]) == pytest.approx(math.sqrt(5 / 4))
    assert rms_n_minus_1([2.0]) is None
    assert rms_n_minus_1([]) is None


def predictions():
    return Predictions(
        "test",
        [
            SensorEstimate("S1", 3.0, 0.0),  # 3 mm off
            SensorEstimate("S2", 10.0, 14.0, sigma_mm=1.0),  # 4 mm off
            SensorEstimate("S3", None, None, status="flat"),
            SensorEstimate("S9", 1.0, 1.0),  # no truth
        ],
    )


TRUTH = {"S1": (0.0, 0.0), "S2": (10.0, 10.0), "S3": (5.0, 5.0), "S4": (7.0, 7.0)}


def test_per_sensor_errors_and_summary():
    result = evaluate(predictions(), TRUTH)
    rows = {r.sensor: r for r in result.rows}
    assert rows["S1"].error_mm == pytest.approx(3.0)
    assert rows["S2"].error_mm == pytest.approx(4.0)
    assert rows["S3"].error_mm is None and rows["S3"].status == "flat"
    assert rows["S9"].status == "notruth" and rows["S9"].error_mm is None
    assert rows["S4"].status == "nopred" and rows["S4"].true_x_mm == 7.0
    assert result.n_ok == 2
    assert result.rms_mm == pytest.approx(5.0)
    assert result.mean_mm == pytest.approx(3.5)
    assert result.max_mm == pytest.approx(4.0)
    d = result.to_dict()
    assert d["rms_mm"] == pytest.approx(5.0) and len(d["sensors"]) == 5
    text = result.table() + "\n" + result.summary()
    assert "S4" in text and "nopred" in text and "RMS (N-1) 5.000 mm" in text


def test_nothing_localized_gives_empty_summary_not_nan():
    p = Predictions("x", [SensorEstimate("S1", None, None, status="dead")])
    result = evaluate(p, {"S1": (0.0, 0.0)})
    assert result.n_ok == 0 and result.rms_mm is None and result.mean_mm is None
    assert "nan" not in result.summary().lower()


def test_predictions_csv_round_trip(tmp_path):
    path = tmp_path / "pred.csv"
    predictions().to_csv(path)
    back = read_predictions_csv(path)
    assert [e.sensor for e in back] == ["S1", "S2", "S3", "S9"]
    assert back.by_name()["S2"].sigma_mm == pytest.approx(1.0)
    assert back.by_name()["S3"].status == "flat" and back.by_name()["S3"].x_mm is None


@pytest.mark.parametrize(
    "text,where",
    [
        ("sensor,x_mm,y_mm,sigma_mm,snr_db,status\nS1,1,2,,,ok\nS1,1,2,,,ok\n", ":3:1:"),
        ("sensor,x_mm,y_mm,sigma_mm,snr_db,status\nS1,one,2,,,ok\n", ":2:2:"),
        ("sensor,x_mm,y_mm,sigma_mm,snr_db,status\nS1,nan,2,,,ok\n", ":2:2:"),
        ("sensor,x_mm,y_mm,sigma_mm,snr_db,status\nS1,1,2,,\n", ":2:6:"),
        ("sensor,x_mm,y_mm,sigma_mm,snr_db,status\nS1,,,,,ok\n", ":2:6:"),
        ("sensor,x,y\n", ":1:2:"),
    ],
)
def test_bad_predictions_csv(tmp_path, text, where):
    path = tmp_path / "pred.csv"
    path.write_text(text)
    with pytest.raises(InputError, match=f"^{path}{where}"):
        read_predictions_csv(path)

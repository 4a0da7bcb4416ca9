"""The point-log CSV: round trips, every malformed input named by file:line:column, warnings."""

from __future__ import annotations

import re

import numpy as np
import pytest

import varskin
from varskin.errors import InputError, PointLogFormatError
from varskin.localization import localize
from varskin.pointlog_csv import (
    read_point_logs,
    read_truth_csv,
    write_point_logs_csv,
    write_samples_csv,
    write_truth_csv,
)
from varskin.simulate import simulate_session, uniform_grid


@pytest.fixture(scope="module")
def session(patch_b):
    return simulate_session(patch_b, uniform_grid(patch_b, 10, 3), "finger", seed=3)


def write(tmp_path, text, name="logs.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


GOOD_HEAD = "touch,x_mm,y_mm,A,B\n"
GOOD_ROWS = "1,0,0,10,1\n1,0,0,12,1\n2,5,0,3,4\n3,0,5,2,8\n"


def test_samples_round_trip_matches_in_memory_averaging(tmp_path, session):
    path = tmp_path / "logs.csv"
    write_samples_csv(path, session)
    logs = read_point_logs(path)
    want = session.point_logs()
    assert logs.sensors == want.sensors == session.sensors
    assert logs.warnings == []
    np.testing.assert_array_equal(logs.touch, want.touch)
    np.testing.assert_allclose(logs.xy_mm, want.xy_mm, rtol=0, atol=0)
    np.testing.assert_allclose(logs.values, want.values, rtol=0, atol=1e-9)
    np.testing.assert_allclose(logs.rest, want.rest, atol=1e-9)
    np.testing.assert_allclose(logs.rest_sd, want.rest_sd, atol=1e-9)
    np.testing.assert_allclose(logs.t_s, want.t_s, atol=1e-9)
    np.testing.assert_allclose(logs.force_n, want.force_n, atol=1e-12)
    np.testing.assert_array_equal(logs.n_samples, want.n_samples)
    # The file keeps every frame: baseline rows first, then one row per frame.
    lines = path.read_text().splitlines()
    assert lines[0].startswith("touch,x_mm,y_mm,t_s,force_n,S1,")
    assert len(lines) == 1 + len(session.baseline) + len(session.samples)
    assert lines[1].startswith("baseline,,,")
    assert not lines[len(session.baseline) + 1].startswith("baseline")


def test_point_logs_round_trip_is_exact_and_has_no_baseline(tmp_path, session):
    logs = session.point_logs()
    path = tmp_path / "averaged.csv"
    write_point_logs_csv(path, logs)
    back = varskin.read_point_logs(path)
    assert "baseline" not in path.read_text()
    np.testing.assert_array_equal(back.values, logs.values)
    np.testing.assert_array_equal(back.xy_mm, logs.xy_mm)
    np.testing.assert_array_equal(back.t_s, logs.t_s)
    np.testing.assert_array_equal(back.force_n, logs.force_n)
    assert back.rest is None and back.rest_sd is None


def test_truth_round_trip(tmp_path, session):
    path = tmp_path / "truth.csv"
    write_truth_csv(path, session.sensors, session.truth)
    truth = read_truth_csv(path)
    assert list(truth) == list(session.sensors)
    np.testing.assert_allclose(np.array(list(truth.values())), session.truth, atol=1e-4)


BAD_INPUTS = [
    # (id, file text, line, column, words in the message)
    ("empty", "", 1, 1, "empty file"),
    ("blank", "\n\n", 1, 1, "empty file"),
    ("header only", GOOD_HEAD, 2, 1, "no data rows"),
    ("missing x column", "touch,x,y_mm,A\n1,0,0,1\n", 1, 2, "'x_mm'"),
    ("missing header columns", "touch\n1\n", 1, 2, "'x_mm'"),
    ("no sensors", "touch,x_mm,y_mm\n1,0,0\n", 1, 4, "no sensor columns"),
    ("duplicate sensor", "touch,x_mm,y_mm,A,B,A\n1,0,0,1,2,3\n", 1, 6, "duplicate sensor name 'A'"),
    ("empty sensor name", "touch,x_mm,y_mm,A,,B\n1,0,0,1,2,3\n", 1, 5, "empty sensor name"),
    ("reserved after sensor", "touch,x_mm,y_mm,A,t_s\n1,0,0,1,2\n", 1, 5, "reserved column 't_s'"),
    ("reserved twice", "touch,x_mm,y_mm,t_s,t_s,A\n1,0,0,1,1,2\n", 1, 5, "appears twice"),
    (
        "non-numeric sample",
        GOOD_HEAD + "1,0,0,10,1\n2,5,0,3,oops\n3,0,5,2,8\n",
        3,
        5,
        "'oops' is not a number",
    ),
    ("empty sample", GOOD_HEAD + "1,0,0,10,1\n2,5,0,,4\n3,0,5,2,8\n", 3, 4, "empty cell"),
    (
        "non-numeric x",
        GOOD_HEAD + "1,zero,0,10,1\n2,5,0,3,4\n3,0,5,2,8\n",
        2,
        2,
        "'zero' is not a number",
    ),
    ("nan position", GOOD_HEAD + "1,0,nan,10,1\n2,5,0,3,4\n3,0,5,2,8\n", 2, 3, "finite"),
    (
        "time at 1e200 s",
        "touch,x_mm,y_mm,t_s,S1,S2\n1,0,0,1e200,10,1\n2,5,0,1,3,4\n3,0,5,2,2,8\n",
        2,
        4,
        "beyond",
    ),
    ("position at 9e18 mm", GOOD_HEAD + "1,0,0,10,1\n2,9e18,0,3,4\n3,0,5,2,8\n", 3, 2, "beyond"),
    ("too few fields", GOOD_HEAD + GOOD_ROWS + "4,5,5,1\n", 6, 5, "4 fields, the header has 5"),
    ("too many fields", GOOD_HEAD + "1,0,0,10,1,7\n" + GOOD_ROWS, 2, 6, "6 fields"),
    (
        "fractional touch id",
        GOOD_HEAD + GOOD_ROWS + "4.5,5,5,1,1\n",
        6,
        1,
        "'4.5' is neither an integer",
    ),
    ("word touch id", GOOD_HEAD + "first,0,0,1,1\n" + GOOD_ROWS, 2, 1, "'first'"),
    (
        "touch moves",
        GOOD_HEAD + GOOD_ROWS + "2,5,1,3,4\n",
        6,
        3,
        "touch 2 is at (5, 1) here but at (5, 0) on line 4",
    ),
    ("touch moves in x", GOOD_HEAD + GOOD_ROWS + "1,0.5,0,3,4\n", 6, 2, "touch 1"),
    (
        "two locations",
        GOOD_HEAD + "1,0,0,1,1\n2,5,0,2,2\n2,5,0,3,3\n",
        4,
        2,
        "only 2 distinct probe location",
    ),
    ("only baseline", GOOD_HEAD + "baseline,,,1,2\nbaseline,,,1,2\n", 3, 1, "no touch rows"),
    (
        "baseline with x",
        GOOD_HEAD + "baseline,3,,1,2\n" + GOOD_ROWS,
        2,
        2,
        "baseline rows leave x_mm empty",
    ),
    (
        "bad t_s",
        "touch,x_mm,y_mm,t_s,A\n1,0,0,soon,1\n2,5,0,1,1\n3,0,5,2,1\n",
        2,
        4,
        "'soon' is not a number in column 't_s'",
    ),
    (
        "bad baseline t_s",
        "touch,x_mm,y_mm,t_s,A\nbaseline,,,x,1\n1,0,0,0,1\n2,5,0,1,1\n3,0,5,2,1\n",
        2,
        4,
        "'x'",
    ),
    (
        "baseline all nan",
        GOOD_HEAD + "baseline,,,nan,1\n" + GOOD_ROWS,
        6,
        4,
        "no finite baseline sample",
    ),
]


@pytest.mark.parametrize(
    "text,line,column,words", [b[1:] for b in BAD_INPUTS], ids=[b[0] for b in BAD_INPUTS]
)
def test_bad_input_names_file_line_and_column(tmp_path, text, line, column, words):
    path = write(tmp_path, text)
    with pytest.raises(PointLogFormatError) as info:
        read_point_logs(path)
    message = str(info.value)
    assert message.startswith(f"{path}:{line}:{column}: "), message
    assert words in message
    assert "\n" not in message
    assert isinstance(info.value, InputError)


def test_missing_file_is_a_format_error(tmp_path):
    with pytest.raises(PointLogFormatError, match="cannot read"):
        read_point_logs(tmp_path / "nope.csv")


def test_bad_cell_deep_in_a_large_file_is_located(tmp_path):
    rows = [f"{k // 40 + 1},{(k // 40) % 7},{(k // 40) // 7},{k},{k + 1}" for k in range(4000)]
    rows[3210] = rows[3210].rsplit(",", 1)[0] + ",12..5"
    path = write(tmp_path, GOOD_HEAD + "\n".join(rows) + "\n")
    with pytest.raises(PointLogFormatError, match=rf"^{re.escape(str(path))}:3212:5: '12\.\.5'"):
        read_point_logs(path)


def test_non_finite_samples_are_skipped_and_counted(tmp_path):
    text = GOOD_HEAD + "1,0,0,10,1\n1,0,0,nan,3\n1,0,0,14,inf\n2,5,0,3,-inf\n2,5,0,5,4\n3,0,5,2,8\n"
    logs = read_point_logs(write(tmp_path, text))
    assert len(logs) == 3
    assert any("3 non-finite" in w for w in logs.warnings), logs.warnings
    np.testing.assert_allclose(logs.values[0], [12.0, 2.0])  # NaN/inf left out of the means
    np.testing.assert_allclose(logs.values[1], [4.0, 4.0])
    assert np.isfinite(logs.values).all()


def test_touch_without_valid_sample_is_dropped_with_warning(tmp_path):
    text = GOOD_HEAD + GOOD_ROWS + "7,5,5,nan,1\n7,5,5,nan,2\n"
    logs = read_point_logs(write(tmp_path, text))
    assert list(logs.touch) == [1, 2, 3]
    assert any("dropped touch(es) 7" in w for w in logs.warnings), logs.warnings


def test_too_few_locations_after_dropping_is_an_error(tmp_path):
    text = GOOD_HEAD + "1,0,0,1,1\n2,5,0,2,2\n3,0,5,nan,3\n"
    with pytest.raises(PointLogFormatError, match="only 2 distinct"):
        read_point_logs(write(tmp_path, text))


def test_baseline_gives_rest_and_sigma0_and_is_subtracted(tmp_path):
    text = (
        "touch,x_mm,y_mm,A,B\n"
        "baseline,,,100,50\nbaseline,,,102,50\nbaseline,,,104,53\n"
        "1,0,0,110,60\n1,0,0,112,60\n2,5,0,100,51\n3,0,5,103,49\n"
    )
    logs = read_point_logs(write(tmp_path, text))
    np.testing.assert_allclose(logs.rest, [102.0, 51.0])
    np.testing.assert_allclose(logs.rest_sd, [2.0, np.sqrt(3.0)])
    np.testing.assert_allclose(logs.values, [[9.0, 9.0], [-2.0, 0.0], [1.0, -2.0]])
    predictions = localize(logs, method="paper", ppcm=16)
    # SNR from the baseline: sensor A peaks 9 counts above rest with sigma0 2.
    assert predictions.by_name()["A"].snr_db == pytest.approx(20 * np.log10(9 / 2))


def test_single_baseline_row_gives_rest_but_no_sigma0(tmp_path, recwarn):
    text = GOOD_HEAD + "baseline,,,5,1\n" + GOOD_ROWS
    logs = read_point_logs(write(tmp_path, text))
    np.testing.assert_allclose(logs.rest, [5.0, 1.0])
    assert any("fewer than 2 finite baseline samples" in w for w in logs.warnings)
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]
    assert all(e.snr_db is None for e in localize(logs, method="paper", ppcm=16))


def test_without_baseline_values_are_relative_and_snr_is_empty(tmp_path):
    logs = read_point_logs(write(tmp_path, GOOD_HEAD + GOOD_ROWS))
    assert logs.rest is None and logs.rest_sd is None
    np.testing.assert_allclose(logs.values[0], [11.0, 1.0])
    predictions = localize(logs, method="paper", ppcm=16)
    assert all(e.snr_db is None for e in predictions)
    out = tmp_path / "pred.csv"
    predictions.to_csv(out)
    for row in out.read_text().splitlines()[1:]:
        assert row.split(",")[4] == ""


def test_reserved_columns_in_either_order_are_averaged_per_touch(tmp_path):
    text = (
        "touch,x_mm,y_mm,force_n,t_s,A\n"
        "baseline,,,,0.5,7\nbaseline,,,0,,9\n"
        "1,0,0,2.0,10,1\n1,0,0,4.0,11,1\n2,5,0,1.0,20,1\n3,0,5,3.0,30,1\n"
    )
    logs = read_point_logs(write(tmp_path, text))
    assert logs.sensors == ("A",)
    np.testing.assert_allclose(logs.force_n, [3.0, 1.0, 3.0])
    np.testing.assert_allclose(logs.t_s, [10.5, 20.0, 30.0])
    np.testing.assert_allclose(logs.rest, [8.0])


def test_reserved_columns_absent_leave_none(tmp_path):
    logs = read_point_logs(write(tmp_path, GOOD_HEAD + GOOD_ROWS))
    assert logs.t_s is None and logs.force_n is None


def test_interleaved_touch_rows_and_blank_lines_are_fine(tmp_path):
    text = GOOD_HEAD + "1,0,0,10,1\n\n2,5,0,3,4\n1,0,0,12,1\n3,0,5,2,8\n\n"
    logs = read_point_logs(write(tmp_path, text))
    np.testing.assert_allclose(logs.values[0], [11.0, 1.0])
    np.testing.assert_array_equal(logs.n_samples, [2, 1, 1])


@pytest.mark.parametrize(
    "text,line,column",
    [
        ("sensor,x_mm,y_mm\nS1,1,2\nS1,3,4\n", 3, 1),
        ("sensor,x_mm,y_mm\nS1,1\n", 2, 3),
        ("sensor,x_mm,y_mm\nS1,one,2\n", 2, 2),
        ("sensor,x,y_mm\nS1,1,2\n", 1, 2),
        ("", 1, 1),
        ("sensor,x_mm,y_mm\n\n", 2, 1),
    ],
)
def test_bad_truth_names_line_and_column(tmp_path, text, line, column):
    path = write(tmp_path, text, "truth.csv")
    with pytest.raises(InputError, match=rf"^{re.escape(str(path))}:{line}:{column}: "):
        read_truth_csv(path)


def test_spaces_around_the_touch_cell_are_read_like_any_other_cell(tmp_path):
    text = (
        "touch,x_mm,y_mm,A,B\n baseline ,,,1,2\nbaseline,,,3,4\n"
        " 1,0,0,5,6\n2 ,10,0,7,8\n3,0,10,9,9\n"
    )
    logs = read_point_logs(write(tmp_path, text))
    np.testing.assert_allclose(logs.rest, [2.0, 3.0])
    assert logs.touch.tolist() == [1, 2, 3]


@pytest.mark.parametrize("block_rows", [3, 4096])
def test_averaging_in_blocks_equals_each_touchs_own_mean_and_sd(monkeypatch, block_rows):
    """Frames are averaged a block of rows at a time (to bound memory); a touch whose frames
    straddle blocks or come back later must get the same mean, sd and counts as its frames
    taken alone."""
    from varskin import pointlogs

    monkeypatch.setattr(pointlogs, "AVERAGE_BLOCK_ROWS", block_rows)
    rng = np.random.default_rng(4)
    touch = np.array([5, 5, 2, 5, 2, 9, 9, 9, 2, 5, 9])
    samples = 10_000.0 + rng.normal(0, 3, (touch.size, 3))
    samples[1, 0] = np.nan
    samples[7, 2] = np.inf
    xy = np.repeat(touch[:, None].astype(float), 2, axis=1)
    logs = pointlogs.average_samples(("A", "B", "C"), touch, xy, samples)
    assert list(logs.touch) == [2, 5, 9]
    assert any("2 non-finite" in w for w in logs.warnings), logs.warnings
    for row, t in enumerate(logs.touch):
        for col in range(3):
            v = samples[touch == t, col]
            v = v[np.isfinite(v)]
            assert logs.values[row, col] == pytest.approx(v.mean(), abs=1e-9)
            assert logs.sample_sd[row, col] == pytest.approx(v.std(ddof=1), abs=1e-9)
    assert list(logs.n_samples) == [3, 3, 3]  # touch 5: 4 frames, one NaN; touch 9: one inf

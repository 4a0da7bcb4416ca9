"""Cutting a point log out of the frame stream: the windows, the robust mean, the link check."""

from __future__ import annotations

import numpy as np
import pytest

from varskin.board.cellmap import CellMap
from varskin.board.frame import N_RX, N_TX, Frame, Gap
from varskin.patch import builtin_patch, patch_from_dict
from varskin.touch_window import (
    BASELINE,
    REST,
    TouchTimes,
    WindowConfig,
    WindowProblem,
    check_link,
    cut_point_log,
    reference_for,
    robust_mean,
    stored_window,
)

PATCH = builtin_patch("patch_b")
CELLMAP = CellMap.from_patch(PATCH)
REST_COUNTS = 9000.0
RESTS = np.full(len(PATCH.names), REST_COUNTS)  # the session's rest values, as measured


def _stream(times, touch_value, t_contact, t_release, rng, spike_at=None):
    """Frames every ``times``: rest + noise; sensor 0 reads +touch_value while pressed, and
    half of it in the transitions (0.1 s either side of contact and release)."""
    frames = []
    for i, t in enumerate(times):
        values = REST_COUNTS + rng.normal(0, 2.0, len(PATCH.names))
        if t_contact <= t <= t_release:
            values[0] += touch_value
        elif t_contact - 0.1 <= t < t_contact or t_release < t <= t_release + 0.1:
            values[0] += touch_value / 2
        if spike_at is not None and i == spike_at:
            values[0] += 5000
        cells = np.full((N_TX, N_RX), 100.0)
        CELLMAP.place(np.rint(values), cells)
        frames.append(Frame(i, float(t), cells.astype(np.uint16)))
    return frames


TIMES = TouchTimes(t_start=10.0, t_contact=12.0, t_settled=12.2, t_release=13.2)


def test_windows_exclude_transitions_and_subtract_the_rest():
    rng = np.random.default_rng(0)
    frames = _stream(np.arange(9.0, 14.0, 0.125), 200.0, 12.0, 13.2, rng)
    log, n_base = cut_point_log(
        frames, TIMES, CELLMAP, WindowConfig(), 7, 5.0, 6.0, 2.0, 1.5, RESTS
    )
    # baseline: [contact - guard - 1 s, contact - guard] = [10.85, 11.85]; touch: [12.2, 13.2]
    assert n_base == 8
    assert log.n_samples == 8  # 12.25 ... 13.125
    assert log.values[0] == pytest.approx(200.0, abs=3.0)  # no half-pressed frame got in
    assert np.all(np.abs(log.values[1:]) < 3.0)
    assert (log.touch, log.x_mm, log.y_mm, log.force_n, log.t_s) == (7, 5.0, 6.0, 2.0, 1.5)


def test_latency_shifts_the_windows():
    """Frames stamped 0.25 s after sampling: without the latency the window would catch the
    release transition and lose the first pressed frames."""
    rng = np.random.default_rng(1)
    sample_t = np.arange(9.0, 14.0, 0.125)
    frames = _stream(sample_t, 200.0, 12.0, 13.2, rng)
    late = [Frame(f.seq, f.t + 0.25, f.cells) for f in frames]
    good, _ = cut_point_log(
        late, TIMES, CELLMAP, WindowConfig(latency_s=0.25), 1, 0, 0, 2.0, 0, RESTS
    )
    bad, _ = cut_point_log(late, TIMES, CELLMAP, WindowConfig(), 1, 0, 0, 2.0, 0, RESTS)
    assert good.values[0] == pytest.approx(200.0, abs=3.0)
    assert abs(bad.values[0] - 200.0) > abs(good.values[0] - 200.0)


def test_robust_mean_ignores_a_spike():
    rng = np.random.default_rng(2)
    frames = _stream(np.arange(9.0, 14.0, 0.125), 200.0, 12.0, 13.2, rng, spike_at=30)
    assert 12.2 <= frames[30].t <= 13.2
    log, _ = cut_point_log(frames, TIMES, CELLMAP, WindowConfig(), 1, 0, 0, 2.0, 0, RESTS)
    assert log.values[0] == pytest.approx(200.0, abs=3.0)
    x = np.array([[1.0], [2.0], [3.0], [1000.0]])
    mean, _ = robust_mean(x)
    assert mean[0] == pytest.approx(2.0)


def test_too_few_frames_is_a_board_problem():
    rng = np.random.default_rng(3)
    frames = _stream(np.arange(9.0, 12.5, 0.125), 200.0, 12.0, 13.2, rng)  # stream stops
    with pytest.raises(WindowProblem) as e:
        cut_point_log(frames, TIMES, CELLMAP, WindowConfig(), 1, 0, 0, 2.0, 0, RESTS)
    assert e.value.kind == "board_gap" and "touch window" in str(e.value)


def test_check_link_finds_gaps_that_overlap_the_touch():
    check_link([], 10.0, 13.2)  # a healthy stream passes
    # a gap recorded after the reconnect, whose loss began inside the touch
    with pytest.raises(WindowProblem, match="link down"):
        check_link([Gap(12.6, 15.0, "device lost", last_frame_t=12.4)], 10.0, 13.2)
    check_link([Gap(5.0, 8.0, "earlier")], 10.0, 13.2)  # an old gap does not count


def test_a_silence_inside_a_window_is_a_board_gap():
    rng = np.random.default_rng(4)
    frames = _stream(np.arange(9.0, 14.0, 0.125), 200.0, 12.0, 13.2, rng)
    cfg = WindowConfig()
    holey = [f for f in frames if not 12.3 < f.t < 13.0]  # 0.75 s without a frame
    with pytest.raises(WindowProblem, match="no frame for 0.75 s in the touch window"):
        cut_point_log(holey, TIMES, CELLMAP, cfg, 1, 0, 0, 2.0, 0, RESTS)
    # the same silence during the descent, outside both windows, does not matter
    early = [f for f in frames if not 10.0 < f.t < 10.8]
    log, _ = cut_point_log(early, TIMES, CELLMAP, cfg, 1, 0, 0, 2.0, 0, RESTS)
    assert log.n_samples == 8


def test_scaled_config_divides_durations():
    w = WindowConfig().scaled(4.0)
    assert w.baseline_s == 0.25 and w.guard_s == WindowConfig().guard_s / 4
    assert w.min_touch_frames == WindowConfig().min_touch_frames


def test_a_log_keeps_the_offset_drift_against_the_rest_and_an_old_session_cancels_it():
    """Since 2026-11-29 a log is relative to the session's rest, so an offset that drifted
    since then stays in it (the localizer takes each sensor's floor from its own map). A
    session stored before cut against the touch's own baseline window, which cancels it."""
    rng = np.random.default_rng(5)
    frames = _stream(np.arange(9.0, 14.0, 0.125), 200.0, 12.0, 13.2, rng)
    drifted = []
    for f in frames:
        cells = f.cells.astype(float)
        values = CELLMAP.values(f) + 40.0  # every sensor's offset is 40 counts up
        CELLMAP.place(values, cells)
        drifted.append(Frame(f.seq, f.t, cells.astype(np.uint16)))
    log, n_base = cut_point_log(drifted, TIMES, CELLMAP, WindowConfig(), 1, 0, 0, 2.0, 0, RESTS)
    assert n_base == 8  # the baseline window is still cut (and checked for silences)
    assert log.values[0] == pytest.approx(240.0, abs=3.0)
    assert np.all(np.abs(log.values[1:] - 40.0) < 3.0)
    old = WindowConfig(reference=BASELINE)
    log, _ = cut_point_log(drifted, TIMES, CELLMAP, old, 1, 0, 0, 2.0, 0, None)
    assert log.values[0] == pytest.approx(200.0, abs=3.0)
    assert np.all(np.abs(log.values[1:]) < 3.0)
    with pytest.raises(ValueError, match="rest values"):
        cut_point_log(drifted, TIMES, CELLMAP, WindowConfig(), 1, 0, 0, 2.0, 0, None)


def test_a_stored_window_without_a_reference_is_an_old_sessions_baseline():
    stored = {k: v for k, v in vars(WindowConfig()).items() if k != "reference"}
    assert stored_window(stored).reference == BASELINE
    assert stored_window({**stored, "reference": "rest"}) == WindowConfig()
    with pytest.raises(ValueError, match="unknown point-log reference 'touch'"):
        stored_window({**stored, "reference": "touch"})
    with pytest.raises(TypeError):
        stored_window({**stored, "window_s": 1.0})


def test_a_patch_at_most_50_mm_long_is_cut_against_its_baselines():
    def patch(length, width):
        return patch_from_dict(
            {"name": "p", "size_mm": [length, width], "tx_x_mm": [5], "rx_y_mm": [5]}, "<p>"
        )

    assert reference_for(PATCH) == REST  # Patch B, 152 mm
    assert reference_for(patch(50, 10)) == BASELINE and reference_for(patch(20, 50)) == BASELINE
    assert reference_for(patch(60, 60)) == REST

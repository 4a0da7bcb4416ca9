"""The point-log mosaic: every sensor gets its own tile, label and estimate, at any size."""

import numpy as np
from matplotlib.collections import PathCollection

from varskin.patch import patch_from_dict
from varskin.plots import MOSAIC_WIDTH_IN, plot_point_log_maps, point_log_mosaic
from varskin.predictions import OK, Predictions, SensorEstimate
from varskin.simulate import simulate_session, uniform_grid


def board(n_tx: int, n_rx: int):
    """Wires 13.6 mm (TX) and 16.7 mm (RX) apart, as on a full Muca board."""
    return patch_from_dict(
        {
            "name": "grid",
            "size_mm": [14.0 + 13.6 * (n_tx - 1), 16.0 + 16.7 * (n_rx - 1)],
            "tx_x_mm": [7.0 + 13.6 * i for i in range(n_tx)],
            "rx_y_mm": [8.0 + 16.7 * j for j in range(n_rx)],
        },
        "<test>",
    )


def estimates(patch, truth: np.ndarray) -> Predictions:
    """Every third sensor not located, the others at their true position."""
    return Predictions(
        "test",
        [
            SensorEstimate(name, float(x), float(y), 0.2)
            if j % 3
            else SensorEstimate(name, None, None, status="dead")
            for j, (name, (x, y)) in enumerate(zip(patch.names, truth, strict=True))
        ],
    )


def tile_of(fig, label: str):
    """The (x, y) where a tile's label was written: its top left corner, just above it."""
    (ax,) = fig.axes
    (hit,) = [t for t in ax.texts if t.get_text().split(" ")[0] == label]
    return hit.get_position(), hit


def test_every_sensor_has_its_tile_label_and_estimate_on_a_full_board(tmp_path):
    patch = board(21, 12)
    s = simulate_session(patch, uniform_grid(patch, 12, 6), "robot", seed=3)
    logs = s.point_logs()
    pred = estimates(patch, s.truth)
    fig = point_log_mosaic(logs, pred, (patch.length_mm, patch.width_mm))

    (ax,) = fig.axes  # one Axes for all 252 sensors
    width, height = fig.get_size_inches()
    assert width <= MOSAIC_WIDTH_IN + 0.5 and height < 2 * width  # not a 50-row strip
    assert len(ax.texts) == len(patch.names)
    (scatter,) = [c for c in ax.collections if isinstance(c, PathCollection)]
    assert len(scatter.get_offsets()) == len(logs) * len(patch.names)
    (marks,) = ax.lines
    ok = [e for e in pred if e.status == OK]
    assert len(marks.get_xdata()) == len(ok)
    # Each estimate sits in its own sensor's tile, where the sensor is on the patch.
    corner = {e.sensor: tile_of(fig, e.sensor)[0] for e in pred}
    drawn = np.column_stack([marks.get_xdata(), marks.get_ydata()])
    for e, (x, y) in zip(ok, drawn, strict=True):
        cx, cy = corner[e.sensor]
        np.testing.assert_allclose([x - cx, y - (cy - 1.05 * patch.width_mm)], [e.x_mm, e.y_mm])
    # A sensor that is not located says why, in red.
    _, label = tile_of(fig, patch.names[0])
    assert label.get_text() == f"{patch.names[0]} (dead)" and label.get_color() == "tab:red"
    assert plot_point_log_maps(logs, tmp_path / "maps.png", pred).stat().st_size > 0


def test_each_tile_is_coloured_by_its_own_sensor_and_a_dead_column_is_blank():
    patch = board(3, 2)
    s = simulate_session(patch, uniform_grid(patch, 12, 8), "robot", seed=1)
    logs = s.point_logs()
    logs.values[:, 1] = np.nan  # a sensor that never reported
    fig = point_log_mosaic(logs)
    (scatter,) = [c for c in fig.axes[0].collections if isinstance(c, PathCollection)]
    shade = np.asarray(scatter.get_array()).reshape(len(logs), len(patch.names))
    for j in (0, 2, 3, 4, 5):
        v = logs.values[:, j]
        np.testing.assert_allclose(shade[:, j], (v - v.min()) / (v.max() - v.min()))
        # the brightest probe of a tile is near that sensor, not near the others
        top = logs.xy_mm[np.argmax(shade[:, j])]
        assert np.argmin(np.hypot(*(s.truth - top).T)) == j
    assert np.isnan(shade[:, 1]).all()

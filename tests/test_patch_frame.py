import numpy as np
import pytest

from robot.patch_frame import PatchFrame


def test_round_trip_and_units():
    f = PatchFrame.from_yaw([0.4, -0.1, 0.05], np.deg2rad(30))
    xy = np.array([[0.0, 0.0], [152.4, 25.4], [10.0, 3.0]])
    base = f.to_base(xy, 5.0)
    np.testing.assert_allclose(base[0], [0.4, -0.1, 0.055])
    # 152.4 mm along a 30-degree-turned x axis plus 25.4 mm along y
    np.testing.assert_allclose(
        np.linalg.norm(base[1, :2] - base[0, :2]) * 1000, np.hypot(152.4, 25.4)
    )
    np.testing.assert_allclose(f.to_patch(base), np.column_stack([xy, np.full(3, 5.0)]), atol=1e-9)


def test_rejects_non_rotation():
    with pytest.raises(ValueError):
        PatchFrame(np.diag([1.0, 1.0, -1.0]), np.zeros(3))

"""Patch registration: three-point touch-off and ArUco markers seen by a camera."""

from __future__ import annotations

import numpy as np
import pytest

from robot.arm import TouchSpec
from robot.fake import FakeArm
from robot.patch_frame import PatchFrame
from robot.registration import (
    MarkerLayout,
    camera_pose_looking_at,
    register_by_touch_off,
    register_from_aruco,
    register_three_points,
    render_markers,
    touch_off_targets,
)
from robot.safety import Envelope
from varskin.errors import RegistrationError


def rot(axis: str, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(a.T @ b) - 1) / 2, -1, 1))))


TRUE = PatchFrame(rot("z", 25) @ rot("x", 4) @ rot("y", -3), np.array([0.41, -0.12, 0.063]))


def test_three_points_recover_a_known_frame(patch_b):
    inset = 5.0
    pts = touch_off_targets(TRUE, patch_b, inset)
    frame = register_three_points(*pts, origin_inset_mm=(inset, inset))
    assert np.allclose(frame.rotation, TRUE.rotation, atol=1e-12)
    assert np.allclose(frame.origin_m, TRUE.origin_m, atol=1e-12)
    # Any third point on the +y side of the x edge gives the same frame.
    other = TRUE.to_base(np.array([90.0, 21.0]))
    frame2 = register_three_points(pts[0], pts[1], other, origin_inset_mm=(inset, inset))
    assert np.allclose(frame2.origin_m, TRUE.origin_m, atol=1e-12)


@pytest.mark.parametrize(
    ("points", "message"),
    [
        ([[0.4, 0, 0.05], [0.402, 0, 0.05], [0.4, 0.02, 0.05]], "apart"),
        ([[0.4, 0, 0.05], [0.5, 0, 0.05], [0.45, 0.001, 0.05]], "collinear"),
        ([[0.4, 0, 0.05], [0.5, 0, 0.05], [0.6, 0.0, 0.05]], "collinear"),
        ([[0.4, 0, 0.05], [0.5, 0, 0.05], [0.45, -0.02, 0.05]], "-y side"),
        ([[0.4, 0, 0.05], [0.5, 0, 0.05], [0.45, 0.0, 0.08]], "tilted 90.0 deg"),
        ([[0.4, 0, 0.05], [0.5, np.nan, 0.05], [0.45, 0.02, 0.05]], "finite"),
    ],
)
def test_degenerate_touch_off_points_are_refused(points, message):
    with pytest.raises(RegistrationError, match=message) as e:
        register_three_points(*points)
    assert isinstance(e.value, ValueError)


def test_touch_off_with_an_arm_recovers_the_true_frame(patch_b):
    # The operator placed the probe over the marks (x, y right) but guessed the height 2 mm
    # high; the touch-off finds the real surface.
    env = Envelope.around_patch(TRUE, patch_b, 10.0, 40.0, 8.0, 5.0, 0.1)
    arm = FakeArm(env, TRUE, patch_b, seed=1)
    approx = PatchFrame(TRUE.rotation, TRUE.origin_m + [0, 0, 0.002])
    spec = TouchSpec(
        target_force_n=1.0, max_force_n=3.0, dwell_s=0.0, settle_s=0.0, max_depth_m=0.006
    )
    frame = register_by_touch_off(arm, approx, patch_b, spec, inset_mm=5.0)
    assert arm.touch_count == 3
    # Contact is detected at the threshold's indentation (0.3 N at 3 N/mm = 0.1 mm).
    assert np.linalg.norm(frame.origin_m - TRUE.origin_m) < 0.0002
    assert angle_deg(frame.rotation, TRUE.rotation) < 0.1


def test_touch_off_without_surface_is_a_registration_error(patch_b):
    env = Envelope.around_patch(TRUE, patch_b, 10.0, 40.0, 8.0, 5.0, 0.1)
    arm = FakeArm(env, None, patch_b)
    with pytest.raises(RegistrationError, match="touch-off origin point failed: no contact"):
        register_by_touch_off(arm, TRUE, patch_b, TouchSpec(dwell_s=0.0, settle_s=0.0))


K = np.array([[1400.0, 0.0, 640.0], [0.0, 1400.0, 480.0], [0.0, 0.0, 1.0]])
# Camera pose in the robot base frame (hand-eye calibration): above the table, looking down.
CAM_TO_BASE = np.eye(4)
CAM_TO_BASE[:3, :3] = rot("z", 30) @ rot("x", 180)
CAM_TO_BASE[:3, 3] = [0.45, -0.10, 0.55]


def test_aruco_recovers_the_pose_within_half_a_mm_and_degree(patch_b):
    layout = MarkerLayout.around_patch(patch_b)
    rng = np.random.default_rng(7)
    centre = np.array([patch_b.length_mm / 2000, patch_b.width_mm / 2000, 0.0])
    for i in range(5):
        eye = centre + [rng.uniform(-0.08, 0.08), rng.uniform(-0.08, 0.08), rng.uniform(0.30, 0.45)]
        cam_from_patch = camera_pose_looking_at(eye, centre + [rng.uniform(-0.01, 0.01), 0.0, 0.0])
        truth = CAM_TO_BASE @ cam_from_patch
        image = render_markers(layout, K, cam_from_patch, (1280, 960), noise_sd=5.0, seed=i)
        frame = register_from_aruco(image, K, np.zeros(5), layout, camera_to_base=CAM_TO_BASE)
        assert np.linalg.norm(frame.origin_m - truth[:3, 3]) < 0.0005
        assert angle_deg(frame.rotation, truth[:3, :3]) < 0.5
        # Not just the origin: the far corner of the patch lands within 0.5 mm as well.
        far = np.array([patch_b.length_mm, patch_b.width_mm])
        expected = PatchFrame(truth[:3, :3], truth[:3, 3]).to_base(far)
        assert np.linalg.norm(frame.to_base(far) - expected) < 0.0005


def test_aruco_without_markers_in_view_is_a_registration_error(patch_b):
    layout = MarkerLayout.around_patch(patch_b)
    blank = np.full((960, 1280), 120, np.uint8)
    with pytest.raises(RegistrationError, match="found 0 of the layout's 8 ArUco markers"):
        register_from_aruco(blank, K, None, layout)


def test_marker_layout_validates(patch_b):
    with pytest.raises(RegistrationError, match="unknown ArUco dictionary"):
        MarkerLayout("DICT_NOPE", {0: np.zeros((4, 2))})
    with pytest.raises(RegistrationError, match="marker 3"):
        MarkerLayout("DICT_4X4_50", {3: np.zeros((3, 2))})

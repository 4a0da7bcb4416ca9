"""How accurately ArUco registration recovers the patch pose from a synthetic camera image.

Renders Patch B's default marker layout (8 markers of 15 mm) from random camera poses 0.30 to
0.45 m above the patch (tilts up to ~15 deg), 1280x960 px, f = 1400 px, at several image
noise levels, and reports the median and worst origin error (mm), far-corner error (mm) and
rotation error (deg) against the known pose. Run: ``python benchmarks/aruco_registration.py``.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from robot.patch_frame import PatchFrame
from robot.registration import (
    MarkerLayout,
    camera_pose_looking_at,
    register_from_aruco,
    render_markers,
)
from varskin.patch import builtin_patch

K = np.array([[1400.0, 0.0, 640.0], [0.0, 1400.0, 480.0], [0.0, 0.0, 1.0]])


def main(poses: int = 30) -> int:
    patch = builtin_patch("patch_b")
    layout = MarkerLayout.around_patch(patch)
    centre = np.array([patch.length_mm / 2000, patch.width_mm / 2000, 0.0])
    far = np.array([patch.length_mm, patch.width_mm])
    print(
        f"ArUco registration, Patch B, {len(layout.markers)} markers, {poses} poses per noise level"
    )
    print(
        "noise_sd  origin_mm(median/max)  far_corner_mm(median/max)  rot_deg(median/max)  s/image"
    )
    for noise in (0.0, 5.0, 10.0, 20.0):
        rng = np.random.default_rng(0)
        origin_err, corner_err, rot_err, took = [], [], [], []
        for i in range(poses):
            eye = centre + [
                rng.uniform(-0.08, 0.08),
                rng.uniform(-0.08, 0.08),
                rng.uniform(0.30, 0.45),
            ]
            truth = camera_pose_looking_at(eye, centre + [rng.uniform(-0.01, 0.01), 0.0, 0.0])
            image = render_markers(layout, K, truth, (1280, 960), noise_sd=noise, seed=i)
            t0 = time.perf_counter()
            frame = register_from_aruco(image, K, None, layout)
            took.append(time.perf_counter() - t0)
            true_frame = PatchFrame(truth[:3, :3], truth[:3, 3])
            origin_err.append(np.linalg.norm(frame.origin_m - true_frame.origin_m) * 1000)
            corner_err.append(np.linalg.norm(frame.to_base(far) - true_frame.to_base(far)) * 1000)
            c = (np.trace(frame.rotation.T @ true_frame.rotation) - 1) / 2
            rot_err.append(np.degrees(np.arccos(np.clip(c, -1, 1))))
        print(
            f"{noise:8.1f}  {np.median(origin_err):8.3f} / {np.max(origin_err):6.3f}"
            f"  {np.median(corner_err):12.3f} / {np.max(corner_err):6.3f}"
            f"  {np.median(rot_err):11.3f} / {np.max(rot_err):6.3f}  {np.median(took):8.3f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())

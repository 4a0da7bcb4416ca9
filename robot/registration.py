"""Registration: where the patch frame lies in the robot base frame.

Every probe target is a patch-frame point (mm) mapped to the base frame (m) through the
``PatchFrame`` this module produces, so its accuracy bounds the whole calibration. Two ways:

(a) Three-point touch-off. The probe is placed over three marks on the patch (the origin
    corner, a point along the x edge, a point across) and touches each; the heights come
    from contact, x and y from where the probe was placed. Cheap and needs no camera.
(b) ArUco markers fixed around the patch outline, seen by a calibrated camera whose pose in
    the base frame is known from hand-eye calibration. The pose of the marker plane comes
    from all marker corners at once (``cv2.solvePnP``), which averages the corner noise.

``render_markers`` draws a synthetic camera image of a marker layout at a known pose, so the
ArUco path can be tested without a camera.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from robot.arm import Arm, TouchSpec
from robot.patch_frame import PatchFrame
from varskin.errors import RegistrationError, RobotError
from varskin.patch import Patch

# The identity frame converts patch mm to metres without moving anything (PatchFrame is the
# only code that converts units).
_PATCH_TO_M = PatchFrame(np.eye(3), np.zeros(3))

# --- (a) three-point touch-off ----------------------------------------------------------


def register_three_points(
    p_origin_m: Sequence[float],
    p_xaxis_m: Sequence[float],
    p_plane_m: Sequence[float],
    *,
    origin_inset_mm: tuple[float, float] = (0.0, 0.0),
    min_separation_m: float = 0.005,
    max_tilt_deg: float = 30.0,
) -> PatchFrame:
    """The patch frame from three touched surface points in the base frame (m).

    ``p_origin_m`` is the origin corner (or, with ``origin_inset_mm=(a, b)``, the point at
    patch (a, b)); ``p_xaxis_m`` lies further along the patch x axis at the same patch y;
    ``p_plane_m`` lies on the +y side of that line. The skin normal must be within
    ``max_tilt_deg`` of base +z, since the probe only descends along -z.
    """
    pts = np.array([p_origin_m, p_xaxis_m, p_plane_m], float)
    if pts.shape != (3, 3) or not np.all(np.isfinite(pts)):
        raise RegistrationError(
            "three-point registration needs three finite (x, y, z) points in metres"
        )
    p0, p1, p2 = pts
    along = p1 - p0
    if np.linalg.norm(along) < min_separation_m:
        raise RegistrationError(
            f"origin and x-axis points are {np.linalg.norm(along) * 1000:.2f} mm apart "
            f"(need >= {min_separation_m * 1000:g} mm)"
        )
    x = along / np.linalg.norm(along)
    off = p2 - p0
    off_line = off - (off @ x) * x
    if np.linalg.norm(off_line) < min_separation_m:
        raise RegistrationError(
            f"the third point is {np.linalg.norm(off_line) * 1000:.2f} mm from the x-axis line "
            f"(need >= {min_separation_m * 1000:g} mm; the points are nearly collinear)"
        )
    y = off_line / np.linalg.norm(off_line)
    z = np.cross(x, y)
    tilt = float(np.degrees(np.arccos(np.clip(z[2], -1.0, 1.0))))
    if tilt > max_tilt_deg:
        hint = " (is the third point on the -y side of the x edge?)" if z[2] < 0 else ""
        raise RegistrationError(
            f"the registered skin normal is tilted {tilt:.1f} deg from base +z "
            f"(max {max_tilt_deg:g} deg){hint}"
        )
    touched = PatchFrame(np.column_stack([x, y, z]), p0)
    # p0 sits at patch (a, b): move the origin back to the corner.
    origin = 2.0 * p0 - touched.to_base(np.asarray(origin_inset_mm, float))
    return PatchFrame(touched.rotation, origin)


def touch_off_targets(approx_frame: PatchFrame, patch: Patch, inset_mm: float = 5.0) -> np.ndarray:
    """(3, 3) base-frame targets for a touch-off: origin, x edge and across, ``inset_mm``
    inside the outline so the probe lands on skin rather than on an edge."""
    if not 0.0 <= inset_mm < min(patch.length_mm, patch.width_mm) / 2:
        raise RegistrationError(
            f"touch-off inset {inset_mm:g} mm does not fit patch {patch.name!r}"
        )
    xy = np.array(
        [
            [inset_mm, inset_mm],
            [patch.length_mm - inset_mm, inset_mm],
            [inset_mm, patch.width_mm - inset_mm],
        ]
    )
    return approx_frame.to_base(xy)


_TOUCH_OFF_NAMES = ("origin", "x-axis", "plane")


def touch_off(arm: Arm, approx_points_m: Sequence[Sequence[float]], spec: TouchSpec) -> np.ndarray:
    """Touch each approximate point and return the contact points (K, 3) in the base frame.

    x and y are where the probe was sent (it descends along -z); z is where contact was
    detected. The approximate z must be within ``spec.clearance_m`` above and
    ``spec.max_depth_m`` below the real surface.
    """
    pts = np.asarray(approx_points_m, float)
    out = []
    for i, p in enumerate(pts):
        name = _TOUCH_OFF_NAMES[i] if i < len(_TOUCH_OFF_NAMES) else f"point {i}"
        try:
            result = arm.touch(p, spec)
        except RobotError as e:
            raise RegistrationError(f"touch-off {name} point failed: {e}") from e
        if not result.contact or result.contact_z_m is None:
            raise RegistrationError(f"touch-off {name} point found no surface")
        out.append([p[0], p[1], result.contact_z_m])
    return np.array(out)


def register_by_touch_off(
    arm: Arm, approx_frame: PatchFrame, patch: Patch, spec: TouchSpec, inset_mm: float = 5.0
) -> PatchFrame:
    """Touch off three points placed by ``approx_frame`` and register the patch from them."""
    targets = touch_off_targets(approx_frame, patch, inset_mm)
    contacts = touch_off(arm, targets, spec)
    return register_three_points(*contacts, origin_inset_mm=(inset_mm, inset_mm))


# --- (b) ArUco markers ------------------------------------------------------------------


@dataclass(frozen=True)
class MarkerLayout:
    """ArUco markers fixed in the patch plane: id -> (4, 2) corners in patch mm.

    Corners are in ArUco order (the marker image's top-left, top-right, bottom-right,
    bottom-left). ``around_patch`` lays them out so a camera above the patch, with image x
    along patch x, sees them upright.
    """

    dictionary: str
    markers: Mapping[int, np.ndarray]

    def __post_init__(self) -> None:
        if not hasattr(cv2.aruco, self.dictionary):
            raise RegistrationError(f"unknown ArUco dictionary {self.dictionary!r}")
        fixed = {}
        for marker_id, corners in self.markers.items():
            c = np.asarray(corners, float)
            if c.shape != (4, 2) or not np.all(np.isfinite(c)):
                raise RegistrationError(f"marker {marker_id}: corners must be 4 (x, y) mm pairs")
            fixed[int(marker_id)] = c
        if not fixed:
            raise RegistrationError("a marker layout needs at least one marker")
        object.__setattr__(self, "markers", fixed)

    @property
    def aruco_dictionary(self):
        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))

    @classmethod
    def around_patch(
        cls,
        patch: Patch,
        size_mm: float = 15.0,
        gap_mm: float = 4.0,
        per_long_side: int = 2,
        first_id: int = 0,
        dictionary: str = "DICT_4X4_50",
    ) -> MarkerLayout:
        """Markers at the four corners just outside the outline, plus ``per_long_side``
        evenly spaced along each long edge."""
        h = size_mm / 2.0
        lo_x, hi_x = -gap_mm - h, patch.length_mm + gap_mm + h
        lo_y, hi_y = -gap_mm - h, patch.width_mm + gap_mm + h
        xs_edge = np.linspace(lo_x, hi_x, per_long_side + 2)[1:-1]
        centres = [(lo_x, lo_y), (hi_x, lo_y), (hi_x, hi_y), (lo_x, hi_y)]
        centres += [(x, lo_y) for x in xs_edge] + [(x, hi_y) for x in xs_edge]
        markers = {}
        for i, (cx, cy) in enumerate(centres):
            markers[first_id + i] = np.array(
                [[cx - h, cy + h], [cx + h, cy + h], [cx + h, cy - h], [cx - h, cy - h]]
            )
        return cls(dictionary, markers)


def detect_markers(image: np.ndarray, layout: MarkerLayout) -> dict[int, np.ndarray]:
    """Marker id -> (4, 2) image corners (px, sub-pixel) for the layout's markers in view.

    A marker id seen twice is dropped: its correspondence would be ambiguous.
    """
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(layout.aruco_dictionary, params)
    corners, ids, _rejected = detector.detectMarkers(gray)
    found: dict[int, np.ndarray] = {}
    seen_twice: set[int] = set()
    for c, marker_id in zip(corners, [] if ids is None else ids.ravel(), strict=False):
        marker_id = int(marker_id)
        if marker_id not in layout.markers:
            continue
        if marker_id in found:
            seen_twice.add(marker_id)
        found[marker_id] = np.asarray(c, float).reshape(4, 2)
    for marker_id in seen_twice:
        del found[marker_id]
    return found


def aruco_pose(
    image: np.ndarray,
    camera_matrix: np.ndarray,
    dist_coeffs: np.ndarray | None,
    layout: MarkerLayout,
    min_markers: int = 2,
    max_rms_px: float = 2.0,
) -> tuple[np.ndarray, float, list[int]]:
    """The patch pose in the camera frame (4x4, m), the reprojection RMS (px) and the ids used."""
    found = detect_markers(image, layout)
    if len(found) < min_markers:
        raise RegistrationError(
            f"found {len(found)} of the layout's {len(layout.markers)} ArUco markers "
            f"(ids {sorted(found)}); need at least {min_markers}"
        )
    ids = sorted(found)
    object_m = np.vstack([_PATCH_TO_M.to_base(layout.markers[i]) for i in ids])
    image_px = np.vstack([found[i] for i in ids])
    k = np.asarray(camera_matrix, float)
    dist = np.zeros(5) if dist_coeffs is None else np.asarray(dist_coeffs, float)
    # IPPE is the planar-target solver; LM then refines on all corners together.
    ok, rvec, tvec = cv2.solvePnP(object_m, image_px, k, dist, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise RegistrationError("solvePnP found no pose for the detected ArUco markers")
    rvec, tvec = cv2.solvePnPRefineLM(object_m, image_px, k, dist, rvec, tvec)
    projected, _ = cv2.projectPoints(object_m, rvec, tvec, k, dist)
    rms = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - image_px) ** 2, axis=1))))
    if not np.isfinite(rms) or rms > max_rms_px:
        raise RegistrationError(
            f"ArUco pose fits the marker corners badly ({rms:.2f} px RMS > {max_rms_px:g} px)"
        )
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(rvec)[0]
    pose[:3, 3] = tvec.ravel()
    return pose, rms, ids


def register_from_aruco(
    image: np.ndarray,
    camera_matrix: np.ndarray,
    dist_coeffs: np.ndarray | None,
    layout: MarkerLayout,
    camera_to_base: np.ndarray | None = None,
    min_markers: int = 2,
    max_rms_px: float = 2.0,
) -> PatchFrame:
    """The patch frame in the base frame from one image of the marker layout.

    ``camera_to_base`` (4x4, m) is the camera pose in the robot base frame from hand-eye
    calibration; without it the result is the patch frame in the camera frame.
    """
    pose, _rms, _ids = aruco_pose(
        image, camera_matrix, dist_coeffs, layout, min_markers, max_rms_px
    )
    t = np.eye(4) if camera_to_base is None else np.asarray(camera_to_base, float)
    if t.shape != (4, 4) or not np.all(np.isfinite(t)):
        raise RegistrationError("camera_to_base must be a finite 4x4 transform")
    base_pose = t @ pose
    try:
        return PatchFrame(base_pose[:3, :3], base_pose[:3, 3])
    except ValueError as e:
        raise RegistrationError(f"camera_to_base is not a rigid transform: {e}") from None


# --- synthetic images -------------------------------------------------------------------


def camera_pose_looking_at(
    eye_m: Sequence[float], target_m: Sequence[float], up=(0.0, 1.0, 0.0)
) -> np.ndarray:
    """The patch pose in the camera frame (4x4) for a camera at ``eye_m`` (patch frame, m)
    looking at ``target_m``, with patch ``up`` pointing up in the image."""
    eye, target = np.asarray(eye_m, float), np.asarray(target_m, float)
    z = target - eye
    z /= np.linalg.norm(z)
    u = np.asarray(up, float)
    y = -(u - (u @ z) * z)
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    r = np.vstack([x, y, z])  # rows: camera axes in patch coordinates
    pose = np.eye(4)
    pose[:3, :3] = r
    pose[:3, 3] = -r @ eye
    return pose


def render_markers(
    layout: MarkerLayout,
    camera_matrix: np.ndarray,
    pose: np.ndarray,
    image_size: tuple[int, int],
    noise_sd: float = 0.0,
    seed: int = 0,
    dist_coeffs: np.ndarray | None = None,
    supersample: int = 3,
    background: int = 110,
    blur_sd_px: float = 0.6,
) -> np.ndarray:
    """A grey camera image (uint8, ``image_size`` = (width, height)) of the layout seen
    from ``pose`` (patch in camera frame, 4x4 m), with Gaussian noise of ``noise_sd`` grey
    levels. Markers are warped at ``supersample`` x resolution and box-filtered down, so
    edges carry the partial coverage a real sensor records; a slight blur stands in for
    the lens. Distortion is applied to the corner positions only (exact without it).
    """
    width, height = image_size
    s = int(supersample)
    canvas = np.full((height * s, width * s), background, np.uint8)
    rvec = cv2.Rodrigues(np.asarray(pose, float)[:3, :3])[0]
    tvec = np.asarray(pose, float)[:3, 3]
    k = np.asarray(camera_matrix, float)
    dist = np.zeros(5) if dist_coeffs is None else np.asarray(dist_coeffs, float)
    dictionary = layout.aruco_dictionary
    module_px = 40
    bits = dictionary.markerSize + 2
    side = bits * module_px
    quiet = module_px  # white margin: ArUco needs contrast around the black border
    for marker_id, corners_mm in layout.markers.items():
        marker = cv2.aruco.generateImageMarker(dictionary, marker_id, side, borderBits=1)
        padded = cv2.copyMakeBorder(
            marker, quiet, quiet, quiet, quiet, cv2.BORDER_CONSTANT, value=255
        )
        src = (
            np.array(
                [
                    [quiet, quiet],
                    [quiet + side, quiet],
                    [quiet + side, quiet + side],
                    [quiet, quiet + side],
                ],
                np.float32,
            )
            - 0.5
        )
        img_px, _ = cv2.projectPoints(_PATCH_TO_M.to_base(corners_mm), rvec, tvec, k, dist)
        dst = (img_px.reshape(4, 2) * s + (s - 1) / 2.0).astype(np.float32)
        h = cv2.getPerspectiveTransform(src, dst)
        canvas = cv2.warpPerspective(
            padded,
            h,
            (width * s, height * s),
            dst=canvas,
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_TRANSPARENT,
        )
    image = cv2.resize(canvas, (width, height), interpolation=cv2.INTER_AREA).astype(float)
    if blur_sd_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), blur_sd_px)
    if noise_sd > 0:
        image += np.random.default_rng(seed).normal(0.0, noise_sd, image.shape)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)

"""Where the patch lies in the robot base frame: the one place mm and m meet.

The patch frame has its origin at a patch corner, x along the length, y across and z out of
the skin surface; the patch and the localizer speak millimetres in it. The robot speaks
metres in its base frame. ``PatchFrame`` holds the rigid transform between them and is the
only code that converts units. Registration (``robot.registration``) produces one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PatchFrame:
    rotation: np.ndarray  # (3, 3) patch axes expressed in the base frame (columns)
    origin_m: np.ndarray  # (3,) patch origin (corner, on the surface) in the base frame, m

    def __post_init__(self) -> None:
        r = np.asarray(self.rotation, float)
        if (
            r.shape != (3, 3)
            or not np.allclose(r @ r.T, np.eye(3), atol=1e-6)
            or np.linalg.det(r) < 0
        ):
            raise ValueError("PatchFrame.rotation must be a proper 3x3 rotation matrix")
        object.__setattr__(self, "rotation", r)
        object.__setattr__(self, "origin_m", np.asarray(self.origin_m, float).reshape(3))

    @classmethod
    def from_yaw(cls, origin_m, yaw_rad: float = 0.0) -> PatchFrame:
        """A patch lying flat (z up) at ``origin_m``, its x axis turned by ``yaw_rad``."""
        c, s = np.cos(yaw_rad), np.sin(yaw_rad)
        return cls(
            np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), np.asarray(origin_m, float)
        )

    @property
    def normal(self) -> np.ndarray:
        """Unit vector out of the skin, in the base frame."""
        return self.rotation[:, 2]

    def to_base(self, xy_mm, height_mm: float | np.ndarray = 0.0) -> np.ndarray:
        """Patch-frame points (mm; (2,) or (K, 2)) at ``height_mm`` above the skin -> base m."""
        p = np.atleast_2d(np.asarray(xy_mm, float))
        h = np.broadcast_to(np.asarray(height_mm, float), (len(p),))
        local_m = np.column_stack([p[:, 0], p[:, 1], h]) / 1000.0
        out = local_m @ self.rotation.T + self.origin_m
        return out[0] if np.ndim(xy_mm) == 1 else out

    def to_patch(self, xyz_m) -> np.ndarray:
        """Base-frame points (m; (3,) or (K, 3)) -> patch frame (x_mm, y_mm, height_mm)."""
        p = np.atleast_2d(np.asarray(xyz_m, float))
        out = (p - self.origin_m) @ self.rotation * 1000.0
        return out[0] if np.ndim(xyz_m) == 1 else out

    def to_dict(self) -> dict:
        return {"rotation": self.rotation.tolist(), "origin_m": self.origin_m.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> PatchFrame:
        return cls(np.array(d["rotation"], float), np.array(d["origin_m"], float))

"""The safety envelope: where the probe may go, how hard it may press and how fast it may move.

A touch plan is checked against the envelope as a whole before the first motion, so a plan
that would leave the workspace is refused while the arm is still parked; the arm drivers
check every commanded point again and watch the measured TCP during motion. The box is
axis-aligned in the robot base frame (what a controller can monitor cheaply) and is built
around the registered patch: its outline plus a margin, from a little below the skin (the
bounded descent's floor) up to the approach height.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from robot.arm import TouchSpec
from robot.patch_frame import PatchFrame
from varskin.errors import ConfigError, SafetyViolation
from varskin.patch import Patch

_AXES = "xyz"


@dataclass(frozen=True)
class Envelope:
    box_min_m: np.ndarray  # (3,) base frame
    box_max_m: np.ndarray  # (3,) base frame
    max_force_n: float  # contact force never to be passed, N
    max_speed_m_s: float  # free-space TCP speed limit
    max_accel_m_s2: float  # TCP acceleration limit
    max_contact_speed_m_s: float  # speed limit while seeking or holding contact

    def __post_init__(self) -> None:
        lo = np.asarray(self.box_min_m, float).reshape(3)
        hi = np.asarray(self.box_max_m, float).reshape(3)
        if not np.all(np.isfinite(lo)) or not np.all(np.isfinite(hi)) or np.any(hi <= lo):
            raise ValueError("Envelope box needs finite corners with box_max_m > box_min_m")
        for name in ("max_force_n", "max_speed_m_s", "max_accel_m_s2", "max_contact_speed_m_s"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"Envelope.{name} must be > 0, got {v!r}")
        object.__setattr__(self, "box_min_m", lo)
        object.__setattr__(self, "box_max_m", hi)

    # --- construction ---------------------------------------------------------------------

    @classmethod
    def around_patch(
        cls,
        frame: PatchFrame,
        patch: Patch,
        margin_mm: float,
        approach_height_mm: float,
        depth_mm: float,
        max_force_n: float,
        max_speed_m_s: float,
        max_accel_m_s2: float = 0.5,
        max_contact_speed_m_s: float = 0.01,
    ) -> Envelope:
        """The axis-aligned box holding the patch outline (plus margin) from ``depth_mm``
        below the skin to ``approach_height_mm`` above it.

        For a tilted patch the box holds all eight corners of that slab, so it is a little
        larger than the slab itself; the approach height is measured along base +z (the
        probe's approach direction), the depth likewise along -z.
        """
        xs = (-margin_mm, patch.length_mm + margin_mm)
        ys = (-margin_mm, patch.width_mm + margin_mm)
        outline = np.array([[x, y] for x in xs for y in ys])
        on_skin = frame.to_base(outline)  # (4, 3) corners on the surface plane, m
        # Heights via PatchFrame (the one mm -> m conversion), applied along base z: the
        # probe approaches along z, so the full height counts, not its tilted projection.
        origin = frame.to_base(np.zeros(2))
        up = np.array(
            [0.0, 0.0, np.linalg.norm(frame.to_base(np.zeros(2), approach_height_mm) - origin)]
        )
        down = np.array([0.0, 0.0, np.linalg.norm(frame.to_base(np.zeros(2), depth_mm) - origin)])
        corners = np.vstack([on_skin + up, on_skin - down])
        return cls(
            box_min_m=corners.min(axis=0),
            box_max_m=corners.max(axis=0),
            max_force_n=float(max_force_n),
            max_speed_m_s=float(max_speed_m_s),
            max_accel_m_s2=float(max_accel_m_s2),
            max_contact_speed_m_s=float(max_contact_speed_m_s),
        )

    @classmethod
    def from_config(
        cls,
        config: object,
        frame: PatchFrame,
        patch: Patch,
        source: str = "<envelope>",
        touch: TouchSpec | None = None,
    ) -> Envelope:
        """Build from a launch file's ``envelope`` mapping; mistakes name ``source`` and the key.

        With ``touch`` given, the touch spec is checked against the limits too, so a launch
        whose target force is above the envelope's maximum fails at load time.
        """
        if not isinstance(config, Mapping):
            raise ConfigError(f"{source}: 'envelope' must be a mapping")
        spec = {
            "margin_mm": (0.0, False),
            "approach_height_mm": (0.0, True),
            "depth_mm": (0.0, True),
            "max_force_n": (0.0, True),
            "max_speed_m_s": (0.0, True),
            "max_accel_m_s2": (0.0, True),
            "max_contact_speed_m_s": (0.0, True),
        }
        unknown = sorted(set(config) - set(spec))
        if unknown:
            raise ConfigError(f"{source}: unknown key 'envelope.{unknown[0]}'")
        values: dict[str, float] = {}
        for key, (low, strict) in spec.items():
            if key not in config:
                raise ConfigError(f"{source}: missing key 'envelope.{key}'")
            v = config[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ConfigError(f"{source}: 'envelope.{key}' is {v!r}, not a number")
            if v < low or (strict and v == low):
                rel = ">" if strict else ">="
                raise ConfigError(f"{source}: 'envelope.{key}' is {v!r}, must be {rel} {low:g}")
            values[key] = float(v)
        if values["max_contact_speed_m_s"] > values["max_speed_m_s"]:
            raise ConfigError(
                f"{source}: 'envelope.max_contact_speed_m_s' ({values['max_contact_speed_m_s']:g}) "
                f"is above 'envelope.max_speed_m_s' ({values['max_speed_m_s']:g})"
            )
        env = cls.around_patch(frame, patch, **values)
        if touch is not None:
            try:
                env.check_touch_spec(touch)
            except SafetyViolation as e:
                raise ConfigError(f"{source}: {e}") from None
            if touch.max_depth_m * 1000.0 > values["depth_mm"] + 1e-9:
                raise ConfigError(
                    f"{source}: 'touch.max_depth_m' ({touch.max_depth_m * 1000:g} mm) is deeper "
                    f"than 'envelope.depth_mm' ({values['depth_mm']:g} mm)"
                )
            if touch.clearance_m * 1000.0 > values["approach_height_mm"] + 1e-9:
                raise ConfigError(
                    f"{source}: 'touch.clearance_m' ({touch.clearance_m * 1000:g} mm) is above "
                    f"'envelope.approach_height_mm' ({values['approach_height_mm']:g} mm)"
                )
        return env

    # --- checks ---------------------------------------------------------------------------

    def outside_by_m(self, xyz_m) -> np.ndarray:
        """Per point, per axis, how far outside the box (m; 0 inside). (3,) or (K, 3)."""
        p = np.asarray(xyz_m, float)
        return np.maximum(self.box_min_m - p, 0.0) + np.maximum(p - self.box_max_m, 0.0)

    def contains(self, xyz_m) -> bool:
        p = np.asarray(xyz_m, float)
        return bool(np.all(np.isfinite(p)) and not np.any(self.outside_by_m(p) > 0.0))

    def check_point(self, xyz_m, what: str = "point") -> None:
        """Raise ``SafetyViolation`` if ``xyz_m`` (base frame, m) lies outside the box."""
        p = np.asarray(xyz_m, float).reshape(3)
        if not np.all(np.isfinite(p)):
            raise SafetyViolation(f"{what} {_fmt(p)} is not a finite position")
        out = self.outside_by_m(p)
        if np.any(out > 0.0):
            axis = int(np.argmax(out))
            side = "below" if p[axis] < self.box_min_m[axis] else "above"
            limit = self.box_min_m[axis] if side == "below" else self.box_max_m[axis]
            raise SafetyViolation(
                f"{what} {_fmt(p)} is {out[axis] * 1000:.2f} mm outside the safety box "
                f"({_AXES[axis]} {side} {limit:.4f} m)"
            )

    def check_plan(self, points_m: Sequence | np.ndarray, what: str = "plan point") -> None:
        """Check every point of a plan; the error names the FIRST offending index."""
        p = np.asarray(points_m, float)
        if p.ndim != 2 or p.shape[1] != 3:
            raise SafetyViolation(
                f"a plan must be a (K, 3) array of base-frame points, got {p.shape}"
            )
        bad = ~np.all(np.isfinite(p), axis=1) | np.any(self.outside_by_m(p) > 0.0, axis=1)
        if np.any(bad):
            i = int(np.argmax(bad))
            self.check_point(p[i], f"{what} {i}")

    def check_touch_spec(self, spec: TouchSpec) -> None:
        """Forces and speeds of a touch against the envelope's limits."""
        problems = []
        if not 0.0 < spec.target_force_n < spec.max_force_n:
            problems.append(
                f"target force {spec.target_force_n:g} N must be > 0 and below the touch's "
                f"max force {spec.max_force_n:g} N"
            )
        if spec.max_force_n > self.max_force_n:
            problems.append(
                f"touch max force {spec.max_force_n:g} N is above the envelope's "
                f"{self.max_force_n:g} N"
            )
        for name in ("search_speed_m_s", "force_speed_limit_m_s"):
            v = getattr(spec, name)
            if not 0.0 < v <= self.max_contact_speed_m_s:
                problems.append(
                    f"touch {name} {v:g} m/s is not in (0, {self.max_contact_speed_m_s:g}] "
                    "(envelope max_contact_speed_m_s)"
                )
        for name in ("clearance_m", "max_depth_m"):
            if getattr(spec, name) <= 0.0:
                problems.append(f"touch {name} must be > 0")
        if spec.dwell_s < 0.0 or spec.settle_s < 0.0:
            problems.append("touch dwell_s and settle_s must be >= 0")
        if problems:
            raise SafetyViolation(problems[0])

    def touch_path(self, point_m, spec: TouchSpec) -> np.ndarray:
        """The two extreme points a touch at ``point_m`` visits: approach and floor (2, 3)."""
        p = np.asarray(point_m, float).reshape(3)
        return np.array([p + [0.0, 0.0, spec.clearance_m], p - [0.0, 0.0, spec.max_depth_m]])

    def check_touch(self, point_m, spec: TouchSpec, what: str = "touch") -> None:
        """A whole touch: its spec, its approach point and its descent floor."""
        self.check_touch_spec(spec)
        approach, floor = self.touch_path(point_m, spec)
        self.check_point(approach, f"{what} approach")
        self.check_point(floor, f"{what} floor")

    def check_touch_plan(self, points_m, spec: TouchSpec) -> None:
        """A whole plan of touches, before anything moves: first offending touch named."""
        self.check_touch_spec(spec)
        p = np.asarray(points_m, float)
        if p.ndim != 2 or p.shape[1] != 3:
            raise SafetyViolation(
                f"a plan must be a (K, 3) array of base-frame points, got {p.shape}"
            )
        approach, floor = p + [0.0, 0.0, spec.clearance_m], p - [0.0, 0.0, spec.max_depth_m]
        bad = np.zeros(len(p), bool)
        for q in (p, approach, floor):
            bad |= ~np.all(np.isfinite(q), axis=1) | np.any(self.outside_by_m(q) > 0.0, axis=1)
        if np.any(bad):
            i = int(np.argmax(bad))
            self.check_touch(p[i], spec, f"plan touch {i}")
            self.check_point(p[i], f"plan touch {i}")

    def describe(self) -> str:
        lo, hi = self.box_min_m, self.box_max_m
        return (
            f"box x [{lo[0]:.4f}, {hi[0]:.4f}] y [{lo[1]:.4f}, {hi[1]:.4f}] "
            f"z [{lo[2]:.4f}, {hi[2]:.4f}] m; max force {self.max_force_n:g} N; "
            f"speed {self.max_speed_m_s:g} m/s (contact {self.max_contact_speed_m_s:g} m/s); "
            f"accel {self.max_accel_m_s2:g} m/s^2"
        )


def _fmt(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:.4f}" for v in p) + ") m"

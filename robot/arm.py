"""The arm as the rest of the system sees it: a small protocol in SI units.

Positions are metres in the robot base frame, forces newtons, times seconds on the host's
``time.monotonic()`` clock (the clock the Muca recorder stamps frames with, so touch
windows and frames line up). The probe always descends along the base frame's -z axis.
Implementations: ``robot.ur.URArm`` (ur-rtde, real or simulated controller) and
``robot.fake.FakeArm`` (in-process, for unit tests that need no sockets).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class TouchSpec:
    """How to press: the force to hold, the limit never to pass, and how long to hold it."""

    target_force_n: float = 2.0
    max_force_n: float = 5.0  # abort (stop, retract, raise ForceLimitExceeded) above this
    dwell_s: float = 0.5  # time the target force is held: the recorder's window
    clearance_m: float = 0.01  # approach height above the expected surface
    search_speed_m_s: float = 0.005  # descent speed while looking for contact
    force_speed_limit_m_s: float = 0.01  # speed limit of the compliant axis in force mode
    max_depth_m: float = 0.004  # the bounded descent's floor below the expected surface
    settle_s: float = 0.15  # after contact, time for the force to settle before the dwell


@dataclass(frozen=True)
class DwellTick:
    """Handed to the dwell callback while the target force is held."""

    t: float  # host monotonic time, s
    elapsed_s: float  # since the dwell started
    force_n: float  # measured contact force (positive = pressing)


DwellCallback = Callable[[DwellTick], "bool | None"]  # return True to end the dwell early


@dataclass(frozen=True)
class TouchResult:
    contact: bool
    contact_z_m: float | None  # TCP z where contact was detected
    t_contact: float | None  # host monotonic time of contact
    t_settled: float | None  # start of the dwell window (force settled)
    t_release: float | None  # end of the dwell window (retract starts)
    peak_force_n: float
    mean_force_n: float


@dataclass(frozen=True)
class ArmStatus:
    connected: bool
    program_running: bool
    protective_stop: bool
    safety_mode: str  # "normal", "protective_stop", "emergency_stop", ... or "unknown"
    tcp_pose: tuple[float, ...]  # [x, y, z, rx, ry, rz], m and rad (rotation vector)
    tcp_force_n: float  # contact force along the probe axis


@runtime_checkable
class Arm(Protocol):
    """One verb each. Every method raises a ``RobotError`` subclass on failure."""

    def move_above(self, point: Sequence[float], clearance_m: float) -> None:
        """Move (linear, at the envelope's speed) to ``clearance_m`` above a surface point."""

    def touch(
        self, point: Sequence[float], spec: TouchSpec, on_dwell: DwellCallback | None = None
    ) -> TouchResult:
        """From above ``point``: bounded descent to contact, hold the force, dwell, retract.

        Retracts to the clearance height in all cases (``finally``). Without contact down to
        ``max_depth_m`` below the point it raises ``NoContact``.
        """

    def retract(self) -> None:
        """Move straight up to the last clearance height (safe to call any time)."""

    def stop(self) -> None:
        """Stop any motion now."""

    def status(self) -> ArmStatus:
        """The controller's state, read without moving."""

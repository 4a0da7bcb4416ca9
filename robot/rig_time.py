"""How long a touch plan takes on a real rig, from the motion and dwell model alone.

A simulated calibration runs its controller faster than real time (``SimRig.time_scale``),
so its wall time says little about a real rig, and it is the real rig's time an operator
plans for. This module is pure arithmetic: it replays what ``robot.ur.URArm.touch`` does per
touch (every motion, at the speed and acceleration the driver commands, and every fixed
wait of the driver) without a controller.

Per touch, in order (see ``URArm.touch``):

* travel: ``move_above``, a linear move with a trapezoidal speed profile at the envelope's
  ``max_speed_m_s`` / ``max_accel_m_s2`` from the previous approach point (the previous
  retract ends there) to this one;
* descent: ``zeroFtSensor``, ``startContactDetection``, an asynchronous ``moveL`` down at
  ``spec.search_speed_m_s`` (accelerating at ``URArm.contact_accel_m_s2``) from the clearance
  height to contact, the contact stop (``stopl(3)``), polling until the driver sees it,
  ``stopContactDetection`` and ``stopL``;
* hold: force-mode damping and gain, the driver's 20 ms without motion before
  ``forceMode``, ``settle_s``, ``dwell_s``, ``forceModeStop``;
* retract: straight up to the clearance height, trapezoidal at the envelope's limits.

Every blocking ur-rtde command also costs a register handshake with the controller
(``command_s`` each). Its default is what the simulated controller's handshake costs the
driver at 125 Hz RTDE on this project's CI machine; a real controller's will differ a little
(measure it with ``benchmarks/ur_touch.py`` on the rig). Plan-level overheads (connecting,
the recorder, anything between touches) are not included.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robot.arm import TouchSpec
from robot.safety import Envelope
from robot.ur import CONTACT_ACCEL_M_S2, FORCE_MODE_QUIET_S, STOP_DECEL_M_S2

# Blocking ur-rtde commands per touch phase (URArm.touch / move_above / retract):
DESCENT_COMMANDS = 5.5  # zeroFtSensor, startContactDetection, moveL async, stopContactDetection,
#                        stopL, + 1.5 readContactDetection polls (the one that sees contact and
#                        on average half of the one in flight when it happens)
HOLD_COMMANDS = 4  # forceModeSetDamping, forceModeSetGainScaling, forceMode, forceModeStop
MOVE_COMMANDS = 1  # the moveL of the travel, and of the retract
# One command's handshake at 125 Hz RTDE: 14-16 ms for the blocking commands on the simulated
# controller in real time (10.6 ms forceModeStop, 1.5 ms the real-time forceMode), measured
# through URArm on the CI machine (see module docstring).
COMMAND_S = 0.015


@dataclass(frozen=True)
class RigTimeEstimate:
    """A touch plan's time on a real rig, by phase (seconds, summed over the plan)."""

    total_s: float
    per_touch_s: np.ndarray  # (K,) each touch, its travel from the previous point included
    travel_s: float  # free-space moves between approach points
    descent_s: float  # searching for contact
    hold_s: float  # settle + dwell (and the force-mode commands around them)
    retract_s: float

    def describe(self) -> str:
        k = len(self.per_touch_s)
        mean = self.total_s / k if k else 0.0
        return (
            f"{self.total_s:.1f} s for {k} touches ({mean:.2f} s each): travel "
            f"{self.travel_s:.1f} s, descent {self.descent_s:.1f} s, hold {self.hold_s:.1f} s, "
            f"retract {self.retract_s:.1f} s"
        )


def trapezoid_time(distance_m: float, speed_m_s: float, accel_m_s2: float) -> float:
    """Duration of a rest-to-rest linear move with a trapezoidal speed profile.

    Long moves cruise at ``speed_m_s`` (``d / v + v / a``); short ones never reach it and
    are a triangle (``2 sqrt(d / a)``).
    """
    d = abs(float(distance_m))
    if d == 0.0:
        return 0.0
    if speed_m_s <= 0 or accel_m_s2 <= 0:
        raise ValueError("speed and acceleration must be > 0")
    if d >= speed_m_s**2 / accel_m_s2:
        return d / speed_m_s + speed_m_s / accel_m_s2
    return 2.0 * math.sqrt(d / accel_m_s2)


@dataclass(frozen=True)
class TouchTime:
    """One touch's phases (s), without its travel."""

    descent_s: float
    hold_s: float
    retract_s: float

    @property
    def total_s(self) -> float:
        return self.descent_s + self.hold_s + self.retract_s


def estimate_touch_time(
    spec: TouchSpec,
    envelope: Envelope,
    *,
    contact_accel_m_s2: float = CONTACT_ACCEL_M_S2,
    command_s: float = COMMAND_S,
    contact_depth_m: float = 0.0,
    press_depth_m: float = 0.0,
) -> TouchTime:
    """The descent, hold and retract of one touch that starts at its approach point.

    ``contact_depth_m``: how far below the expected surface contact is detected (a soft skin
    or a registration error); ``press_depth_m``: how far below it the probe holds the target
    force (target force / skin stiffness). Both lengthen the moves; 0 assumes a rigid skin
    exactly where the registration put it.
    """
    v = spec.search_speed_m_s
    a = min(contact_accel_m_s2, envelope.max_accel_m_s2)  # as URArm.touch commands it
    # The descent is interrupted by contact, never braked by the move itself: accelerate,
    # cruise to the surface (the ramp costs v / 2a over cruising all the way), then stop.
    down = spec.clearance_m + contact_depth_m
    if down >= v * v / (2 * a):
        descent = down / v + v / (2 * a)
    else:  # contact before cruise speed: the speed reached is sqrt(2 a d)
        v = math.sqrt(2 * a * down)
        descent = v / a
    descent += v / STOP_DECEL_M_S2 + DESCENT_COMMANDS * command_s
    hold = FORCE_MODE_QUIET_S + spec.settle_s + spec.dwell_s + HOLD_COMMANDS * command_s
    up = spec.clearance_m + press_depth_m
    retract = (
        trapezoid_time(up, envelope.max_speed_m_s, envelope.max_accel_m_s2)
        + MOVE_COMMANDS * command_s
    )
    return TouchTime(descent, hold, retract)


def estimate_plan_time(
    points_m: np.ndarray,
    spec: TouchSpec,
    envelope: Envelope,
    start_m: np.ndarray | None = None,
    *,
    contact_accel_m_s2: float = CONTACT_ACCEL_M_S2,
    command_s: float = COMMAND_S,
    contact_depth_m: float = 0.0,
    press_depth_m: float = 0.0,
) -> RigTimeEstimate:
    """Real-rig time of touching ``points_m`` (K, 3 surface points, base frame) in order.

    ``start_m``: where the TCP is before the first touch (None: already above the first
    point, so the first travel is free). The keyword arguments are as for
    ``estimate_touch_time``.
    """
    p = np.asarray(points_m, float).reshape(-1, 3)
    approach = p + np.array([0.0, 0.0, spec.clearance_m])  # URArm approaches along base +z
    if len(p) == 0:
        return RigTimeEstimate(0.0, np.zeros(0), 0.0, 0.0, 0.0, 0.0)
    first = approach[0] if start_m is None else np.asarray(start_m, float).reshape(3)
    starts = np.vstack([first[None, :], approach[:-1]])
    distances = np.linalg.norm(approach - starts, axis=1)
    travel = np.array(
        [
            trapezoid_time(d, envelope.max_speed_m_s, envelope.max_accel_m_s2)
            + MOVE_COMMANDS * command_s
            for d in distances
        ]
    )
    touch = estimate_touch_time(
        spec,
        envelope,
        contact_accel_m_s2=contact_accel_m_s2,
        command_s=command_s,
        contact_depth_m=contact_depth_m,
        press_depth_m=press_depth_m,
    )
    per_touch = travel + touch.total_s
    k = len(p)
    return RigTimeEstimate(
        total_s=float(per_touch.sum()),
        per_touch_s=per_touch,
        travel_s=float(travel.sum()),
        descent_s=touch.descent_s * k,
        hold_s=touch.hold_s * k,
        retract_s=touch.retract_s * k,
    )

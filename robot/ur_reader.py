"""``URReader``: a UR controller's state, read without taking control of the robot.

``URArm.connect`` uploads ur-rtde's control script, which takes the robot over (it stops
whatever program the pendant was running). ``varskin robot check`` without ``--move`` must
only read, so it uses this instead: the RTDE receive interface alone, every call supervised
with a timeout. It has the ``Arm`` methods so it can stand in for an arm, but every motion
verb refuses: moving nothing is structural, not a matter of care.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence

import numpy as np

from robot.arm import ArmStatus, DwellCallback, TouchResult, TouchSpec
from robot.supervise import call_with_timeout
from varskin.errors import ConnectionLost, RobotError

STATUS_PROGRAM_RUNNING = 1 << 1  # robot_status_bits, UR RTDE guide
# UR safety_mode values (RTDE guide); anything else is reported as "unknown"
SAFETY_MODES = {
    1: "normal",
    2: "reduced",
    3: "protective_stop",
    4: "recovery",
    5: "safeguard_stop",
    6: "system_emergency_stop",
    7: "robot_emergency_stop",
    8: "violation",
    9: "fault",
    10: "validate_joint_id",
    11: "undefined",
    12: "automatic_mode_safeguard_stop",
    13: "system_three_position_enabling_stop",
}


class URReader:
    """Read-only view of a UR controller (RTDE receive only). Use as a context manager."""

    def __init__(self, host: str, call_timeout_s: float = 5.0, frequency_hz: float = 125.0) -> None:
        self.host = host
        self.call_timeout_s = call_timeout_s
        self.frequency_hz = frequency_hz
        self._recv = None

    def connect(self) -> URReader:
        import rtde_receive  # lazily: only needed when connecting

        self._recv = self._call(
            "RTDEReceiveInterface", rtde_receive.RTDEReceiveInterface, self.host, self.frequency_hz
        )
        return self

    def close(self) -> None:
        recv, self._recv = self._recv, None
        if recv is not None:
            # A dead link has nothing left to close.
            with contextlib.suppress(RobotError):
                self._call("disconnect", recv.disconnect)

    def __enter__(self) -> URReader:
        return self.connect()

    def __exit__(self, *exc) -> None:
        self.close()

    def _call(self, name: str, fn: Callable, *args):
        """Run one ur-rtde call, bounded by ``call_timeout_s``."""
        try:
            return call_with_timeout(fn, args, self.call_timeout_s, f"UR {self.host}: {name}")
        except RuntimeError as e:  # ur-rtde raises RuntimeError for socket failures
            if isinstance(e, RobotError):
                raise
            raise ConnectionLost(f"UR {self.host}: {name} failed: {e}") from e

    def status(self) -> ArmStatus:
        recv = self._recv
        if recv is None:
            return ArmStatus(False, False, False, "unknown", (), 0.0)
        connected = bool(self._call("isConnected", recv.isConnected))
        bits = int(self._call("getRobotStatus", recv.getRobotStatus))
        mode = int(self._call("getSafetyMode", recv.getSafetyMode))
        pose = tuple(float(v) for v in self._call("getActualTCPPose", recv.getActualTCPPose))
        wrench = self._call("getActualTCPForce", recv.getActualTCPForce)
        return ArmStatus(
            connected=connected,
            program_running=bool(bits & STATUS_PROGRAM_RUNNING),
            protective_stop=bool(self._call("isProtectiveStopped", recv.isProtectiveStopped)),
            safety_mode=SAFETY_MODES.get(mode, "unknown"),
            tcp_pose=pose,
            tcp_force_n=float(np.asarray(wrench, float)[2]),  # +z: environment pushing the probe up
        )

    def payload(self) -> tuple[float, tuple[float, ...]]:
        """The payload mass (kg) and centre of gravity (m) set on the controller."""
        recv = self._require()
        mass = float(self._call("getPayload", recv.getPayload))
        cog = tuple(float(v) for v in self._call("getPayloadCog", recv.getPayloadCog))
        return mass, cog

    def _require(self):
        if self._recv is None:
            raise ConnectionLost(f"UR {self.host}: not connected")
        return self._recv

    # --- motion: refused ------------------------------------------------------------------

    def _refuse(self, verb: str) -> RobotError:
        return RobotError(
            f"UR {self.host}: read-only connection refuses {verb} (motion needs --move)"
        )

    def move_above(self, point: Sequence[float], clearance_m: float) -> None:
        raise self._refuse("move_above")

    def touch(
        self, point: Sequence[float], spec: TouchSpec, on_dwell: DwellCallback | None = None
    ) -> TouchResult:
        raise self._refuse("touch")

    def retract(self) -> None:
        raise self._refuse("retract")

    def stop(self) -> None:
        """Nothing to stop: this connection never commands motion."""

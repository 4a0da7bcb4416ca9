"""The robot side: an SI-unit arm protocol, the UR driver, its simulated controller,
the safety envelope and the registration of the patch frame in the robot base frame."""

from robot.arm import Arm, ArmStatus, DwellTick, TouchResult, TouchSpec

__all__ = ["Arm", "ArmStatus", "DwellTick", "TouchResult", "TouchSpec"]

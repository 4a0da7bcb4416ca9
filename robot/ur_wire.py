"""The UR controller's side of the wire as ur-rtde 1.6.5 speaks it: RTDE packet types,
the types of the RTDE variables, the command ids and handshake values of ur-rtde's control
script, and the status words the controller publishes.

Why a module of its own: these are facts of the protocol, fixed by UR's RTDE guide and by
ur-rtde 1.6.5's ``rtde_control.script``, not choices of the simulated controller
(sim_controller.py) that serves them; tests that speak the protocol use them too.
"""

from __future__ import annotations

import re

CONTROLLER_VERSION = (5, 11, 1, 108318)
POLYSCOPE_VERSION = "URSoftware 5.11.1.108318 (Nov 11 2021)"

# RTDE packet types (ASCII codes)
V_REQUEST_PROTOCOL = ord("V")
V_GET_URCONTROL_VERSION = ord("v")
V_TEXT_MESSAGE = ord("M")
V_DATA_PACKAGE = ord("U")
V_SETUP_OUTPUTS = ord("O")
V_SETUP_INPUTS = ord("I")
V_START = ord("S")
V_PAUSE = ord("P")

# Command ids of ur-rtde 1.6.5's control script (RTDE::RobotCommand::Type)
CMD_NONE = 0
CMD_MOVEJ = 1
CMD_MOVEL = 3
CMD_FORCE_MODE = 6
CMD_FORCE_MODE_STOP = 7
CMD_ZERO_FT_SENSOR = 8
CMD_SET_PAYLOAD = 17
CMD_SET_DAMPING = 20
CMD_SET_GAIN_SCALING = 21
CMD_SET_TCP = 29
CMD_PROTECTIVE_STOP = 31
CMD_STOPL = 33
CMD_STOPJ = 34
CMD_START_CONTACT_DETECTION = 62
CMD_STOP_CONTACT_DETECTION = 63
CMD_READ_CONTACT_DETECTION = 64
CMD_STOP_SCRIPT = 255
# commands the script processes and acknowledges with "ready" instead of "done"
REALTIME_CMDS = {24, 11, 9, 10, 6, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71}

UR_READY = 1
UR_DONE = 2

# robot_status_bits, safety_status_bits, safety_mode and runtime_state values (UR RTDE guide)
STATUS_POWER_ON = 1 << 0
STATUS_PROGRAM_RUNNING = 1 << 1
SAFETY_BIT_NORMAL = 1 << 0
SAFETY_BIT_PROTECTIVE_STOP = 1 << 2
SAFETY_MODE_NORMAL = 1
SAFETY_MODE_PROTECTIVE_STOP = 3
RUNTIME_STOPPED = 1
RUNTIME_PLAYING = 2
ROBOT_MODE_RUNNING = 7

_VECTOR6D = ("VECTOR6D", ">6d")
_VECTOR3D = ("VECTOR3D", ">3d")
_DOUBLE = ("DOUBLE", ">d")
_INT32 = ("INT32", ">i")
_UINT32 = ("UINT32", ">I")
_UINT64 = ("UINT64", ">Q")
_UINT8 = ("UINT8", ">B")
_BOOL = ("BOOL", ">?")
_VECTOR6INT32 = ("VECTOR6INT32", ">6i")
_VECTOR6UINT32 = ("VECTOR6UINT32", ">6I")

_FIXED_TYPES: dict[str, tuple[str, str]] = {
    "timestamp": _DOUBLE,
    "actual_execution_time": _DOUBLE,
    "robot_mode": _INT32,
    "joint_mode": _VECTOR6INT32,
    "safety_mode": _INT32,
    "safety_status": _INT32,
    "runtime_state": _UINT32,
    "robot_status_bits": _UINT32,
    "safety_status_bits": _UINT32,
    "actual_digital_input_bits": _UINT64,
    "actual_digital_output_bits": _UINT64,
    "speed_scaling": _DOUBLE,
    "target_speed_fraction": _DOUBLE,
    "actual_momentum": _DOUBLE,
    "actual_main_voltage": _DOUBLE,
    "actual_robot_voltage": _DOUBLE,
    "actual_robot_current": _DOUBLE,
    "actual_tool_accelerometer": _VECTOR3D,
    "elbow_position": _VECTOR3D,
    "elbow_velocity": _VECTOR3D,
    "payload_cog": _VECTOR3D,
    "payload": _DOUBLE,
    "analog_io_types": _UINT32,
    "standard_analog_input0": _DOUBLE,
    "standard_analog_input1": _DOUBLE,
    "standard_analog_output0": _DOUBLE,
    "standard_analog_output1": _DOUBLE,
    "io_current": _DOUBLE,
    "tool_mode": _UINT32,
    "tool_analog_input_types": _UINT32,
    "tool_analog_input0": _DOUBLE,
    "tool_analog_input1": _DOUBLE,
    "tool_output_voltage": _INT32,
    "tool_output_current": _DOUBLE,
    "tool_temperature": _DOUBLE,
    "tcp_force_scalar": _DOUBLE,
    "output_bit_registers0_to_31": _UINT32,
    "output_bit_registers32_to_63": _UINT32,
    "input_bit_registers0_to_31": _UINT32,
    "input_bit_registers32_to_63": _UINT32,
    "script_control_line": _UINT32,
    "joint_position_deviation_ratio": _DOUBLE,
    "collision_detection_ratio": _DOUBLE,
    "time_scale_source": _INT32,
    "standard_digital_output_mask": _UINT8,
    "standard_digital_output": _UINT8,
    "configurable_digital_output_mask": _UINT8,
    "configurable_digital_output": _UINT8,
    "tool_digital_output_mask": _UINT8,
    "tool_digital_output": _UINT8,
    "standard_analog_output_mask": _UINT8,
    "standard_analog_output_type": _UINT8,
    "standard_analog_output_0": _DOUBLE,
    "standard_analog_output_1": _DOUBLE,
    "speed_slider_mask": _UINT32,
    "speed_slider_fraction": _DOUBLE,
    "tool_output_mode": _UINT8,
    "tool_digital_output0_mode": _UINT8,
    "tool_digital_output1_mode": _UINT8,
    "euromap67_input_bits": _UINT32,
    "euromap67_output_bits": _UINT32,
    "euromap67_24V_voltage": _DOUBLE,
    "euromap67_24V_current": _DOUBLE,
}
_VECTOR6D_NAMES = {
    "target_q", "target_qd", "target_qdd", "target_current", "target_moment", "actual_q", "actual_qd",
    "actual_current", "joint_control_output", "actual_TCP_pose", "actual_TCP_speed", "actual_TCP_force",
    "target_TCP_pose", "target_TCP_speed", "joint_temperatures", "actual_joint_voltage", "payload_inertia",
    "ft_raw_wrench", "tcp_offset", "actual_current_as_torque", "actual_current_window", "target_current_window",
}  # fmt: skip


def rtde_type(name: str) -> tuple[str, str] | None:
    """The RTDE type (name, struct format) of a variable, None if this controller lacks it."""
    if name in _FIXED_TYPES:
        return _FIXED_TYPES[name]
    if name in _VECTOR6D_NAMES:
        return _VECTOR6D
    m = re.fullmatch(r"(input|output)_(int|double|bit)_register_(\d+)", name)
    if m and int(m.group(3)) < (128 if m.group(2) == "bit" else 48):
        return {"int": _INT32, "double": _DOUBLE, "bit": _BOOL}[m.group(2)]
    return None

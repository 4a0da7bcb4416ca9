"""The simulated UR controller, driven by the REAL ur-rtde 1.6.5 client (no URArm in between).

These pin what the controller speaks (RTDE, script upload, the script's register protocol)
and the physics behind it (speeds, the skin's contact model, the force sensor, protective
stops), reading the controller's own logs where the client could be fooled.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
import rtde_control  # ur-rtde is a hard dependency: missing it must fail, not skip
import rtde_receive  # ur-rtde is a hard dependency: missing it must fail, not skip

from robot.sim_controller import SimRig, SimulatedController
from robot.ur_wire import rtde_type


@pytest.fixture(scope="module")
def rig(patch_b):
    return SimRig(patch_length_mm=patch_b.length_mm, patch_width_mm=patch_b.width_mm)


@pytest.fixture(scope="module")
def clients(rig):
    with SimulatedController(rig, seed=5) as sim:
        recv = rtde_receive.RTDEReceiveInterface(sim.host, 125.0)
        ctrl = rtde_control.RTDEControlInterface(sim.host, 125.0)
        try:
            yield sim, ctrl, recv
        finally:
            ctrl.stopScript()
            ctrl.disconnect()
            recv.disconnect()


@pytest.fixture
def fresh(clients):
    sim, ctrl, recv = clients
    if not ctrl.isProgramRunning():
        assert ctrl.reuploadScript()
        assert wait_until(ctrl.isProgramRunning)
    sim.clear_logs()
    return sim, ctrl, recv


def wait_until(predicate, timeout_s: float = 3.0) -> bool:
    """Poll ``predicate`` until true or ``timeout_s`` passed (state arrives at 125 Hz)."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


def above(rig: SimRig, x_mm: float, y_mm: float, h_mm: float, pose) -> list[float]:
    p = rig.patch_frame.to_base([x_mm, y_mm], h_mm)
    return [float(p[0]), float(p[1]), float(p[2]), *pose[3:]]


def test_variable_types_cover_what_the_client_asks_for():
    assert rtde_type("actual_TCP_pose")[0] == "VECTOR6D"
    assert rtde_type("output_int_register_0")[0] == "INT32"
    assert rtde_type("input_double_register_17")[0] == "DOUBLE"
    assert rtde_type("robot_status_bits")[0] == "UINT32"
    assert rtde_type("no_such_variable") is None


def test_client_connects_uploads_the_script_and_reads_state(fresh, rig):
    sim, ctrl, recv = fresh
    assert sim.host.startswith("127.") and sim.host not in ("127.0.0.1",)
    assert ctrl.isConnected() and recv.isConnected()
    assert ctrl.isProgramRunning() and sim.script_running and sim.scripts_received >= 1
    assert recv.getSafetyMode() == 1 and not recv.isProtectiveStopped()
    assert np.allclose(recv.getActualTCPPose(), sim.tcp_pose, atol=1e-6)
    # bit 1: program running. rtde_receive's stream is not rtde_control's, so it may show
    # the script a packet or two after isProgramRunning does (a CI run read status 1 here).
    assert wait_until(lambda: recv.getRobotStatus() & 0b10)


def test_movel_runs_at_the_commanded_speed_and_arrives(fresh, rig):
    sim, ctrl, recv = fresh
    start = recv.getActualTCPPose()
    target = list(start)
    target[0] += 0.03
    assert ctrl.moveL(target, 0.05, 1.0) is True
    log = sim.tcp_log()
    speed = np.linalg.norm(np.diff(log[:, 1:], axis=0), axis=1) / np.diff(log[:, 0])
    assert speed.max() == pytest.approx(0.05, rel=0.1)
    assert np.allclose(recv.getActualTCPPose()[:3], target[:3], atol=1e-5)
    assert np.allclose(sim.tcp_pose[:3], target[:3], atol=1e-5)


def test_zero_ft_sensor_removes_the_offset(fresh, rig):
    sim, ctrl, recv = fresh
    assert ctrl.moveL(above(rig, 50, 12, 20.0, recv.getActualTCPPose()), 0.25, 1.0)
    assert recv.getActualTCPForce()[2] == pytest.approx(rig.ft_offset_n, abs=5 * rig.ft_noise_n)
    assert ctrl.zeroFtSensor() is True
    assert wait_until(lambda: abs(recv.getActualTCPForce()[2]) < 5 * rig.ft_noise_n)


def test_skin_contact_force_is_stiffness_times_depth_inside_the_outline_only(fresh, rig):
    sim, ctrl, recv = fresh
    pose = recv.getActualTCPPose()
    assert ctrl.moveL(above(rig, 50, 12, 2.0, pose), 0.1, 1.0)
    assert ctrl.zeroFtSensor()
    assert ctrl.moveL(above(rig, 50, 12, -1.0, pose), 0.005, 0.5)  # 1 mm into the silicone
    f_true = sim.force_log()[-1, 1]
    assert f_true == pytest.approx(rig.stiffness_n_per_mm * 1.0, rel=0.02)
    assert wait_until(lambda: abs(recv.getActualTCPForce()[2] - f_true) < 5 * rig.ft_noise_n)
    x, y, f = sim.probe_state.get()
    assert x == pytest.approx(50.0, abs=0.01) and y == pytest.approx(12.0, abs=0.01)
    assert f == pytest.approx(f_true)
    assert ctrl.moveL(above(rig, 50, 12, 2.0, pose), 0.1, 1.0)
    # beyond the outline there is no skin at the surface height
    assert ctrl.moveL(above(rig, -5, 12, 2.0, pose), 0.1, 1.0)
    assert ctrl.moveL(above(rig, -5, 12, -1.0, pose), 0.01, 0.5)
    assert sim.force_log()[-1, 1] == 0.0 and sim.probe_state.get() == (None, None, 0.0)
    assert ctrl.moveL(above(rig, 50, 12, 20.0, pose), 0.1, 1.0)


def test_contact_detection_stops_an_async_move_at_the_skin(fresh, rig):
    sim, ctrl, recv = fresh
    pose = recv.getActualTCPPose()
    assert ctrl.moveL(above(rig, 60, 12, 3.0, pose), 0.25, 1.0)
    assert ctrl.startContactDetection([0, 0, -0.01, 0, 0, 0])
    assert ctrl.readContactDetection() is False
    assert ctrl.moveL(above(rig, 60, 12, -4.0, pose), 0.01, 0.5, True)
    deadline = time.monotonic() + 3.0
    while not ctrl.readContactDetection():
        assert time.monotonic() < deadline, "no contact detected"
    assert ctrl.stopContactDetection() is True
    depth_mm = -rig.patch_frame.to_patch(sim.tcp_pose[:3])[2]
    assert 0.0 < depth_mm < 0.5  # stopped within half a millimetre of the surface
    assert ctrl.moveL(above(rig, 60, 12, 20.0, pose), 0.1, 1.0)


def test_stopped_script_makes_commands_return_false(fresh, rig):
    sim, ctrl, recv = fresh
    sim.stop_script()
    assert wait_until(lambda: not ctrl.isProgramRunning())
    assert ctrl.moveL(above(rig, 50, 12, 25.0, recv.getActualTCPPose()), 0.1, 1.0) is False
    assert ctrl.reuploadScript()
    assert wait_until(ctrl.isProgramRunning), "script did not restart"
    assert ctrl.moveL(above(rig, 50, 12, 25.0, recv.getActualTCPPose()), 0.1, 1.0) is True


def test_pushing_into_the_rigid_base_protective_stops_the_controller(rig):
    # its own controller: the arm stays jammed in the base afterwards, as a real one would
    with SimulatedController(rig, seed=6) as sim:
        recv = rtde_receive.RTDEReceiveInterface(sim.host, 125.0)
        ctrl = rtde_control.RTDEControlInterface(sim.host, 125.0)
        try:
            pose = recv.getActualTCPPose()
            assert ctrl.moveL(above(rig, 50, 12, 1.0, pose), 0.25, 1.0)
            # 10 mm down: through the 3 mm of silicone into the rigid base
            assert ctrl.moveL(above(rig, 50, 12, -10.0, pose), 0.01, 0.5) is False
            assert wait_until(recv.isProtectiveStopped) and recv.getSafetyMode() == 3
            assert not ctrl.isProgramRunning()
            # it stopped at the threshold (one control cycle of overshoot at most)
            # rigid stiffness (N/mm) x the millimetres moved in one 4 ms cycle at 10 mm/s
            per_cycle_n = 100 * rig.stiffness_n_per_mm * 0.04
            assert sim.force_log()[:, 1].max() <= rig.protective_stop_force_n + per_cycle_n + 1e-6
            assert ctrl.moveL(above(rig, 50, 12, 10.0, pose), 0.1, 1.0) is False
        finally:
            ctrl.disconnect()
            recv.disconnect()


def test_parallel_controllers_get_their_own_loopback_addresses(rig):
    with SimulatedController(rig) as a, SimulatedController(rig) as b:
        assert a.host != b.host
        ra = rtde_receive.RTDEReceiveInterface(a.host, 125.0)
        rb = rtde_receive.RTDEReceiveInterface(b.host, 125.0)
        try:
            a.inject_protective_stop()
            assert wait_until(ra.isProtectiveStopped) and not rb.isProtectiveStopped()
        finally:
            ra.disconnect()
            rb.disconnect()

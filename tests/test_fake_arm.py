"""The in-process fake arm: force-limited touches, typed faults, ProbeState for the board."""

from __future__ import annotations

import numpy as np
import pytest

from robot.arm import Arm, TouchSpec
from robot.fake import FakeArm, FakeFaults
from robot.patch_frame import PatchFrame
from robot.safety import Envelope
from varskin.errors import ConnectionLost, ForceLimitExceeded, NoContact, ProtectiveStop
from varskin.scene import ProbeState

FRAME = PatchFrame.from_yaw([0.40, -0.08, 0.05], np.radians(-15))
SPEC = TouchSpec(target_force_n=2.0, max_force_n=4.0, dwell_s=0.3, settle_s=0.15)


def make(patch, **kw):
    env = Envelope.around_patch(FRAME, patch, 10.0, 40.0, 6.0, 5.0, 0.1)
    return FakeArm(env, FRAME, patch, **kw)


def test_fake_arm_is_an_arm(patch_b):
    assert isinstance(make(patch_b), Arm)


@pytest.mark.parametrize("stiffness", [1.0, 3.0, 10.0])
def test_touch_holds_target_force_and_never_overshoots_10_percent(patch_b, stiffness):
    arm = make(patch_b, stiffness_n_per_mm=stiffness, force_noise_sd_n=0.05, seed=3)
    windows = []
    for xy in ([10.0, 5.0], [76.0, 12.7], [148.0, 20.0]):
        n0 = len(arm.trace)
        r = arm.touch(FRAME.to_base(np.array(xy)), SPEC)
        assert r.contact and r.t_contact <= r.t_settled <= r.t_release
        assert r.mean_force_n == pytest.approx(SPEC.target_force_n, rel=0.10)
        trace = np.array(arm.trace)[n0:]
        true_force = trace[:, 4]
        assert true_force.max() <= 1.10 * SPEC.target_force_n
        t0, t1 = arm.last_dwell_sim_s
        windows.append(true_force[(trace[:, 0] > t0) & (trace[:, 0] <= t1)])
        # Back at the clearance height with nothing pressing.
        assert arm.status().tcp_pose[2] == pytest.approx(FRAME.origin_m[2] + SPEC.clearance_m)
        assert true_force[-1] == 0.0
    # The skin was really pressed to the target (the true force, not only the sensor's).
    for hold in windows:
        assert len(hold) == pytest.approx(SPEC.dwell_s / arm.dt, abs=1)
        assert np.mean(hold) == pytest.approx(SPEC.target_force_n, rel=0.10)
        assert hold.min() >= 0.9 * SPEC.target_force_n


def test_contact_height_is_found_on_the_skin(patch_b):
    arm = make(patch_b)
    point = FRAME.to_base(np.array([40.0, 10.0]))
    r = arm.touch(point + [0, 0, 0.002], SPEC)  # expected surface 2 mm too high
    # Detected within the threshold's indentation (0.3 N / 3 N/mm = 0.1 mm) of the surface.
    assert point[2] - 0.00015 <= r.contact_z_m <= point[2]


def test_no_surface_stops_at_the_floor_and_reports_no_contact(patch_b):
    arm = make(patch_b, faults=FakeFaults(no_surface=True))
    point = FRAME.to_base(np.array([50.0, 10.0]))
    with pytest.raises(NoContact, match=r"no contact down to 4.0 mm below"):
        arm.touch(point, SPEC)
    z = np.array(arm.trace)[:, 3]
    floor = point[2] - SPEC.max_depth_m
    assert z.min() == pytest.approx(floor, abs=1e-6)  # went to the floor, not past it
    assert arm.retract_attempts == 1
    assert arm.status().tcp_pose[2] == pytest.approx(point[2] + SPEC.clearance_m)


def test_off_the_patch_outline_there_is_no_skin(patch_b):
    arm = make(patch_b)
    with pytest.raises(NoContact):
        arm.touch(FRAME.to_base(np.array([-5.0, 10.0])), SPEC)


@pytest.mark.parametrize("phase", ["descent", "dwell"])
def test_protective_stop_mid_touch_raises_attempts_retract_and_reports(patch_b, phase):
    arm = make(patch_b, faults=FakeFaults(protective_stop_at_touch=1, protective_stop_phase=phase))
    point = FRAME.to_base(np.array([70.0, 12.0]))
    arm.touch(point, SPEC)
    assert arm.retract_attempts == 1
    with pytest.raises(ProtectiveStop, match=f"protective stop during {phase} of touch 1"):
        arm.touch(point, SPEC)
    assert arm.retract_attempts == 2  # attempted in finally ...
    assert any(e.startswith("retract after touch 1 failed") for e in arm.events)  # ... and refused
    s = arm.status()
    assert s.protective_stop and s.safety_mode == "protective_stop" and not s.program_running
    with pytest.raises(ProtectiveStop):
        arm.move_above(point, SPEC.clearance_m)
    arm.unlock_protective_stop()
    arm.retract()
    assert arm.status().tcp_pose[2] == pytest.approx(point[2] + SPEC.clearance_m)


def test_force_spike_above_limit_stops_and_retracts(patch_b):
    arm = make(patch_b, faults=FakeFaults(force_spike_at_touch=0, force_spike_n=3.0))
    with pytest.raises(ForceLimitExceeded, match="above the limit 4 N"):
        arm.touch(FRAME.to_base(np.array([30.0, 10.0])), SPEC)
    assert arm.events[-1] == "retract"
    assert np.array(arm.trace)[-1, 4] == 0.0


def test_connection_lost_raises_and_status_says_so(patch_b):
    arm = make(patch_b, faults=FakeFaults(connection_lost_at_touch=0))
    with pytest.raises(ConnectionLost):
        arm.touch(FRAME.to_base(np.array([30.0, 10.0])), SPEC)
    assert not arm.status().connected


def test_probe_state_follows_the_probe_during_the_dwell(patch_b):
    state = ProbeState()
    arm = make(patch_b, probe_state=state)
    seen = []

    def on_dwell(tick):
        seen.append((tick, state.get()))

    xy = np.array([100.8, 7.2])
    r = arm.touch(FRAME.to_base(xy), SPEC, on_dwell=on_dwell)
    assert len(seen) >= SPEC.dwell_s / arm.dwell_tick_s - 1
    for tick, (x, y, f) in seen:
        assert x == pytest.approx(xy[0], abs=1e-6) and y == pytest.approx(xy[1], abs=1e-6)
        assert f == pytest.approx(SPEC.target_force_n, rel=0.10)
        assert r.t_settled <= tick.t <= r.t_release
    assert state.get() == (None, None, 0.0)  # off the skin after the retract


def test_dwell_callback_can_end_the_dwell_early(patch_b):
    arm = make(patch_b)
    calls = []
    arm.touch(
        FRAME.to_base(np.array([50.0, 10.0])),
        SPEC,
        on_dwell=lambda t: calls.append(t) or len(calls) >= 3,
    )
    assert len(calls) == 3


def test_realtime_mode_paces_the_dwell_on_the_host_clock(patch_b):
    arm = make(patch_b, realtime=True)
    spec = TouchSpec(
        target_force_n=2.0, max_force_n=4.0, dwell_s=0.1, settle_s=0.05, clearance_m=0.002
    )
    r = arm.touch(FRAME.to_base(np.array([50.0, 10.0])), spec)
    # The recorder's window is as long on the host clock as the simulated dwell.
    assert r.t_release - r.t_settled >= spec.dwell_s - 2 * arm.dt

"""The safety envelope: plans outside it are refused before motion, breaches stop and retract."""

from __future__ import annotations

import numpy as np
import pytest

from robot.arm import TouchSpec
from robot.fake import FakeArm, FakeFaults
from robot.patch_frame import PatchFrame
from robot.safety import Envelope
from varskin.errors import ConfigError, SafetyViolation

FRAME = PatchFrame.from_yaw([0.40, -0.08, 0.05], np.radians(20))
SPEC = TouchSpec(target_force_n=2.0, max_force_n=4.0, dwell_s=0.1, settle_s=0.05)
ENV_CFG = {
    "margin_mm": 10.0,
    "approach_height_mm": 40.0,
    "depth_mm": 6.0,
    "max_force_n": 5.0,
    "max_speed_m_s": 0.1,
    "max_accel_m_s2": 0.5,
    "max_contact_speed_m_s": 0.01,
}


@pytest.fixture
def env(patch_b):
    return Envelope.from_config(ENV_CFG, FRAME, patch_b, "rig.yaml", touch=SPEC)


def test_box_holds_the_outline_slab_of_a_tilted_patch(patch_b):
    tilt = np.radians(10)
    r = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
    frame = PatchFrame(r @ FRAME.rotation, FRAME.origin_m)
    env = Envelope.around_patch(frame, patch_b, 10.0, 40.0, 6.0, 5.0, 0.1)
    xs, ys = (-10.0, patch_b.length_mm + 10.0), (-10.0, patch_b.width_mm + 10.0)
    corners = frame.to_base(np.array([[x, y] for x in xs for y in ys]))
    for c in corners:
        assert env.contains(c + [0, 0, 0.040]) and env.contains(c - [0, 0, 0.006])
    # ... and not much more: just beyond each corner's reach is outside on some axis.
    assert not env.contains(corners.max(axis=0) + [0.001, 0.001, 0.041])
    assert not env.contains(corners.min(axis=0) - [0.001, 0.001, 0.007])


def test_plan_outside_box_is_refused_before_anything_moves(env, patch_b):
    arm = FakeArm(env, FRAME, patch_b)
    start = arm.status().tcp_pose
    xy = np.array([[10.0, 10.0], [50.0, 12.0], [80.0, 5.0], [200.0, 10.0], [300.0, 10.0]])
    plan = FRAME.to_base(xy)
    with pytest.raises(SafetyViolation, match=r"plan touch 3 .*outside the safety box"):
        env.check_touch_plan(plan, SPEC)
    with pytest.raises(SafetyViolation, match="plan point 3 "):
        env.check_plan(plan)
    # The arm itself refuses the point too, and nothing moved in either case.
    with pytest.raises(SafetyViolation, match="touch approach"):
        arm.touch(plan[3], SPEC)
    with pytest.raises(SafetyViolation):
        arm.move_above(plan[4], SPEC.clearance_m)
    assert arm.motion_log == [] and arm.path_length_m == 0.0 and arm.touch_count == 0
    assert arm.status().tcp_pose == start


def test_floor_below_the_box_is_refused(env, patch_b):
    arm = FakeArm(env, FRAME, patch_b)
    deep = TouchSpec(target_force_n=2.0, max_force_n=4.0, max_depth_m=0.010)
    with pytest.raises(SafetyViolation, match=r"touch floor .* \(z below"):
        arm.touch(FRAME.to_base(np.array([50.0, 10.0])), deep)
    assert arm.motion_log == []


def test_violation_message_names_what_and_how_far(env):
    p = env.box_max_m + [0.0, 0.0125, 0.0] - [0.001, 0.0, 0.001]
    with pytest.raises(
        SafetyViolation, match=r"^probe .* is 12\.50 mm outside the safety box \(y above"
    ):
        env.check_point(p, "probe")
    with pytest.raises(SafetyViolation, match="not a finite"):
        env.check_point([np.nan, 0.0, 0.0])


def test_breach_during_motion_stops_retracts_and_raises(env, patch_b):
    # The TCP creeps sideways during the touch (a bump, bad tracking) until it leaves the box.
    faults = FakeFaults(drift_at_touch=1, drift_m_s=(0.0, 0.03, 0.0))
    arm = FakeArm(env, FRAME, patch_b, faults=faults)
    point = FRAME.to_base(np.array([60.0, 20.0]))
    arm.touch(point, SPEC)  # touch 0 is clean
    with pytest.raises(
        SafetyViolation, match=r"measured TCP during descent .* outside the safety box .*; stopped"
    ):
        arm.touch(point, SPEC)
    halt = next(i for i, e in enumerate(arm.events) if e.startswith("halt: left the box"))
    assert "retract" in arm.events[halt:]
    # It breached by a hair (one control step), not by the drift of a whole touch.
    trace = np.array(arm.trace)[:, 1:4]
    assert np.max(env.outside_by_m(trace)) < 0.0005
    assert arm.status().tcp_pose[2] == pytest.approx(point[2] + SPEC.clearance_m)


def test_touch_spec_above_the_force_limit_is_refused(env, patch_b):
    arm = FakeArm(env, FRAME, patch_b)
    hard = TouchSpec(target_force_n=4.0, max_force_n=8.0)
    with pytest.raises(SafetyViolation, match=r"max force 8 N is above the envelope's 5 N"):
        env.check_touch_spec(hard)
    with pytest.raises(SafetyViolation, match="max force 8 N"):
        arm.touch(FRAME.to_base(np.array([50.0, 10.0])), hard)
    with pytest.raises(SafetyViolation, match="search_speed_m_s 0.05"):
        env.check_touch_spec(TouchSpec(search_speed_m_s=0.05))
    with pytest.raises(SafetyViolation, match="target force 5 N"):
        env.check_touch_spec(TouchSpec(target_force_n=5.0, max_force_n=4.0))
    assert arm.motion_log == []


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"max_force_n": None}, "missing key 'envelope.max_force_n'"),
        ({"max_force_n": -1.0}, "'envelope.max_force_n' is -1.0, must be > 0"),
        ({"max_speed_m_s": "fast"}, "'envelope.max_speed_m_s' is 'fast', not a number"),
        ({"margin_mm": -5}, "'envelope.margin_mm' is -5, must be >= 0"),
        ({"max_accel": 1.0}, "unknown key 'envelope.max_accel'"),
        ({"max_contact_speed_m_s": 0.5}, "'envelope.max_contact_speed_m_s' (0.5) is above"),
        ({"max_force_n": 3.0}, "touch max force 4 N is above the envelope's 3 N"),
        ({"depth_mm": 2.0}, "'touch.max_depth_m' (4 mm) is deeper than 'envelope.depth_mm'"),
        ({"approach_height_mm": 5.0}, "'touch.clearance_m' (10 mm) is above"),
    ],
)
def test_malformed_envelope_config_names_file_and_key(patch_b, change, message):
    cfg = dict(ENV_CFG)
    for k, v in change.items():
        if v is None:
            del cfg[k]
        else:
            cfg[k] = v
    with pytest.raises(ConfigError) as e:
        Envelope.from_config(cfg, FRAME, patch_b, "rig.yaml", touch=SPEC)
    assert str(e.value).startswith("rig.yaml: ")
    assert message in str(e.value)

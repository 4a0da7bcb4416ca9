"""``varskin robot check``: loads, connects, reports, validates the plan, moves only with --move."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import pytest
import yaml

import varskin.cli.robot as robot_cli
from robot.fake import FakeArm
from robot.launch import LaunchConfig
from varskin.cli import main

ROOT = Path(__file__).resolve().parent.parent
SIM = ROOT / "launch" / "sim.yaml"


class FakeRig:
    """An arm factory handing out one FakeArm per connection, kept for inspection."""

    def __init__(self, protective_stop: bool = False) -> None:
        self.arms: list[FakeArm] = []
        self.protective_stop = protective_stop

    @contextlib.contextmanager
    def __call__(self, launch: LaunchConfig, allow_motion: bool):
        arm = FakeArm(launch.envelope, launch.true_frame(), launch.patch, seed=launch.sim.seed)
        arm._protective_stop = self.protective_stop
        self.arms.append(arm)
        yield arm


@pytest.fixture
def rig(monkeypatch):
    r = FakeRig()
    monkeypatch.setattr(robot_cli, "default_arm_factory", r)
    return r


def test_check_without_move_moves_nothing(rig, capsys):
    assert main(["robot", "check", str(SIM)]) == 0
    out = capsys.readouterr().out
    (arm,) = rig.arms
    assert arm.motion_log == [] and arm.path_length_m == 0.0 and arm.touch_count == 0
    assert "robot: connected yes" in out and "protective stop no" in out and "TCP pose [" in out
    assert "plan: 100 touches (20x5" in out
    assert "verdict: OK; nothing was moved" in out


def test_check_with_move_touches_three_plan_points(rig, capsys):
    assert main(["robot", "check", str(SIM), "--move"]) == 0
    out = capsys.readouterr().out
    (arm,) = rig.arms
    assert arm.touch_count == 3
    touches = [line for line in out.splitlines() if line.startswith("touch ")]
    assert len(touches) == 3 and all("mean 2.0" in t or "mean 1.9" in t for t in touches)
    assert "verdict: OK; touched 3 points and retracted" in out


def test_malformed_launch_exits_2_with_one_line_before_connecting(rig, tmp_path, capsys):
    data = yaml.safe_load(SIM.read_text())
    data["patch"] = str(ROOT / "configs" / "patch_b.yaml")
    data["touch"]["max_force_n"] = 50.0
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    assert main(["robot", "check", str(bad), "--move"]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "max force 50 N" in err[0]
    assert rig.arms == [] and captured.out == ""


def test_plan_outside_the_envelope_is_refused_and_nothing_moves(rig, monkeypatch, capsys):
    original = LaunchConfig.plan_points_m

    def plan_with_a_stray_point(self):
        points = original(self)
        points[42] += [0.0, 0.05, 0.0]
        return points

    monkeypatch.setattr(LaunchConfig, "plan_points_m", plan_with_a_stray_point)
    assert main(["robot", "check", str(SIM), "--move"]) == 2
    captured = capsys.readouterr()
    assert "verdict: plan REFUSED" in captured.out
    assert "plan touch 42 " in captured.err and "outside the safety box" in captured.err
    (arm,) = rig.arms
    assert arm.motion_log == [] and arm.touch_count == 0


def test_move_is_refused_while_protective_stopped(monkeypatch, capsys):
    rig = FakeRig(protective_stop=True)
    monkeypatch.setattr(robot_cli, "default_arm_factory", rig)
    assert main(["robot", "check", str(SIM)]) == 1  # a report, not an error: not ready
    assert "robot NOT READY (protective stop)" in capsys.readouterr().out
    assert main(["robot", "check", str(SIM), "--move"]) == 2
    assert "protective-stopped" in capsys.readouterr().err
    assert all(a.motion_log == [] for a in rig.arms)


def test_bad_touch_count_is_a_usage_error(rig, capsys):
    assert main(["robot", "check", str(SIM), "--move", "--touches", "0"]) == 2
    assert "--touches must be >= 1" in capsys.readouterr().err
    assert rig.arms == []


def test_help_names_units_and_the_move_flag(capsys):
    with pytest.raises(SystemExit):
        main(["robot", "check", "--help"])
    out = capsys.readouterr().out
    assert "--move" in out and "default: 3" in out


@pytest.fixture
def sim_snapshot(monkeypatch):
    """Start the launch's simulated controller as the CLI does, and snapshot what really
    happened on it (its own TCP and force trace) just before the CLI stops it."""
    snap: dict = {}
    start = robot_cli.start_simulated_controller

    def start_and_watch(launch):
        ctl = start(launch)
        real_stop = ctl.stop

        def stop():
            snap["tcp"] = ctl.tcp_log()[:, 1:4]
            snap["force"] = ctl.force_log()[:, 1]
            snap["scripts"] = ctl.scripts_received
            snap["commands"] = ctl.commands_log()
            snap["pose"] = ctl.tcp_pose
            real_stop()

        ctl.stop = stop
        return ctl

    monkeypatch.setattr(robot_cli, "start_simulated_controller", start_and_watch)
    return snap


def test_sim_launch_through_ur_rtde_moves_nothing_without_move(sim_snapshot, capsys):
    assert main(["robot", "check", str(SIM)]) == 0
    out = capsys.readouterr().out
    assert "robot: connected yes" in out and "verdict: OK; nothing was moved" in out
    tcp = sim_snapshot["tcp"]
    assert len(tcp) > 0 and np.ptp(tcp, axis=0).max() < 1e-9  # the TCP never moved
    # Read-only: no control script was uploaded, so no command could have run.
    assert sim_snapshot["scripts"] == 0 and len(sim_snapshot["commands"]) == 0


def test_sim_launch_through_ur_rtde_touches_with_move(sim_snapshot, capsys):
    assert main(["robot", "check", str(SIM), "--move", "--touches", "1"]) == 0
    out = capsys.readouterr().out
    assert sum(line.startswith("touch ") for line in out.splitlines()) == 1
    force = sim_snapshot["force"]
    assert 0.9 * 2.0 < force.max() <= 1.10 * 2.0  # pressed to the target, within 10%
    assert sim_snapshot["pose"][2] > 0.05 and force[-1] == 0.0  # retracted off the skin

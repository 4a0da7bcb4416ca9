"""``varskin robot check LAUNCH.yaml [--move]``: is this rig ready and is the plan safe?

The first thing to run on a new rig, and safe to run at any time: it loads the launch file
(every mistake reported before anything connects), connects, reports the controller's
state, and validates the whole touch plan against the safety envelope. It commands no
motion at all unless ``--move`` is given; then it touches a few plan points and reports the
contact forces, which proves the chain end to end.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Callable, Iterator

import numpy as np

from robot.arm import Arm, ArmStatus
from robot.launch import LaunchConfig, load_launch
from varskin.errors import ConnectionLost, InputError, ProtectiveStop, RobotError, ScriptNotRunning

# (launch, allow_motion) -> a context manager yielding a connected Arm. Tests inject one.
ArmFactory = Callable[[LaunchConfig, bool], contextlib.AbstractContextManager[Arm]]


def register(subparsers) -> None:
    robot = subparsers.add_parser("robot", help="UR arm: check a rig and its launch file")
    sub = robot.add_subparsers(dest="robot_command", metavar="SUBCOMMAND")
    check = sub.add_parser(
        "check",
        help="load a launch file, connect, report the robot's state and validate the plan (moves nothing)",
        description=(
            "Load and validate LAUNCH.yaml, connect to the robot (a simulated launch starts its "
            "simulated controller on loopback), report its state and check every plan touch "
            "(approach height and descent floor) against the safety envelope. Nothing moves "
            "unless --move is given."
        ),
    )
    check.add_argument("launch", metavar="LAUNCH.yaml", help="launch file, e.g. launch/sim.yaml")
    check.add_argument(
        "--move",
        action="store_true",
        help="after the checks, really touch plan points with the launch's touch spec (the arm MOVES)",
    )
    check.add_argument(
        "--touches",
        type=int,
        default=3,
        metavar="N",
        help="with --move: how many plan points to touch, spread over the plan (default: 3)",
    )
    check.set_defaults(func=_run_check)
    robot.set_defaults(func=lambda args: robot.print_help() or 0)


def _run_check(args: argparse.Namespace) -> int:
    return check(args.launch, move=args.move, touches=args.touches)


def check(
    launch_path: str,
    move: bool = False,
    touches: int = 3,
    arm_factory: ArmFactory | None = None,
    out: Callable[[str], None] = print,
) -> int:
    """The ``robot check`` command; raises a ``VarskinError`` (exit 2) on any failure."""
    if touches < 1:
        raise InputError("--touches must be >= 1")
    launch = load_launch(launch_path)  # all config errors surface here, before connecting
    points_m = launch.plan_points_m()
    out(
        f"launch: {launch.source} ({'simulated' if launch.simulated else 'REAL robot ' + launch.robot.host})"
    )
    out(
        f"patch: {launch.patch.name} {launch.patch.length_mm:g} x {launch.patch.width_mm:g} mm, "
        f"registered by {launch.registration_method}: origin {_vec(launch.frame.origin_m)} m, "
        f"normal {_vec(launch.frame.normal, 3)}"
    )
    out(f"envelope: {launch.envelope.describe()}")
    factory = arm_factory or default_arm_factory
    with factory(launch, move) as arm:
        status = arm.status()
        out(_describe_status(status))
        tcp = np.asarray(status.tcp_pose[:3], float)
        where = (
            "inside" if launch.envelope.contains(tcp) else "OUTSIDE (the first move enters the box)"
        )
        out(f"TCP: {where} the envelope")
        out(
            f"plan: {len(points_m)} touches ({launch.plan.nx}x{launch.plan.ny}, margin "
            f"{launch.plan.margin_mm:g} mm), approach +{launch.touch.clearance_m * 1000:g} mm, "
            f"floor -{launch.touch.max_depth_m * 1000:g} mm, target {launch.touch.target_force_n:g} N "
            f"(max {launch.touch.max_force_n:g} N)"
        )
        try:
            launch.envelope.check_touch_plan(points_m, launch.touch)
        except RobotError:
            out("verdict: plan REFUSED (nothing was moved)")
            raise
        ready_problem = _not_ready(status)
        if not move:
            verdict = (
                "OK" if ready_problem is None else f"plan OK, robot NOT READY ({ready_problem})"
            )
            out(
                f"verdict: {verdict}; nothing was moved (pass --move to touch {touches} plan points)"
            )
            return 0 if ready_problem is None else 1
        if ready_problem is not None:
            raise _not_ready_error(status, ready_problem)
        picks = np.unique(
            np.linspace(0, len(points_m) - 1, min(touches, len(points_m))).round().astype(int)
        )
        xy_mm = launch.plan.points_mm(launch.patch)
        for n, i in enumerate(picks, 1):
            # the driver's settle and dwell run on the host clock: scaled to a fast simulation
            result = arm.touch(points_m[i], launch.arm_touch_spec())
            out(
                f"touch {n}/{len(picks)} at patch ({xy_mm[i][0]:.1f}, {xy_mm[i][1]:.1f}) mm: "
                f"contact z {result.contact_z_m:.4f} m, mean {result.mean_force_n:.2f} N, "
                f"peak {result.peak_force_n:.2f} N"
            )
        out(f"verdict: OK; touched {len(picks)} points and retracted")
    return 0


def _describe_status(s: ArmStatus) -> str:
    pose = ", ".join(f"{v:.4f}" for v in s.tcp_pose)
    return (
        f"robot: connected {_yn(s.connected)}, program running {_yn(s.program_running)}, "
        f"protective stop {_yn(s.protective_stop)}, safety mode {s.safety_mode}, "
        f"TCP pose [{pose}] (m, rad), force {s.tcp_force_n:.2f} N"
    )


def _not_ready(s: ArmStatus) -> str | None:
    if not s.connected:
        return "not connected"
    if s.protective_stop:
        return "protective stop"
    if s.safety_mode not in ("normal", "reduced"):
        return f"safety mode {s.safety_mode}"
    return None


def _not_ready_error(s: ArmStatus, problem: str) -> RobotError:
    if not s.connected:
        return ConnectionLost(f"robot not connected; not moving ({problem})")
    if s.protective_stop:
        return ProtectiveStop("robot is protective-stopped; unlock it on the pendant before --move")
    if not s.program_running:
        return ScriptNotRunning(f"robot control program is not running; not moving ({problem})")
    return RobotError(f"robot not ready; not moving ({problem})")


def _yn(b: bool) -> str:
    return "yes" if b else "no"


def _vec(v, digits: int = 4) -> str:
    return "(" + ", ".join(f"{x:.{digits}f}" for x in v) + ")"


# --- connecting ---------------------------------------------------------------------------


@contextlib.contextmanager
def default_arm_factory(launch: LaunchConfig, allow_motion: bool) -> Iterator[Arm]:
    """Connect as the launch says: a simulated rig starts its loopback controller first.

    Without ``allow_motion`` the connection is a read-only ``URReader`` (RTDE receive only):
    it neither uploads the control script nor can it command motion.
    """
    controller = None
    try:
        if launch.simulated:
            controller = start_simulated_controller(launch)
            host = controller.host
        else:
            host = launch.robot.host
        if allow_motion:
            from robot.ur import URArm  # lazily: ur-rtde is only needed when connecting

            arm = URArm(host, launch.envelope, **launch.robot.arm_options())
        else:
            from robot.ur_reader import URReader

            arm = URReader(host, call_timeout_s=launch.robot.call_timeout_s)
        arm.connect()
        try:
            yield arm
        finally:
            arm.close()
    finally:
        if controller is not None:
            controller.stop()


def start_simulated_controller(launch: LaunchConfig):
    """The launch's simulated rig: the true skin where the registration says (plus the
    configured registration error), parked above the patch inside the envelope, running
    ``sim.time_scale`` simulated seconds per wall second (drive it with
    ``launch.arm_touch_spec()``)."""
    from robot.sim_controller import SimRig, SimulatedController

    centre = np.array([launch.patch.length_mm / 2, launch.patch.width_mm / 2])
    park = launch.frame.to_base(centre)
    park[2] = launch.envelope.box_max_m[2] - 0.005
    rig = SimRig(
        patch_frame=launch.true_frame(),
        stiffness_n_per_mm=launch.sim.stiffness_n_per_mm,
        ft_offset_n=launch.sim.force_offset_n,
        ft_noise_n=launch.sim.force_noise_sd_n,
        patch_length_mm=launch.patch.length_mm,
        patch_width_mm=launch.patch.width_mm,
        start_pose=(*park.tolist(), 0.0, float(np.pi), 0.0),
        time_scale=launch.sim.time_scale,
    )
    return SimulatedController(rig, host=None, seed=launch.sim.seed).start()

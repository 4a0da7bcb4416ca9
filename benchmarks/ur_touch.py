"""Wall time of one URArm touch through the real ur-rtde client against the simulated controller.

Why: the touch timeline (approach, bounded descent, settle, dwell, retract) sets how many points
a calibration run can press per hour; this measures it end to end, sockets and all, and where
the time goes, beside the real-rig estimate of ``robot.rig_time`` for the same touches. At
``--time-scale 1`` the simulated controller runs in real time, so the wall time is what a
real arm with the same speeds would take plus loopback overheads; at a higher scale the
controller runs that many simulated seconds per wall second and the driver's host-clock
waits (settle, dwell) are divided by the scale, so wall x scale is the simulated time a
real rig would need (plus the client's handshakes, which do not scale).

    python benchmarks/ur_touch.py [--touches 12] [--quick] [--time-scale 8] [--repeats 3]
    python benchmarks/ur_touch.py --launch launch/sim.yaml [--time-scale 8]

Prints medians over the touches (the first touch, which starts from the home pose, excluded)
and, with ``--repeats``, medians over the runs of those medians. The force error is the
controller's TRUE force over the dwell (from its own log): the mean's error and the largest
single-step deviation from the target.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import numpy as np

from robot.arm import TouchSpec
from robot.rig_time import estimate_plan_time
from robot.safety import Envelope
from robot.sim_controller import SimRig, SimulatedController
from robot.ur import URArm
from robot.ur_wire import CMD_FORCE_MODE_STOP
from varskin.patch import builtin_patch


@dataclasses.dataclass
class Setup:
    """What one run touches and how: the rig (or launch), the specs and the points."""

    spec: TouchSpec  # the touch as a real rig would do it (simulated seconds)
    arm_spec: TouchSpec  # what the driver is given: host-clock waits divided by the scale
    envelope: Envelope
    points_m: np.ndarray  # (touches + 1, 3)
    time_scale: float
    start: object  # () -> a started SimulatedController
    surface_z_m: float  # the true skin height (contact z is reported relative to it)


def bench_setup(args: argparse.Namespace) -> Setup:
    if args.launch:
        from robot.launch import load_launch
        from varskin.cli.robot import start_simulated_controller

        launch = load_launch(args.launch)
        if args.time_scale is not None:
            sim = dataclasses.replace(launch.sim, time_scale=args.time_scale)
            launch = dataclasses.replace(launch, sim=sim)
        points = launch.plan_points_m()[: args.touches + 1]
        return Setup(
            spec=launch.touch,
            arm_spec=launch.arm_touch_spec(),
            envelope=launch.envelope,
            points_m=points,
            time_scale=launch.sim.time_scale,
            start=lambda: start_simulated_controller(launch),
            surface_z_m=float(launch.true_frame().origin_m[2]),
        )
    scale = args.time_scale or 1.0
    patch = builtin_patch("patch_b")
    rig = SimRig(patch_length_mm=patch.length_mm, patch_width_mm=patch.width_mm, time_scale=scale)
    if args.quick:
        spec = TouchSpec(clearance_m=0.003, search_speed_m_s=0.01, dwell_s=0.5)
    else:
        # the defaults: 10 mm clearance, 5 mm/s search, 0.15 s settle, 0.5 s dwell
        spec = TouchSpec()
    arm_spec = dataclasses.replace(
        spec, dwell_s=spec.dwell_s / scale, settle_s=spec.settle_s / scale
    )
    env = Envelope.around_patch(rig.patch_frame, patch, 10.0, 60.0, 6.0, 8.0, 0.25, 1.0, 0.01)
    xs = np.linspace(15, patch.length_mm - 15, args.touches + 1)
    points = np.array([rig.patch_frame.to_base([x, patch.width_mm / 2], 0.0) for x in xs])
    return Setup(
        spec=spec,
        arm_spec=arm_spec,
        envelope=env,
        points_m=points,
        time_scale=scale,
        start=lambda: SimulatedController(rig, seed=0).start(),
        surface_z_m=float(rig.patch_frame.origin_m[2]),
    )


def dwell_forces(sim: SimulatedController, dwell_s: float) -> list[np.ndarray]:
    """Per touch, the controller's true force over the dwell: the ``dwell_s`` (simulated)
    before each forceModeStop it processed."""
    log = sim.force_log()
    stops = [t for t, cmd in sim.commands_log() if cmd == CMD_FORCE_MODE_STOP]
    return [log[(log[:, 0] > t - dwell_s) & (log[:, 0] <= t), 1] for t in stops]


def run_once(setup: Setup) -> tuple[list[dict], float, float, float]:
    """One controller, one arm, ``len(points) - 1`` timed touches. Returns the rows, the
    true peak force, connect and close times."""
    rows = []
    sim = setup.start()
    try:
        t0 = time.monotonic()
        arm = URArm(sim.host, setup.envelope).connect()
        t_connect = time.monotonic() - t0
        try:
            for i, point in enumerate(setup.points_m):
                if i == 1:
                    sim.clear_logs()  # from here on, the log holds only timed touches
                ticks = []
                start = time.monotonic()
                res = arm.touch(point, setup.arm_spec, ticks.append)
                end = time.monotonic()
                if i == 0:
                    continue  # starts from home, not from the previous point's clearance
                rows.append(
                    {
                        "total": end - start,
                        "to_contact": res.t_contact - start,
                        "settle": res.t_settled - res.t_contact,
                        "dwell": res.t_release - res.t_settled,
                        "retract": end - res.t_release,
                        "reported_err": abs(res.mean_force_n - setup.spec.target_force_n),
                        "contact_mm": (res.contact_z_m - setup.surface_z_m) * 1000.0,
                        "ticks": len(ticks),
                    }
                )
            windows = dwell_forces(sim, setup.spec.dwell_s)
            true_peak = float(sim.force_log()[:, 1].max())
        finally:
            t0 = time.monotonic()
            arm.close()
            t_close = time.monotonic() - t0
    finally:
        sim.stop()
    target = setup.spec.target_force_n
    for row, f in zip(rows, windows, strict=True):
        row["true_err"] = abs(float(np.mean(f)) - target) / target
        row["true_dev"] = float(np.max(np.abs(f - target))) / target
    return rows, true_peak, t_connect, t_close


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--touches", type=int, default=12, help="touches to time (default 12)")
    ap.add_argument(
        "--quick", action="store_true", help="3 mm clearance at 10 mm/s (the tests' spec)"
    )
    ap.add_argument(
        "--time-scale",
        type=float,
        default=None,
        help="simulated seconds per wall second (default 1, or the launch's sim.time_scale)",
    )
    ap.add_argument("--launch", help="touch the plan of this simulated launch file instead")
    ap.add_argument("--repeats", type=int, default=1, help="runs, each on a fresh controller")
    args = ap.parse_args()
    setup = bench_setup(args)
    scale = setup.time_scale

    runs = []
    for _ in range(args.repeats):
        rows, peak, t_connect, t_close = run_once(setup)
        med = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
        med.update(peak=peak, connect=t_connect, close=t_close)
        runs.append(med)
    med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    # the model for the timed touches: each travels from the previous point's approach
    start = setup.points_m[0] + [0.0, 0.0, setup.spec.clearance_m]
    model = estimate_plan_time(setup.points_m[1:], setup.spec, setup.envelope, start)
    model_touch = float(np.median(model.per_touch_s))

    print(f"spec: {args.launch or ('quick' if args.quick else 'default')} {setup.spec}")
    arm = setup.arm_spec
    print(f"time scale {scale:g}; driver dwell {arm.dwell_s:.4f} s, settle {arm.settle_s:.4f} s")
    print(f"connect {med['connect']:.3f} s, close {med['close']:.3f} s")
    print(f"touches timed: {len(rows)} x {len(runs)} run(s) (medians)")
    print(f"  total per touch   {med['total']:.3f} s wall = {med['total'] * scale:.3f} s simulated")
    ratio = med["total"] * scale / model_touch
    print(f"  model (real rig)  {model_touch:.3f} s  (wall x scale / model = {ratio:.3f})")
    print(f"  approach+descent  {med['to_contact']:.3f} s wall")
    print(f"  settle            {med['settle']:.3f} s wall")
    print(f"  dwell             {med['dwell']:.3f} s wall  ({med['ticks']:.0f} dwell callbacks)")
    print(f"  retract           {med['retract']:.3f} s wall")
    print(f"  contact z - true surface {med['contact_mm']:+.3f} mm")
    print(
        f"  controller's true dwell force: mean error {med['true_err'] * 100:.2f} %, largest "
        f"deviation {med['true_dev'] * 100:.2f} % of {setup.spec.target_force_n:g} N; "
        f"true peak {med['peak']:.3f} N"
    )
    print(f"  |driver's mean force - target| {med['reported_err']:.3f} N")
    totals = ", ".join(f"{r['total']:.3f}" for r in runs)
    print(f"  per-run totals (wall s): {totals}")


if __name__ == "__main__":
    main()

"""Wall time of one URArm touch through the real ur-rtde client against the simulated controller.

Why: the touch timeline (approach, bounded descent, settle, dwell, retract) sets how many points
a calibration run can press per hour; this measures it end to end, sockets and all, and where
the time goes. The simulated controller runs in real time, so the numbers are what a real arm
with the same speeds would take plus loopback overheads.

    python benchmarks/ur_touch.py [--touches 12] [--quick]

Prints medians over the touches (the first touch, which starts from the home pose, excluded).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from robot.arm import TouchSpec
from robot.safety import Envelope
from robot.sim_controller import SimRig, SimulatedController
from robot.ur import URArm
from varskin.patch import builtin_patch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--touches", type=int, default=12, help="touches to time (default 12)")
    ap.add_argument(
        "--quick", action="store_true", help="3 mm clearance at 10 mm/s (the tests' spec)"
    )
    args = ap.parse_args()

    patch = builtin_patch("patch_b")
    rig = SimRig(patch_length_mm=patch.length_mm, patch_width_mm=patch.width_mm)
    if args.quick:
        spec = TouchSpec(clearance_m=0.003, search_speed_m_s=0.01, dwell_s=0.5)
    else:
        spec = (
            TouchSpec()
        )  # the defaults: 10 mm clearance, 5 mm/s search, 0.15 s settle, 0.5 s dwell
    env = Envelope.around_patch(rig.patch_frame, patch, 10.0, 60.0, 6.0, 8.0, 0.25, 1.0, 0.01)
    xs = np.linspace(15, patch.length_mm - 15, args.touches + 1)
    rows = []
    with SimulatedController(rig, seed=0) as sim:
        t0 = time.monotonic()
        arm = URArm(sim.host, env).connect()
        t_connect = time.monotonic() - t0
        try:
            for i, x in enumerate(xs):
                ticks = []
                start = time.monotonic()
                res = arm.touch(
                    rig.patch_frame.to_base([x, patch.width_mm / 2], 0.0), spec, ticks.append
                )
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
                        "force_err": abs(res.mean_force_n - spec.target_force_n),
                        "ticks": len(ticks),
                    }
                )
            true_peak = float(sim.force_log()[:, 1].max())
        finally:
            t0 = time.monotonic()
            arm.close()
            t_close = time.monotonic() - t0

    med = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
    print(f"spec: {'quick' if args.quick else 'default'} {spec}")
    print(f"connect {t_connect:.3f} s, close {t_close:.3f} s")
    print(f"touches timed: {len(rows)} (medians)")
    print(f"  total per touch   {med['total']:.3f} s")
    print(f"  approach+descent  {med['to_contact']:.3f} s")
    print(f"  settle            {med['settle']:.3f} s")
    print(f"  dwell             {med['dwell']:.3f} s  ({med['ticks']:.0f} dwell callbacks)")
    print(f"  retract           {med['retract']:.3f} s")
    print(
        f"  |mean force - target| {med['force_err']:.3f} N; controller's true peak {true_peak:.3f} N"
    )


if __name__ == "__main__":
    main()

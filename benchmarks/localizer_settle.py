"""What longer settling costs a finger solve, against what it buys.

Why it exists: a finger-like ``alternate`` solve takes ``settle_rounds`` over-relaxed
alternations (default 12) after its first four, and still stops short of the alternation's
fixed point at Patch B's outermost wires (docs/benchmarks.md, "How far finger solves
settle"). ``localizer_seeds.py --settle-rounds N`` counts the per-scene misses over many
seeds; this script times the batch solve (error-bar check included) at each setting on a
few of the same scenes, with the paper method (ppcm 128) timed in the same loop for the
ratio, and prints each setting's median time beside its errors. A setting is
``settle_rounds`` or ``settle_rounds:joint_settle_rounds`` (the joint rounds a settled solve
then tries; without the colon, the localizer's default). Run as ``python
benchmarks/localizer_settle.py [--seeds 360-369] [--rounds 0,12:0,12,40:0] [--repeats 3]``
(about six minutes on the 2-core VM; nothing else should run meanwhile).
"""

import _one_core  # noqa: F401  (first: pins BLAS to one thread before numpy loads)

# isort: split
import argparse

import numpy as np
from localizer_live import seed_range

from varskin.bench import _timed  # varskin bench's own timer: median ms of repeated runs
from varskin.evaluate import rms_n_minus_1 as rms  # the paper's sqrt(sum e^2 / (N - 1))
from varskin.patch import builtin_patch
from varskin.planning import uniform_points
from varskin.simulate import simulate_session


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=seed_range, default=range(360, 370), help="default 360-369")
    ap.add_argument(
        "--rounds",
        default="0,12:0,12,40:0",
        help="comma-separated settle_rounds[:joint_settle_rounds] (default 0,12:0,12,40:0)",
    )
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per solve (default 3)")
    args = ap.parse_args(argv)
    rounds = args.rounds.split(",")
    patch = builtin_patch("patch_b")
    grid = uniform_points(patch, 20, 5)
    ms = {r: [] for r in rounds}
    ratio = {r: [] for r in rounds}
    scene_rms = {r: [] for r in rounds}
    worst = {r: 0.0 for r in rounds}
    paper_ms = []
    for seed in args.seeds:
        s = simulate_session(patch, grid, "finger", seed)
        logs = s.point_logs()
        _, tp = _timed(logs, "paper", {"ppcm": 128}, args.repeats)
        paper_ms.append(tp)
        for r in rounds:
            settle, _, joint = r.partition(":")
            params = {"settle_rounds": int(settle)}
            if joint:
                params["joint_settle_rounds"] = int(joint)
            pred, t = _timed(logs, "peakfit", params, args.repeats)
            e = np.linalg.norm(pred.xy() - s.truth, axis=1)
            e = e[np.isfinite(e)]
            ms[r].append(t)
            ratio[r].append(t / tp)
            scene_rms[r].append(rms(e))
            worst[r] = max(worst[r], float(e.max()))
    print(
        f"Patch B, finger, varskin calibrate's 20 x 5 plan, no patch given, seeds "
        f"{args.seeds[0]}-{args.seeds[-1]}, median of {args.repeats} runs per solve; "
        f"paper method (ppcm 128) median {np.median(paper_ms):.0f} ms"
    )
    print(
        "| settle_rounds[:joint_settle_rounds] | batch solve, median | x paper (median) | RMS median | max error |"
    )
    print("|---|---|---|---|---|")
    for r in rounds:
        print(
            f"| {r} | {np.median(ms[r]):.0f} ms | {np.median(ratio[r]):.2f} "
            f"| {np.median(scene_rms[r]):.3f} mm | {worst[r]:.2f} mm |"
        )


if __name__ == "__main__":
    main()

"""A finished session refined: ``varskin calibrate --resume S.db --refine N``, simulated.

Why: a lab that ran the paper's grid (or a quick sparse one) and got some sensors not
located, or located loosely, wants to add touches only where they are needed. This measures
what the refinement adds on simulated Patch B probed by the robot, seed by seed: the base
grid is touched in its serpentine order (as a session does), then the adaptive planner,
given every base touch as its first points (``AdaptivePlanner(first_points=...)``, what
``--refine`` runs), adds touches from the batch solve after each, until every sensor is
located with sigma under the target or N touches are added. The scenes, touches and rig
time are those of ``adaptive_plan.py`` (same seeds give the same scenes); the goal is the
same: every sensor located, RMS <= 0.5 mm.

    python benchmarks/refine_session.py --jobs 2          # 24 fresh seeds, two base grids
"""

from __future__ import annotations

import _one_core  # noqa: F401  (first: pins BLAS to one thread before numpy loads)

# isort: split
import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from adaptive_plan import (  # noqa: E402
    FRAME_RATE_HZ,
    GOAL_RMS_MM,
    RigModel,
    SimSession,
    _grid,
    fmt,
    goal,
    max_sigma,
    run_jobs,
    scene_arguments,
    score,
)

from varskin.localization.peakfit import Localizer  # noqa: E402
from varskin.patch import resolve_patch  # noqa: E402
from varskin.planning import AdaptivePlanner, TouchOutcome, uniform_points  # noqa: E402


@dataclass
class Refined:
    base_rms: float
    base_located: int
    base_sigma: float  # largest sigma_mm after the base grid (inf: not every sensor ok)
    added_at_goal: int | None  # touches added until the goal first held (0: held already)
    added: int  # touches added until the planner stopped
    stop_reason: str
    rms: float
    located: int
    added_time_s: float  # rig time of the added touches (travel from the last base touch)


def refine(patch, seed: int, grid, args, rig: RigModel) -> Refined:
    base = uniform_points(patch, *grid, args.margin)
    s = SimSession(patch, seed, args.frames, rig)
    loc = Localizer(patch.names, s.rest, s.rest_sd, patch=patch)
    planner = AdaptivePlanner(
        patch,
        coarse=None,
        first_points=base,
        budget=len(base) + args.refine,
        target_sigma_mm=args.target,
        margin_mm=args.margin,
    )
    n = len(patch.names)
    gen = planner.plan()
    touch = next(gen)
    base_score = None
    added_at_goal = None
    k = 0
    clock = 0.0
    points = []
    pred = None
    while True:
        loc.update(s.touch(touch.x_mm, touch.y_mm))
        k += 1
        points.append((touch.x_mm, touch.y_mm))
        if k >= len(base):  # the session's own touches watched live; refined from the batch
            pred = loc.result()
            rms, located = score(pred, s.scene.true_xy)
            if k == len(base):
                base_score = (rms, located, max_sigma(pred))
            else:
                clock += rig.next_touch_s(points[-2], points[-1])
            if added_at_goal is None and goal(rms, located, n):
                added_at_goal = k - len(base)
        try:
            touch = gen.send(TouchOutcome(touch, True, pred if k >= len(base) else None))
        except StopIteration:
            break
    rms, located = score(pred, s.scene.true_xy)
    return Refined(
        *base_score,
        added_at_goal,
        k - len(base),
        planner.stop_reason or "",
        rms,
        located,
        clock,
    )


def _job(job):
    seed, grid, args = job
    patch = resolve_patch(args.patch)
    rig = RigModel(args.launch, args.frames / FRAME_RATE_HZ)
    return seed, grid, refine(patch, seed, grid, args, rig)


def report(results, grids, n: int, args) -> list[str]:
    lines = [
        f"Refinement: up to {args.refine} touches after the base grid, target sigma "
        f"{args.target:g} mm; goal: {n}/{n} located and RMS <= {GOAL_RMS_MM} mm.",
        "",
        "| base grid | seeds | at goal after the grid | located after the grid, median (min) "
        "| RMS after the grid, median | at goal after refining | touches added: to the goal, "
        "median (max) | touches added: to the planner's stop, median (max) | stopped at the "
        "target | RMS after refining, median | added rig time, median |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for grid in grids:
        rows = [r for _, g, r in results if g == grid]
        at_base = sum(goal(r.base_rms, r.base_located, n) for r in rows)
        at_end = sum(goal(r.rms, r.located, n) for r in rows)
        to_goal = [r.added_at_goal for r in rows if r.added_at_goal is not None]
        located = [r.base_located for r in rows]
        lines.append(
            f"| {grid[0]}x{grid[1]} ({grid[0] * grid[1]}) | {len(rows)} | {at_base} "
            f"| {np.median(located):.1f} ({min(located)}) "
            f"| {np.nanmedian([r.base_rms for r in rows]):.3f} mm | {at_end} "
            f"| {fmt(np.median(to_goal) if to_goal else None, 1)} ({fmt(max(to_goal) if to_goal else None)}) "
            f"| {np.median([r.added for r in rows]):.1f} ({max(r.added for r in rows)}) "
            f"| {sum(r.stop_reason == 'target' for r in rows)} "
            f"| {np.nanmedian([r.rms for r in rows]):.3f} mm "
            f"| {np.median([r.added_time_s for r in rows]):.0f} s |"
        )
    return lines


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    scene_arguments(p, seeds=24)
    p.add_argument("--grids", type=_grid, nargs="+", default=[(20, 5), (10, 3)], help="base grids")
    p.add_argument("--refine", type=int, default=40, help="most touches added (--refine N)")
    p.add_argument("--target", type=float, default=AdaptivePlanner.target_sigma_mm)
    p.add_argument("--launch", default="launch/sim.yaml", help="rig for the time estimate")
    p.add_argument("--jobs", type=int, default=1, help="runs in parallel")
    args = p.parse_args(argv)

    patch = resolve_patch(args.patch)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    jobs = [(seed, grid, args) for grid in args.grids for seed in seeds]
    t0 = time.perf_counter()
    results = run_jobs(_job, jobs, args.jobs)
    for line in report(results, args.grids, len(patch.names), args):
        print(line)
    print(f"({time.perf_counter() - t0:.0f} s, {args.jobs} job(s))")


if __name__ == "__main__":
    main()

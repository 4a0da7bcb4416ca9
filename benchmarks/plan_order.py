"""The uniform plan's touch order: a sweep against one fixed shuffle, patch by patch.

Why it exists: the board's offsets settle after the no-contact baseline, and a sweep makes
session time run along the patch. On a patch so small that every touch lies in every
sensor's fit window, that settling reads as position; on a long patch a sweep keeps each
window's touches close in time, which the slow floor model needs. ``plan.order: auto``
shuffles only patches whose longer side is at most ``planning.SHUFFLE_UP_TO_MM``; this
measures both orders on every layout, so that rule has numbers behind it.

Each row: ten or more seeded scenes (the simulator's defaults) on ``varskin calibrate``'s
grid (``planning.uniform_points``, 3 mm margin) in the order named, solved with the patch
given, as calibrate solves. Printed: the order ``auto`` picks, sensors located (`ok`),
median and worst scene RMS, the largest error, and 2-sigma coverage of the `ok` sensors.
Run as ``python benchmarks/plan_order.py [--seeds 0-19] [--patch NAME]`` (two processes).
"""

from __future__ import annotations

import _one_core  # noqa: F401  (first: pins BLAS to one thread before numpy loads)

# isort: split
import argparse
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from localizer_live import seed_range
from localizer_other_patches import LAYOUTS

from varskin.evaluate import rms_n_minus_1 as rms
from varskin.localization import localize
from varskin.patch import builtin_patch
from varskin.planning import SHUFFLED, SWEEP, in_order, touch_order, uniform_points
from varskin.simulate import simulate_session

PATCHES = ("tiny3x3", "dense8x4", "strip8x1", "square6x5", "patch_a", "patch_b")


def patch_named(name: str):
    return LAYOUTS[name][0] if name in LAYOUTS else builtin_patch(name)


def one_scene(job: tuple) -> tuple:
    name, probe, order, seed = job
    patch = patch_named(name)
    points = in_order(uniform_points(patch, 20, 5), order)
    session = simulate_session(patch, points, probe, seed)
    pr = localize(session.point_logs(), patch=patch)
    e = np.linalg.norm(pr.xy() - session.truth, axis=1)
    sigma = np.array([np.nan if x.sigma_mm is None else x.sigma_mm for x in pr], float)
    ok = np.isfinite(e)
    return e[ok], sigma[ok]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--patch", choices=PATCHES, help="one layout (default all)")
    ap.add_argument("--seeds", type=seed_range, default=range(0, 20), help="default 0-19")
    args = ap.parse_args(argv)
    print("patch, probe, order (auto's pick) | ok per scene | RMS median / worst | max | 2 sigma")
    with ProcessPoolExecutor(2) as pool:
        for name in (args.patch,) if args.patch else PATCHES:
            n = len(patch_named(name).sensors)
            pick = touch_order(patch_named(name))
            for probe in ("robot", "finger"):
                for order in (SWEEP, SHUFFLED):
                    t0 = time.perf_counter()
                    jobs = [(name, probe, order, seed) for seed in args.seeds]
                    res = list(pool.map(one_scene, jobs))
                    r = np.array([rms(e) if e.size > 1 else np.nan for e, _ in res])
                    e = np.concatenate([e for e, _ in res])
                    s = np.concatenate([s for _, s in res])
                    mark = " (auto)" if order == pick else ""
                    print(
                        f"{name}, {probe}, {order}{mark} | {e.size / len(res):.1f} of {n} | "
                        f"{np.nanmedian(r):.3f} / {np.nanmax(r):.3f} mm | {e.max():.2f} mm | "
                        f"{np.mean(e <= 2.0 * s):.3f}   ({time.perf_counter() - t0:.0f} s)",
                        flush=True,
                    )


if __name__ == "__main__":
    main()

"""A weak sensor probed first while its offset settles: the plain grid against a re-probe.

Why: such a sensor is `drifting` (docs/localizer.md). The status advises probing it again
once the offsets are steady; this checks that doing so locates it, and that the plain grid
still flags it. Patch A and B, seeds 1-12, sensor 0 rising or sensor 1 falling by 120
counts with a 90-count peak (the hard-case test's construction), robot probe, 20 x 5 grid;
the re-probe touches the grid's first three columns again after the grid.

    python benchmarks/localizer_reprobe.py     # about 8 s
"""

import numpy as np

from varskin.localization import peakfit
from varskin.patch import builtin_patch
from varskin.scene import Scene
from varskin.simulate import simulate_session, uniform_grid


def main() -> None:
    summary: dict[str, list[tuple[str, float, float]]] = {"grid": [], "reprobe": []}
    for name in ("patch_a", "patch_b"):
        patch = builtin_patch(name)
        grid = uniform_grid(patch, 20, 5)
        for seed in range(1, 13):
            for drift, i in ((120.0, 0), (-120.0, 1)):
                scene = Scene.create(patch, seed)
                scene.drift[i], scene.peak[i] = drift, 90.0
                for plan, pts in (("grid", grid), ("reprobe", np.vstack([grid, grid[:15]]))):
                    s = simulate_session(patch, pts, probe="robot", seed=seed, scene=scene)
                    est = peakfit.localize(s.point_logs()).estimates[i]
                    ok = est.status == "ok"
                    e = (
                        float(np.hypot(est.x_mm - s.truth[i, 0], est.y_mm - s.truth[i, 1]))
                        if ok
                        else np.nan
                    )
                    sd = est.sigma_mm if ok else np.nan
                    summary[plan].append((est.status, e, sd))
                    print(
                        f"{name} seed {seed:2d} drift {drift:+5.0f} {plan:8s} {est.status:10s} "
                        f"error {e:5.2f} mm sigma {sd:5.2f} mm"
                    )
    for plan, rows in summary.items():
        ok = [(e, sd) for st, e, sd in rows if st == "ok"]
        e = np.array([r[0] for r in ok])
        sd = np.array([r[1] for r in ok])
        print(
            f"{plan}: located {len(ok)}/{len(rows)}"
            + (
                f", max error {e.max():.2f} mm, within 2 sigma {(e <= 2 * sd).sum()}/{len(ok)}"
                if ok
                else ""
            )
        )


if __name__ == "__main__":
    main()

"""The board's settling that a finger fit did not follow: the cases, the cause, the flag.

Patch B finger scenes on the 20 x 5 cell centres, without a patch. ``--cases`` (default) takes
apart the scenes where a sensor ended more than 2 mm off (seeds 410, 494, 540): its error,
sigma and status as simulated, with the offsets' settling made instant (``drift_tau_s`` 1 s:
the same drift, reached before the first touch), and with the settling check switched off.
``--count 360-459`` counts, over those seeds, the sensors the settling check flags that the
older check (the fitted floor's own span) passed, and their fitted peaks' errors; ``--patch
patch_a`` for Patch A. Accuracy only, nothing is timed (about 3 s per scene).
"""

import _one_core  # noqa: F401  (first: pins BLAS to one thread before numpy loads)

# isort: split
import argparse
import dataclasses
import warnings

import numpy as np
from localizer_live import seed_range

from varskin.localization import _peak_model as pm
from varskin.localization import _statuses, peakfit
from varskin.patch import builtin_patch
from varskin.scene import SceneParams
from varskin.simulate import simulate_session, uniform_grid

CASES = ((410, "S3"), (494, "S3"), (540, "S28"))


def cases(p) -> None:
    g = uniform_grid(p, 20, 5)
    instant = dataclasses.replace(SceneParams(), drift_tau_s=1.0)
    for seed, name in CASES:
        for label, params, check in (
            ("as simulated", None, True),
            ("settling instant", instant, True),
            ("check off", None, False),
        ):
            _statuses.UNFOLLOWED_FRACTION = 0.35 if check else np.inf
            s = simulate_session(p, g, "finger", seed, params=params)
            pr = peakfit.localize(s.point_logs())
            i = s.sensors.index(name)
            est = pr.estimates[i]
            e = np.linalg.norm(pr.xy() - s.truth, axis=1)
            where = f"{e[i]:.2f} mm, sigma {est.sigma_mm:.2f} mm" if est.status == "ok" else ""
            print(
                f"seed {seed} {name} {label:16s}: {est.status:9s} {where:26s} "
                f"scene RMS {np.sqrt(np.nanmean(e**2)):.3f} mm, largest {np.nanmax(e):.2f} mm"
            )
    _statuses.UNFOLLOWED_FRACTION = 0.35


def count(p, seeds) -> None:
    g = uniform_grid(p, 20, 5)
    located = flagged = 0
    lines = []
    for seed in seeds:
        s = simulate_session(p, g, "finger", seed)
        loc = peakfit.solved(s.point_logs())
        pr = loc.result()
        f, h = loc.fit, loc.spacing()
        w = pm.half_width(f.theta)
        inside = _statuses.window_members(loc, f.theta[:, :2], w, h)
        own, missed = _statuses.drift_measures(loc, inside)
        old = own > _statuses.DRIFT_FRACTION
        st = np.array([e.status for e in pr])
        new = (st == "drifting") & (missed > _statuses.UNFOLLOWED_FRACTION) & ~old
        located += int((st == "ok").sum() + new.sum())
        flagged += int(new.sum())
        e_fit = np.hypot(*(f.theta[:, :2] - s.truth).T)
        lines += [
            f"  seed {seed} {s.sensors[i]}: missed {missed[i]:.2f} peak heights, fitted peak "
            f"{e_fit[i]:.2f} mm off"
            for i in np.flatnonzero(new)
        ]
    print(
        f"{p.name} finger seeds {seeds[0]}-{seeds[-1]}: the settling check flags {flagged} of "
        f"{located} sensors the other checks pass"
    )
    print("\n".join(lines))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=seed_range, help="count the flags over these seeds")
    ap.add_argument("--patch", default="patch_b", choices=("patch_a", "patch_b"))
    args = ap.parse_args()
    warnings.filterwarnings("ignore")
    p = builtin_patch(args.patch)
    if args.count:
        count(p, args.count)
    else:
        cases(p)


if __name__ == "__main__":
    main()

"""Peaks no touch came near, on sparse grids: their error bars with and without the shapes'
spread (_unseen.py).

A sparse plan leaves gaps between touches wider than a bump, and a sensor in one is fitted
from its flanks. This solves each scene twice, as the localizer does by default and with
the spread left out (``UNSEEN_FRACTION`` 0: nothing counts as unseen), and reports per
grid and scene type: the `ok` sensors, those whose peak was unseen (named in the result's
``shape_spread_mm``), their RMS error and 2-sigma coverage both ways, and the coverage and
RMS of all `ok` sensors both ways. Grids are ``varskin calibrate``'s (3 mm margin); the
patch is given, as a session gives it.

Run as ``python benchmarks/localizer_unseen.py`` (seeds 100-109; 6-9 minutes on the 2-core
VM beside other runs) or with ``--seeds 100-119 --grids 8x3 10x3``.
"""

import _one_core  # noqa: F401  (first: pins BLAS to one thread before numpy loads)

# isort: split
import argparse
from unittest import mock

import numpy as np
from localizer_live import seed_range

from varskin.cli.simulate import parse_grid
from varskin.evaluate import rms_n_minus_1 as rms
from varskin.localization import _unseen, localize
from varskin.patch import builtin_patch
from varskin.planning import uniform_points
from varskin.predictions import OK
from varskin.simulate import simulate_session


def solve_both(logs, patch, truth) -> dict:
    """Errors, sigmas and `ok` of the default solve and of the one without the spread."""
    out = {}
    for name, frac in (("spread", _unseen.UNSEEN_FRACTION), ("without", 0.0)):
        with mock.patch.object(_unseen, "UNSEEN_FRACTION", frac):
            pred = localize(logs, patch=patch)
        ok = np.array([e.status == OK for e in pred])
        sigma = np.array([e.sigma_mm if e.sigma_mm is not None else np.nan for e in pred])
        out[name] = (np.hypot(*(pred.xy() - truth).T), sigma, ok)
        if name == "spread":
            named = set(pred.params.get("shape_spread_mm", {}))
            out["unseen"] = np.array([e.sensor in named for e in pred]) & ok
    return out


def cell(pairs: list[tuple[float, bool]]) -> str:
    """RMS error and 2-sigma coverage of ``pairs``, or "-" if there are none."""
    if not pairs:
        return "-"
    a = np.array(pairs, dtype=float)
    return f"{rms(a[:, 0]):.3f} mm, {a[:, 1].mean():.3f}"


def pairs(e: np.ndarray, sigma: np.ndarray, sel: np.ndarray) -> list[tuple[float, bool]]:
    """(error, within 2 sigma) of the sensors ``sel``."""
    return list(zip(e[sel].tolist(), (e[sel] <= 2.0 * sigma[sel]).tolist(), strict=True))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=seed_range, default=range(100, 110), help="default 100-109")
    ap.add_argument(
        "--grids",
        nargs="+",
        type=parse_grid,
        default=[(8, 3), (10, 3), (13, 3), (13, 4), (20, 5)],
        help="NXxNY plans (default 8x3 10x3 13x3 13x4 20x5)",
    )
    args = ap.parse_args(argv)
    print(
        "| grid | patch, probe | ok, spread / without (unseen) | unseen: RMS, within 2 sigma, spread / "
        "without | all ok: RMS, within 2 sigma, spread / without |"
    )
    print("|---|---|---|---|---|")
    pooled = {"spread": [], "without": []}  # the unseen sensors of every row
    for nx, ny in args.grids:
        for pname in ("patch_a", "patch_b"):
            patch = builtin_patch(pname)
            for probe in ("robot", "finger"):
                rows = {"spread": [], "without": []}
                unseen_rows = {"spread": [], "without": []}
                n_unseen = 0
                for seed in args.seeds:
                    s = simulate_session(patch, uniform_points(patch, nx, ny), probe, seed)
                    both = solve_both(s.point_logs(), patch, s.truth)
                    n_unseen += int(both["unseen"].sum())
                    for name in rows:
                        e, sigma, ok = both[name]
                        rows[name] += pairs(e, sigma, ok)
                        unseen_rows[name] += pairs(e, sigma, both["unseen"] & ok)
                for name in pooled:
                    pooled[name] += unseen_rows[name]
                print(
                    f"| {nx}x{ny} | {pname[-1].upper()}, {probe} | {len(rows['spread'])} / "
                    f"{len(rows['without'])} ({n_unseen}) | {cell(unseen_rows['spread'])} / "
                    f"{cell(unseen_rows['without'])} | {cell(rows['spread'])} / "
                    f"{cell(rows['without'])} |",
                    flush=True,
                )
    print(
        f"Every row's unseen sensors ({len(pooled['spread'])}): RMS, within 2 sigma, "
        f"{cell(pooled['spread'])} with the spread, {cell(pooled['without'])} without"
    )


if __name__ == "__main__":
    main()

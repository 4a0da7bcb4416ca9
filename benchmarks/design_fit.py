"""The located sensors against the patch's design (``varskin.design_fit``) on simulated
scenes: how far the fitted turn, stretch and shift stray on unturned scenes (which sets
the warnings' thresholds) and how well they follow a turned, stretched one.

Each scene's layout is built off its design (the simulator's wire offsets and bends), so
the fit to the localized sensors is compared with the same fit to the hidden truth. Printed
per row (Patch A or B, robot or finger, 20 x 5 cell centres, the patch given): the
smallest, largest and 95th-percentile |turn|, the truth's own largest |turn|, the sd and
largest of fitted minus true turn, the sd of fitted minus true stretch, the largest shift,
the fitted turn less the scene's and the fitted shift in units of the sds the fit gives
them (their sd and largest), and how many scenes the fit warned on. Run as ``python
benchmarks/design_fit.py`` (1m29s on one core); ``--seeds 0-39``, ``--turn 2`` and
``--stretch 0.02`` change the scenes.
"""

import _one_core  # noqa: F401  (first: pins BLAS to one thread before numpy loads)

# isort: split
import argparse
from dataclasses import replace

import numpy as np
from localizer_live import seed_range

from varskin.design_fit import fit_design
from varskin.localization import localize
from varskin.patch import builtin_patch
from varskin.predictions import Predictions, SensorEstimate
from varskin.scene import SceneParams
from varskin.simulate import simulate_session, uniform_grid


def as_located(patch, xy) -> Predictions:
    """The hidden truth as if every sensor were located to 0.01 mm."""
    return Predictions(
        "truth",
        [
            SensorEstimate(s.name, float(x), float(y), 0.01, 30.0)
            for s, (x, y) in zip(patch.sensors, xy, strict=True)
        ],
        {},
    )


def row(name: str, probe: str, seeds, params: SceneParams) -> None:
    patch = builtin_patch(name)
    turn, true_turn, stretch, true_stretch, shift, warned = [], [], [], [], [], 0
    z_turn, z_shift = [], []  # (fitted - scene's) turn and shift in their own sds
    for seed in seeds:
        session = simulate_session(patch, uniform_grid(patch, 20, 5), probe, seed, params)
        fit = fit_design(localize(session.point_logs(), patch=patch), patch)
        truth = fit_design(as_located(patch, session.truth), patch)
        turn.append(fit.turn_deg)
        true_turn.append(truth.turn_deg)
        stretch.append(fit.stretch)
        true_stretch.append(truth.stretch)
        shift.append(float(np.hypot(*fit.shift_mm)))
        z_turn.append((fit.turn_deg - params.rotation_deg) / fit.turn_sd_deg)
        z_shift.extend(np.asarray(fit.shift_mm) / np.asarray(fit.shift_sd_mm))
        warned += bool(fit.warnings())
    turn, true_turn = np.array(turn), np.array(true_turn)
    d_stretch = np.array(stretch) - np.array(true_stretch)
    print(
        f"{name} {probe:<6}: |turn| min {np.abs(turn).min():.2f}, max {np.abs(turn).max():.2f}, 95% "
        f"{np.quantile(np.abs(turn), 0.95):.2f} deg (truth's max {np.abs(true_turn).max():.2f}); "
        f"fitted - true turn sd {np.std(turn - true_turn):.2f}, max "
        f"{np.abs(turn - true_turn).max():.2f} deg; stretch sd {100 * np.std(d_stretch):.2f} %; "
        f"shift max {max(shift):.2f} mm; in their sds: turn {_spread(z_turn)}, shift "
        f"{_spread(z_shift)}; warned on {warned} of {len(turn)}",
        flush=True,
    )


def _spread(z) -> str:
    z = np.asarray(z)
    return f"sd {np.std(z):.2f}, max |z| {np.abs(z).max():.2f}"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=seed_range, default=range(0, 40), help="default 0-39")
    ap.add_argument("--turn", type=float, default=0.0, help="the layout's turn, deg (default 0)")
    ap.add_argument("--stretch", type=float, default=0.0, help="relative (default 0)")
    args = ap.parse_args(argv)
    params = replace(SceneParams(), rotation_deg=args.turn, stretch=args.stretch)
    print(
        f"turn {args.turn:g} deg, stretch {args.stretch:g}, seeds {args.seeds.start}-{args.seeds.stop - 1}"
    )
    for name in ("patch_a", "patch_b"):
        for probe in ("robot", "finger"):
            row(name, probe, args.seeds, params)


if __name__ == "__main__":
    main()

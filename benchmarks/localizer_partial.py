"""A partial session's batch solve: how many `ok` calls are far off, with and without the
reported verdict's checks (``_design_reach.unreached_sparse``, with the patch given, and
``_statuses.unrisen_weak``).

A session cut short (a killed process, a stop, ``varskin localize`` on the logs so far)
is solved like a whole one. After the first columns of a serpentine plan most sensors have
only their RX wire's ridge in their maps, and a bump between the probed columns fits it
(docs/localizer.md, Known limits). This solves the first K touches of ``varskin
calibrate``'s 20 x 5 plan (``planning.uniform_points``) for Patch A and B, robot and finger,
and counts, pooled over the seeds, the `ok` calls, those more than 5 mm from the scene's
truth, and the fraction within 2 sigma. Both verdicts come from the same solve: the checks
change no fit, position or sigma, only which `ok` calls are reported `sparse` or `weak`.

Run as ``python benchmarks/localizer_partial.py`` (seeds 0-5 and the patch given: 2m42s on
2026-11-28, beside another benchmark); ``--seeds 0-15``, ``--patch-given no``.
"""

from __future__ import annotations

import _one_core  # noqa: F401  (first: pins BLAS to one thread before numpy loads)

# isort: split
import argparse

import numpy as np
from localizer_live import seed_range

from varskin.localization import peakfit
from varskin.localization._statuses import judge
from varskin.patch import builtin_patch
from varskin.planning import uniform_points
from varskin.predictions import OK
from varskin.simulate import simulate_session

FAR_MM = 5.0
TOUCHES = (10, 15, 20, 30, 40, 60, 100)


def counts(pred, truth: np.ndarray) -> np.ndarray:
    """`ok` calls, those more than FAR_MM off, those within 2 sigma."""
    err = np.hypot(*(pred.xy() - truth).T)
    ok = np.array([e.status == OK for e in pred])
    sigma = np.array([np.nan if e.sigma_mm is None else e.sigma_mm for e in pred])
    return np.array([ok.sum(), (ok & (err > FAR_MM)).sum(), (ok & (err <= 2 * sigma)).sum()])


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=seed_range, default=range(6), help="default 0-5")
    ap.add_argument("--patch-given", choices=("yes", "no"), default="yes")
    args = ap.parse_args(argv)
    seeds = args.seeds
    print(
        f"seeds {seeds[0]}-{seeds[-1]}, patch given: {args.patch_given}; `ok` calls, "
        f"> {FAR_MM:g} mm off, within 2 sigma (pooled)"
    )
    print("| scene | touches | without the reported checks | with them | right calls lost |")
    print("|---|---|---|---|---|")
    for pname in ("patch_a", "patch_b"):
        p = builtin_patch(pname)
        plan = uniform_points(p, 20, 5)
        kw = {"patch": p} if args.patch_given == "yes" else {}
        for probe in ("robot", "finger"):
            tot = {k: np.zeros((2, 3), int) for k in TOUCHES}
            lost = dict.fromkeys(TOUCHES, 0)
            for seed in seeds:
                s = simulate_session(p, plan, probe, seed)
                logs = s.point_logs()
                for k in TOUCHES:
                    loc = peakfit.solved(logs.subset(np.arange(k)), **kw)
                    checked = loc.result()
                    with peakfit._quiet():
                        plain = peakfit._build(loc, *judge(loc))
                    tot[k] += np.stack([counts(plain, s.truth), counts(checked, s.truth)])
                    err = np.hypot(*(plain.xy() - s.truth).T)
                    right = [
                        a.status == OK and b.status != OK and e <= FAR_MM
                        for a, b, e in zip(plain, checked, err, strict=True)
                    ]
                    lost[k] += sum(right)
            for k in TOUCHES:
                cells = [
                    f"{n} ok, {far} off, {cov / max(n, 1):.3f}" for n, far, cov in tot[k].tolist()
                ]
                print(
                    f"| {pname} {probe} | {k} | {cells[0]} | {cells[1]} | {lost[k]} |", flush=True
                )


if __name__ == "__main__":
    main()

"""How the live view (``Localizer.update``) compares with the batch solve, seed by seed.

``update`` is provisional by design (warm, local re-fits; a full re-solve only when the
session doubles) and ``result()`` is the batch solve. This measures what the provisional
view gives up, on Patch B with the layout prior as ``varskin calibrate`` runs it, 20 x 5
grid, robot and finger:

* the last update against ``localize`` on the same logs: the gap (mm, and in units of the
  live sigma_mm) of the sensors `ok` in both, and how many sensors are `ok` in one only;
* over updates 50-100: how many sensors the live view calls `ok`, the RMS error of those
  against the scene's truth (median over updates and seeds), and the fraction of them
  whose error is within 2x their live sigma_mm (pooled over updates and seeds);
* per quarter of the session (updates 1-25, 26-50, 51-75, 76-100), pooled over updates and
  seeds: the `ok` calls, how many of them are more than 5 mm off (a sensor not yet probed
  near, whose "peak" is its RX wire's ridge: docs/localizer.md, Known limits), and the
  fraction within 2 sigma.

Run as ``python benchmarks/localizer_live.py [--seeds 0-15]`` (about 1 s per session).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from varskin.localization import peakfit
from varskin.patch import builtin_patch
from varskin.predictions import OK
from varskin.simulate import simulate_session, uniform_grid

QUARTER = 25  # updates: the 20 x 5 grid's 100 in four parts
FAR_MM = 5.0


def seed_range(text: str) -> range:
    lo, _, hi = text.partition("-")
    return range(int(lo), int(hi or lo) + 1)


def one_session(patch, probe: str, seed: int) -> dict:
    s = simulate_session(patch, uniform_grid(patch, 20, 5), probe=probe, seed=seed)
    logs = s.point_logs()
    loc = peakfit.Localizer(logs.sensors, rest=logs.rest, rest_sd=logs.rest_sd, patch=patch)
    n_ok, live_rms, within = [], [], []
    quarters = np.zeros((4, 3), int)  # per quarter: ok calls, > FAR_MM off, within 2 sigma
    live = None
    for k, log in enumerate(logs.logs(), 1):
        live = loc.update(log)
        ok = np.array([e.status == OK for e in live])
        e = np.hypot(*(live.xy() - s.truth).T)[ok]
        sig = np.array([x.sigma_mm for x in live.estimates], dtype=float)[ok]
        quarters[(k - 1) // QUARTER] += (ok.sum(), (e > FAR_MM).sum(), (e <= 2.0 * sig).sum())
        if k >= 50:
            within += (e <= 2.0 * sig).tolist()
            n_ok.append(int(ok.sum()))
            if ok.any():
                live_rms.append(float(np.sqrt(np.mean(e**2))))
    batch = peakfit.localize(logs, patch=patch)
    ok_l = np.array([e.status == OK for e in live])
    ok_b = np.array([e.status == OK for e in batch])
    both = ok_l & ok_b
    gap = np.hypot(*(live.xy() - batch.xy()).T)[both]
    sig = np.array([e.sigma_mm for e in live.estimates])[both].astype(float)
    return {
        "gap_med": float(np.median(gap)),
        "gap_max": float(gap.max()),
        "gap_sigma": float((gap / sig).max()),
        "one_side": int((ok_l ^ ok_b).sum()),
        "n_ok": n_ok,
        "rms": live_rms,
        "within": within,
        "quarters": quarters,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-15", help="simulator seeds, e.g. 0-15 (default)")
    args = ap.parse_args()
    seeds = seed_range(args.seeds)
    patch = builtin_patch("patch_b")
    for probe in ("robot", "finger"):
        runs = [one_session(patch, probe, seed) for seed in seeds]
        worst = max(runs, key=lambda r: r["gap_sigma"])
        print(
            f"Patch B {probe}, seeds {seeds.start}-{seeds.stop - 1}: last update vs batch: "
            f"gap median {statistics.median(r['gap_med'] for r in runs):.3f} mm, "
            f"max {max(r['gap_max'] for r in runs):.3f} mm, "
            f"max {worst['gap_sigma']:.2f} sigma; "
            f"sensors ok in one only: median {statistics.median(r['one_side'] for r in runs)}, "
            f"max {max(r['one_side'] for r in runs)} of 30; "
            f"updates 50-100: mean ok {np.mean([n for r in runs for n in r['n_ok']]):.1f}, "
            f"live RMS median {np.median([x for r in runs for x in r['rms']]):.3f} mm, "
            f"within 2 sigma {np.mean([x for r in runs for x in r['within']]):.3f}"
        )
        total = sum(r["quarters"] for r in runs)
        for q, (n, far, inside) in enumerate(total):
            print(
                f"  updates {q * QUARTER + 1}-{(q + 1) * QUARTER}: {n} ok calls, "
                f"{far} of them > {FAR_MM:g} mm off, within 2 sigma {inside / max(n, 1):.3f}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())

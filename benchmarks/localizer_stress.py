"""The localizer on scenes unlike the ones it was tuned on: does it stay honest?

Why it exists: issue 3 warns that the product is judged on recordings that are not in this
repository. Every other localizer benchmark uses the simulator's defaults, the 20 x 5 grid
and seeds that tests and tuning never saw. This one moves one knob at a time well past
those defaults (noise, peak, drift, wire displacement, a stretched or turned patch,
footprint spread, response shape, short touches, grid density, scattered touches, the
probe's placement) and asks two questions per variant: how much better than the paper's
method is peakfit, and is it ever *silently* wrong, i.e. ``ok`` with an error above both
2 mm and 3 sigma_mm. A flagged status is an honest answer; a confident wrong position is
not.

Run as ``python benchmarks/localizer_stress.py [--seeds 500:510] [--jobs 2] [--only ...]
[--solver alternate|joint] [--prior patch|inferred|none] [--settle-rounds N]
[--joint-settle-rounds N] [--settling-shift-rms X]`` (2m41s on the 2-core VM with 2 jobs
in session 53; docs/bench/stress.md). Peakfit runs with the layout prior from the patch
(``patch=``), as ``varskin calibrate`` runs it, unless ``--prior`` says otherwise; the
paper method at ppcm 16. Prints one row per variant x patch x probe: located, pooled RMS
of peakfit and of the paper method over the sensors both located, max error, how many
``ok`` sensors are above 2 mm, 2-sigma coverage (over all ``ok`` sensors, then over those
the board's settling was taken out of, ``settling_taken_out_mm``), peakfit's estimate of
the touches' placement scatter, the response shapes its scenes chose (L, G, E:
Lorentzian, Gaussian, exponential, with their counts), and the silent failures; then how
many rows cover outside 0.90-0.98, and the corrected sensors' coverage per probe.
"""

from __future__ import annotations

import _one_core  # noqa: F401  (first: pins BLAS to one thread before numpy loads)

# isort: split
import argparse
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np
from localizer_seeds import add_settle_rounds, settle_params

from varskin.localization import _statuses, localize
from varskin.patch import builtin_patch
from varskin.scene import ProbeModel, SceneParams
from varskin.simulate import simulate_session, uniform_grid

BASE = SceneParams()

# name -> (scene params, grid (nx, ny) or "scatter100")
VARIANTS: dict[str, tuple[SceneParams, tuple[int, int] | str]] = {
    "defaults": (BASE, (20, 5)),
    "noise x3": (replace(BASE, noise_median=14.7, noise_range=(10.8, 20.7)), (20, 5)),
    # The paper reports 61-65 dB SNR on its patches; the defaults give about 31 dB.
    "noise / 10": (replace(BASE, noise_median=0.49, noise_range=(0.36, 0.69)), (20, 5)),
    "peak / 2": (replace(BASE, peak_median=85.0, peak_range=(43.0, 293.0)), (20, 5)),
    "drift x2, fast": (replace(BASE, drift_sd=90.0, drift_max=240.0, drift_tau_s=20.0), (20, 5)),
    "wires off 1.5 mm": (replace(BASE, wire_offset_sd_mm=1.5, wire_bend_sd_mm=0.75), (20, 5)),
    # A silicone patch laid on the bench 2 % longer and wider than its design (the design
    # map's scale term is what follows it; docs/benchmarks.md, "A stretched patch").
    "stretched 2%": (replace(BASE, stretch=0.02), (20, 5)),
    # The registration's residual rotation, about its worst on noisy images (docs/benchmarks.md,
    # "Patch registration from ArUco markers": 0.62 degrees at 20 grey levels).
    "rotated 0.5 deg": (replace(BASE, rotation_deg=0.5), (20, 5)),
    "widths spread x3": (replace(BASE, width_spread=0.36, anisotropy_spread=0.3), (20, 5)),
    "coupling x3": (replace(BASE, wire_coupling=0.12), (20, 5)),
    "gaussian": (replace(BASE, shape="gaussian"), (20, 5)),
    "exponential": (replace(BASE, shape="exponential"), (20, 5)),
    "8 frames/touch": (replace(BASE, samples_per_touch=(8, 8)), (20, 5)),
    "grid 12x3": (BASE, (12, 3)),
    "grid 30x8": (BASE, (30, 8)),
    "scatter 100": (BASE, "scatter100"),
    # The probe, not the skin: each lands twice as far off (finger 2 mm per axis, which is
    # how "+-2 mm" reads if it is one sd; robot 0.1 mm).
    "placement x2": (BASE, (20, 5)),
}
PLACEMENT_FACTOR = {"placement x2": 2.0}


def _points(patch, grid, seed):
    if grid == "scatter100":
        rng = np.random.default_rng([seed, 7])
        m = 3.0
        return np.column_stack(
            [
                rng.uniform(m, patch.length_mm - m, 100),
                rng.uniform(m, patch.width_mm - m, 100),
            ]
        )
    return uniform_grid(patch, *grid)


def _variant_names(only: str) -> list[str]:
    """``--only`` split at commas, except inside a variant's own name ("drift x2, fast")."""
    names: list[str] = []
    for part in (p.strip() for p in only.split(",")):
        if names and names[-1] not in VARIANTS and f"{names[-1]}, {part}" in VARIANTS:
            names[-1] = f"{names[-1]}, {part}"
        elif part:
            names.append(part)
    return names


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")


def one_scene(job):
    variant, pname, probe, seed, solver, prior, settle, shift_rms = job
    _statuses.SETTLING_SHIFT_RMS = shift_rms
    params, grid = VARIANTS[variant]
    patch = builtin_patch(pname)
    model = ProbeModel.named(probe)
    model = replace(
        model, placement_sd_mm=model.placement_sd_mm * PLACEMENT_FACTOR.get(variant, 1.0)
    )
    s = simulate_session(patch, _points(patch, grid, seed), model, seed, params)
    logs = s.point_logs()
    kw = {"patch": patch} if prior == "patch" else {"infer_wires": prior == "inferred"}
    kw.update(settle)
    pf = localize(logs, solver=solver, **kw)
    pp = localize(logs, method="paper", ppcm=16)
    ef = np.linalg.norm(pf.xy() - s.truth, axis=1)
    ep = np.linalg.norm(pp.xy() - s.truth, axis=1)
    sig = np.array([e.sigma_mm if e.status == "ok" else np.nan for e in pf])
    ok = np.isfinite(ef)
    both = ok & np.isfinite(ep)
    taken_out = pf.params.get("settling_taken_out_mm", {})
    corrected = np.array([e.sensor in taken_out for e in pf])
    silent = [
        (seed, pf.estimates[i].sensor, float(ef[i]), float(sig[i]))
        for i in np.flatnonzero(ok)
        if ef[i] > 2.0 and ef[i] > 3 * sig[i]
    ]
    return {
        "key": (variant, pname, probe),
        "n": len(ef),
        "ok": int(ok.sum()),
        "ef": ef[ok],
        "cover": (ef[ok] <= 2 * sig[ok]),
        "corrected": corrected[ok],
        "ef_both": ef[both],
        "ep_both": ep[both],
        "silent": silent,
        "place_sd": pf.params["touch_placement_sd_mm"],
        "shape": pf.params["response_shape"],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="500:510", help="first:end (end excluded), default 500:510")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--only", default="", help="comma-separated variant names (default all)")
    ap.add_argument(
        "--solver",
        default="alternate",
        choices=("alternate", "joint"),
        help="peakfit's batch solver (default alternate, the default of `localize`)",
    )
    ap.add_argument(
        "--prior",
        default="patch",
        choices=("patch", "inferred", "none"),
        help="peakfit's layout prior: from the patch (default, as `varskin calibrate` runs "
        "it), from wires inferred without a patch (`varskin localize` without --patch), or none",
    )
    add_settle_rounds(ap)
    ap.add_argument(
        "--settling-shift-rms",
        type=float,
        default=_statuses.SETTLING_SHIFT_RMS,
        help="the error of the settling taken out of a sensor's readings, as a multiple of "
        f"how far it moved the fit (default {_statuses.SETTLING_SHIFT_RMS:g}; 0: not in the "
        "error bar)",
    )
    args = ap.parse_args()
    a, b = (int(v) for v in args.seeds.split(":"))
    names = _variant_names(args.only) or list(VARIANTS)
    unknown = [v for v in names if v not in VARIANTS]
    if unknown:
        ap.error(f"--only: unknown variant(s) {unknown}; known: {', '.join(VARIANTS)}")
    jobs = [
        (v, pn, pr, seed, args.solver, args.prior, settle_params(args), args.settling_shift_rms)
        for v in names
        for pn in ("patch_a", "patch_b")
        for pr in ("robot", "finger")
        for seed in range(a, b)
    ]
    rows: dict = {}
    with ProcessPoolExecutor(args.jobs) as pool:
        for r in pool.map(one_scene, jobs, chunksize=2):
            rows.setdefault(r["key"], []).append(r)
    print(
        "| variant | patch | probe | located | peakfit RMS | paper RMS (same sensors) | ratio "
        "| max | ok > 2 mm | 2 sigma | 2 sigma, settling taken out (sensors) "
        "| placement sd, estimated (median) | shape chosen | silent failures |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    outside = 0
    pooled: dict[str, list] = {"robot": [], "finger": []}
    for key, rs in rows.items():
        ok = sum(r["ok"] for r in rs)
        n = sum(r["n"] for r in rs)
        ef = np.concatenate([r["ef"] for r in rs])
        cov = np.concatenate([r["cover"] for r in rs])
        corr = np.concatenate([r["corrected"] for r in rs])
        corr_cov = f"{cov[corr].mean():.3f} ({corr.sum()})" if corr.any() else "- (0)"
        outside += not 0.90 <= cov.mean() <= 0.98
        pooled.setdefault(key[2], []).append(cov[corr])
        fb = np.concatenate([r["ef_both"] for r in rs])
        pb = np.concatenate([r["ep_both"] for r in rs])
        silent = [s for r in rs for s in r["silent"]]
        desc = ", ".join(
            f"{seed}:{name} {e:.1f} mm (sigma {sg:.2f})" for seed, name, e, sg in silent
        )
        shapes = [r["shape"] for r in rs]
        chosen = " ".join(f"{sh[0].upper()}{shapes.count(sh)}" for sh in sorted(set(shapes)))
        print(
            f"| {key[0]} | {key[1][-1].upper()} | {key[2]} | {ok}/{n} | {_rms(ef):.3f} mm "
            f"| {_rms(pb):.3f} mm | {_rms(fb) / _rms(pb):.2f} | {ef.max():.2f} mm "
            f"| {int((ef > 2.0).sum())} | {cov.mean():.3f} | {corr_cov} "
            f"| {np.median([r['place_sd'] for r in rs]):.2f} mm | {chosen} "
            f"| {len(silent)}{': ' + desc if desc else ''} |",
            flush=True,
        )
    print(f"\nrows with 2-sigma coverage outside 0.90-0.98: {outside} of {len(rows)}")
    for probe, parts in pooled.items():
        c = np.concatenate(parts) if parts else np.array([])
        if c.size:
            print(
                f"{probe}: 2 sigma covers {c.mean():.3f} of {c.size} ok sensors "
                "with the settling taken out"
            )


if __name__ == "__main__":
    main()

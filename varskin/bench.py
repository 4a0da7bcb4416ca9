"""Speed versus error of the localization methods on seeded simulated sessions.

Why it exists: claims that one method beats another need the same data, the same clock
and the paper's own axes (eta x ppcm, number of point logs). ``varskin bench`` runs every
method over simulated Patch A and B sessions, finger and robot probing, and reports the
paper's RMS = sqrt(sum e^2 / (N-1)), mean and max error and median run times, with the
paper method (eta 0.65, 128 ppcm) timed on the same data as the reference.

Subsets of 20..100 point logs are *uniform grids of about that many points* over the whole
patch (100: 20x5, 80: 16x5, 60: 12x5, 40: 10x4, 20: 10x2), each its own simulated session
with the same scene seed, as in the paper's "point log grid plan of uniform locations".
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from varskin.evaluate import rms_n_minus_1
from varskin.localization import METHODS
from varskin.localization import localize as run_method
from varskin.patch import builtin_patch
from varskin.predictions import OK
from varskin.progress import Progress
from varskin.simulate import simulate_session, uniform_grid

GRIDS = {100: (20, 5), 80: (16, 5), 60: (12, 5), 40: (10, 4), 20: (10, 2)}
# The paper's Fig. "error versus number of point logs" (finger, eta 0.65, 128 ppcm), mm.
PUBLISHED = {
    "patch_b": {100: 1.58, 80: 1.61, 60: 2.53, 40: 4.58, 20: 9.00},
    "patch_a": {100: 2.68, 80: 2.87, 60: 3.11, 40: 4.16, 20: 7.69},
}
PAPER_DEFAULT = {"eta": 0.65, "ppcm": 128.0}


@dataclass(frozen=True)
class BenchConfig:
    patches: tuple[str, ...] = ("patch_a", "patch_b")
    probes: tuple[str, ...] = ("finger", "robot")
    seeds: tuple[int, ...] = (100, 101)
    ppcm: tuple[float, ...] = (4.0, 16.0, 64.0, 128.0)
    eta: tuple[float, ...] = (0.50, 0.55, 0.60, 0.65, 0.70, 0.75, 0.80)
    n_logs: tuple[int, ...] = (20, 40, 60, 80, 100)
    repeats: int = 3
    reference: dict = field(default_factory=lambda: dict(PAPER_DEFAULT))

    @classmethod
    def quick(cls, seeds: tuple[int, ...] = (100,), repeats: int = 1) -> BenchConfig:
        return cls(
            patches=("patch_b",),
            probes=("finger", "robot"),
            seeds=seeds,
            ppcm=(4.0, 16.0),
            eta=(0.55, 0.65, 0.75),
            n_logs=(20, 60, 100),
            repeats=repeats,
            reference={"eta": 0.65, "ppcm": 16.0},
        )


@dataclass
class Run:
    method: str
    params: dict
    patch: str
    probe: str
    seed: int
    n_logs: int
    rms: float | None
    mean: float | None
    max: float | None
    n_ok: int
    n_sensors: int
    time_ms: float  # median over repeats

    @property
    def label(self) -> str:
        if not self.params:
            return self.method
        return self.method + " " + ",".join(f"{k}={_num(v)}" for k, v in self.params.items())


def _num(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _score(pred, truth: np.ndarray) -> tuple[float | None, float | None, float | None, int]:
    e = np.hypot(*(pred.xy() - truth).T)
    ok = np.array([p.status == OK for p in pred]) & np.isfinite(e)
    e = e[ok]
    if not len(e):
        return None, None, None, 0
    return rms_n_minus_1(e), float(e.mean()), float(e.max()), int(ok.sum())


def _timed(logs, method: str, params: dict, repeats: int):
    times = []
    pred = None
    for _ in range(max(repeats, 1)):
        t0 = time.perf_counter()
        pred = run_method(logs, method=method, **params)
        times.append((time.perf_counter() - t0) * 1000.0)
    return pred, statistics.median(times)


def plan(cfg: BenchConfig) -> list[tuple[str, dict, int]]:
    """(method, params, n_logs) to run on every scene: the paper's map at 100 logs, the
    reference and every other method at every number of logs (peakfit also with the
    patch's wires for its layout prior, ``patch=wires``)."""
    jobs: list[tuple[str, dict, int]] = []
    full_n = max(cfg.n_logs)
    if "paper" in METHODS:
        for ppcm in cfg.ppcm:
            for eta in cfg.eta:
                jobs.append(("paper", {"eta": eta, "ppcm": ppcm}, full_n))
        for n in cfg.n_logs:
            if n != full_n:
                jobs.append(("paper", dict(cfg.reference), n))
    for name in METHODS:
        if name == "paper":
            continue
        for n in cfg.n_logs:
            jobs.append((name, {}, n))
            if name == "peakfit":
                # The same method given the patch's wiring: the optional layout prior.
                jobs.append((name, {"patch": "wires"}, n))
    return jobs


def run_bench(cfg: BenchConfig, progress: bool | None = None) -> list[Run]:
    jobs = plan(cfg)
    scenes = [(p, pr, s) for p in cfg.patches for pr in cfg.probes for s in cfg.seeds]
    total = len(scenes) * len(jobs)
    runs: list[Run] = []
    with Progress(total, "bench", enabled=progress) as bar:
        for patch_name, probe, seed in scenes:
            patch = builtin_patch(patch_name)
            sessions = {}
            for n in sorted({n for _, _, n in jobs}):
                nx, ny = GRIDS[n]
                s = simulate_session(patch, uniform_grid(patch, nx, ny), probe=probe, seed=seed)
                sessions[n] = (s.point_logs(), s.truth)
            for method, params, n in jobs:
                logs, truth = sessions[n]
                call = {k: (patch if v == "wires" else v) for k, v in params.items()}
                pred, ms = _timed(logs, method, call, cfg.repeats)
                rms, mean, mx, n_ok = _score(pred, truth)
                runs.append(
                    Run(
                        method,
                        params,
                        patch_name,
                        probe,
                        seed,
                        n,
                        rms,
                        mean,
                        mx,
                        n_ok,
                        logs.n_sensors,
                        ms,
                    )
                )
                bar.update(1, suffix=f"{patch_name} {probe} {method}")
    return runs


# --- summaries ---------------------------------------------------------------------------


def _agg(runs: list[Run]) -> dict:
    """Median over seeds of each scene's RMS, pooled mean/max, median time."""
    vals = [r.rms for r in runs if r.rms is not None]
    return {
        "rms": statistics.median(vals) if vals else None,
        "mean": statistics.mean([r.mean for r in runs if r.mean is not None]) if vals else None,
        "max": max((r.max for r in runs if r.max is not None), default=None),
        "time_ms": statistics.median([r.time_ms for r in runs]),
        "n_ok": sum(r.n_ok for r in runs),
        "n": sum(r.n_sensors for r in runs),
    }


def table_rows(runs: list[Run], cfg: BenchConfig) -> list[dict]:
    """One row per (method, params, patch, probe, n_logs), with the time ratio to the
    reference paper run (same scenes, same n_logs, same process)."""
    groups: dict[tuple, list[Run]] = {}
    for r in runs:
        groups.setdefault((r.label, r.method, r.patch, r.probe, r.n_logs), []).append(r)
    ref_label = Run("paper", dict(cfg.reference), "", "", 0, 0, None, None, None, 0, 0, 0).label
    rows = []
    for (label, method, patch, probe, n), rs in groups.items():
        a = _agg(rs)
        ref = groups.get((ref_label, "paper", patch, probe, n))
        ratio = None
        ref_rms = None
        if ref:
            ra = _agg(ref)
            ratio = a["time_ms"] / ra["time_ms"] if ra["time_ms"] > 0 else None
            ref_rms = ra["rms"]
        rows.append(
            {
                "label": label,
                "method": method,
                "patch": patch,
                "probe": probe,
                "n_logs": n,
                **a,
                "time_vs_paper": ratio,
                "rms_vs_paper": (a["rms"] / ref_rms) if a["rms"] and ref_rms else None,
            }
        )
    rows.sort(
        key=lambda r: (r["patch"], r["probe"], -r["n_logs"], r["method"] != "paper", r["label"])
    )
    return rows


def _fmt(v, d=2) -> str:
    return "-" if v is None else f"{v:.{d}f}"


def format_table(rows: list[dict], markdown: bool = False) -> str:
    head = [
        "method",
        "patch",
        "probe",
        "logs",
        "RMS mm",
        "mean mm",
        "max mm",
        "time ms",
        "time/paper",
        "RMS/paper",
        "ok",
    ]
    lines = []
    body = [
        [
            r["label"],
            r["patch"],
            r["probe"],
            str(r["n_logs"]),
            _fmt(r["rms"]),
            _fmt(r["mean"]),
            _fmt(r["max"]),
            _fmt(r["time_ms"], 1),
            _fmt(r["time_vs_paper"], 3),
            _fmt(r["rms_vs_paper"]),
            f"{r['n_ok']}/{r['n']}",
        ]
        for r in rows
    ]
    if markdown:
        lines.append("| " + " | ".join(head) + " |")
        lines.append("|" + "---|" * len(head))
        lines += ["| " + " | ".join(b) + " |" for b in body]
    else:
        widths = [max(len(h), *(len(b[i]) for b in body)) for i, h in enumerate(head)]
        lines.append("  ".join(h.ljust(w) for h, w in zip(head, widths, strict=False)))
        lines += ["  ".join(c.ljust(w) for c, w in zip(b, widths, strict=False)) for b in body]
    return "\n".join(lines)


# --- figures -----------------------------------------------------------------------------


def _figure(w=7.0, h=4.5):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), dpi=110)
    FigureCanvasAgg(fig)
    return fig


def plot_pareto(runs: list[Run], path: Path) -> None:
    """Error versus time at the most point logs, every method and parameter set."""
    n = max(r.n_logs for r in runs)
    groups: dict[tuple, list[Run]] = {}
    for r in runs:
        if r.n_logs == n:
            groups.setdefault((r.label, r.method), []).append(r)
    pts = []
    for (label, method), rs in groups.items():
        a = _agg(rs)
        if a["rms"] is not None:
            pts.append((a["time_ms"], a["rms"], label, method))
    fig = _figure()
    ax = fig.add_subplot(1, 1, 1)
    for method, marker in (("paper", "o"), *((m, "*") for m in METHODS if m != "paper")):
        xs = [p[0] for p in pts if p[3] == method]
        ys = [p[1] for p in pts if p[3] == method]
        ax.scatter(xs, ys, marker=marker, s=40 if marker == "o" else 160, label=method, alpha=0.8)
    front, best = [], float("inf")
    for t, e, label, _ in sorted(pts):
        if e < best:
            best = e
            front.append((t, e, label))
    ax.step(
        [p[0] for p in front],
        [p[1] for p in front],
        where="post",
        color="k",
        lw=1,
        label="Pareto front",
    )
    for t, e, label in front:
        ax.annotate(label, (t, e), fontsize=7, xytext=(4, 4), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_xlabel("time per solve, ms (median)")
    ax.set_ylabel("RMS error, mm (median over scenes)")
    ax.set_title(f"Speed versus error, {n} point logs, all patches and probes")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)


def plot_error_vs_logs(runs: list[Run], cfg: BenchConfig, path: Path) -> None:
    """RMS versus number of point logs per patch, beside the paper's published curve."""
    ref_label = Run("paper", dict(cfg.reference), "", "", 0, 0, None, None, None, 0, 0, 0).label
    patches = sorted({r.patch for r in runs})
    fig = _figure(5.0 * len(patches), 4.2)
    for i, patch in enumerate(patches):
        ax = fig.add_subplot(1, len(patches), i + 1)
        pub = PUBLISHED.get(patch)
        if pub:
            ns = sorted(pub)
            ax.plot(ns, [pub[n] for n in ns], "k--", marker="s", label="paper, published (finger)")
        for label, style in ((ref_label, "o-"), *((m, "*-") for m in METHODS if m != "paper")):
            for probe, color in (("finger", "C0"), ("robot", "C1")):
                ns = sorted({r.n_logs for r in runs if r.patch == patch})
                ys = []
                for n in ns:
                    rs = [
                        r
                        for r in runs
                        if r.patch == patch
                        and r.probe == probe
                        and r.n_logs == n
                        and r.label == label
                    ]
                    ys.append(_agg(rs)["rms"] if rs else None)
                if any(y is not None for y in ys):
                    xs = [n for n, y in zip(ns, ys, strict=False) if y is not None]
                    ax.plot(
                        xs,
                        [y for y in ys if y is not None],
                        style,
                        color=color if label != ref_label else "C3" if probe == "finger" else "C2",
                        label=f"{label} ({probe})",
                    )
        ax.set_xlabel("number of point logs (uniform grid)")
        ax.set_ylabel("RMS error, mm")
        ax.set_title(patch)
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)


def plot_eta_ppcm(runs: list[Run], path: Path) -> None:
    """The paper's figure: its error over eta x ppcm (most point logs, finger probing)."""
    n = max(r.n_logs for r in runs)
    sel = [r for r in runs if r.method == "paper" and r.n_logs == n]
    probes = (
        "finger" if any(r.probe == "finger" for r in sel) else sel[0].probe if sel else "finger"
    )
    sel = [r for r in sel if r.probe == probes]
    etas = sorted({r.params["eta"] for r in sel})
    ppcms = sorted({r.params["ppcm"] for r in sel})
    grid = np.full((len(etas), len(ppcms)), np.nan)
    for i, eta in enumerate(etas):
        for j, ppcm in enumerate(ppcms):
            rs = [r for r in sel if r.params["eta"] == eta and r.params["ppcm"] == ppcm]
            v = _agg(rs)["rms"] if rs else None
            grid[i, j] = np.nan if v is None else v
    ours = [r for r in runs if r.method != "paper" and r.n_logs == n and r.probe == probes]
    fig = _figure(6.0, 4.5)
    ax = fig.add_subplot(1, 1, 1)
    im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis")
    ax.set_xticks(range(len(ppcms)), [f"{p:g}" for p in ppcms])
    ax.set_yticks(range(len(etas)), [f"{e:.2f}" for e in etas])
    for i in range(len(etas)):
        for j in range(len(ppcms)):
            if np.isfinite(grid[i, j]):
                ax.text(j, i, f"{grid[i, j]:.2f}", ha="center", va="center", fontsize=7, color="w")
    ax.set_xlabel("interpolation resolution, pixels per cm")
    ax.set_ylabel("threshold eta")
    extra = ""
    if ours:
        extra = f"; {ours[0].method}: {_agg(ours)['rms']:.2f} mm"
    ax.set_title(f"Paper method RMS (mm), {n} logs, {probes}{extra}", fontsize=9)
    fig.colorbar(im, ax=ax, label="RMS error, mm")
    fig.tight_layout()
    fig.savefig(path)


def write_outputs(runs: list[Run], cfg: BenchConfig, out: Path, command: str) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "pareto.png", out / "error_vs_logs.png", out / "eta_ppcm_map.png"]
    plot_pareto(runs, paths[0])
    plot_error_vs_logs(runs, cfg, paths[1])
    plot_eta_ppcm(runs, paths[2])
    rows = table_rows(runs, cfg)
    import platform

    md = [
        "# Localization benchmark",
        "",
        f"Command: `{command}`",
        "",
        f"Machine: {platform.machine()}, {platform.processor() or 'cpu'}, Python "
        f"{platform.python_version()}, numpy {np.__version__}; times are medians of "
        f"{cfg.repeats} repeat(s) per scene, then the median over scenes.",
        f"Scenes: {', '.join(cfg.patches)} x {', '.join(cfg.probes)} x seeds "
        f"{', '.join(map(str, cfg.seeds))}; RMS = sqrt(sum e^2/(N-1)) over ok sensors, median "
        "over seeds; mean/max pooled. time/paper and RMS/paper are against "
        f"paper eta={_num(cfg.reference['eta'])}, ppcm={_num(cfg.reference['ppcm'])} on the "
        "same data in the same run. Subsets of point logs are uniform grids "
        f"({', '.join(f'{n}: {a}x{b}' for n, (a, b) in GRIDS.items() if n in cfg.n_logs)}).",
        "",
        format_table(rows, markdown=True),
        "",
        "Figures: `pareto.png`, `error_vs_logs.png`, `eta_ppcm_map.png`.",
        "",
    ]
    (out / "results.md").write_text("\n".join(md))
    paths.append(out / "results.md")
    return paths

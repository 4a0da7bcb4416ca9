"""Adaptive versus uniform touch plans: touches and rig time to reach 0.5 mm RMS.

Why: issue 6 asks whether an adaptive plan (a coarse pass, then each touch where it shrinks
the localizer's uncertainty most) calibrates a patch with at most half the touches of the
uniform grid. This script measures it on simulated Patch B probed by the robot, seed by
seed: uniform grids of increasing size are localized in one batch each; the adaptive
planner is driven touch by touch, as a session drives it, with a ``Localizer`` updated
after every touch. Both build their point logs the same way, touch by touch from
``Scene.sample`` (``varskin.simulate.simulate_touch``): a no-contact baseline of 50 frames,
then per touch 8 frames (a 1 s dwell at 8 frames/s) with the probe's placement error and
gain variation. The goal is RMS <= 0.5 mm against the scene's truth with every sensor
located. Rig time comes from ``robot.rig_time`` (the launch file's touch spec, envelope
and registered frame) when that module is there.

    python benchmarks/adaptive_plan.py --jobs 2             # 8 fresh seeds, ~70 s on 2 cores
    python benchmarks/adaptive_plan.py --first-seed 0       # the seeds the defaults came from
    python benchmarks/adaptive_plan.py --seeds 2 --no-plot  # a quick look
"""

from __future__ import annotations

import _one_core  # noqa: F401  (first: pins BLAS to one thread before numpy loads)

# isort: split
import argparse
import dataclasses
import math
import time
from dataclasses import dataclass, field
from multiprocessing import Pool
from pathlib import Path

import numpy as np

from varskin.cli.simulate import parse_grid
from varskin.localization import localize
from varskin.localization.peakfit import Localizer
from varskin.patch import Patch, resolve_patch
from varskin.planning import AdaptivePlanner, TouchOutcome, uniform_points
from varskin.pointlogs import PointLog, PointLogs
from varskin.predictions import OK, Predictions
from varskin.scene import ProbeModel, Scene
from varskin.simulate import BASELINE_SAMPLES, FRAME_RATE_HZ, simulate_touch

ROOT = Path(__file__).resolve().parent.parent
GOAL_RMS_MM = 0.5
FALLBACK_TOUCH_S = 2.5  # simulated clock per touch without a rig-time model (dwell + move)


# --- rig time ---------------------------------------------------------------------------


@dataclass
class RigModel:
    """Real-rig seconds per touch, from ``robot.rig_time`` and a launch file (or absent)."""

    launch: str
    dwell_s: float
    available: bool = False
    why: str = ""
    _frame: object = None
    _spec: object = None
    _envelope: object = None
    _estimate: object = None

    def __post_init__(self) -> None:
        try:
            from robot.launch import load_launch
            from robot.rig_time import estimate_plan_time
        except ImportError as e:
            self.why = f"robot.rig_time not importable ({e})"
            return
        cfg = load_launch(
            ROOT / self.launch if not Path(self.launch).is_absolute() else self.launch
        )
        self._frame = cfg.frame
        # The simulated touch dwells for its 8 frames; the rig's dwell must match it.
        self._spec = dataclasses.replace(cfg.touch, dwell_s=self.dwell_s)
        self._envelope = cfg.envelope
        self._estimate = estimate_plan_time
        self.available = True

    def per_touch_s(self, points_mm: np.ndarray) -> np.ndarray:
        """(K,) seconds of each touch in order, its travel from the previous one included."""
        if not self.available or len(points_mm) == 0:
            return np.full(len(points_mm), np.nan)
        pts = self._frame.to_base(np.asarray(points_mm, float).reshape(-1, 2))
        return self._estimate(pts, self._spec, self._envelope).per_touch_s

    def next_touch_s(self, prev_mm, cur_mm) -> float:
        if not self.available:
            return FALLBACK_TOUCH_S
        if prev_mm is None:
            return float(self.per_touch_s(np.array([cur_mm]))[0])
        return float(self.per_touch_s(np.array([prev_mm, cur_mm]))[1])


# --- simulation -------------------------------------------------------------------------


class SimSession:
    """One simulated session on a seeded scene: baseline, then touches on demand."""

    def __init__(self, patch: Patch, seed: int, frames: int, rig: RigModel) -> None:
        self.patch = patch
        self.scene = Scene.create(patch, seed)
        self.probe = ProbeModel.named("robot")
        # Every run on a seed draws the same baseline and its own touch noise from here.
        self.rng = np.random.default_rng([seed, 1])
        self.frames = frames
        self.rig = rig
        bt = np.arange(BASELINE_SAMPLES) / FRAME_RATE_HZ
        base = self.scene.sample(None, None, 0.0, self.probe, bt, self.rng)
        self.rest = base.mean(axis=0)
        self.rest_sd = base.std(axis=0, ddof=1)
        self.t = float(bt[-1]) + 2.0
        self.prev: tuple[float, float] | None = None
        self.logs: list[PointLog] = []

    def touch(self, x: float, y: float) -> PointLog:
        log = simulate_touch(
            self.scene,
            self.probe,
            x,
            y,
            self.t,
            self.rng,
            n_samples=self.frames,
            touch=len(self.logs) + 1,
            rest=self.rest,
        )
        # Drift runs on the rig's clock: the next touch starts when this one and the
        # travel to the next are done.
        self.t += self.rig.next_touch_s(self.prev, (x, y))
        self.prev = (x, y)
        self.logs.append(log)
        return log

    def point_logs(self) -> PointLogs:
        return PointLogs.from_logs(self.patch.names, self.logs, self.rest, self.rest_sd)


def score(pred: Predictions, truth: np.ndarray) -> tuple[float, int]:
    """RMS (mm) over the located sensors, sqrt(sum e^2 / (n - 1)) as in the bench, and n."""
    e = np.hypot(*(pred.xy() - truth).T)
    e = e[np.isfinite(e)]
    if e.size < 2:
        return float("nan"), int(e.size)
    return float(np.sqrt((e**2).sum() / (e.size - 1))), int(e.size)


def max_sigma(pred: Predictions) -> float:
    s = [e.sigma_mm for e in pred if e.status == OK and e.sigma_mm is not None]
    return max(s) if len(s) == len(pred) else float("inf")


# --- the two planners -------------------------------------------------------------------


@dataclass
class UniformRun:
    nx: int
    ny: int
    touches: int
    rms: float
    located: int
    time_s: float


@dataclass
class SessionRun:
    """The default uniform plan run as a session: the batch result after every touch."""

    nx: int
    ny: int
    rms: list[float] = field(default_factory=list)
    located: list[int] = field(default_factory=list)
    cum_time_s: list[float] = field(default_factory=list)


@dataclass
class AdaptiveRun:
    rms: list[float] = field(default_factory=list)  # after touch k+1 (batch solve)
    located: list[int] = field(default_factory=list)
    sigma: list[float] = field(default_factory=list)  # largest sigma_mm (inf: not all ok)
    cum_time_s: list[float] = field(default_factory=list)
    points: list[tuple[float, float]] = field(default_factory=list)
    stop_reason: str = ""
    plan_ms: list[float] = field(default_factory=list)
    localize_ms: list[float] = field(default_factory=list)


def run_uniform(patch: Patch, seed: int, nx: int, ny: int, args, rig: RigModel) -> UniformRun:
    pts = uniform_points(patch, nx, ny, args.margin)
    s = SimSession(patch, seed, args.frames, rig)
    for x, y in pts:
        s.touch(float(x), float(y))
    pred = localize(s.point_logs(), method="peakfit", patch=patch)
    rms, n = score(pred, s.scene.true_xy)
    return UniformRun(nx, ny, len(pts), rms, n, float(np.nansum(rig.per_touch_s(pts))))


def run_uniform_session(
    patch: Patch, seed: int, nx: int, ny: int, args, rig: RigModel
) -> SessionRun:
    """Touch the grid in its planned (serpentine) order, as ``varskin calibrate`` does."""
    pts = uniform_points(patch, nx, ny, args.margin)
    s = SimSession(patch, seed, args.frames, rig)
    loc = Localizer(patch.names, s.rest, s.rest_sd, patch=patch)
    out = SessionRun(nx, ny)
    out.cum_time_s = list(np.cumsum(rig.per_touch_s(pts)))
    for x, y in pts:
        loc.update(s.touch(float(x), float(y)))
        rms, n = score(loc.result(), s.scene.true_xy)
        out.rms.append(rms)
        out.located.append(n)
    return out


def planner_for(patch: Patch, args) -> AdaptivePlanner:
    return AdaptivePlanner(
        patch,
        coarse=args.coarse,
        budget=args.budget,
        target_sigma_mm=args.target,
        margin_mm=args.margin,
    )


def run_adaptive(patch: Patch, seed: int, args, rig: RigModel) -> AdaptiveRun:
    s = SimSession(patch, seed, args.frames, rig)
    loc = Localizer(patch.names, s.rest, s.rest_sd, patch=patch)
    planner = planner_for(patch, args)
    out = AdaptiveRun()
    gen = planner.plan()
    touch = next(gen)
    clock = 0.0
    while True:
        log = s.touch(touch.x_mm, touch.y_mm)
        t0 = time.perf_counter()
        pred = loc.update(log)
        if args.planner_input == "result":
            pred = loc.result()  # the batch solve of every log so far
        out.localize_ms.append(1000 * (time.perf_counter() - t0))
        # What the calibration would report if it stopped here: the batch solve.
        batch = pred if args.planner_input == "result" else loc.result()
        rms, n = score(batch, s.scene.true_xy)
        out.rms.append(rms)
        out.located.append(n)
        out.sigma.append(max_sigma(batch))
        out.points.append((touch.x_mm, touch.y_mm))
        prev = out.points[-2] if len(out.points) > 1 else None
        clock += rig.next_touch_s(prev, out.points[-1]) if rig.available else float("nan")
        out.cum_time_s.append(clock)
        t0 = time.perf_counter()
        try:
            touch = gen.send(TouchOutcome(touch, True, pred))
        except StopIteration:
            break
        if touch.phase == "adaptive":  # the coarse pass costs nothing to plan
            out.plan_ms.append(1000 * (time.perf_counter() - t0))
    out.stop_reason = planner.stop_reason or ""
    return out


def _seed_job(job):
    seed, args = job
    patch = resolve_patch(args.patch)
    rig = RigModel(args.launch, args.frames / FRAME_RATE_HZ)
    grids = [(nx, ny) for nx in range(args.nx[0], args.nx[1] + 1) for ny in args.ny]
    grids.sort(key=lambda g: (g[0] * g[1], g[0]))
    uniform = [run_uniform(patch, seed, nx, ny, args, rig) for nx, ny in grids]
    adaptive = run_adaptive(patch, seed, args, rig)
    session = run_uniform_session(patch, seed, *args.session_grid, args, rig)
    return seed, uniform, adaptive, session


# --- report -----------------------------------------------------------------------------


def goal(rms: float, located: int, n: int) -> bool:
    return located == n and np.isfinite(rms) and rms <= GOAL_RMS_MM


def first_goal(run: AdaptiveRun | SessionRun, n: int) -> int | None:
    for k, (r, m) in enumerate(zip(run.rms, run.located, strict=True)):
        if goal(r, m, n):
            return k + 1
    return None


def median_never_inf(values) -> float | None:
    """Median where None (a run that never reached the goal) counts as worse than all: inf."""
    v = [np.inf if x is None else x for x in values]
    return float(np.median(v)) if v else None


def fmt(v, digits=0, unit=""):
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    return f"{v:.{digits}f}{unit}"


def report(results, patch: Patch, args, rig: RigModel) -> list[str]:
    n = len(patch.sensors)
    lines = []
    rows = []
    for seed, uniform, adaptive, _ in results:
        ok_u = [u for u in uniform if goal(u.rms, u.located, n)]
        u_best = min(ok_u, key=lambda u: (u.touches, u.time_s)) if ok_u else None
        k_a = first_goal(adaptive, n)
        stop_k = len(adaptive.rms)
        rows.append(
            {
                "seed": seed,
                "u_touches": u_best.touches if u_best else None,
                "u_grid": f"{u_best.nx}x{u_best.ny}" if u_best else "-",
                "u_time": u_best.time_s if u_best else None,
                "a_touches": k_a,
                "a_time": adaptive.cum_time_s[k_a - 1] if k_a else None,
                "stop": stop_k,
                "stop_reason": adaptive.stop_reason,
                "stop_rms": adaptive.rms[-1],
                "stop_located": adaptive.located[-1],
                "stop_time": adaptive.cum_time_s[-1],
            }
        )
    for r in rows:
        r["ratio"] = r["a_touches"] / r["u_touches"] if r["a_touches"] and r["u_touches"] else None
        r["t_ratio"] = r["a_time"] / r["u_time"] if r["a_time"] and r["u_time"] else None
    lines.append(
        "| seed | uniform: first grid at goal | uniform touches | adaptive touches | ratio "
        "| uniform time | adaptive time | time ratio | adaptive stop: touches (why), RMS, located, time |"
    )
    lines.append("|---|---|---|---|---|---|---|---|---|")

    def med(key):
        if key in ("ratio", "t_ratio"):
            # Ratios only where both planners reached the goal (said below the table).
            v = [r[key] for r in rows if r[key] is not None]
            return float(np.median(v)) if v else None
        return median_never_inf([r[key] for r in rows])

    for r in rows:
        lines.append(
            f"| {r['seed']} | {r['u_grid']} | {fmt(r['u_touches'])} | {fmt(r['a_touches'])} "
            f"| {fmt(r['ratio'], 2)} | {fmt(r['u_time'], 0, ' s')} | {fmt(r['a_time'], 0, ' s')} "
            f"| {fmt(r['t_ratio'], 2)} | {r['stop']} ({r['stop_reason']}), "
            f"{fmt(r['stop_rms'], 2, ' mm')}, {r['stop_located']}/{n}, {fmt(r['stop_time'], 0, ' s')} |"
        )
    lines.append(
        f"| **median** | | **{fmt(med('u_touches'), 1)}** | **{fmt(med('a_touches'), 1)}** "
        f"| **{fmt(med('ratio'), 2)}** | {fmt(med('u_time'), 0, ' s')} "
        f"| {fmt(med('a_time'), 0, ' s')} | {fmt(med('t_ratio'), 2)} "
        f"| {fmt(med('stop'), 1)}, {fmt(med('stop_rms'), 2, ' mm')}, "
        f"{fmt(med('stop_time'), 0, ' s')} |"
    )
    # A fixed grid must be chosen before the session: which grid meets the goal on every seed?
    grids = {}
    for _, uniform, _, _ in results:
        for u in uniform:
            grids.setdefault((u.nx, u.ny, u.touches), []).append(goal(u.rms, u.located, n))
    every = [g for g, v in sorted(grids.items(), key=lambda kv: kv[0][2]) if all(v)]
    half = [g for g, v in sorted(grids.items(), key=lambda kv: kv[0][2]) if np.mean(v) >= 0.5]
    lines.append("")
    both = sum(r["ratio"] is not None for r in rows)
    lines.append(
        f"Touches: the first count at the goal (uniform: the smallest grid of the seed at it; "
        f"a seed never at it counts as infinite in the median). Ratios: median over the "
        f"{both} seed(s) where both reached the goal."
    )
    if every:
        g = every[0]
        lines.append(
            f"Smallest uniform grid at the goal on every seed: {g[0]}x{g[1]} ({g[2]} touches)."
        )
    else:
        lines.append("No uniform grid tried meets the goal on every seed.")
    if half:
        g = half[0]
        lines.append(
            f"Smallest uniform grid at the goal on at least half the seeds: {g[0]}x{g[1]} ({g[2]} touches)."
        )
    lines += ["", *reliability(rows, grids, n)]
    ok_stop = sum(goal(r["stop_rms"], r["stop_located"], n) for r in rows)
    lines.append(
        f"The adaptive plan stopped at the goal on {ok_stop}/{len(rows)} seeds "
        f"(target sigma {args.target} mm, budget {args.budget})."
    )
    plan_ms = np.concatenate([np.array(a.plan_ms) for _, _, a, _ in results])
    loc_ms = np.concatenate([np.array(a.localize_ms) for _, _, a, _ in results])
    lines.append(
        f"Planner choice: median {np.median(plan_ms):.1f} ms, max {plan_ms.max():.1f} ms per "
        f"touch; localizer ({args.planner_input}) median {np.median(loc_ms):.0f} ms per touch."
    )
    if not rig.available:
        lines.append(f"Rig time: not estimated ({rig.why}); touches only.")
    lines += ["", *session_report(results, n, args)]
    return lines


def reliability(rows, grids, n: int) -> list[str]:
    """Touches each plan needs so that a given share of sessions reach the goal.

    A uniform grid is fixed before the session, so its count is the smallest grid at the
    goal on that share of the seeds. The adaptive plan needs no count in advance; its count
    is that quantile of its touches at the goal, and of where it stopped by itself (a stop
    short of the goal counts as never).
    """
    order = sorted(grids.items(), key=lambda kv: kv[0][2])
    at_goal = sorted(r["a_touches"] or np.inf for r in rows)
    stopped = sorted(
        r["stop"] if goal(r["stop_rms"], r["stop_located"], n) else np.inf for r in rows
    )
    lines = [
        "| sessions at the goal | uniform: smallest fixed grid | adaptive: touches at the goal "
        "| ratio | adaptive: its own stop | ratio |",
        "|---|---|---|---|---|---|",
    ]
    for share, name in ((0.5, "half"), (0.9, "9 in 10"), (1.0, "all")):
        fixed = next(((g[0], g[1], g[2]) for g, v in order if np.mean(v) >= share), None)
        k = max(1, math.ceil(share * len(rows))) - 1  # the seeds' share-quantile, rounded up
        a, st = at_goal[k], stopped[k]
        u = fixed[2] if fixed else None
        lines.append(
            f"| {name} | {f'{fixed[0]}x{fixed[1]} ({fixed[2]})' if fixed else 'none tried'} "
            f"| {fmt(a)} | {fmt(a / u if u else None, 2)} | {fmt(st)} "
            f"| {fmt(st / u if u else None, 2)} |"
        )
    return lines


def session_report(results, n: int, args) -> list[str]:
    """The two plans as sessions run them: touches into the session until the goal."""
    nx, ny = args.session_grid
    lines = [
        f"| seed | uniform {nx}x{ny} in session: touches at goal | its time | adaptive "
        "touches at goal | its time | ratio | time ratio |",
        "|---|---|---|---|---|---|---|",
    ]
    rows = []
    for seed, _, adaptive, session in results:
        k_u, k_a = first_goal(session, n), first_goal(adaptive, n)
        t_u = session.cum_time_s[k_u - 1] if k_u else None
        t_a = adaptive.cum_time_s[k_a - 1] if k_a else None
        rows.append((k_u, t_u, k_a, t_a))
        lines.append(
            f"| {seed} | {fmt(k_u)} | {fmt(t_u, 0, ' s')} | {fmt(k_a)} | {fmt(t_a, 0, ' s')} "
            f"| {fmt(k_a / k_u if k_u and k_a else None, 2)} "
            f"| {fmt(t_a / t_u if t_u and t_a else None, 2)} |"
        )

    def med(i):
        return median_never_inf([r[i] for r in rows])

    both = [r for r in rows if r[0] and r[2]]
    ratio = float(np.median([r[2] / r[0] for r in both])) if both else None
    t_ratio = float(np.median([r[3] / r[1] for r in both])) if both else None
    lines.append(
        f"| **median** | **{fmt(med(0), 1)}** | {fmt(med(1), 0, ' s')} | **{fmt(med(2), 1)}** "
        f"| {fmt(med(3), 0, ' s')} | **{fmt(ratio, 2)}** | {fmt(t_ratio, 2)} |"
    )
    lines.append(
        f"Uniform {nx}x{ny} in its planned order with the batch result after every touch; "
        f"ratios over the {len(both)} seed(s) where both reached the goal."
    )
    return lines


def _scatter_grids(ax, x: np.ndarray, rms: np.ndarray, all_located: np.ndarray) -> None:
    """Uniform grids: filled where every sensor was located, hollow where not."""
    ax.scatter(x[all_located], rms[all_located], color="C0", s=18, label="uniform, all located")
    ax.scatter(
        x[~all_located],
        rms[~all_located],
        facecolor="none",
        edgecolor="C0",
        s=18,
        label="uniform, not all",
    )


def plot(results, patch: Patch, args, rig: RigModel, path: Path) -> None:
    import warnings

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(patch.sensors)
    # Early touch counts locate no sensor on any seed: their median is NaN, not a warning.
    warnings.simplefilter("ignore", RuntimeWarning)
    # Uniform: per grid, the median over seeds.
    per_grid: dict[tuple[int, int], list[UniformRun]] = {}
    for _, uniform, _, _ in results:
        for u in uniform:
            per_grid.setdefault((u.nx, u.ny), []).append(u)
    gx = np.array([v[0].touches for v in per_grid.values()])
    g_rms = np.array([np.nanmedian([u.rms for u in v]) for v in per_grid.values()])
    g_time = np.array([np.median([u.time_s for u in v]) for v in per_grid.values()])
    g_all = np.array([np.mean([u.located == n for u in v]) >= 0.5 for v in per_grid.values()])
    g_loc = np.array([np.median([u.located for u in v]) for v in per_grid.values()])

    # Adaptive: per touch count, the median over seeds; a finished run keeps its final result.
    def held(key, which=2):
        runs = [r[which] for r in results]
        out = np.full((len(runs), max(len(a.rms) for a in runs)), np.nan)
        for i, a in enumerate(runs):
            v = np.array(getattr(a, key), float)
            out[i, : len(v)] = v
            out[i, len(v) :] = v[-1]
        return np.nanmedian(out, axis=0)

    a_rms, a_loc = held("rms"), held("located")
    ks = np.arange(1, len(a_rms) + 1)
    # Time of touch k for a seed that stopped earlier: its stop time (it is done).
    a_time = held("cum_time_s")
    # The default grid touched in its planned order, as a session runs it.
    s_rms, s_loc, s_time = held("rms", 3), held("located", 3), held("cum_time_s", 3)
    s_ks = np.arange(1, len(s_rms) + 1)
    s_label = "uniform {}x{} in session".format(*args.session_grid)
    panels = 3 if rig.available else 2
    fig, axes = plt.subplots(1, panels, figsize=(5.0 * panels, 4.2))
    ax = axes[0]
    ax.plot(ks, a_rms, "-", color="C1", label="adaptive (median over seeds)")
    ax.plot(s_ks, s_rms, "--", color="C2", label=s_label)
    _scatter_grids(ax, gx, g_rms, g_all)
    ax.axhline(GOAL_RMS_MM, color="grey", ls=":", lw=1)
    ax.set_xlabel("touches")
    ax.set_ylabel("RMS error of located sensors (mm)")
    ax.set_ylim(0, 2.0)
    ax.legend(fontsize=8)
    seeds = [r[0] for r in results]
    ax.set_title(f"{patch.name}, robot probe, seeds {min(seeds)}-{max(seeds)}")
    ax = axes[1]
    ax.plot(ks, a_loc, "-", color="C1", label="adaptive")
    ax.plot(s_ks, s_loc, "--", color="C2", label=s_label)
    ax.scatter(gx, g_loc, color="C0", s=14, label="uniform grids")
    ax.axhline(n, color="grey", ls=":", lw=1)
    ax.set_xlabel("touches")
    ax.set_ylabel("sensors located (median)")
    ax.legend(fontsize=8)
    if rig.available:
        ax = axes[2]
        ax.plot(a_time / 60.0, a_rms, "-", color="C1", label="adaptive")
        ax.plot(s_time / 60.0, s_rms, "--", color="C2", label=s_label)
        _scatter_grids(ax, g_time / 60.0, g_rms, g_all)
        ax.axhline(GOAL_RMS_MM, color="grey", ls=":", lw=1)
        ax.set_xlabel("estimated rig time (min)")
        ax.set_ylabel("RMS error of located sensors (mm)")
        ax.set_ylim(0, 2.0)
        ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _grid(text: str) -> tuple[int, int] | None:
    return None if text.lower() == "none" else parse_grid(text)


def _range(text: str) -> tuple[int, int]:
    a, _, b = text.partition("-")
    return int(a), int(b or a)


def scene_arguments(p: argparse.ArgumentParser, seeds: int) -> None:
    """The scene options the planning benchmarks share (same seeds give the same scenes)."""
    p.add_argument("--patch", default="patch_b")
    p.add_argument("--seeds", type=int, default=seeds)
    # Seeds 0-7 chose the planner's defaults; 100 on are fresh.
    p.add_argument("--first-seed", type=int, default=100)
    p.add_argument("--frames", type=int, default=8, help="frames per touch (8 = 1 s dwell)")
    p.add_argument("--margin", type=float, default=3.0)


def run_jobs(fn, jobs: list, n: int) -> list:
    """``fn`` over ``jobs``, in ``n`` processes when ``n`` > 1, in order."""
    if n <= 1:
        return [fn(j) for j in jobs]
    with Pool(n) as pool:
        return pool.map(fn, jobs)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    scene_arguments(p, seeds=8)
    p.add_argument("--nx", type=_range, default=(4, 20), help="uniform columns, e.g. 4-20")
    p.add_argument("--ny", type=int, nargs="+", default=[3, 4, 5], help="uniform rows")
    p.add_argument(
        "--coarse", type=_grid, default=AdaptivePlanner.coarse, help="adaptive coarse grid or none"
    )
    p.add_argument(
        "--target", type=float, default=AdaptivePlanner.target_sigma_mm, help="target sigma_mm"
    )
    p.add_argument("--budget", type=int, default=AdaptivePlanner.budget)
    p.add_argument(
        "--planner-input",
        choices=("result", "update"),
        default="result",
        help="what the planner sees after each touch: the batch result() or the live update()",
    )
    p.add_argument(
        "--session-grid",
        type=_grid,
        default=(20, 5),
        help="uniform grid also run as a session, touch by touch (default 20x5, the paper's)",
    )
    p.add_argument("--launch", default="launch/sim.yaml", help="rig for the time estimate")
    p.add_argument("--jobs", type=int, default=1, help="seeds run in parallel")
    p.add_argument("--plot", default="docs/bench/adaptive_vs_uniform.png")
    p.add_argument("--no-plot", action="store_true")
    args = p.parse_args(argv)

    patch = resolve_patch(args.patch)
    rig = RigModel(args.launch, args.frames / FRAME_RATE_HZ)
    jobs = [(seed, args) for seed in range(args.first_seed, args.first_seed + args.seeds)]
    t0 = time.perf_counter()
    results = run_jobs(_seed_job, jobs, args.jobs)
    for line in report(results, patch, args, rig):
        print(line)
    print(f"({time.perf_counter() - t0:.0f} s, {args.jobs} job(s))")
    if not args.no_plot:
        out = ROOT / args.plot if not Path(args.plot).is_absolute() else Path(args.plot)
        plot(results, patch, args, rig, out)
        print(f"plot: {out}")


if __name__ == "__main__":
    main()

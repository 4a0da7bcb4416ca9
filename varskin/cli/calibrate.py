"""``varskin calibrate [LAUNCH.yaml]``: the whole unattended calibration of a patch.

With no argument it runs ``launch/sim.yaml``: the simulated UR controller driven by the real
ur-rtde client and the simulated Muca board read through a pseudo-terminal by the real
recorder, so the default run exercises every part a real rig uses. ``--resume SESSION.db``
carries on a session that stopped (a crash, a kill, a board that never came back) from its
first missing touch; with ``--refine N`` it adds up to N touches to a finished session,
each where it shrinks the uncertainty of the sensors not yet located within the target
most. A real rig is only driven with ``--real``.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import sys
import time
from pathlib import Path

from robot.launch import LaunchConfig, load_launch
from varskin.cli._args import count, positive
from varskin.errors import InputError, StoreError, VarskinError
from varskin.localization import DEFAULT_METHOD, METHODS
from varskin.patch import config_dir

DEFAULT_LAUNCH = config_dir().parent / "launch" / "sim.yaml"
PLANNERS = ("uniform", "adaptive")
REFINE = "refine"  # a finished session's touches again, then adaptive ones (--refine)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "calibrate",
        help="run a calibration session (default: the simulated rig of launch/sim.yaml)",
        description=(
            "Touch the patch on a plan, record the Muca board in sync, localize every sensor "
            "live, store everything in one SQLite session file and write a report. Without "
            "LAUNCH.yaml it runs launch/sim.yaml (simulated UR controller + simulated board)."
        ),
    )
    p.add_argument(
        "launch",
        nargs="?",
        metavar="LAUNCH.yaml",
        help=f"the rig's launch file (default: {DEFAULT_LAUNCH.relative_to(config_dir().parent)})",
    )
    p.add_argument(
        "-o",
        "--output",
        metavar="SESSION.db",
        help="session file to create (default: sessions/<patch>-<date>-<time>.db); the report "
        "goes to a folder of the same name without .db",
    )
    p.add_argument(
        "--resume",
        metavar="SESSION.db",
        help="continue this stopped session (its launch file must be unchanged)",
    )
    p.add_argument(
        "--refine",
        type=count,
        metavar="N",
        help="with --resume of a finished session: up to N more touches, each where it "
        "shrinks the uncertainty of the sensors not yet located within --target-sigma most "
        "(the adaptive planner, fed every touch the session made; no default)",
    )
    p.add_argument(
        "--planner",
        choices=PLANNERS,
        help="uniform: the launch's grid (default 20x5, as in the paper); adaptive: a coarse "
        "pass, then each touch where it shrinks the sensors' uncertainty most "
        "(default: the launch's plan.mode, else uniform)",
    )
    p.add_argument(
        "--budget",
        type=int,
        metavar="N",
        help="adaptive planner: most touches in all (default: the launch's plan.budget, else 100)",
    )
    p.add_argument(
        "--target-sigma",
        type=positive,
        metavar="MM",
        help="adaptive planner and --refine: stop once every sensor's sigma is below this, "
        "mm (default: the launch's plan.target_sigma_mm, else 0.6)",
    )
    p.add_argument(
        "--method",
        choices=list(METHODS),
        help=f"localization method of the final estimate (default: {DEFAULT_METHOD})",
    )
    p.add_argument(
        "--max-retries",
        type=int,
        default=2,
        metavar="N",
        help="extra attempts of a touch without contact or with a board gap (default: 2)",
    )
    p.add_argument(
        "--real",
        action="store_true",
        help="required to drive a REAL robot (a launch file with simulated: false)",
    )
    p.set_defaults(func=run)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _patch_text(launch_path: Path) -> str:
    """The patch YAML the launch names, kept in the session so replay needs no checkout."""
    import yaml

    rel = Path(str(yaml.safe_load(launch_path.read_text())["patch"]))
    return (rel if rel.is_absolute() else launch_path.parent / rel).read_text()


def _default_output(launch: LaunchConfig) -> Path:
    stamp = time.strftime("%Y%m%d-%H%M%S")
    return Path("sessions") / f"{launch.patch.name}-{stamp}.db"


def make_planner(launch: LaunchConfig, settings: dict):
    """The plan generator a session's stored settings describe (the same on resume)."""
    from varskin.planning import AdaptivePlanner, UniformPlanner

    if settings["planner"] in ("adaptive", REFINE):
        kwargs = {"budget": settings["budget"], "margin_mm": launch.plan.margin_mm}
        if settings.get("target_sigma_mm") is not None:
            kwargs["target_sigma_mm"] = settings["target_sigma_mm"]
        if settings["planner"] == REFINE:
            points = settings["points"]
            kwargs.update(coarse=None, first_points=points, budget=len(points) + settings["budget"])
        return AdaptivePlanner(launch.patch, **kwargs).plan()
    return UniformPlanner(
        launch.patch, launch.plan.nx, launch.plan.ny, launch.plan.margin_mm, settings["order"]
    ).plan()


def run(args: argparse.Namespace) -> int:
    from varskin.live_view import LiveView
    from varskin.planning import touch_order
    from varskin.rig import open_rig
    from varskin.session import CalibrationSession, SessionSettings, live_schedule
    from varskin.store import SessionStore
    from varskin.touch_window import WindowConfig, reference_for

    if args.max_retries < 0:
        raise InputError("--max-retries must be >= 0")
    if args.refine and not args.resume:
        raise InputError("--refine adds touches to a finished session: give --resume SESSION.db")
    if args.resume:
        if args.launch or args.output or args.planner or args.budget:
            raise InputError(
                "--resume takes its launch file and plan from the session; give no other plan options"
            )
        if args.target_sigma and not args.refine:
            raise InputError("--target-sigma with --resume needs --refine N")
        store, meta, launch, launch_path, plan_settings = _open_for_resume(args.resume, args)
        live_mode, batch_after = live_schedule(args.resume, meta)
        if args.refine:
            plan_settings, batch_after = _refine(
                store, meta, launch, plan_settings, args, live_mode, batch_after
            )
        method = args.method or str(meta["method"])
        out_path = Path(args.resume)
    else:
        launch_path = Path(args.launch) if args.launch else DEFAULT_LAUNCH
        launch = load_launch(launch_path)  # every config mistake surfaces before anything moves
        plan_settings = {
            "planner": args.planner or launch.plan.mode,
            "budget": args.budget if args.budget is not None else launch.plan.budget,
            "target_sigma_mm": args.target_sigma
            if args.target_sigma is not None
            else launch.plan.target_sigma_mm,
        }
        if plan_settings["planner"] == "uniform":
            # Resolved once and stored, so that a resumed session keeps its order.
            plan_settings["order"] = touch_order(launch.patch, launch.plan.order)
        if plan_settings["budget"] < 1:
            raise InputError("--budget must be >= 1")
        method = args.method or DEFAULT_METHOD
        # The adaptive planner chooses by the sigmas, so it needs the batch solve after every
        # touch; a uniform plan's live view only needs the fast update.
        live_mode = "batch" if plan_settings["planner"] == "adaptive" else "update"
        batch_after = None
        out_path = Path(args.output) if args.output else _default_output(launch)
        if out_path.exists():
            raise StoreError(f"{out_path}: already exists; use --resume {out_path} to continue it")
        store = None
    _check_plan_safe(launch, plan_settings)
    if not launch.simulated and not args.real:
        raise InputError(
            f"{launch.source}: drives a REAL robot; pass --real once the workspace is clear"
        )
    # A resumed session goes on with the reference its logs have (CalibrationSession.run).
    window = WindowConfig(reference=reference_for(launch.patch))
    settings = SessionSettings(
        method=method,
        max_retries=args.max_retries,
        window=window,
        live_estimate=live_mode,
        batch_after_logs=batch_after,
    )
    print(
        f"launch: {launch.source} ({'simulated rig' if launch.simulated else 'REAL robot ' + launch.robot.host}), "
        f"patch {launch.patch.name}, planner {plan_settings['planner']}"
        + (f" ({plan_settings['order']} order)" if plan_settings["planner"] == "uniform" else "")
        + f", session {out_path}",
        file=sys.stderr,
    )
    with open_rig(launch, allow_real=args.real) as rig:
        if store is None:
            store = SessionStore.create(
                out_path,
                {
                    "launch_path": str(launch_path.resolve()),
                    "launch_sha256": _sha256(launch_path),
                    "patch": launch.patch.name,
                    "patch_yaml": _patch_text(launch_path),
                    "sensors": list(launch.patch.names),
                    "plan": plan_settings,
                    "method": method,
                    "simulated": launch.simulated,
                    "time_scale": rig.time_scale,
                    "truth_xy": rig.truth_xy.tolist() if rig.truth_xy is not None else None,
                    "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                    "status": "running",
                },
            )
        elif args.refine:
            # Stored once the plan passed its checks and the rig is up, before the first
            # touch: a refinement stopped part way resumes as a refinement.
            store.set_meta("plan", plan_settings)
            store.set_meta("live_batch_after", batch_after)
            store.set_meta("status", "running")
            store.commit()
        try:
            planner = make_planner(launch, plan_settings)
            total = _plan_length(launch, plan_settings)
            session = CalibrationSession(rig, store, planner, settings, on_event=LiveView(total))
            try:
                result = session.run()
            except VarskinError as e:
                # The store holds every finished touch: say how to carry on, in the same line.
                raise type(e)(f"{e}; {_resume_hint(out_path)}") from None
            except KeyboardInterrupt:  # Ctrl-C or SIGTERM; the rig stops on the way out
                print(f"varskin: interrupted; {_resume_hint(out_path)}", file=sys.stderr)
                return 130
            _finish(store, result, launch, rig, out_path)
        finally:
            store.close()
    return 0


def _open_for_resume(path: str, args) -> tuple:
    """The stored session and what it ran with, each checked before anything moves: a
    resume writes to the file and drives the rig from what it holds (a damaged value found
    at the end, after every touch, would cost the whole run)."""
    from varskin.store import SessionStore

    store = SessionStore.open(path)
    store.check()
    meta = store.meta()
    wall = meta.get("wall_s")
    if wall is not None and (isinstance(wall, bool) or not isinstance(wall, (int, float))):
        raise StoreError(f"{path}: damaged session file (its wall_s is {wall!r})")
    launch_path = Path(str(meta["launch_path"]))
    if not launch_path.is_file():
        raise StoreError(f"{path}: its launch file {launch_path} is gone")
    if _sha256(launch_path) != meta["launch_sha256"]:
        raise StoreError(f"{path}: launch file {launch_path} changed since the session started")
    launch = load_launch(launch_path)
    if meta["sensors"] != list(launch.patch.names):
        raise StoreError(f"{path}: damaged session file (its sensors are not its patch's)")
    if not args.method and meta["method"] not in METHODS:
        raise StoreError(f"{path}: damaged session file (its method is {meta['method']!r})")
    plan = meta["plan"]
    _check_plan_settings(path, plan)
    return store, meta, launch, launch_path, stored_plan(plan)  # type: ignore[arg-type]


def stored_plan(plan: dict) -> dict:
    """A session's stored plan settings as ``make_planner`` takes them: a uniform plan
    stored before plans had an order was swept."""
    from varskin.planning import SWEEP

    plan = dict(plan)
    if plan.get("planner") == "uniform":
        plan.setdefault("order", SWEEP)
    return plan


def _check_plan_settings(path: str, plan: object) -> None:
    """A stored plan must be one this code can rebuild: refuse a damaged one by name."""

    from varskin.planning import SHUFFLED, SWEEP

    def number(v) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

    kind = plan.get("planner") if isinstance(plan, dict) else None
    ok = kind in (*PLANNERS, REFINE) and plan.get("order", SWEEP) in (SWEEP, SHUFFLED)
    if ok and kind != "uniform":
        budget, target = plan.get("budget"), plan.get("target_sigma_mm")
        ok = isinstance(budget, int) and number(budget) and budget >= 1
        ok = ok and (target is None or (number(target) and target > 0))
    if ok and kind == REFINE:
        pts = plan.get("points")
        ok = isinstance(pts, list) and all(
            isinstance(p, list) and len(p) == 2 and all(map(number, p)) for p in pts
        )
    if not ok:
        raise StoreError(f"{path}: damaged session file (its plan is {plan!r})")


def _refine(
    store, meta, launch: LaunchConfig, plan: dict, args, mode: str, batch_after: int | None
) -> tuple[dict, int | None]:
    """The plan of a refinement: every touch the session made, in its order, then up to
    ``args.refine`` adaptive ones; and after how many point logs the live estimates become
    batch solves (the adaptive choice needs them; before, the session kept its own mode)."""
    if meta.get("status") != "complete":
        raise InputError(
            f"{args.resume}: the session has not finished its plan; continue it first with "
            f"varskin calibrate --resume {args.resume}"
        )
    if mode == "update" and batch_after is None:
        batch_after = store.n_point_logs()
    target = args.target_sigma
    if target is None:
        target = plan.get("target_sigma_mm", launch.plan.target_sigma_mm)
    refined = {
        "planner": REFINE,
        "budget": args.refine,
        "target_sigma_mm": target,
        "points": [[o.x_mm, o.y_mm] for o in store.outcomes()],
    }
    return refined, batch_after


def _resume_hint(out_path: Path) -> str:
    return f"the session is saved: continue it with varskin calibrate --resume {out_path}"


def _plan_length(launch: LaunchConfig, plan: dict) -> int:
    if plan["planner"] == "adaptive":
        return int(plan["budget"])
    if plan["planner"] == REFINE:
        return len(plan["points"]) + int(plan["budget"])
    return launch.plan.nx * launch.plan.ny


def _check_plan_safe(launch: LaunchConfig, plan: dict) -> None:
    """Refuse, before anything moves, a plan that could leave the envelope: the uniform grid
    itself, or for the adaptive planner the corners and edges of the area it may choose from."""
    from varskin.planning import uniform_points

    if plan["planner"] in ("adaptive", REFINE):
        pts = uniform_points(launch.patch, 9, 5, launch.plan.margin_mm)
    else:
        pts = uniform_points(launch.patch, launch.plan.nx, launch.plan.ny, launch.plan.margin_mm)
    launch.envelope.check_touch_plan(launch.frame.to_base(pts), launch.touch)


def _finish(store, result, launch: LaunchConfig, rig, out_path: Path) -> None:
    from robot.rig_time import estimate_plan_time
    from varskin.cli.localize import print_design_fit
    from varskin.report import write_report
    from varskin.session import rms_error_mm

    report_dir = out_path.with_suffix("")
    truth = rig.truth_xy
    files = write_report(report_dir, store, result.predictions, launch.patch, truth)
    est = estimate_plan_time(rig.to_base(result.touch_points_mm), launch.touch, launch.envelope)
    lines = [
        f"touches: {result.n_planned} planned, {len(result.logs)} point logs, "
        f"{result.n_failed} failed, {result.n_attempts} attempts",
        f"time: {result.wall_s:.1f} s wall in this run"
        + (f" (simulated clock x{rig.time_scale:g})" if rig.time_scale != 1 else "")
        + f"; the same plan on a real rig: about {est.total_s / 60:.1f} min "
        f"(motion and dwell model: travel {est.travel_s:.0f} s, descent {est.descent_s:.0f} s, "
        f"hold {est.hold_s:.0f} s, retract {est.retract_s:.0f} s)",
    ]
    located = sum(e.status == "ok" for e in result.predictions.estimates)
    if truth is not None and located:
        rms, n = rms_error_mm(result.predictions, truth)
        lines.append(
            f"error vs the simulated rig's hidden layout: RMS {rms:.3f} mm over {n} located sensors"
        )
    lines.append(f"located {located}/{len(result.predictions.estimates)} sensors")
    for line in lines:
        print(line)
    if files.design_fit is not None:
        print_design_fit(files.design_fit)
        store.set_meta("design_fit", files.design_fit.as_dict())
    print(f"session: {out_path}; report: {files.predictions_csv.parent}/")
    store.set_meta("rig_time_estimate_s", est.total_s)
    # a resumed session adds this run's time to the earlier runs'
    store.set_meta("wall_s", float(store.meta().get("wall_s") or 0.0) + result.wall_s)

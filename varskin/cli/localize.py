"""``varskin localize``: point-log CSV in, one predicted position per sensor out.

Method parameters reach the method only when the user gave them, so each method keeps
its own defaults and no method is handed another method's parameters.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

from varskin import localization as registry
from varskin.errors import InputError
from varskin.localization._peak_model import SHAPES
from varskin.patch import resolve_patch


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "localize",
        help="localize every sensor from a point-log CSV",
        description="Read a point-log CSV and predict each sensor's position (mm, patch frame). "
        "Output columns: sensor,x_mm,y_mm,sigma_mm,snr_db,status.",
    )
    p.add_argument("pointlogs", metavar="POINTLOGS.csv", help="point-log CSV (touch,x_mm,y_mm,...)")
    p.add_argument(
        "--method",
        choices=list(registry.METHODS),
        default=registry.DEFAULT_METHOD,
        help=f"localization method; default {registry.DEFAULT_METHOD}",
    )
    p.add_argument(
        "--eta",
        type=float,
        help="paper method: keep pixels above ETA x the map's maximum, 0 < ETA < 1; default 0.65",
    )
    p.add_argument(
        "--ppcm",
        type=float,
        help="paper method: interpolation resolution in pixels per cm; default 128",
    )
    p.add_argument(
        "--area",
        type=parse_area,
        metavar="X0,Y0,X1,Y1",
        help="paper method: area to interpolate over, mm in the patch frame; "
        "default the bounding box of the probe locations",
    )
    p.add_argument(
        "--solver",
        choices=["alternate", "joint"],
        help="peakfit: how the batch solve couples the sensors' fits with the touches' gain "
        "and placement: alternate between them, or take joint Gauss-Newton steps (converges; "
        "more accurate with finger touches; as fast as the default with a robot and about a "
        "third of its time with a finger, as it skips the error-bar check, whose sigma it "
        "does not fit); default alternate",
    )
    p.add_argument(
        "--placement-sd",
        dest="placement_sd_mm",
        type=float,
        metavar="MM",
        help="peakfit: how far (mm, per axis, one standard deviation) the probe really lands "
        "from the logged point, if known: about 1 for a finger, 0.05 for a robot. Used as a "
        "floor for the scatter estimated from the data, which sparse plans underestimate; "
        "default none (estimated only)",
    )
    p.add_argument(
        "--settle-rounds",
        dest="settle_rounds",
        type=int,
        metavar="N",
        help="peakfit: extra over-relaxed alternations a finger-like solve takes to settle "
        "(0: none); 40 lowers Patch B finger errors at the outermost wires, at about twice "
        "the time of the default (docs/benchmarks.md); default 12",
    )
    p.add_argument(
        "--joint-settle-rounds",
        dest="joint_settle_rounds",
        type=int,
        metavar="N",
        help="peakfit: joint rounds a settled solve then takes, kept only while the touches' "
        "offsets fit their placement scatter (0: none); default 8, but none with a --patch "
        "whose design prior pins both axes, where it holds the edge sensors they are for "
        "(a family of fewer than 3 wires has no design map; docs/localizer.md)",
    )
    p.add_argument(
        "--response-shape",
        dest="response_shape",
        choices=["auto", *SHAPES],
        help="peakfit: the profile of a sensor's bump with the probe's distance, all at half "
        "height at the fitted half width; auto keeps the Lorentzian unless the whole patch's "
        "fits favour another by a paired test over sensors (docs/localizer.md); default auto",
    )
    p.add_argument(
        "--first-order-sigma",
        dest="calibrate_sigma",
        action="store_const",
        const=False,
        help="peakfit: report sigma_mm as the first-order propagation gives it, without "
        "the check that re-runs the solve on sessions simulated from the fit and scales "
        "every sigma to what it measures; the batch solve is 1.3-3x faster, but 2 sigma then "
        "covers 98-100%% of sensors on dense grids and 84-89%% on sparse finger plans "
        "instead of 90-98%%; without --patch the wires inferred for a finger session, and "
        "so its positions, may differ; default: checked",
    )
    p.add_argument(
        "--patch",
        metavar="PATCH",
        help="patch YAML or builtin name (patch_a, patch_b): its TX/RX wiring and design feed "
        "peakfit's layout prior (sensors on one wire share nearly one line; the wires lie near "
        "their design) and its outline is drawn in plots; default none: peakfit infers the "
        "wires from its fits when they form a clear grid, without the design",
    )
    p.add_argument("-o", "--output", metavar="PRED.csv", help="write predictions CSV here")
    p.add_argument("--json", metavar="PRED.json", help="also write predictions as JSON")
    p.add_argument(
        "--plots",
        metavar="DIR",
        help="write PNGs: predictions.png and each sensor's point log map (map_<sensor>.png)",
    )
    p.add_argument(
        "--plot-sensors",
        metavar="S1,S2",
        help="with --plots: only these sensors' point log maps; default all sensors",
    )
    p.add_argument("-q", "--quiet", action="store_true", help="do not print the table")
    p.set_defaults(func=run)


def parse_area(text: str) -> tuple[float, float, float, float]:
    parts = text.split(",")
    try:
        vals = tuple(float(v) for v in parts)
    except ValueError:
        vals = ()
    if len(vals) != 4:
        raise argparse.ArgumentTypeError(f"area must be X0,Y0,X1,Y1 in mm, got {text!r}")
    return vals  # type: ignore[return-value]


@contextlib.contextmanager
def writing():
    """Turn a failed write (missing folder, no permission, full disk) into a one-line error."""
    try:
        yield
    except OSError as e:
        where = e.filename or "output"
        raise InputError(f"{where}: cannot write ({e.strerror or e})") from None


def method_params(args) -> dict:
    """Only the parameters the user actually set."""
    return {
        k: getattr(args, k)
        for k in (
            "eta",
            "ppcm",
            "area",
            "solver",
            "settle_rounds",
            "joint_settle_rounds",
            "placement_sd_mm",
            "calibrate_sigma",
            "response_shape",
        )
        if getattr(args, k) is not None
    }


def print_warnings(logs) -> None:
    for w in logs.warnings:
        print(f"varskin: warning: {w}", file=sys.stderr)


# Where peakfit's layout prior took the wires from, as the summary line says it.
WIRES_NOTE = {
    "patch": "wires from the patch",
    "inferred": "wires inferred from the fits (no --patch)",
    "none": "no wire prior: the fits form no clear grid (--patch gives the wires)",
}


NOTE_NAMES = 10  # a full board may correct dozens; the JSON has them all


def settling_note(params: dict) -> str:
    """A line naming how many sensors had the board's settling taken out of their readings
    (peakfit, ``settling_taken_out_mm``) and the largest move that made; "" if none."""
    return _note(
        params.get("settling_taken_out_mm"),
        "board settling taken out of {n} sensor(s)' readings",
        "largest move",
        "in their sigma_mm",
    )


def unseen_note(params: dict) -> str:
    """A line naming the located sensors whose peaks no touch came near (peakfit,
    ``shape_spread_mm``) and the largest spread of their places; "" if none."""
    return _note(
        params.get("shape_spread_mm"),
        "{n} sensor(s) placed from their peaks' flanks, no touch near the top",
        "largest move under the other response shapes",
        "in their sigma_mm; a touch nearer places them better",
    )


def _note(by_sensor: dict | None, head: str, largest: str, tail: str) -> str:
    """``head`` (with {n}, how many), the first NOTE_NAMES sensor names, and the largest
    of their values (mm); "" if there are none."""
    if not by_sensor:
        return ""
    names = list(by_sensor)
    worst = max(names, key=by_sensor.get)
    more = len(names) - NOTE_NAMES
    shown = ", ".join(names[:NOTE_NAMES]) + (f", ... ({more} more)" if more > 0 else "")
    return (
        f"{head.format(n=len(names))}: {shown} "
        f"({largest} {worst}, {by_sensor[worst]:.2f} mm; {tail})"
    )


def prediction_table(predictions) -> str:
    lines = [f"{'sensor':<8} {'x_mm':>8} {'y_mm':>8} {'sigma_mm':>8} {'snr_db':>7} status"]
    for e in predictions:
        lines.append(
            f"{e.sensor:<8} {_f(e.x_mm):>8} {_f(e.y_mm):>8} {_f(e.sigma_mm):>8} "
            f"{_f(e.snr_db, 1):>7} {e.status}"
        )
    return "\n".join(lines)


def _f(v, digits: int = 2) -> str:
    return "" if v is None else f"{v:.{digits}f}"


def run(args) -> int:
    from varskin.localization import localize
    from varskin.pointlog_csv import read_point_logs

    logs = read_point_logs(args.pointlogs)
    print_warnings(logs)
    params = method_params(args)
    patch = resolve_patch(args.patch) if args.patch else None
    method_kwargs = dict(params)
    if patch is not None:
        if args.method == "paper":
            raise InputError(
                "--patch: the paper method has no layout prior; drop --patch or use peakfit"
            )
        method_kwargs["patch"] = patch
    predictions = localize(logs, method=args.method, **method_kwargs)
    design_fit = None
    if patch is not None:
        from varskin.design_fit import fit_design

        design_fit = fit_design(predictions, patch)
    sensors = list(logs.sensors)
    if args.plot_sensors:
        sensors = [s.strip() for s in args.plot_sensors.split(",") if s.strip()]
        unknown = [s for s in sensors if s not in logs.sensors]
        if unknown:
            raise InputError(f"--plot-sensors: no sensor {', '.join(unknown)} in {args.pointlogs}")
    with writing():
        if args.output:
            predictions.to_csv(args.output)
        if args.json:
            predictions.to_json(args.json)
        if args.plots:
            outline = (patch.length_mm, patch.width_mm) if patch else None
            write_plots(
                Path(args.plots), logs, predictions, sensors, params, outline=outline,
                design_fit=design_fit,
            )  # fmt: skip
    if not args.quiet:
        print(prediction_table(predictions))
        if design_fit is not None:
            print_design_fit(design_fit)
        for note in (settling_note(predictions.params), unseen_note(predictions.params)):
            if note:
                print(note)
        ok = sum(e.status == "ok" for e in predictions)
        line = f"{predictions.method}: {ok}/{len(predictions)} sensors localized"
        wires = predictions.params.get("wires")
        if wires in WIRES_NOTE:
            line += f"; {WIRES_NOTE[wires]}"
        shape = predictions.params.get("response_shape")
        if shape not in (None, "lorentzian"):
            line += f"; {shape} response"
        print(line)
    return 0


def print_design_fit(fit) -> None:
    """The located sensors against the patch's design (a ``DesignFit``): one line, and a
    warning on stderr where the whole layout lies turned or shifted beyond what a
    registration leaves."""
    print(fit.summary())
    for w in fit.warnings():
        print(f"varskin: warning: {w}", file=sys.stderr)


def write_plots(
    folder: Path, logs, predictions, sensors, params, truth=None, outline=None, design_fit=None
) -> list[Path]:
    from varskin import plots

    # The maps show the paper's steps; use the paper parameters the user gave, else its defaults.
    map_params = {k: v for k, v in params.items() if k in ("eta", "ppcm", "area")}
    truth = truth or {}
    out = [
        plots.plot_predictions(predictions, folder / "predictions.png", logs.xy_mm, truth, outline)
    ]
    if design_fit is not None:
        out.append(
            plots.plot_off_design(predictions, design_fit, folder / "off_design.png", outline)
        )
    for s in sensors:
        out.append(
            plots.plot_point_log_map(
                logs, s, folder / f"map_{s}.png", truth_xy=truth.get(s), **map_params
            )
        )
    return out

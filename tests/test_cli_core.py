"""The core commands end to end through ``varskin.cli.main``: simulate, localize, evaluate, demo."""

from __future__ import annotations

import json
import sys
import types

import numpy as np
import pytest

from varskin.cli import main
from varskin.cli.localize import settling_note, unseen_note
from varskin.predictions import Predictions, SensorEstimate


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    logs, truth = d / "logs.csv", d / "truth.csv"
    code = main(
        [
            "simulate",
            "--patch",
            "configs/patch_b.yaml",
            "--grid",
            "20x5",
            "--probe",
            "finger",
            "--seed",
            "1",
            "-o",
            str(logs),
            "--truth",
            str(truth),
        ]
    )
    assert code == 0
    return logs, truth


def test_simulate_writes_frames_and_truth_with_the_same_names(simulated):
    logs, truth = simulated
    header = logs.read_text().splitlines()[0].split(",")
    truth_rows = truth.read_text().splitlines()
    assert header[:5] == ["touch", "x_mm", "y_mm", "t_s", "force_n"]
    assert [r.split(",")[0] for r in truth_rows[1:]] == header[5:]
    assert len(header) == 35


def test_simulate_accepts_a_builtin_name_and_rejects_unknown(tmp_path, capsys):
    out = tmp_path / "a.csv"
    assert main(["simulate", "--patch", "patch_a", "--grid", "4x3", "-o", str(out)]) == 0
    assert (tmp_path / "a_truth.csv").read_text().count("\n") == 23
    assert main(["simulate", "--patch", "patch_z", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "patch_z" in err and "Traceback" not in err and err.count("\n") == 1


def test_simulate_localize_evaluate(simulated, tmp_path, capsys):
    logs, truth = simulated
    pred, pred_json, plots = tmp_path / "pred.csv", tmp_path / "pred.json", tmp_path / "plots"
    code = main(
        [
            "localize",
            str(logs),
            "--method",
            "paper",
            "--ppcm",
            "16",
            "-o",
            str(pred),
            "--json",
            str(pred_json),
            "--plots",
            str(plots),
            "--plot-sensors",
            "S14",
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "S30" in out and "30/30 sensors localized" in out
    assert pred.read_text().splitlines()[0] == "sensor,x_mm,y_mm,sigma_mm,snr_db,status"
    data = json.loads(pred_json.read_text())
    assert data["method"] == "paper" and data["params"]["ppcm"] == 16 and len(data["sensors"]) == 30
    for name in ("predictions.png", "map_S14.png"):
        assert (plots / name).stat().st_size > 5000
    assert sorted(p.name for p in plots.iterdir()) == ["map_S14.png", "predictions.png"]

    ev_json = tmp_path / "eval.json"
    assert main(["evaluate", str(pred), "--truth", str(truth), "--json", str(ev_json)]) == 0
    out = capsys.readouterr().out
    assert "RMS (N-1)" in out and "S14" in out
    ev = json.loads(ev_json.read_text())
    assert ev["n_ok"] == 30 and 1.0 <= ev["rms_mm"] <= 2.5


def test_quiet_prints_nothing(simulated, tmp_path, capsys):
    logs, _ = simulated
    assert (
        main(
            [
                "localize",
                str(logs),
                "--method",
                "paper",
                "--ppcm",
                "8",
                "-q",
                "-o",
                str(tmp_path / "p.csv"),
            ]
        )
        == 0
    )
    assert capsys.readouterr().out == ""


@pytest.mark.parametrize(
    "args_tail,words",
    [
        (["--eta", "1.5"], "eta"),
        (["--ppcm", "0"], "ppcm"),
        (["--area", "10,0,0,10"], "x1 > x0"),
    ],
)
def test_bad_method_parameters_exit_2(simulated, capsys, args_tail, words):
    logs, _ = simulated
    assert main(["localize", str(logs), "--method", "paper", *args_tail]) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err and err.count("\n") == 1


def test_bad_csv_is_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("touch,x_mm,y_mm,A\n1,0,0,1\n2,0,x,1\n3,5,5,1\n")
    assert main(["localize", str(bad), "--method", "paper", "-o", str(tmp_path / "p.csv")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"varskin: error: {bad}:3:3: ")
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "p.csv").exists()


def test_warnings_go_to_stderr(tmp_path, capsys):
    f = tmp_path / "w.csv"
    f.write_text("touch,x_mm,y_mm,A\n1,0,0,1\n1,0,0,nan\n2,5,0,2\n3,0,5,3\n4,5,5,nan\n")
    assert main(["localize", str(f), "--method", "paper", "--ppcm", "16"]) == 0
    err = capsys.readouterr().err
    assert "2 non-finite" in err and "dropped touch(es) 4" in err


def test_only_given_parameters_reach_the_method(simulated, monkeypatch, tmp_path):
    """A method without eta/ppcm/area must not be handed them by default."""
    seen = {}

    def fake_localize(logs, **params):
        seen.update(params)
        return Predictions("fake", [SensorEstimate(s, 1.0, 1.0) for s in logs.sensors])

    module = types.ModuleType("fake_method_for_test")
    module.localize = fake_localize
    monkeypatch.setitem(sys.modules, "fake_method_for_test", module)
    from varskin import localization as registry

    monkeypatch.setitem(registry.METHODS, "fake", "fake_method_for_test")
    logs, _ = simulated
    assert main(["localize", str(logs), "--method", "fake", "-q"]) == 0
    assert seen == {}
    assert main(["localize", str(logs), "--method", "fake", "-q", "--eta", "0.6"]) == 0
    assert seen == {"eta": 0.6}


def test_demo_runs(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--seed", "2", "--ppcm", "32"]) == 0
    text = capsys.readouterr().out
    assert "summary" in text and "paper: 30/30 sensors localized" in text
    for name in ("logs.csv", "truth.csv", "pred_paper.csv", "pred_paper.json", "eval_paper.json"):
        assert (out / name).stat().st_size > 0
    assert (out / "plots_paper" / "map_S14.png").stat().st_size > 5000
    assert (out / "plots_paper" / "predictions.png").stat().st_size > 5000


def test_unwritable_output_is_one_line_exit_2(simulated, tmp_path, capsys):
    logs, _ = simulated
    target = tmp_path / "missing-folder" / "pred.csv"
    assert (
        main(["localize", str(logs), "--method", "paper", "--ppcm", "8", "-q", "-o", str(target)])
        == 2
    )
    err = capsys.readouterr().err
    assert err == f"varskin: error: {target}: cannot write (No such file or directory)\n"


def _blocked(tmp_path):
    """A path under a plain file: no command can create it, on any OS."""
    (tmp_path / "afile").write_text("x")
    return tmp_path / "afile" / "out"


# Each once a traceback (found by fuzzing the commands' arguments): a user's mistake or a
# path that cannot be written must end in one line naming it, exit 2.
@pytest.mark.parametrize(
    "argv,words",
    [
        (lambda t: ["simulate", "--seed", "-1", "-o", str(t / "s.csv")], "seed must be"),
        (lambda t: ["demo", "--seed", "-2"], "seed must be"),
        (lambda t: ["calibrate", "--target-sigma", "-1"], "finite number > 0"),
        (
            lambda t: ["board", "record", "--port", "loop://", "--seconds", "nan", "-o", "x.csv"],
            "finite number > 0",
        ),  # fmt: skip
        (
            lambda t: ["simulate", "--patch", str(t / "bin.yaml"), "-o", str(t / "s.csv")],
            "is not a text file",
        ),  # fmt: skip
        (lambda t: ["calibrate", str(t / "bin.yaml")], "is not a text file"),
        (
            lambda t: ["simulate", "--grid", "4x3", "-o", str(_blocked(t) / "s.csv")],
            "Not a directory",
        ),  # fmt: skip
        (lambda t: ["calibrate", "-o", str(_blocked(t) / "s.db")], "cannot create session"),
    ],
)
def test_bad_arguments_and_unwritable_paths_are_one_line(tmp_path, capsys, argv, words):
    (tmp_path / "bin.yaml").write_bytes(bytes(range(256)))  # not text
    try:
        code = main(argv(tmp_path))
    except SystemExit as e:  # argparse refuses before the command runs
        code = e.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert words in err[-1] and err[-1].startswith("varskin"), err


def test_plots_handle_error_circles_and_sensors_without_data(tmp_path):
    import numpy as np

    from varskin import plots
    from varskin.pointlogs import PointLogs

    xy = np.array([[x, y] for x in (0.0, 5.0, 10.0) for y in (0.0, 5.0)])
    values = np.column_stack([np.arange(6.0), np.full(6, np.nan)])
    logs = PointLogs(("A", "B"), np.arange(6), xy, values, np.ones(6, int))
    for sensor in ("A", "B"):
        path = plots.plot_point_log_map(logs, sensor, tmp_path / f"{sensor}.png", ppcm=8)
        assert path.stat().st_size > 5000
    predictions = Predictions(
        "m",
        [
            SensorEstimate("A", 5.0, 2.0, sigma_mm=1.5),
            SensorEstimate("B", None, None, status="nodata"),
        ],
    )
    path = plots.plot_predictions(
        predictions, tmp_path / "p.png", xy, {"A": (4.0, 2.5)}, outline_mm=(10.0, 5.0)
    )
    assert path.stat().st_size > 5000


def test_localize_says_where_the_wire_prior_took_the_wires_from(simulated, tmp_path, capsys):
    """Without the patch, the 20 x 5 finger scene's fits form a clear grid and a sparse
    12 x 3 one's do not."""
    logs, _ = simulated
    sparse = tmp_path / "sparse.csv"
    grid = ["--patch", "configs/patch_b.yaml", "--grid", "12x3", "--probe", "finger"]
    assert main(["simulate", *grid, "--seed", "0", "-o", str(sparse)]) == 0
    capsys.readouterr()
    for path, extra, words in (
        (logs, [], "wires inferred from the fits (no --patch)"),
        (sparse, [], "no wire prior: the fits form no clear grid (--patch gives the wires)"),
        (logs, ["--patch", "patch_b"], "wires from the patch"),
    ):
        assert main(["localize", str(path), *extra]) == 0
        last = capsys.readouterr().out.strip().splitlines()[-1]
        assert last.startswith("peakfit: ") and last.endswith(words), last


def test_localize_names_the_sensors_the_board_settling_was_taken_out_of(
    simulated, tmp_path, capsys
):
    """This finger scene's batch solve takes the board's settling out of some sensors'
    readings: the JSON's params give each one's move in mm, and the printout names them,
    with the largest move, just above the summary line."""
    logs, _ = simulated
    note, moved, worst = _note_above_summary(capsys, tmp_path, [str(logs)], "settling_taken_out_mm")
    assert note.startswith(f"board settling taken out of {len(moved)} sensor(s)' readings: ")
    assert ", ".join(moved) in note and f"largest move {worst}, {moved[worst]:.2f} mm" in note
    assert settling_note({}) == ""
    many = {f"S{i}": 0.01 * i for i in range(1, 14)}
    assert "S1, S2, S3, S4, S5, S6, S7, S8, S9, S10, ... (3 more)" in settling_note(
        {"settling_taken_out_mm": many}
    )


def test_localize_names_the_sensors_placed_from_their_peaks_flanks(tmp_path, capsys):
    """A 10 x 4 robot plan leaves gaps wider than a bump: the sensors no touch came near
    are named, with the largest move the other response shapes gave, above the summary
    line; the JSON's params hold every one of them."""
    logs = tmp_path / "logs.csv"
    args = ["simulate", "--patch", "patch_b", "--grid", "10x4", "--probe", "robot"]
    assert main([*args, "--seed", "1", "-o", str(logs)]) == 0
    note, spread, worst = _note_above_summary(
        capsys, tmp_path, [str(logs), "--patch", "patch_b"], "shape_spread_mm"
    )
    assert note.startswith(f"{len(spread)} sensor(s) placed from their peaks' flanks, ")
    assert ", ".join(spread) in note
    assert f"other response shapes {worst}, {spread[worst]:.2f} mm" in note
    assert unseen_note({}) == ""


def _note_above_summary(capsys, tmp_path, args, key):
    """``varskin localize ARGS --json``: the line just above the summary line, the JSON
    params' ``key`` (sensor: mm, every value > 0) and its sensor of the largest value."""
    path = tmp_path / "p.json"
    capsys.readouterr()
    assert main(["localize", *args, "--json", str(path)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1].startswith("peakfit: ")
    by_sensor = json.loads(path.read_text())["params"][key]
    assert by_sensor and all(v > 0 for v in by_sensor.values())
    return lines[-2], by_sensor, max(by_sensor, key=by_sensor.get)


def test_localize_first_order_sigma_skips_the_error_bar_check(simulated, tmp_path):
    """``--first-order-sigma`` gives the sigmas of ``calibrate_sigma=False``, the same
    positions, and sigmas that differ from the checked default (on this finger scene the
    check narrows them). With the patch: without it, the wires inferred may differ."""
    from varskin.localization import localize
    from varskin.patch import builtin_patch
    from varskin.pointlog_csv import read_point_logs

    logs, _ = simulated
    out, scale = {}, {}
    for name, extra in (("checked", []), ("first", ["--first-order-sigma"])):
        extra = [*extra, "--patch", "patch_b"]
        path = tmp_path / f"{name}.json"
        assert main(["localize", str(logs), "-q", "--json", str(path), *extra]) == 0
        saved = json.loads(path.read_text())
        out[name] = {e["sensor"]: e for e in saved["sensors"]}
        scale[name] = saved["params"]["sigma_scale"]
    assert scale["first"] == 1.0
    direct = localize(read_point_logs(logs), calibrate_sigma=False, patch=builtin_patch("patch_b"))
    for e in direct:
        got = out["first"][e.sensor]
        assert got["status"] == e.status
        if e.status == "ok":
            assert got["sigma_mm"] == pytest.approx(e.sigma_mm, rel=1e-9)
    both = [s for s, e in out["first"].items() if e["status"] == "ok"]
    both = [s for s in both if out["checked"][s]["status"] == "ok"]
    assert len(both) >= 25
    for s in both:
        assert out["checked"][s]["x_mm"] == pytest.approx(out["first"][s]["x_mm"], abs=1e-9)
    ratio = [out["checked"][s]["sigma_mm"] / out["first"][s]["sigma_mm"] for s in both]
    assert np.ptp(ratio) < 1e-6 and abs(ratio[0] - 1.0) > 0.05, ratio[:3]
    assert ratio[0] == pytest.approx(scale["checked"], rel=1e-9)


def test_localize_settle_rounds_reaches_the_solver_and_refuses_bad_counts(
    simulated, tmp_path, capsys
):
    """``--settle-rounds N`` gives ``localize(..., settle_rounds=N)``'s positions (on this
    finger scene 0 rounds differ from the default's 12), and ``--joint-settle-rounds N``
    ``joint_settle_rounds=N``'s (with --patch the default takes none); a negative count or
    one the paper method has no use for is a one-line error."""
    from varskin.localization import localize
    from varskin.patch import builtin_patch
    from varskin.pointlog_csv import read_point_logs

    logs, _ = simulated
    path = tmp_path / "zero.json"
    args = ["localize", str(logs), "-q", "--patch", "patch_b", "--first-order-sigma"]
    assert main([*args, "--settle-rounds", "0", "--json", str(path)]) == 0
    got = {e["sensor"]: e for e in json.loads(path.read_text())["sensors"]}
    kw = {"calibrate_sigma": False, "patch": builtin_patch("patch_b")}
    zero = localize(read_point_logs(logs), settle_rounds=0, **kw)
    default = localize(read_point_logs(logs), **kw)
    moved = 0.0
    for e, d in zip(zero, default, strict=True):
        assert got[e.sensor]["x_mm"] == e.x_mm and got[e.sensor]["y_mm"] == e.y_mm
        if e.x_mm is not None and d.x_mm is not None:
            moved = max(moved, abs(e.x_mm - d.x_mm), abs(e.y_mm - d.y_mm))
    assert moved > 0.01
    assert main([*args, "--joint-settle-rounds", "8", "--json", str(path)]) == 0
    got = {e["sensor"]: e for e in json.loads(path.read_text())["sensors"]}
    joint = localize(read_point_logs(logs), joint_settle_rounds=8, **kw)
    assert "joint_settle_ratio" in joint.params and "joint_settle_ratio" not in default.params
    for e in joint:
        assert got[e.sensor]["x_mm"] == e.x_mm and got[e.sensor]["y_mm"] == e.y_mm
    capsys.readouterr()
    for bad in (
        ["--settle-rounds", "-1"],
        ["--method", "paper", "--settle-rounds", "40"],
        ["--joint-settle-rounds", "-1"],
    ):
        assert main(["localize", str(logs), "-q", *bad]) == 2
        err = capsys.readouterr().err
        assert "settle_rounds" in err and "Traceback" not in err and err.count("\n") == 1, err


def test_localize_response_shape_fixes_the_profile_or_lets_the_patch_choose(simulated, capsys):
    """``--response-shape gaussian`` fits that profile (the summary says so); the default,
    auto, keeps the Lorentzian on this Lorentzian scene and reports the test it ran. An
    unknown shape is argparse's one-line error."""
    from varskin.localization import localize
    from varskin.patch import builtin_patch
    from varskin.pointlog_csv import read_point_logs

    logs, _ = simulated
    args = ["localize", str(logs), "--patch", "patch_b", "--first-order-sigma"]
    kw = {"calibrate_sigma": False, "patch": builtin_patch("patch_b")}
    capsys.readouterr()
    assert main([*args, "--response-shape", "gaussian"]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.endswith("wires from the patch; gaussian response"), last
    fixed = localize(read_point_logs(logs), response_shape="gaussian", **kw)
    auto = localize(read_point_logs(logs), **kw)
    assert fixed.params["response_shape"] == "gaussian" and "response_shape_z" not in fixed.params
    assert auto.params["response_shape"] == "lorentzian"
    assert auto.params["response_shape_z"] > -3.0
    assert np.nanmax(np.abs(fixed.xy() - auto.xy())) > 0.01  # the profile moved them
    assert main([*args]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1].endswith("wires from the patch")
    with pytest.raises(SystemExit):
        main([*args, "--response-shape", "sech"])
    err = capsys.readouterr().err
    assert "invalid choice: 'sech'" in err and "Traceback" not in err

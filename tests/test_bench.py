"""``varskin bench --quick`` runs end to end and writes its table and figures (no timings
are asserted: timing claims come from the full bench, run by hand)."""

from __future__ import annotations

from varskin.bench import GRIDS, PUBLISHED, BenchConfig, plan
from varskin.cli import main


def test_quick_bench_writes_table_and_figures(tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["bench", "--quick", "--out", str(out), "--seeds", "100"]) == 0
    printed = capsys.readouterr().out
    assert "peakfit" in printed and "paper eta=0.65,ppcm=16" in printed
    for name in ("pareto.png", "error_vs_logs.png", "eta_ppcm_map.png"):
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    md = (out / "results.md").read_text()
    assert "| method |" in md and "RMS/paper" in md
    rows = [line for line in md.splitlines() if line.startswith("| peakfit |")]
    assert len(rows) == 2 * 3  # two probes x three numbers of point logs
    assert sum(line.startswith("| peakfit patch=wires |") for line in md.splitlines()) == 6
    # The reference row of the paper has ratio 1 to itself.
    ref = [line for line in md.splitlines() if line.startswith("| paper eta=0.65,ppcm=16")]
    assert ref and all("| 1.000 | 1.00 |" in line for line in ref)


def test_full_plan_covers_the_issue_grid():
    cfg = BenchConfig()
    jobs = plan(cfg)
    paper_map = {(p["eta"], p["ppcm"]) for m, p, n in jobs if m == "paper" and n == 100}
    assert len(paper_map) == 7 * 4
    assert {n for m, _, n in jobs if m == "peakfit"} == {20, 40, 60, 80, 100}
    assert set(GRIDS) == set(PUBLISHED["patch_b"]) == set(cfg.n_logs)
    assert all(abs(a * b - n) <= 0.05 * n for n, (a, b) in GRIDS.items())


def test_bad_repeats_is_a_one_line_error(capsys, tmp_path):
    assert main(["bench", "--quick", "--repeats", "0", "--out", str(tmp_path)]) == 2
    assert "--repeats" in capsys.readouterr().err

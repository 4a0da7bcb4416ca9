"""Wires inferred from fitted positions: right when the grid is clear, absent when not."""

from __future__ import annotations

import numpy as np
import pytest

from varskin.localization import localize
from varskin.localization._wire_inference import infer_wires
from varskin.simulate import simulate_session, uniform_grid


def same_partition(found: np.ndarray, truth: np.ndarray) -> bool:
    """Every pair of assigned sensors is together in ``found`` iff together in ``truth``."""
    m = found >= 0
    a = found[m][:, None] == found[m][None, :]
    b = truth[m][:, None] == truth[m][None, :]
    return bool((a == b).all())


def wires_of(patch) -> tuple[np.ndarray, np.ndarray]:
    return np.array([s.tx for s in patch.sensors]), np.array([s.rx for s in patch.sensors])


@pytest.fixture
def seen(monkeypatch) -> list:
    """Every answer of ``infer_wires`` as the localizer calls it, in order."""
    from varskin.localization import _statuses

    answers = []

    def spy(*args):
        answers.append(infer_wires(*args))
        return answers[-1]

    monkeypatch.setattr(_statuses, "infer_wires", spy)
    return answers


@pytest.mark.parametrize("name", ["patch_a", "patch_b"])
def test_a_clear_grid_gives_every_sensor_its_wires(name, request):
    patch = request.getfixturevalue(name)
    tx, rx = wires_of(patch)
    rng = np.random.default_rng(1)
    xy = patch.design_xy + rng.normal(0, 0.2, patch.design_xy.shape)
    sd = np.full((len(tx), 2), 0.2)
    found = infer_wires(xy, sd, np.ones(len(tx), bool), np.zeros(len(tx), bool), 0.25)
    assert found is not None
    gx, gy = found
    assert (gx >= 0).all() and (gy >= 0).all()
    assert same_partition(gx, tx) and same_partition(gy, rx)


def test_an_extrapolated_last_column_keeps_its_wire_by_rank(patch_b):
    """The sensors beyond the last probe column, 2-4 mm off with sd ~3 mm, are the ones the
    prior is for: within their rows they are still the last, so they keep their TX wire."""
    tx, rx = wires_of(patch_b)
    rng = np.random.default_rng(2)
    xy = patch_b.design_xy + rng.normal(0, 0.3, patch_b.design_xy.shape)
    sd = np.full((len(tx), 2), 0.3)
    last = tx == tx.max()
    xy[last, 0] += [4.0, 2.5, 3.0]
    sd[last, 0] = 3.0  # loose along x only: one flank seen
    gx, gy = infer_wires(xy, sd, np.ones(len(tx), bool), np.zeros(len(tx), bool), 0.25)
    assert same_partition(gx, tx) and same_partition(gy, rx)
    assert (gx[last] >= 0).all() and len(set(gx[last])) == 1


@pytest.mark.parametrize(("loose_x_mm", "ranked"), [(152.4, True), (135.0, False)])
def test_a_row_completed_by_a_loose_sensor_is_ranked(patch_b, loose_x_mm, ranked):
    """Patch B finger, seed 540: S28 too loose to be located beyond the last probe column,
    and S25 between the last two columns, reaching both. Neither joins a column alone; once
    S28 has joined its row, the row has a sensor for every column and is ranked, which
    gives S25 the last column but one and S28 the last. A loose sensor whose rank would
    take a column its row already holds (fitted inside the last column but two) leaves the
    row as it was."""
    tx, rx = wires_of(patch_b)
    rng = np.random.default_rng(9)
    xy = patch_b.design_xy + rng.normal(0, 0.2, patch_b.design_xy.shape)
    sd = np.full((len(tx), 2), 0.2)
    s25, s28 = 24, 27
    assert tx[s28] == tx.max() and tx[s25] == tx.max() - 1 and rx[s25] == rx[s28]
    xy[s25, 0], sd[s25, 0] = 146.3, 1.3  # 1.0 and 2.1 mm from the two columns' centres
    xy[s28, 0], sd[s28, 0] = loose_x_mm, 3.5
    located = np.ones(len(tx), bool)
    located[s28] = False
    gx, gy = infer_wires(xy, sd, located, ~located, 0.25)
    assert same_partition(gx, tx) and same_partition(gy, rx)
    assert gy[s28] == gy[s25]  # S28 joined its row either way
    if ranked:
        assert gx[s25] == gx[s25 + 1] and gx[s28] == gx[s28 + 1]
        assert (gx >= 0).all()
    else:
        assert gx[s25] == -1 and gx[s28] == -1
        assert (np.delete(gx, [s25, s28]) >= 0).all()


def test_columns_too_close_to_tell_apart_get_no_wire(patch_b):
    """Patch B's last two TX wires are 3.2 mm apart: with 1 mm fits the ranks within a row
    may swap, so those two columns keep no TX wire; the others and every row do."""
    tx, rx = wires_of(patch_b)
    rng = np.random.default_rng(3)
    xy = patch_b.design_xy + rng.normal(0, [1.0, 0.3], patch_b.design_xy.shape)
    sd = np.tile([1.0, 0.3], (len(tx), 1))
    gx, gy = infer_wires(xy, sd, np.ones(len(tx), bool), np.zeros(len(tx), bool), 0.25)
    assert same_partition(gx, tx) and same_partition(gy, rx)
    assert (gx[tx >= tx.max() - 1] == -1).all()
    assert (gx[tx < tx.max() - 1] >= 0).all() and (gy >= 0).all()


def test_a_loose_sensor_far_off_gets_no_wire(patch_b):
    """A sensor too loose to be located, fitted 20 mm off with a 10 mm sd (as on Patch A,
    12 x 3 robot, seed 317): more than one row is within its reach, so it gets no wire, and
    the others keep theirs."""
    tx, rx = wires_of(patch_b)
    rng = np.random.default_rng(6)
    xy = patch_b.design_xy + rng.normal(0, 0.2, patch_b.design_xy.shape)
    sd = np.full((len(tx), 2), 0.2)
    located = np.ones(len(tx), bool)
    far = 3  # S4
    xy[far] = (-0.5, -14.0)
    sd[far] = (29.0, 10.0)
    located[far] = False
    gx, gy = infer_wires(xy, sd, located, ~located, 0.25)
    assert gx[far] == -1 and gy[far] == -1
    assert same_partition(gx, tx) and same_partition(gy, rx)
    assert ((gx >= 0) & (gy >= 0)).sum() >= 25


@pytest.mark.parametrize(
    ("beyond_mm", "sd_mm", "sd_x_mm", "joins"),  # joins: (its row, its column)
    [
        # Patch B finger, seed 338: S1 fitted 5 mm beyond the last row with a 3.1 mm sd
        # (over half the ~6 mm gap between rows), 3.97 mm off when it kept no wire.
        (6.0, 3.3, 0.2, (True, True)),
        # Patch B finger, plan grid, seed 469: 3.6 mm beyond with a 9.5 mm sd along y, so
        # within reach of two rows and joining neither; its column is sure, and that
        # column's other two crossings are held: it is placed on the free one.
        (3.6, 9.5, 0.2, (True, True)),
        # The same at 2.4 sd from the free row: that column has no other to offer.
        (21.6, 9.0, 0.2, (True, True)),
        # A fit flung far out in x as well: no sure column, and 2.4 sd from its row against
        # 3.1 from the next is far from 100 to 1.
        (21.6, 9.0, 20.0, (False, False)),
        # Beyond JOIN_SDS of the free row: it keeps its sure column, and no row.
        (30.0, 9.0, 0.2, (False, True)),
    ],
)
def test_a_loose_sensor_beyond_the_last_row_joins_it_only_at_clear_odds(
    patch_b, beyond_mm, sd_mm, sd_x_mm, joins
):
    tx, rx = wires_of(patch_b)
    rng = np.random.default_rng(7)
    xy = patch_b.design_xy + rng.normal(0, 0.2, patch_b.design_xy.shape)
    sd = np.full((len(tx), 2), 0.2)
    corner = 0  # S1: first TX wire, the RX wire of the largest y
    assert rx[corner] == 0 and xy[rx == 0, 1].mean() > xy[rx == 1, 1].mean()
    xy[corner, 1] = patch_b.design_xy[corner, 1] + beyond_mm
    sd[corner] = (sd_x_mm, sd_mm)
    located = np.ones(len(tx), bool)
    located[corner] = False
    variants = [~located, np.zeros(len(tx), bool)]  # too loose to locate, or located
    if beyond_mm > 3.0 * sd_mm:
        # Located, yet beyond every row's reach: it refutes the rows (one may be missing).
        assert infer_wires(xy, sd, np.ones(len(tx), bool), variants.pop(), 0.25) is None
    for loose in variants:
        gx, gy = infer_wires(xy, sd, located | ~loose, loose, 0.25)
        assert same_partition(gx, tx) and same_partition(gy, rx)
        row, column = joins
        assert gy[corner] == (gy[3] if row else -1)  # S4 is on the same RX wire
        assert gx[corner] == (gx[1] if column else -1)  # and S2 on the same TX wire


def test_rows_that_slant_apart_are_cut_as_lines(patch_b):
    """Patch B finger, plan grid, seed 403: its middle RX wire displaced 2 mm towards the
    next at one end and bent, so the two are 3.3 mm apart at x = 6 and 4.4 mm at x = 148.
    Sorted by y, the rows' ends interleave with the gap between them: no cut is clear, and
    level rows gave no wires. As lines each row is clear, and the grid is the simulator's;
    the corner's loose S1 then joins its row. Rows that cross are still refused."""
    tx, rx = wires_of(patch_b)
    x = patch_b.design_xy[:, 0]
    rng = np.random.default_rng(8)
    lines = {0: (21.0, 0.0), 1: (11.1, 0.015), 2: (8.0, 0.006)}  # y at x = 4, slope
    y = np.array([lines[r][0] + lines[r][1] * (xi - 4.0) for r, xi in zip(rx, x, strict=True)])
    xy = np.column_stack([x, y]) + rng.normal(0, [0.5, 0.3], (len(tx), 2))
    sd = np.tile([0.55, 0.6], (len(tx), 1))
    xy[0, 1], sd[0, 1] = 23.25, 2.9  # S1, fitted beyond the top row, loose in y
    ys = np.sort(xy[:, 1])
    gaps = np.diff(ys) / np.hypot(0.6, 0.6)
    assert np.sort(gaps)[-2] < 4.0  # the second-widest gap is no clear cut (CUT_SDS)
    ok = np.ones(len(tx), bool)
    gx, gy = infer_wires(xy, sd, ok, ~ok, 0.25)
    assert same_partition(gx, tx) and same_partition(gy, rx)
    assert (gy >= 0).all() and gy[0] == gy[3]
    crossing = xy.copy()
    crossing[rx == 2, 1] = 17.5 - 0.06 * x[rx == 2]  # from above row 1 to below it
    assert infer_wires(crossing, sd, ok, ~ok, 0.25) is None


def test_a_settled_finger_solve_infers_its_wires_at_the_checked_sds(patch_b, seen):
    """A settled finger solve's first-order sds are wider than its errors by the error-bar
    check's factor (0.6 here); at them this scene's rows blurred as level rows and no grid
    was clear. At the checked sds the grid is, at the first try, and it is the simulator's.
    Since rows may be cut as slanted lines, the first-order sds find the same grid too.
    (The alternation's solve, as where its joint rounds are declined: kept, they sharpen
    this scene's rows enough for the first-order sds as well.)"""
    from varskin.localization import _statuses
    from varskin.localization.peakfit import solved

    tx, rx = wires_of(patch_b)
    s = simulate_session(patch_b, uniform_grid(patch_b, 20, 5), "finger", 1)
    loc = solved(s.point_logs(), joint_settle_rounds=0)
    assert loc._settled and loc._sigma_scale < 0.7
    seen.clear()  # the solve's own calls
    assert _statuses.judge(loc)[4]["wires"] == "inferred"
    assert len(seen) == 1  # answered at the checked sds: no fallback to the first-order ones
    gx, gy = seen[-1]
    assert same_partition(gx, tx) and same_partition(gy, rx)
    assert (gx >= 0).mean() >= 0.9 and (gy >= 0).all()
    loc._sigma_scale = 1.0  # the first-order sds alone
    seen.clear()
    assert _statuses.judge(loc)[4]["wires"] == "inferred"
    gx1, gy1 = seen[-1]
    assert same_partition(gx1, tx) and same_partition(gy1, rx)


def test_no_grid_means_no_wires():
    rng = np.random.default_rng(4)
    xy = rng.uniform(0, 100, (30, 2))  # scattered: no rows, no columns
    assert (
        infer_wires(xy, np.full((30, 2), 0.3), np.ones(30, bool), np.zeros(30, bool), 0.25) is None
    )
    # A grid turned 30 degrees in the patch frame: its wires are not along x and y.
    gx, gy = np.meshgrid(np.arange(10) * 10.0, np.arange(3) * 8.0, indexing="ij")
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    turned = pts @ np.array([[c, s], [-s, c]])
    assert (
        infer_wires(turned, np.full((30, 2), 0.2), np.ones(30, bool), np.zeros(30, bool), 0.25)
        is None
    )


def test_rows_that_would_merge_two_wires_are_not_taken(patch_b):
    """Two RX wires 3 mm apart, too close to cut with 0.7 mm fits, and a third far off, with
    five sensors of the close pair unlocated: the pair then fits one 'row' of 15, as a 15 x 2
    grid would have it. Its columns come out unclear (each holds two sensors at one x), so
    that grid is refused, and with the 10 x 3 one unclear too, nothing is returned."""
    tx, rx = wires_of(patch_b)
    xy = patch_b.design_xy.copy()
    xy[:, 1] = np.array([20.0, 9.5, 6.5])[rx]
    rng = np.random.default_rng(5)
    xy += rng.normal(0, 0.1, xy.shape)
    usable = np.ones(len(tx), bool)
    usable[np.flatnonzero(rx >= 1)[::3][:5]] = False
    assert (
        infer_wires(xy, np.full((len(tx), 2), 0.7), usable, np.zeros(len(tx), bool), 0.25) is None
    )


def test_localize_without_a_patch_infers_the_wires_of_a_finger_session(patch_b):
    """No patch, no wires: the layout prior runs on inferred wires, as well as with the
    wires given, and better than without it; ``infer_wires=False`` turns it off. (The
    joint rounds these solves take narrowed the prior's gain: RMS 0.513 against 0.621 mm
    without them, 0.362 against 0.399 mm with them.)"""
    tx, rx = wires_of(patch_b)
    wires = {s.name: (s.tx, s.rx) for s in patch_b.sensors}
    err = {"inferred": [], "given": [], "off": []}
    for seed in (11, 12, 13):
        s = simulate_session(patch_b, uniform_grid(patch_b, 20, 5), "finger", seed)
        logs = s.point_logs()
        runs = {
            "inferred": localize(logs),
            "given": localize(logs, wires=wires),
            "off": localize(logs, infer_wires=False),
        }
        for k, pred in runs.items():
            e = np.hypot(*(pred.xy() - s.truth).T)
            err[k].append(e[np.isfinite(e)])
        assert [runs[k].params["wires"] for k in runs] == ["inferred", "given", "none"]
    rms = {k: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for k, v in err.items()}
    assert rms["inferred"] <= 1.05 * rms["given"], rms
    assert rms["inferred"] <= 0.95 * rms["off"], rms


@pytest.mark.parametrize(("seed", "within_mm"), [(403, 2.0), (469, 1.0)])
def test_the_corner_sensor_of_a_slanted_or_loose_row_keeps_its_wires(
    patch_b, seen, seed, within_mm
):
    """The two Patch B finger scenes on ``varskin calibrate``'s plan grid (seeds 360-559)
    that, without a patch, kept a sensor above 2 mm: S1 at the corner, 2.38 mm off with
    its rows slanting apart (403: no wires were inferred) and 3.65 mm off loose in y
    across two rows (469: no wire for S1). Now both its wires are inferred: 1.91 and
    0.48 mm. (403 keeps a ~1.8 mm shift of its whole first TX wire in x, with the patch
    given too: 1.63 mm.)"""
    from varskin.planning import uniform_points

    tx, rx = wires_of(patch_b)
    s = simulate_session(patch_b, uniform_points(patch_b, 20, 5), "finger", seed)
    pred = localize(s.point_logs())
    assert pred.params["wires"] == "inferred"
    gx, gy = seen[-1]
    assert same_partition(gx, tx) and same_partition(gy, rx)
    assert gx[0] >= 0 and gy[0] >= 0
    e = np.hypot(*(pred.xy() - s.truth).T)
    assert np.isfinite(e[0]) and e[0] < within_mm, e[0]
    assert np.nanmax(e) < 2.0

"""Re-running a recorded session without hardware, and proving it matches the live run.

Replay takes the session file alone. It re-cuts every point log from the stored raw frames
and the stored touch times (the same ``touch_window`` code the live session ran), feeds the
point logs in plan order to a fresh live localizer (the same updates the terminal showed),
and batch-solves them with any method. Against what the live run stored it reports the
largest difference of each stage, so "bit for bit" is a checked claim, not a hope.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from varskin.board.cellmap import CellMap
from varskin.localization.peakfit import Localizer
from varskin.patch import Patch
from varskin.pointlogs import PointLog
from varskin.predictions import Predictions
from varskin.session import final_estimate, live_estimate, live_schedule, window_config
from varskin.store import SessionStore, StoredLog
from varskin.touch_window import REST, TouchTimes, WindowConfig, WindowProblem, cut_point_log


@dataclass(frozen=True)
class ReplayResult:
    predictions: Predictions  # the batch estimate with the requested method
    n_logs: int
    # largest |re-cut - stored| point-log value, counts (0.0: identical; inf: a point
    # log could not be re-cut, its frames or attempt record missing or damaged)
    recut_max_diff: float
    live_max_diff_mm: float  # largest difference of the live estimates (0.0: identical)
    live_status_mismatches: int
    final_max_diff_mm: float | None  # vs the stored final of the same method; None: none stored
    final_status_mismatches: int


def _max_diff(a: Predictions, b: Predictions) -> tuple[float, int]:
    """Largest coordinate/sigma difference (mm) and number of differing statuses (a sensor
    missing from the stored estimates, as in a damaged file, counts as one)."""
    worst, mismatches = 0.0, abs(len(a.estimates) - len(b.estimates))
    for ea, eb in zip(a.estimates, b.estimates, strict=False):
        if ea.sensor != eb.sensor or ea.status != eb.status:
            mismatches += 1
            continue
        for u, v in ((ea.x_mm, eb.x_mm), (ea.y_mm, eb.y_mm), (ea.sigma_mm, eb.sigma_mm)):
            if (u is None) != (v is None):
                mismatches += 1
            elif u is not None:
                worst = max(worst, abs(u - v))
    return worst, mismatches


def recut_logs(
    store: SessionStore, patch: Patch, cfg: WindowConfig | None = None
) -> list[tuple[StoredLog, PointLog, int]] | None:
    """Every stored point log cut again from the stored frames, with ``cfg`` (default: the
    session's own windows): (stored, re-cut, its baseline frames) in plan order; None if
    some cannot be (frames, an attempt record or the rest values lost)."""
    cfg = cfg or window_config(store)
    cellmap = CellMap.from_patch(patch)
    base = store.baseline()
    rest = base[0] if base else None
    if rest is None and cfg.reference == REST:
        return None
    out = []
    for s in store.stored_logs():
        a = store.attempt(s.attempt_id)
        if None in (a.seq_first, a.seq_last, a.t_start, a.t_contact, a.t_settled, a.t_release):
            return None
        times = TouchTimes(a.t_start, a.t_contact, a.t_settled, a.t_release)
        frames = store.frames_by_seq(a.seq_first, a.seq_last)
        try:
            log, n_base = cut_point_log(
                frames, times, cellmap, cfg, s.plan_index, s.log.x_mm, s.log.y_mm,
                s.log.force_n, s.log.t_s, rest,
            )  # fmt: skip
        except WindowProblem:
            return None
        out.append((s, log, n_base))
    return out


def recut_point_logs(store: SessionStore, patch: Patch) -> float:
    """Re-cut every stored point log from the stored frames; the largest difference."""
    recut = recut_logs(store, patch)
    if recut is None:
        return np.inf
    worst = 0.0
    for s, log, n_base in recut:
        diff = np.abs(log.values - s.log.values).max() if len(log.values) else 0.0
        diff = max(diff, np.abs(log.sample_sd - s.log.sample_sd).max())
        if log.n_samples != s.log.n_samples or n_base != s.n_baseline:
            diff = np.inf
        worst = max(worst, float(diff))
    return worst


def replay(store: SessionStore, patch: Patch, method: str | None = None) -> ReplayResult:
    meta = store.meta()
    method = method or str(meta.get("method", "peakfit"))
    recut = recut_point_logs(store, patch)
    logs = store.point_logs()
    live = store.estimates("live")
    loc = Localizer(logs.sensors, rest=logs.rest, rest_sd=logs.rest_sd, patch=patch)
    live_diff, live_bad = 0.0, 0
    mode, batch_after = live_schedule(store.path, meta)
    for k, log in enumerate(logs.logs(), 1):
        p = live_estimate(loc, log, mode, batch_after)
        if k in live:
            d, m = _max_diff(p, live[k])
            live_diff, live_bad = max(live_diff, d), live_bad + m
        else:
            live_bad += 1
    final = final_estimate(logs, method, patch)
    stored_final = store.estimates("final", method).get(len(logs))
    final_diff: float | None = None
    final_bad = 0
    if stored_final is not None:
        final_diff, final_bad = _max_diff(final, stored_final)
    return ReplayResult(final, len(logs), recut, live_diff, live_bad, final_diff, final_bad)

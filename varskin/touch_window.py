"""Cutting one touch's point log out of the frame stream, the same way live and in replay.

The recorder stamps each frame with the host's monotonic clock when its line completes; the
arm reports the touch's phases (start of descent, contact, force settled, release) on the
same clock. A frame's *sample time* is its stamp minus the line's transmission latency.
Two windows are cut:

* the **baseline**: no-contact frames during the descent, ending ``guard_s`` before contact
  (the probe's approach and the first squeeze are transitions), at most ``baseline_s`` long;
* the **touch**: frames sampled between force settled and release (the arm's dwell).

The point log is the robust mean of the touch window minus a reference (``reference``):

* the session's **rest** values (the no-contact frames measured before the first touch), as
  in every point log the localizer reads elsewhere: the board's slow offset drift stays in
  the log, and the localizer takes each sensor's floor from its own map. On ten
  simulated-rig scenes of Patch B the median RMS was 0.198 mm this way and 0.305 mm against
  the baselines, from the same frames;
* or the touch's own **baseline** window, which cancels the drift between touches but adds
  that window's noise to every log. A patch at most ``planning.SHUFFLE_UP_TO_MM`` long
  needs it: there each sensor's own touches span the whole session, the board's settling
  falls within them, and against the rest 1.0-1.9 sensors per scene came out ``drifting``
  on the 20-50 mm patches measured (``reference_for``).

Sessions stored before 2026-11-29 were all cut against their baselines, and are replayed
and resumed that way (docs/benchmarks.md, "The main job's point logs: against the rest").
The baseline window is cut either way: it shows the board streamed through the approach.
Everything here is a pure function of the frames, the attempt's times and the rest: replay
runs this very code on the stored frames and gets the stored point log back bit for bit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from varskin.board.cellmap import CellMap
from varskin.board.frame import Frame, Gap
from varskin.patch import Patch
from varskin.planning import is_small_patch
from varskin.pointlogs import PointLog

REST = "rest"  # the session's rest values
BASELINE = "baseline"  # the touch's own no-contact window
REFERENCES = (REST, BASELINE)


@dataclass(frozen=True)
class WindowConfig:
    """Host-clock seconds (a time-scaled simulated rig divides its values by the scale)."""

    baseline_s: float = 1.0  # longest no-contact window before contact
    guard_s: float = 0.15  # excluded before contact: the probe is landing
    latency_s: float = 0.0  # line transmission: a frame was sampled this long before its stamp
    min_touch_frames: int = 3
    min_baseline_frames: int = 2
    max_frame_interval_s: float = 0.6  # a longer silence inside a window is a board gap
    reference: str = REST  # what a log's values are relative to: REST or BASELINE

    def scaled(self, time_scale: float) -> WindowConfig:
        """The same windows on a rig whose clock runs ``time_scale`` times faster."""
        k = float(time_scale)
        return replace(
            self,
            baseline_s=self.baseline_s / k,
            guard_s=self.guard_s / k,
            latency_s=self.latency_s / k,
            max_frame_interval_s=self.max_frame_interval_s / k,
        )


def reference_for(patch: Patch) -> str:
    """What a new session's point logs on ``patch`` are taken against: BASELINE on a small
    patch (``planning.is_small_patch``, whose plan is shuffled), else REST."""
    return BASELINE if is_small_patch(patch) else REST


def stored_window(w: dict) -> WindowConfig:
    """The windows a session stored in its meta; ``TypeError`` or ``ValueError`` if damaged.
    A session stored before point logs had a ``reference`` was cut against its baselines."""
    cfg = WindowConfig(**{"reference": BASELINE, **w})
    if cfg.reference not in REFERENCES:
        raise ValueError(f"unknown point-log reference {cfg.reference!r}")
    return cfg


class WindowProblem(Exception):
    """The frames do not make a trustworthy point log; ``kind`` says why ("board_gap")."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class TouchTimes:
    t_start: float  # the descent began (the probe is at clearance height)
    t_contact: float
    t_settled: float
    t_release: float


def robust_mean(samples: np.ndarray, floor: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Per column: the mean of the samples within 3 robust sigmas of the median, and their
    standard deviation. A spike (a garbled cell, an ESD glitch) in one frame cannot move the
    log; ``floor`` keeps integer counts with zero MAD from rejecting everything but the median.
    """
    x = np.asarray(samples, float)
    med = np.median(x, axis=0)
    mad = 1.4826 * np.median(np.abs(x - med), axis=0)
    keep = np.abs(x - med) <= 3.0 * np.maximum(mad, floor)
    n = keep.sum(axis=0)
    mean = np.where(keep, x, 0.0).sum(axis=0) / n
    dev = np.where(keep, x - mean, 0.0)
    sd = np.sqrt((dev**2).sum(axis=0) / np.maximum(n - 1, 1))
    return mean, sd


def _sample_times(frames: Sequence[Frame], cfg: WindowConfig) -> np.ndarray:
    return np.array([f.t for f in frames], float) - cfg.latency_s


def check_link(gaps: Sequence[Gap], t0: float, t1: float) -> None:
    """Raise ``WindowProblem("board_gap")`` if the recorder lost the link anywhere in
    [t0, t1] (the loss starts at the last frame before the gap was noticed)."""
    for g in gaps:
        lost = g.last_frame_t if g.last_frame_t is not None else g.start
        if lost <= t1 and g.end >= t0:
            raise WindowProblem("board_gap", f"board link down {g.duration_s:.2f} s ({g.reason})")


def _check_silence(ts: np.ndarray, start: float, end: float, what: str, cfg: WindowConfig):
    """A board that stops sending without dropping the link (a hung firmware, a starved
    host) leaves a hole in a window; the frames around it would misrepresent the touch."""
    edges = np.concatenate([[start], ts, [end]])
    silence = float(np.max(np.diff(edges)))
    if silence > cfg.max_frame_interval_s:
        raise WindowProblem("board_gap", f"no frame for {silence:.2f} s in the {what} window")


def cut_point_log(
    frames: Sequence[Frame],
    times: TouchTimes,
    cellmap: CellMap,
    cfg: WindowConfig,
    touch: int,
    x_mm: float,
    y_mm: float,
    force_n: float,
    t_session_s: float,
    rest: np.ndarray | None,
) -> tuple[PointLog, int]:
    """(point log, number of baseline frames) for one touch; ``WindowProblem`` if the
    windows hold too few frames. ``frames`` may be any superset of the touch's frames;
    ``rest`` (per used cell, in the cell map's order) is needed unless ``cfg.reference`` is
    ``BASELINE``."""
    if cfg.reference == REST and rest is None:
        raise ValueError("a point log against the rest needs the session's rest values")
    ts = _sample_times(frames, cfg)
    b_end = times.t_contact - cfg.guard_s
    b_start = max(times.t_start, b_end - cfg.baseline_s)
    base_rows = [f for f, t in zip(frames, ts, strict=True) if b_start <= t <= b_end]
    touch_rows = [
        f for f, t in zip(frames, ts, strict=True) if times.t_settled <= t <= times.t_release
    ]
    if len(touch_rows) < cfg.min_touch_frames:
        raise WindowProblem(
            "board_gap",
            f"{len(touch_rows)} frame(s) in the touch window, need {cfg.min_touch_frames}",
        )
    if len(base_rows) < cfg.min_baseline_frames:
        raise WindowProblem(
            "board_gap",
            f"{len(base_rows)} frame(s) in the baseline window, need {cfg.min_baseline_frames}",
        )
    _check_silence(ts[(ts >= b_start) & (ts <= b_end)], b_start, b_end, "baseline", cfg)
    in_touch = (ts >= times.t_settled) & (ts <= times.t_release)
    _check_silence(ts[in_touch], times.t_settled, times.t_release, "touch", cfg)
    touch_mean, touch_sd = robust_mean(np.array([cellmap.values(f) for f in touch_rows]))
    if cfg.reference == REST:
        reference = np.asarray(rest, float)
    else:
        reference, _ = robust_mean(np.array([cellmap.values(f) for f in base_rows]))
    log = PointLog(
        touch=touch,
        x_mm=float(x_mm),
        y_mm=float(y_mm),
        values=touch_mean - reference,
        n_samples=len(touch_rows),
        sample_sd=touch_sd,
        t_s=float(t_session_s),
        force_n=float(force_n),
    )
    return log, len(base_rows)

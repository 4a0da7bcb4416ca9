"""The calibration loop: plan a touch, make it, cut its point log, update, store, repeat.

This is where the devices meet the mathematics. For every touch the planner proposes, the
session moves the arm above it and presses; the arm reports its phases on the host clock,
the recorder stamps frames on the same clock, and ``touch_window`` cuts the point log out
of the stream. A touch without contact, with a board gap or with too few frames is retried
a bounded number of times; a protective stop pauses the session until someone unlocks the
arm on the pendant. Each finished touch is committed to the ``SessionStore`` with the live
estimates after it, so a killed session resumes (``resume=True``) by re-feeding the stored
point logs to the localizer, and the stored outcomes with the estimates the planner chose
by to the planner. Both are deterministic: the planner reaches exactly the state it had,
the localizer one that gives the same estimates, and the session carries on from the next
plan index.

What happens is also reported as a stream of plain ``SessionEvent``s to a callback (the
terminal's live view); nothing in the loop depends on who listens.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable, Generator
from dataclasses import dataclass, field

import numpy as np

from robot.arm import TouchResult
from varskin.board.frame import Frame, Gap
from varskin.errors import (
    BoardDisconnected,
    ForceLimitExceeded,
    NoContact,
    ProtectiveStop,
    StoreError,
)
from varskin.localization import localize
from varskin.localization.peakfit import NAME as LIVE_METHOD
from varskin.localization.peakfit import Localizer
from varskin.planning import PlannedTouch, TouchOutcome
from varskin.pointlogs import PointLogs
from varskin.predictions import OK, Predictions
from varskin.rig import Rig
from varskin.store import Attempt, Outcome, SessionStore, StoredLog
from varskin.touch_window import (
    TouchTimes,
    WindowConfig,
    WindowProblem,
    check_link,
    cut_point_log,
    robust_mean,
    stored_window,
)

Planner = Generator[PlannedTouch, "TouchOutcome | None", None]
MAX_STOPS_PER_TOUCH = 2  # protective stops (each unlocked by a person) before giving up


@dataclass(frozen=True)
class SessionSettings:
    method: str = "peakfit"  # the final (batch) estimate; the live one is always peakfit
    max_retries: int = 2  # extra attempts of a touch after no contact / a board gap
    baseline_frames: int = 50  # no-contact frames at the start: the rest values S0, sigma0
    window: WindowConfig = field(default_factory=WindowConfig)  # in simulated/real seconds
    pause_timeout_s: float = 600.0  # how long a protective stop may wait for its unlock
    board_timeout_s: float = 30.0  # how long an unplugged board may take to come back
    # The estimate after each touch: "update" (fast, provisional: enough to watch) or "batch"
    # (the converged solve of all logs so far, ~0.1 s: what the adaptive planner needs, since
    # it chooses by the sigmas; benchmarks/adaptive_plan.py measured both).
    live_estimate: str = "update"
    # A refined session (``--refine``) was watched with "update" up to this many point logs
    # and plans adaptively after it, from "batch" estimates (None: one mode throughout).
    batch_after_logs: int | None = None


@dataclass(frozen=True)
class SessionEvent:
    kind: str  # start, baseline, attempt, point_log, failed, pause, resume, final
    message: str = ""
    plan_index: int | None = None
    n_logs: int = 0
    predictions: Predictions | None = None


@dataclass
class SessionResult:
    predictions: Predictions  # the final batch estimate
    logs: PointLogs
    n_planned: int
    n_failed: int
    n_attempts: int
    wall_s: float
    touch_points_mm: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


class _FrameTap:
    """Collects the recorder's frames and gaps on its thread for the session's thread."""

    def __init__(self, seq_offset: int) -> None:
        self._lock = threading.Lock()
        self._frames: list[Frame] = []
        self._gaps: list[Gap] = []
        self._offset = seq_offset
        self._last_t = -np.inf
        self._arrived = threading.Condition(self._lock)

    def __call__(self, event: Frame | Gap) -> None:
        with self._lock:
            if isinstance(event, Frame):
                # Frame numbers restart with each recorder; the store's must not.
                self._frames.append(Frame(event.seq + self._offset, event.t, event.cells))
                self._last_t = event.t
            else:
                self._gaps.append(event)
            self._arrived.notify_all()

    def drain(self) -> tuple[list[Frame], list[Gap]]:
        with self._lock:
            frames, gaps = self._frames, self._gaps
            self._frames, self._gaps = [], []
        return frames, gaps

    def wait_until(self, t: float, timeout_s: float) -> bool:
        """True once a frame stamped after ``t`` has arrived."""
        deadline = time.monotonic() + timeout_s
        with self._lock:
            while self._last_t < t:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._arrived.wait(left)
        return True


def window_config(store: SessionStore) -> WindowConfig:
    """The windows a stored session's point logs were cut with (``StoreError`` if its
    record of them is damaged): replay re-cuts with them, and a resume goes on with them."""
    w = store.meta().get("window")
    try:
        return stored_window(w)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise StoreError(
            f"{store.path}: damaged session file (its touch window is {w!r})"
        ) from None


class CalibrationSession:
    def __init__(
        self,
        rig: Rig,
        store: SessionStore,
        planner: Planner,
        settings: SessionSettings | None = None,
        on_event: Callable[[SessionEvent], None] | None = None,
    ) -> None:
        self.rig = rig
        self.store = store
        self.planner = planner
        self.settings = settings or SessionSettings()
        self.window = dataclasses.replace(
            self.settings.window.scaled(rig.time_scale), latency_s=rig.frame_latency_s
        )
        self.spec = rig.launch.arm_touch_spec()
        self.on_event = on_event or (lambda e: None)
        self.sensors = tuple(rig.launch.patch.names)
        self._tap = _FrameTap(store.max_frame_seq() + 1)
        self._recent: list[Frame] = []  # frames since the current attempt began
        self._gaps: list[Gap] = []
        self.localizer: Localizer | None = None
        self._t0 = 0.0
        self._t_offset = 0.0
        self._rest: np.ndarray | None = None  # the session's rest values, once measured

    # --- the loop -----------------------------------------------------------------------

    def run(self) -> SessionResult:
        started = time.monotonic()
        self.rig.recorder.subscribe(self._tap)
        self._t0 = time.monotonic()
        stored = self.store.stored_logs()
        if stored:
            # A resumed session's logs stay relative to what its first ones were.
            reference = window_config(self.store).reference
            self.window = dataclasses.replace(self.window, reference=reference)
        # replay re-cuts point logs with exactly these windows
        self.store.set_meta("window", dataclasses.asdict(self.window))
        self.store.set_meta("live_estimate", self.settings.live_estimate)
        self._t_offset = (max(s.log.t_s for s in stored) + 1.0) if stored else 0.0
        touch = self._replay_history(stored)
        if touch is not None and self.store.baseline() is None:
            self._measure_rest(touch)
        rest, rest_sd, _ = self.store.baseline() or (None, None, 0)
        self._rest = rest
        if self.localizer is None:
            self.localizer = self._new_localizer(rest, rest_sd)
        while touch is not None:
            outcome = self._do_touch(touch)
            try:
                touch = self.planner.send(outcome)
            except StopIteration:
                touch = None
        self._save_frames()
        self.store.commit()
        logs = self.store.point_logs()
        final = final_estimate(logs, self.settings.method, self.rig.launch.patch)
        self.store.write_final(final)
        self.store.set_meta("status", "complete")
        self.on_event(SessionEvent("final", n_logs=len(logs), predictions=final))
        outcomes = self.store.outcomes()
        return SessionResult(
            predictions=final,
            logs=logs,
            n_planned=len(outcomes),
            n_failed=sum(not o.ok for o in outcomes),
            n_attempts=len(self.store.attempts()),
            wall_s=time.monotonic() - started,
            touch_points_mm=np.array([[o.x_mm, o.y_mm] for o in outcomes]).reshape(-1, 2),
        )

    def _live(self, log, shown: Predictions | None = None) -> Predictions:
        return live_estimate(
            self.localizer, log, self.settings.live_estimate, self.settings.batch_after_logs, shown
        )

    def _new_localizer(self, rest, rest_sd) -> Localizer:
        return Localizer(self.sensors, rest=rest, rest_sd=rest_sd, patch=self.rig.launch.patch)

    def _replay_history(self, stored: list[StoredLog]) -> PlannedTouch | None:
        """Bring the planner and the localizer to where a previous run of this session left
        them, and return the first touch still to do (None: the plan is complete)."""
        outcomes = self.store.outcomes()
        logs = {s.plan_index: s.log for s in stored}
        if outcomes:
            rest, rest_sd, _ = self.store.baseline() or (None, None, 0)
            self.localizer = self._new_localizer(rest, rest_sd)
        # The batch solves the session showed, keyed by their number of point logs (a fast
        # update's estimate is made again, so none of those is read).
        after = batch_after(self.settings.live_estimate, self.settings.batch_after_logs)
        shown = {}
        if outcomes and after is not None:
            shown = self.store.estimates("live", LIVE_METHOD, after_logs=after)
        n_logs = 0
        touch: PlannedTouch | None = None
        try:
            touch = next(self.planner)
            for o in outcomes:
                if touch.index != o.plan_index or (touch.x_mm, touch.y_mm) != (o.x_mm, o.y_mm):
                    raise StoreError(
                        f"{self.store.path}: plan touch {o.plan_index} was at "
                        f"({o.x_mm:g}, {o.y_mm:g}) mm but the planner now proposes "
                        f"({touch.x_mm:g}, {touch.y_mm:g}) mm; was the launch file changed?"
                    )
                if o.ok and o.plan_index not in logs:
                    raise StoreError(
                        f"{self.store.path}: damaged session file (plan touch {o.plan_index} "
                        f"succeeded but its point log is missing)"
                    )
                preds = None
                if o.ok:
                    n_logs += 1
                    preds = self._live(logs[o.plan_index], shown.get(n_logs))
                planned, touch = touch, None  # None if the plan ends here
                touch = self.planner.send(TouchOutcome(planned, o.ok, preds))
        except StopIteration:
            pass
        if outcomes:
            what = "the plan is complete" if touch is None else f"next: touch {touch.index}"
            self.on_event(
                SessionEvent(
                    "resume",
                    f"resumed after {len(outcomes)} plan touches ({len(logs)} point logs); {what}",
                    n_logs=len(logs),
                )
            )
        return touch

    def _measure_rest(self, first: PlannedTouch) -> None:
        """No-contact frames above the first touch give each sensor's rest value and noise."""
        arm = self.rig.arm
        arm.move_above(self.rig.to_base([first.x_mm, first.y_mm]), self.spec.clearance_m)
        self._save_frames()
        self._recent = []
        n = self.settings.baseline_frames
        period = self.window.max_frame_interval_s
        deadline = time.monotonic() + n * period + self.settings.board_timeout_s
        while len(self._recent) < n:
            if time.monotonic() > deadline:
                raise BoardDisconnected(
                    f"{self.rig.recorder.url}: only {len(self._recent)} of {n} baseline frames"
                )
            time.sleep(0.01)
            self._save_frames()
        values = np.array([self.rig.cellmap.values(f) for f in self._recent[:n]])
        rest, rest_sd = robust_mean(values)
        self.store.write_baseline(self.sensors, rest, np.maximum(rest_sd, 1e-3), len(values))
        self.on_event(SessionEvent("baseline", f"rest values from {len(values)} frames"))

    def _save_frames(self) -> list[Frame]:
        frames, gaps = self._tap.drain()
        self.store.add_frames(frames)
        self.store.add_gaps(gaps)
        self._recent.extend(frames)
        self._gaps.extend(gaps)
        return frames

    # --- one touch ----------------------------------------------------------------------

    def _do_touch(self, touch: PlannedTouch) -> TouchOutcome:
        failures = stops = 0
        attempt_no = len(self.store.attempts(touch.index))
        point_m = self.rig.to_base([touch.x_mm, touch.y_mm])
        while True:
            attempt_no += 1
            self._save_frames()
            self.store.commit()
            self._recent = []
            status, message, result, t_start = "ok", "", None, None
            try:
                self.rig.arm.move_above(point_m, self.spec.clearance_m)
                t_start = time.monotonic()
                result = self.rig.arm.touch(point_m, self.spec)
                log_and_n = self._cut(touch, result, t_start)
            except NoContact as e:
                status, message = "no_contact", str(e)
            except ForceLimitExceeded as e:
                status, message = "force_limit", str(e)
            except WindowProblem as e:
                status, message = e.kind, str(e)
            except ProtectiveStop as e:
                self._record(touch, attempt_no, "protective_stop", str(e), t_start, result)
                self.store.commit()
                stops += 1
                if stops > MAX_STOPS_PER_TOUCH:
                    # the same touch keeps stopping the arm: a person must look at the rig
                    raise ProtectiveStop(
                        f"touch {touch.index} protective-stopped the arm {stops} times; "
                        f"stopping the session"
                    ) from None
                self._pause(touch, e)
                continue
            except BaseException as e:
                # Anything else stops the session: keep what this attempt saw, then raise.
                self._save_frames()
                self._record(
                    touch, attempt_no, "aborted", f"{type(e).__name__}: {e}", t_start, result
                )
                self.store.commit()
                raise
            if status == "ok":
                log, n_base = log_and_n
                aid = self._record(touch, attempt_no, "ok", "", t_start, result)
                preds = self._live(log)
                self.store.commit_touch(
                    Outcome(touch.index, touch.x_mm, touch.y_mm, touch.phase, True),
                    StoredLog(touch.index, aid, n_base, log),
                    preds,
                )
                self.on_event(
                    SessionEvent(
                        "point_log",
                        plan_index=touch.index,
                        n_logs=self.store.n_point_logs(),
                        predictions=preds,
                    )
                )
                return TouchOutcome(touch, True, preds)
            self._record(touch, attempt_no, status, message, t_start, result)
            self.store.commit()
            failures += 1
            self.on_event(
                SessionEvent("attempt", f"touch {touch.index}: {status}: {message}", touch.index)
            )
            if status == "board_gap":
                self._wait_for_board()
            if failures > self.settings.max_retries:
                self.store.commit_touch(
                    Outcome(touch.index, touch.x_mm, touch.y_mm, touch.phase, False), None, None
                )
                self.on_event(
                    SessionEvent(
                        "failed",
                        f"touch {touch.index} at ({touch.x_mm:.1f}, {touch.y_mm:.1f}) mm gave up "
                        f"after {failures} attempts ({status})",
                        touch.index,
                        n_logs=self.store.n_point_logs(),
                    )
                )
                return TouchOutcome(touch, False, None)

    def _cut(self, touch: PlannedTouch, result: TouchResult, t_start: float):
        if result.t_settled is None or result.t_release is None or result.t_contact is None:
            raise NoContact(f"touch {touch.index}: the arm reported no dwell window")
        w = self.window
        # Wait for the frame that closes the window (its line completes after release).
        self._tap.wait_until(result.t_release + w.latency_s, w.max_frame_interval_s + 0.5)
        self._save_frames()
        if not self.rig.recorder.connected:
            raise WindowProblem("board_gap", f"{self.rig.recorder.url}: board disconnected")
        check_link(self._gaps, t_start, result.t_release + w.latency_s)
        times = TouchTimes(t_start, result.t_contact, result.t_settled, result.t_release)
        t_session = self._t_offset + (result.t_settled - self._t0) * self.rig.time_scale
        return cut_point_log(
            self._recent, times, self.rig.cellmap, w, touch.index,
            touch.x_mm, touch.y_mm, result.mean_force_n, t_session, self._rest,
        )  # fmt: skip

    def _record(
        self,
        touch: PlannedTouch,
        attempt_no: int,
        status: str,
        message: str,
        t_start: float | None,
        r: TouchResult | None,
    ) -> int:
        seqs = [f.seq for f in self._recent]
        return self.store.add_attempt(
            Attempt(
                plan_index=touch.index,
                attempt=attempt_no,
                x_mm=touch.x_mm,
                y_mm=touch.y_mm,
                phase=touch.phase,
                status=status,
                message=message,
                t_start=t_start,
                t_contact=r.t_contact if r else None,
                t_settled=r.t_settled if r else None,
                t_release=r.t_release if r else None,
                t_end=time.monotonic(),
                peak_force_n=r.peak_force_n if r else None,
                mean_force_n=r.mean_force_n if r else None,
                seq_first=min(seqs) if seqs else None,
                seq_last=max(seqs) if seqs else None,
            )
        )

    def _wait_for_board(self) -> None:
        if not self.rig.recorder.wait_connected(self.settings.board_timeout_s):
            raise BoardDisconnected(
                f"{self.rig.recorder.url}: board gone for {self.settings.board_timeout_s:g} s"
            )

    def _pause(self, touch: PlannedTouch, cause: ProtectiveStop) -> None:
        """Wait for a person to clear the protective stop on the pendant, then carry on."""
        self.on_event(
            SessionEvent(
                "pause",
                f"PAUSED at touch {touch.index}: {cause}. Inspect the rig and unlock the "
                f"protective stop on the pendant; the session resumes by itself.",
                touch.index,
            )
        )
        arm = self.rig.arm
        deadline = time.monotonic() + self.settings.pause_timeout_s
        while arm.status().protective_stop:
            if time.monotonic() > deadline:
                raise ProtectiveStop(
                    f"protective stop not cleared within {self.settings.pause_timeout_s:g} s"
                )
            self._save_frames()
            time.sleep(0.1)
        arm.recover()
        arm.retract()  # straight up first: the stop may have left the probe in the skin
        self.on_event(
            SessionEvent("resume", f"unlocked; retrying touch {touch.index}", touch.index)
        )


def live_schedule(path, meta) -> tuple[str, int | None]:
    """How a stored session computed its live estimates: the mode, and after how many point
    logs they became batch solves (a refinement of a session watched with fast updates)."""
    mode = meta.get("live_estimate", "update")
    after = meta.get("live_batch_after")
    if mode not in ("update", "batch") or not (
        after is None or (isinstance(after, int) and not isinstance(after, bool) and after >= 0)
    ):
        raise StoreError(f"{path}: damaged session file (live estimates {mode!r} after {after!r})")
    return mode, after


def batch_after(mode: str, batch_after_logs: int | None) -> int | None:
    """After how many point logs a session's estimates are batch solves (None: never)."""
    return 0 if mode == "batch" else batch_after_logs


def live_estimate(
    localizer: Localizer,
    log,
    mode: str,
    batch_after_logs: int | None = None,
    shown: Predictions | None = None,
) -> Predictions:
    """The estimate after one more point log, as the session shows and stores it: the fast
    update, or with ``mode`` "batch" (or beyond ``batch_after_logs`` logs) the batch solve.

    A batch solve depends on the point logs alone (``Localizer.result``), so the log is only
    added for it: the fast update's re-fits would be thrown away. ``shown``: a resumed
    session's stored estimate for this log, which stands in for the batch solve. That costs
    up to a second per touch: an adaptive session resumed after 100 touches would re-solve
    100 times before the arm moved again. ``varskin replay`` is what recomputes every
    estimate.
    """
    after = batch_after(mode, batch_after_logs)
    if after is None or localizer.n_logs < after:
        return localizer.update(log)
    localizer.add(log)
    return shown if shown is not None else localizer.result()


def final_estimate(logs: PointLogs, method: str, patch) -> Predictions:
    """The session's result: the batch solve of every point log (replay calls this too)."""
    params = {"patch": patch} if method == "peakfit" else {}
    return localize(logs, method=method, **params)


def rms_error_mm(predictions: Predictions, truth_xy: np.ndarray) -> tuple[float, int]:
    """RMS distance of the located sensors from the truth, and how many were located."""
    ok = np.array([e.status == OK for e in predictions.estimates])
    if not ok.any():
        return float("nan"), 0
    d = predictions.xy()[ok] - np.asarray(truth_xy)[ok]
    return float(np.sqrt((d**2).sum(axis=1).mean())), int(ok.sum())

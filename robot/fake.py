"""An in-process arm for unit tests: the ``Arm`` protocol with no sockets and no controller.

Tests of the planner, the recorder's windows, registration and the safety logic need an arm
that behaves like the real one (moves at the envelope's speeds, finds the skin, holds a
force, fails in the typed ways the UR driver fails) but runs in milliseconds. ``FakeArm``
keeps a simulated clock and steps a point TCP through it; with ``realtime=True`` it paces
that clock against the host clock, so a simulated board following the shared ``ProbeState``
sees the dwell at the right time. The physics is the least the scenes need: a flat skin
(the true patch plane, only inside the patch outline) with a linear stiffness, a force
sensor with an offset that zeroing removes and seeded noise, and a first-order force loop.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from robot.arm import ArmStatus, DwellCallback, DwellTick, TouchResult, TouchSpec
from robot.patch_frame import PatchFrame
from robot.safety import Envelope
from varskin.errors import (
    ConnectionLost,
    ForceLimitExceeded,
    NoContact,
    ProtectiveStop,
    RobotError,
    SafetyViolation,
)
from varskin.patch import Patch
from varskin.scene import ProbeState

# The probe points straight down: a half turn about base y (UR rotation-vector convention).
_TOOL_DOWN = (0.0, float(np.pi), 0.0)


@dataclass(frozen=True)
class FakeFaults:
    """Faults to inject, each at one touch (0-based index of ``touch`` calls)."""

    protective_stop_at_touch: int | None = None
    protective_stop_phase: str = "dwell"  # "descent" or "dwell"
    no_surface: bool = False  # the skin is missing: every descent reaches its floor
    connection_lost_at_touch: int | None = None  # the controller vanishes during the descent
    drift_at_touch: int | None = None  # the TCP creeps off its command (a bump, bad tracking)
    drift_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    force_spike_at_touch: int | None = None  # something hard under the probe during the dwell
    force_spike_n: float = 0.0


class FakeArm:
    """A simulated point TCP in the base frame, implementing ``robot.arm.Arm``.

    ``surface`` is the TRUE patch frame (where the skin really is, which registration may
    only approximate); ``patch`` bounds the skin to its outline. Without a surface the arm
    touches nothing. ``motion_log`` records every motion segment, so tests can assert that a
    refused plan never moved the arm.
    """

    def __init__(
        self,
        envelope: Envelope,
        surface: PatchFrame | None = None,
        patch: Patch | None = None,
        *,
        stiffness_n_per_mm: float = 3.0,
        force_offset_n: float = 0.8,
        force_noise_sd_n: float = 0.03,
        seed: int = 0,
        probe_state: ProbeState | None = None,
        realtime: bool = False,
        home_m: Sequence[float] | None = None,
        faults: FakeFaults | None = None,
        control_dt_s: float = 0.002,
        dwell_tick_s: float = 0.01,
        contact_threshold_n: float = 0.3,
        force_gain_m_s_per_n: float = 0.005,
        max_extra_settle_s: float = 2.0,
    ) -> None:
        self.envelope = envelope
        self.surface = surface
        self.patch = patch
        self.stiffness_n_per_mm = float(stiffness_n_per_mm)
        self.force_offset_n = float(force_offset_n)
        self.force_noise_sd_n = float(force_noise_sd_n)
        self.probe_state = probe_state
        self.realtime = bool(realtime)
        self.faults = faults or FakeFaults()
        self.dt = float(control_dt_s)
        self.dwell_tick_s = float(dwell_tick_s)
        self.contact_threshold_n = float(contact_threshold_n)
        self.force_gain = float(force_gain_m_s_per_n)
        self.max_extra_settle_s = float(max_extra_settle_s)
        self._rng = np.random.default_rng(seed)
        if home_m is None:
            lo, hi = envelope.box_min_m, envelope.box_max_m
            home_m = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2] - 0.001]
        self._cmd = np.asarray(home_m, float).reshape(3).copy()  # commanded TCP
        self._drift = np.zeros(3)  # actual = commanded + drift
        self._drift_rate = np.zeros(3)
        self._spike_n = 0.0
        self._zero_n = 0.0  # force sensor zero, set by zeroing before each touch
        self._last_clearance_z = float(self._cmd[2])
        self._inside_box = envelope.contains(self._cmd)
        self._protective_stop = False
        self._connected = True
        self._stop_requested = threading.Event()
        self._pace_origin = time.monotonic()
        self.sim_time_s = 0.0  # simulated seconds spent moving, pressing and dwelling
        self.path_length_m = 0.0  # commanded TCP travel
        self.touch_count = 0
        self.last_dwell_sim_s: tuple[float, float] | None = None  # the last dwell, sim clock
        self.retract_attempts = 0
        self.motion_log: list[tuple[str, tuple[float, ...], tuple[float, ...]]] = []
        self.events: list[str] = []  # what happened, in order (faults, retracts, stops)
        # (sim time s, x, y, z m, true force N) every control step: what really happened
        self.trace: deque[tuple[float, float, float, float, float]] = deque(maxlen=500_000)

    # --- the Arm protocol -----------------------------------------------------------------

    def move_above(self, point: Sequence[float], clearance_m: float) -> None:
        p = np.asarray(point, float).reshape(3)
        target = p + [0.0, 0.0, clearance_m]
        self.envelope.check_point(target, "move_above target")
        self._check_live()
        self._begin()
        # Never sweep across the skin low: rise first, then travel, then descend.
        up_z = max(self._actual()[2], target[2])
        if up_z > self._cmd[2] + 1e-9:
            self._move_linear(
                [self._cmd[0], self._cmd[1], up_z], self.envelope.max_speed_m_s, "rise"
            )
        self._move_linear([target[0], target[1], up_z], self.envelope.max_speed_m_s, "travel")
        self._move_linear(target, self.envelope.max_speed_m_s, "lower")
        self._last_clearance_z = float(target[2])

    def touch(
        self, point: Sequence[float], spec: TouchSpec, on_dwell: DwellCallback | None = None
    ) -> TouchResult:
        p = np.asarray(point, float).reshape(3)
        self.envelope.check_touch(p, spec)  # refuse before anything moves
        self._check_live()
        k = self.touch_count
        self.touch_count += 1
        limit_n = min(spec.max_force_n, self.envelope.max_force_n)
        succeeded = False
        try:
            self.move_above(p, spec.clearance_m)
            if self.faults.drift_at_touch == k:
                self._drift_rate = np.asarray(self.faults.drift_m_s, float)
            self._zero_force_sensor()
            floor = p - [0.0, 0.0, spec.max_depth_m]
            threshold = min(self.contact_threshold_n, 0.5 * spec.target_force_n)

            def in_contact(force_n: float) -> bool:
                if self.faults.connection_lost_at_touch == k:
                    self._connected = False
                    self.events.append(f"connection lost during descent of touch {k}")
                    raise ConnectionLost(f"robot controller connection lost during touch {k}")
                if (
                    self.faults.protective_stop_at_touch == k
                    and self.faults.protective_stop_phase == "descent"
                ):
                    self._enter_protective_stop(f"descent of touch {k}")
                return force_n >= threshold

            peak = [0.0]
            if not self._move_linear(
                floor,
                spec.search_speed_m_s,
                "descent",
                stop_when=in_contact,
                force_limit_n=limit_n,
                peak=peak,
            ):
                raise NoContact(
                    f"no contact down to {spec.max_depth_m * 1000:.1f} mm below "
                    f"{_fmt(p)} (touch {k})"
                )
            contact_z = float(self._actual()[2])
            t_contact = time.monotonic()
            t_settled, t_release, mean_force = self._hold_force(spec, k, limit_n, on_dwell, peak)
            succeeded = True
            return TouchResult(
                contact=True,
                contact_z_m=contact_z,
                t_contact=t_contact,
                t_settled=t_settled,
                t_release=t_release,
                peak_force_n=peak[0],
                mean_force_n=mean_force,
            )
        finally:
            self._drift_rate = np.zeros(3)
            self._spike_n = 0.0
            try:
                self.retract()
            except RobotError as e:
                self.events.append(f"retract after touch {k} failed: {e}")
                if succeeded:
                    raise

    def retract(self) -> None:
        self.retract_attempts += 1
        self.events.append("retract")
        self._check_live()
        self._begin()
        z = min(self._last_clearance_z, self.envelope.box_max_m[2])
        if self._cmd[2] < z - 1e-9:
            # Up is the safe direction: the box is not enforced on the way out.
            self._move_linear(
                [self._cmd[0], self._cmd[1], z],
                self.envelope.max_speed_m_s,
                "retract",
                watch_box=False,
            )
        self._publish(0.0)

    def stop(self) -> None:
        self._stop_requested.set()
        self.events.append("stop")

    def status(self) -> ArmStatus:
        return ArmStatus(
            connected=self._connected,
            program_running=self._connected and not self._protective_stop,
            protective_stop=self._protective_stop,
            safety_mode="protective_stop" if self._protective_stop else "normal",
            tcp_pose=(*(float(v) for v in self._actual()), *_TOOL_DOWN),
            tcp_force_n=self._measured_force() if self._connected else 0.0,
        )

    # --- recovery, as the dashboard would offer --------------------------------------------

    def unlock_protective_stop(self) -> None:
        self._protective_stop = False
        self._stop_requested.clear()
        self.events.append("unlock protective stop")

    def reconnect(self) -> None:
        self._connected = True
        self.events.append("reconnect")

    # --- simulation -----------------------------------------------------------------------

    def _actual(self) -> np.ndarray:
        return self._cmd + self._drift

    def _true_force(self) -> float:
        if self.surface is None or self.faults.no_surface:
            return 0.0
        x_mm, y_mm, h_mm = self.surface.to_patch(self._actual())
        if self.patch is not None and not (
            0.0 <= x_mm <= self.patch.length_mm and 0.0 <= y_mm <= self.patch.width_mm
        ):
            return 0.0
        return self.stiffness_n_per_mm * max(-h_mm, 0.0) + (self._spike_n if h_mm < 0 else 0.0)

    def _measured_force(self) -> float:
        raw = (
            self._true_force() + self.force_offset_n + self._rng.normal(0.0, self.force_noise_sd_n)
        )
        return float(raw - self._zero_n)

    def _zero_force_sensor(self) -> None:
        samples = [
            self._true_force() + self.force_offset_n + self._rng.normal(0.0, self.force_noise_sd_n)
            for _ in range(20)
        ]
        self._zero_n = float(np.mean(samples))
        self._advance(20 * self.dt)

    def _publish(self, force_n: float) -> None:
        x, y, z = self._actual()
        self.trace.append((self.sim_time_s, float(x), float(y), float(z), float(force_n)))
        if self.probe_state is None:
            return
        if force_n <= 0.0 or self.surface is None:
            self.probe_state.set(None, None, 0.0)
        else:
            x_mm, y_mm, _ = self.surface.to_patch(self._actual())
            self.probe_state.set(float(x_mm), float(y_mm), float(force_n))

    def _begin(self) -> None:
        """Re-anchor pacing: host time that passed between commands is not simulated."""
        self._pace_origin = time.monotonic() - self.sim_time_s

    def _advance(self, dt: float) -> None:
        self.sim_time_s += dt
        if self.realtime:
            ahead = self._pace_origin + self.sim_time_s - time.monotonic()
            if ahead > 0.001:
                time.sleep(ahead)

    def _check_live(self) -> None:
        if not self._connected:
            raise ConnectionLost("robot controller is not connected")
        if self._protective_stop:
            raise ProtectiveStop("robot is protective-stopped; unlock it before moving")
        if self._stop_requested.is_set():
            self._stop_requested.clear()
            raise RobotError("motion stopped on request")

    def _enter_protective_stop(self, where: str) -> None:
        self._protective_stop = True
        self.events.append(f"protective stop during {where}")
        raise ProtectiveStop(f"protective stop during {where}")

    def _halt(self, why: str) -> None:
        self.events.append(f"halt: {why}")

    def _step_drift(self) -> None:
        self._drift = self._drift + self._drift_rate * self.dt

    def _watch(self, what: str, force_n: float, force_limit_n: float, watch_box: bool) -> None:
        """The controller's safety monitor: force limit and workspace box, every cycle."""
        if watch_box and self.envelope.contains(self._actual()):
            self._inside_box = True
        if force_n > force_limit_n:
            self._halt(f"force {force_n:.2f} N during {what}")
            raise ForceLimitExceeded(
                f"contact force {force_n:.2f} N above the limit {force_limit_n:g} N during {what}"
            )
        if watch_box and not self.envelope.contains(self._actual()):
            # A TCP parked outside may enter the box; leaving it once inside is the breach.
            if not self._inside_box:
                return
            self._inside_box = False
            self._halt(f"left the box during {what}")
            try:
                self.envelope.check_point(self._actual(), f"measured TCP during {what}")
            except SafetyViolation as e:
                raise SafetyViolation(f"{e}; stopped") from None

    def _move_linear(
        self,
        target: Sequence[float],
        speed_m_s: float,
        what: str,
        *,
        stop_when=None,
        force_limit_n: float | None = None,
        peak: list[float] | None = None,
        watch_box: bool = True,
    ) -> bool:
        """Step the commanded TCP to ``target`` with trapezoidal speed; True if stopped early."""
        target = np.asarray(target, float)
        start = self._cmd.copy()
        limit = self.envelope.max_force_n if force_limit_n is None else force_limit_n
        accel = self.envelope.max_accel_m_s2
        v = 0.0
        stopped_early = False
        try:
            while True:
                self._check_live()
                d = target - self._cmd
                dist = float(np.linalg.norm(d))
                if dist < 1e-9:
                    self._cmd = target.copy()
                    break
                v = min(speed_m_s, v + accel * self.dt, np.sqrt(2.0 * accel * dist))
                step = min(v * self.dt, dist)
                self._cmd = self._cmd + d / dist * step
                self.path_length_m += step
                self._step_drift()
                self._advance(self.dt)
                force = self._measured_force()
                if peak is not None:
                    peak[0] = max(peak[0], force)
                self._publish(self._true_force())
                self._watch(what, force, limit, watch_box)
                if stop_when is not None and stop_when(force):
                    stopped_early = True
                    break
        finally:
            self.motion_log.append((what, tuple(start), tuple(self._cmd)))
        return stopped_early

    def _hold_force(
        self,
        spec: TouchSpec,
        k: int,
        limit_n: float,
        on_dwell: DwellCallback | None,
        peak: list[float],
    ) -> tuple[float, float, float]:
        """Force control along z: settle, then dwell with callbacks. Returns the window.

        The dwell opens once ``settle_s`` has passed AND the (smoothed) force is within 5% of
        the target, so a soft skin that takes longer to reach it still gets a window at the
        target force; after ``settle_s + max_extra_settle_s`` it opens regardless.
        """
        t_settled = t_release = time.monotonic()
        dwell_forces: list[float] = []
        settle_elapsed = dwell_elapsed = 0.0
        next_tick = 0.0
        smoothed = None
        dwell_start_sim = self.sim_time_s
        start = self._cmd.copy()
        try:
            while dwell_elapsed < spec.dwell_s - 1e-12 or not dwell_forces:
                self._check_live()
                force = self._measured_force()
                peak[0] = max(peak[0], force)
                self._watch("force hold", force, limit_n, True)
                # Admittance: descend while below the target, rise above it, speed-limited.
                v = float(
                    np.clip(
                        self.force_gain * (spec.target_force_n - force),
                        -spec.force_speed_limit_m_s,
                        spec.force_speed_limit_m_s,
                    )
                )
                self._cmd = self._cmd - [0.0, 0.0, v * self.dt]
                self.path_length_m += abs(v) * self.dt
                self._step_drift()
                self._advance(self.dt)
                self._publish(self._true_force())
                if not dwell_forces:
                    settle_elapsed += self.dt
                    smoothed = force if smoothed is None else smoothed + 0.1 * (force - smoothed)
                    near = abs(smoothed - spec.target_force_n) <= 0.05 * spec.target_force_n
                    if settle_elapsed < spec.settle_s or (
                        not near and settle_elapsed < spec.settle_s + self.max_extra_settle_s
                    ):
                        continue
                    t_settled = time.monotonic()
                    dwell_start_sim = self.sim_time_s
                    if self.faults.force_spike_at_touch == k:
                        self._spike_n = self.faults.force_spike_n
                    if (
                        self.faults.protective_stop_at_touch == k
                        and self.faults.protective_stop_phase == "dwell"
                    ):
                        self._enter_protective_stop(f"dwell of touch {k}")
                else:
                    dwell_elapsed += self.dt
                dwell_forces.append(force)
                if on_dwell is not None and dwell_elapsed >= next_tick:
                    next_tick += self.dwell_tick_s
                    if on_dwell(
                        DwellTick(t=time.monotonic(), elapsed_s=dwell_elapsed, force_n=force)
                    ):
                        break
            t_release = time.monotonic()
            self.last_dwell_sim_s = (dwell_start_sim, self.sim_time_s)
        finally:
            self.motion_log.append(("force hold", tuple(start), tuple(self._cmd)))
        return t_settled, t_release, float(np.mean(dwell_forces))


def _fmt(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:.4f}" for v in p) + ") m"

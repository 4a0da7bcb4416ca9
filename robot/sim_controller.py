"""A simulated UR controller on loopback that the real ur-rtde 1.6.5 client can drive.

CI has no robot, yet the UR driver must be tested with the real client library, its threads,
its return-value quirks and its hangs. This module speaks the controller's side of the wire:
RTDE (TCP 30004, ``>HB`` framed packets), the dashboard server's text protocol (29999) and the
script port (30003) that ur-rtde uploads its control script to. It does not interpret URScript;
it emulates the command loop of ur-rtde's ``rtde_control.script`` (command id in
``input_int_register_0``, arguments in the other input registers, ``output_int_register_0``
1 = ready, 2 = done), so the register protocol it speaks is pinned to ur-rtde 1.6.5.

Behind the wire sits a point TCP (moves at the commanded speed and acceleration, force mode
along the compliant axis with the speed limit) and a contact model of the skin: the surface
is the plane of the TRUE patch frame, only within the patch outline, force = stiffness x
penetration, rigid below the silicone's thickness. The controller protective-stops itself
above ``protective_stop_force_n`` like a real UR. Every control cycle it writes the probe's
patch-frame position and force to ``probe_state`` for the simulated Muca board, and it keeps
its own trace (time, TCP, true force) so tests check what really happened, not what the
driver reports.

The controller runs in a child process (``SimulatedController`` is the parent-side handle):
ur-rtde's constructors hold Python's GIL while waiting for replies, so a controller served by
threads of the client's own process would deadlock it. ``probe_state`` crosses the boundary
through shared memory, everything else (fault injection, logs) through a pipe.

Simplifications (documented, deliberate): no kinematics (``actual_q`` is a plausible function
of the pose), orientation is carried but never changes the contact, the force sensor noise is
kinder than a real UR's (see ``SimRig.ft_noise_n``), contact detection fires on the skin's
force whatever direction it was started with, the async progress register
(``output_int_register_2``) stays 0, and input registers are not guarded against a second
RTDE client (a real controller answers IN_USE).

Time: by default simulated time is real time. ``SimRig.time_scale`` > 1 runs the controller
faster than the wall clock (``time_scale`` simulated seconds per wall second) so a long
simulated calibration finishes in CI time. Its loop then wakes every ``MIN_TICK_S`` of wall
time (or ``cycle_s / time_scale`` if longer) and integrates ``tick x time_scale`` simulated
seconds in sub-steps of at most one normal cycle, so force mode, contact detection and the
force lag see the same step as at scale 1. The script's command loop runs in every sub-step
and RTDE publishes at the requested frequency in simulated time. Speeds, accelerations and durations are in simulated
seconds, and so are the logs (``force_log``, ``tcp_log``, ``commands_log``) and RTDE's
``timestamp``. What cannot be scaled is the client: ur-rtde and the driver run on the host
clock, so each of their wall milliseconds (a command handshake, a polling sleep) costs
``time_scale`` simulated milliseconds, more than on a real rig; and the driver's own timed
waits (dwell, settle) must be divided by the scale (``LaunchConfig.arm_touch_spec``).
"""

from __future__ import annotations

import contextlib
import logging
import math
import random
import re
import socket
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from robot import ur_wire as wire
from robot.patch_frame import PatchFrame
from varskin.scene import ProbeState

log = logging.getLogger(__name__)

RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORT = 30003
# ur-rtde's script client uses 30003 on e-Series; the primary/secondary ports are bound as
# silent sinks so a client that probes them finds a controller rather than a refusal.
SINK_PORTS = (30001, 30002)
# Shortest wall tick of a time-scaled controller: Python's sleep and the GIL make shorter
# ticks jittery and CPU-hungry on a 2-core CI machine.
MIN_TICK_S = 0.001


@dataclass
class SimRig:
    """The physical set-up the simulated controller pretends to have in front of it."""

    # the TRUE patch pose in the base frame (registration estimates it; the sim knows it)
    patch_frame: PatchFrame = field(
        default_factory=lambda: PatchFrame.from_yaw([0.35, -0.08, 0.10], 0.0)
    )
    stiffness_n_per_mm: float = 3.0  # silicone skin
    skin_thickness_mm: float = 3.0  # below this the probe meets the rigid base (x100 stiffness)
    ft_offset_n: float = 4.0  # force-sensor offset along base z, removed by zeroFtSensor
    # sd of the sensor noise. A real UR's is ~1 N with a ~3.5 N precision spec; the sim is
    # kinder so force-limit tests test the control loop rather than the noise.
    ft_noise_n: float = 0.1
    ft_drift_n_per_s: float = 0.0  # sensor drift along base z (zeroFtSensor removes what accrued)
    surface_present: bool = True  # False: no skin anywhere (the NoContact case)
    patch_length_mm: float | None = 120.0  # outline: outside it there is no skin (None: infinite)
    patch_width_mm: float | None = 80.0
    start_pose: tuple[float, ...] | None = None  # home TCP pose; None: 50 mm above the patch centre
    protective_stop_force_n: float = 150.0  # the controller protective-stops above this, like a UR
    contact_detect_force_n: float = 0.5  # contact detection fires above this true force
    unlock_delay_s: float = 0.0  # a real UR refuses unlocking for 5 s after a protective stop
    # simulated seconds per wall second: > 1 runs the physics faster than real time (CI runs
    # of long plans); 1 is a real-time controller
    time_scale: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.time_scale) and self.time_scale > 0):
            raise ValueError(f"SimRig.time_scale must be > 0, got {self.time_scale!r}")

    def home_pose(self) -> tuple[float, ...]:
        if self.start_pose is not None:
            return tuple(float(v) for v in self.start_pose)
        cx = (self.patch_length_mm or 0.0) / 2
        cy = (self.patch_width_mm or 0.0) / 2
        p = self.patch_frame.to_base([cx, cy], 50.0)
        return (float(p[0]), float(p[1]), float(p[2]), 0.0, math.pi, 0.0)  # probe pointing down


def _rotvec_to_matrix(rv) -> np.ndarray:
    rv = np.asarray(rv, float)
    th = float(np.linalg.norm(rv))
    if th < 1e-12:
        return np.eye(3)
    k = rv / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * kx + (1 - math.cos(th)) * kx @ kx


class _Motion:
    """A linear move with a trapezoidal speed profile (speed along the path)."""

    def __init__(
        self, start: np.ndarray, target: np.ndarray, speed: float, accel: float, v0: float = 0.0
    ):
        self.start = start.copy()
        self.target = target.copy()
        d = target[:3] - start[:3]
        self.length = float(np.linalg.norm(d))
        self.direction = d / self.length if self.length > 1e-12 else np.zeros(3)
        self.speed = max(speed, 1e-6)
        self.accel = max(accel, 1e-6)
        self.s = 0.0
        self.v = v0

    def step(self, dt: float) -> tuple[np.ndarray, np.ndarray, bool]:
        remaining = self.length - self.s
        v_brake = math.sqrt(max(2 * self.accel * remaining, 0.0))
        self.v = max(0.0, min(self.speed, self.v + self.accel * dt, v_brake))
        self.s = min(self.length, self.s + self.v * dt)
        done = self.length - self.s < 1e-7 or (self.v == 0.0 and remaining < 1e-6)
        if done:
            self.s = self.length
        frac = self.s / self.length if self.length > 1e-12 else 1.0
        pose = self.start + (self.target - self.start) * frac
        return pose, self.direction * (0.0 if done else self.v), done


class _ControllerCore:
    """The controller itself: sockets, the script's command loop and the physics. It runs in
    its own process (see ``SimulatedController``)."""

    def __init__(
        self, rig: SimRig, host: str | None, seed: int, cycle_s: float, probe_state: ProbeState
    ):
        self.rig = rig
        self._requested_host = host
        self.host: str = host or ""
        self.probe_state = probe_state
        self.cycle_s = cycle_s
        self._rng = np.random.default_rng(seed)
        self._lock = threading.RLock()
        self._stop_event = threading.Event()
        self._threads: list[threading.Thread] = []
        self._listeners: list[socket.socket] = []
        self._clients: set[socket.socket] = set()
        self._sim_t = 0.0  # controller time: simulated seconds integrated so far
        # The wall tick: one control cycle in real time; when scaled, as short as the host's
        # sleep allows (MIN_TICK_S), so that a command handshake with the client (which runs
        # on the wall clock) costs few simulated cycles. Each tick integrates tick x scale
        # simulated seconds in sub-steps of at most one cycle, so the force loop and contact
        # detection are integrated as finely as in real time.
        scale = rig.time_scale
        self.tick_s = cycle_s if scale <= 1.0 else max(cycle_s / scale, min(MIN_TICK_S, cycle_s))
        self._substeps = max(1, math.ceil(self.tick_s * scale / cycle_s - 1e-9))
        # controller state (all under _lock)
        self._pose = np.array(self.rig.home_pose(), float)
        self._vel = np.zeros(3)
        self._motion: _Motion | None = None
        self._stopping_decel: float | None = None
        self._force_mode: dict | None = None
        self._damping = 0.025
        self._gain_scaling = 0.5
        # What setTcp / setPayload installed, reported back on RTDE. The simulated pose is
        # always the probe tip (there are no kinematics), so the TCP is recorded, not applied.
        self.tcp_offset: tuple[float, ...] = (0.0,) * 6
        self.payload_kg = 0.0
        self.payload_cog: tuple[float, ...] = (0.0, 0.0, 0.0)
        self._ft_bias = np.zeros(6)
        self._contact: dict | None = None  # active contact detection
        self._contact_detected = False
        self._true_force = 0.0
        self._probe_xy: tuple[float, float] | None = None  # patch x, y mm while in contact
        self._reported_force = np.zeros(6)
        self._in_int: dict[int, int] = {}
        self._in_double: dict[int, float] = {}
        self._out_int: dict[int, int] = {}
        self._out_double: dict[int, float] = {}
        self._script_running = False
        self._executing_cmd = False
        self._logged_realtime_cmd: int | None = None
        self._busy: str | None = None  # a blocking command in progress ("move", "stop")
        self._protective_stop = False
        self._protective_stop_t: float | None = None
        self._gone = False
        self._blackhole = False
        self.trace: deque[tuple[float, float, float, float, float]] = deque(maxlen=200_000)
        self.commands: deque[tuple[float, int]] = deque(maxlen=10_000)  # (t, cmd id) processed
        self.dashboard_log: deque[tuple[str, str]] = deque(maxlen=1000)
        self.scripts_received = 0

    # --- lifecycle ------------------------------------------------------------------------

    def start(self) -> _ControllerCore:
        ports = (RTDE_PORT, DASHBOARD_PORT, SCRIPT_PORT, *SINK_PORTS)
        for _attempt in range(50):
            host = self._requested_host or self._random_loopback()
            socks = []
            try:
                for port in ports:
                    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                    socks.append(s)
                    s.bind((host, port))
                    s.listen(8)
            except OSError:
                for s in socks:
                    s.close()
                if self._requested_host:
                    raise
                continue
            self.host = host
            self._listeners = socks
            break
        else:
            raise OSError("no free loopback address for the simulated controller")
        handlers = (
            self._serve_rtde,
            self._serve_dashboard,
            self._serve_script,
            self._serve_sink,
            self._serve_sink,
        )
        for sock, handler in zip(self._listeners, handlers, strict=True):
            self._spawn(self._accept_loop, sock, handler)
        self._spawn(self._control_loop)
        return self

    def stop(self) -> None:
        self._stop_event.set()
        self._close_all()
        deadline = time.monotonic() + 2.0
        for t in self._threads:
            t.join(timeout=max(deadline - time.monotonic(), 0.01))
        self._threads.clear()
        self.probe_state.set(None, None, 0.0)

    @staticmethod
    def _random_loopback() -> str:
        r = random.SystemRandom()
        return f"127.{r.randint(1, 254)}.{r.randint(1, 254)}.{r.randint(2, 254)}"

    def _spawn(self, fn, *args) -> None:
        t = threading.Thread(target=fn, args=args, daemon=True, name=f"simur-{fn.__name__}")
        t.start()
        self._threads.append(t)

    def _close_all(self) -> None:
        for s in list(self._listeners):
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)  # wakes the accept() blocked in another thread
            with contextlib.suppress(OSError):
                s.close()
        with self._lock:
            clients = list(self._clients)
            self._clients.clear()
        for c in clients:
            with contextlib.suppress(OSError):
                c.shutdown(socket.SHUT_RDWR)
            with contextlib.suppress(OSError):
                c.close()

    # --- fault injection -------------------------------------------------------------------

    def inject_protective_stop(self) -> None:
        """The controller protective-stops now (as if a collision was detected)."""
        with self._lock:
            self._enter_protective_stop()

    def stop_script(self) -> None:
        """The control script stops (as if a user pressed stop on the pendant)."""
        with self._lock:
            self._end_script()

    def drop_connections(self, abrupt: bool = False) -> None:
        """The controller vanishes. Default: it goes silent on every open connection (a cable
        pulled, a controller frozen): no data, no replies, no error, which is how ur-rtde's
        blocking calls end up hanging. ``abrupt``: every socket is closed and the ports stop
        listening (a controller powered off), so reconnects are refused."""
        with self._lock:
            self._blackhole = True
            self._gone = self._gone or abrupt
        if abrupt:
            self._close_all()

    # --- inspection for tests --------------------------------------------------------------

    def force_log(self) -> np.ndarray:
        """(K, 2) array of (simulated controller time s, true contact force N), one row per
        physics step."""
        with self._lock:
            rows = [(t, f) for t, _, _, _, f in self.trace]
        return np.array(rows, float).reshape(-1, 2)

    def tcp_log(self) -> np.ndarray:
        """(K, 4) array of (controller time s, x, y, z m)."""
        with self._lock:
            rows = [(t, x, y, z) for t, x, y, z, _ in self.trace]
        return np.array(rows, float).reshape(-1, 4)

    def clear_logs(self) -> None:
        with self._lock:
            self.trace.clear()
            self.commands.clear()

    @property
    def tcp_pose(self) -> tuple[float, ...]:
        with self._lock:
            return tuple(float(v) for v in self._pose)

    @property
    def sim_time_s(self) -> float:
        with self._lock:
            return self._sim_t

    @property
    def protective_stopped(self) -> bool:
        with self._lock:
            return self._protective_stop

    @property
    def tool(self) -> tuple[tuple[float, ...], float, tuple[float, ...]]:
        with self._lock:
            return self.tcp_offset, self.payload_kg, self.payload_cog

    @property
    def script_running(self) -> bool:
        with self._lock:
            return self._script_running

    # --- the control cycle -----------------------------------------------------------------

    def _control_loop(self) -> None:
        next_t = time.monotonic()
        dt = self.tick_s * self.rig.time_scale / self._substeps  # simulated s per sub-step
        while not self._stop_event.is_set():
            next_t += self.tick_s
            with self._lock:
                # each sub-step is one control cycle of the faster controller: its script's
                # command loop runs in it too, so a command takes the same simulated time to
                # be picked up and acknowledged as at scale 1
                for _ in range(self._substeps):
                    if self._script_running and not self._protective_stop:
                        self._script_step()
                    self._physics_step(dt)
                self._update_sensors()
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -0.1:  # overloaded machine: do not try to catch up in a burst
                next_t = time.monotonic()

    def _script_step(self) -> None:
        """One pass of rtde_control.script's main loop (see module docstring)."""
        if self._busy is not None:
            if self._busy_finished():
                self._busy = None
                self._out_int[0] = wire.UR_DONE
            return
        cmd = self._in_int.get(0, 0)
        if cmd != self._logged_realtime_cmd:
            self._logged_realtime_cmd = None
        if cmd == wire.CMD_NONE:
            self._executing_cmd = False
            self._out_int[0] = wire.UR_READY
        elif cmd in wire.REALTIME_CMDS:
            # processed in every cycle the register holds it; logged once, when it arrives
            if self._logged_realtime_cmd is None:
                self._logged_realtime_cmd = cmd
                self.commands.append((self._sim_t, cmd))
            self._process(cmd)
            self._out_int[0] = wire.UR_READY
        elif not self._executing_cmd:
            self._executing_cmd = True
            self.commands.append((self._sim_t, cmd))
            self._process(cmd)
            if self._busy is None and self._script_running:
                self._out_int[0] = wire.UR_DONE

    def _busy_finished(self) -> bool:
        if self._busy == "move":
            return self._motion is None
        if self._busy == "stop":
            return self._stopping_decel is None
        return True

    def _pose_arg(self, first: int) -> np.ndarray:
        return np.array([self._in_double.get(first + i, 0.0) for i in range(6)], float)

    def _process(self, cmd: int) -> None:
        d = self._in_double
        if cmd == wire.CMD_MOVEL:
            target = self._pose_arg(0)
            speed, accel = d.get(6, 0.25), d.get(7, 1.2)
            self._start_move(target, speed, accel)
            if self._in_int.get(1, 0) == 0:  # synchronous: done when the move ends
                self._busy = "move"
        elif cmd == wire.CMD_FORCE_MODE:
            frame = self._pose_arg(0)
            self._force_mode = {
                "type": self._in_int.get(1, 2),
                "selection": [self._in_int.get(2 + i, 0) for i in range(6)],
                "rot": _rotvec_to_matrix(frame[3:]),
                "wrench": np.array([d.get(6 + i, 0.0) for i in range(6)]),
                "limits": np.array([d.get(12 + i, 0.0) for i in range(6)]),
            }
            self._motion = None
            self._stopping_decel = None
        elif cmd == wire.CMD_FORCE_MODE_STOP:
            self._force_mode = None
            self._motion = None
            self._stop_motion(10.0)
            self._busy = "stop"
        elif cmd == wire.CMD_ZERO_FT_SENSOR:
            self._ft_bias = self._raw_wrench()
        elif cmd == wire.CMD_SET_PAYLOAD:
            self.payload_kg = float(d.get(0, 0.0))
            self.payload_cog = tuple(float(d.get(1 + i, 0.0)) for i in range(3))
        elif cmd == wire.CMD_SET_TCP:
            self.tcp_offset = tuple(float(v) for v in self._pose_arg(0))
        elif cmd == wire.CMD_SET_DAMPING:
            self._damping = min(max(d.get(0, 0.025), 0.0), 1.0)
        elif cmd == wire.CMD_SET_GAIN_SCALING:
            self._gain_scaling = min(max(d.get(0, 0.5), 0.0), 2.0)
        elif cmd in (wire.CMD_STOPL, wire.CMD_STOPJ):
            self._stop_motion(d.get(0, 10.0))
            self._busy = "stop"
        elif cmd == wire.CMD_START_CONTACT_DETECTION:
            direction = self._pose_arg(0)[:3]
            n = float(np.linalg.norm(direction))
            self._contact = {"direction": direction / n if n > 0 else np.array([0.0, 0.0, -1.0])}
            self._contact_detected = False
            self._out_int[1] = 0
        elif cmd == wire.CMD_READ_CONTACT_DETECTION:
            self._out_int[1] = 1 if self._contact_detected else 0
        elif cmd == wire.CMD_STOP_CONTACT_DETECTION:
            self._out_int[1] = 1 if self._contact_detected else 0
            self._contact = None
        elif cmd == wire.CMD_PROTECTIVE_STOP:
            self._enter_protective_stop()
        elif cmd == wire.CMD_STOP_SCRIPT:
            self._end_script()
        else:
            log.debug("simulated controller: command %d acknowledged without effect", cmd)

    def _start_move(self, target: np.ndarray, speed: float, accel: float) -> None:
        v0 = float(np.linalg.norm(self._vel))
        self._motion = _Motion(
            self._pose, target, speed, accel, v0=v0 if self._motion is not None else 0.0
        )
        self._stopping_decel = None
        self._force_mode = None

    def _stop_motion(self, decel: float) -> None:
        self._motion = None
        if float(np.linalg.norm(self._vel)) > 0:
            self._stopping_decel = max(decel, 1e-3)
        else:
            self._stopping_decel = None

    def _end_script(self) -> None:
        self._script_running = False
        self._executing_cmd = False
        self._busy = None
        self._force_mode = None
        self._contact = None
        self._motion = None
        if float(np.linalg.norm(self._vel)) > 0:
            self._stopping_decel = 10.0
        self._out_int[0] = 0

    def _enter_protective_stop(self) -> None:
        if self._protective_stop:
            return
        log.info("simulated controller: protective stop (true force %.1f N)", self._true_force)
        self._protective_stop = True
        self._protective_stop_t = time.monotonic()  # host clock (see dashboard_reply)
        self._vel = np.zeros(3)  # a protective stop halts the arm at once
        self._end_script()
        self._stopping_decel = None

    # --- physics ---------------------------------------------------------------------------

    def _contact_force(self, pos: np.ndarray) -> tuple[float, float | None, float | None]:
        """True force (N) of the skin on the probe at ``pos`` and the patch x/y (mm)."""
        pf = self.rig.patch_frame
        x, y, h = pf.to_patch(pos[:3])
        inside = (self.rig.patch_length_mm is None or 0.0 <= x <= self.rig.patch_length_mm) and (
            self.rig.patch_width_mm is None or 0.0 <= y <= self.rig.patch_width_mm
        )
        if not self.rig.surface_present or not inside or h >= 0.0:
            return 0.0, (float(x) if inside else None), (float(y) if inside else None)
        depth = -float(h)
        k = self.rig.stiffness_n_per_mm
        t = self.rig.skin_thickness_mm
        force = k * min(depth, t) + 100.0 * k * max(depth - t, 0.0)
        return force, float(x), float(y)

    def _raw_wrench(self) -> np.ndarray:
        """What the force sensor reads before zeroing: contact + offset + noise."""
        w = np.zeros(6)
        w[:3] = self._true_force * self.rig.patch_frame.normal  # the skin pushes the tool outwards
        w[2] += self.rig.ft_offset_n + self.rig.ft_drift_n_per_s * self._sim_t
        w[:3] += self._rng.normal(0.0, self.rig.ft_noise_n, 3) if self.rig.ft_noise_n > 0 else 0.0
        return w

    def _physics_step(self, dt: float) -> None:
        if self._protective_stop:
            self._vel = np.zeros(3)
        elif self._motion is not None:
            pose, vel, done = self._motion.step(dt)
            self._pose, self._vel = pose, vel
            if done:
                self._motion = None
        elif self._stopping_decel is not None:
            speed = float(np.linalg.norm(self._vel))
            new_speed = max(0.0, speed - self._stopping_decel * dt)
            self._vel = self._vel * (new_speed / speed) if speed > 0 else self._vel
            self._pose[:3] += self._vel * dt
            if new_speed == 0.0:
                self._stopping_decel = None
        elif self._force_mode is not None:
            self._force_mode_step(dt)
        else:
            self._vel = np.zeros(3)

        force, px, py = self._contact_force(self._pose)
        self._true_force = force
        self._probe_xy = (px, py) if px is not None and force > 0.0 else None
        self._sim_t += dt
        self.trace.append(
            (self._sim_t, float(self._pose[0]), float(self._pose[1]), float(self._pose[2]), force)
        )

        if force > self.rig.protective_stop_force_n:
            self._enter_protective_stop()
        detecting = self._contact is not None and not self._contact_detected
        if detecting and force > self.rig.contact_detect_force_n:
            # like the script's contact thread: the motion stops where contact was seen
            # (stopl(3); at search speeds that is well under a control cycle)
            self._contact_detected = True
            self._motion = None
            self._stop_motion(3.0)

    def _update_sensors(self) -> None:
        """What leaves the controller once per wall cycle: the force sensor's reading (RTDE
        publishes it on the wall clock) and the probe state the simulated board samples.
        Computed after the cycle's sub-steps rather than in each, since nothing reads the
        intermediate values (and the shared-memory write is the costly part of a step)."""
        self._reported_force = self._raw_wrench() - self._ft_bias
        if self._probe_xy is not None:
            self.probe_state.set(*self._probe_xy, self._true_force)
        else:
            self.probe_state.set(None, None, 0.0)

    def _force_mode_step(self, dt: float) -> None:
        """Admittance control along the compliant axes of the task frame, speed-limited.

        Commanded speed = gain x force error (clipped to the axis' limit), gain 0.02 m/s/N
        scaled by ``forceModeSetGainScaling`` and reduced by damping.
        """
        fm = self._force_mode
        rot = fm["rot"]
        # external force on the tool in the task frame; the robot applies -(that) to the world
        ext = rot.T @ (self._true_force * self.rig.patch_frame.normal)
        applied = -ext
        vel_task = np.zeros(3)
        gain = 0.02 * self._gain_scaling * (1.0 - 0.9 * self._damping)  # m/s per N
        for i in range(3):
            if fm["selection"][i]:
                err = fm["wrench"][i] - applied[i]
                limit = abs(fm["limits"][i])
                vel_task[i] = max(-limit, min(limit, gain * err))
        # the arm does not change speed instantly: a first-order lag (tau = 20 ms) makes the
        # loop second order, so too high a gain overshoots the target force as on a real arm
        target_vel = rot @ vel_task
        self._vel = self._vel + (target_vel - self._vel) * min(dt / 0.02, 1.0)
        self._pose[:3] += self._vel * dt

    # --- network: shared ------------------------------------------------------------------

    def _accept_loop(self, listener: socket.socket, handler) -> None:
        while not self._stop_event.is_set():
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                if self._gone:
                    conn.close()
                    continue
                self._clients.add(conn)
            self._spawn(self._guard, handler, conn)

    def _guard(self, handler, conn: socket.socket) -> None:
        try:
            handler(conn)
        except (OSError, ConnectionError, struct.error):
            pass
        finally:
            with self._lock:
                self._clients.discard(conn)
            with contextlib.suppress(OSError):
                conn.close()

    @staticmethod
    def _recv_exact(conn: socket.socket, n: int) -> bytes:
        buf = b""
        while len(buf) < n:
            chunk = conn.recv(n - len(buf))
            if not chunk:
                raise ConnectionError("peer closed")
            buf += chunk
        return buf

    def _silent(self) -> bool:
        with self._lock:
            return self._blackhole

    def _serve_sink(self, conn: socket.socket) -> None:
        while conn.recv(4096):
            pass

    # --- network: RTDE ---------------------------------------------------------------------

    def _serve_rtde(self, conn: socket.socket) -> None:
        send_lock = threading.Lock()
        outputs: dict = {"names": [], "types": [], "freq": 125.0, "recipe": 0}
        inputs: dict[int, list[tuple[str, tuple[str, str]]]] = {}
        started = threading.Event()
        publisher: list[threading.Thread] = []

        def send(ptype: int, payload: bytes) -> None:
            if self._silent():
                return
            with send_lock:
                conn.sendall(struct.pack(">HB", len(payload) + 3, ptype) + payload)

        while not self._stop_event.is_set():
            size, ptype = struct.unpack(">HB", self._recv_exact(conn, 3))
            payload = self._recv_exact(conn, size - 3)
            if self._silent():
                continue
            if ptype == wire.V_REQUEST_PROTOCOL:
                send(ptype, struct.pack(">B", 1))
            elif ptype == wire.V_GET_URCONTROL_VERSION:
                send(ptype, struct.pack(">IIII", *wire.CONTROLLER_VERSION))
            elif ptype == wire.V_SETUP_OUTPUTS:
                freq = struct.unpack(">d", payload[:8])[0]
                names = [n for n in payload[8:].decode().split(",") if n]
                types = [wire.rtde_type(n) for n in names]
                ok = all(t is not None for t in types)
                outputs.update(
                    names=names,
                    types=types,
                    freq=freq if freq > 0 else 125.0,
                    recipe=1 if ok else 0,
                )
                reply = ",".join(t[0] if t else "NOT_FOUND" for t in types).encode()
                send(ptype, struct.pack(">B", outputs["recipe"]) + reply)
            elif ptype == wire.V_SETUP_INPUTS:
                names = [n for n in payload.decode().split(",") if n]
                types = [wire.rtde_type(n) for n in names]
                ok = all(t is not None for t in types)
                rid = len(inputs) + 1 if ok else 0
                if ok:
                    inputs[rid] = list(zip(names, types, strict=True))
                reply = ",".join(t[0] if t else "NOT_FOUND" for t in types).encode()
                send(ptype, struct.pack(">B", rid) + reply)
            elif ptype == wire.V_START:
                send(ptype, struct.pack(">B", 1))
                if not started.is_set():
                    started.set()
                    t = threading.Thread(
                        target=self._publish,
                        args=(conn, send, outputs, started),
                        daemon=True,
                        name="simur-publish",
                    )
                    t.start()
                    publisher.append(t)
            elif ptype == wire.V_PAUSE:
                started.clear()
                send(ptype, struct.pack(">B", 1))
            elif ptype == wire.V_DATA_PACKAGE:
                self._apply_inputs(payload, inputs)
            elif ptype == wire.V_TEXT_MESSAGE:
                pass
            else:
                log.debug("simulated controller: unknown RTDE packet type %r", ptype)
        started.clear()

    def _apply_inputs(self, payload: bytes, inputs: dict) -> None:
        rid = payload[0]
        recipe = inputs.get(rid)
        if recipe is None:
            return
        off = 1
        values: list[tuple[str, object]] = []
        for name, (_, fmt) in recipe:
            n = struct.calcsize(fmt)
            if off + n > len(payload):
                break  # ur-rtde sends only the fields a command uses
            v = struct.unpack(fmt, payload[off : off + n])
            values.append((name, v[0] if len(v) == 1 else v))
            off += n
        with self._lock:
            for name, v in values:
                m = re.fullmatch(r"input_(int|double|bit)_register_(\d+)", name)
                if not m:
                    continue
                if m.group(1) == "int":
                    self._in_int[int(m.group(2))] = int(v)
                elif m.group(1) == "double":
                    self._in_double[int(m.group(2))] = float(v)

    def _publish(self, conn: socket.socket, send, outputs: dict, started: threading.Event) -> None:
        # the requested frequency is in controller (simulated) time, like everything else
        period = 1.0 / (outputs["freq"] * self.rig.time_scale)
        next_t = time.monotonic()
        try:
            while started.is_set() and not self._stop_event.is_set():
                next_t += period
                if outputs["recipe"]:
                    with self._lock:
                        values = [self._value(n) for n in outputs["names"]]
                    body = b"".join(
                        struct.pack(t[1], *(v if isinstance(v, tuple | list) else (v,)))
                        for t, v in zip(outputs["types"], values, strict=True)
                    )
                    send(wire.V_DATA_PACKAGE, struct.pack(">B", outputs["recipe"]) + body)
                delay = next_t - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                elif delay < -0.1:
                    next_t = time.monotonic()
        except OSError:
            pass

    def _value(self, name: str):
        """The current value of an RTDE output variable (called under the lock)."""
        pose = tuple(float(v) for v in self._pose)
        speed6 = (*(float(v) for v in self._vel), 0.0, 0.0, 0.0)
        if name == "timestamp":
            return self._sim_t
        if name in ("actual_TCP_pose", "target_TCP_pose"):
            return pose
        if name in ("actual_TCP_speed", "target_TCP_speed"):
            return speed6
        if name == "actual_TCP_force":
            return tuple(float(v) for v in self._reported_force)
        if name == "ft_raw_wrench":
            return tuple(float(v) for v in self._raw_wrench())
        if name in ("actual_q", "target_q"):
            # no kinematics: a smooth, plausible function of the pose
            x, y, z = pose[:3]
            return (math.atan2(y, x), -1.2 + z, 1.5 - z, -1.9, -1.57, 0.0)
        if name in ("actual_qd", "target_qd"):
            return (float(self._vel[0]), float(self._vel[2]), -float(self._vel[2]), 0.0, 0.0, 0.0)
        if name == "robot_mode":
            return wire.ROBOT_MODE_RUNNING
        if name in ("safety_mode", "safety_status"):
            return (
                wire.SAFETY_MODE_PROTECTIVE_STOP
                if self._protective_stop
                else wire.SAFETY_MODE_NORMAL
            )
        if name == "safety_status_bits":
            return (
                wire.SAFETY_BIT_PROTECTIVE_STOP if self._protective_stop else wire.SAFETY_BIT_NORMAL
            )
        if name == "robot_status_bits":
            return wire.STATUS_POWER_ON | (
                wire.STATUS_PROGRAM_RUNNING if self._script_running else 0
            )
        if name == "runtime_state":
            return wire.RUNTIME_PLAYING if self._script_running else wire.RUNTIME_STOPPED
        if name in ("speed_scaling", "target_speed_fraction"):
            return 1.0
        if name == "payload":
            return self.payload_kg
        if name == "payload_cog":
            return self.payload_cog
        if name == "tcp_offset":
            return self.tcp_offset
        if name == "tcp_force_scalar":
            return float(np.linalg.norm(self._reported_force[:3]))
        if name == "joint_temperatures":
            return (30.0,) * 6
        if name in ("actual_main_voltage", "actual_robot_voltage"):
            return 48.0
        m = re.fullmatch(r"output_(int|double)_register_(\d+)", name)
        if m:
            idx = int(m.group(2))
            return (
                self._out_int.get(idx, 0) if m.group(1) == "int" else self._out_double.get(idx, 0.0)
            )
        kind = wire.rtde_type(name)
        if kind is None:
            return 0
        fmt = kind[1]
        count = int(fmt[1]) if fmt[1].isdigit() else 1
        zero = 0.0 if fmt[-1] == "d" else (False if fmt[-1] == "?" else 0)
        return (zero,) * count if count > 1 else zero

    # --- network: script upload ------------------------------------------------------------

    def _serve_script(self, conn: socket.socket) -> None:
        buf = b""
        conn.settimeout(0.05)
        while not self._stop_event.is_set():
            try:
                chunk = conn.recv(65536)
                if not chunk:
                    break
                buf += chunk
                continue
            except TimeoutError:
                pass
            if buf and not self._silent():
                self._run_script(buf.decode(errors="replace"))
            buf = b""
        if buf and not self._silent():
            self._run_script(buf.decode(errors="replace"))

    def _run_script(self, text: str) -> None:
        """A script arrived on 30003: the ur-rtde control script starts its command loop."""
        with self._lock:
            self.scripts_received += 1
            if "rtde_control" not in text and "def " not in text:
                return
            if self._protective_stop:
                log.info("simulated controller: script refused while protective-stopped")
                return
            self._script_running = True
            self._executing_cmd = False
            self._busy = None
            self._force_mode_defaults()

    def _force_mode_defaults(self) -> None:
        self._gain_scaling = 0.5
        self._damping = 0.025

    # --- network: dashboard ----------------------------------------------------------------

    def _serve_dashboard(self, conn: socket.socket) -> None:
        conn.sendall(b"Connected: Universal Robots Dashboard Server\n")
        buf = b""
        while not self._stop_event.is_set():
            chunk = conn.recv(4096)
            if not chunk:
                return
            buf += chunk
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                if self._silent():
                    continue
                request = line.decode(errors="replace").strip()
                reply = self.dashboard_reply(request)
                self.dashboard_log.append((request, reply))
                conn.sendall(reply.encode() + b"\n")
                if request == "quit":
                    return

    def dashboard_reply(self, request: str) -> str:
        """The dashboard server's answer to one text command (as a UR e-Series 5.11 words it)."""
        with self._lock:
            ps = self._protective_stop
            running = self._script_running
            mode = "PROTECTIVE_STOP" if ps else "NORMAL"
            cmd = request.strip()
            low = cmd.lower()
            if low == "robotmode":
                return "Robotmode: RUNNING"
            if low == "safetymode":
                return f"Safetymode: {mode}"
            if low == "safetystatus":
                return f"Safetystatus: {mode}"
            if low == "running":
                return f"Program running: {'true' if running else 'false'}"
            if low == "programstate":
                return "PLAYING rtde_control" if running else "STOPPED <unnamed>"
            if low == "polyscopeversion":
                return wire.POLYSCOPE_VERSION
            if low == "version":
                return "Version information: " + ".".join(str(v) for v in wire.CONTROLLER_VERSION)
            if low == "is in remote control":
                return "true"
            if low == "unlock protective stop":
                if not ps:
                    return "Protective stop releasing"
                # simulated seconds since the stop, from the host clock (not from _sim_t, which
                # lags the wall clock when the machine is overloaded)
                since = (time.monotonic() - (self._protective_stop_t or 0.0)) * self.rig.time_scale
                if since < self.rig.unlock_delay_s:
                    return (
                        "Cannot unlock protective stop until 5s after occurrence. "
                        "Always inspect cause of protective stop before unlocking"
                    )
                self._protective_stop = False
                self._protective_stop_t = None
                return "Protective stop releasing"
            if low == "close safety popup":
                return "closing safety popup"
            if low == "close popup":
                return "closing popup"
            if low == "stop":
                if running:
                    self._end_script()
                    return "Stopped"
                return "Failed to execute: stop"
            if low == "pause":
                return "Failed to execute: pause"
            if low == "play":
                return "Failed to execute: play"
            if low == "power on":
                return "Powering on"
            if low == "power off":
                return "Powering off"
            if low == "brake release":
                return "Brake releasing"
            if low == "get robot model":
                return "UR5"
            if low == "get serial number":
                return "20205500000"
            if low == "get loaded program":
                return "No program loaded"
            if low == "restart safety":
                self._protective_stop = False
                return "Restarting safety"
            if low == "quit":
                return "Disconnected"
            if low.startswith("popup "):
                return "showing popup"
            return f"could not understand: '{cmd}'"


# --- the process boundary ----------------------------------------------------------------
#
# ur-rtde's constructors hold Python's GIL while they wait for the controller's replies, so a
# controller served by Python threads in the same process would deadlock the client. The
# controller therefore runs in a child process; this side keeps the same API and forwards.


class _SharedProbeState(ProbeState):
    """A ``ProbeState`` whose values live in shared memory written by the child process."""

    def __init__(self, shared) -> None:
        super().__init__()
        self._shared = shared  # multiprocessing Array('d', 4): valid, x_mm, y_mm, force_n

    def set(self, x_mm: float | None, y_mm: float | None, force_n: float) -> None:
        with self._shared.get_lock():
            valid = x_mm is not None and y_mm is not None
            self._shared[:] = [1.0 if valid else 0.0, x_mm or 0.0, y_mm or 0.0, max(force_n, 0.0)]

    def get(self) -> tuple[float | None, float | None, float]:
        with self._shared.get_lock():
            valid, x, y, f = self._shared[:]
        return (x, y, f) if valid else (None, None, f)


_RPC_METHODS = {
    "inject_protective_stop", "stop_script", "drop_connections", "force_log", "tcp_log", "clear_logs",
    "tcp_pose", "protective_stopped", "script_running", "dashboard_reply", "commands_log", "scripts_received", "dashboard_log",
    "tool", "sim_time_s",
}  # fmt: skip


def _child_main(conn, shared, rig: SimRig, host: str | None, seed: int, cycle_s: float) -> None:
    logging.basicConfig(level=logging.WARNING)
    core = _ControllerCore(rig, host, seed, cycle_s, _SharedProbeState(shared))
    try:
        core.start()
    except OSError as e:
        conn.send(("error", f"{type(e).__name__}: {e}"))
        return
    conn.send(("ok", core.host))
    try:
        while True:
            try:
                name, args = conn.recv()
            except (EOFError, OSError):
                break  # the parent is gone
            if name == "stop":
                break
            try:
                if name == "commands_log":
                    result = list(core.commands)
                elif name == "dashboard_log":
                    result = list(core.dashboard_log)
                elif name == "scripts_received":
                    result = core.scripts_received
                else:
                    attr = getattr(core, name)
                    result = attr(*args) if callable(attr) else attr
                conn.send(("ok", result))
            except Exception as e:  # report, keep serving
                conn.send(("error", f"{type(e).__name__}: {e}"))
    finally:
        core.stop()
        with contextlib.suppress(OSError):
            conn.send(("ok", None))


class SimulatedController:
    """The loopback UR controller the real ur-rtde client connects to.

    ``start()`` launches it in a child process bound to ``host`` (a free random 127.x.y.z when
    None: ur-rtde's ports are fixed, so each controller needs its own loopback address) and
    returns once its ports listen. ``probe_state`` is live (shared memory). Fault injection:
    ``inject_protective_stop()``, ``stop_script()``, ``drop_connections()``.
    """

    def __init__(
        self,
        rig: SimRig | None = None,
        host: str | None = None,
        seed: int = 0,
        cycle_s: float = 0.004,
    ):
        import multiprocessing as mp

        self.rig = rig or SimRig()
        self.host: str = host or ""
        self._requested_host = host
        self.seed = seed
        self.cycle_s = cycle_s
        self._ctx = mp.get_context("spawn")
        self._shared = self._ctx.Array("d", 4)
        self.probe_state: ProbeState = _SharedProbeState(self._shared)
        self._conn = None
        self._proc = None
        self._rpc_lock = threading.Lock()

    def start(self) -> SimulatedController:
        parent, child = self._ctx.Pipe()
        self._proc = self._ctx.Process(
            target=_child_main,
            args=(child, self._shared, self.rig, self._requested_host, self.seed, self.cycle_s),
            daemon=True,
            name="simulated-ur-controller",
        )
        self._proc.start()
        child.close()
        self._conn = parent
        if not parent.poll(30.0):
            self.stop()
            raise OSError("simulated UR controller did not start within 30 s")
        status, value = parent.recv()
        if status != "ok":
            self.stop()
            raise OSError(f"simulated UR controller failed to start: {value}")
        self.host = value
        return self

    def stop(self) -> None:
        proc, conn = self._proc, self._conn
        self._proc = self._conn = None
        if conn is not None:
            with contextlib.suppress(OSError, EOFError, BrokenPipeError), self._rpc_lock:
                conn.send(("stop", ()))
                if conn.poll(5.0):
                    conn.recv()
            conn.close()
        if proc is not None:
            proc.join(timeout=5.0)
            if proc.is_alive():
                proc.terminate()
                proc.join(timeout=2.0)

    def __enter__(self) -> SimulatedController:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        return self._proc is not None and self._proc.is_alive()

    def _rpc(self, name: str, *args):
        assert name in _RPC_METHODS
        if self._conn is None:
            raise RuntimeError("simulated UR controller is not running")
        with self._rpc_lock:
            self._conn.send((name, args))
            if not self._conn.poll(10.0):
                raise TimeoutError(f"simulated UR controller did not answer {name}")
            status, value = self._conn.recv()
        if status != "ok":
            raise RuntimeError(value)
        return value

    # fault injection
    def inject_protective_stop(self) -> None:
        """The controller protective-stops now (as if it had detected a collision)."""
        self._rpc("inject_protective_stop")

    def stop_script(self) -> None:
        """The control script stops (as if someone pressed stop on the pendant)."""
        self._rpc("stop_script")

    def drop_connections(self, abrupt: bool = False) -> None:
        """The controller vanishes: silent on every connection (default: cable pulled,
        controller frozen; ur-rtde's blocking calls hang) or, with ``abrupt``, every socket
        closed and the ports no longer listening (powered off; reconnects are refused)."""
        self._rpc("drop_connections", abrupt)

    # inspection
    def force_log(self) -> np.ndarray:
        """(K, 2): simulated controller time s, TRUE contact force N, one row per physics
        step (one 4 ms control cycle of simulated time, also when time-scaled)."""
        return self._rpc("force_log")

    def tcp_log(self) -> np.ndarray:
        """(K, 4): simulated controller time s, TCP x, y, z m (rows as ``force_log``)."""
        return self._rpc("tcp_log")

    def clear_logs(self) -> None:
        self._rpc("clear_logs")

    def tool(self) -> tuple[tuple[float, ...], float, tuple[float, ...]]:
        """The TCP offset, payload mass (kg) and centre of gravity (m) the script installed."""
        return self._rpc("tool")

    def commands_log(self) -> list[tuple[float, int]]:
        """(controller time, command id) of every command the emulated script processed."""
        return self._rpc("commands_log")

    @property
    def tcp_pose(self) -> tuple[float, ...]:
        return self._rpc("tcp_pose")

    @property
    def sim_time_s(self) -> float:
        """The controller's clock now: simulated seconds, the time base of the logs. It lags
        ``time_scale`` x the wall clock when the host starves the controller's process."""
        return self._rpc("sim_time_s")

    @property
    def protective_stopped(self) -> bool:
        return self._rpc("protective_stopped")

    @property
    def script_running(self) -> bool:
        return self._rpc("script_running")

    def dashboard_log(self) -> list[tuple[str, str]]:
        """(request, reply) of every dashboard command served."""
        return self._rpc("dashboard_log")

    @property
    def scripts_received(self) -> int:
        return self._rpc("scripts_received")

"""``URArm``: the ``Arm`` protocol on a Universal Robots arm through ur-rtde 1.6.5.

Why a wrapper at all: ur-rtde's blocking commands return False instead of raising (protective
stop, control script not running, controller not ready within 3 s, command over 300 s), and
after the controller vanishes the next blocking call can hang for minutes. Here every ur-rtde
call goes through ``URArm._call``: it runs the call in a worker thread supervised by our own
timeout, checks the return value, and turns a False into the typed error the controller's
state explains (``ProtectiveStop``, ``ScriptNotRunning``, ``ConnectionLost``, ...). A call that
times out marks the connection dead; later calls fail fast with ``ConnectionLost`` until
``connect()`` builds fresh interfaces.

The touch (see ``touch``): the envelope is checked before anything moves, then approach above
the point, zero the force sensor, a *bounded* descent (contact detection + an asynchronous
moveL to a floor pose, polled against a deadline; ur-rtde's moveUntilContact has no distance
limit), force mode with a low compliant-axis speed limit, a dwell calling the recorder back,
and the retract in ``finally``.

Sign conventions (checked against the simulated controller; verify on a real arm with the
``hardware`` tests): the probe descends along base -z; ``forceMode``'s wrench is the force the
robot applies to its environment, so pressing down is ``[0, 0, -F, 0, 0, 0]``;
``getActualTCPForce()[2]`` is the environment's force on the tool, positive when pressing.
Caveat: ur-rtde's *constructors* hold Python's GIL while they wait for the controller, so the
connect timeout cannot pre-empt them; it relies on ur-rtde's own socket timeouts.
"""

from __future__ import annotations

import logging
import math
import socket
import struct
import time
from collections.abc import Callable, Sequence

import numpy as np

from robot.arm import ArmStatus, DwellCallback, DwellTick, TouchResult, TouchSpec
from robot.supervise import call_with_timeout
from varskin.errors import (
    ConnectionLost,
    ForceLimitExceeded,
    NoContact,
    ProtectiveStop,
    RobotError,
    RobotTimeout,
    ScriptNotRunning,
)

log = logging.getLogger(__name__)

SAFETY_MODES = {
    1: "normal", 2: "reduced", 3: "protective_stop", 4: "recovery", 5: "safeguard_stop",
    6: "system_emergency_stop", 7: "robot_emergency_stop", 8: "violation", 9: "fault",
    10: "validate_joint_id", 11: "undefined", 12: "automatic_mode_safeguard_stop",
    13: "system_three_position_enabling_stop",
}  # fmt: skip
_EMERGENCY_MODES = {6, 7}
_PROTECTIVE_MODES = {3, 5, 12, 13}

# interfaces abandoned after a hung call: kept referenced so their C++ destructors (which
# join threads that may never return) do not run on the caller's thread
_ABANDONED: list[object] = []

_DOWN = np.array([0.0, 0.0, -1.0])
RTDE_PORT = 30004
DASHBOARD_PORT = 29999
# Fixed parts of the touch, shared with robot.rig_time's model of it.
CONTACT_ACCEL_M_S2 = 0.5  # the descent's acceleration (default of URArm.contact_accel_m_s2)
STOP_DECEL_M_S2 = 3.0  # stopL: after contact, and in a safe stop
FORCE_MODE_QUIET_S = 0.02  # without motion before forceMode
RUNTIME_PLAYING = 2  # RTDE runtime_state
RUNTIME_PAUSED = 4
# A protective stop also ends the control script, and the two reach us on separate RTDE
# streams (rtde_control's and rtde_receive's), so the script's end can be seen first. This
# long (a dozen packets at 125 Hz) the stop is looked for before the end is called a stop.
SCRIPT_END_GRACE_S = 0.1


class URArm:
    """A UR arm through ur-rtde, implementing ``robot.arm.Arm`` (SI units, base frame)."""

    def __init__(
        self,
        host: str,
        envelope,
        *,
        call_timeout_s: float = 5.0,
        connect_timeout_s: float = 10.0,
        frequency_hz: float = 125.0,
        contact_accel_m_s2: float = CONTACT_ACCEL_M_S2,
        damping: float = 0.05,
        gain_scaling: float = 0.5,
        tcp_offset: Sequence[float] | None = None,
        payload: tuple[float, Sequence[float]] | None = None,
    ) -> None:
        """``tcp_offset`` (flange -> probe tip, [x, y, z m, rx, ry, rz rad]) and ``payload``
        (kg, centre of gravity m from the flange) are installed on the controller at
        ``connect()``: every pose and force here is the probe tip's, and the force limits
        mean what they say only with the mount's weight known. None leaves the arm's own."""
        self.host = host
        self.envelope = envelope
        self.call_timeout_s = call_timeout_s
        self.connect_timeout_s = connect_timeout_s
        self.frequency_hz = frequency_hz
        self.contact_accel_m_s2 = contact_accel_m_s2
        self.damping = damping
        self.gain_scaling = gain_scaling
        self.tcp_offset = None if tcp_offset is None else [float(v) for v in tcp_offset]
        if self.tcp_offset is not None and len(self.tcp_offset) != 6:
            raise ValueError(f"tcp_offset needs 6 numbers, got {len(self.tcp_offset)}")
        self.payload = None
        if payload is not None:
            mass, cog = payload
            self.payload = (float(mass), [float(v) for v in cog])
        self._ctrl = None
        self._recv = None
        self._dash = None
        self._dead: str | None = None  # why the connection is unusable
        self._in_force_mode = False
        self._clearance_z: float | None = None
        self.last_retract_error: BaseException | None = None

    # --- connection -----------------------------------------------------------------------

    def connect(self) -> URArm:
        try:
            import dashboard_client
            import rtde_control
            import rtde_receive
        except ImportError as e:  # pragma: no cover - the dependency is pinned in pyproject
            raise RobotError(
                f"ur-rtde is not installed ({e}); pip install ur-rtde==1.6.5"
            ) from None
        self._dead = None
        t = self.connect_timeout_s
        self._probe_controller(t)
        self._recv = self._call(
            "RTDEReceiveInterface",
            rtde_receive.RTDEReceiveInterface,
            self.host,
            self.frequency_hz,
            timeout=t,
        )
        self._dash = self._call(
            "DashboardClient", dashboard_client.DashboardClient, self.host, timeout=t
        )
        self._call("dashboard connect", self._dash.connect, timeout=t, check=False)
        self._ctrl = self._call(
            "RTDEControlInterface",
            rtde_control.RTDEControlInterface,
            self.host,
            self.frequency_hz,
            timeout=t,
        )
        if not self._call("isProgramRunning", self._ctrl.isProgramRunning, check=False):
            raise ScriptNotRunning(f"UR {self.host}: the ur-rtde control script did not start")
        self._install_tool()
        return self

    def _install_tool(self) -> None:
        """setTcp and setPayload, then read the payload back before anything moves."""
        if self.tcp_offset is not None:
            self._call("setTcp", self._ctrl.setTcp, self.tcp_offset)
        if self.payload is None:
            return
        mass, cog = self.payload
        self._call("setPayload", self._ctrl.setPayload, mass, cog)
        got = [math.nan]

        def reads_back() -> bool:
            got[0] = float(self._call("getPayload", self._recv.getPayload))
            return abs(got[0] - mass) <= 1e-3

        # RTDE reports the new payload from the next cycle on: give it a few.
        self._poll(
            reads_back,
            lambda: RobotError(
                f"UR {self.host}: the controller reports a {got[0]:g} kg payload after "
                f"setPayload({mass:g} kg); check the arm's installation before moving"
            ),
        )

    def _poll(self, done: Callable[[], bool], failure: Callable[[], RobotError]) -> None:
        """Poll ``done`` every 20 ms for up to ``call_timeout_s``; raise ``failure()`` if it
        never holds."""
        deadline = time.monotonic() + self.call_timeout_s
        while not done():
            if time.monotonic() > deadline:
                raise failure()
            time.sleep(0.02)

    def _probe_controller(self, timeout: float) -> None:
        """Check, in plain Python with socket timeouts, that the controller answers on RTDE
        (a protocol-version request) and on the dashboard (its welcome line).

        ur-rtde's constructors hold the GIL while they wait for replies, so against a frozen
        controller they would hang the whole interpreter, past any supervision; this bounds
        that case (a controller dying between the probe and the constructor remains open).
        """
        try:
            with socket.create_connection((self.host, RTDE_PORT), timeout=timeout) as s:
                s.settimeout(timeout)
                s.sendall(struct.pack(">HBH", 5, ord("V"), 2))
                head = b""
                while len(head) < 3:
                    chunk = s.recv(3 - len(head))
                    if not chunk:
                        raise ConnectionError("closed by the controller")
                    head += chunk
                if head[2] != ord("V"):
                    raise ConnectionError(f"unexpected RTDE reply type {head[2]!r}")
            with socket.create_connection((self.host, DASHBOARD_PORT), timeout=timeout) as s:
                s.settimeout(timeout)
                if not s.recv(256):
                    raise ConnectionError("dashboard closed the connection")
        except (OSError, ConnectionError) as e:
            raise ConnectionLost(
                f"UR {self.host}: controller does not answer ({type(e).__name__}: {e}); "
                "check the address, the network and that the robot is powered"
            ) from None

    def close(self) -> None:
        """Disconnect every interface (bounded: a hung interface is abandoned, not joined)."""
        ifaces = [
            ("RTDEControlInterface", self._ctrl),
            ("RTDEReceiveInterface", self._recv),
            ("dashboard", self._dash),
        ]
        self._ctrl = self._recv = self._dash = None
        if self._dead is not None:
            _ABANDONED.extend(i for _, i in ifaces if i is not None)
            return
        for name, iface in ifaces:
            if iface is None:
                continue
            if name == "RTDEControlInterface":
                try:
                    self._run(name + ".stopScript", iface.stopScript, self.call_timeout_s)
                except RobotError as e:
                    log.warning("UR %s: stopScript on close failed: %s", self.host, e)
            try:
                self._run(name + ".disconnect", iface.disconnect, self.call_timeout_s)
            except RobotError as e:
                log.warning("UR %s: %s", self.host, e)
                _ABANDONED.append(iface)

    def __enter__(self) -> URArm:
        return self.connect()

    def __exit__(self, *exc) -> None:
        self.close()

    # --- the one door to ur-rtde ----------------------------------------------------------

    def _run(self, name: str, fn: Callable, timeout: float, *args):
        """Run ``fn(*args)`` supervised; raise ``RobotTimeout`` if it outlives ``timeout``."""
        return call_with_timeout(fn, args, timeout, f"UR {self.host}: {name}")

    def _call(
        self, name: str, fn: Callable, *args, timeout: float | None = None, check: bool = True
    ):
        """Every ur-rtde call: supervised by a timeout, result checked, failures typed."""
        if self._dead is not None:
            raise ConnectionLost(
                f"UR {self.host}: connection is dead ({self._dead}); connect() again"
            )
        timeout = self.call_timeout_s if timeout is None else timeout
        try:
            result = self._run(name, fn, timeout, *args)
        except RobotTimeout as e:
            self._dead = f"{name} hung"
            if self._recv is not None and not self._peek_connected():
                raise ConnectionLost(
                    f"UR {self.host}: {name} hung and the controller is unreachable"
                ) from e
            raise
        except RobotError:
            raise
        except RuntimeError as e:  # ur-rtde raises RuntimeError for socket failures
            text = str(e)
            if any(
                w in text.lower()
                for w in ("connect", "socket", "end of file", "refused", "timed out", "broken")
            ):
                self._dead = f"{name}: {text}"
                raise ConnectionLost(f"UR {self.host}: {name} failed: {text}") from e
            raise RobotError(f"UR {self.host}: {name} failed: {text}") from e
        if check and result is False:
            self._diagnose(name)
        return result

    def _peek_connected(self) -> bool:
        """isConnected() of the receive interface, bounded (it only reads a flag)."""
        try:
            return bool(self._run("isConnected", self._recv.isConnected, 1.0))
        except (RobotTimeout, RuntimeError):
            return False

    def _diagnose(self, name: str) -> None:
        """A ur-rtde command returned False: find out why from the controller's state."""
        where = f"UR {self.host}: {name} refused"
        if not self._call("isConnected", self._recv.isConnected, check=False) or not self._call(
            "isConnected", self._ctrl.isConnected, check=False
        ):
            self._dead = f"{name}: not connected"
            raise ConnectionLost(f"{where}: controller connection lost")
        mode = int(self._call("getSafetyMode", self._recv.getSafetyMode, check=False))
        if (
            self._call("isProtectiveStopped", self._recv.isProtectiveStopped, check=False)
            or mode in _PROTECTIVE_MODES
        ):
            raise ProtectiveStop(
                f"{where}: robot is in {SAFETY_MODES.get(mode, mode)}; inspect, then recover()"
            )
        if (
            self._call("isEmergencyStopped", self._recv.isEmergencyStopped, check=False)
            or mode in _EMERGENCY_MODES
        ):
            raise ProtectiveStop(
                f"{where}: robot is emergency-stopped ({SAFETY_MODES.get(mode, mode)})"
            )
        if not self._call("isProgramRunning", self._ctrl.isProgramRunning, check=False):
            raise ScriptNotRunning(
                f"{where}: the ur-rtde control script is not running; recover() re-uploads it"
            )
        if self._call("getRuntimeState", self._recv.getRuntimeState, check=False) == RUNTIME_PAUSED:
            raise ScriptNotRunning(f"{where}: the control program is paused; recover() restarts it")
        raise RobotError(f"{where}: controller not ready within 3 s or command ran over 300 s")

    # --- reading state --------------------------------------------------------------------

    def _tcp_pose(self) -> list[float]:
        return list(self._call("getActualTCPPose", self._recv.getActualTCPPose, check=False))

    def _force_n(self) -> float:
        """Contact force along the probe axis (N, positive = pressing)."""
        f = self._call("getActualTCPForce", self._recv.getActualTCPForce, check=False)
        return float(-np.dot(np.asarray(f[:3], float), _DOWN))

    def status(self) -> ArmStatus:
        """The controller's state; a dead or closed connection reports ``connected=False``."""
        if self._recv is None or self._ctrl is None or self._dead is not None:
            return ArmStatus(False, False, False, "unknown", (), 0.0)
        connected = bool(self._call("isConnected", self._recv.isConnected, check=False)) and bool(
            self._call("isConnected", self._ctrl.isConnected, check=False)
        )
        mode = int(self._call("getSafetyMode", self._recv.getSafetyMode, check=False))
        return ArmStatus(
            connected=connected,
            program_running=bool(
                self._call("isProgramRunning", self._ctrl.isProgramRunning, check=False)
            ),
            protective_stop=bool(
                self._call("isProtectiveStopped", self._recv.isProtectiveStopped, check=False)
            ),
            safety_mode=SAFETY_MODES.get(mode, "unknown"),
            tcp_pose=tuple(self._tcp_pose()),
            tcp_force_n=self._force_n(),
        )

    # --- motion ---------------------------------------------------------------------------

    def _require(self) -> None:
        if self._ctrl is None or self._recv is None:
            raise ConnectionLost(f"UR {self.host}: not connected; call connect() first")

    def _move_timeout(self, target: Sequence[float], speed: float, accel: float) -> float:
        here = np.asarray(self._tcp_pose()[:3])
        dist = float(np.linalg.norm(np.asarray(target[:3]) - here))
        return dist / speed + 2 * speed / accel + self.call_timeout_s

    def _move_l(self, xyz: Sequence[float], speed: float, accel: float, what: str) -> None:
        self.envelope.check_point(xyz, what)
        pose = self._tcp_pose()
        target = [float(xyz[0]), float(xyz[1]), float(xyz[2]), *pose[3:]]
        timeout = self._move_timeout(target, speed, accel)
        self._call("moveL", self._ctrl.moveL, target, speed, accel, False, timeout=timeout)

    def move_above(self, point: Sequence[float], clearance_m: float) -> None:
        self._require()
        p = np.asarray(point, float).reshape(3)
        above = p - _DOWN * clearance_m
        self.envelope.check_plan(np.array([above]), "approach point")
        self._move_l(
            above, self.envelope.max_speed_m_s, self.envelope.max_accel_m_s2, "approach point"
        )
        self._clearance_z = float(above[2])

    def retract(self) -> None:
        """Straight up to the last clearance height (or 10 mm up if none is known)."""
        self._require()
        if self._in_force_mode:
            self._call("forceModeStop", self._ctrl.forceModeStop)
            self._in_force_mode = False
        pose = self._tcp_pose()
        z = self._clearance_z if self._clearance_z is not None else pose[2] + 0.01
        z = max(z, pose[2])
        self._move_l(
            [pose[0], pose[1], z],
            self.envelope.max_speed_m_s,
            self.envelope.max_accel_m_s2,
            "retract point",
        )

    def stop(self) -> None:
        self._require()
        if self._in_force_mode:
            self._call("forceModeStop", self._ctrl.forceModeStop, check=False)
            self._in_force_mode = False
        self._call("stopL", self._ctrl.stopL, self.envelope.max_accel_m_s2 * 4, check=False)

    def recover(self) -> None:
        """After a protective stop or a stopped script: unlock, close the popup, re-upload the
        control script and wait until it runs. Call only after inspecting the cause."""
        self._require()
        if self._call("isProtectiveStopped", self._recv.isProtectiveStopped, check=False):
            reply = self._call("unlockProtectiveStop", self._dash.unlockProtectiveStop, check=False)
            log.info("UR %s: unlock protective stop: %s", self.host, reply)
            self._call("closeSafetyPopup", self._dash.closeSafetyPopup, check=False)
            self._poll(
                lambda: (
                    not self._call(
                        "isProtectiveStopped", self._recv.isProtectiveStopped, check=False
                    )
                ),
                lambda: ProtectiveStop(f"UR {self.host}: protective stop did not clear ({reply})"),
            )
        self._in_force_mode = False
        running = self._call("isProgramRunning", self._ctrl.isProgramRunning, check=False)
        # a real controller may leave the program paused rather than stopped: restart it too
        runtime = self._call("getRuntimeState", self._recv.getRuntimeState, check=False)
        if not running or runtime == RUNTIME_PAUSED:
            try:
                self._call("reuploadScript", self._ctrl.reuploadScript)
            except RobotError as e:
                # reuploadScript stops a running script, then asks the dashboard to "stop";
                # if the program ended in between, the dashboard refuses and ur-rtde raises.
                if "Failed to execute" not in str(e):
                    raise
                self._call("reuploadScript", self._ctrl.reuploadScript)
            self._poll(
                lambda: self._call("isProgramRunning", self._ctrl.isProgramRunning, check=False),
                lambda: ScriptNotRunning(f"UR {self.host}: control script did not restart"),
            )

    # --- the touch ------------------------------------------------------------------------

    def _check_running(self, what: str) -> None:
        """Raise the typed error if the controller stopped us (polled during long phases)."""
        if self._call("isProtectiveStopped", self._recv.isProtectiveStopped, check=False):
            raise ProtectiveStop(f"UR {self.host}: protective stop during {what}")
        if not self._call("isConnected", self._recv.isConnected, check=False):
            self._dead = f"lost during {what}"
            raise ConnectionLost(f"UR {self.host}: connection lost during {what}")
        if not self._call("isProgramRunning", self._ctrl.isProgramRunning, check=False):
            deadline = time.monotonic() + SCRIPT_END_GRACE_S
            while time.monotonic() < deadline:
                if self._call("isProtectiveStopped", self._recv.isProtectiveStopped, check=False):
                    raise ProtectiveStop(f"UR {self.host}: protective stop during {what}")
                time.sleep(0.5 / self.frequency_hz)
            raise ScriptNotRunning(f"UR {self.host}: control script stopped during {what}")

    def _watch(self, what: str, limit_n: float) -> tuple[float, list[float]]:
        """One supervision tick: state, force limit and envelope. Returns (force, pose)."""
        self._check_running(what)
        force = self._force_n()
        pose = self._tcp_pose()
        if force > limit_n:
            raise ForceLimitExceeded(
                f"UR {self.host}: {force:.2f} N during {what}, above the {limit_n:g} N limit"
            )
        self.envelope.check_point(pose[:3], f"TCP during {what}")
        return force, pose

    def touch(
        self, point: Sequence[float], spec: TouchSpec, on_dwell: DwellCallback | None = None
    ) -> TouchResult:
        self._require()
        p = np.asarray(point, float).reshape(3)
        approach = p - _DOWN * spec.clearance_m
        floor = p + _DOWN * spec.max_depth_m
        # refuse before anything moves
        self.envelope.check_touch_spec(spec)
        self.envelope.check_plan(np.array([approach, p, floor]), "touch point")
        limit_n = min(spec.max_force_n, self.envelope.max_force_n)
        period = 1.0 / self.frequency_hz

        self.move_above(p, spec.clearance_m)
        t_contact = t_settled = t_release = None
        contact_z = None
        forces: list[float] = []
        dwell_forces: list[float] = []
        try:
            self._call("zeroFtSensor", self._ctrl.zeroFtSensor)
            # bounded descent: contact detection + asynchronous move to the floor
            speed = spec.search_speed_m_s
            accel = min(self.contact_accel_m_s2, self.envelope.max_accel_m_s2)
            self._call(
                "startContactDetection",
                self._ctrl.startContactDetection,
                [0.0, 0.0, -speed, 0.0, 0.0, 0.0],
            )
            pose = self._tcp_pose()
            floor_pose = [float(floor[0]), float(floor[1]), float(floor[2]), *pose[3:]]
            self._call("moveL async", self._ctrl.moveL, floor_pose, speed, accel, True)
            deadline = (
                time.monotonic()
                + (spec.clearance_m + spec.max_depth_m) / speed
                + 2 * speed / accel
                + 1.0
            )
            detected = False
            try:
                while True:
                    if self._call(
                        "readContactDetection", self._ctrl.readContactDetection, check=False
                    ):
                        detected = True
                        t_contact = time.monotonic()
                        break
                    _, pose = self._watch("descent", limit_n)
                    if pose[2] <= floor[2] + 1e-5:
                        # the floor reached; one last look (contact may land on the last cycle)
                        detected = bool(
                            self._call(
                                "readContactDetection", self._ctrl.readContactDetection, check=False
                            )
                        )
                        t_contact = time.monotonic() if detected else None
                        break
                    if time.monotonic() > deadline:
                        raise RobotTimeout(
                            f"UR {self.host}: descent did not reach contact or floor in time"
                        )
            except BaseException:
                self._best_effort("stopContactDetection", self._ctrl.stopContactDetection)
                raise
            self._call("stopContactDetection", self._ctrl.stopContactDetection, check=False)
            self._call("stopL", self._ctrl.stopL, STOP_DECEL_M_S2, check=False)
            if not detected:
                raise NoContact(
                    f"UR {self.host}: no contact down to the floor {spec.max_depth_m * 1000:g} mm below "
                    f"({p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}) m"
                )
            contact_z = self._tcp_pose()[2]

            # hold the target force: parameters first, no motion in the 20 ms before force mode
            self._call("forceModeSetDamping", self._ctrl.forceModeSetDamping, self.damping)
            self._call(
                "forceModeSetGainScaling", self._ctrl.forceModeSetGainScaling, self.gain_scaling
            )
            time.sleep(FORCE_MODE_QUIET_S)
            limits = [
                0.01,
                0.01,
                spec.force_speed_limit_m_s,
                math.radians(5),
                math.radians(5),
                math.radians(5),
            ]
            task_frame = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
            wrench = [0.0, 0.0, -spec.target_force_n, 0.0, 0.0, 0.0]
            self._call(
                "forceMode", self._ctrl.forceMode, task_frame, [0, 0, 1, 0, 0, 0], wrench, 2, limits
            )
            self._in_force_mode = True

            t_end = time.monotonic() + spec.settle_s
            while time.monotonic() < t_end:
                force, _ = self._watch("settle", limit_n)
                forces.append(force)
                time.sleep(period)
            t_settled = time.monotonic()
            while True:
                now = time.monotonic()
                elapsed = now - t_settled
                if elapsed >= spec.dwell_s:
                    break
                force, _ = self._watch("dwell", limit_n)
                forces.append(force)
                dwell_forces.append(force)
                if on_dwell is not None and on_dwell(DwellTick(now, elapsed, force)):
                    break
                time.sleep(period)
            t_release = time.monotonic()
            self._call("forceModeStop", self._ctrl.forceModeStop)
            self._in_force_mode = False
        except BaseException as err:
            self._safe_stop()
            self._retract_after(err)
            raise
        self._retract_after(None)
        return TouchResult(
            contact=True,
            contact_z_m=contact_z,
            t_contact=t_contact,
            t_settled=t_settled,
            t_release=t_release,
            peak_force_n=max(forces) if forces else 0.0,
            mean_force_n=float(np.mean(dwell_forces)) if dwell_forces else 0.0,
        )

    def _best_effort(self, name: str, fn: Callable, *args) -> None:
        """A clean-up call while an error propagates: never raises, never masks that error."""
        if self._dead is not None:
            return
        try:
            self._call(name, fn, *args, check=False)
        except RobotError as e:
            log.warning("UR %s: %s during clean-up failed: %s", self.host, name, e)

    def _safe_stop(self) -> None:
        """Leave force mode and halt, best effort (the controller may already have stopped us)."""
        if self._in_force_mode:
            self._best_effort("forceModeStop", self._ctrl.forceModeStop)
            self._in_force_mode = False
        self._best_effort("stopL", self._ctrl.stopL, STOP_DECEL_M_S2)

    def _retract_after(self, err: BaseException | None) -> None:
        """The retract of ``finally``: always attempted; its failure never hides ``err``."""
        self.last_retract_error = None
        try:
            self.retract()
        except RobotError as e:
            self.last_retract_error = e
            if err is None:
                raise
            log.warning("UR %s: retract after %s failed: %s", self.host, type(err).__name__, e)
            err.add_note(f"retract attempted and failed: {e}")

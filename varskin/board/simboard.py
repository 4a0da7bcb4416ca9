"""A fake Muca firmware behind a real pseudo-terminal, so tests and demos exercise the
exact serial path a real board does.

The board writes the raw firmware's ASCII frames into the master side of ``os.openpty()``;
the recorder opens the slave side by its device path with pyserial, like ``/dev/ttyACM0``.
Values come from the shared simulated scene: at every frame the board reads where the probe
is and how hard it presses (``ProbeState``, written by the simulated robot or by the
scripted touch demo) and samples ``Scene.sample`` (rest, drift, touch response, noise).

The device is published under a stable symlink, as udev does with /dev/serial/by-id, so an
unplug (both pty ends closed, link removed) and a replug (a fresh pty, link re-pointed) look
to the recorder like a USB board going away and coming back. A pty ignores baud rate, so
the line rate is paced in software. Faults a bench really produces can be injected: garbage
bytes, truncated lines, log lines and I2C failure messages.

Time can run faster than the wall clock (``time_scale``, simulated seconds per wall second,
as ``robot.sim_controller.SimRig.time_scale``), so a board beside a time-scaled simulated
controller drifts and streams per *simulated* second as it would in real time: the scene's
clock is ``time_scale`` x the wall seconds since start, and the frame rate (``rate_hz`` and
the baud-rate pacing) is multiplied by it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import queue
import select
import shutil
import tempfile
import threading
import time
import tty
from pathlib import Path

import numpy as np

from varskin.board.cellmap import CellMap
from varskin.board.frame import N_RX, N_TX
from varskin.board.protocol import format_frame
from varskin.patch import Patch
from varskin.scene import ProbeModel, ProbeState, Scene, SceneParams

STAMP_CELL = (N_TX - 1, N_RX - 1)  # the last cell sent; no published patch wires it
USB_PACKET = 64  # bytes per USB full-speed bulk packet
FAULTS = ("garbage", "truncated", "log", "i2c")
BOOT_LOG = (b"[Muca] Init\r\n", b"[Muca] Set TEST mode\r\n", b"[Muca] Gain set to 8\r\n")


class SimBoard:
    def __init__(
        self,
        patch: Patch,
        scene: Scene | None = None,
        probe_state: ProbeState | None = None,
        probe: ProbeModel | None = None,
        rate_hz: float | None = None,
        baud: int | None = 115200,
        reverse_tx: bool | None = None,
        empty_zero: bool = False,
        seed: int = 0,
        touch_demo: bool = False,
        stamp_seq: bool = False,
        fault_rate: float = 0.0,
        link_path: str | Path | None = None,
        time_scale: float = 1.0,
    ):
        """``rate_hz`` None: as fast as ``baud`` allows (~8 frames/s at 115200); ``baud``
        None or 0: no line-rate limit. ``stamp_seq`` writes the board's frame number (mod
        65536) into cell (20, 11) so a test can prove no frame was lost. ``fault_rate`` is
        the chance per frame of one random injected fault. ``time_scale``: simulated seconds
        per wall second; ``rate_hz`` and ``baud`` are per simulated second, so the wall frame
        rate is ``time_scale`` times theirs."""
        if rate_hz is not None and rate_hz <= 0:
            raise ValueError("rate_hz must be > 0")
        if not (np.isfinite(time_scale) and time_scale > 0):
            raise ValueError("time_scale must be > 0")
        self.patch = patch
        wiring = patch.wiring
        if reverse_tx is not None:
            wiring = dataclasses.replace(wiring, reverse_tx=reverse_tx)
        self.cellmap = CellMap.from_patch(dataclasses.replace(patch, wiring=wiring))
        if stamp_seq and self.cellmap.used_mask()[STAMP_CELL]:
            raise ValueError(f"patch {patch.name} wires cell {STAMP_CELL}; cannot stamp it")
        self.scene = scene or Scene.create(patch, seed, SceneParams(inverted=wiring.inverted))
        self.probe_state = probe_state or ProbeState()
        # The scripted demo stands in for a person pressing with a finger.
        self.probe = probe or ProbeModel.named("finger" if touch_demo else "robot")
        self.rate_hz = rate_hz
        self.baud = baud or None
        self.time_scale = float(time_scale)
        self.empty_zero = empty_zero
        self.touch_demo = touch_demo
        self.stamp_seq = stamp_seq
        self.fault_rate = fault_rate
        self._rng = np.random.default_rng(seed + 1)
        self._fault_rng = np.random.default_rng(seed + 2)
        # Unwired cells: a fixed level per cell (a few read 0) plus small noise; with the
        # wired ones this gives the real ~1.3-1.4 kB lines, ~8 frames/s at 115200 baud.
        level = self._rng.uniform(5000, 14000, (N_TX, N_RX))
        level[self._rng.random((N_TX, N_RX)) < 0.05] = 0
        self._background = level
        self._unused = ~self.cellmap.used_mask()

        self._own_dir: str | None = None
        if link_path is None:
            self._own_dir = tempfile.mkdtemp(prefix="varskin-muca-")
            link_path = Path(self._own_dir) / "ttyMUCA0"
        self.path = str(link_path)  # the stable device path to open
        self.pty_name = ""  # the current /dev/pts/N behind it

        self._lock = threading.Lock()  # guards the fds against unplug from another thread
        self._master: int | None = None
        self._slave: int | None = None
        self._injections: queue.Queue[tuple[str, bytes]] = queue.Queue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._cmd_buf = bytearray()
        self._t0 = 0.0

        self.frames_made = 0  # frames sampled, sent or not
        self.frames_written = 0  # complete frames written to the line
        self.frames_skipped = 0  # frames not sent because nobody drained the line
        self.faults_injected = 0
        self.gain = 8
        self.calibrations = 0
        self.hung = False  # firmware stuck (e.g. an I2C lock-up): the USB stays, frames stop

    # --- life cycle ---------------------------------------------------------------------

    def start(self) -> SimBoard:
        self._plug()
        self._t0 = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="sim-muca", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        self.unplug()
        if self._own_dir is not None:
            shutil.rmtree(self._own_dir, ignore_errors=True)

    def __enter__(self) -> SimBoard:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # --- faults -------------------------------------------------------------------------

    def unplug(self) -> None:
        """The cable is pulled: both pty ends close and the device path disappears."""
        with self._lock:
            for fd in (self._master, self._slave):
                if fd is not None:
                    os.close(fd)
            self._master = self._slave = None
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.path)

    def replug(self) -> None:
        """The cable is back: a fresh pty under the same path, firmware booting from scratch."""
        self.unplug()
        self._plug()

    def inject(self, kind: str, text: str = "") -> None:
        """Queue one fault, written between two frames: garbage, truncated, log or i2c."""
        if kind not in FAULTS:
            raise ValueError(f"unknown fault {kind!r}; one of {FAULTS}")
        self._injections.put((kind, text.encode("ascii", "replace")))

    # --- internals ----------------------------------------------------------------------

    def _plug(self) -> None:
        master, slave = os.openpty()
        # Raw mode at once: the default line discipline would echo our frames back and
        # turn CR into NL before the recorder gets to configure the port.
        tty.setraw(slave)
        os.set_blocking(master, False)
        tmp = f"{self.path}.tmp{os.getpid()}"
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.path)
        with self._lock:
            self._master, self._slave = master, slave
            self.pty_name = os.ttyname(slave)
            for line in BOOT_LOG:
                self._write(line, timeout_s=0.0)

    def _run(self) -> None:
        next_t = time.monotonic()
        while not self._stop.is_set():
            self._serve_commands(max(0.0, next_t - time.monotonic()))
            if self._stop.is_set():
                break
            now = time.monotonic()
            if now < next_t:
                continue
            self._inject_pending()
            line = self._next_line(now)
            self._send_frame(line)
            # wall seconds per frame: the simulated rates run time_scale times faster
            interval = 1.0 / (self.rate_hz * self.time_scale) if self.rate_hz else 0.0
            if self.baud:
                interval = max(interval, len(line) * 10 / (self.baud * self.time_scale))
            # Keep a steady rate, but never burst to catch up after a stall.
            next_t = max(next_t + interval, time.monotonic() - interval)

    def _send_frame(self, line: bytes) -> None:
        """Write one frame; with baud pacing it trickles out in 64-byte USB CDC packets, so
        the line completes on the host one transmission time after the board sampled it."""
        packet = USB_PACKET if self.baud else len(line)
        step = packet * 10 / (self.baud * self.time_scale) if self.baud else 0.0
        t0 = time.monotonic()
        for k, i in enumerate(range(0, len(line), packet)):
            delay = t0 + k * step - time.monotonic()
            if delay > 0 and self._stop.wait(delay):
                return
            with self._lock:
                if self._master is None or self.hung:
                    return  # unplugged or stuck: the frame is simply never sent
                if not self._write(line[i : i + packet], timeout_s=0.5):
                    self.frames_skipped += 1  # nobody drains the line
                    return
        with self._lock:
            self.frames_written += 1

    def _next_line(self, now: float) -> bytes:
        t = (now - self._t0) * self.time_scale  # scene (simulated) seconds since start
        if self.touch_demo:
            self.probe_state.set(*self._scripted_touch(t))
        x, y, force = self.probe_state.get()
        values = self.scene.sample(x, y, force, self.probe, t, self._rng)
        cells = self._background + self._rng.normal(0, 3.0, (N_TX, N_RX))
        cells[self._background == 0] = 0
        cells = np.clip(np.rint(cells), 0, 65535)
        self.cellmap.place(values, cells)
        if self.stamp_seq:
            # Numbered as made, not as sent: a frame that could not be sent leaves a hole.
            cells[STAMP_CELL] = self.frames_made % 65536
        self.frames_made += 1
        return format_frame(cells.astype(np.int64), empty_zero=self.empty_zero)

    def _scripted_touch(self, t: float) -> tuple[float | None, float | None, float]:
        """Standalone demo: press each sensor's design position in turn, 1.5 s on, 1 s off."""
        period = 2.5
        k = int(t // period) % len(self.patch.sensors)
        if t % period < 1.0:
            return None, None, 0.0
        s = self.patch.sensors[k]
        return s.x_mm, s.y_mm, self.probe.nominal_force_n

    def _inject_pending(self) -> None:
        if self.fault_rate and self._fault_rng.random() < self.fault_rate:
            self.inject(FAULTS[int(self._fault_rng.integers(len(FAULTS)))])
        while True:
            try:
                kind, text = self._injections.get_nowait()
            except queue.Empty:
                return
            if kind == "garbage":
                data = text or bytes(self._fault_rng.integers(0, 256, 40, dtype=np.uint8))
            elif kind == "truncated":
                # The firmware reset mid-line: half a frame, then the line just ends.
                full = format_frame(np.full((N_TX, N_RX), 1234))
                data = (text or full[: len(full) // 2]) + b"\r\n"
            elif kind == "log":
                data = b"[Muca] " + (text or b"Set TEST mode") + b"\r\n"
            else:
                data = b"[Muca] i2c write failed\r\n"
            with self._lock:
                if self._master is not None and self._write(data, timeout_s=0.5):
                    self.faults_injected += 1

    def _write(self, data: bytes, timeout_s: float) -> bool:
        """Write all of ``data`` to the master (caller holds the lock); False if the line
        stayed full. A half-written line stays half-written, as on a real link."""
        assert self._master is not None
        view = memoryview(data)
        deadline = time.monotonic() + timeout_s
        first = True
        while view:
            try:
                n = os.write(self._master, view)
            except BlockingIOError:
                n = 0
            except OSError:
                return False
            view = view[n:]
            if not view:
                return True
            if first and n == 0 and timeout_s == 0.0:
                return False
            first = False
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            select.select([], [self._master], [], min(remaining, 0.05))
        return True

    def _serve_commands(self, wait_s: float) -> None:
        """Wait up to ``wait_s`` for the host's commands: ``c`` recalibrates, ``g:<n>`` sets
        the gain (1-31). The board acknowledges with the library's log lines."""
        with self._lock:
            master = self._master
        if master is None:
            self._stop.wait(wait_s)
            return
        try:
            ready, _, _ = select.select([master], [], [], wait_s)
        except (OSError, ValueError):
            return
        if not ready:
            return
        with self._lock:
            if self._master != master:
                return
            try:
                data = os.read(master, 256)
            except (BlockingIOError, OSError):
                # EIO: nobody has the slave open right now; nothing to read.
                time.sleep(min(wait_s, 0.01))
                return
        self._cmd_buf += data
        replies = []
        while self._cmd_buf:
            if self._cmd_buf[:1] in (b"\r", b"\n", b" "):
                del self._cmd_buf[:1]
            elif self._cmd_buf[:1] == b"c":
                del self._cmd_buf[:1]
                self.calibrations += 1
                replies.append(b"[Muca] Calibrate\r\n")
            elif b"\n" in self._cmd_buf:
                cmd, _, rest = bytes(self._cmd_buf).partition(b"\n")
                self._cmd_buf[:] = rest
                cmd = cmd.strip()
                if cmd.startswith(b"g:") and cmd[2:].isdigit() and 1 <= int(cmd[2:]) <= 31:
                    self.gain = int(cmd[2:])
                    replies.append(b"[Muca] Gain set to %d\r\n" % self.gain)
                else:
                    replies.append(b"[Muca] Unknown command\r\n")
            else:
                break  # wait for the rest of the command
        if replies:
            with self._lock:
                if self._master is not None:
                    self._write(b"".join(replies), timeout_s=0.5)

"""Reads a Muca board on its own thread and keeps reading through unplugs.

The port is opened with pyserial's ``serial_for_url``, so a USB device (``/dev/ttyACM0``),
a pseudo-terminal path (the simulated board) and ``loop://`` all take the same code path.
Each frame is stamped with the host's monotonic clock the moment its line completes, since
the board sends no time of its own. Frames and gaps go to subscribers (plain callables):
the live display, the CSV sink and the session store are all just subscribers.

A lost device is normal on a bench (a cable gets knocked): the recorder closes the port,
retries with bounded exponential backoff, records the gap, and resynchronizes the parser
so the first partial line after the reconnect cannot become a frame.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import serial

from varskin.board.frame import Frame, Gap
from varskin.board.protocol import AsciiFrameParser
from varskin.errors import BoardDisconnected, BoardError, BoardTimeout

Event = Frame | Gap
Subscriber = Callable[[Event], None]


@dataclass(frozen=True)
class RecorderStats:
    frames: int
    frames_per_s: float  # over the last few seconds
    drops: dict[str, int]
    gaps: tuple[Gap, ...]
    connected: bool
    reconnects: int
    subscriber_errors: int
    thread_cpu_s: float  # CPU time the reader thread used so far
    # Longest time between two returns from read(): normally at most the read timeout plus
    # parsing. Much more means the host starved the thread, the usual cause of lost frames.
    max_read_interval_s: float
    log_lines: tuple[str, ...] = field(default=())


class Recorder:
    """``start()`` opens the port (an unopenable port is the user's error, raised at once);
    from then on the reader thread owns the port until ``stop()``."""

    def __init__(
        self,
        url: str,
        baudrate: int = 115200,
        read_timeout_s: float = 0.05,
        backoff_s: tuple[float, float] = (0.05, 2.0),
        stall_check_s: float = 1.0,
        rate_window_s: float = 2.0,
    ):
        self.url = url
        self.baudrate = baudrate
        self.read_timeout_s = read_timeout_s
        self.backoff_s = backoff_s
        self.stall_check_s = stall_check_s
        self._subscribers: list[Subscriber] = []
        self._parser = AsciiFrameParser()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._connected = threading.Event()
        self._first_frame = threading.Event()
        self._thread: threading.Thread | None = None
        self._port: serial.SerialBase | None = None
        self._frames = 0
        self._times: deque[float] = deque()
        self._rate_window_s = rate_window_s
        self._gaps: list[Gap] = []
        self._reconnects = 0
        self._subscriber_errors = 0
        self._cpu_s = 0.0
        self._last_frame_t: float | None = None
        self._device_id: tuple[int, int] | None = None
        self._t_cpu0 = 0.0
        self._started_at = 0.0
        self._max_read_interval_s = 0.0

    # --- public API ---------------------------------------------------------------------

    def subscribe(self, fn: Subscriber) -> None:
        """``fn`` is called on the reader thread with every Frame and Gap; keep it quick."""
        with self._lock:
            self._subscribers.append(fn)

    def start(self) -> Recorder:
        if self._thread is not None:
            raise RuntimeError("recorder already started")
        self._port = self._open()
        self._started_at = time.monotonic()
        self._connected.set()
        self._thread = threading.Thread(
            target=self._run, name=f"muca-recorder {self.url}", daemon=True
        )
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop reading, join the thread and close the port, all within ``timeout_s``."""
        self._stop.set()
        port = self._port
        if port is not None and hasattr(port, "cancel_read"):
            # Best-effort wake-up of a blocked read; the read timeout would end it anyway.
            with contextlib.suppress(Exception):
                port.cancel_read()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                raise BoardError(f"recorder thread on {self.url} did not stop within {timeout_s} s")
        self._close()
        self._connected.clear()

    def __enter__(self) -> Recorder:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def wait_for_frame(self, timeout_s: float) -> None:
        """Return once any frame arrived; ``BoardTimeout`` naming the port otherwise."""
        if not self._first_frame.wait(timeout_s):
            drops = self.stats().drops
            seen = ", ".join(f"{k}={v}" for k, v in sorted(drops.items()))
            hint = (
                f" (lines dropped: {seen}; is the baud rate right?)"
                if seen
                else " (no lines at all)"
            )
            raise BoardTimeout(f"{self.url}: no valid Muca frame within {timeout_s:g} s{hint}")

    def wait_connected(self, timeout_s: float) -> bool:
        return self._connected.wait(timeout_s)

    def send(self, data: bytes) -> None:
        """Write to the board (autocalibration sketch commands such as ``b"g:8\\n"``)."""
        port = self._port
        if port is None or not self._connected.is_set():
            raise BoardDisconnected(f"{self.url}: not connected")
        try:
            port.write(data)
        except (serial.SerialException, OSError) as e:
            raise BoardDisconnected(f"{self.url}: write failed ({e})") from None

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    def stats(self) -> RecorderStats:
        with self._lock:
            now = time.monotonic()
            self._trim_times(now)
            # Frames in the last window over the window (or the time since start, if shorter).
            span = min(self._rate_window_s, now - self._started_at)
            rate = len(self._times) / span if span > 0.2 else 0.0
            return RecorderStats(
                frames=self._frames,
                frames_per_s=rate,
                drops=dict(self._parser.drops),
                gaps=tuple(self._gaps),
                connected=self._connected.is_set(),
                reconnects=self._reconnects,
                subscriber_errors=self._subscriber_errors,
                thread_cpu_s=self._cpu_s,
                max_read_interval_s=self._max_read_interval_s,
                log_lines=tuple(self._parser.log_lines),
            )

    # --- the reader thread ----------------------------------------------------------------

    def _open(self) -> serial.SerialBase:
        try:
            port = serial.serial_for_url(
                self.url, baudrate=self.baudrate, timeout=self.read_timeout_s
            )
        except (serial.SerialException, OSError, ValueError) as e:
            code = getattr(e, "errno", None)
            reason = os.strerror(code) if isinstance(code, int) else str(e)
            raise BoardError(f"cannot open serial port {self.url}: {reason}") from None
        self._device_id = self._identity()
        return port

    def _identity(self) -> tuple[int, int] | None:
        """Which device node the path names now (a replugged device gets a new one)."""
        if "://" in self.url:
            return None
        try:
            st = os.stat(self.url)
        except OSError:
            return None
        return (st.st_dev, st.st_rdev)

    def _close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            # A vanished device may fail to close cleanly; it is gone either way.
            with contextlib.suppress(Exception):
                port.close()

    def _run(self) -> None:
        self._t_cpu0 = time.thread_time()
        try:
            while not self._stop.is_set():
                try:
                    self._read_until_lost()
                except (serial.SerialException, OSError) as e:
                    if self._stop.is_set():
                        break
                    self._reconnect(f"{type(e).__name__}: {e}")
        finally:
            self._cpu_s = time.thread_time() - self._t_cpu0

    def _read_until_lost(self) -> None:
        port = self._port
        assert port is not None
        last_data = last_read = time.monotonic()
        while not self._stop.is_set():
            waiting = port.in_waiting
            data = port.read(waiting if waiting > 0 else 1)
            now = time.monotonic()
            if now - last_read > self._max_read_interval_s:
                self._max_read_interval_s = now - last_read
            last_read = now
            if not data:
                # Silence: check the device node is still the one we opened (udev removes
                # or replaces it on unplug; a read on a dead pty may just time out).
                if now - last_data > self.stall_check_s:
                    last_data = now
                    if self._device_id is not None and self._identity() != self._device_id:
                        raise BoardDisconnected(f"{self.url}: device node vanished")
                continue
            last_data = now
            if waiting == 0 and port.in_waiting:
                data += port.read(port.in_waiting)
                now = time.monotonic()
            with self._lock:  # stats() reads the parser's drop counts
                frames = self._parser.feed(data, now)
            if frames:
                self._deliver_frames(frames)
            self._cpu_s = time.thread_time() - self._t_cpu0

    def _deliver_frames(self, frames: list[Frame]) -> None:
        with self._lock:
            self._frames += len(frames)
            self._times.extend(f.t for f in frames)
            self._trim_times(frames[-1].t)
            self._last_frame_t = frames[-1].t
            subscribers = list(self._subscribers)
        self._first_frame.set()
        for frame in frames:
            self._publish(subscribers, frame)

    def _publish(self, subscribers: list[Subscriber], event: Event) -> None:
        for fn in subscribers:
            try:
                fn(event)
            except Exception:  # one bad subscriber must not stop recording
                with self._lock:
                    self._subscriber_errors += 1

    def _trim_times(self, now: float) -> None:
        while self._times and now - self._times[0] > self._rate_window_s:
            self._times.popleft()

    def _reconnect(self, reason: str) -> None:
        start = time.monotonic()
        self._connected.clear()
        self._close()
        delay, max_delay = self.backoff_s
        while not self._stop.wait(delay):
            try:
                self._port = self._open()
            except BoardError:
                delay = min(delay * 2, max_delay)
                continue
            break
        if self._port is None:
            # Stopped while the device was away: the gap still belongs in the record.
            gap = Gap(
                start, time.monotonic(), f"{reason}; not back before stop", self._last_frame_t
            )
            with self._lock:
                self._gaps.append(gap)
                subscribers = list(self._subscribers)
            self._publish(subscribers, gap)
            return
        with self._lock:
            self._parser.resync()
        gap = Gap(start, time.monotonic(), reason, self._last_frame_t)
        with self._lock:
            self._gaps.append(gap)
            self._reconnects += 1
            subscribers = list(self._subscribers)
        self._connected.set()
        self._publish(subscribers, gap)

"""The recorder reading the simulated board through a real pseudo-terminal (and loop://)."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest
import serial

from varskin.board.cellmap import CellMap
from varskin.board.frame import Frame, Gap
from varskin.board.protocol import LOG_LINE, format_frame
from varskin.board.recorder import Recorder
from varskin.board.simboard import STAMP_CELL, SimBoard
from varskin.errors import BoardError, BoardTimeout


def wait_until(cond, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.01)
    return cond()


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


class Collector:
    def __init__(self):
        self.events: list[Frame | Gap] = []
        self.threads: set[str] = set()

    def __call__(self, event):
        self.threads.add(threading.current_thread().name)
        self.events.append(event)

    @property
    def frames(self) -> list[Frame]:
        return [e for e in self.events if isinstance(e, Frame)]

    @property
    def gaps(self) -> list[Gap]:
        return [e for e in self.events if isinstance(e, Gap)]


@pytest.fixture
def sim(patch_b):
    board = SimBoard(patch_b, rate_hz=100, baud=None, stamp_seq=True, seed=1).start()
    yield board
    board.stop()


def stamps(frames) -> list[int]:
    return [int(f.cells[STAMP_CELL]) for f in frames]


def test_reads_a_real_pty_and_delivers_scene_values(sim, patch_b):
    assert os.path.islink(sim.path) and sim.pty_name.startswith("/dev/pts/")
    target = patch_b.sensor("S14")
    sim.probe_state.set(target.x_mm, target.y_mm, 2.0)
    got = Collector()
    rec = Recorder(sim.path)
    rec.subscribe(got)
    t_before = time.monotonic()
    with rec:
        rec.wait_for_frame(3.0)
        assert wait_until(lambda: len(got.frames) >= 30)
    t_after = time.monotonic()
    frames = got.frames
    assert got.threads == {f"muca-recorder {sim.path}"}  # delivered on the reader thread
    t = np.array([f.t for f in frames])
    # Host monotonic clock; frames whose lines completed in the same read share a time.
    assert np.all(np.diff(t) >= 0) and t_before <= t[0] and t[-1] <= t_after
    assert len(set(t.tolist())) > len(t) // 2  # mostly one frame per read at 100 frames/s
    assert [f.seq for f in frames] == list(range(len(frames)))
    # The pressed sensor stands out against its rest value; idle ones stay near rest.
    values = np.array([CellMap.from_patch(patch_b).values(f) for f in frames])
    rise = values.mean(axis=0) - sim.scene.rest
    expected = sim.scene.response(target.x_mm, target.y_mm, 2.0, sim.probe)
    assert expected.max() > 50
    # Mean of >= 30 frames: noise ~1 count, drift in the first second < 3 counts.
    np.testing.assert_allclose(rise, expected, atol=8)
    stats = rec.stats()
    assert stats.frames == len(frames) and not stats.gaps and not stats.connected


def test_loop_url_works_and_send_reaches_the_line():
    got = Collector()
    rec = Recorder("loop://", read_timeout_s=0.02)
    rec.subscribe(got)
    cells = (np.arange(252) * 3).reshape(21, 12)
    with rec:
        rec.send(
            b"\r\n" + format_frame(cells) + b"[Muca] Gain set to 8\r\n" + format_frame(cells + 1)
        )
        assert wait_until(lambda: len(got.frames) == 2)
        stats = rec.stats()
    assert got.frames[0].cells.tolist() == cells.tolist()
    assert got.frames[1].cells.tolist() == (cells + 1).tolist()
    assert stats.drops == {"partial_start": 1, LOG_LINE: 1}
    assert stats.log_lines == ("[Muca] Gain set to 8",)


def test_unplug_reconnects_records_the_gap_and_keeps_recording(sim):
    got = Collector()
    rec = Recorder(sim.path, backoff_s=(0.02, 0.2))
    rec.subscribe(got)
    with rec:
        rec.wait_for_frame(3.0)
        assert wait_until(lambda: len(got.frames) >= 20)
        before = len(got.frames)
        sim.unplug()
        assert wait_until(lambda: not rec.connected, 3.0)
        time.sleep(0.3)  # the board stays away a while
        sim.replug()
        # Counted from the gap, not from `before`: a frame may still land between that count
        # and the unplug, and it belongs before the gap.
        assert wait_until(
            lambda: bool(got.gaps) and sum(f.t > got.gaps[0].end for f in got.frames) >= 20, 5.0
        )
        stats = rec.stats()
    assert stats.reconnects == 1 and len(stats.gaps) == 1
    (gap,) = got.gaps
    assert gap == stats.gaps[0]
    assert gap.duration_s >= 0.25
    assert gap.last_frame_t <= gap.start < gap.end
    pre = [f for f in got.frames if f.t <= gap.last_frame_t]
    after = [f for f in got.frames if f.t > gap.end]
    assert len(pre) >= before and len(after) >= 20
    assert len(pre) + len(after) == len(got.frames)  # none inside the gap
    assert pre[-1].t == gap.last_frame_t
    # The gap event is delivered in order: after the last frame before it, before the rest.
    i = got.events.index(gap)
    assert all(isinstance(e, Frame) and e.t <= gap.start for e in got.events[:i])
    assert all(e.t >= gap.end for e in got.events[i + 1 :])
    assert stats.drops.get("partial_start", 0) == 2


def test_stop_is_clean_and_bounded_even_while_the_device_is_away(sim):
    fds = open_fds()
    rec = Recorder(sim.path, backoff_s=(0.05, 10.0)).start()
    rec.wait_for_frame(3.0)
    sim.unplug()
    assert wait_until(lambda: not rec.connected, 3.0)
    time.sleep(0.5)  # the backoff is now long
    t0 = time.monotonic()
    rec.stop(timeout_s=2.0)
    assert time.monotonic() - t0 < 2.0
    assert not any(t.name.startswith("muca-recorder") for t in threading.enumerate())
    assert open_fds() <= fds
    (gap,) = rec.stats().gaps  # the unfinished gap is still recorded
    assert "not back before stop" in gap.reason


def test_bad_port_is_a_board_error_naming_it(tmp_path):
    missing = str(tmp_path / "ttyACM9")
    with pytest.raises(BoardError, match="ttyACM9"):
        Recorder(missing).start()
    assert not any(t.name.startswith("muca-recorder") for t in threading.enumerate())


def test_no_frame_is_a_timeout_naming_the_port():
    with Recorder("loop://") as rec:
        rec.send(b"\r\n1,2,3\r\n")
        with pytest.raises(BoardTimeout, match=r"loop://.*field_count=1"):
            rec.wait_for_frame(0.3)


def test_faults_are_dropped_and_counted_and_frames_stay_intact(sim):
    got = Collector()
    rec = Recorder(sim.path)
    rec.subscribe(got)
    with rec:
        rec.wait_for_frame(3.0)
        for kind in ("log", "i2c", "truncated", "garbage"):
            sim.inject(kind)
            time.sleep(0.05)
        rec.send(b"g:12\n")
        assert wait_until(lambda: sim.gain == 12 and sim.faults_injected == 4)
        assert wait_until(lambda: "[Muca] Gain set to 12" in rec.stats().log_lines)
        n = len(got.frames)
        assert wait_until(lambda: len(got.frames) >= n + 10)
        stats = rec.stats()
    assert stats.drops[LOG_LINE] >= 3
    assert stats.drops.get("field_count", 0) + stats.drops.get("non_numeric", 0) >= 2
    s = stamps(got.frames)
    assert s == sorted(set(s))  # no frame is invented, mixed or repeated
    # Each fault costs at most the frame it ran into.
    assert s[-1] - s[0] + 1 - len(s) <= 2


def test_short_soak_loses_no_frame(sim):
    got = Collector()
    rec = Recorder(sim.path)
    rec.subscribe(got)
    with rec:
        rec.wait_for_frame(3.0)
        time.sleep(4.0)
    s = np.array(stamps(got.frames))
    assert len(s) >= 300
    assert np.all(np.diff(s) == 1), "the board's frame numbers must arrive without a hole"
    assert rec.stats().drops == {"partial_start": 1}


def test_recorder_survives_a_failing_subscriber(sim):
    def broken(event):
        raise RuntimeError("boom")

    got = Collector()
    rec = Recorder(sim.path)
    rec.subscribe(broken)
    rec.subscribe(got)
    with rec:
        assert wait_until(lambda: len(got.frames) >= 5)
    assert rec.stats().subscriber_errors >= 5


def test_sim_board_releases_its_pty_and_link(patch_b):
    fds = open_fds()
    board = SimBoard(patch_b, rate_hz=50, baud=None).start()
    path = board.path
    port = serial.serial_for_url(path, timeout=0.5)
    try:
        assert port.read(2000)  # a real device path with data behind it
    finally:
        port.close()
    board.stop()
    assert not os.path.lexists(path)
    assert open_fds() <= fds


def test_silent_device_replaced_under_its_path_is_reopened(sim, patch_b):
    """A hung board that the OS replaces under the same path (udev re-creating the by-id
    link for a re-enumerated device) gives no read error, only silence: the recorder
    notices the path now names another device and reopens it."""
    got = Collector()
    rec = Recorder(sim.path, stall_check_s=0.2, backoff_s=(0.02, 0.2))
    rec.subscribe(got)
    with rec:
        rec.wait_for_frame(3.0)
        sim.hung = True
        time.sleep(0.5)
        assert rec.connected and not rec.stats().gaps  # silence alone is not an unplug
        with SimBoard(patch_b, rate_hz=100, baud=None, seed=5, link_path=sim.path) as other:
            assert wait_until(lambda: rec.stats().reconnects == 1, 3.0)
            n = len(got.frames)
            assert wait_until(lambda: len(got.frames) >= n + 10, 3.0)
            assert "vanished" in rec.stats().gaps[0].reason
            assert other.frames_written > 0
            rec.stop()


def test_frames_trickling_in_usb_packets_arrive_whole(patch_b):
    """With baud pacing the board sends each line in 64-byte packets, so the recorder
    reads partial lines all the time; every frame must still arrive, intact and in order."""
    got = Collector()
    with SimBoard(patch_b, rate_hz=100, baud=2_000_000, stamp_seq=True, seed=3) as board:
        rec = Recorder(board.path, baudrate=2_000_000)
        rec.subscribe(got)
        with rec:
            rec.wait_for_frame(3.0)
            assert wait_until(lambda: len(got.frames) >= 60, 5.0)
    s = stamps(got.frames)
    assert s == list(range(s[0], s[0] + len(s)))
    assert rec.stats().drops == {"partial_start": 1}


def test_reversed_tx_and_empty_fields_end_to_end(patch_b):
    """A board on newer firmware (TX reversed) printing zeros as empty fields: with the
    matching patch option the pressed sensor is found; without it, it is not."""
    import dataclasses

    reversed_patch = dataclasses.replace(
        patch_b, wiring=dataclasses.replace(patch_b.wiring, reverse_tx=True)
    )
    got = Collector()
    with SimBoard(reversed_patch, rate_hz=100, baud=None, empty_zero=True, seed=4) as board:
        target = patch_b.sensor("S7")
        board.probe_state.set(target.x_mm, target.y_mm, 2.0)
        rec = Recorder(board.path)
        rec.subscribe(got)
        with rec:
            assert wait_until(lambda: len(got.frames) >= 20)
        zero_cells = board._background == 0
    frames = got.frames
    assert zero_cells.any()
    assert all((f.cells[zero_cells] == 0).all() for f in frames)  # empty fields became 0
    expected = board.scene.response(target.x_mm, target.y_mm, 2.0, board.probe)
    right = np.mean([CellMap.from_patch(reversed_patch).values(f) for f in frames], axis=0)
    np.testing.assert_allclose(right - board.scene.rest, expected, atol=8)
    wrong = np.mean([CellMap.from_patch(patch_b).values(f) for f in frames], axis=0)
    assert np.abs(wrong - board.scene.rest - expected).max() > 500  # other cells entirely

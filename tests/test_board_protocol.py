"""The Muca ASCII parser: tables of bytes in, frames and drop reasons out."""

from __future__ import annotations

import numpy as np
import pytest

from varskin.board.frame import N_CELLS, N_RX, N_TX
from varskin.board.protocol import (
    BLANK,
    FIELD_COUNT,
    LOG_LINE,
    MAX_LINE,
    NON_NUMERIC,
    OUT_OF_RANGE,
    OVERLONG,
    PARTIAL_START,
    AsciiFrameParser,
    format_frame,
)


def grid(base: int = 0) -> np.ndarray:
    """Every cell distinct, so a value in the wrong cell cannot go unnoticed."""
    return (np.arange(N_CELLS, dtype=np.int64) * 7 + 100 + base).reshape(N_TX, N_RX)


def line(values, sep: str = ",", end: str = "\r\n") -> bytes:
    return (sep.join(str(v) for v in values) + end).encode()


GOOD = format_frame(grid())
GOOD2 = format_frame(grid(1))
ZERO_HOLES = grid()
ZERO_HOLES[0, 0] = ZERO_HOLES[5, 7] = ZERO_HOLES[-1, -1] = 0
EMPTY_FIELDS = format_frame(ZERO_HOLES, empty_zero=True)
ALL_EMPTY = format_frame(np.zeros((N_TX, N_RX), int), empty_zero=True)
VALUES = grid().reshape(-1).tolist()

# (name, stream after a clean line start, expected frames as grids, expected drop counts)
CASES = [
    ("one frame", GOOD, [grid()], {}),
    ("two frames", GOOD + GOOD2, [grid(), grid(1)], {}),
    ("LF only", GOOD.replace(b"\r\n", b"\n"), [grid()], {}),
    ("empty fields mean 0", EMPTY_FIELDS, [ZERO_HOLES], {}),
    ("all empty", ALL_EMPTY, [np.zeros((N_TX, N_RX))], {}),
    ("max value", line([65535] * N_CELLS), [np.full((N_TX, N_RX), 65535)], {}),
    ("log line", b"[Muca] Set TEST mode\r\n" + GOOD, [grid()], {LOG_LINE: 1}),
    ("gain log", GOOD + b"[Muca] Gain set to 8\r\n" + GOOD2, [grid(), grid(1)], {LOG_LINE: 1}),
    ("i2c failure", b"[Muca] i2c write failed\r\n" + GOOD, [grid()], {LOG_LINE: 1}),
    ("blank line", b"\r\n" + GOOD, [grid()], {BLANK: 1}),
    ("too few fields", line(VALUES[:-1]) + GOOD, [grid()], {FIELD_COUNT: 1}),
    ("too many fields", line(VALUES + [5]) + GOOD, [grid()], {FIELD_COUNT: 1}),
    ("trailing comma", line(VALUES, end=",\r\n") + GOOD, [grid()], {FIELD_COUNT: 1}),
    ("truncated line", GOOD[:700] + b"\r\n" + GOOD2, [grid(1)], {FIELD_COUNT: 1}),
    # A reset mid-line: half a frame runs straight into the next one.
    ("merged lines", GOOD[:700] + GOOD2, [], {FIELD_COUNT: 1}),
    ("letters", line(VALUES[:10] + ["1a"] + VALUES[11:]) + GOOD, [grid()], {NON_NUMERIC: 1}),
    ("negative", line(VALUES[:3] + [-5] + VALUES[4:]) + GOOD, [grid()], {NON_NUMERIC: 1}),
    ("spaces", line(VALUES, sep=", ") + GOOD, [grid()], {NON_NUMERIC: 1}),
    ("underscore digits", line(["1_000"] + VALUES[1:]) + GOOD, [grid()], {NON_NUMERIC: 1}),
    ("float", line(["1.5"] + VALUES[1:]) + GOOD, [grid()], {NON_NUMERIC: 1}),
    ("binary garbage", b"\x00\xff\x13\x80garbage" + GOOD, [], {NON_NUMERIC: 1}),
    ("garbage line", b"\x00\xff\x13\x80\r\n" + GOOD, [grid()], {NON_NUMERIC: 1}),
    ("65536", line(VALUES[:-1] + [65536]) + GOOD, [grid()], {OUT_OF_RANGE: 1}),
    ("huge", line([10**30] + VALUES[1:]) + GOOD, [grid()], {OUT_OF_RANGE: 1}),
    ("no newline for long", b"1," * MAX_LINE + b"\r\n" + GOOD, [grid()], {OVERLONG: 1}),
    ("incomplete tail", GOOD + GOOD2[:-2], [grid()], {}),
]


def run(stream: bytes, chunks, synced: bool = True):
    p = AsciiFrameParser(synced=synced)
    frames = []
    pos = 0
    for n in chunks:
        frames += p.feed(stream[pos : pos + n], t=float(pos))
        pos += n
    frames += p.feed(stream[pos:], t=float(pos))
    return frames, dict(p.drops)


@pytest.mark.parametrize(("name", "stream", "expected", "drops"), CASES, ids=[c[0] for c in CASES])
def test_table(name, stream, expected, drops):
    frames, got_drops = run(stream, [])
    assert [f.cells.tolist() for f in frames] == [np.asarray(e).tolist() for e in expected]
    assert got_drops == drops
    assert [f.seq for f in frames] == list(range(len(expected)))
    for f in frames:
        assert f.cells.dtype == np.uint16 and f.cells.shape == (N_TX, N_RX)


@pytest.mark.parametrize(("name", "stream", "expected", "drops"), CASES, ids=[c[0] for c in CASES])
def test_chunking_does_not_matter(name, stream, expected, drops):
    whole, whole_drops = run(stream, [])
    bytewise, byte_drops = run(stream, [1] * len(stream))
    rng = np.random.default_rng(len(stream))
    sizes = rng.integers(1, 300, len(stream)).tolist()
    random_chunks, random_drops = run(stream, sizes[: len(stream) // 2])
    for frames, drops_ in ((bytewise, byte_drops), (random_chunks, random_drops)):
        assert [f.cells.tolist() for f in frames] == [f.cells.tolist() for f in whole]
        assert drops_ == whole_drops


def test_first_line_is_dropped_after_start_and_resync():
    # Cut inside the first number: "12345,..." seen as "345,..." still has 252 fields.
    stream = GOOD[1:] + GOOD2
    p = AsciiFrameParser()
    frames = p.feed(stream, t=1.0)
    assert [f.cells.tolist() for f in frames] == [grid(1).tolist()]
    assert dict(p.drops) == {PARTIAL_START: 1}
    # After a reconnect the stream restarts anywhere again.
    p.feed(GOOD[:300], t=2.0)
    p.resync()
    frames = p.feed(GOOD[900:] + GOOD, t=3.0)
    assert [f.cells.tolist() for f in frames] == [grid().tolist()]
    assert p.drops[PARTIAL_START] == 2
    assert [f.seq for f in frames] == [1]  # numbering continues across reconnects


def test_timestamp_is_when_the_line_completed():
    p = AsciiFrameParser(synced=True)
    assert p.feed(GOOD[:-1], t=10.0) == []
    (frame,) = p.feed(GOOD[-1:] + GOOD2[:5], t=11.5)
    assert frame.t == 11.5


def test_no_unbounded_growth_without_newline():
    p = AsciiFrameParser(synced=True)
    for _ in range(2000):
        assert p.feed(b"1234," * 200, t=0.0) == []
    assert len(p._buf) <= p.max_line
    frames = p.feed(b"\r\n" + GOOD, t=1.0)
    assert len(frames) == 1 and dict(p.drops) == {OVERLONG: 1}


def test_fuzzed_stream_never_shifts_a_value():
    """Random corruption of a stream of distinct frames: every accepted frame is exactly one
    of the frames sent, never a mixture or a shifted copy."""
    rng = np.random.default_rng(7)
    sent = [grid(1000 * k) for k in range(40)]
    pieces = []
    for g in sent:
        data = bytearray(format_frame(g, empty_zero=bool(rng.integers(2))))
        r = rng.random()
        if r < 0.15:
            data = data[: rng.integers(1, len(data))]  # truncated, runs into the next
        elif r < 0.3:
            data[rng.integers(len(data))] = int(rng.integers(256))  # one corrupted byte
        elif r < 0.4:
            data = b"[Muca] i2c write failed\r\n" + data
        pieces.append(bytes(data))
    stream = b"".join(pieces)
    p = AsciiFrameParser(synced=True)
    frames = []
    pos = 0
    while pos < len(stream):
        n = int(rng.integers(1, 2000))
        frames += p.feed(stream[pos : pos + n], t=0.0)
        pos += n
    sent_lists = [g.tolist() for g in sent]
    assert frames, "some frames should survive"
    for f in frames:
        # A corrupted digit that stays a digit changes a value in place (no checksum can
        # catch that); it must never move values: all other cells equal one sent frame.
        matches = [s for s in sent_lists if (np.array(s) != f.cells).sum() <= 1]
        assert len(matches) == 1
    assert sum(p.drops.values()) + len(frames) >= len(sent) - 1


def test_never_crashes_on_random_bytes():
    rng = np.random.default_rng(3)
    p = AsciiFrameParser()
    for _ in range(200):
        p.feed(bytes(rng.integers(0, 256, int(rng.integers(1, 3000)), dtype=np.uint8)), t=0.0)
    p.feed(b"\n" + GOOD, t=0.0)  # and still recovers
    assert p.seq >= 1

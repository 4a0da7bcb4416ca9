"""Streaming parser for the Muca's ASCII frames, robust to everything a serial line does.

The raw firmware prints 252 comma-separated unsigned 16-bit decimals (TX-major) and CRLF,
with no header, counter or checksum. Some sketches print a value only when it is > 0, so
an empty field means 0. The same line also carries the library's log messages
(``[Muca] ...``), and a reset, an I2C fault or an unplug leaves partial lines and garbage.

Because nothing in the format marks where a frame starts, the only safe unit is a whole
line: a line is accepted only if it is exactly 252 fields of decimal digits, each <= 65535.
Anything else is dropped as a whole and counted by reason, so a value can never slide into
a neighbouring cell. The first line after (re)start is always dropped: it may have lost its
beginning, and a cut inside the first number would still give 252 plausible fields.

The 254-byte binary variant (min as two bytes, then 252 uint8 deltas) is deliberately not
parsed: it has no sync marker, so the frame phase could only be guessed from statistics,
and that guess is ambiguous when deltas saturate at 255 - a wrong guess would shift every
value. Use the ASCII firmware.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from varskin.board.frame import N_CELLS, N_RX, N_TX, Frame

ADC_MAX = 65535
# A real frame is at most 252 * 6 bytes; anything much longer never had its newline.
MAX_LINE = 4 * N_CELLS * 6
LOG_PREFIX = b"[Muca]"
_DIGITS_AND_COMMAS = b"0123456789,"

# Reasons a line is not a frame; the recorder reports counts under these names.
PARTIAL_START = "partial_start"  # first line after start or reconnect
LOG_LINE = "log_line"  # "[Muca] ..." message (not a fault, but not a frame either)
BLANK = "blank"
FIELD_COUNT = "field_count"  # wrong number of fields (truncated or merged lines)
NON_NUMERIC = "non_numeric"  # anything but digits and commas
OUT_OF_RANGE = "out_of_range"  # a value above 65535
OVERLONG = "overlong"  # no newline within MAX_LINE bytes
REASONS = (PARTIAL_START, LOG_LINE, BLANK, FIELD_COUNT, NON_NUMERIC, OUT_OF_RANGE, OVERLONG)


class AsciiFrameParser:
    """Feed it bytes in any chunking; it returns the complete, valid frames.

    The result does not depend on how the stream is cut into chunks: feeding byte by byte
    gives the same frames and the same drop counts as feeding everything at once.
    """

    def __init__(self, synced: bool = False, max_line: int = MAX_LINE, first_seq: int = 0):
        self.max_line = max_line
        self.drops: Counter[str] = Counter()
        self.log_lines: list[str] = []  # the most recent log messages, for the user
        self.seq = first_seq
        self._buf = bytearray()
        self._at_line_start = synced
        self._overflowed = False  # current line already exceeded max_line and was discarded

    def resync(self) -> None:
        """Forget the partial line: call after a reconnect (the stream restarts anywhere)."""
        self._buf.clear()
        self._at_line_start = False
        self._overflowed = False

    def feed(self, data: bytes, t: float) -> list[Frame]:
        """Parse a chunk received at host time ``t``; frames completed in it get that time."""
        frames: list[Frame] = []
        if b"\n" not in data:
            self._append(data)
            return frames
        *complete, rest = data.split(b"\n")
        for i, piece in enumerate(complete):
            if i == 0:
                if self._overflowed:
                    line = None
                else:
                    self._buf += piece
                    line = bytes(self._buf)
                self._buf.clear()
            else:
                line = piece
            frame = self._line(line, t)
            if frame is not None:
                frames.append(frame)
        self._append(rest)
        return frames

    def _append(self, data: bytes) -> None:
        if self._overflowed:
            return
        self._buf += data
        if len(self._buf) > self.max_line:
            self._buf.clear()
            self._overflowed = True

    def _line(self, line: bytes | None, t: float) -> Frame | None:
        """Judge one completed line (``None``: it overflowed and was discarded)."""
        overflowed, self._overflowed = self._overflowed, False
        if not self._at_line_start:
            self._at_line_start = True
            self.drops[PARTIAL_START] += 1
            return None
        if overflowed or line is None or len(line) > self.max_line:
            self.drops[OVERLONG] += 1
            return None
        if line.endswith(b"\r"):
            line = line[:-1]
        if not line:
            self.drops[BLANK] += 1
            return None
        if line.translate(None, _DIGITS_AND_COMMAS):
            if line.startswith(LOG_PREFIX):
                self.drops[LOG_LINE] += 1
                self.log_lines = [*self.log_lines[-19:], line.decode("ascii", "replace")]
            else:
                self.drops[NON_NUMERIC] += 1
            return None
        if line.count(b",") != N_CELLS - 1:
            self.drops[FIELD_COUNT] += 1
            return None
        # Empty fields mean 0. Filling them in keeps every value at its position; two passes
        # because ",,," overlaps.
        if b",," in line:
            line = line.replace(b",,", b",0,").replace(b",,", b",0,")
        if line[0] == 44:  # ord(",")
            line = b"0" + line
        if line[-1] == 44:
            line += b"0"
        values = list(map(int, line.split(b",")))
        if max(values) > ADC_MAX:
            self.drops[OUT_OF_RANGE] += 1
            return None
        cells = np.array(values, dtype=np.uint16).reshape(N_TX, N_RX)
        frame = Frame(self.seq, t, cells)
        self.seq += 1
        return frame


def format_frame(cells: np.ndarray, empty_zero: bool = False) -> bytes:
    """The bytes the raw firmware prints for one frame (the sim board and tests use it)."""
    values = np.asarray(cells).reshape(-1).tolist()
    if empty_zero:
        text = ",".join(str(v) if v > 0 else "" for v in values)
    else:
        text = ",".join(map(str, values))
    return text.encode("ascii") + b"\r\n"

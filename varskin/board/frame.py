"""What the recorder hands on: one Muca frame, or the record of a gap in the stream.

The Muca sends no header, counter or checksum, so the only identity a frame has is the
order in which this host accepted it (``seq``) and the host's monotonic time when its
line completed (``t``). Both are assigned here, on the host, and nowhere else.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

N_TX = 21  # FT5316DME transmit lines
N_RX = 12  # receive lines
N_CELLS = N_TX * N_RX  # 252 values per frame, TX-major


@dataclass(frozen=True)
class Frame:
    seq: int  # 0, 1, 2 ... in order of acceptance by this host (survives reconnects)
    t: float  # host time.monotonic() when the frame's line completed, s
    cells: np.ndarray  # (21, 12) uint16 as sent: row i is the i-th group of 12 values


@dataclass(frozen=True)
class Gap:
    """The serial link was down between ``start`` and ``end`` (host monotonic, s)."""

    start: float
    end: float
    reason: str
    last_frame_t: float | None = None  # when the last frame before the gap arrived

    @property
    def duration_s(self) -> float:
        return self.end - self.start

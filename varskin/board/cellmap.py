"""Which board cell holds which patch sensor, from the patch config's ``board:`` section.

A patch wires only some of the Muca's 21 TX x 12 RX lines, in its own order, and the
library has changed the order in which it sends lines (TX reversed since late 2022, RX
before that). Keeping that knowledge here means frames stay exactly as the board sent
them and every consumer gets sensor vectors in the patch's sensor order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from varskin.board.frame import N_RX, N_TX, Frame
from varskin.errors import ConfigError
from varskin.patch import Patch


@dataclass(frozen=True)
class CellMap:
    names: tuple[str, ...]  # patch sensor order
    rows: np.ndarray  # (N,) frame row (position in the sent TX order) of each sensor
    cols: np.ndarray  # (N,) frame column of each sensor
    sign: float  # -1 where a touch lowers the value, so touches are always positive

    @classmethod
    def from_patch(cls, patch: Patch) -> CellMap:
        w = patch.wiring
        for key, lines, n in (("tx_lines", w.tx_lines, N_TX), ("rx_lines", w.rx_lines, N_RX)):
            bad = [line for line in lines if not 0 <= line < n]
            if bad:
                raise ConfigError(
                    f"{patch.source or patch.name}: board.{key} {bad} outside the Muca's 0..{n - 1}"
                )
        tx_line = np.array([w.tx_lines[s.tx] for s in patch.sensors])
        rx_line = np.array([w.rx_lines[s.rx] for s in patch.sensors])
        rows = (N_TX - 1 - tx_line) if w.reverse_tx else tx_line
        cols = (N_RX - 1 - rx_line) if w.reverse_rx else rx_line
        return cls(tuple(patch.names), rows, cols, -1.0 if w.inverted else 1.0)

    @property
    def cells(self) -> list[tuple[int, int]]:
        """(row, col) in the frame for each sensor."""
        return list(zip(self.rows.tolist(), self.cols.tolist(), strict=True))

    def raw(self, frame: Frame | np.ndarray) -> np.ndarray:
        """(N,) counts as sent, in patch sensor order."""
        cells = frame.cells if isinstance(frame, Frame) else frame
        return cells[self.rows, self.cols]

    def values(self, frame: Frame | np.ndarray) -> np.ndarray:
        """(N,) float counts with the bench's sign applied: a touch always raises them."""
        return self.sign * self.raw(frame).astype(np.float64)

    def place(self, sensor_values: np.ndarray, cells: np.ndarray) -> None:
        """Write per-sensor counts into a (21, 12) frame grid (the simulated board's side)."""
        cells[self.rows, self.cols] = sensor_values

    def used_mask(self) -> np.ndarray:
        mask = np.zeros((N_TX, N_RX), bool)
        mask[self.rows, self.cols] = True
        return mask

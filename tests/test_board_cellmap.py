"""Board cells to patch sensors: line selection, order, reversed TX/RX and the sign."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from varskin.board.cellmap import CellMap
from varskin.board.frame import N_RX, N_TX, Frame
from varskin.errors import ConfigError


def coded_frame() -> Frame:
    """Cell (row, col) holds 100*row + col, so a value names the cell it came from."""
    rows, cols = np.mgrid[0:N_TX, 0:N_RX]
    return Frame(0, 0.0, (100 * rows + cols).astype(np.uint16))


def rewire(patch, **changes):
    return dataclasses.replace(patch, wiring=dataclasses.replace(patch.wiring, **changes))


def test_patch_b_reads_the_first_10_tx_and_3_rx(patch_b):
    cm = CellMap.from_patch(patch_b)
    raw = cm.raw(coded_frame())
    assert cm.names == tuple(f"S{i}" for i in range(1, 31))
    # S1..S30: TX wire i, RX wire j, y fastest.
    assert raw.tolist() == [100 * i + j for i in range(10) for j in range(3)]
    assert cm.used_mask().sum() == 30


def test_patch_a_reads_11_tx_and_2_rx(patch_a):
    raw = CellMap.from_patch(patch_a).raw(coded_frame())
    assert raw.tolist() == [100 * i + j for i in range(11) for j in range(2)]


def test_custom_lines_and_order(patch_b):
    patch = rewire(patch_b, tx_lines=tuple(range(19, 9, -1)), rx_lines=(11, 4, 0))
    raw = CellMap.from_patch(patch).raw(coded_frame())
    assert raw[0] == 100 * 19 + 11  # S1: TX wire 0 on line 19, RX wire 0 on line 11
    assert raw[1] == 100 * 19 + 4
    assert raw[-1] == 100 * 10 + 0  # S30: TX wire 9 on line 10, RX wire 2 on line 0


def test_reversed_tx_reads_rows_from_the_end(patch_b):
    raw = CellMap.from_patch(rewire(patch_b, reverse_tx=True)).raw(coded_frame())
    # TX line 0 is sent last (row 20), line 9 is row 11.
    assert raw.tolist() == [100 * (20 - i) + j for i in range(10) for j in range(3)]


def test_reversed_rx(patch_b):
    raw = CellMap.from_patch(rewire(patch_b, reverse_rx=True)).raw(coded_frame())
    assert raw[:3].tolist() == [11, 10, 9]


def test_inverted_sign_makes_touches_positive(patch_b):
    frame = coded_frame()
    normal = CellMap.from_patch(patch_b)
    inverted = CellMap.from_patch(rewire(patch_b, inverted=True))
    np.testing.assert_array_equal(inverted.values(frame), -normal.values(frame))
    assert inverted.raw(frame).tolist() == normal.raw(frame).tolist()  # raw stays as sent


def test_place_is_the_inverse_of_raw(patch_b):
    cm = CellMap.from_patch(rewire(patch_b, reverse_tx=True))
    cells = np.zeros((N_TX, N_RX), np.uint16)
    values = np.arange(1, 31)
    cm.place(values, cells)
    assert cm.raw(cells).tolist() == values.tolist()


def test_line_outside_the_board_is_a_config_error(patch_b):
    with pytest.raises(ConfigError, match="tx_lines"):
        CellMap.from_patch(rewire(patch_b, tx_lines=(0, 1, 2, 3, 4, 5, 6, 7, 8, 21)))

"""Reading the Muca board: the serial protocol, the cell map, a threaded recorder, and a
simulated board behind a pseudo-terminal for tests and demos."""

from varskin.board.cellmap import CellMap
from varskin.board.csvsink import FrameCsvSink
from varskin.board.frame import N_CELLS, N_RX, N_TX, Frame, Gap
from varskin.board.protocol import AsciiFrameParser, format_frame
from varskin.board.recorder import Recorder, RecorderStats
from varskin.board.simboard import SimBoard

__all__ = [
    "N_CELLS",
    "N_RX",
    "N_TX",
    "AsciiFrameParser",
    "CellMap",
    "Frame",
    "FrameCsvSink",
    "Gap",
    "Recorder",
    "RecorderStats",
    "SimBoard",
    "format_frame",
]

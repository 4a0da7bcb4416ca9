"""The patch model: a skin's outline and its sensors, in millimetres in the patch frame.

The patch frame has its origin at a patch corner, x along the length and y across. A sensor
is the crossing of one TX and one RX wire; its design position is where those wires cross
on the drawing. The real (hidden) position differs, which is what calibration measures.
Patch configs are YAML files in ``configs/``; ``load_patch`` validates them and names the
file and key of any mistake.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from varskin.errors import ConfigError
from varskin.yaml_file import read_yaml


@dataclass(frozen=True)
class Sensor:
    name: str
    tx: int  # index into the patch's TX wires (0-based, patch order)
    rx: int  # index into the patch's RX wires
    x_mm: float  # design position
    y_mm: float


@dataclass(frozen=True)
class BoardWiring:
    """Which Muca lines the patch's wires are soldered to, in patch wire order."""

    tx_lines: tuple[int, ...]
    rx_lines: tuple[int, ...]
    reverse_tx: bool = False  # Muca library versions since late 2022 send TX in reverse order
    reverse_rx: bool = False
    inverted: bool = False  # True where a touch lowers the value on this bench


@dataclass(frozen=True)
class Patch:
    name: str
    length_mm: float
    width_mm: float
    tx_x_mm: tuple[float, ...]
    rx_y_mm: tuple[float, ...]
    sensors: tuple[Sensor, ...]
    wiring: BoardWiring
    source: str = field(default="", compare=False)

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.sensors]

    @property
    def design_xy(self) -> np.ndarray:
        """(N, 2) design positions in mm, in sensor order."""
        return np.array([[s.x_mm, s.y_mm] for s in self.sensors], dtype=float)

    def sensor(self, name: str) -> Sensor:
        for s in self.sensors:
            if s.name == name:
                return s
        raise KeyError(name)


def _err(path: str, msg: str) -> ConfigError:
    return ConfigError(f"{path}: {msg}")


def _floats(path: str, key: str, value: object) -> tuple[float, ...]:
    if not isinstance(value, list) or not value:
        raise _err(path, f"'{key}' must be a non-empty list of numbers")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise _err(path, f"'{key}[{i}]' is {v!r}, not a finite number")
        out.append(float(v))
    return tuple(out)


def _ints(path: str, key: str, value: object, n: int) -> tuple[int, ...]:
    if not isinstance(value, list) or len(value) != n:
        raise _err(path, f"'{key}' must list {n} line numbers")
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise _err(path, f"'{key}[{i}]' is {v!r}, not a line number >= 0")
    if len(set(value)) != n:
        raise _err(path, f"'{key}' repeats a line number")
    return tuple(value)


def patch_from_dict(data: object, source: str = "<patch>") -> Patch:
    """Build and validate a patch from the parsed YAML mapping."""
    if not isinstance(data, dict):
        raise _err(source, "a patch config must be a YAML mapping")
    for key in ("name", "size_mm", "tx_x_mm", "rx_y_mm"):
        if key not in data:
            raise _err(source, f"missing key '{key}'")
    size = _floats(source, "size_mm", data["size_mm"])
    if len(size) != 2 or min(size) <= 0:
        raise _err(source, "'size_mm' must be [length, width] with both > 0")
    tx_x = _floats(source, "tx_x_mm", data["tx_x_mm"])
    rx_y = _floats(source, "rx_y_mm", data["rx_y_mm"])

    raw_sensors = data.get("sensors")
    if raw_sensors is None:
        # Default naming: S1, S2, ... TX-major with y varying fastest, as in the paper.
        raw_sensors = [
            {"name": f"S{i * len(rx_y) + j + 1}", "tx": i, "rx": j}
            for i in range(len(tx_x))
            for j in range(len(rx_y))
        ]
    if not isinstance(raw_sensors, list) or not raw_sensors:
        raise _err(source, "'sensors' must be a non-empty list")
    sensors = []
    seen: set[str] = set()
    for i, s in enumerate(raw_sensors):
        where = f"sensors[{i}]"
        if not isinstance(s, dict) or not {"name", "tx", "rx"} <= s.keys():
            raise _err(source, f"'{where}' needs name, tx and rx")
        name = str(s["name"])
        if not name or name in seen or name in ("touch", "x_mm", "y_mm", "t_s", "force_n"):
            raise _err(source, f"'{where}.name' {name!r} is empty, reserved or repeated")
        seen.add(name)
        tx, rx = s["tx"], s["rx"]
        if not isinstance(tx, int) or not 0 <= tx < len(tx_x):
            raise _err(source, f"'{where}.tx' is {tx!r}, not in 0..{len(tx_x) - 1}")
        if not isinstance(rx, int) or not 0 <= rx < len(rx_y):
            raise _err(source, f"'{where}.rx' is {rx!r}, not in 0..{len(rx_y) - 1}")
        sensors.append(Sensor(name, tx, rx, tx_x[tx], rx_y[rx]))

    board = data.get("board") or {}
    if not isinstance(board, dict):
        raise _err(source, "'board' must be a mapping")
    wiring = BoardWiring(
        tx_lines=_ints(
            source, "board.tx_lines", board.get("tx_lines", list(range(len(tx_x)))), len(tx_x)
        ),
        rx_lines=_ints(
            source, "board.rx_lines", board.get("rx_lines", list(range(len(rx_y)))), len(rx_y)
        ),
        reverse_tx=bool(board.get("reverse_tx", False)),
        reverse_rx=bool(board.get("reverse_rx", False)),
        inverted=bool(board.get("inverted", False)),
    )
    return Patch(
        name=str(data["name"]),
        length_mm=size[0],
        width_mm=size[1],
        tx_x_mm=tx_x,
        rx_y_mm=rx_y,
        sensors=tuple(sensors),
        wiring=wiring,
        source=source,
    )


def load_patch(path: str | Path) -> Patch:
    """Read a patch YAML; every mistake is a ``ConfigError`` naming the file."""
    path = Path(path)
    data = read_yaml(path, "a patch config")
    return patch_from_dict(data, str(path))


def builtin_patch(name: str) -> Patch:
    """The published patches shipped in ``configs/`` (``patch_a`` or ``patch_b``)."""
    return load_patch(config_dir() / f"{name}.yaml")


def config_dir() -> Path:
    """The repository's ``configs/`` folder (the package is used from a checkout)."""
    return Path(__file__).resolve().parent.parent / "configs"


def resolve_patch(spec: str | Path) -> Patch:
    """A patch YAML path, or the name of a patch shipped in ``configs/`` (``patch_b``)."""
    path = Path(spec)
    if path.suffix in (".yaml", ".yml") or path.exists():
        return load_patch(path)
    if (config_dir() / f"{spec}.yaml").exists():
        return builtin_patch(str(spec))
    names = sorted(p.stem for p in config_dir().glob("patch_*.yaml"))
    raise ConfigError(f"{spec}: no such patch file or builtin patch (builtin: {', '.join(names)})")

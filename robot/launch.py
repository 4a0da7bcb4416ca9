"""Launch files: one YAML describing a rig (robot, board, patch, registration, touch, limits).

Everything a session needs before it talks to hardware is read and checked here, so a typo
or an unsafe number is reported as one line naming the file and the key BEFORE anything
connects or moves. Loading also resolves the registration into a ``PatchFrame`` and builds
the safety ``Envelope`` around it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from robot.arm import TouchSpec
from robot.patch_frame import PatchFrame
from robot.registration import MarkerLayout, register_from_aruco, register_three_points
from robot.safety import Envelope
from varskin.errors import ConfigError, RegistrationError
from varskin.patch import Patch, load_patch
from varskin.yaml_file import read_yaml

TOP_LEVEL_KEYS = {
    "simulated",
    "robot",
    "board",
    "patch",
    "registration",
    "touch",
    "envelope",
    "plan",
    "sim",
}


@dataclass(frozen=True)
class RobotConfig:
    host: str  # controller IP (ignored for a simulated rig, which listens on loopback)
    tcp_offset: tuple[float, ...]  # [x, y, z, rx, ry, rz] flange -> probe tip, m and rad
    payload_kg: float
    payload_cog_m: tuple[float, float, float]
    call_timeout_s: float = 5.0  # supervision timeout of every controller call

    def arm_options(self) -> dict:
        """The ``URArm`` keyword arguments this config sets (TCP, payload, timeout)."""
        return {
            "call_timeout_s": self.call_timeout_s,
            "tcp_offset": self.tcp_offset,
            "payload": (self.payload_kg, self.payload_cog_m),
        }


@dataclass(frozen=True)
class BoardConfig:
    port: str | None  # serial device; None on a simulated rig (a pty is made for it)
    baud: int = 115200


@dataclass(frozen=True)
class PlanConfig:
    nx: int  # touches along the patch length (x)
    ny: int  # touches across (y)
    margin_mm: float  # keep-out band inside the outline
    mode: str = "uniform"  # "uniform" (the nx x ny grid) or "adaptive"
    budget: int = 100  # adaptive: most touches in all
    target_sigma_mm: float | None = None  # adaptive: stop when every sigma is below (None: default)
    order: str = "auto"  # uniform: "sweep", "shuffled" or "auto" (varskin.planning.touch_order)

    def points_mm(self, patch: Patch) -> np.ndarray:
        """(nx*ny, 2) uniform grid in the patch frame, in the order the plan touches it."""
        from varskin.planning import in_order, touch_order, uniform_points

        points = uniform_points(patch, self.nx, self.ny, self.margin_mm)
        return in_order(points, touch_order(patch, self.order))


@dataclass(frozen=True)
class SimConfig:
    """The simulated rig's hidden truth (only with ``simulated: true``)."""

    seed: int = 0
    stiffness_n_per_mm: float = 3.0
    force_offset_n: float = 0.8
    force_noise_sd_n: float = 0.05
    registration_error_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)  # true patch - registered
    # simulated seconds per wall second of the simulated controller (and board): > 1 runs a
    # long plan in CI time; see LaunchConfig.arm_touch_spec for what it does to the touch
    time_scale: float = 1.0


@dataclass(frozen=True)
class LaunchConfig:
    source: str
    simulated: bool
    robot: RobotConfig
    board: BoardConfig
    patch: Patch
    registration_method: str  # "frame", "three_point" or "aruco"
    frame: PatchFrame  # the registered patch frame in the base frame
    touch: TouchSpec
    envelope: Envelope
    plan: PlanConfig
    sim: SimConfig = field(default_factory=SimConfig)

    def plan_points_m(self) -> np.ndarray:
        """The plan's surface points in the base frame (K, 3)."""
        return self.frame.to_base(self.plan.points_mm(self.patch))

    def arm_touch_spec(self) -> TouchSpec:
        """The touch spec to hand the arm driver: ``touch`` with its host-clock durations
        (``dwell_s``, ``settle_s``) divided by ``sim.time_scale``.

        The driver times the settle and the dwell on the host clock, while a time-scaled
        simulated controller runs ``time_scale`` simulated seconds per wall second; dividing
        makes the robot hold the force for ``touch.dwell_s`` *simulated* seconds, as it would
        on a real rig. Speeds are not changed: the controller already runs them faster. For
        a real rig (time scale 1) this is ``touch`` itself.
        """
        scale = self.sim.time_scale
        if scale == 1.0:
            return self.touch
        return replace(
            self.touch, dwell_s=self.touch.dwell_s / scale, settle_s=self.touch.settle_s / scale
        )

    def true_frame(self) -> PatchFrame:
        """Where a simulated rig really puts the skin: the registration plus its error."""
        err = np.asarray(self.sim.registration_error_mm, float)
        shift = self.frame.to_base(err[:2], err[2]) - self.frame.origin_m
        return PatchFrame(self.frame.rotation, self.frame.origin_m + shift)


# --- loading ----------------------------------------------------------------------------


def load_launch(path: str | Path) -> LaunchConfig:
    """Read and validate a launch YAML; any mistake is a ``ConfigError`` naming file and key."""
    path = Path(path)
    src = str(path)
    data = read_yaml(path, "a launch file")
    return launch_from_dict(data, src, base_dir=path.parent)


def launch_from_dict(
    data: object, source: str = "<launch>", base_dir: Path | None = None
) -> LaunchConfig:
    base_dir = base_dir or Path.cwd()
    c = _Checker(source)
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: a launch file must be a YAML mapping")
    c.known(data, TOP_LEVEL_KEYS, "")
    for key in ("simulated", "robot", "patch", "registration", "touch", "envelope", "plan"):
        c.require(data, key, "")
    simulated = data["simulated"]
    if not isinstance(simulated, bool):
        raise c.err("simulated", f"is {simulated!r}, not true or false")

    robot = _robot(c, data["robot"], simulated)
    board = _board(c, data.get("board") or {}, simulated)
    patch_path = data["patch"]
    if not isinstance(patch_path, str) or not patch_path:
        raise c.err("patch", "must be the path of a patch YAML")
    p = Path(patch_path)
    patch = load_patch(p if p.is_absolute() else base_dir / p)
    method, frame = _registration(c, data["registration"], base_dir, patch)
    touch = _touch(c, data["touch"])
    try:
        envelope = Envelope.from_config(data["envelope"], frame, patch, source, touch=touch)
    except ConfigError:
        raise
    except ValueError as e:
        raise c.err("envelope", str(e)) from None
    plan = _plan(c, data["plan"], patch)
    sim = _sim(c, data.get("sim") or {}) if simulated else SimConfig()
    if not simulated and data.get("sim"):
        raise c.err("sim", "is only allowed with 'simulated: true'")
    return LaunchConfig(
        source, simulated, robot, board, patch, method, frame, touch, envelope, plan, sim
    )


class _Checker:
    """Typed reads of YAML values with errors naming the file and the dotted key."""

    def __init__(self, source: str) -> None:
        self.source = source

    def err(self, key: str, msg: str) -> ConfigError:
        return ConfigError(f"{self.source}: '{key}' {msg}")

    def mapping(self, value: object, key: str) -> Mapping:
        if not isinstance(value, Mapping):
            raise self.err(key, "must be a mapping")
        return value

    def known(self, m: Mapping, keys: set[str], prefix: str) -> None:
        unknown = sorted(str(k) for k in set(m) - keys)
        if unknown:
            raise ConfigError(f"{self.source}: unknown key '{prefix}{unknown[0]}'")

    def require(self, m: Mapping, key: str, prefix: str) -> None:
        if key not in m:
            raise ConfigError(f"{self.source}: missing key '{prefix}{key}'")

    def number(
        self, value: object, key: str, low: float | None = None, strict: bool = False
    ) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
            raise self.err(key, f"is {value!r}, not a number")
        if low is not None and (value < low or (strict and value == low)):
            raise self.err(key, f"is {value!r}, must be {'>' if strict else '>='} {low:g}")
        return float(value)

    def integer(self, value: object, key: str, low: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise self.err(key, f"is {value!r}, not an integer >= {low}")
        return value

    def vector(self, value: object, key: str, n: int) -> np.ndarray:
        if not isinstance(value, list) or len(value) != n:
            raise self.err(key, f"must be a list of {n} numbers")
        return np.array([self.number(v, f"{key}[{i}]") for i, v in enumerate(value)])

    def matrix(self, value: object, key: str, rows: int, cols: int) -> np.ndarray:
        if not isinstance(value, list) or len(value) != rows:
            raise self.err(key, f"must be a {rows}x{cols} list of lists")
        return np.array([self.vector(r, f"{key}[{i}]", cols) for i, r in enumerate(value)])


def _robot(c: _Checker, value: object, simulated: bool) -> RobotConfig:
    m = c.mapping(value, "robot")
    c.known(m, {"host", "tcp_offset", "payload_kg", "payload_cog_m", "call_timeout_s"}, "robot.")
    for key in ("tcp_offset", "payload_kg", "payload_cog_m"):
        c.require(m, key, "robot.")
    host = m.get("host", "127.0.0.1")
    if not simulated and "host" not in m:
        c.require(m, "host", "robot.")
    if not isinstance(host, str) or not host.strip():
        raise c.err("robot.host", f"is {host!r}, not a host name or IP address")
    tcp = c.vector(m["tcp_offset"], "robot.tcp_offset", 6)
    if np.linalg.norm(tcp[:3]) > 0.5:
        raise c.err(
            "robot.tcp_offset", "puts the probe tip more than 0.5 m from the flange (units are m)"
        )
    payload = c.number(m["payload_kg"], "robot.payload_kg", 0.0)
    if payload > 5.0:
        raise c.err("robot.payload_kg", f"is {payload:g} kg, above a UR5e's 5 kg")
    cog = c.vector(m["payload_cog_m"], "robot.payload_cog_m", 3)
    timeout = c.number(m.get("call_timeout_s", 5.0), "robot.call_timeout_s", 0.0, strict=True)
    return RobotConfig(host.strip(), tuple(tcp), payload, tuple(cog), timeout)


def _board(c: _Checker, value: object, simulated: bool) -> BoardConfig:
    m = c.mapping(value, "board")
    c.known(m, {"port", "baud"}, "board.")
    port = m.get("port")
    if port is None and not simulated:
        raise ConfigError(f"{c.source}: missing key 'board.port' (the Muca serial device)")
    if port is not None and (not isinstance(port, str) or not port):
        raise c.err("board.port", f"is {port!r}, not a serial device path")
    baud = c.integer(m.get("baud", 115200), "board.baud", 1200)
    return BoardConfig(port, baud)


def _registration(
    c: _Checker, value: object, base_dir: Path, patch: Patch
) -> tuple[str, PatchFrame]:
    m = c.mapping(value, "registration")
    c.known(m, {"method", "frame", "three_point", "aruco"}, "registration.")
    c.require(m, "method", "registration.")
    method = m["method"]
    if method not in ("frame", "three_point", "aruco"):
        raise c.err("registration.method", f"is {method!r}, not one of frame, three_point, aruco")
    c.require(m, method, "registration.")
    key = f"registration.{method}"
    sub = c.mapping(m[method], key)
    try:
        if method == "frame":
            return method, _frame(c, sub, key)
        if method == "three_point":
            c.known(sub, {"origin_m", "xaxis_m", "plane_m", "inset_mm"}, key + ".")
            pts = []
            for name in ("origin_m", "xaxis_m", "plane_m"):
                c.require(sub, name, key + ".")
                pts.append(c.vector(sub[name], f"{key}.{name}", 3))
            inset = c.number(sub.get("inset_mm", 0.0), f"{key}.inset_mm", 0.0)
            return method, register_three_points(*pts, origin_inset_mm=(inset, inset))
        return method, _aruco(c, sub, key, base_dir, patch)
    except RegistrationError as e:
        raise c.err(key, f"does not register the patch: {e}") from None


def _frame(c: _Checker, m: Mapping, key: str) -> PatchFrame:
    c.known(m, {"origin_m", "rotation", "yaw_deg"}, key + ".")
    c.require(m, "origin_m", key + ".")
    origin = c.vector(m["origin_m"], f"{key}.origin_m", 3)
    if "rotation" in m and "yaw_deg" in m:
        raise c.err(key, "gives both 'rotation' and 'yaw_deg'; keep one")
    if "rotation" in m:
        try:
            return PatchFrame(c.matrix(m["rotation"], f"{key}.rotation", 3, 3), origin)
        except ValueError as e:
            if isinstance(e, ConfigError):
                raise
            raise c.err(f"{key}.rotation", "is not a proper rotation matrix") from None
    yaw = c.number(m.get("yaw_deg", 0.0), f"{key}.yaw_deg")
    return PatchFrame.from_yaw(origin, np.radians(yaw))


def _aruco(c: _Checker, m: Mapping, key: str, base_dir: Path, patch: Patch) -> PatchFrame:
    c.known(m, {"image", "camera_matrix", "dist_coeffs", "camera_to_base", "markers"}, key + ".")
    for name in ("image", "camera_matrix", "camera_to_base", "markers"):
        c.require(m, name, key + ".")
    k = c.matrix(m["camera_matrix"], f"{key}.camera_matrix", 3, 3)
    dist_raw = m.get("dist_coeffs", [0, 0, 0, 0, 0])
    if not isinstance(dist_raw, list) or len(dist_raw) not in (4, 5, 8, 12, 14):
        raise c.err(f"{key}.dist_coeffs", "must list 4, 5, 8, 12 or 14 numbers")
    dist = c.vector(dist_raw, f"{key}.dist_coeffs", len(dist_raw))
    cam_to_base = c.matrix(m["camera_to_base"], f"{key}.camera_to_base", 4, 4)
    mk = c.mapping(m["markers"], f"{key}.markers")
    c.known(mk, {"dictionary", "size_mm", "gap_mm", "per_long_side", "first_id"}, f"{key}.markers.")
    image_path = m["image"]
    if not isinstance(image_path, str):
        raise c.err(f"{key}.image", "must be an image file path")
    p = Path(image_path)
    p = p if p.is_absolute() else base_dir / p
    image = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise c.err(f"{key}.image", f"cannot read image {p}")
    layout_kwargs = {}
    for name in ("size_mm", "gap_mm"):
        if name in mk:
            layout_kwargs[name] = c.number(mk[name], f"{key}.markers.{name}", 0.0, strict=True)
    for name, low in (("per_long_side", 0), ("first_id", 0)):
        if name in mk:
            layout_kwargs[name] = c.integer(mk[name], f"{key}.markers.{name}", low)
    if "dictionary" in mk:
        if not isinstance(mk["dictionary"], str) or not mk["dictionary"].startswith("DICT_"):
            raise c.err(
                f"{key}.markers.dictionary",
                f"is {mk['dictionary']!r}, not an ArUco dictionary like DICT_4X4_50",
            )
        layout_kwargs["dictionary"] = mk["dictionary"]
    layout = MarkerLayout.around_patch(patch, **layout_kwargs)
    return register_from_aruco(image, k, dist, layout, camera_to_base=cam_to_base)


def _touch(c: _Checker, value: object) -> TouchSpec:
    m = c.mapping(value, "touch")
    fields = TouchSpec.__dataclass_fields__
    c.known(m, set(fields), "touch.")
    kwargs = {}
    for name in fields:
        if name in m:
            kwargs[name] = c.number(
                m[name], f"touch.{name}", 0.0, strict=name not in ("dwell_s", "settle_s")
            )
    spec = TouchSpec(**kwargs)
    if spec.target_force_n >= spec.max_force_n:
        raise c.err(
            "touch.max_force_n",
            f"({spec.max_force_n:g} N) must be above touch.target_force_n ({spec.target_force_n:g} N)",
        )
    return spec


def _plan(c: _Checker, value: object, patch: Patch) -> PlanConfig:
    m = c.mapping(value, "plan")
    c.known(m, {"grid", "margin_mm", "mode", "budget", "target_sigma_mm", "order"}, "plan.")
    c.require(m, "grid", "plan.")
    grid = m["grid"]
    if isinstance(grid, str) and "x" in grid:
        parts = grid.lower().split("x")
        try:
            grid = [int(parts[0]), int(parts[1])]
        except (ValueError, IndexError):
            raise c.err("plan.grid", f"is {m['grid']!r}, not NXxNY like '20x5'") from None
    if not isinstance(grid, list) or len(grid) != 2:
        raise c.err("plan.grid", f"is {m['grid']!r}, not NXxNY like '20x5'")
    nx = c.integer(grid[0], "plan.grid[0]", 1)
    ny = c.integer(grid[1], "plan.grid[1]", 1)
    margin = c.number(m.get("margin_mm", 3.0), "plan.margin_mm", 0.0)
    if 2 * margin >= min(patch.length_mm, patch.width_mm):
        raise c.err("plan.margin_mm", f"({margin:g} mm) leaves no room on patch {patch.name!r}")
    mode = m.get("mode", "uniform")
    if mode not in ("uniform", "adaptive"):
        raise c.err("plan.mode", f"is {mode!r}, not uniform or adaptive")
    budget = c.integer(m.get("budget", 100), "plan.budget", 1)
    target = m.get("target_sigma_mm")
    if target is not None:
        target = c.number(target, "plan.target_sigma_mm", 0.0, strict=True)
    from varskin.planning import ORDERS

    order = m.get("order", "auto")
    if order not in ORDERS:
        raise c.err("plan.order", f"is {order!r}, not {', '.join(ORDERS)}")
    return PlanConfig(nx, ny, margin, mode, budget, target, order)


def _sim(c: _Checker, value: object) -> SimConfig:
    m = c.mapping(value, "sim")
    c.known(m, set(SimConfig.__dataclass_fields__), "sim.")
    seed = c.integer(m.get("seed", 0), "sim.seed", 0)
    err = m.get("registration_error_mm", [0.0, 0.0, 0.0])
    return SimConfig(
        seed=seed,
        stiffness_n_per_mm=c.number(
            m.get("stiffness_n_per_mm", 3.0), "sim.stiffness_n_per_mm", 0.0, strict=True
        ),
        force_offset_n=c.number(m.get("force_offset_n", 0.8), "sim.force_offset_n"),
        force_noise_sd_n=c.number(m.get("force_noise_sd_n", 0.05), "sim.force_noise_sd_n", 0.0),
        registration_error_mm=tuple(c.vector(err, "sim.registration_error_mm", 3)),
        time_scale=c.number(m.get("time_scale", 1.0), "sim.time_scale", 0.0, strict=True),
    )

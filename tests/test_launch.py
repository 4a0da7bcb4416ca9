"""Launch files: both shipped files load; every mistake names the file and the key."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import yaml

from robot.launch import load_launch
from varskin.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent
SIM = ROOT / "launch" / "sim.yaml"
UR5E = ROOT / "launch" / "ur5e_muca.yaml"


def test_sim_launch_loads_and_its_plan_is_inside_the_envelope():
    launch = load_launch(SIM)
    assert launch.simulated and launch.board.port is None
    assert launch.patch.name == "patch_b"
    assert (launch.plan.nx, launch.plan.ny) == (20, 5)
    points = launch.plan_points_m()
    assert points.shape == (100, 3)
    launch.envelope.check_touch_plan(points, launch.touch)
    # Serpentine: consecutive touches are neighbours, never a jump back across the patch.
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    assert steps.max() < 0.01


def test_arm_touch_spec_divides_host_clock_waits_by_the_sim_time_scale(tmp_path):
    launch = load_launch(SIM)
    scale = launch.sim.time_scale
    assert scale > 1  # the shipped simulated rig runs faster than real time
    arm = launch.arm_touch_spec()
    assert arm.dwell_s == pytest.approx(launch.touch.dwell_s / scale)
    assert arm.settle_s == pytest.approx(launch.touch.settle_s / scale)
    # speeds, distances and forces are the controller's business: it runs them faster
    assert dataclasses.replace(arm, dwell_s=0.0, settle_s=0.0) == dataclasses.replace(
        launch.touch, dwell_s=0.0, settle_s=0.0
    )
    # a real rig, and a simulated one at scale 1 (the default), get the touch unchanged
    real = load_launch(UR5E)
    assert real.sim.time_scale == 1.0 and real.arm_touch_spec() == real.touch
    data = yaml.safe_load(SIM.read_text())
    del data["sim"]["time_scale"]
    unscaled = load_launch(_write(tmp_path, data))
    assert unscaled.sim.time_scale == 1.0 and unscaled.arm_touch_spec() == unscaled.touch


def test_ur5e_template_loads_and_its_three_points_register_the_patch():
    launch = load_launch(UR5E)
    assert not launch.simulated
    assert launch.robot.host == "192.168.1.10" and launch.board.port == "/dev/ttyACM0"
    assert launch.registration_method == "three_point"
    assert np.allclose(launch.frame.origin_m, [0.400, -0.080, 0.050], atol=1e-9)
    assert np.allclose(launch.frame.rotation, np.eye(3), atol=1e-9)
    assert launch.touch.max_force_n <= launch.envelope.max_force_n


def _write(tmp_path: Path, data: dict, name: str = "rig.yaml") -> Path:
    data = dict(data)
    data["patch"] = str(ROOT / "configs" / "patch_b.yaml")
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def _set(d: dict, dotted: str, value) -> None:
    keys = dotted.split(".")
    for k in keys[:-1]:
        d = d[k]
    if value is _DELETE:
        del d[keys[-1]]
    else:
        d[keys[-1]] = value


_DELETE = object()

CASES = [
    ("touch", _DELETE, "missing key 'touch'"),
    ("simulated", "yes", "'simulated' is 'yes', not true or false"),
    ("robot.tcp_offset", [0, 0, 0.1, 0, 0], "'robot.tcp_offset' must be a list of 6 numbers"),
    (
        "robot.tcp_offset",
        [0, 0, 120, 0, 0, 0],
        "'robot.tcp_offset' puts the probe tip more than 0.5 m",
    ),
    ("robot.payload_kg", -1, "'robot.payload_kg' is -1, must be >= 0"),
    ("robot.call_timeout_s", 0, "'robot.call_timeout_s' is 0, must be > 0"),
    ("board.baud", "fast", "'board.baud' is 'fast', not an integer"),
    ("touch.target_force_n", -2.0, "'touch.target_force_n' is -2.0, must be > 0"),
    (
        "touch.max_force_n",
        1.5,
        "'touch.max_force_n' (1.5 N) must be above touch.target_force_n (2 N)",
    ),
    ("touch.max_force_n", 9.0, "touch max force 9 N is above the envelope's 5 N"),
    ("touch.force_speed_limit_m_s", 1.5, "touch force_speed_limit_m_s 1.5 m/s is not in (0, 0.01]"),
    ("touch.dwel_s", 0.5, "unknown key 'touch.dwel_s'"),
    ("envelope.max_force_n", -5, "'envelope.max_force_n' is -5, must be > 0"),
    ("envelope.depth_mm", _DELETE, "missing key 'envelope.depth_mm'"),
    ("plan.grid", "twentyxfive", "'plan.grid' is 'twentyxfive', not NXxNY"),
    ("plan.grid", [0, 5], "'plan.grid[0]' is 0, not an integer >= 1"),
    ("plan.margin_mm", 13, "'plan.margin_mm' (13 mm) leaves no room"),
    ("plan.order", "zigzag", "'plan.order' is 'zigzag', not auto, sweep, shuffled"),
    ("registration.method", "laser", "'registration.method' is 'laser', not one of"),
    (
        "registration.frame.origin_m",
        [0.4, "a", 0.05],
        "'registration.frame.origin_m[1]' is 'a', not a number",
    ),
    (
        "registration.frame.rotation",
        [[1, 0, 0], [0, 1, 0], [0, 0, 2]],
        "'registration.frame' gives both",
    ),
    ("sim.seed", -1, "'sim.seed' is -1, not an integer >= 0"),
    ("sim.stiffness", 3.0, "unknown key 'sim.stiffness'"),
    ("sim.time_scale", 0, "'sim.time_scale' is 0, must be > 0"),
    ("sim.time_scale", "fast", "'sim.time_scale' is 'fast', not a number"),
    ("robots", {}, "unknown key 'robots'"),
]


@pytest.mark.parametrize(("key", "value", "message"), CASES, ids=[c[0] for c in CASES])
def test_malformed_launch_names_file_and_key(tmp_path, key, value, message):
    data = yaml.safe_load(SIM.read_text())
    _set(data, key, value)
    path = _write(tmp_path, data)
    with pytest.raises(ConfigError) as e:
        load_launch(path)
    text = str(e.value)
    assert text.startswith(f"{path}: ") and message in text
    assert "\n" not in text


def test_bad_rotation_and_three_point_registration(tmp_path):
    data = yaml.safe_load(SIM.read_text())
    data["registration"]["frame"] = {
        "origin_m": [0.4, -0.08, 0.05],
        "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 2]],
    }
    with pytest.raises(
        ConfigError, match=r"'registration.frame.rotation' is not a proper rotation"
    ):
        load_launch(_write(tmp_path, data))
    data["registration"] = {
        "method": "three_point",
        "three_point": {
            "origin_m": [0.4, 0, 0.05],
            "xaxis_m": [0.5, 0, 0.05],
            "plane_m": [0.6, 0, 0.05],
        },
    }
    with pytest.raises(
        ConfigError, match=r"'registration.three_point' does not register the patch: .*collinear"
    ):
        load_launch(_write(tmp_path, data))


def test_real_rig_needs_a_serial_port_and_no_sim_section(tmp_path):
    data = yaml.safe_load(UR5E.read_text())
    del data["board"]["port"]
    with pytest.raises(ConfigError, match="missing key 'board.port'"):
        load_launch(_write(tmp_path, data))
    data = yaml.safe_load(UR5E.read_text())
    data["sim"] = {"seed": 1}
    with pytest.raises(ConfigError, match="'sim' is only allowed with 'simulated: true'"):
        load_launch(_write(tmp_path, data))


def test_unreadable_and_invalid_yaml(tmp_path):
    with pytest.raises(ConfigError, match="nope.yaml: cannot read"):
        load_launch(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("simulated: true\nrobot: [unclosed\n")
    with pytest.raises(ConfigError, match=r"bad.yaml line \d+: is not valid YAML"):
        load_launch(bad)


def test_aruco_registration_from_a_launch(tmp_path, patch_b):
    import cv2

    from robot.registration import MarkerLayout, camera_pose_looking_at, render_markers

    k = [[1400.0, 0.0, 640.0], [0.0, 1400.0, 480.0], [0.0, 0.0, 1.0]]
    pose = camera_pose_looking_at([0.08, 0.0, 0.4], [0.076, 0.0127, 0.0])
    image = render_markers(
        MarkerLayout.around_patch(patch_b), np.array(k), pose, (1280, 960), noise_sd=3.0
    )
    cv2.imwrite(str(tmp_path / "photo.png"), image)
    base_from_cam = np.linalg.inv(pose)  # the camera as if the base frame were the patch frame
    data = yaml.safe_load(SIM.read_text())
    data["registration"] = {
        "method": "aruco",
        "aruco": {
            "image": "photo.png",
            "camera_matrix": k,
            "camera_to_base": base_from_cam.tolist(),
            "markers": {},
        },
    }
    launch = load_launch(_write(tmp_path, data))
    assert np.allclose(launch.frame.origin_m, 0.0, atol=5e-4)
    data["registration"]["aruco"]["image"] = "missing.png"
    with pytest.raises(ConfigError, match="'registration.aruco.image' cannot read image"):
        load_launch(_write(tmp_path, data))

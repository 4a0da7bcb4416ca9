import numpy as np
import pytest

from varskin.errors import ConfigError
from varskin.patch import load_patch, patch_from_dict
from varskin.scene import ProbeModel, Scene, SceneParams


def test_published_patch_b_layout(patch_b):
    assert len(patch_b.sensors) == 30
    assert (patch_b.length_mm, patch_b.width_mm) == (152.4, 25.4)
    s1, s2, s3, s4 = patch_b.sensors[:4]
    assert (s1.x_mm, s1.y_mm) == (5.544, 19.831)
    assert (s2.x_mm, s2.y_mm) == (5.544, 13.506)
    assert (s3.x_mm, s3.y_mm) == (5.544, 7.156)
    assert (s4.x_mm, s4.y_mm) == (34.119, 19.831)
    assert patch_b.sensors[-1].x_mm == 148.444


def test_published_patch_a_layout(patch_a):
    assert len(patch_a.sensors) == 22
    xs = sorted({s.x_mm for s in patch_a.sensors})
    np.testing.assert_allclose(xs, [9.525 + 13.494 * k for k in range(11)], atol=1e-3)
    assert sorted({s.y_mm for s in patch_a.sensors}) == [9.525, 19.05]


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("name: p\n", "missing key 'size_mm'"),
        ("name: p\nsize_mm: [10, 5]\ntx_x_mm: [1, 'a']\nrx_y_mm: [1]\n", "tx_x_mm[1]"),
        (
            "name: p\nsize_mm: [10, 5]\ntx_x_mm: [1]\nrx_y_mm: [1]\nsensors: [{name: a, tx: 3, rx: 0}]\n",
            "sensors[0].tx",
        ),
        (
            "name: p\nsize_mm: [10, 5]\ntx_x_mm: [1]\nrx_y_mm: [1, 2]\nsensors: [{name: a, tx: 0, rx: 0}, {name: a, tx: 0, rx: 1}]\n",
            "repeated",
        ),
        ("name: [unclosed\n", "not valid YAML"),
        # NaN and inf used to pass and reach the localizer's design prior (found by fuzzing).
        ("name: p\nsize_mm: [10, 5]\ntx_x_mm: [1, .nan]\nrx_y_mm: [1]\n", "tx_x_mm[1]"),
        ("name: p\nsize_mm: [.inf, 5]\ntx_x_mm: [1]\nrx_y_mm: [1]\n", "size_mm[0]"),
    ],
)
def test_bad_patch_config_names_the_problem(tmp_path, text, fragment):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as e:
        load_patch(path)
    assert fragment in str(e.value) and "bad.yaml" in str(e.value)


def test_missing_file_is_config_error(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_patch(tmp_path / "nope.yaml")


def test_scene_response_peaks_at_true_position(patch_b):
    scene = Scene.create(patch_b, seed=3)
    probe = ProbeModel.named("robot")
    for i in (0, 13, 29):
        x, y = scene.true_xy[i]
        at = scene.response(x, y, 2.0, probe)[i]
        off = scene.response(x + 3.0, y, 2.0, probe)[i]
        assert at > off > 0
    assert not np.allclose(scene.true_xy, patch_b.design_xy)  # layout is hidden by default
    assert scene.response(10, 10, 0.0, probe).sum() == 0.0  # no force, no signal


def test_a_stretched_scene_scales_the_layout_about_the_patch_centre(patch_b):
    """``stretch`` lays the patch that much longer and wider about its centre; the hidden
    wires' displacements come on top, from the same random draws as unstretched (a bent
    wire's slope then spans a stretched wire: a few micrometres more here). A crossing is
    still kept 0.5 mm inside the patch's edge (S28 and S29 of this seed)."""
    centre = np.array([patch_b.length_mm, patch_b.width_mm]) / 2
    flat = Scene.create(patch_b, seed=3, params=SceneParams(hidden_layout=False, stretch=0.02))
    np.testing.assert_allclose(flat.true_xy, centre + (patch_b.design_xy - centre) * 1.02)
    plain = Scene.create(patch_b, seed=3)
    stretched = Scene.create(patch_b, seed=3, params=SceneParams(stretch=0.02))
    edge = stretched.true_xy[:, 0] >= patch_b.length_mm - 0.5
    assert edge.sum() == 2
    np.testing.assert_allclose(
        (stretched.true_xy - plain.true_xy)[~edge],
        ((patch_b.design_xy - centre) * 0.02)[~edge],
        atol=0.005,
    )
    np.testing.assert_array_equal(stretched.peak, plain.peak)


def test_a_turned_scene_lies_rotated_about_the_patch_centre(patch_b):
    """``rotation_deg``: the registration's residual rotation turns the layout about the
    patch's centre in the probes' frame (anticlockwise), keeping every distance."""
    centre = np.array([patch_b.length_mm, patch_b.width_mm]) / 2
    turned = Scene.create(patch_b, params=SceneParams(hidden_layout=False, rotation_deg=0.5))
    before = patch_b.design_xy - centre
    after = turned.true_xy - centre
    np.testing.assert_allclose(np.hypot(*after.T), np.hypot(*before.T))
    angle = np.degrees(
        np.arctan2(after[:, 1], after[:, 0]) - np.arctan2(before[:, 1], before[:, 0])
    )
    np.testing.assert_allclose((angle + 180.0) % 360.0 - 180.0, 0.5, atol=1e-9)


def test_patch_defaults_name_sensors_y_fastest():
    p = patch_from_dict({"name": "t", "size_mm": [10, 5], "tx_x_mm": [1, 2], "rx_y_mm": [1, 3]})
    assert [(s.name, s.tx, s.rx) for s in p.sensors] == [
        ("S1", 0, 0),
        ("S2", 0, 1),
        ("S3", 1, 0),
        ("S4", 1, 1),
    ]

"""Offscreen cameras (bench.sims.camera) and visual perturbation axes (bench.sims.perturb.scene, bench.sims.perturb.visual) on a
real MuJoCo scene rendered with EGL (software rendering on CPU machines): a table with a textured top, a cube, a
floor, a wall, a light, a fixed front camera and a camera on a moving body."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from bench.core.errors import ConfigError
from bench.sims.camera import CameraRig, check_cameras, parse_image_size
from bench.sims.perturb.scene import ROWS, VisualScene


def check(model, objects, axis, named, cameras, where):
    """A visual row's model check (rows without one apply to any model)."""
    if ROWS[axis].check is not None:
        ROWS[axis].check(model, objects, named, cameras, where)


AXES = tuple(ROWS)

mujoco = pytest.importorskip("mujoco")

SCENE = """
<mujoco>
  <asset>
    <texture name="wood" type="2d" builtin="checker" rgb1=".6 .4 .2" rgb2=".5 .3 .1" width="64" height="64"/>
    <material name="tablemat" texture="wood" texrepeat="2 2"/>
  </asset>
  <worldbody>
    <light name="sun" pos="0.5 -0.5 2" dir="-0.2 0.2 -1"/>
    <geom name="floor" type="plane" size="3 3 .1" rgba=".7 .7 .75 1"/>
    <geom name="wall" type="box" pos="0 1.5 1" size="3 .05 1" rgba=".6 .65 .7 1"/>
    <body name="table" pos="0 0 .4">
      <geom name="table_top" type="box" size=".4 .4 .02" pos="0 0 .38" material="tablemat"/>
      <geom name="table_leg" type="cylinder" size=".03 .38" rgba=".3 .3 .3 1"/>
    </body>
    <body name="cube" pos="0.05 0 .82"><freejoint/><geom name="cube_g" type="box" size=".04 .04 .04" rgba=".9 .1 .1 1"/></body>
    <body name="hand" pos="0 -.1 1.1">
      <joint name="slide" type="slide" axis="1 0 0"/>
      <camera name="wrist" xyaxes="1 0 0 0 1 0"/><geom name="hand_g" type="sphere" size=".02" rgba=".2 .2 .2 1"/>
    </body>
    <camera name="front" pos="0 -1.2 1.3" xyaxes="1 0 0 0 .6 .8"/>
  </worldbody>
</mujoco>
"""


@pytest.fixture
def scene():
    model = mujoco.MjModel.from_xml_string(SCENE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    rig = CameraRig(model, data, ["front", "wrist"], (64, 80), where="scene")
    yield model, data, rig
    rig.close()


def test_images_are_named_shaped_and_deterministic(scene):
    model, data, rig = scene
    assert set(rig.spec()) == {"rgb.front", "rgb.wrist"}
    assert rig.spec()["rgb.front"].shape == (64, 80, 3) and rig.spec()["rgb.front"].dtype == "uint8"
    first = rig.render()
    assert first["rgb.front"].shape == (64, 80, 3) and first["rgb.front"].dtype == np.uint8
    assert first["rgb.front"].std() > 10  # a scene, not a blank frame
    again = rig.render()
    np.testing.assert_array_equal(first["rgb.front"], again["rgb.front"])
    other = CameraRig(model, data, ["front"], (64, 80))  # a second rig on the same state: same pixels
    np.testing.assert_array_equal(other.render()["rgb.front"], first["rgb.front"])
    other.close()
    data.qpos[model.jnt_qposadr[model.joint("slide").id]] = 0.2  # the wrist camera moves with its body
    mujoco.mj_forward(model, data)
    moved = rig.render()
    assert not np.array_equal(moved["rgb.wrist"], first["rgb.wrist"])
    np.testing.assert_array_equal(moved["rgb.front"], first["rgb.front"])
    assert rig.describe() == {
        "cameras": ["front", "wrist"],
        "height": 64,
        "width": 80,
        "scene": {"shadows": False, "reflections": False, "skybox": False},
        "gl": rig.describe()["gl"],
    }


def test_orientation_top_row_is_the_top_of_the_view(scene):
    """OpenGL reads the bottom row first; the rig flips it: the wall (above the table) is in the top rows."""
    model, data, rig = scene
    img = rig.render()["rgb.front"].astype(float)
    assert img[:8].mean() != pytest.approx(img[-8:].mean(), abs=5)
    floor = np.array([0.7, 0.7, 0.75]) * 255
    assert np.abs(img[-4:].mean(axis=(0, 1)) - floor).max() < np.abs(img[:4].mean(axis=(0, 1)) - floor).max() + 60


def test_bad_cameras_and_sizes(scene):
    model, _, _ = scene
    with pytest.raises(
        ConfigError, match=r"cameras: 'frnt' is not a camera of scene; valid: front, wrist\. Did you mean 'front'\?"
    ):
        check_cameras(["frnt"], model, "scene")
    with pytest.raises(ConfigError, match="names a camera twice"):
        check_cameras(["front", "front"], model, "scene")
    for bad in (8, 2048, "abc", 0, 64.5, [64, 12]):
        with pytest.raises(
            ConfigError, match=r"image_size: .* image sizes are whole numbers of pixels in \[16, 1024\]"
        ):
            parse_image_size(bad)
    assert parse_image_size(128) == (128, 128) and parse_image_size([96, "128"]) == (96, 128)
    empty = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='1' type='sphere'/></worldbody></mujoco>")
    with pytest.raises(ConfigError, match="has no cameras, so it cannot give image observations"):
        check_cameras(["front"], empty, "ball")


def test_large_image_grows_the_offscreen_buffer():
    model = mujoco.MjModel.from_xml_string(SCENE)
    data = mujoco.MjData(model)
    with CameraRig(model, data, ["front"], (700, 1024)) as rig:
        assert rig.render()["rgb.front"].shape == (700, 1024, 3)


def test_no_renderer_is_one_line_naming_mujoco_gl():
    """With a backend that cannot start here (GLFW needs a display), the error says how to enable EGL."""
    code = (
        "import mujoco\nfrom bench.sims.camera import CameraRig, RendererError\n"
        "m = mujoco.MjModel.from_xml_string(\"<mujoco><worldbody><camera name='c'/></worldbody></mujoco>\")\n"
        "try:\n    CameraRig(m, mujoco.MjData(m), ['c'], (32, 32)).start()\nexcept RendererError as e:\n    print('ERR', e)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["MUJOCO_GL"] = "glfw"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120).stdout
    assert out.startswith("ERR obs=rgb: no offscreen OpenGL renderer could start with MUJOCO_GL=glfw"), out
    assert "set MUJOCO_GL=egl" in out and len(out.strip().splitlines()) == 1


@pytest.mark.parametrize(
    "axis,level",
    [
        ("light", 0.4),
        ("light_dir", 40),
        ("camera_pos", 0.1),
        ("camera_rot", 8),
        ("camera_fov", 1.5),
        ("object_color", 1.0),
        ("table_color", 0.8),
        ("background", 0.9),
        ("texture", 1),
        ("texture", 4),
        ("distractors", 5),
    ],
)
def test_each_visual_axis_changes_the_image_and_clears_exactly(scene, axis, level):
    model, data, rig = scene
    vs = VisualScene(rig, object_bodies=["cube"], where="scene")
    nominal = rig.render(vs)
    params = vs.apply(axis, level, {}, np.random.default_rng(3))
    assert params[axis] == level
    seen = rig.render(vs)
    assert np.abs(seen["rgb.front"].astype(int) - nominal["rgb.front"]).mean() > 0.3, axis
    again = rig.render(vs)  # stable within the episode
    np.testing.assert_array_equal(again["rgb.front"], seen["rgb.front"])
    vs.clear()
    back = rig.render(vs)
    np.testing.assert_array_equal(back["rgb.front"], nominal["rgb.front"])  # textures re-uploaded, nothing drifts
    np.testing.assert_array_equal(back["rgb.wrist"], nominal["rgb.wrist"])
    # the same episode generator gives the same scene; another gives another (where the axis draws anything)
    vs.apply(axis, level, {}, np.random.default_rng(3))
    np.testing.assert_array_equal(rig.render(vs)["rgb.front"], seen["rgb.front"])
    vs.clear()
    if axis not in ("light", "camera_fov"):  # these draw nothing
        vs.apply(axis, level, {}, np.random.default_rng(4))
        assert not np.array_equal(rig.render(vs)["rgb.front"], seen["rgb.front"]), axis
        vs.clear()


def test_camera_fov_zooms_the_named_cameras_and_records_degrees(scene):
    model, data, rig = scene
    vs = VisualScene(rig, object_bodies=["cube"], where="scene")

    def red(img):  # pixels of the red cube
        return int(((img[..., 0] > 150) & (img[..., 1] < 80)).sum())

    nominal = rig.render(vs)
    assert red(nominal["rgb.front"]) > 0
    params = vs.apply("camera_fov", 0.8, {"cameras": ["front"]}, np.random.default_rng(0))
    assert params == {"camera_fov": 0.8, "camera_fov.deg": 36.0}  # 0.8 x MuJoCo's default 45 degrees
    narrow = rig.render(vs)
    assert red(narrow["rgb.front"]) > red(nominal["rgb.front"])  # a narrower view: the cube looks bigger
    np.testing.assert_array_equal(narrow["rgb.wrist"], nominal["rgb.wrist"])  # only the named camera
    vs.clear()
    vs.apply("camera_fov", 1.5, {}, np.random.default_rng(0))
    assert red(rig.render(vs)["rgb.front"]) < red(nominal["rgb.front"])  # wider: smaller
    vs.clear()
    np.testing.assert_array_equal(rig.render(vs)["rgb.front"], nominal["rgb.front"])
    with pytest.raises(ConfigError, match=r"perturb.camera_fov.cameras: 'top' is not a rendered camera"):
        check(model, ["cube"], "camera_fov", {"cameras": ["top"]}, ["front", "wrist"], "scene")


def test_physics_untouched_and_camera_targets(scene):
    model, data, rig = scene
    vs = VisualScene(rig, object_bodies=["cube"], where="scene")
    before = {f: np.array(getattr(model, f), copy=True) for f in ("geom_rgba", "geom_size", "body_mass", "light_dir")}
    nominal = rig.render(vs)
    for axis, level in (("light", 0.5), ("light_dir", 30), ("object_color", 1.0), ("distractors", 3), ("texture", 2)):
        vs.apply(axis, level, {}, np.random.default_rng(0))
    vs.apply("camera_pos", 0.2, {"cameras": ["wrist"]}, np.random.default_rng(0))
    rig.render(vs)
    for f, v in before.items():
        np.testing.assert_array_equal(getattr(model, f), v, err_msg=f)
    vs.clear()
    vs.apply("camera_pos", 0.2, {"cameras": ["wrist"]}, np.random.default_rng(0))
    moved = rig.render(vs)
    np.testing.assert_array_equal(moved["rgb.front"], nominal["rgb.front"])  # only the named camera moved
    assert not np.array_equal(moved["rgb.wrist"], nominal["rgb.wrist"])


def test_visual_axes_that_cannot_apply_say_why(scene):
    model, _, _ = scene
    with pytest.raises(
        ConfigError, match=r"perturb.camera_pos.cameras: 'top' is not a rendered camera of scene; valid: front, wrist"
    ):
        check(model, ["cube"], "camera_pos", {"cameras": ["top"]}, ["front", "wrist"], "scene")
    with pytest.raises(ConfigError, match="perturb.object_color: scene declares no manipulated object"):
        check(model, [], "object_color", {}, ["front"], "scene")
    with pytest.raises(ConfigError, match=r"perturb.texture: the targeted geoms of scene have no texture to replace"):
        check(model, ["cube"], "texture", {"geoms": ["cube_g"]}, ["front"], "scene")
    with pytest.raises(ConfigError, match=r"perturb.table_color.geoms: 'tabel' is not a geom of scene.*Did you mean"):
        check(model, ["cube"], "table_color", {"geoms": ["tabel"]}, ["front"], "scene")
    bare = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><geom size='.1'/></body><camera name='c'/></worldbody></mujoco>"
    )
    with pytest.raises(ConfigError, match="perturb.table_color: found no table in bare"):
        check(bare, [], "table_color", {}, ["c"], "bare")
    with pytest.raises(ConfigError, match="perturb.distractors: bare has no table .* or floor plane"):
        check(bare, [], "distractors", {}, ["c"], "bare")
    for axis in AXES:
        check(model, ["cube"], axis, {}, ["front", "wrist"], "scene")  # all apply to the full scene

"""Visual axes on ManiSkill (SAPIEN's render scene): the rows' SAPIEN hooks, bad input, and the images.

Without a Vulkan device (the default suite) the refusals and the row plumbing are tested: one line, exit 2,
nothing written, through the command line, and the episode's perturbation set and cleared through
`bench.sims.perturb.reset`. The images themselves need a device: the tests marked `vulkan` run one
subprocess with `VK_ICD_FILENAMES` (lavapipe from scripts/fetch_lavapipe.sh on CPU), since a process that
installed the no-Vulkan stand-ins cannot render afterwards.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mani_skill", reason="the maniskill extra is not installed (pip install -e '.[maniskill]')")

from bench.cli import main  # noqa: E402
from bench.sims.perturb.scene import ROWS  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
ON_SAPIEN = (
    "light",
    "light_dir",
    "camera_pos",
    "camera_rot",
    "camera_fov",
    "object_color",
    "table_color",
    "background",
)


# -- the rows ----------------------------------------------------------------------------------
def test_rows_carry_a_sapien_hook_except_texture_and_distractors():
    assert [n for n, a in ROWS.items() if a.sapien is not None] == list(ON_SAPIEN)
    for name in ("light", "light_dir", "camera_pos", "camera_rot", "object_color", "table_color", "background"):
        assert ROWS[name].sapien is ROWS[name].paint, name  # one function: the same draws, the same params
    assert ROWS["camera_fov"].sapien is not ROWS["camera_fov"].paint  # each camera's own fovy on SAPIEN


# -- bad input: one line, exit 2, nothing written -------------------------------------------------
@pytest.mark.parametrize(
    "extra, message",
    [
        (["perturb.light=[0.3]"], "perturb.light changes only what the cameras see, and obs=state gives the policy"),
        (
            ["perturb.texture=[1]"],
            "perturb.texture: not available on ManiSkill/SAPIEN (PickCube-v1 with panda); visual axes there: light, "
            "light_dir, camera_pos, camera_rot, camera_fov, object_color, table_color, background (and the "
            "image-noise axes)",
        ),
        (["perturb.distractors=[2]"], "perturb.distractors: not available on ManiSkill/SAPIEN"),
        (
            ["perturb.camera_pos.levels=[0.1]", "perturb.camera_pos.cameras=[base_camra]"],
            "perturb.camera_pos.cameras: 'base_camra' is not among the cameras of PickCube-v1 with panda; valid: "
            "base_camera. Did you mean 'base_camera'?",
        ),
        (
            ["perturb.object_color.levels=[1]", "perturb.object_color.bodies=[cueb]"],
            "perturb.object_color.bodies: 'cueb' is not among the actors and links of PickCube-v1 with panda",
        ),
        (
            ["perturb.table_color.levels=[1]", "perturb.table_color.geoms=[table]"],
            "perturb.table_color.geoms: ManiSkill/SAPIEN names actors and links, not geoms; use "
            "perturb.table_color.bodies=[...]",
        ),
        (["perturb.camera_fov=[-1]"], "perturb.camera_fov: -1 is invalid; camera_fov levels"),
        (["perturb.image_noise=[0.1]"], "perturb.image_noise changes only camera images"),
    ],
    ids=["obs-state", "texture", "distractors", "camera-typo", "body-typo", "geoms", "negative-fov", "image-noise"],
)
def test_bad_visual_input_is_one_line_exit_2_nothing_written(extra, message, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["run", "suite=maniskill_tasks", "tasks=[PickCube]", "episodes=1", f"out={out}", *extra]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not out.exists()


# -- the flow through bench.sims.perturb.reset, without rendering ----------------------------------
def test_episode_perturbation_set_recorded_and_cleared():
    """reset.apply reaches the SAPIEN scene with the episode's generator and clears it the next episode."""
    from bench.sims import perturb
    from bench.sims.maniskill import ManiSkillEnv
    from bench.sims.perturb.axes import conditions_from_config

    env = ManiSkillEnv("PickCube-v1", "panda", 10, object_names=("cube",))
    scene = env.sapien_scene
    conds = conditions_from_config({"light": [0.3], "camera_pos": [0.05], "object_color": [0.5]})
    _, params = perturb.apply(env, conds[1], np.random.default_rng(0))
    assert params == {"light": 0.3} and scene.light_scale == 0.3
    _, params = perturb.apply(env, conds[2], np.random.default_rng(0))
    assert scene.light_scale == 1.0 and scene.cam_cameras == ()  # obs=state renders no camera to move
    direction = np.random.default_rng(0).normal(size=3)
    assert params["camera_pos.direction"] == [round(float(v), 6) for v in direction / np.linalg.norm(direction)]
    _, params = perturb.apply(env, conds[3], np.random.default_rng(0))
    assert list(scene.colors) == ["cube"] and params["object_color.rgb"] == [
        round(float(v), 4) for v in np.random.default_rng(0).uniform(0.0, 1.0, size=3)
    ]
    assert scene.after_reset() is False  # nothing renders: nothing is edited
    perturb.apply(env, conds[0], np.random.default_rng(0))
    assert not scene.active
    env.reset(0)
    env.close()


# -- the images (a Vulkan device) ------------------------------------------------------------------
_PROBE = r"""
import json, numpy as np
from bench.core.errors import ConfigError
from bench.sims import perturb
from bench.sims.maniskill import ManiSkillEnv
from bench.sims.perturb.axes import conditions_from_config
from bench.protocols.suite import NOMINAL

out = {}
for reset in ("rebuild", "soft"):
    env = ManiSkillEnv("PickCube-v1", "panda", 10, obs="rgb", object_names=("cube",), reset=reset)
    def episode(cond, seed=3):
        stepper, params = perturb.apply(env, cond, np.random.default_rng(7))
        return stepper.reset(seed)["rgb.base_camera"], params
    fresh, _ = episode(NOMINAL)
    axes = {"light": [0.3, 2.0], "light_dir": [45], "camera_pos": [0.1], "camera_rot": [10], "camera_fov": [0.7, 1.3],
            "object_color": [0.5, 1.0], "table_color": [1.0], "background": [1.0], "image_noise": [0.1], "motion_blur": [9]}
    conds = conditions_from_config(axes)[1:]
    perturb.validate(env, conds)
    res = {"nominal": {"mean": float(fresh.mean()), "img": fresh.tolist()}}
    same = []
    for cond in conds:
        img, params = episode(cond)
        back, _ = episode(NOMINAL)
        same.append(bool(np.array_equal(back, fresh)))
        res[cond.name] = {"mean": float(img.mean()), "img": img.tolist(), "params": params}
    res["nominal_after_each"] = same
    errors = []
    for bad in ({"texture": [1]}, {"camera_fov": {"levels": [1.2], "cameras": ["hand_camera"]}}):
        try:
            perturb.validate(env, conditions_from_config(bad)[1:])
        except ConfigError as exc:
            errors.append(str(exc))
    res["errors"] = errors
    out[reset] = res
    env.close()
print(json.dumps(out))
"""


_RENDERED: dict[str, dict] = {}  # one subprocess for both parametrisations


def _rendered(vulkan_icd: str) -> dict:
    if vulkan_icd not in _RENDERED:
        env = {k: v for k, v in os.environ.items() if k != "VK_ICD_FILENAMES"}
        env["VK_ICD_FILENAMES"] = vulkan_icd
        run = subprocess.run(
            [sys.executable, "-c", _PROBE], capture_output=True, text=True, cwd=REPO, env=env, timeout=900
        )
        assert run.returncode == 0, run.stderr[-3000:]
        _RENDERED[vulkan_icd] = json.loads(run.stdout.strip().splitlines()[-1])
    return _RENDERED[vulkan_icd]


def _img(res: dict, name: str) -> np.ndarray:
    return np.asarray(res[name]["img"], dtype=np.float64)


def _cube_mask(img: np.ndarray) -> np.ndarray:
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return (r > 120) & (g < 60) & (b < 60)


def _cosine_to(img: np.ndarray, mask: np.ndarray, rgb: list[float]) -> float:
    mean = img[mask].mean(axis=0)
    return float(mean @ np.asarray(rgb) / (np.linalg.norm(mean) * np.linalg.norm(rgb)))


@pytest.mark.vulkan
@pytest.mark.parametrize("reset", ["rebuild", "soft"])
def test_each_axis_changes_the_image_as_intended_and_nominal_comes_back(vulkan_icd, reset):
    res = _rendered(vulkan_icd)[reset]
    nominal = _img(res, "nominal")
    assert all(res["nominal_after_each"]), res["nominal_after_each"]  # to the bit, after every condition
    assert res["light=0.3"]["mean"] < 0.7 * res["nominal"]["mean"]
    assert res["light=2"]["mean"] > res["nominal"]["mean"]
    for name in ("light_dir=45", "camera_pos=0.1", "camera_rot=10", "image_noise=0.1", "motion_blur=9"):
        assert np.abs(_img(res, name) - nominal).mean() > 0.5, name
    cube = _cube_mask(nominal).sum()
    assert cube > 5
    assert _cube_mask(_img(res, "camera_fov=1.3")).sum() < cube < _cube_mask(_img(res, "camera_fov=0.7")).sum()
    assert res["camera_fov=1.3"]["params"]["camera_fov.deg"] == pytest.approx(117.0)
    mask = _cube_mask(nominal)
    rgb = res["object_color=1"]["params"]["object_color.rgb"]
    before = _cosine_to(nominal, mask, rgb)
    half, full = (
        _cosine_to(_img(res, "object_color=0.5"), mask, rgb),
        _cosine_to(_img(res, "object_color=1"), mask, rgb),
    )
    assert before < half < full  # the cube's pixels move toward the drawn colour with the blend
    table = ~mask
    table[: nominal.shape[0] // 2] = False  # the lower half: table, arm and cube
    rgb = res["table_color=1"]["params"]["table_color.rgb"]
    assert _cosine_to(_img(res, "table_color=1"), table, rgb) > _cosine_to(nominal, table, rgb) + 0.05
    assert np.abs(_img(res, "background=1") - nominal)[: nominal.shape[0] // 4].mean() > 5  # the floor behind
    texture, fov = res["errors"]
    assert texture.startswith("perturb.texture: not available on ManiSkill/SAPIEN")
    assert "perturb.camera_fov.cameras: 'hand_camera' is not among the rendered cameras" in fov

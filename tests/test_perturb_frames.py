"""Image-noise axes (bench.sims.perturb.frames) on a real simulator's rendered frames (Gymnasium HalfCheetah,
obs=state+rgb, EGL): each corrupts what the policy sees as its level says, per episode generator, and leaves
the state alone; the nominal level changes nothing; envs and policies without images are refused in one line.
Also: an axis is one row — a row added at run time works through the grammar, validation and apply."""

from __future__ import annotations

import numpy as np
import pytest

from bench import api
from bench.core.errors import ConfigError
from bench.protocols.suite import NOMINAL, Condition, condition_rng
from bench.sims import perturb
from bench.sims.perturb import axes, frames
from bench.sims.perturb.axis import Axis

pytest.importorskip("gymnasium")

FRAME_AXES = [a.name for a in frames.ROWS]


@pytest.fixture(scope="module")
def cheetah():
    p = api.plan(
        api.config_from_argv(["suite=gym", "env_id=HalfCheetah-v5", "obs=state+rgb", "image_size=32", "policy=random"])
    )
    env = p.suite.make_env(p.cells[0], 5)
    yield env
    env.close()


def _first(env, axis: str, level, seed: int = 7):
    c = Condition(name=f"{axis}={level}", axis=axis, level=level, spec={"kind": "grid", "targets": {}})
    stepper, params = perturb.apply(env, c, condition_rng(seed, c))
    obs = stepper.reset(seed)
    return obs, params, stepper


@pytest.mark.parametrize(
    "axis,level",
    [("image_noise", 0.1), ("shot_noise", 0.1), ("salt_pepper", 0.05), ("motion_blur", 7), ("jpeg_quality", 5)],
)
def test_each_image_axis_corrupts_the_frames_the_policy_sees_not_the_state(cheetah, axis, level):
    zero = np.zeros(cheetah.action_spec.dim, np.float32)
    perturb.apply(cheetah, NOMINAL, condition_rng(7, NOMINAL))
    nominal = [cheetah.reset(7), cheetah.step(zero)[0]]
    obs, params, stepper = _first(cheetah, axis, level)
    assert params[axis] == level
    seen = [obs, stepper.step(zero)[0]]  # every observation, not only the first
    for got, ref in zip(seen, nominal):
        np.testing.assert_array_equal(got["state"], ref["state"])
        assert got["rgb.track"].shape == ref["rgb.track"].shape and got["rgb.track"].dtype == np.uint8
        assert np.abs(got["rgb.track"].astype(int) - ref["rgb.track"]).mean() > 0.5, axis
    again, _, _ = _first(cheetah, axis, level)  # the same episode generator: the same frames
    np.testing.assert_array_equal(again["rgb.track"], obs["rgb.track"])


def test_levels_mean_what_the_docs_say(cheetah):
    gray = np.full((64, 64, 3), 128, np.uint8)
    white = np.full((64, 64, 3), 255, np.uint8)
    rng = np.random.default_rng(0)
    assert abs(frames._gaussian(0.1)(gray, rng).astype(float).std() - 25.5) < 2.0  # std 0.1 of full scale
    dark = np.full((64, 64, 3), 64, np.uint8)  # Poisson: variance = mean, so std = level * sqrt(x * 255)
    assert abs(frames._shot(0.1)(dark, rng).astype(float).std() - 0.1 * np.sqrt(64 * 255)) < 0.5
    shot = frames._shot(0.1)(white, rng).astype(float)
    assert abs(shot[shot < 255].size / shot.size - 0.5) < 0.1  # clipped above white: half the pixels below it
    hit = frames._salt_pepper(0.2)(gray, rng)
    assert abs(np.mean(np.any(hit != 128, axis=-1)) - 0.2) < 0.02 and set(np.unique(hit)) == {0, 128, 255}
    edge = np.zeros((32, 32, 3), np.uint8)
    edge[:, 16:] = 255
    blurred = frames._motion_blur(9, 0.0)(edge, rng)  # a horizontal blur smears a vertical edge
    assert 0 < blurred[0, 14, 0] < 255 and blurred[0, 0, 0] == 0
    img = cheetah.reset(3)["rgb.track"]
    errs = [np.abs(frames._jpeg(q)(img, rng).astype(int) - img).mean() for q in (90, 30, 5)]
    assert errs[0] < errs[1] < errs[2]


@pytest.mark.parametrize("axis,level", [("image_noise", 0.0), ("jpeg_quality", 100), ("motion_blur", 1)])
def test_the_nominal_level_changes_nothing(cheetah, axis, level):
    obs, _, stepper = _first(cheetah, axis, level)
    assert stepper is cheetah
    np.testing.assert_array_equal(obs["rgb.track"], cheetah.reset(7)["rgb.track"])


def test_image_axes_are_refused_without_images():
    p = api.plan(api.config_from_argv(["suite=gym", "env_id=HalfCheetah-v5", "policy=random"]))
    env = p.suite.make_env(p.cells[0], 5)
    try:
        with pytest.raises(
            ConfigError, match=r"^perturb.image_noise changes only camera images, and .* gives the policy none"
        ):
            perturb.validate(env, axes.conditions_from_config({"image_noise": [0.1]})[1:], "HalfCheetah-v5")
    finally:
        env.close()
    with pytest.raises(
        ConfigError, match=r"perturb.jpeg_quality changes only camera images, and policy 'zero' reads none"
    ):
        axes.check_policy_sees(axes.conditions_from_config({"jpeg_quality": [20]}), ("state",), {"state": None}, "zero")
    with pytest.raises(ConfigError, match=r"perturb.jpeg_quality: 0 is invalid; .* must be >= 1"):
        axes.conditions_from_config({"jpeg_quality": [0]})


def test_an_axis_is_one_row(cheetah, monkeypatch):
    """A row with a selection and an edit is all a new model axis needs: the grammar, --help, validation and
    apply read it; nothing dispatches on its name."""

    def select(mj, named, field, where):
        return np.arange(mj.model.njnt)

    def scale(model, nominal, idx, s):
        model.jnt_stiffness[idx] = nominal["jnt_stiffness"][idx] * s + 1e-3 * (s != 1)

    row = Axis(
        "stiffness",
        "model",
        "scale of nominal",
        "joint stiffness",
        "joint stiffness",
        fields=("jnt_stiffness",),
        select=select,
        scale=scale,
    )
    monkeypatch.setitem(axes.AXES, "stiffness", row)
    assert "stiffness" in axes.axes_help()
    conds = axes.conditions_from_config({"stiffness": [3.0]})
    mj = cheetah.mujoco
    before = np.array(mj.model.jnt_stiffness, copy=True)
    perturb.validate(cheetah, conds[1:], "HalfCheetah-v5")
    _, params = perturb.apply(cheetah, conds[1], np.random.default_rng(0))
    assert params == {"stiffness": 3.0}
    assert not np.array_equal(mj.model.jnt_stiffness, before)
    perturb.apply(cheetah, conds[0], np.random.default_rng(0))  # nominal restores it
    np.testing.assert_array_equal(mj.model.jnt_stiffness, before)

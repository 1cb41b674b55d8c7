"""Suites aloha and pusht (lerobot's simulated tasks): the same starts, observations and physics as gym-aloha and
gym-pusht themselves, declared held-out scenes, the scripted experts, and bench's own checks on them."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from bench.api import RunConfig
from bench.cli import main
from bench.core.errors import ConfigError
from bench.protocols.suite import episode_seed, select_cells
from bench.records import read_records

# gym-aloha renders its top camera in every observation, and dm_control picks its OpenGL backend when imported: EGL
# unless the caller chose one (run alone, nothing else in the session has set it; conftest's default is `disable`)
os.environ.setdefault("MUJOCO_GL", "egl")
gym = pytest.importorskip("gymnasium")
pytest.importorskip("gym_aloha", reason="suite aloha needs the lerobot-sims extra: pip install -e '.[lerobot-sims]'")
pytest.importorskip("gym_pusht", reason="suite pusht needs the lerobot-sims extra: pip install -e '.[lerobot-sims]'")

from suites import aloha, pusht  # noqa: E402

TRANSFER = "AlohaTransferCube-v0"


def _cell(suite, task: str, env: str):
    return next(c for c in suite.all_cells() if c.task == task and c.env == env)


def _gym_aloha(task: str):
    import gym_aloha  # noqa: F401  (registers the ids)

    return gym.make(f"gym_aloha/{task}", obs_type="pixels_agent_pos", disable_env_checker=True)


@pytest.mark.parametrize("task", list(aloha.TASKS), ids=str)
def test_aloha_steps_exactly_as_gym_aloha(task):
    """Same seed, same actions: agent_pos, env_state, reward and termination equal gym-aloha's (40 steps)."""
    suite = aloha.Aloha()
    env = suite.make_env(_cell(suite, task, "nominal"), 40)
    ref = _gym_aloha(task)
    try:
        rng = np.random.default_rng(0)
        for seed in (3, 1234567):
            obs = env.reset(seed)
            ref_obs, _ = ref.reset(seed=seed)
            assert np.array_equal(obs["state"][:14], ref_obs["agent_pos"].astype(np.float32))
            physics = ref.unwrapped._env.physics
            assert np.array_equal(obs["state"][14:], physics.data.qpos[16:].astype(np.float32))  # the objects' start
            assert obs["task"] == aloha.TASKS[task].instruction
            for _ in range(40):
                action = (obs["state"][:14] + rng.normal(0, 0.05, 14)).astype(np.float32)
                obs, reward, terminated, _, _ = env.step(action)
                ref_obs, ref_reward, ref_terminated, _, _ = ref.step(action)
                assert np.array_equal(obs["state"][:14], ref_obs["agent_pos"].astype(np.float32))
                assert reward == ref_reward and terminated == ref_terminated
    finally:
        env.close()
        ref.close()


def test_aloha_top_camera_is_gym_aloha_image():
    """obs=state+rgb: rgb.top is bit-identical to the 480 x 640 image gym-aloha gives lerobot."""
    suite = aloha.Aloha(aloha.AlohaOptions(obs="state+rgb"))
    cell = _cell(suite, TRANSFER, "nominal")
    assert suite.obs_spec(cell)["rgb.top"].shape == (480, 640, 3)
    env = suite.make_env(cell, 5)
    ref = _gym_aloha(TRANSFER)
    try:
        obs = env.reset(7)
        ref_obs, _ = ref.reset(seed=7)
        assert np.array_equal(obs["rgb.top"], ref_obs["pixels"]["top"])
        action = obs["state"][:14] + 0.1
        obs, *_ = env.step(action)
        ref_obs, *_ = ref.step(action.astype(np.float32))
        assert np.array_equal(obs["rgb.top"], ref_obs["pixels"]["top"])
    finally:
        env.close()
        ref.close()


def test_aloha_scenes_scale_the_model_and_split_by_region():
    suite = aloha.Aloha()
    assert set(suite.manifest["envs"]["seen"]).isdisjoint(suite.manifest["envs"]["unseen"])
    for name, levels in aloha.SEEN_SCENES.items():
        assert aloha.in_seen_region(levels), name
    for name, levels in aloha.UNSEEN_SCENES.items():
        assert not aloha.in_seen_region(levels), name
    nominal = suite.make_env(_cell(suite, TRANSFER, "nominal"), 10)
    heavy = suite.make_env(_cell(suite, TRANSFER, "heavy_object"), 10)
    weak = suite.make_env(_cell(suite, TRANSFER, "weak_servos"), 10)
    try:
        box = nominal.mujoco.model.body("box").id
        assert heavy.mujoco.model.body_mass[box] == pytest.approx(4 * nominal.mujoco.model.body_mass[box])
        assert np.allclose(
            heavy.mujoco.model.body_mass[:box], nominal.mujoco.model.body_mass[:box]
        )  # arms as they were
        assert np.allclose(weak.mujoco.model.actuator_gainprm[:, 0], 0.4 * nominal.mujoco.model.actuator_gainprm[:, 0])
        assert np.allclose(weak.mujoco.model.actuator_biasprm[:, 1], 0.4 * nominal.mujoco.model.actuator_biasprm[:, 1])
    finally:
        for e in (nominal, heavy, weak):
            e.close()


def test_set_nominal_refuses_a_non_model_axis_and_a_used_env():
    from bench.api.sims import set_nominal
    from bench.sims import perturb

    suite = aloha.Aloha()
    env = suite.make_env(_cell(suite, TRANSFER, "nominal"), 10)
    try:
        with pytest.raises(ConfigError, match="'latency' is a interface axis"):
            set_nominal(env.mujoco, {"latency": 2})
        perturb.nominal_of(env.mujoco)  # what the first episode does
        with pytest.raises(RuntimeError, match="before its first episode"):
            set_nominal(env.mujoco, {"mass": 2.0})
    finally:
        env.close()


def test_aloha_visual_axes_change_the_image_only():
    from bench.sims import perturb
    from bench.sims.perturb.axes import conditions_from_config

    suite = aloha.Aloha(aloha.AlohaOptions(obs="state+rgb", image_size=[48, 64]))
    env = suite.make_env(_cell(suite, TRANSFER, "nominal"), 2)
    try:
        nominal, dim, red_table = conditions_from_config({"light": [0.3], "table_color": [1.0]})
        rng = np.random.default_rng(0)
        images, states = [], []
        for cond in (nominal, dim, red_table):
            stepper, _ = perturb.apply(env, cond, rng)
            obs = stepper.reset(1)
            images.append(obs["rgb.top"].astype(float))
            states.append(obs["state"])
        assert images[1].mean() < images[0].mean() - 5  # dimmer
        assert np.abs(images[2] - images[0]).mean() > 1  # another table colour
        assert all(np.array_equal(s, states[0]) for s in states)  # the physics is untouched
    finally:
        env.close()


def test_aloha_unknown_task_lists_the_valid_ones():
    suite = aloha.Aloha()
    with pytest.raises(ConfigError, match="tasks: 'AlohaTransferCub-v0' is not in suite 'aloha'.*AlohaTransferCube-v0"):
        select_cells(suite, RunConfig(tasks=["AlohaTransferCub-v0"]))


def run_records(out: Path, run_id: str, *keys: str) -> list:
    """The records of `bench run KEYS` (run `run_id` in `out`; asserts it exits 0)."""
    assert main(["run", *keys, f"out={out}", f"run_id={run_id}"]) == 0
    return read_records(out / run_id / "episodes.jsonl")


def test_aloha_expert_and_perturbed_run_through_bench(tmp_path, capsys):
    """policy=scripted on transfer-cube, nominal and one held-out scene, plus a mass perturbation: all succeed;
    `bench check` finds nothing wrong with the suite."""
    assert main(["check", "suite=aloha"]) == 0
    out = tmp_path / "runs"
    keys = ["suite=aloha", f"tasks=[{TRANSFER}]", "envs=[nominal,slippery]", "policy=scripted", "episodes=2"]
    records = run_records(out, "x", *keys, "workers=1", "perturb.mass=[2]")
    assert len(records) == 8 and all(r.error is None for r in records)
    assert all(r.success_once for r in records), [(r.env, r.condition, r.success_once) for r in records]
    assert {r.split for r in records} == {"seen", "unseen"}
    assert all(r.length < 400 for r in records)  # the episode ends at success, as gym-aloha's does
    summary = json.loads((out / "x" / "summary.json").read_text())
    assert summary["suite"]["name"] == "aloha"


def test_consecutive_seeds_are_lerobot_evals(tmp_path):
    """seed_scheme=consecutive: episode i of seed=S starts from seed S + i (lerobot-eval's --seed)."""
    out = tmp_path / "runs"
    base = ["run", "suite=pusht", "envs=[nominal]", "policy=random", "episodes=3", "horizon=5", "workers=1"]
    consecutive = run_records(out, "c", *base[1:], "seed=1000", "seed_scheme=consecutive")
    assert sorted(r.seed for r in consecutive) == [1000, 1001, 1002]
    hashed = run_records(out, "h", *base[1:], "seed=1000")
    assert sorted(r.seed for r in hashed) == sorted(episode_seed(1000, e) for e in range(3))
    assert main([*base, "seed_scheme=lerobot", f"out={out}", "run_id=bad"]) == 2
    assert main([*base, f"seed={2**32 - 2}", "seed_scheme=consecutive", f"out={out}", "run_id=bad"]) == 2
    assert not (out / "bad").exists()


def test_pusht_matches_gym_pusht_and_its_scenes():
    import gym_pusht  # noqa: F401  (registers the id)

    suite = pusht.PushT()
    env = suite.make_env(_cell(suite, "PushT-v0", "nominal"), 30)
    ref = gym.make("gym_pusht/PushT-v0", obs_type="environment_state_agent_pos", disable_env_checker=True)
    try:
        obs = env.reset(5)
        ref_obs, _ = ref.reset(seed=5)
        assert np.array_equal(
            obs["state"], np.concatenate([ref_obs["agent_pos"], ref_obs["environment_state"]]).astype(np.float32)
        )
        for t in range(30):
            action = np.array([100 + 10 * t, 300.0], np.float32)
            obs, reward, *_ = env.step(action)
            ref_obs, ref_reward, *_ = ref.step(action)
            assert reward == ref_reward
        assert np.array_equal(obs["state"][2:], ref_obs["environment_state"].astype(np.float32))
    finally:
        env.close()
        ref.close()
    for name in {**pusht.SEEN_SCENES, **pusht.UNSEEN_SCENES}:
        assert pusht.in_seen_region(pusht.scene_params(name)) == (name in pusht.SEEN_SCENES), name
    big = suite.make_env(_cell(suite, "PushT-v0", "big_block"), 5)
    moved = suite.make_env(_cell(suite, "PushT-v0", "goal_moved"), 5)
    try:
        big.reset(0)
        moved.reset(0)
        assert np.ptp(big.local_keypoints[:, 0]) == pytest.approx(1.3 * 120)  # the T's bar: 120 px at scale 1
        assert moved.goal.tolist() == pusht.UNSEEN_SCENES["goal_moved"]["goal"]
    finally:
        big.close()
        moved.close()


def test_pusht_images_and_recolouring():
    suite = pusht.PushT(pusht.PushTOptions(obs="state+rgb"))
    nominal = suite.make_env(_cell(suite, "PushT-v0", "nominal"), 5)
    recoloured = suite.make_env(_cell(suite, "PushT-v0", "recoloured"), 5)
    try:
        a, b = nominal.reset(2), recoloured.reset(2)
        assert a["rgb.top"].shape == (96, 96, 3) and a["rgb.top"].dtype == np.uint8
        assert np.array_equal(a["state"], b["state"])  # the same physics ...
        assert not np.array_equal(a["rgb.top"], b["rgb.top"])  # ... drawn in other colours
    finally:
        nominal.close()
        recoloured.close()
    with pytest.raises(ConfigError, match="obs: 'pixels' is not an observation mode"):
        pusht.PushT(pusht.PushTOptions(obs="pixels"))


def test_pusht_expert_moves_the_block_towards_the_goal(tmp_path):
    """The pushing controller covers part of the goal zone (its success rate is measured in the README)."""
    records = run_records(
        tmp_path / "runs", "p", "suite=pusht", "envs=[nominal]", "policy=scripted", "episodes=4", "workers=1"
    )
    assert all(r.error is None for r in records)
    assert max(r.return_ for r in records) > 30  # summed coverage / 0.95 over 300 steps; a still agent scores ~0

"""Parity with lerobot-eval (slow; lerobot's side venv): the same policy, seeds and nominal environment give the
same per-episode successes and rewards in bench as in `lerobot-eval` itself.

A tiny ACT is trained by lerobot's training script on bench recordings, then evaluated twice from the side venv:
by `lerobot-eval` and by `baselines/lerobot_eval.py` with lerobot-eval's own flags (the one-command move to
bench: it serves the policy and runs `bench run ... policy=remote seed_scheme=consecutive`). PushT with a
state policy (continuous rewards: the summed coverage must agree to float precision), ALOHA transfer-cube with
an image policy (the 480 x 640 `top` camera; rewards are gym-aloha's contact stages). Budgets: a few recorded
episodes, 100 (PushT) / 4 (ALOHA) training steps, 3 / 2 evaluated episodes of 100 / 30 steps.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from bench.records import read_records
from tests.lerobot_side import ONE_COMMAND, as_lerobot_sims, side, train

EGL = "egl"  # MUJOCO_GL in the side venv: lerobot-eval renders its envs headless


def both(py: str, tmp: Path, policy: Path, flags: list[str]) -> tuple[dict, list]:
    """lerobot-eval's per-episode metrics, and bench's records of the same command."""
    side(
        py,
        "-m",
        "lerobot.scripts.lerobot_eval",
        f"--policy.path={policy}",
        *flags,
        f"--output_dir={tmp / 'le'}",
        mujoco_gl=EGL,
    )
    metrics = json.loads((tmp / "le" / "eval_info.json").read_text())["per_task"][0]["metrics"]
    bench = Path(sys.executable).parent / "bench"  # bench's own executable, beside the Python running the tests
    out = side(
        py,
        str(ONE_COMMAND),
        f"--policy.path={policy}",
        *flags,
        f"--bench={bench}",
        f"out={tmp}",
        "run_id=bench",
        mujoco_gl=EGL,
    )
    assert "seed_scheme=consecutive" in out and "policy=remote" in out
    records = sorted(read_records(tmp / "bench" / "episodes.jsonl"), key=lambda r: r.episode)
    assert all(r.error is None for r in records), [r.error for r in records]
    return metrics, records


@pytest.mark.slow
def test_pusht_state_act_same_episodes_as_lerobot_eval(lerobot_python, tmp_path):
    policy, _ = train(
        lerobot_python,
        tmp_path,
        ["run", "suite=pusht", "envs=[nominal]", "policy=scripted", "episodes=4"],
        as_lerobot_sims("env_state"),
        steps=100,
        batch=8,
        mujoco_gl=EGL,
    )
    flags = [
        "--env.type=pusht",
        "--env.obs_type=environment_state_agent_pos",
        "--env.episode_length=100",
        "--eval.n_episodes=3",
        "--eval.batch_size=1",
        "--seed=1000",
        "--policy.device=cpu",
    ]
    metrics, records = both(lerobot_python, tmp_path, policy, flags)
    assert [r.seed for r in records] == [1000, 1001, 1002]
    assert [r.success_once for r in records] == metrics["successes"]
    assert [r.return_ for r in records] == pytest.approx(metrics["sum_rewards"], rel=1e-9, abs=1e-9)
    assert sum(metrics["sum_rewards"]) > 0  # the block moved: the comparison is not one of idle episodes


@pytest.mark.slow
def test_aloha_image_act_same_episodes_as_lerobot_eval(lerobot_python, tmp_path):
    policy, _ = train(
        lerobot_python,
        tmp_path,
        [
            "run",
            "suite=aloha",
            "tasks=[AlohaTransferCube-v0]",
            "envs=[nominal]",
            "policy=scripted",
            "obs=state+rgb",
            "episodes=2",
            "horizon=30",
        ],
        as_lerobot_sims(""),
        steps=4,
        batch=2,
        mujoco_gl=EGL,
    )
    config = json.loads((policy / "config.json").read_text())
    assert set(config["input_features"]) == {"observation.state", "observation.images.top"}
    assert config["input_features"]["observation.images.top"]["shape"] == [3, 480, 640]
    flags = [
        "--env.type=aloha",
        "--env.task=AlohaTransferCube-v0",
        "--env.episode_length=30",
        "--eval.n_episodes=2",
        "--eval.batch_size=1",
        "--seed=7",
        "--policy.device=cpu",
    ]
    metrics, records = both(lerobot_python, tmp_path, policy, flags)
    assert [r.seed for r in records] == [7, 8]
    assert [r.success_once for r in records] == metrics["successes"]
    assert [r.return_ for r in records] == pytest.approx(metrics["sum_rewards"], abs=1e-9)
    assert [r.length for r in records] == [30, 30]

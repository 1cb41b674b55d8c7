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
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bench.cli import main
from bench.records import read_records

REPO = Path(__file__).resolve().parents[1]
ADAPTER = REPO / "baselines" / "lerobot_adapter.py"
ONE_COMMAND = REPO / "baselines" / "lerobot_eval.py"
TINY_ACT = [
    "--policy.type=act",
    "--policy.device=cpu",
    "--policy.push_to_hub=false",
    "--policy.dim_model=32",
    "--policy.n_heads=2",
    "--policy.dim_feedforward=64",
    "--policy.n_encoder_layers=1",
    "--policy.n_decoder_layers=1",
    "--policy.use_vae=false",
    "--policy.chunk_size=8",
    "--policy.n_action_steps=8",
    "--policy.pretrained_backbone_weights=null",
    "--num_workers=0",
    "--eval_freq=0",
    "--wandb.enable=false",
    "--seed=0",
]


@pytest.fixture(scope="module")
def lerobot_python() -> str:
    py = os.environ.get("BENCH_LEROBOT_PYTHON", "")
    if not py:
        pytest.skip(
            "BENCH_LEROBOT_PYTHON is not set: lerobot lives in a side venv; build it with "
            "`bash .ci/lerobot-venv.sh` and set BENCH_LEROBOT_PYTHON=.lerobot-venv/bin/python"
        )
    if not Path(py).exists():
        pytest.fail(f"BENCH_LEROBOT_PYTHON={py} does not exist")
    return py


def side(py: str, *args: str, timeout: int = 900) -> str:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "MUJOCO_GL": "egl"}
    res = subprocess.run([py, *args], cwd=REPO, capture_output=True, text=True, timeout=timeout, env=env)
    assert res.returncode == 0, (res.stdout[-3000:], res.stderr[-3000:])
    return res.stdout


def train(py: str, tmp: Path, record_argv: list[str], env_fields: str, steps: int, batch: int) -> Path:
    """Record with bench, prepare for lerobot (observation.state = agent_pos, as lerobot's envs give it), train."""
    assert main([*record_argv, f"out={tmp}", "run_id=rec", f"record={tmp / 'demos'}", "workers=1"]) == 0
    side(
        py,
        str(ADAPTER),
        "prepare",
        str(tmp / "demos"),
        str(tmp / "lr"),
        f"--env-fields={env_fields}",
        "--state-fields=agent_pos",
    )
    side(
        py,
        "-m",
        "lerobot.scripts.lerobot_train",
        "--dataset.repo_id=bench/lr",
        f"--dataset.root={tmp / 'lr'}",
        f"--output_dir={tmp / 'act'}",
        *TINY_ACT,
        f"--batch_size={batch}",
        f"--steps={steps}",
        f"--save_freq={steps}",
        f"--log_freq={steps}",
    )
    policy = tmp / "act" / "checkpoints" / "last" / "pretrained_model"
    assert (policy / "model.safetensors").is_file()
    return policy


def both(py: str, tmp: Path, policy: Path, flags: list[str]) -> tuple[dict, list]:
    """lerobot-eval's per-episode metrics, and bench's records of the same command."""
    side(py, "-m", "lerobot.scripts.lerobot_eval", f"--policy.path={policy}", *flags, f"--output_dir={tmp / 'le'}")
    metrics = json.loads((tmp / "le" / "eval_info.json").read_text())["per_task"][0]["metrics"]
    bench = Path(sys.executable).parent / "bench"  # bench's own executable, beside the Python running the tests
    out = side(
        py, str(ONE_COMMAND), f"--policy.path={policy}", *flags, f"--bench={bench}", f"out={tmp}", "run_id=bench"
    )
    assert "seed_scheme=consecutive" in out and "policy=remote" in out
    records = sorted(read_records(tmp / "bench" / "episodes.jsonl"), key=lambda r: r.episode)
    assert all(r.error is None for r in records), [r.error for r in records]
    return metrics, records


@pytest.mark.slow
def test_pusht_state_act_same_episodes_as_lerobot_eval(lerobot_python, tmp_path):
    policy = train(
        lerobot_python,
        tmp_path,
        ["run", "suite=pusht", "envs=[nominal]", "policy=scripted", "episodes=4"],
        "env_state",
        steps=100,
        batch=8,
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
    policy = train(
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
        "",
        steps=4,
        batch=2,
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

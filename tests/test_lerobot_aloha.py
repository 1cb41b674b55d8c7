"""A lerobot ACT trained on the ALOHA suite, served to `policy=remote` (slow; lerobot's side venv).

bench's scripted expert records transfer-cube demonstrations (`record=`); lerobot's dataset tool (through
`baselines/lerobot_adapter.py prepare`) makes observation.state the 14 joint values lerobot's ALOHA policies
read and observation.environment_state the cube's pose; lerobot's own training script trains a tiny ACT; the
adapter serves it and `bench run suite=aloha policy=remote` evaluates it on a seen and a held-out scene under a
perturbation. A checkpoint whose input features the observation does not match is refused in one line before
any episode, and so is an unknown task. Budget: 3 recorded episodes, 60 training steps, 4 episodes of 40 steps.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from bench.cli import main
from bench.records import read_records
from tests.lerobot_side import ONE_COMMAND, REPO, SIDE_ENV, as_lerobot_sims, served, train

TASK = "AlohaTransferCube-v0"
OBS_MAP = "obs_map=[observation.state:state.agent_pos,observation.environment_state:state.env_state]"


@pytest.mark.slow
def test_act_trained_on_aloha_runs_through_policy_remote(lerobot_python, tmp_path, capsys):
    policy, _ = train(
        lerobot_python,
        tmp_path,
        ["run", "suite=aloha", f"tasks=[{TASK}]", "envs=[nominal]", "policy=scripted", "episodes=3"],
        as_lerobot_sims("env_state"),
        steps=60,
        batch=8,
        mujoco_gl="egl",
    )
    err_log = tmp_path / "adapter.err"
    with served(lerobot_python, policy, err_log) as (proc, port):
        base = ["run", "suite=aloha", f"tasks=[{TASK}]", "policy=remote", f"port={port}", "timeout_s=120", "workers=1"]
        base += [f"out={tmp_path}"]
        argv = [*base, "envs=[nominal,slippery]", "episodes=1", "horizon=40", "replan_every=8"]
        assert main([*argv, "perturb.friction=[0.5]", OBS_MAP, "run_id=remote"]) == 0
        records = read_records(tmp_path / "remote" / "episodes.jsonl")
        assert len(records) == 4 and all(r.error is None for r in records), [r.error for r in records]
        assert {(r.env, r.split, r.condition) for r in records} == {
            (e, s, c) for e, s in (("nominal", "seen"), ("slippery", "unseen")) for c in ("nominal", "friction=0.5")
        }
        assert all(r.extras["policy"]["requests"] >= 1 for r in records)
        assert records[0].checkpoint_sha256 and len(records[0].checkpoint_sha256) == 64
        capsys.readouterr()

        # the checkpoint's observation.state is 14 joint values: the whole state (21) is refused before any episode
        assert (
            main(
                [*argv, "obs_map=[observation.state:state,observation.environment_state:state.env_state]", "run_id=bad"]
            )
            == 2
        )
        err = capsys.readouterr().err
        assert "input feature 'observation.state'" in err and "[14]" in err and "[21]" in err, err
        assert not (tmp_path / "bad").exists()
        # ... and a feature it needs that the map does not send
        assert main([*argv, "obs_map=[observation.state:state.agent_pos]", "run_id=bad"]) == 2
        err = capsys.readouterr().err
        assert "input feature 'observation.environment_state'" in err and "is not in the observation" in err, err
        assert not (tmp_path / "bad").exists()
    log = err_log.read_text()
    assert proc.returncode == 0 and "Traceback" not in log, log[-2000:]

    # the one-command move from lerobot-eval: an unknown task lists the valid ones, nothing runs
    res = subprocess.run(
        [
            lerobot_python,
            str(ONE_COMMAND),
            f"--policy.path={policy}",
            "--env.type=aloha",
            "--env.task=AlohaTransfer-v0",
            f"--bench={Path(sys.executable).parent / 'bench'}",  # bench beside the tests' Python, wherever its venv is
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        env={**os.environ, **SIDE_ENV},
        timeout=300,
    )
    assert res.returncode == 2, res.stderr[-2000:]
    assert (
        "--env.task='AlohaTransfer-v0': not a task of aloha; valid: AlohaTransferCube-v0, AlohaInsertion-v0"
        in res.stderr
    )

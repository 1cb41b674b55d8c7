"""A lerobot policy evaluated by bench over the remote-policy protocol, end to end (slow; lerobot's side venv).

bench records Lift demonstrations on Panda; lerobot's own dataset tool and training script (in the side venv
built by `.ci/lerobot-venv.sh`, BENCH_LEROBOT_PYTHON) train a tiny ACT on them; `baselines/lerobot_adapter.py`
serves it; `bench run suite=held_out_robots policy=remote` and `bench actions policy=remote` evaluate it. Budget:
4 recorded episodes of 60 steps, 60 training steps of an 80k-parameter model, 1 evaluation episode.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest

from bench.cli import main
from bench.records import read_records

REPO = Path(__file__).resolve().parents[1]
ADAPTER = REPO / "baselines" / "lerobot_adapter.py"
OBS_MAP = (
    "obs_map=[observation.state:state,"
    "observation.environment_state:state.object_pos+state.object_quat+state.gripper_to_object]"
)
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
    "--batch_size=8",
    "--steps=60",
    "--num_workers=0",
    "--save_freq=60",
    "--log_freq=20",
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


def wait_for_line(proc: subprocess.Popen, marker: str, timeout: float) -> str:
    """The first stdout line of `proc` containing `marker` (other lines, e.g. lerobot's own prints, are skipped)."""
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout] + [lines.put(None)], daemon=True).start()
    deadline, seen = time.monotonic() + timeout, []
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=max(0.01, deadline - time.monotonic()))
        except queue.Empty:
            break
        if line is None:
            break
        seen.append(line)
        if marker in line:
            return line
    proc.kill()
    proc.wait()
    pytest.fail(f"no {marker!r} line within {timeout:g} s; stdout: {seen[-5:]}")


def _side(py: str, *args: str, timeout: int = 600) -> str:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    res = subprocess.run([py, *args], cwd=REPO, capture_output=True, text=True, timeout=timeout, env=env)
    assert res.returncode == 0, (res.stdout[-2000:], res.stderr[-3000:])
    return res.stdout


@pytest.mark.slow
def test_lerobot_act_trained_on_bench_data_runs_through_policy_remote(lerobot_python, tmp_path, capsys):
    demos, prepared, run_dir = tmp_path / "demos", tmp_path / "demos_lerobot", tmp_path / "act"
    assert (
        main(
            [
                "run",
                "suite=held_out_robots",
                "policy=scripted",
                "robots=[Panda]",
                "episodes=4",
                "horizon=60",
                "workers=1",
                f"out={tmp_path}",
                "run_id=rec",
                f"record={demos}",
            ]
        )
        == 0
    )
    out = _side(lerobot_python, str(ADAPTER), "prepare", str(demos), str(prepared))
    assert "observation.environment_state = object_pos_0" in out
    _side(
        lerobot_python,
        "-m",
        "lerobot.scripts.lerobot_train",
        "--dataset.repo_id=bench/demos_lerobot",
        f"--dataset.root={prepared}",
        f"--output_dir={run_dir}",
        *TINY_ACT,
    )
    policy_dir = run_dir / "checkpoints" / "last" / "pretrained_model"
    assert (policy_dir / "model.safetensors").is_file()

    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
    err_log = tmp_path / "adapter.err"  # a file, not a pipe: a full pipe would block the server
    proc = subprocess.Popen(
        [lerobot_python, str(ADAPTER), "serve", str(policy_dir), "--port", "0"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=err_log.open("w"),
        text=True,
        env=env,
    )
    try:
        line = wait_for_line(proc, "lerobot adapter: act policy", timeout=300)
        assert "ws://127.0.0.1:" in line, line
        port = int(line.split("ws://127.0.0.1:")[1].split(" ")[0])
        capsys.readouterr()
        assert (
            main(
                [
                    "run",
                    "suite=held_out_robots",
                    "policy=remote",
                    f"port={port}",
                    "timeout_s=60",
                    "robots=[Panda]",
                    "episodes=1",
                    "horizon=40",
                    "replan_every=4",
                    "workers=1",
                    OBS_MAP,
                    f"out={tmp_path}",
                    "run_id=remote",
                ]
            )
            == 0
        )
        records = read_records(tmp_path / "remote" / "episodes.jsonl")
        assert len(records) == 1 and records[0].error is None and records[0].length == 40
        stats = records[0].extras["policy"]
        assert stats["requests"] == 10 and stats["rtt_ms"]["p50"] > 0 and stats["server_ms"]["p50"] > 0
        assert records[0].checkpoint_sha256 and len(records[0].checkpoint_sha256) == 64  # the served weights
        # policy on logs with the same served policy (its first action of each chunk vs the logged one)
        assert (
            main(
                [
                    "actions",
                    f"logs={demos}",
                    "policy=remote",
                    f"port={port}",
                    "timeout_s=60",
                    OBS_MAP,
                    f"out={tmp_path / 'actions.json'}",
                ]
            )
            == 0
        )
        assert "round trips: 240" in capsys.readouterr().out
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=60)
    log = err_log.read_text()
    assert proc.returncode == 0 and "disconnected after" in log and "Traceback" not in log, log[-2000:]

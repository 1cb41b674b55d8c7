"""Driving lerobot's side venv from bench's tests (BENCH_LEROBOT_PYTHON, built by `.ci/lerobot-venv.sh`; the
`lerobot_python` fixture in conftest.py): running its scripts, training a tiny ACT on bench recordings with
lerobot's own training script, and serving a policy with `baselines/lerobot_adapter.py`.

Runs in bench's environment; `tests/lerobot_load.py` and `tests/lerobot_write.py` are what runs inside the side
venv.
"""

from __future__ import annotations

import contextlib
import os
import queue
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from bench.cli import main

REPO = Path(__file__).resolve().parents[1]
ADAPTER = REPO / "baselines" / "lerobot_adapter.py"
ONE_COMMAND = REPO / "baselines" / "lerobot_eval.py"
# the side venv offline and on one thread (a CPU torch on a machine shared with the test workers)
SIDE_ENV = {"HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
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


def side(py: str, *args: str, timeout: int = 900, mujoco_gl: str | None = None) -> str:
    """Run `py args...` in the side venv from the repository root; its stdout (asserts it exits 0)."""
    env = {**os.environ, **SIDE_ENV, **({"MUJOCO_GL": mujoco_gl} if mujoco_gl else {})}
    res = subprocess.run([py, *args], cwd=REPO, capture_output=True, text=True, timeout=timeout, env=env)
    assert res.returncode == 0, (res.stdout[-3000:], res.stderr[-3000:])
    return res.stdout


def train(
    py: str,
    tmp: Path,
    record_argv: list[str],
    prepare: list[str],
    steps: int,
    batch: int,
    mujoco_gl: str | None = None,
) -> tuple[Path, str]:
    """Record with bench (`record_argv` + record=tmp/demos), prepare the recording for lerobot
    (`lerobot_adapter.py prepare` with the flags `prepare`) and train a tiny ACT on it with lerobot's
    training script: the trained policy's folder, and what `prepare` printed."""
    assert main([*record_argv, f"out={tmp}", "run_id=rec", f"record={tmp / 'demos'}", "workers=1"]) == 0
    prepared = side(py, str(ADAPTER), "prepare", str(tmp / "demos"), str(tmp / "lr"), *prepare, mujoco_gl=mujoco_gl)
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
        mujoco_gl=mujoco_gl,
    )
    policy = tmp / "act" / "checkpoints" / "last" / "pretrained_model"
    assert (policy / "model.safetensors").is_file()
    return policy, prepared


def as_lerobot_sims(env_fields: str) -> list[str]:
    """`prepare` flags that shape a recording like lerobot's simulated envs observe: observation.state is
    agent_pos, observation.environment_state the fields `env_fields` names ("" for none)."""
    return [f"--env-fields={env_fields}", "--state-fields=agent_pos"]


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


@contextlib.contextmanager
def served(py: str, policy: Path, err_log: Path) -> Iterator[tuple[subprocess.Popen, int]]:
    """`lerobot_adapter.py serve policy` on a free port, for the `with` block: (the server's process, its port).

    Its stderr goes to `err_log` (a file, not a pipe: a full pipe would block the server); it is stopped with
    SIGTERM on the way out, so the caller can check its exit status and log afterwards."""
    proc = subprocess.Popen(
        [py, str(ADAPTER), "serve", str(policy), "--port", "0"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=err_log.open("w"),
        text=True,
        env={**os.environ, **SIDE_ENV},
    )
    try:
        line = wait_for_line(proc, "lerobot adapter: act policy", timeout=300)
        assert "ws://127.0.0.1:" in line, line
        yield proc, int(line.split("ws://127.0.0.1:")[1].split(" ")[0])
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=60)

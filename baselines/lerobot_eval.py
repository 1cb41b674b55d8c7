"""An existing lerobot evaluation, run by bench: `lerobot-eval`'s own flags, one command, the same episodes.

Runs in lerobot's venv (`bash .ci/lerobot-venv.sh`), beside `lerobot-eval`. Replace the program name and keep
the flags; bench keys may follow (held-out scenes, perturbations, more episodes):

    lerobot-eval --policy.path=outputs/act/checkpoints/last/pretrained_model --env.type=aloha \\
        --env.task=AlohaTransferCube-v0 --eval.n_episodes=50 --seed=1000
    .lerobot-venv/bin/python baselines/lerobot_eval.py --policy.path=outputs/act/checkpoints/last/pretrained_model \\
        --env.type=aloha --env.task=AlohaTransferCube-v0 --eval.n_episodes=50 --seed=1000 \\
        [envs=[nominal,slippery] perturb.friction=[0.5,2] out=runs run_id=act-aloha ...]

It serves the policy from this process (`lerobot_adapter.py`'s server, on 127.0.0.1, a free port) and runs
`bench run suite=aloha|pusht tasks=[TASK] policy=remote episodes=N seed=SEED seed_scheme=consecutive` with the
observation mapping the policy's input features need (`obs_map=`, `obs=state+rgb` for image policies) and
`replan_every=n_action_steps`, as lerobot-eval executes a chunk. Without bench keys it runs the nominal scene
only (`envs=[nominal]`), so its per-episode successes are lerobot-eval's: episode i starts from seed
SEED + i in both (tests/test_lerobot_parity.py checks it). The bench executable is `--bench` (default: this
checkout's `.venv/bin/bench`, else `bench` on PATH).

Flags read (the others of lerobot-eval are refused with the list of these):
    --policy.path  --env.type (aloha | pusht)  --env.task  --env.episode_length  --eval.n_episodes
    --seed  --policy.device  --bench; accepted and not needed: --eval.batch_size (bench runs one env per
    worker) and --env.obs_type (bench sends what the policy's input features name)
"""

from __future__ import annotations

import difflib
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

os.environ.setdefault("HF_HUB_OFFLINE", "1")
REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from baselines.lerobot_adapter import LerobotSession, Served, fail  # noqa: E402

# lerobot's env types -> bench suites: tasks, and where each of lerobot's input features comes from
ENVS: dict[str, dict[str, Any]] = {
    "aloha": {
        "suite": "aloha",
        "tasks": ("AlohaTransferCube-v0", "AlohaInsertion-v0"),
        "default_task": "AlohaInsertion-v0",  # lerobot's AlohaEnv default
        "episode_length": 400,
        "sources": {
            "observation.state": "state.agent_pos",
            "observation.environment_state": "state.env_state",
            "observation.images.top": "rgb.top",
        },
    },
    "pusht": {
        "suite": "pusht",
        "tasks": ("PushT-v0",),
        "default_task": "PushT-v0",
        "episode_length": 300,
        "sources": {
            "observation.state": "state.agent_pos",
            "observation.environment_state": "state.env_state",
            "observation.image": "rgb.top",
        },
    },
}
FLAGS = (
    "--policy.path",
    "--env.type",
    "--env.task",
    "--env.episode_length",
    "--env.obs_type",
    "--eval.n_episodes",
    "--eval.batch_size",
    "--seed",
    "--policy.device",
    "--bench",
)


def parse(argv: list[str]) -> tuple[dict[str, str], list[str]]:
    """lerobot-eval's `--flag=value` (or `--flag value`) arguments, and the bench `key=value` ones after them."""
    flags: dict[str, str] = {}
    extra: list[str] = []
    it = iter(argv)
    for arg in it:
        if not arg.startswith("--"):
            extra.append(arg)
            continue
        name, eq, value = arg.partition("=")
        if name not in FLAGS:
            hint = difflib.get_close_matches(name, FLAGS, 1)
            fail(
                f"{name}: not a flag this command reads; valid: {', '.join(FLAGS)}"
                + (f"; did you mean {hint[0]}?" if hint else "")
            )
        flags[name] = value if eq else next(it, "")
    return flags, extra


def _int(flags: dict[str, str], name: str, default: int, low: int) -> int:
    text = flags.get(name, str(default))
    try:
        value = int(text)
    except ValueError:
        value = low - 1
    if value < low:
        fail(f"{name}={text}: must be a whole number >= {low}")
    return value


def env_and_task(flags: dict[str, str]) -> tuple[dict, str]:
    """lerobot's env type and task as bench's suite entry and task id (one-line errors listing the valid ones)."""
    env_type = flags.get("--env.type", "")
    if env_type not in ENVS:
        fail(f"--env.type={env_type!r}: bench has suites for {', '.join(ENVS)}")
    env = ENVS[env_type]
    task = flags.get("--env.task") or str(env["default_task"])
    if task not in env["tasks"]:
        hint = difflib.get_close_matches(task, env["tasks"], 1)
        fail(
            f"--env.task={task!r}: not a task of {env_type}; valid: {', '.join(env['tasks'])}"
            + (f"; did you mean {hint[0]}?" if hint else "")
        )
    return env, task


def bench_command(flags: dict[str, str], extra: list[str], served: Served, port: int) -> list[str]:
    """The `bench run` argv that evaluates the served policy as lerobot-eval would."""
    env, task = env_and_task(flags)
    env_type = flags["--env.type"]
    sources: dict[str, str] = env["sources"]  # type: ignore[assignment]
    obs_map = []
    for key in served.inputs:
        if key not in sources:
            fail(
                f"the policy's input feature {key!r} is not an observation of bench's {env_type} suite; "
                f"it provides {', '.join(sources)}"
            )
        obs_map.append(f"{key}:{sources[key]}")
    images = any(sources[k].startswith("rgb.") for k in served.inputs)
    episodes, seed, horizon = numbers(flags, env)
    n_action_steps = int(getattr(served.policy.config, "n_action_steps", 0) or 0)
    cmd = [
        "run",
        f"suite={env['suite']}",
        f"tasks=[{task}]",
        "policy=remote",
        f"port={port}",
        "timeout_s=300",
        f"episodes={episodes}",
        f"seed={seed}",
        "seed_scheme=consecutive",
        f"horizon={horizon}",
        f"obs_map=[{','.join(obs_map)}]",
        f"obs={'state+rgb' if images else 'state'}",
    ]
    if n_action_steps:
        cmd.append(f"replan_every={n_action_steps}")
    keys = {a.split("=", 1)[0].split(".", 1)[0] for a in extra}
    if not keys & {"envs", "splits"}:
        cmd.append("envs=[nominal]")
    return [*cmd, *extra]


def numbers(flags: dict[str, str], env: dict) -> tuple[int, int, int]:
    """--eval.n_episodes, --seed and --env.episode_length, checked."""
    episodes = _int(flags, "--eval.n_episodes", 50, 1)
    seed = _int(flags, "--seed", 1000, 0)
    return episodes, seed, _int(flags, "--env.episode_length", int(env["episode_length"]), 1)


def bench_executable(flags: dict[str, str]) -> str:
    given = flags.get("--bench")
    if given:
        return given
    local = REPO / ".venv" / "bin" / "bench"
    found = str(local) if local.exists() else shutil.which("bench")
    if not found:
        fail("no bench executable: give --bench=PATH (bench's venv: .venv/bin/bench)")
    return str(found)


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__)
        return 0
    flags, extra = parse(argv)
    if not flags.get("--policy.path"):
        fail("--policy.path: give the trained policy's folder (.../checkpoints/last/pretrained_model)")
    exe = bench_executable(flags)
    numbers(flags, env_and_task(flags)[0])  # every flag checked before the policy loads
    from bench.api.serving import WebsocketServer

    served = Served(flags["--policy.path"], flags.get("--policy.device", "cpu"))
    server = WebsocketServer(lambda: LerobotSession(served), served.metadata, "127.0.0.1", 0, log=lambda t: None)
    port = server.start()
    cmd = [exe, *bench_command(flags, extra, served, port)]
    print("bench " + " ".join(cmd[1:]), flush=True)
    try:
        return subprocess.run(cmd, cwd=os.getcwd()).returncode
    finally:
        server.shutdown()


if __name__ == "__main__":
    try:
        code = main(sys.argv[1:])
    except SystemExit as exc:  # fail(): a one-line error, exit 2
        code = exc.code if isinstance(exc.code, int) else 2
    sys.stdout.flush()
    sys.stderr.flush()
    # exit now: tearing the interpreter down under the server's thread aborts in torch's native code
    # ("terminate called without an active exception"), which would turn bench's exit code into 134
    os._exit(code)

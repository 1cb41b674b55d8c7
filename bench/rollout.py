"""One episode: reset with the episode's seed, apply its condition, step the policy, record."""
from __future__ import annotations

import os
import signal
import time
import traceback
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench.env import state_hash
from bench.records import EpisodeRecord
from bench.suite import Job, condition_rng


class EpisodeTimeout(Exception):
    """The episode ran past its wall-clock limit."""


@contextmanager
def time_limit(seconds: float | None):
    """Raise EpisodeTimeout in the main thread after `seconds` (no-op when None/0 or off-main-thread)."""
    if not seconds or seconds <= 0 or not hasattr(signal, "setitimer"):
        yield
        return
    try:
        old = signal.signal(signal.SIGALRM, _on_alarm)
    except ValueError:  # not the main thread
        yield
        return
    signal.setitimer(signal.ITIMER_REAL, float(seconds))
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _on_alarm(signum, frame):
    raise EpisodeTimeout("episode timed out")


@dataclass(frozen=True)
class RunContext:
    """What every episode of a run shares (passed once to each worker)."""

    run_id: str
    suite_version: str
    policy_id: str
    checkpoint_sha256: str | None
    versions: dict[str, str]
    horizon: int
    timeout_s: float
    trajectory_dir: str | None = None   # set when `record=` asks for the rollouts


def trajectory_path(directory: str | Path, job_id: str) -> Path:
    """Where a job's trajectory (.npz) is kept until the run assembles the dataset."""
    safe = job_id.replace("/", "__").replace("|", "--").replace("=", "-").replace("~", "_")
    return Path(directory) / f"{safe}.npz"


def _save_trajectory(path: Path, traj: dict[str, list]) -> None:
    """Write the episode's arrays atomically (tmp + rename): a record implies its trajectory exists."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **{k: np.asarray(v) for k, v in traj.items()})
    os.replace(tmp, path)


def run_episode(job: Job, env, policy, ctx: RunContext) -> tuple[EpisodeRecord, bool]:
    """Run `job` on an already-built env; return its record and whether the env is still usable.

    An exception or timeout is recorded in `error` (the run goes on); the env is then
    reported unusable so the caller rebuilds it.
    """
    from bench import perturb

    t0 = time.perf_counter()
    success_once = success_at_end = False
    ret, length, first_success = 0.0, 0, None
    init_hash, params, error = None, {}, None
    traj: dict[str, list] | None = {"obs": [], "action": [], "reward": [], "success": [], "sim_state": [],
                                    "ctrl": []} if ctx.trajectory_dir else None
    log_ctrl = traj is not None and hasattr(env, "log_ctrl")  # MuJoCo inputs of every physics step
    try:
        with time_limit(ctx.timeout_s):
            rng = condition_rng(job.seed, job.condition)
            stepper, params = perturb.apply(env, job.condition, rng)
            obs = stepper.reset(job.seed)
            init_hash = state_hash(env.init_state())
            policy.reset(job.seed)
            if log_ctrl:
                env.log_ctrl(True)
            for t in range(ctx.horizon):
                action = policy.act(obs)
                if traj is not None:
                    _append_frame(traj, env, obs, action)
                obs, reward, done, info = stepper.step(action)
                if log_ctrl:
                    traj["ctrl"].append(env.take_ctrl().astype(np.float32).ravel())
                ret += reward
                length = t + 1
                success_at_end = bool(info.get("success", False))
                if traj is not None:
                    traj["reward"].append(float(reward))
                    traj["success"].append(success_at_end)
                if success_at_end and first_success is None:
                    first_success = length
                    success_once = True
                if done:
                    break
    except EpisodeTimeout:
        error = f"timeout after {ctx.timeout_s:g} s at step {length}"
    except Exception as exc:  # recorded, the run goes on
        if ctx.timeout_s and time.perf_counter() - t0 >= ctx.timeout_s:
            # the alarm fired inside a library that re-raised it as its own exception type
            error = f"timeout after {ctx.timeout_s:g} s at step {length} (surfaced as {type(exc).__name__})"
        else:
            tb = traceback.extract_tb(exc.__traceback__)[-1]
            error = f"{type(exc).__name__}: {exc} ({os.path.basename(tb.filename)}:{tb.lineno})"
    finally:
        if log_ctrl:
            env.log_ctrl(False)
    if error:
        success_once = success_at_end = False
    elif traj is not None and length:
        traj["obs_names"] = [f"{n}:{w}" for n, w in env.obs_names]
        traj["action_names"] = list(env.action_names)
        traj["fps"] = [float(getattr(env, "fps", 0.0) or 0.0)]
        if log_ctrl:
            from bench.env import mj_input_names

            traj["ctrl_names"] = mj_input_names(env.model, env.ctrl_spec)
            traj["ctrl_spec"] = [int(env.ctrl_spec)]
        _save_trajectory(trajectory_path(ctx.trajectory_dir, job.job_id), traj)
    cell = job.cell
    record = EpisodeRecord(
        run_id=ctx.run_id, job_id=job.job_id, suite=cell.suite, suite_version=ctx.suite_version,
        task=cell.task, robot=cell.robot, env=cell.env, split=cell.split,
        condition=job.condition.name, axis=job.condition.axis, level=_jsonable(job.condition.level),
        params=_jsonable(params), episode=job.episode, seed=job.seed, init_state_hash=init_hash,
        success_once=success_once, success_at_end=success_at_end, return_=float(ret), length=length,
        steps_to_success=first_success, error=error, policy=ctx.policy_id,
        checkpoint_sha256=ctx.checkpoint_sha256, backend=getattr(env, "backend", None),
        wall_s=round(time.perf_counter() - t0, 4), finished_at=round(time.time(), 3), worker_pid=os.getpid(),
        versions=ctx.versions,
    )
    return record, error is None


def _append_frame(traj: dict[str, list], env, obs: np.ndarray, action: np.ndarray) -> None:
    traj["obs"].append(np.asarray(obs, np.float32))
    traj["action"].append(np.asarray(action, np.float32))
    data = getattr(env, "data", None)
    if data is not None and hasattr(data, "qpos"):  # MuJoCo state, so logs can be replayed in simulation
        traj["sim_state"].append(np.concatenate([data.qpos, data.qvel]).astype(np.float32))


def _jsonable(x: Any) -> Any:
    """numpy scalars/arrays -> plain Python, so records serialise without surprises."""
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, float):
        return round(x, 10)
    return x

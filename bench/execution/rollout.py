"""One episode: reset with the episode's seed, apply its condition, step the policy, record.

The rollout is the boundary between plugins and the records: an exception, a timeout, or a
non-finite number coming out of the env (reward, observation) or the policy (action) ends
the episode with its reason in `error` (the run goes on), and never reaches a summary.
A policy may return an action chunk (T, A): its rows are executed open loop, one per step. An episode's logic is
one `Episode`: `run_episode` runs it alone, `bench.execution.vector` runs N of them in lockstep (`vector=N`).

An `instruction` episode (`bench.sims.perturb.language`) also measures how much the words steer the policy: a
shadow instance of the policy, reset with the same seed, is asked whenever the policy is asked, on the same
observation but with the true instruction; its answer is recorded, never executed. Per executed step the
difference is the mean over action dimensions of |variant - true| / half-range (the chunk row executed against the
shadow chunk's row of the same index, its last when shorter), so a stateful or chunking policy is compared query by
query on one observation stream. The episode's `extras["instruction"]` holds the variant, the text the policy saw,
the true one, `action_diff` (the mean over steps) and `steps_differ` (the share of steps that differ).
"""

from __future__ import annotations

import _signal  # signal's C functions: `signal.signal` wraps each in enum conversions (time_limit)
import os
import signal
import time
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np

from bench.core.io import first_nonfinite, jsonable
from bench.execution import episode_video
from bench.protocols import RGB, STATE, TASK, ActionSpec, EnvAdapter, NumArray, Obs, Policy, ReportsStats
from bench.protocols.env import mj_input_names, state_hash
from bench.protocols.suite import Job, condition_rng
from bench.records import EpisodeRecord
from bench.sims import perturb
from bench.sims.perturb import language

# an episode's trajectory while it runs: per-step lists (arrays, rewards, flags) and per-episode name lists
Trajectory = dict[str, list[object]]


class EpisodeTimeout(Exception):
    """The episode ran past its wall-clock limit."""


class NonFinite(Exception):
    """The env or the policy produced a NaN or infinite number."""


@contextmanager
def time_limit(seconds: float | None) -> Iterator[None]:
    """Raise EpisodeTimeout in the main thread after `seconds` (no-op when None/0 or off-main-thread).

    It is entered around every env and policy call of an episode, twice per world and step in a vector run, so the
    handler is swapped with `_signal.signal`, the C function `signal.signal` wraps: with the wrapper's enum
    conversions (5 us a call) entering and leaving took 10.2 us, without them 3.8 (timeit): twice per world and
    step, 21 vs 8 ms of each control step of 1,024 MJX worlds."""
    if not seconds or seconds <= 0 or not hasattr(signal, "setitimer"):
        yield
        return
    try:
        old = _signal.signal(signal.SIGALRM, _on_alarm)
    except ValueError:  # not the main thread
        yield
        return
    signal.setitimer(signal.ITIMER_REAL, float(seconds))
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        _signal.signal(signal.SIGALRM, old)


def _on_alarm(signum: int, frame: FrameType | None) -> None:
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
    trajectory_dir: str | None = None  # set when `record=` asks for the rollouts
    video_dir: str | None = None  # the run directory, when `video=N` asks for episode videos
    video_episodes: int = 0  # N: videos of episodes 0..N-1 of every cell and condition
    policy_stats: bool = False  # the policy reports `episode_stats()` (PolicyPlugin.reports_stats)


def trajectory_path(directory: str | Path, job_id: str) -> Path:
    """Where a job's trajectory (.npz) is kept until the run assembles the dataset."""
    safe = job_id.replace("/", "__").replace("|", "--").replace("=", "-").replace("~", "_")
    return Path(directory) / f"{safe}.npz"


def _save_trajectory(path: Path, traj: Trajectory) -> None:
    """Write the episode's arrays atomically (tmp + rename): a record implies its trajectory exists.

    Camera frames (`rgb.*`) are compressed (rendered scenes shrink several times; numbers barely do)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    save = np.savez_compressed if any(k.startswith(RGB) for k in traj) else np.savez
    save(tmp, **{k: np.asarray(v) for k, v in traj.items()})
    os.replace(tmp, path)


def _check_obs(obs: Obs, t: int) -> None:
    for key, value in obs.items():
        if isinstance(value, np.ndarray) and value.dtype.kind == "f" and not np.all(np.isfinite(value)):
            raise NonFinite(f"non-finite observation {key!r} at step {t}")


class _Actions:
    """The policy's commands one step at a time: a chunk (T, A) is executed open loop, row by row.

    A policy with `prefetch(obs, t) -> bool` (a remote one with `overlap=true`) is told when the current
    chunk's last row is about to execute at step t, so it can start computing the next chunk while the
    env steps; its next `act` returns that chunk.
    """

    def __init__(self, policy: Policy, dim: int, horizon: int):
        self.policy, self.dim, self.horizon = policy, dim, horizon
        self.queue: list[NumArray] = []
        self.prefetch = getattr(policy, "prefetch", None)
        self.fresh, self.row = False, 0  # this step's action starts a new answer; its row in that answer
        self.given = False  # the queue holds an answer `give` put there, not yet executed

    def give(self, answer: object, t: int) -> None:
        """The policy's answer for step t, asked for by the caller (a vectorised rollout's batched call)."""
        self.queue, self.given = chunk(answer, self.dim, t), True

    def next(self, obs: Obs, t: int) -> NumArray:
        if not self.queue:
            self.give(self.policy.act(obs), t)
        self.fresh, self.given = self.given, False
        self.row = 0 if self.fresh else self.row + 1
        action = self.queue.pop(0)
        if not self.queue and self.prefetch is not None and t + 1 < self.horizon:
            self.prefetch(obs, t)
        return action


def chunk(answer: object, dim: int, t: int, who: str = "policy") -> list[NumArray]:
    """A policy's answer as the rows to execute: one action (A,) or a chunk (T, A) of finite numbers."""
    out = np.asarray(answer)
    if out.ndim == 1 and out.shape[0] == dim:
        rows = [out]
    elif out.ndim == 2 and out.shape[1] == dim and out.shape[0] >= 1:
        rows = list(out)
    else:
        raise ValueError(f"{who} returned an action of shape {out.shape}; expected ({dim},) or a chunk (T, {dim})")
    if out.dtype.kind not in "fiu" or not np.all(np.isfinite(out)):
        raise NonFinite(f"{who} returned a non-finite action at step {t}")
    return rows


def needs_shadow(job: Job) -> bool:
    """Whether `job` varies the instruction, so `run_episode` wants a shadow policy (the worker builds one)."""
    return language.varies(job.condition)


DIFFER = 1e-6  # a step's actions differ when their mean normalised difference exceeds this (float noise below it)


class _Shadow:
    """The shadow policy of an instruction episode: asked when the policy is asked, on the same observation with
    the true instruction; accumulates the per-step action difference (see the module doc)."""

    def __init__(self, policy: Policy, view: language.InstructionView, spec: ActionSpec):
        self.policy, self.view, self.dim = policy, view, spec.dim
        half = (np.asarray(spec.high, np.float64) - np.asarray(spec.low, np.float64)) / 2.0
        self.half = np.where(np.isfinite(half) & (half > 0), half, 1.0)
        self.rows: list[NumArray] = []
        self.diffs: list[float] = []

    def step(self, obs: Obs, actions: _Actions, action: NumArray, t: int) -> None:
        if actions.fresh:
            self.rows = chunk(self.policy.act({**obs, TASK: self.view.true}), self.dim, t, "the shadow policy")
        true = np.asarray(self.rows[min(actions.row, len(self.rows) - 1)], np.float64)
        self.diffs.append(float(np.mean(np.abs(np.asarray(action, np.float64) - true) / self.half)))

    def record(self) -> dict[str, object]:
        out: dict[str, object] = {"steps": len(self.diffs)}
        if self.diffs:
            d = np.asarray(self.diffs)
            out["action_diff"] = round(float(d.mean()), 9)
            out["steps_differ"] = round(float(np.mean(d > DIFFER)), 9)
        return out


class Episode:
    """One episode while it runs: `start` (condition, reset), `step` once per control step, `finish` into its record.

    The one place an episode's step logic lives: `run_episode` runs one env through it, and
    `bench.execution.vector.run_vector` N envs in lockstep, asking their policy once per step for all of them. Every
    call goes through `guarded`, on the episode's own clock (`spent`: its own calls, and the batched answers it
    waited for): an exception, a timeout or a non-finite number ends the episode (`done`) with its reason in `error`.
    """

    def __init__(self, job: Job, env: EnvAdapter, policy: Policy, ctx: RunContext, shadow: Policy | None = None):
        self.job, self.env, self.policy, self.ctx, self.shadow = job, env, policy, ctx, shadow
        self.spent = 0.0  # wall seconds charged to this episode
        self.done = False  # terminated, truncated, out of steps, or failed
        self.success_once = self.success_at_end = False
        self.ret, self.length = 0.0, 0
        self.first_success: int | None = None
        self.params: dict[str, object] = {}
        self.init_hash: str | None = None
        self.error: str | None = None
        self.traj: Trajectory | None = (
            {"obs": [], "action": [], "reward": [], "success": [], "sim_state": [], "ctrl": []}
            if ctx.trajectory_dir
            else None
        )
        self.log = env.inputs if self.traj is not None else None  # MuJoCo inputs of every physics step
        self.video: episode_video.EpisodeVideo | None = None
        self.view: language.InstructionView | None = None
        self.compare: _Shadow | None = None
        self.stepper: EnvAdapter = env
        self.obs: Obs = {}
        self.actions = _Actions(policy, env.action_spec.dim, ctx.horizon)
        self.pending: NumArray | None = None  # the action `choose` took for the coming step

    def guarded(self, call: Callable[[], object]) -> None:
        """`call()` on this episode's clock, unless it is done; a failure ends it with the reason."""
        if self.done:
            return
        began = time.perf_counter()
        limit = self.ctx.timeout_s - self.spent if self.ctx.timeout_s else None
        try:
            if limit is not None and limit <= 0:
                raise EpisodeTimeout("episode timed out")
            with time_limit(limit):
                call()
        except Exception as exc:  # recorded, the run goes on
            self.fail(exc, time.perf_counter() - began)
        else:
            self.spent += time.perf_counter() - began

    def fail(self, exc: Exception, took: float) -> None:
        """End the episode with `exc` as its reason; `took`: the seconds the failed call cost it."""
        self.spent += took
        self.done = True
        if isinstance(exc, EpisodeTimeout):
            self.error = f"timeout after {self.ctx.timeout_s:g} s at step {self.length}"
        elif isinstance(exc, NonFinite):
            self.error = str(exc)
        elif self.ctx.timeout_s and self.spent >= self.ctx.timeout_s:
            # the alarm fired inside a library that re-raised it as its own exception type
            self.error = (
                f"timeout after {self.ctx.timeout_s:g} s at step {self.length} (surfaced as {type(exc).__name__})"
            )
        else:
            tb = traceback.extract_tb(exc.__traceback__)[-1]
            self.error = f"{type(exc).__name__}: {exc} ({os.path.basename(tb.filename)}:{tb.lineno})"

    def wants(self) -> bool:
        """The policy must be asked at this step (the last answer's rows are used up)."""
        return not self.done and not self.actions.queue

    def start(self) -> None:
        """Apply the job's condition (its own generator, the episode seed), reset, reset the policy."""
        job, env, ctx = self.job, self.env, self.ctx
        rng = condition_rng(job.seed, job.condition)
        self.stepper, self.params = perturb.apply(env, job.condition, rng, seed=job.seed)
        self.view = language.view_of(self.stepper)
        if self.view is not None:
            self.view.bind(job.condition.spec.get("instructions"), job.cell.task)
        self.obs = self.stepper.reset(job.seed)
        _check_obs(self.obs, 0)
        self.video = episode_video.start(ctx.video_dir, ctx.video_episodes, job, env)
        if self.video is not None:
            self.video.frame(self.obs)
        self.init_hash = state_hash(env.init_state())
        self.policy.reset(job.seed)
        if self.view is not None and self.shadow is not None:
            self.shadow.reset(job.seed)
            self.compare = _Shadow(self.shadow, self.view, env.action_spec)
        if self.log is not None:
            self.log.start()

    def choose(self, t: int) -> None:
        """Take control step t's action now (`pending`), so a batch of worlds can be stepped before `step` reads it."""
        self.pending = self.actions.next(self.obs, t)

    def step(self, t: int) -> None:
        """Control step t: the policy's action (asked now unless an answer is queued or `choose` took it), the env's
        step, the bookkeeping."""
        env, traj, log = self.env, self.traj, self.log
        action = self.pending if self.pending is not None else self.actions.next(self.obs, t)
        self.pending = None
        if self.compare is not None:
            self.compare.step(self.obs, self.actions, action, t)
        if traj is not None:
            _append_frame(traj, env, self.obs, action)
        obs, reward, terminated, truncated, _ = self.stepper.step(action)
        if log is not None and traj is not None:
            traj["ctrl"].append(log.take().astype(np.float32).ravel())
        if not np.isfinite(reward):
            raise NonFinite(f"non-finite reward ({reward}) at step {t}")
        _check_obs(obs, t + 1)
        self.obs = obs
        if self.video is not None:
            self.video.frame(obs)
        self.ret += reward
        self.length = t + 1
        self.success_at_end = bool(env.success())
        if traj is not None:
            traj["reward"].append(float(reward))
            traj["success"].append(self.success_at_end)
        if self.success_at_end and self.first_success is None:
            self.first_success = self.length
            self.success_once = True
        if terminated or truncated or self.length >= self.ctx.horizon:
            self.done = True

    def run(self) -> None:
        """`start`, then `step` until the episode ends (one env alone)."""
        self.start()
        for t in range(self.ctx.horizon):
            if self.done:
                break
            self.step(t)

    def finish(self) -> tuple[EpisodeRecord, bool]:
        """The episode's record (its video, policy statistics and trajectory written), and whether the env is
        still usable (False after an error: the caller rebuilds it)."""
        began = time.perf_counter()
        job, env, ctx, error = self.job, self.env, self.ctx, self.error
        if self.log is not None:
            self.log.stop()
        extras: dict[str, object] = {}
        if self.video is not None:
            extras["video"] = self.video.close(str(ctx.video_dir))
        stats = _policy_stats(self.policy) if ctx.policy_stats else {}
        if self.view is not None and self.view.text is not None:
            words = {"variant": self.view.variant, "text": self.view.text, "true": self.view.true}
            extras["instruction"] = {**words, **(self.compare.record() if self.compare is not None else {})}
        success_once, success_at_end, ret = self.success_once, self.success_at_end, self.ret
        traj = self.traj
        if error:
            success_once = success_at_end = False
            ret = 0.0 if not np.isfinite(ret) else ret
        elif traj is not None and self.length:
            if STATE in env.obs_spec:
                traj["obs_names"] = [f"{n}:{w}" for n, w in env.obs_spec[STATE].fields]
            traj["action_names"] = list(env.action_spec.names)
            traj["fps"] = [float(env.fps)]
            if self.log is not None and env.mujoco is not None:
                traj["ctrl_names"] = [*mj_input_names(env.mujoco.model, self.log.spec)]
                traj["ctrl_spec"] = [int(self.log.spec)]
            _save_trajectory(trajectory_path(str(ctx.trajectory_dir), job.job_id), traj)
        record = job_record(
            job,
            ctx,
            level=jsonable(job.condition.level, 10),
            params=jsonable(self.params, 10),
            init_state_hash=self.init_hash,
            success_once=success_once,
            success_at_end=success_at_end,
            return_=float(ret),
            length=self.length,
            steps_to_success=self.first_success,
            error=error,
            backend=env.backend,
            wall_s=round(self.spent + time.perf_counter() - began, 4),
            extras={**({"policy": stats} if stats else {}), **extras},
        )
        return record, error is None


def run_episode(
    job: Job, env: EnvAdapter, policy: Policy, ctx: RunContext, shadow: Policy | None = None
) -> tuple[EpisodeRecord, bool]:
    """Run `job` on an already-built env; return its record and whether the env is still usable.

    An exception, a timeout or a non-finite number is recorded in `error` (the run goes on);
    the env is then reported unusable so the caller rebuilds it. `shadow`: for an instruction episode, a second
    instance of the policy fed the true instruction (module doc); its actions are recorded, not executed.
    """
    episode = Episode(job, env, policy, ctx, shadow)
    episode.guarded(episode.run)  # one clock for the whole episode: the timeout bounds all of it
    return episode.finish()


def job_record(job: Job, ctx: RunContext, **outcome: Any) -> EpisodeRecord:
    """The record of `job`: which run, cell, condition, episode and policy it is, plus its `outcome` fields (the
    record's other fields, by name: `EpisodeRecord` checks them).

    The one place a job's identity is written into a record, for episodes that ran and for
    those that could not start (`bench.execution.runner.error_record`)."""
    cell = job.cell
    return EpisodeRecord(
        run_id=ctx.run_id,
        job_id=job.job_id,
        suite=cell.suite,
        suite_version=ctx.suite_version,
        task=cell.task,
        robot=cell.robot,
        env=cell.env,
        split=cell.split,
        condition=job.condition.name,
        axis=job.condition.axis,
        episode=job.episode,
        seed=job.seed,
        policy=ctx.policy_id,
        checkpoint_sha256=ctx.checkpoint_sha256,
        finished_at=round(time.time(), 3),
        worker_pid=os.getpid(),
        versions=ctx.versions,
        **outcome,
    )


def _policy_stats(policy: Policy) -> dict[str, object]:
    """The policy's `episode_stats()`, made JSON-safe; a failure is reported in place of the stats."""
    try:
        if not isinstance(policy, ReportsStats):
            raise AttributeError(f"{type(policy).__name__!r} object has no attribute 'episode_stats'")
        stats = jsonable(policy.episode_stats(), 10)
    except Exception as exc:
        return {"error": f"episode_stats failed: {type(exc).__name__}: {exc}"}
    bad = first_nonfinite(stats)
    if bad is not None or not isinstance(stats, dict):
        return {
            "error": f"episode_stats returned a non-finite number at {bad}" if bad else "episode_stats is not a dict"
        }
    return stats


def _append_frame(traj: Trajectory, env: EnvAdapter, obs: Obs, action: NumArray) -> None:
    if STATE in obs:
        traj["obs"].append(np.asarray(obs[STATE], np.float32))
    for key, value in obs.items():  # camera images: `record=` stores them as LeRobot video features
        if key.startswith(RGB):
            traj.setdefault(key, []).append(np.asarray(value, np.uint8))
    traj["action"].append(np.asarray(action, np.float32))
    if env.mujoco is not None:  # MuJoCo state, so logs can be replayed in simulation
        data = env.mujoco.data
        traj["sim_state"].append(np.concatenate([data.qpos, data.qvel]).astype(np.float32))

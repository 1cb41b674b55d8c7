"""`bench run vector=N`: N episodes of one cell and condition stepped in lockstep, their policy asked once per step.

Each env has its own `Episode` (`bench.execution.rollout`): its own episode seed, its own condition generator
and perturbation draw, its own policy instance, reset and clock, exactly as when it runs alone. Per control step,
the episodes whose last answer is used up are answered together:

- policies that declare batches (`bench.protocols.BatchPolicy`: an `act_batch` and a `batch_key`; equal keys are
  interchangeable) in one `act_batch` call per key (a torch checkpoint: one forward pass);
- policies whose answer can be sent before it is read (`bench.protocols.SplitPolicy`: a remote one) are all sent
  their observation before any answer is read, so a server that batches (`bench serve batch=N`) answers them in
  one forward pass;
- any other policy is asked per env, in its episode's step, as without `vector=`.

Envs that are worlds of one batched simulator (an MJX suite: `batch.step_all`) are then stepped in one call
(`step_batches`). Then every episode still running takes its step. An episode that ends (terminated, truncated, failed) is masked
from then on, never stepped again, so each record equals the one its job gives alone (`vector=1`). A batched
answer that is not one valid answer per observation (a count or shape `act_batch` should not give) fails the
episodes it was for, with the reason in their records, like a wrong `act` answer does alone: the run goes on.
Before a run, `probe` asks a batched policy once on a freshly reset env, so a policy whose `act_batch` answers the
wrong shape everywhere is refused in one line before anything is written.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Hashable, Sequence
from dataclasses import dataclass

import numpy as np

from bench.core.errors import ConfigError
from bench.execution.rollout import Episode, RunContext, chunk, time_limit
from bench.protocols import EnvAdapter, Policy, PolicyContext, PolicyPlugin, SplitPolicy, Suite, batchable
from bench.protocols.batch import BatchEnv, WorldBatch, batch_of
from bench.protocols.suite import Cell, Job
from bench.records import EpisodeRecord


def run_vector(
    jobs: Sequence[Job],
    envs: Sequence[EnvAdapter],
    policies: Sequence[Policy],
    ctx: RunContext,
    shadows: Sequence[Policy | None] | None = None,
) -> list[tuple[EpisodeRecord, bool]]:
    """Run `jobs[i]` on `envs[i]` with `policies[i]` (and `shadows[i]`), all in lockstep; per job, its record and
    whether its env is still usable (as `run_episode` returns them)."""
    twins = list(shadows) if shadows is not None else [None] * len(jobs)
    episodes = [Episode(j, e, p, ctx, s) for j, e, p, s in zip(jobs, envs, policies, twins)]
    for ep in episodes:
        ep.guarded(ep.start)
    together = Lockstep.of(episodes)
    for t in range(ctx.horizon):
        live = [ep for ep in episodes if not ep.done]
        if not live:
            break
        answer(together, t)
        step_batches(together, t, {id(ep) for ep in live})
        for ep in live:
            ep.guarded(functools.partial(ep.step, t))
    return [ep.finish() for ep in episodes]


@dataclass(frozen=True)
class Lockstep:
    """Which episodes are answered together and which are worlds stepped together, found once per run (after
    `Episode.start`, which sets each episode's env): a capability is a runtime protocol check, and the world checks
    (`batch_of`, `BatchEnv`) asked per world at every step took 28 us per world, 29 ms of each control step of
    1,024 MJX worlds (about a tenth of it; timeit on an MJX Lift world)."""

    batched: dict[Hashable, list[Episode]]  # batch_key -> episodes whose policy declares batches (BatchPolicy)
    split: list[Episode]  # episodes whose policy is sent before it is read (SplitPolicy)
    worlds: list[tuple[WorldBatch, list[tuple[Episode, int]]]]  # a batched simulator and its worlds' episodes

    @classmethod
    def of(cls, episodes: Sequence[Episode]) -> Lockstep:
        batched: dict[Hashable, list[Episode]] = {}
        split: list[Episode] = []
        worlds: dict[int, tuple[WorldBatch, list[tuple[Episode, int]]]] = {}
        for ep in episodes:
            if ep.done:
                continue
            if batchable(ep.policy):
                batched.setdefault(ep.policy.batch_key, []).append(ep)
            elif isinstance(ep.policy, SplitPolicy):
                split.append(ep)
            stepper = ep.stepper
            batch = batch_of(stepper)
            if batch is not None and isinstance(stepper, BatchEnv):
                worlds.setdefault(id(batch), (batch, []))[1].append((ep, stepper.index))
        return cls(batched, split, list(worlds.values()))


def answer(together: Lockstep, t: int) -> None:
    """Ask the policies of the episodes that want an answer at step t, batched where their policies declare it.

    Episodes whose policy declares neither are left to ask in their own step."""
    groups = [[ep for ep in group if not ep.done and ep.wants()] for group in together.batched.values()]
    split = [ep for ep in together.split if not ep.done and ep.wants()]
    for group in groups:
        if group:
            _batch(group, t)
    for ep in split:
        ep.guarded(functools.partial(_send, ep))
    for ep in split:
        ep.guarded(functools.partial(_receive, ep, t))


def step_batches(together: Lockstep, t: int, live: set[int]) -> None:
    """Step together the episodes whose envs are worlds of one batched simulator (`bench.protocols.batch.BatchEnv`:
    a `batch` whose `step_all({index: action})` steps those worlds in one call, and an `index`: an MJX world,
    `bench.sims.mjx_lift`) among `live` (ids of the episodes running when step t began).

    Each takes its action first (`Episode.choose`); its own `step` then reads the world's row of that batched step.
    An env under a wrapper that changes actions (a perturbed interface) is left to step alone."""
    for batch, worlds in together.worlds:
        group = [(ep, i) for ep, i in worlds if id(ep) in live]
        if len(group) < 2:
            continue
        for ep, _ in group:
            ep.guarded(functools.partial(ep.choose, t))
        ready = [(ep, i) for ep, i in group if not ep.done and ep.pending is not None]
        if not ready:
            continue
        began = time.perf_counter()
        try:
            batch.step_all({i: ep.pending for ep, i in ready if ep.pending is not None})
        except Exception as exc:  # every world of the call fails with the reason; the run goes on
            for ep, _ in ready:
                ep.fail(exc, time.perf_counter() - began)
            continue
        took = (time.perf_counter() - began) / len(ready)
        for ep, _ in ready:
            ep.spent += took


def probe(
    suite: Suite, cell: Cell, plugin: PolicyPlugin, options: object, horizon: int, seed: int, vector: int
) -> None:
    """Before a `vector=N` run writes anything: the policy of `cell`, if it declares batches, asked once for two
    observations of a freshly reset env; an answer that is not two valid actions (a wrong batch shape) is refused
    in one line (ConfigError, exit 2). Policies that do not declare batches are asked per env and not probed."""
    env = suite.make_env(cell, horizon)
    try:
        policy = plugin.make(cell, env, PolicyContext(options, suite, seed, horizon))
        policy.reset(seed)
        if not batchable(policy):
            return
        obs = env.reset(seed)
        try:
            for one in split_answers(policy.act_batch([obs, obs]), 2):
                chunk(one, env.action_spec.dim, 0, "an answer of its act_batch")
        except ValueError as exc:
            raise ConfigError(
                f"vector={vector}: the batched policy {type(policy).__name__} on {cell.key}: {exc}; act_batch must "
                "answer one action (A,) or chunk (T, A) per observation"
            ) from None
    finally:
        env.close()


def _send(ep: Episode) -> None:
    assert isinstance(ep.policy, SplitPolicy)
    ep.policy.send(ep.obs)


def _receive(ep: Episode, t: int) -> None:
    assert isinstance(ep.policy, SplitPolicy)
    ep.actions.give(ep.policy.receive(), t)


def _batch(group: list[Episode], t: int) -> None:
    """One `act_batch` call for `group` (policies with one `batch_key`), its time charged to each episode."""
    policy = group[0].policy
    assert batchable(policy)
    timeout = group[0].ctx.timeout_s
    limit = min(timeout - ep.spent for ep in group) if timeout else None
    began = time.perf_counter()
    try:
        with time_limit(limit if limit is None or limit > 0 else 1e-6):
            answers = split_answers(policy.act_batch([ep.obs for ep in group]), len(group))
    except Exception as exc:  # every episode it was for fails with the reason; the run goes on
        took = time.perf_counter() - began
        for ep in group:
            ep.fail(exc, took)
        return
    took = time.perf_counter() - began
    for ep, one in zip(group, answers):
        ep.spent += took
        ep.guarded(functools.partial(ep.actions.give, one, t))


def split_answers(out: object, n: int) -> list[object]:
    """`act_batch`'s answer as n answers (each then checked as an `act` answer is); ValueError naming the shape."""
    if isinstance(out, np.ndarray):
        if out.ndim not in (2, 3) or out.shape[0] != n:
            raise ValueError(
                f"policy act_batch returned an array of shape {out.shape} for {n} observations; expected "
                f"({n}, A) or ({n}, T, A)"
            )
        return list(out)
    try:
        answers = list(out)  # type: ignore[call-overload]
    except TypeError:
        raise ValueError(
            f"policy act_batch returned a {type(out).__name__} for {n} observations; expected {n} answers"
        ) from None
    if len(answers) != n:
        raise ValueError(f"policy act_batch returned {len(answers)} answers for {n} observations")
    return answers

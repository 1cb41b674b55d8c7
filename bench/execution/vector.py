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
"""

from __future__ import annotations

import functools
import time
from collections.abc import Hashable, Sequence

import numpy as np

from bench.execution.rollout import Episode, RunContext, time_limit
from bench.protocols import EnvAdapter, Policy, SplitPolicy, batchable
from bench.protocols.suite import Job
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
    for t in range(ctx.horizon):
        live = [ep for ep in episodes if not ep.done]
        if not live:
            break
        answer(live, t)
        step_batches(live, t)
        for ep in live:
            ep.guarded(functools.partial(ep.step, t))
    return [ep.finish() for ep in episodes]


def answer(live: Sequence[Episode], t: int) -> None:
    """Ask the policies of the episodes that want an answer at step t, batched where their policies declare it.

    Episodes whose policy declares neither are left to ask in their own step."""
    groups: dict[Hashable, list[Episode]] = {}
    split: list[Episode] = []
    for ep in live:
        if not ep.wants():
            continue
        if batchable(ep.policy):
            groups.setdefault(ep.policy.batch_key, []).append(ep)
        elif isinstance(ep.policy, SplitPolicy):
            split.append(ep)
    for group in groups.values():
        _batch(group, t)
    for ep in split:
        ep.guarded(functools.partial(_send, ep))
    for ep in split:
        ep.guarded(functools.partial(_receive, ep, t))


def step_batches(live: Sequence[Episode], t: int) -> None:
    """Step together the episodes whose envs are worlds of one batched simulator (an env with `batch`, whose
    `step_all({index: action})` steps those worlds in one call, and `index`: an MJX world, `bench.sims.mjx_lift`).

    Each takes its action first (`Episode.choose`); its own `step` then reads the world's row of that batched step.
    An env under a wrapper that changes actions (a perturbed interface) is left to step alone."""
    groups: dict[int, list[Episode]] = {}
    for ep in live:
        batch = getattr(ep.stepper, "batch", None)
        if batch is not None and callable(getattr(batch, "step_all", None)):
            groups.setdefault(id(batch), []).append(ep)
    for group in groups.values():
        if len(group) < 2:
            continue
        for ep in group:
            ep.guarded(functools.partial(ep.choose, t))
        ready = [ep for ep in group if not ep.done and ep.pending is not None]
        if not ready:
            continue
        batch = ready[0].stepper.batch  # type: ignore[attr-defined]  # a batched world (checked above)
        began = time.perf_counter()
        try:
            batch.step_all({ep.stepper.index: ep.pending for ep in ready})  # type: ignore[attr-defined]
        except Exception as exc:  # every world of the call fails with the reason; the run goes on
            for ep in ready:
                ep.fail(exc, time.perf_counter() - began)
            continue
        took = (time.perf_counter() - began) / len(ready)
        for ep in ready:
            ep.spent += took


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

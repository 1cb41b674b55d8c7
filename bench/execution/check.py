"""`bench check`: split hygiene and the simulator contract, per suite.

Hygiene ("unseen really is unseen"):
- manifest: on every axis the seen and unseen lists are disjoint, and no value appears twice;
- cells: each cell's split agrees with the manifest (a cell on an unseen robot is not `seen`);
- episode seeds: no two episodes of a run share a seed;
- initial states (full check only; builds each cell's env): two episode seeds that give the same
  initial state (seed wrap-around: e.g. an adapter that reduces seeds modulo a small number), and
  identical initial states in a seen cell and an unseen cell.
The first three run before every `bench run` (fast path, nothing built); a violation stops the run
with exit 2 unless `allow_split_violation=true`.

Contract (Gymnasium-checker style): the suite against the `Suite` protocol (attributes, options,
declared capabilities, cells), and on one cell of every suite its env against `EnvAdapter`: the
observation matches the declared spec (the suite's and the env's), actions have the declared
bounds, `step` returns (obs, reward, terminated, truncated, info), `success()` is a bool, numbers
are finite, and the same seed and actions give the same trajectory twice.
"""

from __future__ import annotations

import dataclasses
from collections import Counter, defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bench.protocols import CAPABILITIES, STATE, Cell, EnvAdapter, Suite, check_obs
from bench.protocols.env import state_hash
from bench.protocols.suite import METRICS, SPLIT_AXES, SPLITS, Job


@dataclass(frozen=True)
class Problem:
    """One hygiene or contract violation, phrased for the user."""

    kind: str  # manifest | cell | seeds | wraparound | cross-split | contract
    message: str


def check_manifest(manifest: Mapping[str, Mapping[str, Sequence[str]]], source: str = "manifest") -> list[Problem]:
    """Seen and unseen disjoint on every axis; no value listed twice on one side."""
    problems = []
    for axis, split in manifest.items():
        seen, unseen = list(split.get("seen", [])), list(split.get("unseen", []))
        both = sorted(set(map(str, seen)) & set(map(str, unseen)))
        if both:
            problems.append(Problem("manifest", f"{source}: {axis} {both} listed as both seen and unseen"))
        for side, vals in (("seen", seen), ("unseen", unseen)):
            dup = sorted(v for v, n in Counter(map(str, vals)).items() if n > 1)
            if dup:
                problems.append(Problem("manifest", f"{source}: {axis} {dup} listed twice in {side}"))
    return problems


def check_cells(cells: list[Cell], manifest: Mapping[str, Mapping[str, Sequence[str]]]) -> list[Problem]:
    """Each cell's split must match what the manifest says about its robot/task/env."""
    problems = []
    for cell in cells:
        for axis, split in manifest.items():
            attr = SPLIT_AXES.get(axis)
            if attr is None:
                continue
            value = getattr(cell, attr)
            if value in split.get("unseen", []) and cell.split == "seen":
                problems.append(Problem("cell", f"cell {cell.key} is marked seen but {axis} {value!r} is unseen"))
            if (
                value in split.get("seen", [])
                and value not in split.get("unseen", [])
                and cell.split == "unseen"
                and len(split.get("unseen", [])) > 0
            ):
                problems.append(Problem("cell", f"cell {cell.key} is marked unseen but {axis} {value!r} is seen"))
    return problems


def check_seeds(jobs: list[Job]) -> list[Problem]:
    """No two episodes of one cell and condition share a seed."""
    by_cell: dict[tuple, list[int]] = defaultdict(list)
    for j in jobs:
        by_cell[(j.cell.key, j.condition.name)].append(j.seed)
    for key, seeds in by_cell.items():
        if len(set(seeds)) != len(seeds):
            return [Problem("seeds", f"cell {key[0]}: episode seeds repeat")]
    return []


def fast_check(suite: Suite, cells: list[Cell], jobs: list[Job]) -> list[Problem]:
    """The checks `bench run` does before starting (nothing is built)."""
    return (
        check_manifest(suite.manifest, f"suite {suite.name}") + check_cells(cells, suite.manifest) + check_seeds(jobs)
    )


def check_init_states(
    suite, cells: list[Cell], seeds: list[int], horizon: int, seed_transform=None
) -> tuple[list[Problem], dict[str, list[str]]]:
    """Reset each cell's env with every seed; find repeated and cross-split identical initial states.

    Args:
        seed_transform: optional function applied to each seed before reset (used to inject a
            wrap-around bug and show that the check catches it).
    """
    problems: list[Problem] = []
    hashes: dict[str, list[str]] = {}
    owner: dict[str, Cell] = {}
    for cell in cells:
        env = suite.make_env(cell, horizon)
        try:
            hs = []
            for s in seeds:
                env.reset(seed_transform(s) if seed_transform else s)
                hs.append(state_hash(env.init_state()))
        finally:
            env.close()
        hashes[cell.key] = hs
        dup = [(i, j) for i in range(len(hs)) for j in range(i + 1, len(hs)) if hs[i] == hs[j]]
        if dup:
            i, j = dup[0]
            problems.append(
                Problem(
                    "wraparound",
                    f"cell {cell.key}: episodes {i} and {j} (seeds {seeds[i]}, {seeds[j]}) "
                    f"start from the same state ({len(dup)} repeated pair(s))",
                )
            )
        for h in set(hs):
            other = owner.get(h)
            if other is not None and other.split != cell.split:
                problems.append(
                    Problem(
                        "cross-split",
                        f"cells {other.key} ({other.split}) and {cell.key} ({cell.split}) share an initial state",
                    )
                )
            owner.setdefault(h, cell)
    return problems, hashes


def check_suite(suite: Suite) -> list[Problem]:
    """The suite against the `Suite` protocol: attributes, options, capabilities, cells and their specs."""
    where = f"suite {getattr(suite, 'name', '?')}"
    problems: list[Problem] = []

    def bad(msg: str) -> None:
        problems.append(Problem("contract", f"{where}: {msg}"))

    for attr, kind in (
        ("name", str),
        ("version", str),
        ("reference_policy", str),
        ("default_policy", str),
        ("default_horizon", int),
        ("default_metric", str),
    ):
        if not isinstance(getattr(suite, attr, None), kind):
            bad(f"{attr} must be a {kind.__name__}, got {getattr(suite, attr, None)!r}")
    if not dataclasses.is_dataclass(getattr(suite, "Options", None)):
        bad("Options must be a dataclass of the suite's keys")
    if getattr(suite, "default_metric", None) not in METRICS:
        bad(f"default_metric {getattr(suite, 'default_metric', None)!r} is not one of {', '.join(METRICS)}")
    unknown = sorted(set(getattr(suite, "capabilities", frozenset())) - set(CAPABILITIES))
    if unknown:
        bad(f"capabilities {unknown} are not known; valid: {', '.join(CAPABILITIES)}")
    max_h = getattr(suite, "max_horizon", None)
    if max_h is not None and (not isinstance(max_h, int) or max_h < getattr(suite, "default_horizon", 0)):
        bad(f"max_horizon {max_h!r} must be None or an int >= default_horizon")
    cells = suite.all_cells()
    if not cells or not all(isinstance(c, Cell) for c in cells):
        bad("all_cells() must return a non-empty list of bench.protocols.suite.Cell")
        return problems
    for c in cells:
        if c.suite != suite.name or c.split not in SPLITS:
            bad(f"cell {c.key}: suite {c.suite!r} / split {c.split!r} (expected {suite.name!r} / seen|unseen)")
            break
    if len({c.key for c in cells}) != len(cells):
        bad("two cells share a key (task/robot/env)")
    for c in cells[:1]:
        spec = suite.obs_spec(c)
        if STATE in spec and not spec[STATE].fields:
            bad(f"obs_spec({c.key})['state'] names no fields")
    return problems


def check_contract(suite: Suite, cell: Cell, horizon: int, steps: int = 20, seed: int = 123) -> list[Problem]:
    """Gymnasium-checker-like test of one cell's env: spec, reset/step, success, finiteness, determinism."""
    problems: list[Problem] = []
    env = suite.make_env(cell, horizon)
    where = f"{suite.name}:{cell.key}"

    def bad(msg: str) -> None:
        problems.append(Problem("contract", f"{where}: {msg}"))

    try:
        if not isinstance(env, EnvAdapter):
            missing = [
                a
                for a in (
                    "backend",
                    "horizon",
                    "fps",
                    "obs_spec",
                    "action_spec",
                    "mujoco",
                    "inputs",
                    "model_axes",
                    "reset",
                    "step",
                    "success",
                    "init_state",
                    "close",
                )
                if not hasattr(env, a)
            ]
            bad(f"the env is not an EnvAdapter (missing: {', '.join(missing)})")
            return problems
        declared = dict(suite.obs_spec(cell))
        if dict(env.obs_spec) != declared:
            bad(f"env.obs_spec {sorted(env.obs_spec)} differs from the suite's declared obs_spec {sorted(declared)}")
        low, high = np.asarray(env.action_spec.low), np.asarray(env.action_spec.high)
        if low.shape != (env.action_spec.dim,) or high.shape != low.shape or np.any(low > high):
            bad(f"action bounds {low.shape}/{high.shape} do not match {env.action_spec.dim} action names")
        rng = np.random.default_rng(seed)
        finite = np.isfinite(low) & np.isfinite(high)
        actions = np.where(
            finite, rng.uniform(np.where(finite, low, -1), np.where(finite, high, 1), size=(steps, len(low))), 0.0
        ).astype(np.float32)
        runs = []
        for _ in range(2):
            obs = env.reset(seed)
            why = check_obs(env.obs_spec, obs)
            if why:
                bad(f"reset: {why}")
                break
            traj = [np.asarray(obs[STATE], np.float64).copy()] if STATE in obs else []
            for a in actions:
                out = env.step(a)
                if not isinstance(out, tuple) or len(out) != 5:
                    bad("step must return (obs, reward, terminated, truncated, info)")
                    break
                obs, reward, terminated, truncated, info = out
                why = check_obs(env.obs_spec, obs)
                if why:
                    bad(f"step: {why}")
                    break
                if not isinstance(env.success(), (bool, np.bool_)):
                    bad(f"success() returned {type(env.success()).__name__}, expected bool")
                    break
                if not np.isfinite(reward) or (STATE in obs and not np.all(np.isfinite(obs[STATE]))):
                    bad("non-finite observation or reward")
                    break
                if STATE in obs:
                    traj.append(np.asarray(obs[STATE], np.float64).copy())
                if terminated or truncated:
                    break
            runs.append(np.stack(traj) if traj else np.zeros((0,)))
        if len(runs) == 2 and (runs[0].shape != runs[1].shape or not np.allclose(runs[0], runs[1], atol=1e-9)):
            bad("same seed and actions gave different trajectories")
    finally:
        env.close()
    return problems

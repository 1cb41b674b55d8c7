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

Contract (Gymnasium-checker style), on one cell of every registered suite: observation size and
dtype match `obs_names`, actions have the declared bounds, `info["success"]` is a bool, and the
same seed and actions give the same trajectory twice.
"""
from __future__ import annotations

import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from bench import config as config_mod
from bench.env import state_hash
from bench.errors import ConfigError
from bench.suite import Cell, Job, episode_seed


@dataclass(frozen=True)
class Problem:
    """One hygiene or contract violation, phrased for the user."""

    kind: str      # manifest | cell | seeds | wraparound | cross-split | contract
    message: str


def check_manifest(manifest: dict[str, dict[str, list]], source: str = "manifest") -> list[Problem]:
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


_AXIS_ATTR = {"robots": "robot", "tasks": "task", "envs": "env", "scenes": "env"}


def check_cells(cells: list[Cell], manifest: dict[str, dict[str, list]]) -> list[Problem]:
    """Each cell's split must match what the manifest says about its robot/task/env."""
    problems = []
    for cell in cells:
        for axis, split in manifest.items():
            attr = _AXIS_ATTR.get(axis)
            if attr is None:
                continue
            value = getattr(cell, attr)
            if value in split.get("unseen", []) and cell.split == "seen":
                problems.append(Problem("cell", f"cell {cell.key} is marked seen but {axis} {value!r} is unseen"))
            if value in split.get("seen", []) and value not in split.get("unseen", []) and cell.split == "unseen" \
                    and len(split.get("unseen", [])) > 0:
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


def fast_check(suite, cells: list[Cell], jobs: list[Job]) -> list[Problem]:
    """The checks `bench run` does before starting (nothing is built)."""
    return check_manifest(suite.manifest, f"suite {suite.name}") + check_cells(cells, suite.manifest) + check_seeds(jobs)


def check_init_states(suite, cells: list[Cell], seeds: list[int], horizon: int,
                      seed_transform=None) -> tuple[list[Problem], dict[str, list[str]]]:
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
            problems.append(Problem("wraparound", f"cell {cell.key}: episodes {i} and {j} (seeds {seeds[i]}, {seeds[j]}) "
                                                  f"start from the same state ({len(dup)} repeated pair(s))"))
        for h in set(hs):
            other = owner.get(h)
            if other is not None and other.split != cell.split:
                problems.append(Problem("cross-split", f"cells {other.key} ({other.split}) and {cell.key} ({cell.split}) "
                                                       "share an initial state"))
            owner.setdefault(h, cell)
    return problems, hashes


def check_contract(suite, cell: Cell, horizon: int, steps: int = 20, seed: int = 123) -> list[Problem]:
    """Gymnasium-checker-like test of one cell's env: spaces, reset/step, determinism."""
    problems: list[Problem] = []
    env = suite.make_env(cell, horizon)
    where = f"{suite.name}:{cell.key}"
    try:
        width = sum(w for _, w in env.obs_names)
        low, high = np.asarray(env.action_low), np.asarray(env.action_high)
        if low.shape != (len(env.action_names),) or high.shape != low.shape or np.any(low > high):
            problems.append(Problem("contract", f"{where}: action bounds {low.shape}/{high.shape} do not match "
                                                f"{len(env.action_names)} action names"))
        rng = np.random.default_rng(seed)
        actions = rng.uniform(low, high, size=(steps, len(low))).astype(np.float32)
        runs = []
        for _ in range(2):
            obs = env.reset(seed)
            traj = [np.asarray(obs, np.float64).copy()]
            if np.shape(obs) != (width,) or np.asarray(obs).dtype != np.float32:
                problems.append(Problem("contract", f"{where}: reset returned shape {np.shape(obs)} dtype "
                                                    f"{np.asarray(obs).dtype}, expected ({width},) float32"))
                break
            for a in actions:
                obs, reward, done, info = env.step(a)
                if not isinstance(info.get("success"), (bool, np.bool_)):
                    problems.append(Problem("contract", f"{where}: info['success'] is "
                                                        f"{type(info.get('success')).__name__}, expected bool"))
                    break
                if not np.all(np.isfinite(obs)) or not np.isfinite(reward):
                    problems.append(Problem("contract", f"{where}: non-finite observation or reward"))
                    break
                traj.append(np.asarray(obs, np.float64).copy())
                if done:
                    break
            runs.append(np.stack(traj))
        if len(runs) == 2 and (runs[0].shape != runs[1].shape or not np.allclose(runs[0], runs[1], atol=1e-9)):
            problems.append(Problem("contract", f"{where}: same seed and actions gave different trajectories"))
    finally:
        env.close()
    return problems


@dataclass(frozen=True)
class CheckConfig:
    """Keys of `bench check`."""

    suite: Optional[str] = None          # a registered suite; default: every registered suite
    robots: Optional[list[str]] = None   # only these robots
    tasks: Optional[list[str]] = None    # only these tasks
    envs: Optional[list[str]] = None     # only these envs/scenes
    splits: Optional[list[str]] = None   # only these splits
    episodes: int = 5                    # episode seeds per cell for the initial-state check
    seed: int = 0                        # run seed the episode seeds derive from
    states: bool = True                  # build envs and hash initial states (slower)
    contract: bool = True                # run the contract test on one cell per suite
    manifest: Optional[str] = None       # check an external manifest instead, e.g. metaworld:ML25
    wrap_seeds: int = 0                  # inject a bug: reset with seed % wrap_seeds (shows the check works)
    env_id: Optional[str] = None         # for suite=gym
    perturb: dict[str, Any] = field(default_factory=dict)  # unused; accepted so run configs can be reused


HELP = """usage: bench check [suite=NAME] [key=value ...]

Checks that "unseen really is unseen" and that suites honour the simulator contract:
  - seen/unseen manifests disjoint on every axis, cells consistent with the manifest,
  - episode seeds distinct; initial-state hashes: no two seeds with the same initial state
    (seed wrap-around) and no initial state shared by a seen and an unseen cell,
  - contract on one cell per suite: spaces, reset/step, same seed -> same trajectory.
Exit 0 when clean, 2 when a problem is found. `bench run` runs the manifest/seed part first.

keys:
  suite=NAME          a registered suite (default: all)
  robots/tasks/envs/splits=[...]   restrict the cells
  episodes=5 seed=0   episode seeds per cell for the initial-state check
  states=false        skip building envs (manifest and seeds only)
  contract=false      skip the contract test
  manifest=metaworld:ML25   check Meta-World's own ML10/ML25/ML45 definition
  wrap_seeds=N        inject a seed wrap-around bug (reset with seed % N) to see it caught

examples:
  bench check suite=held_out_robots robots=[Panda,UR5e]
  bench check manifest=metaworld:ML25
  bench check suite=held_out_robots robots=[Panda] wrap_seeds=2 contract=false
"""


def main(argv: list[str]) -> int:
    if argv and argv[0] in ("-h", "--help"):
        print(HELP)
        return 0
    from bench import registry

    cfg: CheckConfig = config_mod.build_from_argv(CheckConfig, argv, "bench check")
    problems: list[Problem] = []
    t0 = time.perf_counter()
    if cfg.manifest:
        source, _, name = cfg.manifest.partition(":")
        if source != "metaworld" or not name:
            raise ConfigError(f"manifest={cfg.manifest!r}: valid: metaworld:ML10, metaworld:ML25, metaworld:ML45")
        from bench.sim_metaworld import metaworld_manifest

        problems += check_manifest(metaworld_manifest(name), f"Meta-World {name.upper()}")
        return _report(problems, t0)
    names = [cfg.suite] if cfg.suite else registry.names(registry.SUITES)
    for name in names:
        suite = registry.make_suite(name)
        if hasattr(suite, "configure"):
            if name == "gym" and not cfg.env_id and not cfg.suite:
                print(f"{name}: skipped (needs env_id=)")
                continue
            suite.configure(cfg)
        cells = suite.cells(cfg)
        seeds = [episode_seed(cfg.seed, e) for e in range(cfg.episodes)]
        jobs = [Job(c, _nominal(), e, s) for c in cells for e, s in enumerate(seeds)]
        found = fast_check(suite, cells, jobs)
        print(f"{name}: manifest and {len(cells)} cells: {'ok' if not found else f'{len(found)} problem(s)'}")
        problems += found
        if cfg.states:
            wrap = (lambda s: s % cfg.wrap_seeds) if cfg.wrap_seeds else None
            found, _ = check_init_states(suite, cells, seeds, suite.default_horizon, wrap)
            print(f"{name}: initial states of {len(cells)} cells x {len(seeds)} seeds: "
                  f"{'ok' if not found else f'{len(found)} problem(s)'}")
            problems += found
        if cfg.contract:
            found = check_contract(suite, cells[0], suite.default_horizon)
            print(f"{name}: contract on {cells[0].key}: {'ok' if not found else f'{len(found)} problem(s)'}")
            problems += found
    return _report(problems, t0)


def _nominal():
    from bench.suite import NOMINAL

    return NOMINAL


def _report(problems: list[Problem], t0: float) -> int:
    for p in problems:
        print(f"  [{p.kind}] {p.message}")
    print(f"{'clean' if not problems else f'{len(problems)} problem(s)'} ({time.perf_counter() - t0:.1f} s)")
    return 0 if not problems else 2

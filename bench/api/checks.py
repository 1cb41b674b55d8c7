"""`bench check` from Python: split hygiene (manifests, seeds, initial states) and the plugin contract of suites,
or an external manifest (`bench.execution.check` has the checks)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Optional

from bench.core import config as config_mod
from bench.core.errors import ConfigError
from bench.execution.check import Problem, check_contract, check_init_states, check_manifest, check_suite, fast_check
from bench.protocols import Suite, registry
from bench.protocols.suite import NOMINAL, Job, episode_seed, select_cells
from bench.sims.metaworld import metaworld_manifest

__all__ = ["CheckConfig", "CheckReport", "Problem", "check"]


@dataclass(frozen=True)
class CheckConfig:
    """Keys of `bench check`."""

    suite: Optional[str] = None  # a suite (registered or package.module:Class); default: every registered suite
    robots: Optional[list[str]] = None  # only these robots
    tasks: Optional[list[str]] = None  # only these tasks
    envs: Optional[list[str]] = None  # only these envs/scenes
    splits: Optional[list[str]] = None  # only these splits
    episodes: int = 5  # episode seeds per cell for the initial-state check
    seed: int = 0  # run seed the episode seeds derive from
    states: bool = True  # build envs and hash initial states (slower)
    contract: bool = True  # run the contract test on one cell per suite
    manifest: Optional[str] = None  # check an external manifest instead, e.g. metaworld:ML25
    wrap_seeds: int = 0  # inject a bug: reset with seed % wrap_seeds (shows the check works)


@dataclass(frozen=True)
class CheckReport:
    """What `check` found: every problem (none: clean) and how long the checks took."""

    problems: list[Problem]
    wall_s: float

    @property
    def clean(self) -> bool:
        return not self.problems


def _required(options_type: type) -> list[str]:
    return [
        f.name
        for f in dataclasses.fields(options_type)
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]


def _verdict(found: list[Problem]) -> str:
    return "ok" if not found else f"{len(found)} problem(s)"


def check(cfg: CheckConfig, suite_keys: Sequence[str] = (), note: Callable[[str], None] | None = None) -> CheckReport:
    """Check `cfg.suite` (or every registered suite), or the external manifest `cfg.manifest`.

    `suite_keys`: the named suite's own `key=value` settings (e.g. `env_id=CartPole-v1` for suite=gym); checking
    every suite skips those whose required keys are not given, and those unavailable here. `note` gets one line
    per suite and check as it finishes (what `bench check` prints).
    """
    say = note or (lambda _line: None)
    t0 = time.perf_counter()
    problems: list[Problem] = []
    if cfg.manifest:
        source, _, name = cfg.manifest.partition(":")
        if source != "metaworld" or not name:
            raise ConfigError(f"manifest={cfg.manifest!r}: valid: metaworld:ML10, metaworld:ML25, metaworld:ML45")
        problems += check_manifest(metaworld_manifest(name), f"Meta-World {name.upper()}")
        return CheckReport(problems, time.perf_counter() - t0)
    names = [cfg.suite] if cfg.suite else registry.names(registry.SUITES)
    for name in names:
        cls: type[Suite] = registry.suite_class(name)
        required = _required(cls.Options)
        if required and not cfg.suite:
            say(f"{name}: skipped (needs {', '.join(f'{k}=' for k in required)})")
            continue
        unavailable = getattr(cls, "unavailable", None)
        why = unavailable() if unavailable is not None and not cfg.suite else None
        if why:
            say(f"{name}: skipped (unavailable: {why})")
            continue
        suite = cls(config_mod.build(cls.Options, list(suite_keys) if cfg.suite else []))
        problems += check_suite(suite)
        cells = select_cells(suite, cfg)
        seeds = [episode_seed(cfg.seed, e) for e in range(cfg.episodes)]
        jobs = [Job(c, NOMINAL, e, s) for c in cells for e, s in enumerate(seeds)]
        found = fast_check(suite, cells, jobs)
        say(f"{name}: manifest and {len(cells)} cells: {_verdict(found)}")
        problems += found
        if cfg.states:
            wrap = (lambda s: s % cfg.wrap_seeds) if cfg.wrap_seeds else None
            found, _ = check_init_states(suite, cells, seeds, suite.default_horizon, wrap)
            say(f"{name}: initial states of {len(cells)} cells x {len(seeds)} seeds: {_verdict(found)}")
            problems += found
        if cfg.contract:
            found = check_contract(suite, cells[0], suite.default_horizon)
            say(f"{name}: contract on {cells[0].key}: {_verdict(found)}")
            problems += found
    return CheckReport(problems, time.perf_counter() - t0)

"""`bench check`: its keys, its help and the command over `bench.execution.check`."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, fields
from typing import Optional

from bench.core import config as config_mod
from bench.core.errors import ConfigError
from bench.execution.check import Problem, check_contract, check_init_states, check_manifest, check_suite, fast_check
from bench.protocols import Suite, option_keys, registry
from bench.protocols.suite import NOMINAL, Job, episode_seed, select_cells
from bench.sims.metaworld import metaworld_manifest


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


def help_text() -> str:
    return config_mod.command_help(
        "usage: bench check [suite=NAME] [key=value ...]",
        'Checks that "unseen really is unseen" and that suites honour the plugin contract:\n'
        "  - seen/unseen manifests disjoint on every axis, cells consistent with the manifest,\n"
        "  - episode seeds distinct; initial-state hashes: no two seeds with the same initial state\n"
        "    (seed wrap-around) and no initial state shared by a seen and an unseen cell,\n"
        "  - the suite against the Suite protocol, and on one cell its env against EnvAdapter: declared\n"
        "    observation spec, spaces, reset/step/success, finite numbers, same seed -> same trajectory.\n"
        "Exit 0 when clean, 2 when a problem is found. `bench run` runs the manifest/seed part first.\n"
        "A suite's own keys (e.g. env_id= for suite=gym) are accepted when suite= names it; checking\n"
        "every suite skips those whose required keys are not given.",
        CheckConfig,
        [
            "bench check suite=held_out_robots robots=[Panda,UR5e]",
            "bench check suite=gym env_id=CartPole-v1",
            "bench check manifest=metaworld:ML25",
            "bench check suite=held_out_robots robots=[Panda] wrap_seeds=2 contract=false",
        ],
    )


def _required(options_type: type) -> list[str]:
    return [
        f.name
        for f in dataclasses.fields(options_type)
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]


def main(argv: list[str]) -> int:
    if argv and argv[0] in ("-h", "--help"):
        print(help_text(), end="")
        return 0

    positional, overrides = config_mod.split_args(argv)
    if positional:
        raise ConfigError(f"unexpected argument {positional[0]!r}; bench check takes key=value only")
    own = [f.name for f in fields(CheckConfig)]
    head = config_mod.build(CheckConfig, [o for o in overrides if config_mod.top_key(o) == "suite"])
    names = [head.suite] if head.suite else registry.names(registry.SUITES)
    suite_keys: list[str] = []
    if head.suite:
        head_cls: type[Suite] = registry.suite_class(head.suite)
        suite_keys = option_keys(head_cls.Options)
    parts = config_mod.partition(overrides, {"check": own, f"suite {head.suite}": suite_keys}, "bench check")
    cfg: CheckConfig = config_mod.build(CheckConfig, parts["check"])
    problems: list[Problem] = []
    t0 = time.perf_counter()
    if cfg.manifest:
        source, _, name = cfg.manifest.partition(":")
        if source != "metaworld" or not name:
            raise ConfigError(f"manifest={cfg.manifest!r}: valid: metaworld:ML10, metaworld:ML25, metaworld:ML45")

        problems += check_manifest(metaworld_manifest(name), f"Meta-World {name.upper()}")
        return _report(problems, t0)
    for name in names:
        cls: type[Suite] = registry.suite_class(name)
        required = _required(cls.Options)
        given = parts.get(f"suite {head.suite}", []) if head.suite else []
        if required and not head.suite:
            print(f"{name}: skipped (needs {', '.join(f'{k}=' for k in required)})")
            continue
        unavailable = getattr(cls, "unavailable", None)
        why = unavailable() if unavailable is not None and not head.suite else None
        if why:
            print(f"{name}: skipped (unavailable: {why})")
            continue
        suite = cls(config_mod.build(cls.Options, given))
        problems += check_suite(suite)
        cells = select_cells(suite, cfg)
        seeds = [episode_seed(cfg.seed, e) for e in range(cfg.episodes)]
        jobs = [Job(c, NOMINAL, e, s) for c in cells for e, s in enumerate(seeds)]
        found = fast_check(suite, cells, jobs)
        print(f"{name}: manifest and {len(cells)} cells: {'ok' if not found else f'{len(found)} problem(s)'}")
        problems += found
        if cfg.states:
            wrap = (lambda s: s % cfg.wrap_seeds) if cfg.wrap_seeds else None
            found, _ = check_init_states(suite, cells, seeds, suite.default_horizon, wrap)
            print(
                f"{name}: initial states of {len(cells)} cells x {len(seeds)} seeds: "
                f"{'ok' if not found else f'{len(found)} problem(s)'}"
            )
            problems += found
        if cfg.contract:
            found = check_contract(suite, cells[0], suite.default_horizon)
            print(f"{name}: contract on {cells[0].key}: {'ok' if not found else f'{len(found)} problem(s)'}")
            problems += found
    return _report(problems, t0)


def _report(problems: list[Problem], t0: float) -> int:
    for p in problems:
        print(f"  [{p.kind}] {p.message}")
    print(f"{'clean' if not problems else f'{len(problems)} problem(s)'} ({time.perf_counter() - t0:.1f} s)")
    return 0 if not problems else 2

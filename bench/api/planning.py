"""A run planned: `bench run`'s argv parsed once (`parse_run`), the suite, policy, cells, conditions and
executor resolved and every key checked before anything is written (`plan`, `plan_with_workers`); the
`Plan` a run executes, with its calibration (`Calibration`) and worker count. Re-exported by `bench.api`."""

from __future__ import annotations

import dataclasses
import functools
import json
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from bench.core import config as config_mod
from bench.core import provenance
from bench.core.errors import (
    ConfigError,
    SplitError,
)
from bench.execution import vector
from bench.execution.check import fast_check
from bench.execution.episode_video import check_run
from bench.execution.local import LocalExecutor
from bench.execution.ray_executor import RayExecutor
from bench.execution.rollout import RunContext
from bench.execution.run_config import (
    RUNNER_KEYS,
    RunConfig,
    build_options,
    check_outputs,
    check_runner,
    check_work,
    observation_bytes,
)
from bench.execution.runner import WorkerSpec
from bench.protocols import PolicyIdentity, PolicyPlugin, Suite, describe_spec, option_keys, registry
from bench.protocols.executor import Executor
from bench.protocols.suite import Cell, Condition, Job, expand_jobs, policy_ref, select_cells
from bench.scoring.curves import check_curves
from bench.sims import perturb
from bench.sims.perturb import axes, language
from bench.sims.perturb.reset import ModelEdit


@dataclass(frozen=True)
class Calibration:
    """A suite calibration loaded for a run (`calibration=`, `bench.calibrate.apply.load`): its robot's cells run
    the model with `edits` written in."""

    path: str  # the calibration.json, absolute
    sha256: str  # of that file
    robot: str  # the robot of the suite it was fitted for
    model_hash: str  # the fingerprint of the model it was fitted on
    joints: tuple[str, ...]  # the joints the fingerprint covers
    edits: tuple[ModelEdit, ...]  # model values by name ({field, element, value[, column]})
    trust: Mapping[str, Any] | None  # the forward check on held-out data (None: never checked)
    robot_hash: str | None = None  # a portable calibration's robot fingerprint (any suite with that robot)
    delay_steps: int = 0  # a servo calibration's transport delay: the robot's commands act this many steps late

    @classmethod
    def of(cls, loaded: Mapping[str, Any]) -> Calibration:
        """From what `bench.calibrate.apply.load` returns."""
        return cls(
            path=str(loaded["path"]),
            sha256=str(loaded["sha256"]),
            robot=str(loaded["robot"]),
            model_hash=str(loaded["model_hash"]),
            joints=tuple(loaded["joints"]),
            edits=tuple(loaded["edits"]),
            trust=loaded.get("trust"),
            robot_hash=loaded.get("robot_hash"),
            delay_steps=int(loaded.get("delay_steps", 0)),
        )

    def loaded(self) -> dict[str, Any]:
        """The mapping `bench.calibrate.apply`'s checks and descriptions read (what `load` returned)."""
        out = {
            "path": self.path,
            "sha256": self.sha256,
            "robot": self.robot,
            "model_hash": self.model_hash,
            **({"robot_hash": self.robot_hash} if self.robot_hash is not None else {}),
            "joints": list(self.joints),
            "edits": list(self.edits),
            "trust": self.trust,
            **({"delay_steps": self.delay_steps} if self.delay_steps else {}),
        }
        return out

    def provenance(self) -> dict[str, Any]:
        """What run.json records of it: where it is (portable), its sha256, robot, model fingerprint and trust."""
        return {
            "path": provenance.portable(self.path),
            "sha256": self.sha256,
            "robot": self.robot,
            "model_hash": self.model_hash,
            "trust": self.trust,
            **({"delay_steps": self.delay_steps} if self.delay_steps else {}),
        }


@dataclass(frozen=True)
class ParsedRun:
    """`bench run`'s arguments parsed once: the config, and the plugins and typed options the parse resolved
    (`plan` builds the run from these instead of looking them up and validating them again)."""

    config: RunConfig
    suite_cls: type[Suite]
    suite_options: Any  # an instance of the suite's Options
    policy: str  # the policy's reference: policy=, else the suite's default
    plugin: PolicyPlugin
    policy_options: Any  # an instance of the policy plugin's Options


@dataclass(frozen=True)
class Plan:
    """A checked run: everything `run` needs, resolved; nothing has been written yet."""

    config: RunConfig  # with run_id, policy and metric resolved
    suite: Suite  # built with `suite_options`
    plugin: PolicyPlugin
    suite_options: Any  # an instance of the suite's Options
    policy_options: Any  # an instance of the policy plugin's Options
    identity: PolicyIdentity
    calibration: Calibration | None  # the loaded suite calibration (calibration=), or None
    cells: list[Cell]
    conditions: list[Condition]
    jobs: list[Job]
    horizon: int
    run_dir: Path
    workers: int  # executor=local: the worker processes asked for (`workers_for`: workers=, 0 = all cores)

    def config_dict(self) -> dict[str, Any]:
        """The flat config stored in run.json and the summary: runner keys, then the suite's and policy's."""
        cfg = {k: getattr(self.config, k) for k in RUNNER_KEYS}
        if cfg["seed_scheme"] == "hashed":  # the default, left out: runs written before the key existed resume
            del cfg["seed_scheme"]
        if not cfg["strict"]:  # the default, left out: run.json of a run without it is as before the key existed
            del cfg["strict"]
        if cfg["vector"] == 1:  # the default, left out likewise
            del cfg["vector"]
        for opts in (self.suite_options, self.policy_options):
            if dataclasses.is_dataclass(opts) and not isinstance(opts, type):
                cfg.update(dataclasses.asdict(opts))
        out: dict[str, Any] = json.loads(json.dumps(cfg))
        return out

    def worker_spec(self, ctx: RunContext, build_memo: str | None = None) -> WorkerSpec:
        cal = self.calibration
        return WorkerSpec(
            self.config.suite,
            self.suite_options,
            str(self.config.policy),
            self.policy_options,
            self.config.seed,
            ctx,
            (cal.robot, cal.edits) if cal is not None else None,
            build_memo,
            self.config.vector,
            cal.delay_steps if cal is not None else 0,
        )


def load_suite(ref: str, **options: Any) -> Suite:
    """The suite `ref` (registered name or package.module:Class) built with typed `options`."""
    cls = registry.suite_class(ref)
    return cls(build_options(cls.Options, options, f"suite {ref}"))


def load_policy(ref: str) -> PolicyPlugin:
    """The policy plugin `ref` (registered name or package.module:attr)."""
    return registry.load_policy(ref)


def workers_for(cfg: RunConfig) -> int:
    """The worker processes a run asks for: `workers=`, or every core with workers=0 (executor=local)."""
    return cfg.workers or os.cpu_count() or 1


def make_executor(cfg: RunConfig, workers: int, note: Callable[[str], None] | None = None) -> Executor:
    """The executor `cfg` asks for: local processes, or actors on a Ray cluster."""
    if cfg.executor == "ray":
        return RayExecutor(cfg.ray_address, cfg.actors, cfg.actor_cpus, cfg.actor_gpus, cfg.ray_env, note=note)
    return LocalExecutor(workers)


def _route(argv: Sequence[str]) -> tuple[RunConfig, type[Suite], str, PolicyPlugin, list[list[str]]]:
    """`bench run`'s arguments routed: the runner's keys built into a RunConfig, the suite class and the policy
    plugin they name, and the `key=value` overrides of [runner, suite, policy]."""
    positional, overrides = config_mod.split_args(argv)
    if positional:
        raise ConfigError(f"unexpected argument {positional[0]!r}; bench run takes key=value only (bench run --help)")
    head = config_mod.build(RunConfig, [o for o in overrides if config_mod.top_key(o) in ("suite", "policy")])
    suite_cls = registry.suite_class(head.suite)
    ref = policy_ref(suite_cls, head.policy)
    plugin = registry.load_policy(ref)
    owners = {
        "runner": RUNNER_KEYS,
        f"suite {head.suite}": option_keys(suite_cls.Options),
        f"policy {ref}": option_keys(plugin.Options),
    }
    parts = list(config_mod.partition(overrides, owners, f"suite={head.suite} policy={ref}").values())
    return config_mod.build(RunConfig, parts[0]), suite_cls, ref, plugin, parts


def parse_run(argv: Sequence[str]) -> ParsedRun:
    """`key=value` arguments of `bench run` parsed once: each key routed to the runner, the suite or the policy,
    each owner's keys typed, the plugins looked up once; `plan` takes the result as it is (`bench run` does).

    A key that none of them declares is refused with every owner's keys listed (e.g.
    `checkpoint=` without a policy that takes one, or `env_id=` for a suite other than gym).
    """
    cfg, suite_cls, ref, plugin, (_, suite_keys, policy_keys) = _route(argv)
    suite_options: Any = config_mod.build(suite_cls.Options, suite_keys)  # an instance of the suite's Options
    policy_options: Any = config_mod.build(plugin.Options, policy_keys)
    cfg = dataclasses.replace(
        cfg,
        suite_options=dataclasses.asdict(suite_options) if suite_keys else {},
        policy_options=dataclasses.asdict(policy_options) if policy_keys else {},
    )
    return ParsedRun(cfg, suite_cls, suite_options, ref, plugin, policy_options)


def config_from_argv(argv: Sequence[str]) -> RunConfig:
    """`key=value` arguments of `bench run` -> a RunConfig (the suite's and policy's keys given as dicts, checked
    against their Options); `parse_run` also keeps the plugins and typed options for `plan`."""
    cfg, suite_cls, _, plugin, (_, suite_keys, policy_keys) = _route(argv)
    suite_opts: dict[str, Any] = (
        dataclasses.asdict(config_mod.build(suite_cls.Options, suite_keys)) if suite_keys else {}
    )
    policy_opts: dict[str, Any] = (
        dataclasses.asdict(config_mod.build(plugin.Options, policy_keys)) if policy_keys else {}
    )
    return dataclasses.replace(cfg, suite_options=suite_opts, policy_options=policy_opts)


def _resolve(cfg: RunConfig) -> tuple[Suite, ParsedRun]:
    """A config built in Python: its plugins looked up and its suite's and policy's keys typed (what `parse_run`
    does for `key=value` arguments), and the suite built."""
    suite_cls = registry.suite_class(cfg.suite)
    suite_options = build_options(suite_cls.Options, cfg.suite_options, f"suite {cfg.suite}")
    suite = suite_cls(suite_options)
    ref = policy_ref(suite, cfg.policy)
    plugin = registry.load_policy(ref)
    policy_options = build_options(plugin.Options, cfg.policy_options, f"policy {ref}")
    return suite, ParsedRun(cfg, suite_cls, suite_options, ref, plugin, policy_options)


def plan_with_workers(cfg: RunConfig | ParsedRun, own_process: bool = False) -> tuple[Plan, Executor]:
    """`plan(cfg)` and the executor `run` should use, its local worker processes already starting.

    The children start as soon as the job count is known and import what the suite and policy `preload`
    (robosuite, torch) while this process finishes the plan (a checkpoint's preflight imports torch, ~1 s),
    so they reach their first episode about when this process does. A plan that fails closes the executor
    (its children are killed; they wrote nothing); otherwise pass both to `run`, which closes it.
    `own_process`: this process exists for the run (the `bench run` command; see `LocalExecutor`).
    """
    config = cfg.config if isinstance(cfg, ParsedRun) else cfg
    workers = workers_for(config)
    if config.executor != "local":  # a cluster's workers are reached in `run`
        p = plan(cfg, workers=workers)
        return p, make_executor(config, workers)
    executor = LocalExecutor(workers, own_process)
    try:
        p = plan(cfg, on_jobs=functools.partial(executor.prestart, config.suite, config.policy), workers=workers)
    except BaseException:
        executor.close()
        raise
    return p, executor


def plan(
    cfg: RunConfig | ParsedRun, on_jobs: Callable[[int], None] | None = None, *, workers: int | None = None
) -> Plan:
    """Check everything a run needs (keys, plugins, cells, observation keys, perturbations, splits); write nothing.

    `cfg`: a RunConfig (its plugins are looked up and its options typed here), or `parse_run`'s result (used as
    parsed). `on_jobs` is called with the number of jobs as soon as it is known, before the policy's preflight
    (which may import torch, ~1 s): `bench run` starts its worker processes there (`LocalExecutor.prestart`).
    `workers`: what `workers_for(config)` gave, when the caller already has it.
    """
    config = cfg.config if isinstance(cfg, ParsedRun) else cfg
    check_runner(config)
    if isinstance(cfg, ParsedRun):
        parsed = cfg
        suite = cfg.suite_cls(cfg.suite_options)
    else:
        suite, parsed = _resolve(cfg)
    plugin, policy_name, policy_options = parsed.plugin, parsed.policy, parsed.policy_options
    workers = workers_for(config) if workers is None else workers
    horizon = config.horizon or suite.default_horizon
    if suite.max_horizon is not None and horizon > suite.max_horizon:
        raise ConfigError(
            f"horizon={horizon}: suite {suite.name!r} episodes last at most {suite.max_horizon} steps "
            f"(0 = the suite default, {suite.default_horizon})"
        )
    cells = select_cells(suite, config)
    if not cells:
        raise ConfigError("the selection (robots/tasks/envs/splits) leaves no cell to run")
    needs = tuple(plugin.obs_keys(policy_options))
    step_bytes = 0
    for cell in cells:
        spec = suite.obs_spec(cell)
        step_bytes = max(step_bytes, observation_bytes(spec))
        missing = [k for k in needs if k not in spec]
        if missing:
            raise ConfigError(
                f"policy {policy_name!r} needs observation keys {missing}; suite {suite.name!r} cell "
                f"{cell.key} provides {describe_spec(spec)}"
            )
    conditions = axes.conditions_from_config(config.perturb, config.seed)
    axes.check_horizon(conditions, horizon)
    check_curves(conditions, len(cells) * config.episodes)
    n_jobs = len(cells) * len(conditions) * config.episodes
    if on_jobs is not None:
        on_jobs(n_jobs)
    identity = plugin.identity(policy_options)
    plugin.preflight(policy_options, suite, cells, horizon)
    calibration = None
    if config.calibration:
        from bench.calibrate.apply import load, refuse, verify  # mujoco and pyarrow: only calibration= runs need them

        loaded = load(config.calibration, suite.name, suite.version, [c.robot for c in cells])
        if config.strict:  # before its env is built: a model that simulates worse, or unchecked, is refused
            refuse(loaded)
        verify(suite, cells, horizon, loaded)
        calibration = Calibration.of(loaded)
    check_work(config, n_jobs, horizon, step_bytes)
    suite.check_worlds(cells, config.vector, workers)  # a batched simulator's memory per world (suites/mjx_lift.py)
    perturb.validate_run(suite, cells, conditions, horizon)  # names in the model
    if config.vector > 1:  # a batched policy's answer shape, asked once before anything is written
        vector.probe(suite, cells[0], plugin, policy_options, horizon, config.seed, config.vector)
    for cell in cells:  # a visual axis on a policy that sees no image would report a drop of +0 [0, 0]
        axes.check_policy_sees(conditions, needs, suite.obs_spec(cell), policy_name)
    # an instruction axis on a policy that reads none would report an action difference of 0 by construction
    conditions = language.prepare(conditions, suite, cells, needs, policy_name)
    if config.video:
        check_run(suite, cells, horizon)
    jobs = expand_jobs(cells, conditions, config.episodes, config.seed, config.seed_scheme)
    problems = fast_check(suite, cells, jobs)
    if problems and not config.allow_split_violation:
        raise SplitError(
            f"{problems[0].message} ({len(problems)} split problem(s); `bench check suite={config.suite}` "
            "lists them; allow_split_violation=true runs anyway)"
        )
    run_id = config.run_id or f"{suite.name}-{policy_name.replace(':', '.')}-{datetime.now().strftime('%Y%m%d-%H%M%S')}"
    resolved = dataclasses.replace(
        config, run_id=run_id, policy=policy_name, metric=config.metric or suite.default_metric
    )
    run_dir = check_outputs(config, run_id, identity.checkpoint)
    return Plan(
        resolved,
        suite,
        plugin,
        parsed.suite_options,
        policy_options,
        identity,
        calibration,
        cells,
        conditions,
        jobs,
        horizon,
        run_dir,
        workers,
    )

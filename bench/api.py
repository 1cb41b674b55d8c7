"""The typed Python API: plan and run a suite, score a run, load plugins (docs/api.md).

    from bench import api

    result = api.run(api.RunConfig(suite="held_out_robots", policy="scripted", robots=["Panda"], episodes=2))
    print(result.summary["splits"]["seen"]["success_once"]["mean"])

`plan` checks everything a run needs and writes nothing; `run` executes a plan (or a
config) into OUT/RUN_ID (episodes.jsonl, run.json, summary.json), resuming recorded
episodes. The CLI (`bench run`), the regression gate, benchmarks and experiments all go
through these functions.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Optional

from bench import config as config_mod
from bench.errors import ConfigError, SplitError
from bench.protocols import PolicyIdentity, PolicyPlugin, describe_spec, option_keys
from bench.records import EPISODES, EpisodeRecord
from bench.runner import LocalExecutor, Worker, WorkerSpec
from bench.suite import METRICS, SPLITS, Cell, Condition, Job, expand_jobs, select_cells

# limits that keep a typo from starting an absurd job (the message names the limit; bench.config owns them)
MAX_EPISODES = config_mod.MAX_EPISODES
MAX_HORIZON = config_mod.MAX_HORIZON
MAX_WORKERS = config_mod.MAX_WORKERS
MAX_N_BOOT = config_mod.MAX_N_BOOT
MAX_TIMEOUT_S = config_mod.MAX_TIMEOUT_S
MAX_RUN_ID = config_mod.MAX_RUN_ID
MAX_TOTAL_STEPS = 10**10  # control steps of one run: ~12 days at 10,000 steps/s
ranged = config_mod.ranged


@dataclass(frozen=True)
class RunConfig:
    """Keys of `bench run` (all optional; `bench run --help` prints these docs)."""

    suite: str = "held_out_robots"  # registered suite name (`bench list`) or package.module:Class
    policy: Optional[str] = None  # registered policy or package.module:attr; default: the suite's default
    episodes: int = ranged(10, 1, MAX_EPISODES)  # episodes per cell and condition
    seed: int = ranged(0, 0, config_mod.MAX_SEED)  # run seed: episode seeds, perturbation draws, bootstrap
    workers: int = ranged(0, 0, MAX_WORKERS)  # executor=local: processes running episodes; 0 = all cores
    out: str = "runs"  # parent folder of run directories
    run_id: Optional[str] = None  # run directory name; an existing one is resumed
    horizon: int = ranged(0, 0, MAX_HORIZON)  # control steps per episode; 0 = the suite's default
    timeout: float = ranged(
        600.0, 0, MAX_TIMEOUT_S, lo_open=True
    )  # wall seconds per episode before it is recorded as timed out
    robots: Optional[list[str]] = None  # only these robots (suite-dependent)
    tasks: Optional[list[str]] = None  # only these tasks
    envs: Optional[list[str]] = None  # only these environments/scenes
    splits: Optional[list[str]] = None  # only these splits: seen, unseen
    metric: Optional[str] = None  # headline metric: success_once, success_at_end, return; default: the suite's
    n_boot: int = ranged(2000, 100, MAX_N_BOOT)  # bootstrap resamples for aggregate and gap intervals
    confidence: float = ranged(0.95, 0, 1, lo_open=True, hi_open=True)  # two-sided interval level
    perturb: dict[str, Any] = field(default_factory=dict)  # perturbation axes, e.g. perturb.friction=[0.5,1,2]
    record: Optional[str] = None  # also write rollouts as a LeRobot v3 dataset here (camera images as video)
    video: int = ranged(0, 0, MAX_EPISODES)  # MP4 of the first N episodes of every cell and condition (RUN_DIR/videos)
    calibration: Optional[str] = None  # a `bench calibrate suite=` result: its robot's cells run the calibrated model
    allow_split_violation: bool = False  # run even if `bench check` finds a split problem
    executor: str = "local"  # where episodes run: local (processes on this machine) or ray (docs/ray.md)
    ray_address: str = "auto"  # executor=ray: auto (the cluster here), HOST:PORT, or local (a private one)
    actors: int = ranged(0, 0, MAX_WORKERS)  # executor=ray: long-lived worker actors; 0 = as many as the cluster allows
    actor_cpus: float = ranged(1.0, 0, 1024, lo_open=True)  # executor=ray: CPUs each actor reserves
    actor_gpus: float = ranged(0.0, 0, 64)  # executor=ray: GPUs each actor reserves (ManiSkill on GPU, renderers)
    ray_env: str = "code"  # executor=ray: code (ship this checkout), pip (also its pins), installed
    suite_options: dict[str, Any] = field(default_factory=dict)
    policy_options: dict[str, Any] = field(default_factory=dict)


# keys that may differ when a run is resumed: where and how episodes run, not what they compute
RESUMABLE_KEYS = {
    "workers",
    "timeout",
    "out",
    "run_id",
    "executor",
    "ray_address",
    "actors",
    "actor_cpus",
    "actor_gpus",
    "ray_env",
}
EXECUTORS = ("local", "ray")
RAY_KEYS = {"ray_address": "auto", "actors": 0, "actor_cpus": 1.0, "actor_gpus": 0.0, "ray_env": "code"}
RUNNER_KEYS = [f.name for f in dataclasses.fields(RunConfig) if f.name not in ("suite_options", "policy_options")]


@dataclass(frozen=True)
class Plan:
    """A checked run: everything `run` needs, resolved; nothing has been written yet."""

    config: RunConfig  # with run_id, policy and metric resolved
    suite: Any  # the Suite, built with `suite_options`
    plugin: PolicyPlugin
    suite_options: Any  # an instance of the suite's Options
    policy_options: Any  # an instance of the policy plugin's Options
    identity: PolicyIdentity
    calibration: dict[str, Any] | None  # a loaded suite calibration (bench.calibrate.apply.load), or None
    cells: list[Cell]
    conditions: list[Condition]
    jobs: list[Job]
    horizon: int
    run_dir: Path

    def config_dict(self) -> dict[str, Any]:
        """The flat config stored in run.json and the summary: runner keys, then the suite's and policy's."""
        cfg = {k: getattr(self.config, k) for k in RUNNER_KEYS}
        for opts in (self.suite_options, self.policy_options):
            if dataclasses.is_dataclass(opts) and not isinstance(opts, type):
                cfg.update(dataclasses.asdict(opts))
        return json.loads(json.dumps(cfg))

    def worker_spec(self, ctx: Any) -> WorkerSpec:
        return WorkerSpec(
            self.config.suite,
            self.suite_options,
            str(self.config.policy),
            self.policy_options,
            self.config.seed,
            ctx,
            self.calibration,
        )


@dataclass(frozen=True)
class RunResult:
    """What `run` produced: the run directory, its summary and all its records."""

    run_dir: Path
    summary: dict[str, Any] | None
    records: list[EpisodeRecord]
    ran: int  # episodes run by this call
    resumed: int  # episodes found already recorded


def load_suite(ref: str, **options: Any) -> Any:
    """The suite `ref` (registered name or package.module:Class) built with typed `options`."""
    from bench import registry

    cls = registry.suite_class(ref)
    return cls(_options(cls.Options, options, f"suite {ref}"))


def load_policy(ref: str) -> PolicyPlugin:
    """The policy plugin `ref` (registered name or package.module:attr)."""
    from bench import registry

    return registry.load_policy(ref)


def _options(schema: type, values: Mapping[str, Any], owner: str) -> Any:
    """`values` validated into an instance of the Options dataclass `schema` (types, required keys)."""
    bad = [k for k in values if k not in option_keys(schema)]
    if bad:
        raise ConfigError(f"unknown key {bad[0]!r} for {owner}; valid: {', '.join(option_keys(schema)) or '(none)'}")
    return config_mod.build(schema, [], base=dict(values))


def config_from_argv(argv: list[str]) -> RunConfig:
    """`key=value` arguments of `bench run` -> a RunConfig, each key routed to the runner, the suite or the policy.

    A key that none of them declares is refused with every owner's keys listed (e.g.
    `checkpoint=` without a policy that takes one, or `env_id=` for a suite other than gym).
    """
    from bench import registry

    positional, overrides = config_mod.split_args(argv)
    if positional:
        raise ConfigError(f"unexpected argument {positional[0]!r}; bench run takes key=value only (bench run --help)")
    head = config_mod.build(RunConfig, [o for o in overrides if config_mod.top_key(o) in ("suite", "policy")])
    suite_cls = registry.suite_class(head.suite)
    policy_ref = head.policy or suite_cls.default_policy or suite_cls.reference_policy
    plugin = registry.load_policy(policy_ref)
    owners = {
        "runner": RUNNER_KEYS,
        f"suite {head.suite}": option_keys(suite_cls.Options),
        f"policy {policy_ref}": option_keys(plugin.Options),
    }
    parts = list(config_mod.partition(overrides, owners, f"suite={head.suite} policy={policy_ref}").values())
    cfg = config_mod.build(RunConfig, parts[0])
    suite_opts = dataclasses.asdict(config_mod.build(suite_cls.Options, parts[1])) if parts[1] else {}
    policy_opts = dataclasses.asdict(config_mod.build(plugin.Options, parts[2])) if parts[2] else {}
    return dataclasses.replace(cfg, suite_options=suite_opts, policy_options=policy_opts)


def _check_runner(cfg: RunConfig) -> None:
    """Ranges of the runner's own keys (one line each, naming the limit): the field ranges of RunConfig
    (also for a RunConfig built in Python, not from key=value), then the keys that need more than a range."""
    config_mod.validate(cfg)
    if cfg.metric is not None and cfg.metric not in METRICS:
        raise ConfigError(f"metric={cfg.metric!r}: valid: {', '.join(METRICS)}")
    for s in cfg.splits or []:
        if s not in SPLITS:
            raise ConfigError(f"splits: {s!r} is not a split; valid: {', '.join(SPLITS)}")
    for key in ("robots", "tasks", "envs", "splits"):
        given = getattr(cfg, key) or []
        twice = next((v for i, v in enumerate(given) if v in given[:i]), None)
        if twice is not None:
            raise ConfigError(f"{key}: {twice!r} is listed twice; list each once")
    _check_executor(cfg)
    check_run_id(cfg.run_id)


def check_run_id(rid: str | None) -> None:
    """run_id names a folder under out=: non-empty, printable, no slash, not hidden, at most MAX_RUN_ID characters."""
    if rid is None:
        return
    if not isinstance(rid, str) or not rid.strip():
        raise ConfigError(f"run_id={rid!r}: must be a non-empty folder name")
    if "/" in rid or "\\" in rid or rid.startswith(".") or config_mod._CONTROL.search(rid) or len(rid) > MAX_RUN_ID:
        raise ConfigError(
            f"run_id={rid[:40]!r}{'...' if len(rid) > 40 else ''}: must be a plain folder name (no "
            f"slash, control character or leading dot) of at most {MAX_RUN_ID} characters"
        )


def check_work(cfg: RunConfig, episodes: int, horizon: int, step_bytes: int) -> None:
    """Refuse up front a run whose estimated time or memory is absurd, naming the keys that set it.

    Time: episodes x cells x conditions x horizon control steps, at most MAX_TOTAL_STEPS. Memory: an
    episode that is recorded (record=, video=) keeps horizon x observation bytes per worker; all of
    them together must fit in this machine's memory.
    """
    steps = episodes * horizon
    keys = "episodes=, horizon=, robots=/tasks=/envs= and perturb.*"
    if steps > MAX_TOTAL_STEPS:
        raise ConfigError(
            f"this run is {episodes} episodes x {horizon} steps = {steps:.3g} control steps, over the "
            f"limit of {MAX_TOTAL_STEPS:.0e}; reduce {keys}"
        )
    if cfg.record or cfg.video:
        try:
            ram = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (ValueError, OSError, AttributeError):
            return
        parallel = min(cfg.workers or os.cpu_count() or 1, max(1, episodes))
        need = horizon * step_bytes * parallel
        if need > ram:
            raise ConfigError(
                f"recording needs about {need / 2**30:.1f} GiB at once ({parallel} worker(s) x {horizon} "
                f"steps x {step_bytes} observation bytes), more than this machine's "
                f"{ram / 2**30:.1f} GiB; reduce horizon= or workers=, or leave out record=/video="
            )


def _step_bytes(spec: Any) -> int:
    """Bytes of one observation of `spec` (strings count nothing)."""
    import numpy as np

    total = 0
    for feat in spec.values():
        try:
            total += int(np.prod(feat.shape, dtype=np.float64)) * np.dtype(feat.dtype).itemsize
        except TypeError:
            continue
    return total


def _check_executor(cfg: RunConfig) -> None:
    """executor= and the keys that belong to it (a key of the other executor is refused, not ignored)."""
    from bench import ray_env

    if cfg.executor not in EXECUTORS:
        raise ConfigError(f"executor={cfg.executor!r}: valid: {', '.join(EXECUTORS)}")
    if cfg.executor == "local":
        given = [k for k, default in RAY_KEYS.items() if getattr(cfg, k) != default]
        if given:
            raise ConfigError(
                f"{given[0]}={getattr(cfg, given[0])!r} applies to executor=ray; add executor=ray or leave it out"
            )
        return
    if cfg.workers:
        raise ConfigError(
            f"workers={cfg.workers} applies to executor=local; with executor=ray give actors= "
            "(0 = as many as the cluster's CPUs allow)"
        )
    if cfg.ray_env not in ray_env.RAY_ENVS:
        raise ConfigError(f"ray_env={cfg.ray_env!r}: valid: {', '.join(ray_env.RAY_ENVS)}")
    ray_env.check_address(cfg.ray_address)
    if not ray_env.ray_installed():
        raise ConfigError(f"executor=ray needs Ray, which is not installed here: {ray_env.INSTALL}")


def make_executor(cfg: RunConfig, workers: int, note: Callable[[str], None] | None = None) -> Any:
    """The executor `cfg` asks for: local processes, or actors on a Ray cluster."""
    if cfg.executor == "ray":
        from bench.ray_executor import RayExecutor

        return RayExecutor(cfg.ray_address, cfg.actors, cfg.actor_cpus, cfg.actor_gpus, cfg.ray_env, note=note)
    return LocalExecutor(workers)


def plan(cfg: RunConfig) -> Plan:
    """Check everything a run needs (keys, plugins, cells, observation keys, perturbations, splits); write nothing."""
    from bench import axes, perturb, registry
    from bench.check import fast_check

    _check_runner(cfg)
    suite_cls = registry.suite_class(cfg.suite)
    suite_options = _options(suite_cls.Options, cfg.suite_options, f"suite {cfg.suite}")
    suite = suite_cls(suite_options)
    policy_ref = cfg.policy or suite.default_policy
    plugin = registry.load_policy(policy_ref)
    policy_options = _options(plugin.Options, cfg.policy_options, f"policy {policy_ref}")
    horizon = cfg.horizon or suite.default_horizon
    if suite.max_horizon is not None and horizon > suite.max_horizon:
        raise ConfigError(
            f"horizon={horizon}: suite {suite.name!r} episodes last at most {suite.max_horizon} steps "
            f"(0 = the suite default, {suite.default_horizon})"
        )
    cells = select_cells(suite, cfg)
    if not cells:
        raise ConfigError("the selection (robots/tasks/envs/splits) leaves no cell to run")
    needs = tuple(plugin.obs_keys(policy_options))
    step_bytes = 0
    for cell in cells:
        spec = suite.obs_spec(cell)
        step_bytes = max(step_bytes, _step_bytes(spec))
        missing = [k for k in needs if k not in spec]
        if missing:
            raise ConfigError(
                f"policy {policy_ref!r} needs observation keys {missing}; suite {suite.name!r} cell "
                f"{cell.key} provides {describe_spec(spec)}"
            )
    identity = plugin.identity(policy_options)
    plugin.preflight(policy_options, suite, cells, horizon)
    calibration = None
    if cfg.calibration:
        from bench.calibrate.apply import load, verify

        calibration = load(cfg.calibration, suite.name, suite.version, [c.robot for c in cells])
        verify(suite, cells, horizon, calibration)
    conditions = axes.conditions_from_config(cfg.perturb)
    axes.check_horizon(conditions, horizon)
    check_work(cfg, len(cells) * len(conditions) * cfg.episodes, horizon, step_bytes)
    perturb.validate_run(suite, cells, conditions, horizon)  # names in the model
    if cfg.video:
        from bench.episode_video import check_run

        check_run(suite, cells, horizon)
    jobs = expand_jobs(cells, conditions, cfg.episodes, cfg.seed)
    problems = fast_check(suite, cells, jobs)
    if problems and not cfg.allow_split_violation:
        raise SplitError(
            f"{problems[0].message} ({len(problems)} split problem(s); `bench check suite={cfg.suite}` "
            "lists them; allow_split_violation=true runs anyway)"
        )
    run_id = cfg.run_id or f"{suite.name}-{policy_ref.replace(':', '.')}-{datetime.now().strftime('%Y%m%d-%H%M%S')}"
    resolved = dataclasses.replace(cfg, run_id=run_id, policy=policy_ref, metric=cfg.metric or suite.default_metric)
    run_dir = _check_outputs(cfg, run_id, identity.checkpoint)
    return Plan(
        resolved,
        suite,
        plugin,
        suite_options,
        policy_options,
        identity,
        calibration,
        cells,
        conditions,
        jobs,
        horizon,
        run_dir,
    )


def _is_run_dir(folder: Path) -> bool:
    """A folder `bench run` may resume: it holds the run.json of a bench run."""
    try:
        meta = json.loads((folder / "run.json").read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return False
    return isinstance(meta, dict) and isinstance(meta.get("config"), dict)


def _check_outputs(cfg: RunConfig, run_id: str, checkpoint: str | None) -> Path:
    """The run directory and `record=` checked against `bench.outputs`' rule before anything is written."""
    from bench import outputs

    inputs = {"checkpoint": checkpoint, "calibration": cfg.calibration}
    if not run_id or run_id in (".", "..") or any(c in run_id for c in "/\\\0") or not run_id.isprintable():
        raise ConfigError(f"run_id={run_id!r}: a run id names one folder (printable, no slashes, not . or ..)")
    run_dir = Path(cfg.out) / run_id
    outputs.names_fit("out", str(run_dir), run_dir.expanduser().absolute())
    if run_dir.is_dir() and any(run_dir.iterdir()) and not _is_run_dir(run_dir):
        raise ConfigError(
            f"run_id={run_id!r}: {str(run_dir)!r} exists and is not a bench run directory (no run.json "
            "of a bench run); give a new run_id or out=, nothing there is touched"
        )
    outputs.check("out", run_dir, inputs, resume=_is_run_dir, can_overwrite=False)
    if cfg.record:
        outputs.check("record", cfg.record, {**inputs, "out (the run directory)": run_dir}, can_overwrite=False)
    return run_dir


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def start(p: Plan, workers: int) -> tuple[dict[str, Any], Any]:
    """Open (or resume) the run directory: writes run.json; returns (run metadata, RunContext)."""
    from bench import __version__, provenance
    from bench.io import write_atomic

    cfg = p.config
    meta = {
        "run_id": cfg.run_id,
        "suite": p.suite.describe(),
        "policy": {
            "name": cfg.policy,
            "checkpoint": p.identity.checkpoint,
            "checkpoint_sha256": p.identity.checkpoint_sha256,
        },
        "config": p.config_dict(),
        "expected_episodes": len(p.jobs),
        "provenance": {
            "bench_version": __version__,
            "git_sha": provenance.git_sha(),
            "packages": provenance.package_versions(),
            **provenance.machine(),
            "workers": workers,
            "backend": [],
            "seed": cfg.seed,
            "episode_seeds": sorted({j.seed for j in p.jobs}),
            "started_at": _now(),
            "finished_at": None,
            **(
                {"calibration": {k: p.calibration[k] for k in ("path", "sha256", "robot", "model_hash")}}
                if p.calibration
                else {}
            ),
        },
    }
    meta_path = p.run_dir / "run.json"
    if meta_path.exists():
        from bench.schema import load_json

        old = load_json(meta_path)
        new_cfg = meta["config"]
        diffs = [
            k
            for k in sorted(set(old.get("config", {})) | set(new_cfg))
            if k not in RESUMABLE_KEYS and old.get("config", {}).get(k) != new_cfg.get(k)
        ]
        if diffs:
            k = diffs[0]
            raise ConfigError(
                f"run_id={cfg.run_id!r} exists with {k}={old.get('config', {}).get(k)!r} (now "
                f"{new_cfg.get(k)!r}); use the same settings to resume it, or a new run_id"
            )
        meta = old
    else:
        write_atomic(meta_path, meta)
    ctx = dataclasses.replace(
        context(p),
        timeout_s=cfg.timeout,
        trajectory_dir=str(p.run_dir / "trajectories") if cfg.record else None,
        video_dir=str(p.run_dir) if cfg.video else None,
        video_episodes=cfg.video,
    )
    return meta, ctx


def finish(p: Plan, meta: dict[str, Any], workers: int) -> dict[str, Any]:
    """Stamp run.json (finish time, workers, backends), write and return the validated summary.json."""
    from bench.io import write_atomic
    from bench.records import read_records
    from bench.schema import validate
    from bench.summary import build

    records = read_records(p.run_dir / EPISODES)
    meta["provenance"]["finished_at"] = _now()
    meta["provenance"]["workers"] = workers
    meta["provenance"]["backend"] = sorted({r.backend for r in records if r.backend})
    write_atomic(p.run_dir / "run.json", meta)
    summary = build(records, run_meta=meta)
    validate(summary, "summary")
    write_atomic(p.run_dir / "summary.json", summary)
    return summary


def run(
    cfg: RunConfig | Plan,
    *,
    only: Callable[[Job], bool] | None = None,
    progress: bool = False,
    summarize: bool = True,
    executor: Any = None,
    on_record: Callable[[EpisodeRecord], None] | None = None,
) -> RunResult:
    """Run a config or a plan into its run directory; recorded episodes are skipped (resume).

    Args:
        cfg: a RunConfig (planned here) or a Plan from `plan`.
        only: run only the jobs it accepts (e.g. the first k episodes); the others stay to do.
        progress: show a progress bar on stderr.
        summarize: write summary.json when done (and assemble `record=` datasets).
        executor: an object with `execute(jobs, worker_spec, on_record)`; default: local processes.
        on_record: called with each new record after it is written.
    """
    from bench.records import RecordWriter, read_records

    p = cfg if isinstance(cfg, Plan) else plan(cfg)
    c = p.config
    episodes_path = p.run_dir / EPISODES
    done_ids = {r.job_id for r in read_records(episodes_path)}
    todo = [j for j in p.jobs if j.job_id not in done_ids and (only is None or only(j))]
    workers = min(c.workers or os.cpu_count() or 1, max(1, len(todo)))
    executor = executor or make_executor(c, workers)
    try:
        if todo and hasattr(executor, "connect"):  # a cluster: reached and sized before anything is written
            workers = executor.connect(len(todo), p.config.suite, str(p.config.policy))
        meta, ctx = start(p, workers)
        t0 = time.time()
        with (
            RecordWriter(episodes_path) as writer,
            _Progress(progress, c, len(todo), len(done_ids), len(p.jobs), p.run_dir, workers) as bar,
        ):

            def write(record: EpisodeRecord) -> None:
                writer.write(record)
                bar.advance(record)
                if on_record is not None:
                    on_record(record)

            if progress and hasattr(executor, "note"):
                executor.note = bar.note
            executor.execute(todo, p.worker_spec(ctx), write)
    finally:
        if hasattr(executor, "close"):
            executor.close()
    meta["provenance"]["executor"] = (
        c.executor if not hasattr(executor, "cluster") else {"kind": c.executor, **executor.cluster}
    )
    summary = finish(p, meta, workers) if summarize else None
    records = read_records(episodes_path)
    if summarize and c.record:
        from bench.recording import assemble

        path = assemble(records, p.run_dir / "trajectories", Path(c.record))
        bar.note(f"recorded {sum(r.error is None for r in records)} episodes as a LeRobot v3 dataset: {path}")
    bar.note(f"{len(todo)} episodes in {time.time() - t0:.1f} s; records: {episodes_path}")
    return RunResult(p.run_dir, summary, records, len(todo), len(done_ids))


class _Progress:
    """A rich progress bar on stderr (done/total, successes, errors, elapsed, ETA), or nothing."""

    def __init__(self, show: bool, cfg: RunConfig, todo: int, done: int, total: int, run_dir: Path, workers: int):
        self.show = show
        self.metric = "success_once" if cfg.metric == "return" else str(cfg.metric)
        self.counts = {"succ": 0, "err": 0}
        self.console = self.progress = None
        if not show:
            return
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.console = Console(stderr=True)
        if done:
            self.console.print(f"resuming {run_dir}: {done} of {total} episodes already recorded", soft_wrap=True)
        where = f"{workers} Ray actor(s)" if cfg.executor == "ray" else f"{workers} worker(s)"
        self.console.print(f"run {cfg.run_id}: {todo} episodes on {where} -> {run_dir}", soft_wrap=True)
        columns = [
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("successes {task.fields[succ]}"),
            TextColumn("errors {task.fields[err]}"),
            TimeElapsedColumn(),
            TextColumn("eta"),
            TimeRemainingColumn(),
        ]
        self.progress = Progress(*columns, console=self.console, transient=False)
        self.task = self.progress.add_task(cfg.suite, total=todo, succ=0, err=0)

    def __enter__(self) -> _Progress:
        if self.progress is not None:
            self.progress.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.progress is not None:
            self.progress.stop()

    def advance(self, record: EpisodeRecord) -> None:
        if self.progress is None:
            return
        self.counts["succ"] += int(bool(getattr(record, self.metric, False)))
        self.counts["err"] += int(record.error is not None)
        self.progress.update(self.task, advance=1, succ=self.counts["succ"], err=self.counts["err"])

    def note(self, text: str) -> None:
        if self.console is not None:
            self.console.print(text, soft_wrap=True)


def score(run_dir: str | os.PathLike[str]) -> dict[str, Any]:
    """Recompute, validate and write RUN_DIR/summary.json from its episodes.jsonl (the source of truth)."""
    from bench.io import write_atomic
    from bench.schema import validate
    from bench.summary import build, load_run

    records, meta = load_run(Path(run_dir))
    config_mod.check_stored(
        RunConfig, meta.get("config") if isinstance(meta, dict) else None, str(Path(run_dir) / "run.json")
    )
    summary = build(records, run_meta=meta)
    validate(summary, "summary")
    write_atomic(Path(run_dir) / "summary.json", summary)
    return summary


def context(p: Plan, run_id: str | None = None) -> Any:
    """The RunContext workers of plan `p` share, for runs that write no run directory (benchmarks)."""
    from bench import provenance
    from bench.rollout import RunContext

    return RunContext(
        run_id=run_id or str(p.config.run_id),
        suite_version=p.suite.version,
        policy_id=str(p.config.policy),
        checkpoint_sha256=p.identity.checkpoint_sha256,
        versions=provenance.package_versions(),
        horizon=p.horizon,
        timeout_s=0,
        policy_stats=bool(p.plugin.reports_stats),
    )


def worker(p: Plan, ctx: Any = None) -> Worker:
    """An in-process worker of a plan (benchmarks time episodes with it; nothing is written)."""
    return Worker(p.worker_spec(ctx or context(p)))

"""`bench run`: config -> suite -> jobs -> runner -> records -> summary (-> leaderboard entry)."""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Optional

from bench import config as config_mod
from bench.errors import ConfigError, SplitError


@dataclass(frozen=True)
class RunConfig:
    """Keys of `bench run` (all optional; `bench run --help` prints these docs)."""

    suite: str = "held_out_robots"          # registered suite name (`bench list`)
    policy: Optional[str] = None            # registered policy; default: the suite's reference expert
    checkpoint: Optional[str] = None        # checkpoint file for policy=checkpoint
    episodes: int = 10                      # episodes per cell and condition
    seed: int = 0                           # run seed: episode seeds, perturbation draws, bootstrap
    workers: int = 0                        # worker processes; 0 = all cores
    out: str = "runs"                       # parent folder of run directories
    run_id: Optional[str] = None            # run directory name; an existing one is resumed
    horizon: int = 0                        # control steps per episode; 0 = the suite's default
    timeout: float = 600.0                  # wall seconds per episode before it is recorded as timed out
    robots: Optional[list[str]] = None      # only these robots (suite-dependent)
    tasks: Optional[list[str]] = None       # only these tasks
    envs: Optional[list[str]] = None        # only these environments/scenes
    splits: Optional[list[str]] = None      # only these splits: seen, unseen
    metric: str = "success_once"            # headline metric: success_once or success_at_end
    n_boot: int = 2000                      # bootstrap resamples for aggregate and gap intervals
    confidence: float = 0.95                # two-sided interval level
    perturb: dict[str, Any] = field(default_factory=dict)  # perturbation axes, e.g. perturb.friction=[0.5,1,2]
    env_id: Optional[str] = None            # Gymnasium env id for suite=gym
    record: Optional[str] = None            # also write rollouts as a LeRobot v3 dataset here
    allow_split_violation: bool = False     # run even if `bench check` finds a split problem


# keys that may differ when a run is resumed (they do not change any record)
RESUMABLE_KEYS = {"workers", "timeout", "out", "run_id"}


def help_text() -> str:
    keys = config_mod.key_help(RunConfig)
    return (
        "usage: bench run [key=value ...]\n\n"
        "Runs a policy on every cell (task x robot x env) and condition of a suite, appends one\n"
        "record per episode to OUT/RUN_ID/episodes.jsonl as it finishes, then writes\n"
        "OUT/RUN_ID/summary.json (success per cell with Wilson intervals, seen/unseen means with\n"
        "bootstrap intervals, the seen-unseen transfer gap) and prints the table.\n"
        "Rerunning with the same run_id resumes: recorded episodes are skipped.\n\n"
        f"keys:\n{keys}\n\n"
        "examples:\n"
        "  bench run suite=held_out_robots\n"
        "  bench run suite=held_out_robots policy=random episodes=10 workers=2\n"
        "  bench run suite=held_out_robots robots=[UR5e,IIWA] episodes=3 run_id=try1\n"
        "  bench run robots=[Panda] perturb.friction=[0.01,0.1] perturb.latency=uniform(0,4)\n"
        "  bench run suite=gym env_id=HalfCheetah-v5 perturb.gravity=[0.5,1.5] perturb.mass.bodies=[torso] perturb.mass.levels=[2]\n"
        + _perturb_help()
    )


def _perturb_help() -> str:
    from bench.perturb import axes_help

    return ("\nperturbations (perturb.AXIS=[levels] | uniform(lo,hi) | loguniform(lo,hi); dict form\n"
            "perturb.AXIS.levels=[...] perturb.AXIS.bodies=[...]; details: docs/perturbations.md):\n" + axes_help() + "\n")


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def prepare(argv: list[str]):
    """Parse and check everything a run needs; writes nothing. Returns a dict of run pieces."""
    from bench import perturb, registry

    cfg: RunConfig = config_mod.build_from_argv(RunConfig, argv, "bench run")
    if cfg.episodes < 1:
        raise ConfigError(f"episodes={cfg.episodes}: must be >= 1")
    if cfg.workers < 0:
        raise ConfigError(f"workers={cfg.workers}: must be >= 0 (0 = all cores)")
    if cfg.metric not in ("success_once", "success_at_end"):
        raise ConfigError(f"metric={cfg.metric!r}: valid: success_once, success_at_end")
    if not 0.5 <= cfg.confidence < 1:
        raise ConfigError(f"confidence={cfg.confidence}: must be in [0.5, 1)")
    if cfg.n_boot < 100:
        raise ConfigError(f"n_boot={cfg.n_boot}: must be >= 100")
    for s in cfg.splits or []:
        if s not in ("seen", "unseen"):
            raise ConfigError(f"splits: {s!r} is not a split; valid: seen, unseen")
    if cfg.run_id is not None and (not cfg.run_id or "/" in cfg.run_id or cfg.run_id.startswith(".")):
        raise ConfigError(f"run_id={cfg.run_id!r}: must be a plain folder name")
    suite = registry.make_suite(cfg.suite)
    policy_name = cfg.policy or suite.reference_policy
    factory = registry.policy_factory(policy_name)  # fails early on a bad name
    checkpoint_sha = None
    if cfg.checkpoint:
        ckpt = Path(cfg.checkpoint)
        if not ckpt.is_file():
            raise ConfigError(f"checkpoint={cfg.checkpoint!r}: no such file")
        checkpoint_sha = sha256_file(ckpt)
    if hasattr(suite, "configure"):
        suite.configure(cfg)  # suite-specific keys (e.g. env_id for suite=gym)
    cells = suite.cells(cfg)
    if not cells:
        raise ConfigError("the selection (robots/tasks/envs/splits) leaves no cell to run")
    preflight = getattr(factory, "preflight", None)  # optional factory hook: check e.g. a checkpoint before workers
    if preflight is not None:
        preflight(cfg, suite, cells)
    if cfg.record and Path(cfg.record).exists() and any(Path(cfg.record).iterdir()):
        raise ConfigError(f"record={cfg.record!r} exists and is not empty; give a new folder (nothing is overwritten)")
    conditions = perturb.conditions_from_config(cfg.perturb)
    perturb.validate_run(suite, cells, conditions, cfg.horizon or suite.default_horizon)  # names in the model
    jobs = suite.jobs(cfg, conditions)
    from bench.check import fast_check

    problems = fast_check(suite, cells, jobs)
    if problems and not cfg.allow_split_violation:
        raise SplitError(f"{problems[0].message} ({len(problems)} split problem(s); `bench check suite={suite.name}` "
                         "lists them; allow_split_violation=true runs anyway)")
    run_id = cfg.run_id or f"{suite.name}-{policy_name}-{datetime.now().strftime('%Y%m%d-%H%M%S')}"
    cfg = dataclasses.replace(cfg, run_id=run_id, policy=policy_name)
    return dict(cfg=cfg, suite=suite, policy_name=policy_name, checkpoint_sha=checkpoint_sha, jobs=jobs,
                run_dir=Path(cfg.out) / run_id)


def _config_dict(cfg: RunConfig) -> dict[str, Any]:
    return json.loads(json.dumps(dataclasses.asdict(cfg)))


def _open_run_dir(run_dir: Path, cfg: RunConfig, meta: dict[str, Any]) -> dict[str, Any]:
    """Create the run dir with run.json, or check that an existing one is the same run."""
    meta_path = run_dir / "run.json"
    if meta_path.exists():
        old = json.loads(meta_path.read_text())
        new_cfg = meta["config"]
        diffs = [k for k in sorted(set(old["config"]) | set(new_cfg))
                 if k not in RESUMABLE_KEYS and old["config"].get(k) != new_cfg.get(k)]
        if diffs:
            k = diffs[0]
            raise ConfigError(
                f"run_id={cfg.run_id!r} exists with {k}={old['config'].get(k)!r} (now {new_cfg.get(k)!r}); "
                "use the same settings to resume it, or a new run_id"
            )
        return old
    run_dir.mkdir(parents=True, exist_ok=True)
    from bench.summary import write_atomic

    write_atomic(meta_path, meta)
    return meta


def start(p: dict[str, Any], workers: int):
    """Open (or resume) the run directory of a prepared run `p`: writes run.json; returns (meta, RunContext)."""
    from bench import __version__, provenance
    from bench.rollout import RunContext

    cfg: RunConfig = p["cfg"]
    suite, jobs = p["suite"], p["jobs"]
    meta = {
        "run_id": cfg.run_id,
        "suite": suite.describe(),
        "policy": {"name": p["policy_name"], "checkpoint": cfg.checkpoint, "checkpoint_sha256": p["checkpoint_sha"]},
        "config": _config_dict(cfg),
        "expected_episodes": len(jobs),
        "provenance": {
            "bench_version": __version__, "git_sha": provenance.git_sha(), "packages": provenance.package_versions(),
            **provenance.machine(), "workers": workers, "backend": [], "seed": cfg.seed,
            "episode_seeds": sorted({j.seed for j in jobs}), "started_at": _now(), "finished_at": None,
        },
    }
    meta = _open_run_dir(p["run_dir"], cfg, meta)
    ctx = RunContext(run_id=cfg.run_id, suite_version=suite.version, policy_id=p["policy_name"],
                     checkpoint_sha256=p["checkpoint_sha"], versions=provenance.package_versions(),
                     horizon=cfg.horizon or suite.default_horizon, timeout_s=cfg.timeout,
                     trajectory_dir=str(p["run_dir"] / "trajectories") if cfg.record else None)
    return meta, ctx


def finish(p: dict[str, Any], meta: dict[str, Any], workers: int) -> dict[str, Any]:
    """Stamp run.json (finish time, workers, backends), write and return the validated summary.json."""
    from bench.leaderboard import validate
    from bench.records import EPISODES, read_records
    from bench.summary import build, write_atomic

    run_dir = p["run_dir"]
    records = read_records(run_dir / EPISODES)
    meta["provenance"]["finished_at"] = _now()
    meta["provenance"]["workers"] = workers
    meta["provenance"]["backend"] = sorted({r.backend for r in records if r.backend})
    write_atomic(run_dir / "run.json", meta)
    summary = build(records, run_meta=meta)
    validate(summary, "summary")
    write_atomic(run_dir / "summary.json", summary)
    return summary


def main(argv: list[str]) -> int:
    if argv and argv[0] in ("-h", "--help"):
        print(help_text())
        return 0
    from bench.records import EPISODES, RecordWriter, read_records
    from bench.runner import execute
    from bench.summary import render

    p = prepare(argv)
    cfg: RunConfig = p["cfg"]
    suite, jobs, run_dir = p["suite"], p["jobs"], p["run_dir"]
    workers = min(cfg.workers or os.cpu_count() or 1, len(jobs))
    meta, ctx = start(p, workers)
    episodes_path = run_dir / EPISODES
    done_ids = {r.job_id for r in read_records(episodes_path)}
    todo = [j for j in jobs if j.job_id not in done_ids]
    from rich.console import Console

    console = Console(stderr=True)
    if done_ids:
        console.print(f"resuming {run_dir}: {len(done_ids)} of {len(jobs)} episodes already recorded")
    console.print(f"run {cfg.run_id}: {len(todo)} episodes on {workers} worker(s) -> {run_dir}")
    t0 = time.time()
    _execute_with_progress(todo, suite, cfg, ctx, workers, episodes_path, console, execute, RecordWriter)
    summary = finish(p, meta, workers)
    render(summary)
    if cfg.record:
        from bench.recording import assemble

        records = read_records(episodes_path)
        path = assemble(records, run_dir / "trajectories", Path(cfg.record))
        console.print(f"recorded {sum(r.error is None for r in records)} episodes as a LeRobot v3 dataset: {path}")
    console.print(f"{len(todo)} episodes in {time.time() - t0:.1f} s; records: {episodes_path}; "
                  f"summary: {run_dir / 'summary.json'}")
    return 0


def _execute_with_progress(todo, suite, cfg, ctx, workers, episodes_path, console, execute, RecordWriter) -> None:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    columns = [TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
               TextColumn("successes {task.fields[succ]}"), TextColumn("errors {task.fields[err]}"),
               TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn()]
    with RecordWriter(episodes_path) as writer, Progress(*columns, console=console, transient=False) as progress:
        task = progress.add_task(cfg.suite, total=len(todo), succ=0, err=0)
        counts = {"succ": 0, "err": 0}

        def on_record(record) -> None:
            writer.write(record)
            counts["succ"] += int(getattr(record, cfg.metric))
            counts["err"] += int(record.error is not None)
            progress.update(task, advance=1, **counts)

        execute(todo, suite_name=cfg.suite, policy_name=ctx.policy_id, cfg=cfg, ctx=ctx, workers=workers,
                on_record=on_record)

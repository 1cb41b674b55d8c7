"""The keys of `bench run` (`RunConfig`) and every check of them made before a run starts.

`bench.api.parse_run` routes `key=value` arguments to the runner, the suite and the policy;
`bench.api.plan` builds the suite and the policy, then calls these: ranges and lists of the
runner's own keys, the executor's keys, the run id, the estimated work and the output folders.
Each refusal is one line naming the key, the value and what is valid (`ConfigError`).
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from bench.core import config as config_mod
from bench.core import outputs
from bench.core.errors import ConfigError
from bench.execution import ray_env, run_lock
from bench.protocols import ObsSpec, option_keys
from bench.protocols.suite import MAX_ENV_SEED, METRICS, SEED_SCHEMES, SPLITS

# limits that keep a typo from starting an absurd job (the message names the limit; bench.core.config owns them)
MAX_EPISODES = config_mod.MAX_EPISODES
MAX_HORIZON = config_mod.MAX_HORIZON
MAX_WORKERS = config_mod.MAX_WORKERS
MAX_VECTOR = 65_536  # envs one worker holds at once (simulator instances, or worlds of one batched simulator: mjx_lift)
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
    seed_scheme: str = "hashed"  # episode seeds: hashed (bench's) or consecutive (seed + episode, lerobot-eval's)
    workers: int = ranged(0, 0, MAX_WORKERS)  # executor=local: processes running episodes; 0 = all cores
    vector: int = ranged(1, 1, MAX_VECTOR)  # lockstep envs per worker (one cell and condition), one act per step
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
    strict: bool = False  # refuse a calibration= whose model simulates the held-out data worse than the declared one, or was never checked
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
    "vector",  # how episodes are stepped, not what they compute: records equal vector=1's
    "timeout",
    "out",
    "run_id",
    "executor",
    "ray_address",
    "actors",
    "actor_cpus",
    "actor_gpus",
    "ray_env",
    "strict",  # a gate on the calibration before the run, not part of what its episodes compute
}
EXECUTORS = ("local", "ray")
RAY_KEYS = {"ray_address": "auto", "actors": 0, "actor_cpus": 1.0, "actor_gpus": 0.0, "ray_env": "code"}
RUNNER_KEYS = [f.name for f in dataclasses.fields(RunConfig) if f.name not in ("suite_options", "policy_options")]


def build_options(schema: type, values: Mapping[str, object], owner: str) -> Any:
    """`values` validated into an instance of the Options dataclass `schema` (types, required keys): the
    plugin's own type, which bench passes on without reading."""
    bad = [k for k in values if k not in option_keys(schema)]
    if bad:
        raise ConfigError(f"unknown key {bad[0]!r} for {owner}; valid: {', '.join(option_keys(schema)) or '(none)'}")
    return config_mod.build(schema, [], base=dict(values))


def check_runner(cfg: RunConfig) -> None:
    """Ranges of the runner's own keys (one line each, naming the limit): the field ranges of RunConfig
    (also for a RunConfig built in Python, not from key=value), then the keys that need more than a range."""
    config_mod.validate(cfg)
    if cfg.metric is not None and cfg.metric not in METRICS:
        raise ConfigError(f"metric={cfg.metric!r}: valid: {', '.join(METRICS)}")
    if cfg.seed_scheme not in SEED_SCHEMES:
        raise ConfigError(f"seed_scheme={cfg.seed_scheme!r}: valid: {', '.join(SEED_SCHEMES)}")
    if cfg.seed_scheme == "consecutive" and cfg.seed + cfg.episodes - 1 > MAX_ENV_SEED:
        raise ConfigError(
            f"seed={cfg.seed}: with seed_scheme=consecutive the last episode's seed (seed + episodes - 1) must be "
            f"at most {MAX_ENV_SEED} (environments take 32-bit seeds)"
        )
    for s in cfg.splits or []:
        if s not in SPLITS:
            raise ConfigError(f"splits: {s!r} is not a split; valid: {', '.join(SPLITS)}")
    for key in ("robots", "tasks", "envs", "splits"):
        given = getattr(cfg, key) or []
        twice = next((v for i, v in enumerate(given) if v in given[:i]), None)
        if twice is not None:
            raise ConfigError(f"{key}: {twice!r} is listed twice; list each once")
    if cfg.vector > cfg.episodes:
        raise ConfigError(
            f"vector={cfg.vector}: more envs than a cell has episodes (episodes={cfg.episodes} per cell and "
            f"condition); give vector at most {cfg.episodes}"
        )
    if cfg.strict and not cfg.calibration:
        raise ConfigError(
            "strict=true applies to calibration= (it refuses a calibration whose model simulates the held-out data "
            "worse than the declared one, or was never checked); add calibration=FILE or leave strict out"
        )
    _check_executor(cfg)
    check_run_id(cfg.run_id)


def check_run_id(rid: str | None) -> None:
    """run_id names a folder under out=: non-empty, printable, no slash, not hidden, at most MAX_RUN_ID characters."""
    if rid is None:
        return
    if not isinstance(rid, str) or not rid.strip():
        raise ConfigError(f"run_id={rid!r}: must be a non-empty folder name")
    if (
        "/" in rid
        or "\\" in rid
        or rid.startswith(".")
        or config_mod.CONTROL_CHARS.search(rid)
        or len(rid) > MAX_RUN_ID
    ):
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


def observation_bytes(spec: ObsSpec) -> int:
    """Bytes of one observation of `spec` (strings count nothing)."""
    total = 0
    for feat in spec.values():
        try:
            total += int(np.prod(feat.shape, dtype=np.float64)) * np.dtype(feat.dtype).itemsize
        except TypeError:
            continue
    return total


def _check_executor(cfg: RunConfig) -> None:
    """executor= and the keys that belong to it (a key of the other executor is refused, not ignored)."""
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


def _is_run_dir(folder: Path) -> bool:
    """A folder `bench run` may resume: it holds the run.json of a bench run."""
    try:
        meta = json.loads((folder / "run.json").read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return False
    return isinstance(meta, dict) and isinstance(meta.get("config"), dict)


def _entries(folder: Path) -> list[Path]:
    """What `folder` holds besides a run lock (a run killed before its run.json leaves only that)."""
    return [p for p in folder.iterdir() if p.name != run_lock.LOCK]


def _resumable(folder: Path) -> bool:
    return _is_run_dir(folder) or not _entries(folder)


def check_outputs(cfg: RunConfig, run_id: str, checkpoint: str | None) -> Path:
    """The run directory and `record=` checked against `bench.core.outputs`' rule before anything is written."""
    inputs = {"checkpoint": checkpoint, "calibration": cfg.calibration}
    if not run_id or run_id in (".", "..") or any(c in run_id for c in "/\\\0") or not run_id.isprintable():
        raise ConfigError(f"run_id={run_id!r}: a run id names one folder (printable, no slashes, not . or ..)")
    run_dir = Path(cfg.out) / run_id
    outputs.names_fit("out", str(run_dir), run_dir.expanduser().absolute())
    run_lock.check_free(run_dir)  # another run writing it: named here; `bench.api.run` takes the lock itself
    if run_dir.is_dir() and _entries(run_dir) and not _is_run_dir(run_dir):
        raise ConfigError(
            f"run_id={run_id!r}: {str(run_dir)!r} exists and is not a bench run directory (no run.json "
            "of a bench run); give a new run_id or out=, nothing there is touched"
        )
    outputs.check("out", run_dir, inputs, resume=_resumable, can_overwrite=False)
    if cfg.record:
        outputs.check("record", cfg.record, {**inputs, "out (the run directory)": run_dir}, can_overwrite=False)
    return run_dir

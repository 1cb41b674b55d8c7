"""The command line of `bench regress`: its own keys (`RegressConfig`), its help, and the
`bench run` keys it forwards, every one checked (names, types, ranges) before anything is read or run.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Optional

from bench import api
from bench.core import config as config_mod
from bench.core.errors import ConfigError, did_you_mean
from bench.execution.run_config import RUNNER_KEYS, RunConfig
from bench.protocols import Suite, option_keys, registry

DEFAULT_EPISODES = 20
FORBIDDEN_KEYS = {"policy": "candidate=/baseline=", "checkpoint": "candidate=/baseline=", "record": None}


@dataclass(frozen=True)
class RegressConfig:
    """Keys of `bench regress` besides the `bench run` keys it forwards."""

    candidate: Optional[str] = None  # checkpoint (.safetensors/.pt), registered policy name, or a recorded run dir
    baseline: Optional[str] = None  # checkpoint file, policy name, or a recorded run dir (its episodes are reused)
    margin: float = 0.05  # tolerated drop in success (baseline - candidate) before it is a regression
    alpha: float = 0.05  # false-alarm rate when no drop exceeds margin (over all looks, tests and cells)
    cell_alpha: float = 0.5  # share of alpha for the per-cell tests (Holm); 0 = pooled statistics only
    batch: int = 5  # episodes per cell between looks (early stopping); 0 = one look at the end
    strict: bool = False  # inconclusive (budget spent, nothing certain) fails with exit 1
    allow_spec_change: bool = False  # pair episodes of runs whose suite options or simulator versions differ
    out: Optional[str] = None  # verdict JSON (X.junit.xml, X.md beside it); default RUNS/RUN_ID/verdict.json
    runs: str = "runs"  # parent folder of the gate's run directories
    run_id: Optional[str] = None  # gate folder name; default regress-<timestamp>
    plan: bool = False  # print the episodes per cell needed for `power` and exit (runs nothing)
    power: float = 0.8  # plan: target chance to flag the drop below
    drop: float = 0.6  # plan: the drop to detect (one cell falls from rate to rate - drop)
    rate: float = 0.9  # plan: baseline success rate of the cell(s) that drop
    cells: int = 0  # plan: number of cells; 0 = those the suite/robots/tasks/envs/perturb keys select


def help_text() -> str:
    return config_mod.command_help(
        "usage: bench regress candidate=X baseline=Y [key=value ...]\n"
        "       bench regress plan=true [cells=N] [power=0.8 drop=0.6 rate=0.9] [margin= alpha= batch= episodes=]",
        "CI regression gate: runs candidate and baseline on the same suite cells with the same episode\n"
        "seeds, pairs outcomes by (cell, episode), and fails when the candidate is confidently worse by\n"
        "more than `margin`: pooled over all pairs, in the IQM across cells, in a split, or in any one cell\n"
        "(one-sided paired tests, weighted Holm across them, alpha spent over the looks). Episodes run in\n"
        "batches and stop once the verdict is certain. A baseline run directory is reused (the candidate\n"
        "runs with its settings; different cells, horizon or seeds are refused). Identical checkpoints\n"
        "(same sha256) are not simulated.",
        RegressConfig,
        notes=(
            "  (and the `bench run` keys suite, episodes (default 20), seed, workers, horizon, timeout, robots,\n"
            "   tasks, envs, splits, metric, n_boot, confidence, perturb.*, the suite's own keys; bench run --help)\n\n"
            "exit: 0 no regression (inconclusive passes unless strict=true), 1 regression, 2 bad input,\n"
            "3 nothing measured (a side completed no episode of some cell: verdict nothing_measured).\n"
            "writes: RUNS/RUN_ID/RUN_ID-candidate/ (and -baseline/ unless reused) run dirs, the verdict JSON\n"
            "(schema bench.regress/2: verdict, regressed cells with drops and bounds, looks, checkpoint sha256,\n"
            "size and training metadata), and beside it X.junit.xml (one test case per cell) and X.md (a\n"
            "Markdown summary for a CI step summary). plan=true prints a budget table and writes nothing."
        ),
        examples=[
            "bench regress candidate=ckpt/new.safetensors baseline=ckpt/old.safetensors robots=[Panda,UR5e]",
            "bench regress candidate=ckpt/new.safetensors baseline=results/runs/<run_id> out=gate/verdict.json",
            "bench regress candidate=random baseline=scripted episodes=4 batch=2",
            "bench regress plan=true suite=held_out_robots power=0.9 drop=0.6 rate=0.9",
        ],
    )


def _split_overrides(argv: list[str]) -> tuple[RegressConfig, list[str], dict[str, str]]:
    """Own keys -> RegressConfig; `bench run` keys (the runner's and the suite's) forwarded verbatim."""
    positional, overrides = config_mod.split_args(argv)
    if positional:
        raise ConfigError(
            f"unexpected argument {positional[0]!r}; bench regress takes key=value only (see bench regress --help)"
        )
    own_names = {f.name for f in fields(RegressConfig)}
    suite = config_mod.build(RunConfig, [o for o in overrides if config_mod.top_key(o) == "suite"]).suite
    suite_cls: type[Suite] = registry.suite_class(suite)
    run_names = set(RUNNER_KEYS) | set(option_keys(suite_cls.Options))
    own, forwarded, by_key = [], [], {}
    for item in overrides:
        key = item.split("=", 1)[0]
        top = key.split(".")[0]
        if top in own_names:
            own.append(item)
        elif top in FORBIDDEN_KEYS:
            hint = f"; use {FORBIDDEN_KEYS[top]}" if FORBIDDEN_KEYS[top] else ""
            raise ConfigError(f"key {top!r} is not valid for bench regress{hint}")
        elif top in run_names:
            forwarded.append(item)
            by_key[top] = item
        else:
            valid = sorted(own_names | (run_names - set(FORBIDDEN_KEYS) - {"out", "run_id"}))
            raise ConfigError(f"unknown key {key!r}; valid keys: {', '.join(valid)}.{did_you_mean(top, valid)}")
    cfg: RegressConfig = config_mod.build(RegressConfig, own)
    for key, lo, hi, what in (
        ("margin", 0.0, 1.0, "[0, 1)"),
        ("alpha", 0.0, 0.5, "(0, 0.5)"),
        ("cell_alpha", 0.0, 1.0, "[0, 1)"),
        ("power", 0.0, 1.0, "(0, 1)"),
        ("drop", 0.0, 1.0, "(0, 1]"),
        ("rate", 0.0, 1.0, "(0, 1]"),
    ):
        v = getattr(cfg, key)
        closed_lo, closed_hi = what[0] == "[", what[-1] == "]"
        if not ((lo <= v if closed_lo else lo < v) and (v <= hi if closed_hi else v < hi)):
            raise ConfigError(f"{key}={v}: must be in {what}")
    if cfg.batch < 0:
        raise ConfigError(f"batch={cfg.batch}: must be >= 0 (0 = a single look)")
    if cfg.cells < 0:
        raise ConfigError(f"cells={cfg.cells}: must be >= 0 (0 = count the suite selection's cells)")
    if cfg.run_id is not None and (not cfg.run_id or "/" in cfg.run_id or cfg.run_id.startswith(".")):
        raise ConfigError(f"run_id={cfg.run_id!r}: must be a plain folder name")
    return cfg, forwarded, by_key


def parse_args(argv: list[str]) -> tuple[RegressConfig, list[str], dict[str, str]]:
    """Every key of a `bench regress` command line checked (names, types, ranges); nothing is run or read.

    Returns the gate's own config, the `bench run` overrides it forwards, and those by key.
    The forwarded keys are typed by the runner's and the suite's configs (bench.api).
    """
    cfg, forwarded, by_key = _split_overrides(argv)
    api.config_from_argv(forwarded)
    return cfg, forwarded, by_key


@dataclass(frozen=True)
class _Episodes:
    """Parses the forwarded `episodes=` value (typed like bench run's)."""

    episodes: int = DEFAULT_EPISODES


def episodes_of(user_keys: dict[str, str], default: int) -> int:
    """The forwarded `episodes=` value, typed like bench run's, or `default` when none was given."""
    return int(config_mod.build(_Episodes, [user_keys["episodes"]]).episodes) if "episodes" in user_keys else default

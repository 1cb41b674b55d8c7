"""`bench coverage` from Python: a training dataset's coverage of a suite's evaluation (support, initial states,
perturbation ranges). The metrics are `bench.scoring.coverage`'s; docs/coverage.md has the method."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import bench.sims.perturb.axes as axes
from bench.core import outputs
from bench.core.config import MAX_HORIZON, MAX_SEED, one_or_more, ranged
from bench.core.errors import ConfigError
from bench.core.io import write_atomic
from bench.protocols import Suite, registry
from bench.protocols.suite import SPLIT_AXES, Cell, select_cells
from bench.scoring.coverage import (
    coverage_report,
    fmt_pct,
    initial_states_from_dataset,
    initial_states_from_suite,
    read_training,
)

__all__ = ["SPLIT_AXES", "CoverageConfig", "coverage", "fmt_pct"]


@dataclass(frozen=True)
class CoverageConfig:
    """Keys of `bench coverage` (see `bench coverage --help`)."""

    data: Optional[list[str]] = one_or_more()  # training dataset folder(s) (LeRobot v3), e.g. data=demos/seen
    suite: str = "held_out_robots"  # the suite whose evaluation the data is compared with
    robots: Optional[list[str]] = None  # evaluated robots (default: every robot of the suite)
    tasks: Optional[list[str]] = None  # evaluated tasks
    envs: Optional[list[str]] = None  # evaluated environments/scenes
    splits: Optional[list[str]] = None  # evaluated splits: seen, unseen
    seed: int = ranged(0, 0, MAX_SEED)  # evaluation run seed: the initial states are its episode seeds'
    episodes: int = ranged(10, 1, 10_000)  # evaluation episodes per cell (initial states per cell)
    horizon: int = ranged(0, 0, MAX_HORIZON)  # env horizon when building envs (0 = suite default)
    eval_data: Optional[str] = None  # recorded evaluation dataset: initial states = first frames (no env built)
    perturb: dict[str, Any] = field(default_factory=dict)  # evaluated perturbation axes, grammar of bench run
    quantile: float = ranged(
        0.95, 0, 1, lo_open=True
    )  # reference radius quantile (training initial states, leave-one-episode-out)
    out: Optional[str] = None  # write the JSON report here
    overwrite: bool = False  # replace an existing out= file that bench wrote


def _check_common(suite_name: str, quantile: float) -> Suite:
    if not 0 < quantile < 1:
        raise ConfigError(f"quantile={quantile}: must be in (0, 1)")
    suite: Suite = registry.make_suite(suite_name)
    return suite


def _eval_cells(suite: Suite, cfg: CoverageConfig) -> list[Cell]:
    for s in cfg.splits or []:
        if s not in ("seen", "unseen"):
            raise ConfigError(f"splits: {s!r} is not a split; valid: seen, unseen")

    cells = select_cells(suite, cfg)
    if not cells:
        raise ConfigError("the selection (robots/tasks/envs/splits) leaves no cell to evaluate")
    return cells


def coverage(cfg: CoverageConfig) -> dict[str, Any]:
    """The coverage report (schema bench.coverage/1) of `cfg.data` against `cfg.suite`'s evaluation; also written
    to `cfg.out`."""
    if not cfg.data:
        raise ConfigError("data: give the training dataset folder(s), e.g. data=demos/seen")
    if cfg.episodes < 1:
        raise ConfigError(f"episodes={cfg.episodes}: must be >= 1")
    if cfg.out:
        outputs.check(
            "out", cfg.out, {"data": list(cfg.data), "eval_data": cfg.eval_data}, kind="file", overwrite=cfg.overwrite
        )
    suite = _check_common(cfg.suite, cfg.quantile)
    cells = _eval_cells(suite, cfg)
    conditions = axes.conditions_from_config(cfg.perturb)
    if cfg.eval_data and not Path(cfg.eval_data).is_dir():
        raise ConfigError(f"eval_data={cfg.eval_data!r}: not a dataset folder")
    train = read_training(cfg.data)
    if cfg.eval_data:
        states, groups = initial_states_from_dataset(cfg.eval_data, cells)
        source: dict[str, Any] = {"eval_data": cfg.eval_data}
    else:
        states, groups = initial_states_from_suite(suite, cells, cfg.seed, cfg.episodes, cfg.horizon)
        source = {"seed": cfg.seed, "episodes": cfg.episodes}
    report = coverage_report(train, cells, dict(suite.manifest), conditions, states, groups, cfg.quantile)
    doc = {
        "schema": "bench.coverage/1",
        "suite": suite.describe(),
        "data": list(cfg.data),
        "evaluation": {"cells": [c.key for c in cells], **source, "conditions": [c.name for c in conditions]},
        **report,
    }
    if cfg.out:
        write_atomic(Path(cfg.out), doc)
    return doc

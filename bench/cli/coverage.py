"""`bench coverage`: its keys, the evaluation it compares with, and the tables it prints.

The metrics (support, state coverage, parameter-range coverage) and the reading of training
data and evaluation initial states are `bench.scoring.coverage`'; docs/coverage.md has the
method, and `python -m baselines.coverage_sweep` measures what coverage buys.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import bench.sims.perturb.axes as axes
from bench.core import config as config_mod
from bench.core import outputs
from bench.core.config import MAX_HORIZON, MAX_SEED, command_help, one_or_more, ranged
from bench.core.console import table_console
from bench.core.errors import ConfigError
from bench.core.io import write_atomic
from bench.protocols import Suite, registry
from bench.protocols.suite import SPLIT_AXES, select_cells
from bench.scoring.coverage import (
    coverage_report,
    fmt_pct,
    initial_states_from_dataset,
    initial_states_from_suite,
    read_training,
)


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


def help_text() -> str:
    return command_help(
        "usage: bench coverage data=DIR [suite=NAME] [key=value ...]",
        "Coverage of a training dataset against a suite's evaluation: support (robots/tasks/envs present\n"
        "vs evaluated, per split), state coverage (distance from the evaluation initial states to the\n"
        "nearest training state in training-std units; covered = within the leave-one-episode-out\n"
        "reference radius of the training data itself), and parameter-range coverage of perturb.* axes.\n"
        "Prints a table; out=FILE writes the JSON. What coverage buys (training on nested sets and\n"
        "evaluating): the experiment `python -m baselines.coverage_sweep --help` (docs/coverage.md).",
        CoverageConfig,
        [
            "bench coverage data=demos/seen suite=held_out_robots episodes=10 seed=1",
            "bench coverage data=[demos/a,demos/b] splits=[unseen] out=coverage.json",
            "bench coverage data=demos/dr perturb.gain=uniform(0.5,1.5) eval_data=runs/eval/dataset",
        ],
    )


def _check_common(suite_name: str, quantile: float) -> Any:
    if not 0 < quantile < 1:
        raise ConfigError(f"quantile={quantile}: must be in (0, 1)")
    return registry.make_suite(suite_name)


def _eval_cells(suite: Suite, cfg: Any) -> list:
    for s in cfg.splits or []:
        if s not in ("seen", "unseen"):
            raise ConfigError(f"splits: {s!r} is not a split; valid: seen, unseen")

    cells = select_cells(suite, cfg)
    if not cells:
        raise ConfigError("the selection (robots/tasks/envs/splits) leaves no cell to evaluate")
    return cells


def main(argv: list[str]) -> int:
    """`bench coverage ...`."""
    if argv and argv[0] == "sweep":
        raise ConfigError(
            "the coverage sweep is an experiment script now: python -m baselines.coverage_sweep "
            "(same keys; --help lists them)"
        )
    if argv and argv[0] in ("-h", "--help"):
        print(help_text(), end="")
        return 0

    positional, overrides = config_mod.split_args(argv)
    if positional:
        raise ConfigError(
            f"unexpected argument {positional[0]!r}; bench coverage takes key=value only "
            "(the sweep: python -m baselines.coverage_sweep)"
        )
    cfg: CoverageConfig = config_mod.build(CoverageConfig, overrides)
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
    report = coverage_report(train, cells, suite.manifest, conditions, states, groups, cfg.quantile)
    doc = {
        "schema": "bench.coverage/1",
        "suite": suite.describe(),
        "data": list(cfg.data),
        "evaluation": {"cells": [c.key for c in cells], **source, "conditions": [c.name for c in conditions]},
        **report,
    }
    render(doc)
    if cfg.out:
        write_atomic(Path(cfg.out), doc)
        print(f"wrote {cfg.out}")
    return 0


def render(doc: dict[str, Any], console=None) -> None:
    """Print the support, state-coverage and parameter-coverage tables of a coverage report."""
    from rich.table import Table  # rich: loaded only when something is drawn on the terminal

    console = console or table_console()
    t = Table(title=f"support: training data vs evaluated ({doc['suite']['name']})", title_justify="left")
    for col in ("axis", "evaluated", "covered", "missing", "held-out values in training"):
        t.add_column(col)
    for axis in SPLIT_AXES:
        s = doc["support"][axis]
        split_txt = ", ".join(f"{k} {len(v['covered'])}/{len(v['evaluated'])}" for k, v in s["by_split"].items())
        t.add_row(
            axis,
            str(len(s["evaluated"])),
            f"{len(s['covered'])} ({fmt_pct(s['fraction'])}; {split_txt})",
            ", ".join(s["missing"]) or "-",
            ", ".join(s["unseen_in_training"]) or "-",
        )
    console.print(t)
    sc = doc["state"]
    st = Table(
        title=f"state coverage: evaluation initial states -> nearest training state (RMS z, "
        f"radius {sc['reference_radius']} = q{int(sc['quantile'] * 100)} of training, leave-one-episode-out)",
        title_justify="left",
    )
    for col in ("cell", "n", "mean dist", "median", "max", "covered"):
        st.add_column(col, justify="left" if col == "cell" else "right")
    rows = list((sc.get("groups") or {}).items()) + [(f"[bold]{k}[/]", v) for k, v in sc.get("splits", {}).items()]
    rows.append(("[bold]all[/]", sc["overall"]))
    for name, g in rows:
        st.add_row(
            name,
            str(g["n"]),
            *(f"{g[k]:.3f}" if g.get(k) is not None else "n/a" for k in ("mean", "median", "max")),
            fmt_pct(g.get("covered")),
        )
    console.print(st)
    if doc.get("params"):
        pt = Table(title="parameter-range coverage (perturb.*)", title_justify="left")
        for col in ("axis", "evaluated", "training span", "coverage", "log-scale", "levels inside"):
            pt.add_column(col)
        for axis, p in doc["params"].items():
            pt.add_row(
                axis,
                f"[{p['evaluated'][0]:g}, {p['evaluated'][1]:g}]",
                f"[{p['training'][0]:g}, {p['training'][1]:g}]" if p.get("training") else "n/a",
                fmt_pct(p.get("coverage")),
                fmt_pct(p.get("coverage_log")),
                fmt_pct(p.get("levels_inside")),
            )
        console.print(pt)

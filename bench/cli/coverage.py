"""`bench coverage`: its help, its command line over `bench.api.coverage`, and the tables it prints.

The metrics (support, state coverage, parameter-range coverage) and the reading of training
data and evaluation initial states are `bench.scoring.coverage`'; docs/coverage.md has the
method, and `python -m baselines.coverage_sweep` measures what coverage buys.
"""

from __future__ import annotations

from typing import Any

from bench.api.data_coverage import SPLIT_AXES, CoverageConfig, coverage, fmt_pct
from bench.core import config as config_mod
from bench.core.config import command_help
from bench.core.console import table_console
from bench.core.errors import ConfigError


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
    doc = coverage(cfg)
    render(doc)
    if cfg.out:
        print(f"wrote {cfg.out}")
    return 0


def render(doc: dict[str, Any], console: Any = None) -> None:
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

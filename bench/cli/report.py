"""`bench report RUN|LEADERBOARD out=DIR`: its help and the command over `bench.api.report`."""

from __future__ import annotations

from bench.api.board import ReportConfig, report
from bench.core import config as config_mod
from bench.core.errors import ConfigError


def help_text() -> str:
    """`bench report --help`: what a page holds for each input, and the keys (from ReportConfig)."""
    return config_mod.command_help(
        "usage: bench report RUN|SUMMARY|LEADERBOARD|SWEEP out=DIR [calibration=DIR] [verdict=FILE] [title=TEXT]",
        "Writes DIR/index.html with matplotlib figures (PNG, next to it):\n"
        "  run:          success per task x robot/env with Wilson intervals, seen and unseen side by side; split\n"
        "                means and transfer gaps with intervals; sensitivity curves per perturbation axis when\n"
        "                the run has perturbed conditions; round-trip latency distribution for remote policies;\n"
        "                per-cell table. Given a run directory: its episode videos (bench run video=N) in the\n"
        "                cell table, copied into DIR/videos, and a robustness table (per axis, levels pooled:\n"
        "                nominal vs perturbed success, drop with its interval).\n"
        "  leaderboard:  score, seen/unseen success and gap per entry with intervals, ranked by the lower bound\n"
        "                (entries scored by return, e.g. HalfCheetah, in the env's units, in a panel of their own).\n"
        "  sweep:        a bench sweep folder (or its sweep.json): success against training step with the\n"
        "                simultaneous intervals, the best set and the selected checkpoint, a table per\n"
        "                checkpoint, and the sweep's leaderboard.json (one entry per checkpoint) when beside it.\n"
        "  calibration=  held-out error (one-step, k-step, free-run NRMSE) nominal -> declared fit -> final.\n"
        "  verdict=      a bench regress verdict: per-cell baseline vs candidate and the looks.\n"
        "Inputs are validated before anything is written. DIR is never an input or inside one; an existing\n"
        "DIR is replaced (atomically) only with overwrite=true, and only when bench wrote everything in it.",
        ReportConfig,
        examples=[
            "bench report runs/my_run out=report/",
            "bench report results/leaderboard.json out=report/ calibration=runs/calib1",
            "bench report runs/sweep out=report/",
        ],
    )


def main(argv: list[str]) -> int:
    if not argv or any(a in ("-h", "--help") for a in argv):
        print(help_text(), end="")
        return 0 if argv else 2
    positional, overrides = config_mod.split_args(argv)
    cfg: ReportConfig = config_mod.build(ReportConfig, overrides)
    if len(positional) != 1:
        raise ConfigError(f"report takes one RUN|LEADERBOARD|SWEEP, got {len(positional)}: {positional}")
    done = report(positional[0], cfg)
    print(f"report of {done.source} -> {done.index} ({', '.join(done.figures) or 'no figures'})")
    return 0

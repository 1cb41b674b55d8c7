"""`bench report RUN|LEADERBOARD out=DIR`: its keys, its help and the command."""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Optional

from bench.board.report.page import build_page, load_calibration, load_input, load_verdict
from bench.core import config as config_mod
from bench.core import outputs
from bench.core.errors import ConfigError


@dataclass(frozen=True)
class ReportConfig:
    """Keys of `bench report` (the input RUN|LEADERBOARD is positional)."""

    out: Optional[str] = None  # output folder (index.html + PNG figures); never an input or inside one
    overwrite: bool = False  # replace an existing report folder (only one bench wrote)
    calibration: Optional[str] = None  # a calibrate output dir or its calibration.json: errors before/after
    verdict: Optional[str] = None  # a `bench regress` verdict.json to include
    title: Optional[str] = None  # page title; default from the input


def help_text() -> str:
    """`bench report --help`: what a page holds for each input, and the keys (from ReportConfig)."""
    return config_mod.command_help(
        "usage: bench report RUN|SUMMARY|LEADERBOARD out=DIR [calibration=DIR] [verdict=FILE] [title=TEXT]",
        "Writes DIR/index.html with matplotlib figures (PNG, next to it):\n"
        "  run:          success per task x robot/env with Wilson intervals, seen and unseen side by side; split\n"
        "                means and transfer gaps with intervals; sensitivity curves per perturbation axis when\n"
        "                the run has perturbed conditions; round-trip latency distribution for remote policies;\n"
        "                per-cell table. Given a run directory: its episode videos (bench run video=N) in the\n"
        "                cell table, copied into DIR/videos, and a robustness table (per axis, levels pooled:\n"
        "                nominal vs perturbed success, drop with its interval).\n"
        "  leaderboard:  score, seen/unseen success and gap per entry with intervals, ranked by the lower bound\n"
        "                (entries scored by return, e.g. HalfCheetah, in the env's units, in a panel of their own).\n"
        "  calibration=  held-out error (one-step, k-step, free-run NRMSE) nominal -> declared fit -> final.\n"
        "  verdict=      a bench regress verdict: per-cell baseline vs candidate and the looks.\n"
        "Inputs are validated before anything is written. DIR is never an input or inside one; an existing\n"
        "DIR is replaced (atomically) only with overwrite=true, and only when bench wrote everything in it.",
        ReportConfig,
        examples=[
            "bench report runs/my_run out=report/",
            "bench report results/leaderboard.json out=report/ calibration=runs/calib1",
        ],
    )


def main(argv: list[str]) -> int:
    if not argv or any(a in ("-h", "--help") for a in argv):
        print(help_text(), end="")
        return 0 if argv else 2
    positional, overrides = config_mod.split_args(argv)
    cfg: ReportConfig = config_mod.build(ReportConfig, overrides)
    if len(positional) != 1:
        raise ConfigError(f"report takes one RUN|LEADERBOARD, got {len(positional)}: {positional}")
    if not cfg.out:
        raise ConfigError("report: out=DIR is required")
    kind, doc, src = load_input(positional[0])
    cal = load_calibration(cfg.calibration) if cfg.calibration else None
    verdict = load_verdict(cfg.verdict) if cfg.verdict else None
    # a run's records and videos are read from the folder of its summary.json
    run_dir = src.parent if kind == "run" and (src.parent / "episodes.jsonl").exists() else None
    out = outputs.check(
        "out",
        cfg.out,
        {"input": positional[0], "run": run_dir, "calibration": cfg.calibration, "verdict": cfg.verdict},
        overwrite=cfg.overwrite,
    )
    with warnings.catch_warnings():  # matplotlib's layout notes are not the reader's concern: stderr stays clean
        warnings.simplefilter("ignore")
        outputs.replace_dir(
            out,
            lambda tmp: (tmp / "index.html").write_text(
                build_page(kind, doc, tmp, cal, verdict, cfg.title, run_dir), encoding="utf-8"
            ),
        )
    figs = sorted(p.name for p in out.glob("*.png"))
    print(f"report of {src} -> {out / 'index.html'} ({', '.join(figs) or 'no figures'})")
    return 0

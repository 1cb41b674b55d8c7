"""`bench leaderboard` and `bench report` from Python: merge runs into a leaderboard, validate result files, and
write the static HTML report of a run or a leaderboard (`bench.board`)."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from bench.board.leaderboard import LEADERBOARD_ID, merge, read_input
from bench.board.leaderboard import render as render_leaderboard
from bench.board.report.page import build_page, load_calibration, load_input, load_verdict
from bench.core import outputs
from bench.core.errors import ConfigError, DataError
from bench.core.io import write_atomic
from bench.core.schema import load_json, validate

__all__ = [
    "LEADERBOARD_ID",
    "MergeConfig",
    "ReportConfig",
    "ReportResult",
    "leaderboard_merge",
    "leaderboard_show",
    "leaderboard_validate",
    "render_leaderboard",
    "report",
]


@dataclass(frozen=True)
class MergeConfig:
    """Keys of `bench leaderboard merge` (the inputs RUN... are positional)."""

    out: Optional[str] = None  # the merged leaderboard, a new .json file (required; never an input)
    overwrite: bool = False  # replace an existing out file that bench wrote
    allow_spec_change: bool = False  # rank runs whose suite options or simulator versions differ (refused by default)


@dataclass(frozen=True)
class ReportConfig:
    """Keys of `bench report` (the input RUN|LEADERBOARD is positional)."""

    out: Optional[str] = None  # output folder (index.html + PNG figures); never an input or inside one
    overwrite: bool = False  # replace an existing report folder (only one bench wrote)
    calibration: Optional[str] = None  # a calibrate output dir or its calibration.json: errors before/after
    verdict: Optional[str] = None  # a `bench regress` verdict.json to include
    title: Optional[str] = None  # page title; default from the input


@dataclass(frozen=True)
class ReportResult:
    """What `report` wrote: OUT/index.html and its figures, from the input at `source`."""

    index: Path
    source: Path  # the summary.json or leaderboard.json the page shows
    figures: list[str]  # the PNG files beside index.html, sorted


def leaderboard_merge(inputs: Sequence[str], cfg: MergeConfig) -> dict[str, Any]:
    """One leaderboard (bench.leaderboard/1) from run directories, summary.json files or leaderboards, written to
    `cfg.out` (every input validated first; refused when a suite's runs differ in spec, unless allowed)."""
    if not cfg.out:
        raise ConfigError("leaderboard merge: out=FILE is required (e.g. out=results/leaderboard.json)")
    if not inputs:
        raise ConfigError("leaderboard merge: give at least one RUN directory, summary.json or leaderboard.json")
    if not cfg.out.endswith(".json"):
        raise ConfigError(f"leaderboard merge: out={cfg.out!r} must end in .json")
    board = merge([read_input(a) for a in inputs], cfg.allow_spec_change)  # every input validated before writing
    validate(board, "merged leaderboard")
    outputs.check("out", cfg.out, {"input": list(inputs)}, kind="file", overwrite=cfg.overwrite)
    write_atomic(Path(cfg.out), board)
    return board


def leaderboard_validate(path: str) -> str:
    """Validate a result file (summary, leaderboard, verdict) against the schema its "schema" field names; that id."""
    return validate(load_json(Path(path)), str(path))


def leaderboard_show(path: str) -> dict[str, Any]:
    """The leaderboard in `path`, validated (`render_leaderboard` draws it)."""
    board: dict[str, Any] = load_json(Path(path))
    sid = validate(board, path)
    if sid != LEADERBOARD_ID:
        raise DataError(
            f"{path}: schema {sid} is not a leaderboard ({LEADERBOARD_ID}); make one with bench leaderboard merge"
        )
    return board


def report(source: str, cfg: ReportConfig) -> ReportResult:
    """OUT/index.html (and its PNG figures) of a run directory, summary.json or leaderboard.json, with a
    calibration's errors and a regress verdict when given; inputs are validated before anything is written."""
    if not cfg.out:
        raise ConfigError("report: out=DIR is required")
    kind, doc, src = load_input(source)
    cal = load_calibration(cfg.calibration) if cfg.calibration else None
    verdict = load_verdict(cfg.verdict) if cfg.verdict else None
    # a run's records and videos are read from the folder of its summary.json
    run_dir = src.parent if kind == "run" and (src.parent / "episodes.jsonl").exists() else None
    out = outputs.check(
        "out",
        cfg.out,
        {"input": source, "run": run_dir, "calibration": cfg.calibration, "verdict": cfg.verdict},
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
    return ReportResult(out / "index.html", src, sorted(p.name for p in out.glob("*.png")))

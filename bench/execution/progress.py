"""The progress bar of `bench.api.run` on stderr (rich): done/total, successes (or the mean return, for a run
scored by return), errors, elapsed, ETA."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bench.execution.run_config import RunConfig
from bench.records import EpisodeRecord


class RunProgress:
    """A rich progress bar on stderr (done/total, successes or mean return, errors, elapsed, ETA), or nothing."""

    def __init__(self, show: bool, cfg: RunConfig, todo: int, done: int, total: int, run_dir: Path, workers: int):
        self.show = show
        self.by_return = cfg.metric == "return"  # no success signal (e.g. HalfCheetah): show the mean return
        self.metric = str(cfg.metric)  # the success flag counted when not by return
        self.counts = {"succ": 0, "err": 0}
        self.total_return, self.completed = 0.0, 0
        self.console = self.progress = None
        if not show:
            return
        from rich.console import Console  # rich: loaded only when something is drawn on the terminal
        from rich.progress import (  # rich: loaded only when something is drawn on the terminal
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
            TextColumn("mean return {task.fields[succ]}" if self.by_return else "successes {task.fields[succ]}"),
            TextColumn("errors {task.fields[err]}"),
            TimeElapsedColumn(),
            TextColumn("eta"),
            TimeRemainingColumn(),
        ]
        self.progress = Progress(*columns, console=self.console, transient=False)
        self.task = self.progress.add_task(cfg.suite, total=todo, succ="-" if self.by_return else 0, err=0)

    def __enter__(self) -> RunProgress:
        if self.progress is not None:
            self.progress.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.progress is not None:
            self.progress.stop()

    def advance(self, record: EpisodeRecord) -> None:
        if self.progress is None:
            return
        self.counts["err"] += int(record.error is not None)
        if self.by_return:
            if record.error is None:
                self.total_return += record.return_
                self.completed += 1
            shown: Any = f"{self.total_return / self.completed:.2f}" if self.completed else "-"
        else:
            self.counts["succ"] += int(bool(getattr(record, self.metric, False)))
            shown = self.counts["succ"]
        self.progress.update(self.task, advance=1, succ=shown, err=self.counts["err"])

    def note(self, text: str) -> None:
        if self.console is not None:
            self.console.print(text, soft_wrap=True)

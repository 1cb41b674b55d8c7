"""The progress of `bench.api.run` on stderr: done/total, successes (or the mean return, for a run scored by
return), errors, elapsed, ETA, and what the workers are waiting for (e.g. a policy server warming up) or, until
the first episode ends, that they are starting (imports and env builds take seconds to a minute).

On a terminal it is a rich progress bar. When stderr is not a terminal (a CI log, a file) a bar would draw
nothing until the end, so the same numbers are printed as one plain line at least every `PERIOD_S`
seconds (from a background thread: a line comes even while no episode finishes), and when the run ends.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Hashable
from pathlib import Path

from bench.execution.run_config import RunConfig
from bench.records import EpisodeRecord

PERIOD_S = 20.0  # stderr not a terminal: a progress line at least this often (CI logs show a job is alive)


def starting_text(workers: int, ray: bool = False) -> str:
    """What the progress says until the first episode ends: the workers import the suite's simulator and the
    policy (robosuite, torch: seconds each; a first run also compiles robosuite's numba kernels), then build envs."""
    unit = "Ray actor" if ray else "worker"
    return (
        f"starting {workers} {unit}{'' if workers == 1 else 's'}: importing the simulator and the policy, building envs"
    )


def _clock(seconds: float) -> str:
    s = int(max(seconds, 0))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


class RunProgress:
    """Progress on stderr (done/total, successes or mean return, errors, elapsed, ETA, waits), or nothing."""

    def __init__(self, show: bool, cfg: RunConfig, todo: int, done: int, total: int, run_dir: Path, workers: int):
        self.show = show
        self.by_return = cfg.metric == "return"  # no success signal (e.g. HalfCheetah): show the mean return
        self.metric = str(cfg.metric)  # the success flag counted when not by return
        self.counts = {"succ": 0, "err": 0, "done": 0}
        self.total_return, self.completed = 0.0, 0
        self.todo, self.name = todo, cfg.suite
        self.waits: dict[Hashable, str] = {}  # worker (its pid, say) -> what it waits for (`waiting`)
        self.starting = starting_text(workers, cfg.executor == "ray") if todo else ""  # until the first record
        self.console = self.progress = None
        self.t0 = time.monotonic()
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None
        if not show:
            return
        from rich.console import Console  # rich: loaded only when something is drawn on the terminal

        self.console = Console(stderr=True)
        if done:
            self.console.print(f"resuming {run_dir}: {done} of {total} episodes already recorded", soft_wrap=True)
        where = f"{workers} Ray actor(s)" if cfg.executor == "ray" else f"{workers} worker(s)"
        self.console.print(
            f"run {cfg.run_id}: {todo} episode{'' if todo == 1 else 's'} on {where} -> {run_dir}", soft_wrap=True
        )
        if not self.console.is_terminal:
            if self.starting:  # a log says at once why no episode ends for a while
                self.console.print(self.starting, soft_wrap=True, highlight=False)
            return
        from rich.progress import (  # rich: loaded only when something is drawn on the terminal
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        columns = [
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("mean return {task.fields[succ]}" if self.by_return else "successes {task.fields[succ]}"),
            TextColumn("errors {task.fields[err]}"),
            TimeElapsedColumn(),
            TextColumn("eta"),
            TimeRemainingColumn(),
            TextColumn("[yellow]{task.fields[status]}"),
        ]
        self.progress = Progress(*columns, console=self.console, transient=False)
        self.task = self.progress.add_task(
            cfg.suite, total=todo, succ="-" if self.by_return else 0, err=0, status=self._status()
        )

    def __enter__(self) -> RunProgress:
        self.t0 = time.monotonic()
        if self.progress is not None:
            self.progress.start()
        elif self.console is not None:
            self._ticker = threading.Thread(target=self._tick, name="bench-progress", daemon=True)
            self._ticker.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.progress is not None:
            self.progress.stop()
        elif self._ticker is not None:
            self._stop.set()
            self._ticker.join(5)
            self._print_line()

    # -- what the executor reports ---------------------------------------------------------------
    def advance(self, record: EpisodeRecord) -> None:
        self.counts["done"] += 1
        self.counts["err"] += int(record.error is not None)
        if record.error is None:
            self.total_return += record.return_
            self.completed += 1
        self.counts["succ"] += int(record.error is None and bool(getattr(record, self.metric, False)))
        self.starting = ""  # an episode ended: the workers have started
        if self.progress is not None:
            self.progress.update(
                self.task, advance=1, succ=self._shown(), err=self.counts["err"], status=self._status()
            )

    def note(self, text: str) -> None:
        if self.console is not None:
            self.console.print(text, soft_wrap=True)

    def waiting(self, text: str | None, who: Hashable = None) -> None:
        """Worker `who` waits for `text` (e.g. "the policy server at HOST:PORT to warm up"); None: it no longer waits.

        The bar shows it beside the counts; a plain (non-terminal) progress line ends with it, and the
        start of a wait is printed at once, so a log says what a run that seems stuck is waiting for.
        """
        if text is None:
            self.waits.pop(who, None)
        else:
            fresh = who not in self.waits
            self.waits[who] = text
            if fresh and self.progress is None and self.console is not None:
                self.console.print(f"waiting for {text}", soft_wrap=True)
        if self.progress is not None:
            self.progress.update(self.task, status=self._status())

    # -- text ------------------------------------------------------------------------------------
    def _shown(self) -> str | int:
        if self.by_return:
            return f"{self.total_return / self.completed:.2f}" if self.completed else "-"
        return self.counts["succ"]

    def _status(self) -> str:
        waits = list(self.waits.values())
        if not waits:
            return self.starting
        more = f" (and {len(waits) - 1} more worker(s))" if len(waits) > 1 else ""
        return f"waiting for {waits[0]}{more}"

    def line(self) -> str:
        """The plain progress line: what the bar shows, as text."""
        done, elapsed = self.counts["done"], time.monotonic() - self.t0
        eta = _clock(elapsed / done * (self.todo - done)) if done else "?"
        score = f"mean return {self._shown()}" if self.by_return else f"successes {self._shown()}"
        status = self._status()
        return (
            f"[{time.strftime('%H:%M:%S')}] {self.name}: {done}/{self.todo} episodes, {score}, errors "
            f"{self.counts['err']}, elapsed {_clock(elapsed)}, eta {eta}" + (f"; {status}" if status else "")
        )

    def _print_line(self) -> None:
        if self.console is not None:
            self.console.print(self.line(), soft_wrap=True, highlight=False)

    def _tick(self) -> None:
        while not self._stop.wait(PERIOD_S):
            self._print_line()

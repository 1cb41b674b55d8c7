"""Suites, cells and jobs: what a run is made of.

A suite is a named set of cells (task x robot x environment) with a declared split
manifest: for each axis (robots, envs, tasks) which values are `seen` (allowed in
training data) and which are `unseen` (held out). A run expands a suite into jobs
(cell, condition, episode index); the episode seed depends only on the run seed
and the episode index, so the same episode index starts from the same initial
state in every condition (pairing by seed).
"""
from __future__ import annotations

import dataclasses
import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.errors import ConfigError, did_you_mean

SPLITS = ("seen", "unseen")


@dataclass(frozen=True)
class Cell:
    """One (task, robot, env) cell of a suite and the split it belongs to."""

    suite: str
    task: str
    robot: str
    env: str
    split: str
    options: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)

    @property
    def key(self) -> str:
        return f"{self.task}/{self.robot}/{self.env}"


@dataclass(frozen=True)
class Condition:
    """A physics/interface condition: `nominal`, or one perturbation setting (see bench.perturb)."""

    name: str = "nominal"
    axis: str | None = None       # e.g. "friction"; None for nominal
    level: Any = None             # a scale/value, or a [low, high] range for randomisation
    spec: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)


NOMINAL = Condition()


@dataclass(frozen=True)
class Job:
    """One episode to run: a cell under a condition with its own seed."""

    cell: Cell
    condition: Condition
    episode: int
    seed: int

    @property
    def job_id(self) -> str:
        return f"{self.cell.key}|{self.condition.name}|{self.episode}"


def episode_seed(run_seed: int, episode: int) -> int:
    """Seed of episode `episode` of a run: independent of cell and condition (paired by seed)."""
    return int(np.random.SeedSequence([int(run_seed), int(episode)]).generate_state(1)[0])


def condition_rng(seed: int, condition: Condition) -> np.random.Generator:
    """Generator for a condition's random draws in one episode (stable across processes)."""
    return np.random.default_rng([int(seed), zlib.crc32(condition.name.encode())])


class Suite:
    """Base class of built-in suites; third-party suites may follow the same attributes.

    Subclasses set the class attributes and implement `all_cells` and `make_env`.
    """

    name: str = ""
    version: str = "1"
    reference_policy: str = "scripted"
    default_horizon: int = 200
    manifest: dict[str, dict[str, list[str]]] = {}

    def all_cells(self) -> list[Cell]:
        raise NotImplementedError

    def make_env(self, cell: Cell, horizon: int):
        raise NotImplementedError

    def summary_line(self) -> str:
        doc = (self.__doc__ or "").strip().splitlines()
        return doc[0] if doc else ""

    def cells(self, cfg) -> list[Cell]:
        """The cells selected by `robots=`, `tasks=`, `envs=` and `splits=` (all when unset)."""
        cells = self.all_cells()
        for key, attr in (("robots", "robot"), ("tasks", "task"), ("envs", "env"), ("splits", "split")):
            wanted = getattr(cfg, key, None)
            if not wanted:
                continue
            valid = sorted({getattr(c, attr) for c in cells})
            for w in wanted:
                if w not in valid:
                    raise ConfigError(
                        f"{key}: {w!r} is not in suite {self.name!r}; valid: {', '.join(valid)}.{did_you_mean(w, valid)}"
                    )
            cells = [c for c in cells if getattr(c, attr) in wanted]
        return cells

    def jobs(self, cfg, conditions: list[Condition]) -> list[Job]:
        """Expand into jobs, cell-major so each worker reuses its env across consecutive episodes."""
        return [
            Job(cell, cond, ep, episode_seed(cfg.seed, ep))
            for cell in self.cells(cfg)
            for cond in conditions
            for ep in range(cfg.episodes)
        ]

    def describe(self) -> dict[str, Any]:
        """JSON-able identity of the suite: name, version and split manifest."""
        return {"name": self.name, "version": self.version, "manifest": self.manifest}


def cell_to_dict(cell: Cell) -> dict[str, Any]:
    return dataclasses.asdict(cell)

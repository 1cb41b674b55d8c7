"""The run summary and run metadata as typed, frozen dataclasses: summary.json is written from them and read
back into them.

`Summary.to_json()` is exactly the document bench has always written (key order included, so committed
summaries re-score byte-identically); `Summary.from_json()` reads one back, refusing a field of the wrong
type with one line. `RunMeta` is run.json. The parts whose shape belongs to another owner (the suite's
description, the policy identity, the config, provenance, sensitivity rows, latency) stay mappings.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, TypeVar, overload

from bench.core.errors import DataError

SUCCESS = ("success_once", "success_at_end")
T = TypeVar("T")


@overload
def _need(d: object, key: str, types: type[T] | tuple[type[T], ...], where: str) -> T: ...


@overload
def _need(
    d: object, key: str, types: type[T] | tuple[type[T], ...], where: str, nullable: Literal[True]
) -> T | None: ...


def _need(d: object, key: str, types: type[T] | tuple[type[T], ...], where: str, nullable: bool = False) -> T | None:
    """`d[key]`, refused with one line (DataError) when `d` has no such field or it is not of `types`."""
    if not isinstance(d, dict) or key not in d:
        raise DataError(f"{where}: field {key!r} is missing")
    v = d[key]
    if v is None and nullable:
        return None
    if isinstance(v, bool) and bool not in (types if isinstance(types, tuple) else (types,)):
        raise DataError(f"{where}: field {key!r} is {v!r}; expected {types}")
    if not isinstance(v, types):
        raise DataError(f"{where}: field {key!r} is {v!r}; expected {types}")
    return v


def _get(d: object, key: str) -> object:
    """`d[key]` when `d` is a mapping holding it, else None."""
    return d.get(key) if isinstance(d, dict) else None


def _raw(d: object, key: str) -> Any:  # a JSON value passed through unread (its shape is its owner's)
    return d.get(key) if isinstance(d, dict) else None


@dataclass(frozen=True)
class Interval:
    """An estimate as summaries hold it: value with its two-sided interval, or None with the reason."""

    value: float | None
    ci: tuple[float, float] | None
    reason: str | None = None

    def to_json(self) -> dict[str, object]:
        out: dict[str, object] = {"value": self.value, "ci": None if self.ci is None else list(self.ci)}
        if self.reason is not None:
            out["reason"] = self.reason
        return out

    @classmethod
    def from_json(cls, d: object, where: str) -> Interval:
        value = _need(d, "value", (int, float), where, nullable=True)
        ci = _need(d, "ci", list, where, nullable=True)
        reason = _get(d, "reason")
        if ci is not None and len(ci) != 2:
            raise DataError(f"{where}: field 'ci' is {ci!r}; expected [low, high]")
        if reason is not None and not isinstance(reason, str):
            raise DataError(f"{where}: field 'reason' is {reason!r}; expected a string")
        return cls(value, None if ci is None else (ci[0], ci[1]), reason)


@dataclass(frozen=True)
class Rate:
    """A success rate of a cell: successes among the completed episodes, and its Wilson interval."""

    successes: int
    estimate: Interval

    def to_json(self) -> dict[str, object]:
        return {"successes": self.successes, **self.estimate.to_json()}

    @classmethod
    def from_json(cls, d: object, where: str) -> Rate:
        return cls(_need(d, "successes", int, where), Interval.from_json(d, where))


@dataclass(frozen=True)
class CellRow:
    """One cell (task x robot x env) under one condition: counts, and its success rates."""

    task: str
    robot: str
    env: str
    split: str
    condition: str
    n: int  # completed episodes
    errors: int
    mean_return: float | None
    mean_length: float | None
    success_once: Rate
    success_at_end: Rate
    return_: Interval | None = None  # runs scored by return

    def to_json(self) -> dict[str, object]:
        out: dict[str, object] = {
            "task": self.task,
            "robot": self.robot,
            "env": self.env,
            "split": self.split,
            "condition": self.condition,
            "n": self.n,
            "errors": self.errors,
            "mean_return": self.mean_return,
            "mean_length": self.mean_length,
            "success_once": self.success_once.to_json(),
            "success_at_end": self.success_at_end.to_json(),
        }
        if self.return_ is not None:
            out["return"] = self.return_.to_json()
        return out

    @classmethod
    def from_json(cls, d: object, where: str) -> CellRow:
        task, robot, env, split, condition = (
            _need(d, k, str, where) for k in ("task", "robot", "env", "split", "condition")
        )
        ret = _get(d, "return")
        return cls(
            task=task,
            robot=robot,
            env=env,
            split=split,
            condition=condition,
            n=_need(d, "n", int, where),
            errors=_need(d, "errors", int, where),
            mean_return=_need(d, "mean_return", (int, float), where, nullable=True),
            mean_length=_need(d, "mean_length", (int, float), where, nullable=True),
            success_once=Rate.from_json(_get(d, "success_once"), f"{where}.success_once"),
            success_at_end=Rate.from_json(_get(d, "success_at_end"), f"{where}.success_at_end"),
            return_=None if ret is None else Interval.from_json(ret, f"{where}.return"),
        )

    @property
    def key(self) -> str:
        return f"{self.task}/{self.robot}/{self.env}"


@dataclass(frozen=True)
class Gap:
    """A transfer gap: reference minus target of one metric and statistic, with its interval."""

    kind: str
    metric: str
    statistic: str
    reference: str
    target: str
    estimate: Interval

    def to_json(self) -> dict[str, object]:
        return {
            "kind": self.kind,
            "metric": self.metric,
            "statistic": self.statistic,
            "reference": self.reference,
            "target": self.target,
            **self.estimate.to_json(),
        }

    @classmethod
    def from_json(cls, d: object, where: str) -> Gap:
        kind, metric, statistic, reference, target = (
            _need(d, k, str, where) for k in ("kind", "metric", "statistic", "reference", "target")
        )
        return cls(kind, metric, statistic, reference, target, estimate=Interval.from_json(d, where))


@dataclass(frozen=True)
class Counts:
    episodes: int
    errors: int
    expected: int | None
    complete: bool

    def to_json(self) -> dict[str, object]:
        return {"episodes": self.episodes, "errors": self.errors, "expected": self.expected, "complete": self.complete}

    @classmethod
    def from_json(cls, d: object, where: str) -> Counts:
        return cls(
            _need(d, "episodes", int, where),
            _need(d, "errors", int, where),
            _need(d, "expected", int, where, nullable=True),
            _need(d, "complete", bool, where),
        )


# split -> metric -> statistic ("mean", "iqm") -> estimate
SplitStats = dict[str, dict[str, dict[str, Interval]]]


@dataclass(frozen=True)
class Summary:
    """A run's summary: what summary.json holds, typed."""

    schema: str
    run_id: str
    suite: dict[str, object]
    policy: dict[str, object]
    metric: str
    confidence: float
    counts: Counts
    cells: tuple[CellRow, ...]
    splits: SplitStats
    gaps: tuple[Gap, ...]
    config: dict[str, object]
    provenance: dict[str, object]
    policy_latency: dict[str, object] | None = None
    sensitivity: list[dict[str, object]] | None = field(default=None)
    curves: list[dict[str, object]] | None = field(default=None)  # `bench.scoring.curves`: one per range condition
    instructions: list[dict[str, object]] | None = field(default=None)  # `bench.scoring.instructions`: per variant
    interactions: list[dict[str, object]] | None = field(default=None)  # `bench.scoring.interactions`: per combination

    def to_json(self) -> dict[str, object]:
        out: dict[str, object] = {
            "schema": self.schema,
            "run_id": self.run_id,
            "suite": self.suite,
            "policy": self.policy,
            "metric": self.metric,
            "confidence": self.confidence,
            "counts": self.counts.to_json(),
            "cells": [c.to_json() for c in self.cells],
            "splits": {
                s: {m: {k: e.to_json() for k, e in st.items()} for m, st in ms.items()} for s, ms in self.splits.items()
            },
            "gaps": [g.to_json() for g in self.gaps],
            "config": self.config,
            "provenance": self.provenance,
        }
        if self.policy_latency is not None:
            out["policy_latency"] = self.policy_latency
        if self.sensitivity is not None:
            out["sensitivity"] = self.sensitivity
        if self.curves is not None:
            out["curves"] = self.curves
        if self.instructions is not None:
            out["instructions"] = self.instructions
        if self.interactions is not None:
            out["interactions"] = self.interactions
        return out

    @classmethod
    def from_json(cls, d: object, where: str = "summary") -> Summary:
        """A summary document read back (one DataError naming the field when its type is wrong)."""
        splits: SplitStats = {}
        for s, ms in (_need(d, "splits", dict, where)).items():
            splits[s] = {}
            for m, st in ms.items():
                if not isinstance(st, dict):
                    raise DataError(f"{where}.splits.{s}.{m}: expected a mapping of statistics")
                splits[s][m] = {k: Interval.from_json(e, f"{where}.splits.{s}.{m}.{k}") for k, e in st.items()}
        return cls(
            schema=_need(d, "schema", str, where),
            run_id=_need(d, "run_id", str, where),
            suite=_need(d, "suite", dict, where),
            policy=_need(d, "policy", dict, where),
            metric=_need(d, "metric", str, where),
            confidence=_need(d, "confidence", (int, float), where),
            counts=Counts.from_json(_get(d, "counts"), f"{where}.counts"),
            cells=tuple(
                CellRow.from_json(c, f"{where}.cells[{i}]") for i, c in enumerate(_need(d, "cells", list, where))
            ),
            splits=splits,
            gaps=tuple(Gap.from_json(g, f"{where}.gaps[{i}]") for i, g in enumerate(_need(d, "gaps", list, where))),
            config=_need(d, "config", dict, where),
            provenance=_need(d, "provenance", dict, where),
            policy_latency=_raw(d, "policy_latency"),
            sensitivity=_raw(d, "sensitivity"),
            curves=_raw(d, "curves"),
            instructions=_raw(d, "instructions"),
            interactions=_raw(d, "interactions"),
        )

    def nominal_cells(self) -> list[CellRow]:
        return [c for c in self.cells if c.condition == "nominal"]


@dataclass(frozen=True)
class RunMeta:
    """run.json: what a run was (suite, policy, config) and where it came from (provenance)."""

    run_id: str
    suite: dict[str, object]
    policy: dict[str, object]
    config: dict[str, object]
    expected_episodes: int | None
    provenance: dict[str, object]
    suite_spec: dict[str, object] | None = None  # bench.protocols.suite.SuiteSpec (runs before it existed lack it)

    def to_json(self) -> dict[str, Any]:  # JSON: run.json, which the run reads back by key and stamps
        out: dict[str, Any] = {"run_id": self.run_id, "suite": self.suite}
        if self.suite_spec is not None:
            out["suite_spec"] = self.suite_spec
        out.update(
            policy=self.policy,
            config=self.config,
            expected_episodes=self.expected_episodes,
            provenance=self.provenance,
        )
        return out

    @classmethod
    def from_json(cls, d: object, where: str = "run.json") -> RunMeta:
        return cls(
            run_id=_need(d, "run_id", str, where),
            suite=_need(d, "suite", dict, where),
            policy=_need(d, "policy", dict, where),
            config=_need(d, "config", dict, where),
            expected_episodes=_raw(d, "expected_episodes"),
            provenance=_need(d, "provenance", dict, where),
            suite_spec=_raw(d, "suite_spec"),
        )

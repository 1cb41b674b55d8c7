"""Combined perturbations (`perturb.combine`): several axes applied together in one episode.

Grammar (docs/perturbations.md, "Combined axes"):
    perturb.combine=[friction,mass]                         the full factorial of the axes' levels
    perturb.combine.axes=[friction,mass,latency] perturb.combine.fraction=0.5
                                                            a seeded share of it (the all-at-once one always kept)

Each combined axis takes its levels from its own `perturb.AXIS=...` key, and those single-axis conditions stay
in the run: a combination's drop is read against theirs (`bench.scoring.interactions`). A combination is one
`Combination` condition whose `parts` are the single-axis conditions themselves, so each part is applied, and
draws from its generator (`condition_rng(seed, part)`), exactly as it is alone; `bench.sims.perturb.reset`
applies the parts in the order the axes are given. The all-at-once combination puts every axis at its most
severe level: the one farthest from nominal (`severity`).
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import product

import numpy as np

from bench.core.errors import ConfigError, did_you_mean
from bench.protocols.suite import Condition
from bench.sims.perturb.axis import Axis

KEY = "combine"  # perturb.combine
SEP = "&"  # joins the parts' names ("friction=0.5&mass=2") and axes ("friction&mass")
_KEYS = ("axes", "fraction")  # the dict form's keys


@dataclass(frozen=True)
class Combination(Condition):
    """A condition that applies several single-axis conditions (`parts`) in one episode.

    `name` joins the parts' names with `&`, `axis` their axes, `level` maps each axis to its part's level.
    """

    parts: tuple[Condition, ...] = ()
    all_at_once: bool = False  # every axis at its most severe level


def part_names(name: str) -> list[str]:
    """The names of a combined condition's parts ([name] itself for a single-axis condition)."""
    return name.split(SEP)


def severity(axis: Axis | None, name: str, level: object) -> float:
    """How far a level is from nominal: |log(level)| on a scale axis (x0.5 and x2 are as far), |level - nominal|
    otherwise, the farther end of a [low, high] range; -1 for what has no distance (a calibration's draws,
    a word), so that among those the one given last is taken."""
    if axis is None or "~from(" in name:
        return -1.0
    ends: list[float] = []
    for v in level if isinstance(level, (list, tuple)) else [level]:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            return -1.0
        ends.append(float(v))
    if not ends:
        return -1.0
    if axis.unit.startswith("scale"):
        return max(math.inf if v <= 0 else abs(math.log(v)) for v in ends)
    return max(abs(v - axis.nominal) for v in ends)


def most_severe(axis: Axis | None, conditions: Sequence[Condition]) -> Condition:
    """The condition of `conditions` (one axis' levels) farthest from nominal; ties: the one given last."""
    best = max(range(len(conditions)), key=lambda i: (severity(axis, conditions[i].name, conditions[i].level), i))
    return conditions[best]


def _spec(value: object) -> tuple[list[str], float]:
    """(axis names, fraction) from `perturb.combine=[A,B]` or its dict form."""
    fraction: object = 1.0
    if isinstance(value, Mapping):
        for key in value:
            if key not in _KEYS:
                raise ConfigError(
                    f"perturb.{KEY}.{key}: unknown key; valid: {', '.join(_KEYS)}.{did_you_mean(str(key), _KEYS)}"
                )
        if "axes" not in value:
            raise ConfigError(f"perturb.{KEY}: give the axes, perturb.{KEY}.axes=[A,B] beside perturb.{KEY}.fraction")
        fraction, value = value.get("fraction", 1.0), value["axes"]
    names = [value] if isinstance(value, str) else value
    if not isinstance(names, (list, tuple)) or not all(isinstance(n, str) and n for n in names):
        raise ConfigError(f"perturb.{KEY}: expected a list of axis names, e.g. perturb.{KEY}=[friction,mass]")
    if isinstance(fraction, bool) or not isinstance(fraction, (int, float)) or not 0 < fraction <= 1:
        raise ConfigError(
            f"perturb.{KEY}.fraction: {fraction!r} is invalid; valid: a share of the factorial in (0, 1] (1 = all)"
        )
    return list(dict.fromkeys(names)), float(fraction)


def combinations(
    value: object, singles: Sequence[Condition], axes: Mapping[str, Axis], seed: int = 0
) -> list[Combination]:
    """The combined conditions `perturb.combine=value` asks for, from the run's single-axis conditions.

    Every combination of one level per axis (the full factorial, in the order the axes and their levels are
    given), or with `fraction` < 1 a subset of round(fraction x size) of them (at least one) drawn with a
    generator seeded from the run `seed`, always keeping the all-at-once combination.

    Raises ConfigError (one line) for an unknown axis, an axis without levels in the run, fewer than two
    axes, a fraction outside (0, 1], or an axis whose levels cannot be applied together with others.
    """
    names, fraction = _spec(value)
    by_axis: dict[str, list[Condition]] = {}
    for c in singles:
        if c.axis is not None:
            by_axis.setdefault(c.axis, []).append(c)
    for name in names:
        if name not in axes:
            raise ConfigError(
                f"perturb.{KEY}: {name!r} is not a perturbation axis; valid: {', '.join(axes)}."
                f"{did_you_mean(name, axes)}"
            )
        if name not in by_axis:
            given = ", ".join(by_axis) or "none"
            raise ConfigError(
                f"perturb.{KEY}: {name} has no levels in this run; give them with perturb.{name}=[...] "
                f"(axes with levels: {given})"
            )
        row = axes[name]
        if row.scale is None and row.physx is None and row.wrap is None and row.paint is None and row.start is None:
            raise ConfigError(f"perturb.{KEY}: {name} cannot be applied together with other axes (a {row.kind} axis)")
        if row.words:  # its episodes bind paraphrase data and a shadow policy per condition: one axis at a time
            raise ConfigError(
                f"perturb.{KEY}: {name} is measured one variant at a time (its action difference needs the true "
                "instruction beside the variant); leave it out of the combination"
            )
        for c in by_axis[name]:
            if SEP in c.name:
                raise ConfigError(f"perturb.{KEY}: {c.name!r} has {SEP!r} in its name; a combined part cannot")
    if len(names) < 2:
        raise ConfigError(
            f"perturb.{KEY}: {len(names)} distinct axis given ({', '.join(names) or 'none'}); combining needs at "
            f"least 2, e.g. perturb.{KEY}=[friction,mass]"
        )
    worst = tuple(most_severe(axes[n], by_axis[n]) for n in names)
    grid = [tuple(p) for p in product(*(by_axis[n] for n in names))]
    keep = list(range(len(grid)))
    if fraction < 1:
        k = min(len(grid), max(1, round(fraction * len(grid))))
        rng = np.random.default_rng([int(seed), zlib.crc32(KEY.encode())])
        others = [i for i, parts in enumerate(grid) if parts != worst]
        keep = sorted([grid.index(worst), *rng.choice(others, size=k - 1, replace=False).tolist()])
    return [_combination(grid[i], all_at_once=grid[i] == worst) for i in keep]


def _combination(parts: tuple[Condition, ...], all_at_once: bool) -> Combination:
    return Combination(
        name=SEP.join(p.name for p in parts),
        axis=SEP.join(str(p.axis) for p in parts),
        level={str(p.axis): p.level for p in parts},
        spec={"kind": KEY},
        parts=parts,
        all_at_once=all_at_once,
    )

"""Per-axis robustness: success under each perturbation axis, all its levels pooled, against nominal.

The table robustness benchmarks print (one row per axis: nominal success, perturbed success,
absolute and relative drop), with the drop paired by (cell, episode seed) as in
`bench.scoring.sensitivity` and its paired interval (Tango's score interval for success). `bench.scoring.sensitivity` gives the same per
level; this pools an axis' levels (a grid, or the draws of a `uniform()` range) into one number,
so axes can be ranked: which change of the world hurts the policy most.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from typing import TypedDict

import numpy as np

from bench.records import EpisodeRecord, dedupe
from bench.scoring import stats as scoring
from bench.scoring.sensitivity import paired_arrays
from bench.sims.perturb.axes import AXES


class AxisRow(TypedDict):
    """One row of the robustness table (`table`)."""

    axis: str
    kind: str | None  # model / interface / visual / frame (None: an axis this bench does not know)
    levels: list[str]  # the axis' condition names
    pairs: int
    nominal: float | None
    perturbed: float | None
    drop: scoring.EstimateJSON
    relative_drop: float | None


def table(
    records: Sequence[EpisodeRecord],
    metric: str,
    rng: np.random.Generator,
    n_boot: int = 2000,
    confidence: float = 0.95,
) -> list[AxisRow]:
    """One row per perturbation axis of the run (JSON-able, no NaN), most harmful first.

    Row: axis, kind (model / interface / visual), levels (condition names), pairs, nominal and
    perturbed success over the paired episodes, drop = nominal - perturbed with its interval, and
    relative drop = drop / nominal (null when nominal is 0).
    """
    recs = [r for r in dedupe(records) if r.error is None]
    nominal: dict[str, dict[int, EpisodeRecord]] = defaultdict(dict)
    by_axis: dict[str, dict[str, dict[int, EpisodeRecord]]] = defaultdict(lambda: defaultdict(dict))
    levels: dict[str, set[str]] = defaultdict(set)
    cell_of: dict[str, str] = {}
    for r in recs:
        cell = f"{r.task}/{r.robot}/{r.env}"
        if r.axis is None:
            nominal[cell][r.episode] = r
        else:
            key = f"{cell}|{r.condition}"
            by_axis[r.axis][key][r.episode] = r
            levels[r.axis].add(r.condition)
            cell_of[key] = cell
    rows: list[AxisRow] = []
    for axis, target in by_axis.items():
        ref_by_key = {key: nominal.get(cell_of[key], {}) for key in target}
        ref, tgt = paired_arrays(ref_by_key, target, metric)
        n = int(ref.size)
        est = scoring.paired_gap(ref, tgt, rng, n_boot=n_boot, confidence=confidence).to_dict()
        base = float(ref.mean()) if n else None
        drop = est.get("value")
        rows.append(
            {
                "axis": axis,
                "kind": AXES[axis].kind if axis in AXES else None,
                "levels": sorted(levels[axis]),
                "pairs": n,
                "nominal": round(base, 6) if base is not None else None,
                "perturbed": round(float(tgt.mean()), 6) if n else None,
                "drop": est,
                "relative_drop": round(drop / base, 6) if drop is not None and base else None,
            }
        )
    rows.sort(key=lambda row: -(row["drop"].get("value") or 0.0))
    return rows

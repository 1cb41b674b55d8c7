"""Checkpoint sweeps: success per checkpoint with simultaneous intervals, and the best selected with its
multiplicity accounted for (`bench sweep`).

Every checkpoint plays the same episodes (same cells, conditions and seeds), so checkpoints compare paired.

- Each checkpoint's success is the mean of its cell rates with the stratified Wilson interval `bench run`
  reports, at the simultaneous level 1 − α/K (Bonferroni over the K checkpoints): all K intervals cover their
  true rates together with probability ≥ 1 − α, so the curve of success against training step can be read as a
  whole, not one point at a time.
- The selection is Hsu's multiple comparison with the best (Hsu 1984, Ann. Statist. 12:1136) in its
  Bonferroni form, one-sided and paired: checkpoint i stays in the *best set* unless some checkpoint j is
  better than it with a paired lower bound above 0 (Tango's score bound on the difference of the two
  checkpoints' success over the common episodes, one-sided at 1 − α/(K − 1)). The truly best checkpoint is in
  the set with probability ≥ 1 − α however many were looked at (for it, every such event is a false bound,
  each of probability ≤ α/(K − 1)). The *selected* checkpoint is the set's highest estimate (ties: the later
  step). A set of one is a clear winner; a larger set says which checkpoints the episodes cannot tell apart.
  Why this and not "the highest estimate": with many checkpoints the highest estimate is biased upward (the
  winner's curse), and a verdict needs to say when the runner-up is as good.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bench.records import EpisodeRecord
from bench.scoring.stats import Estimate, paired_score_bound, stratified_wilson

Pair = tuple[str, str, int]  # (cell, condition, seed): one episode every checkpoint plays


@dataclass(frozen=True)
class Point:
    """One checkpoint of the sweep as the selection sees it."""

    name: str
    step: float
    outcomes: dict[Pair, float]  # 0/1 per episode


def outcomes_of(records: Sequence[EpisodeRecord], metric: str) -> dict[Pair, float]:
    """Completed episodes' 0/1 `metric` by (cell, condition, seed)."""
    return {
        (f"{r.task}/{r.robot}/{r.env}", r.condition, r.seed): float(getattr(r, metric))
        for r in records
        if r.error is None
    }


def success(outcomes: dict[Pair, float], confidence: float) -> Estimate:
    """Mean of cell rates (cell x condition) with the stratified Wilson interval at `confidence`."""
    cells: dict[tuple[str, str], list[float]] = {}
    for (cell, cond, _), y in outcomes.items():
        cells.setdefault((cell, cond), []).append(y)
    if not cells:
        return Estimate(None, reason="no completed episode")
    return stratified_wilson([np.array(v) for v in cells.values()], confidence)


def paired_lower(better: dict[Pair, float], worse: dict[Pair, float], confidence: float) -> tuple[float, int]:
    """One-sided lower bound on success(better) − success(worse) over their common episodes (Tango), and the
    number of pairs (bound −1 without any)."""
    common = sorted(set(better) & set(worse))
    if not common:
        return -1.0, 0
    b = sum(1 for k in common if better[k] > worse[k])
    c = sum(1 for k in common if better[k] < worse[k])
    return paired_score_bound(b, c, len(common), confidence, "lower"), len(common)


def select(points: Sequence[Point], alpha: float) -> dict[str, Any]:
    """Per checkpoint its simultaneous interval and whether it is in the best set; the selected checkpoint."""
    k = len(points)
    simultaneous = 1.0 - alpha / k
    pairwise = 1.0 - alpha / max(k - 1, 1)
    estimates = [success(p.outcomes, simultaneous) for p in points]
    beaten: dict[str, tuple[str, float]] = {}
    for i, pi in enumerate(points):
        for j, pj in enumerate(points):
            if i == j or estimates[j].value is None:
                continue
            lower, _ = paired_lower(pj.outcomes, pi.outcomes, pairwise)
            if lower > 0 and (pi.name not in beaten or lower > beaten[pi.name][1]):
                beaten[pi.name] = (pj.name, lower)
    rows: list[dict[str, Any]] = []
    for p, est in zip(points, estimates):
        rows.append(
            {
                "name": p.name,
                "step": p.step,
                "episodes": len(p.outcomes),
                "success": est.to_dict(),
                "in_best_set": p.name not in beaten and est.value is not None,
                "beaten_by": None
                if p.name not in beaten
                else {"checkpoint": beaten[p.name][0], "lower_bound": round(beaten[p.name][1], 6)},
            }
        )
    best_set = [r for r in rows if r["in_best_set"]]
    chosen = max(best_set, key=lambda r: (float(r["success"]["value"]), float(r["step"])), default=None)
    return {
        "method": "multiple comparison with the best (Hsu 1984), Bonferroni: paired one-sided Tango bounds at "
        f"1 - alpha/(K-1); simultaneous stratified Wilson intervals at 1 - alpha/K (K={k})",
        "alpha": alpha,
        "simultaneous_confidence": round(simultaneous, 6),
        "pairwise_confidence": round(pairwise, 6),
        "checkpoints": rows,
        "best_set": [r["name"] for r in best_set],
        "selected": None if chosen is None else chosen["name"],
    }

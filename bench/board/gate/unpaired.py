"""The regression gate on unpaired runs (`bench regress paired=false`): one look, exact unconditional tests per cell.

Two recorded runs whose episodes started from other states (other seeds) cannot be paired, so the paired
gate's Tango tests do not apply; each side of a cell is then a binomial batch (successes out of episodes)
and drop = baseline rate - candidate rate is tested with two independent batches:

    cell:C    one cell                     Chan's exact unconditional test (`scoring.exact.chan`):
                                           Farrington-Manning score, p maximised on the boundary
    split:S   the cells of split S         stratified Farrington-Manning score: the per-cell score
    pooled    all cells                    numerators summed with Mantel-Haenszel weights
                                           n_b n_c / (n_b + n_c) over the root of the weighted sum of
                                           their restricted variances, referred to the normal
                                           (asymptotic); with one cell it is that cell's exact test

One look at the episodes the runs have (no early stopping: the runs are already recorded); the tests'
shares of alpha are the paired gate's (`sequential.base_weights`, no IQM: its bootstrap resamples pairs)
and weighted Holm across them (`sequential.holm`), so the chance of any false alarm when no cell's drop
exceeds `margin` is at most alpha (exactly for the cells; the split and pooled tests are asymptotic).
"no regression" is certified when the pooled non-inferiority test (H1: drop < margin, same statistic)
has p below alpha. Bounds on each drop are the score-test inversions at the test's level (reporting only).
Errored episodes count as failures of their side.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bench.board.gate import sequential
from bench.board.gate.sequential import CellKey, cell_id
from bench.records import dedupe
from bench.scoring import exact

TEST_NAME = "chan_exact_unconditional"
POOLED_NAME = "stratified_farrington_manning_mantel_haenszel"


@dataclass(frozen=True)
class Batches:
    """Successes and episodes of each side of one cell (or of several cells, summed for the rates only)."""

    x_base: int = 0
    n_base: int = 0
    x_cand: int = 0
    n_cand: int = 0

    @property
    def drop(self) -> float:
        return self.x_base / self.n_base - self.x_cand / self.n_cand

    def __add__(self, o: Batches) -> Batches:
        return Batches(self.x_base + o.x_base, self.n_base + o.n_base, self.x_cand + o.x_cand, self.n_cand + o.n_cand)


def cell_batches(candidate: list, baseline: list, metric: str) -> tuple[dict[CellKey, Batches], dict[str, int]]:
    """Records of each side -> successes and episodes per cell (an errored episode is a failure of its side),
    and the errored episodes per side. Cells that one side lacks are left out (`bench.api` refuses them first)."""
    per: dict[str, dict[CellKey, list[int]]] = {}
    errors = {"candidate": 0, "baseline": 0, "both": 0}
    for role, records in (("candidate", candidate), ("baseline", baseline)):
        cells: dict[CellKey, list[int]] = {}
        for r in dedupe(records):
            k = (r.task, r.robot, r.env, r.condition, r.split)
            xs = cells.setdefault(k, [0, 0])
            ok = r.error is None and bool(getattr(r, metric))
            errors[role] += r.error is not None
            xs[0] += ok
            xs[1] += 1
        per[role] = cells
    keys = sorted(set(per["candidate"]) & set(per["baseline"]))
    return {k: Batches(*per["baseline"][k], *per["candidate"][k]) for k in keys}, errors


def _weight(b: Batches) -> float:
    return b.n_base * b.n_cand / (b.n_base + b.n_cand)


def stratified_z(groups: Sequence[Batches], margin: float) -> float:
    """Stratified Farrington-Manning score of the drop against `margin`, Mantel-Haenszel weights."""
    num = var = 0.0
    for b in groups:
        r1, r2 = exact.restricted_rates(b.x_base, b.n_base, b.x_cand, b.n_cand, margin)
        w = _weight(b)
        num += w * (b.drop - margin)
        var += w * w * (float(r1) * (1 - float(r1)) / b.n_base + float(r2) * (1 - float(r2)) / b.n_cand)
    if abs(num) < 1e-12:
        return 0.0
    return float(np.sign(num) * np.inf) if var <= 0 else num / float(np.sqrt(var))


def p_value(groups: Sequence[Batches], margin: float, alternative: str) -> float:
    """p of "drop > margin" ("greater") or "drop < margin" ("less"): exact for one cell, stratified score else."""
    from scipy.stats import norm  # scipy: loaded only when a gate is evaluated

    if len(groups) == 1:
        b = groups[0]
        return exact.chan(b.x_base, b.n_base, b.x_cand, b.n_cand, margin, alternative)
    z = stratified_z(groups, margin)
    return float(norm.sf(z) if alternative == "greater" else norm.cdf(z))


def bound(groups: Sequence[Batches], level: float, side: str) -> float:
    """Score-test bound on the drop at one-sided `level`: the margin where the stratified score reaches the quantile."""
    from scipy.stats import norm  # scipy: loaded only when a gate is evaluated

    q = float(norm.ppf(level)) * (1.0 if side == "lower" else -1.0)
    lo, hi = -1.0 + 1e-9, 1.0 - 1e-9  # the score falls as the margin grows
    for _ in range(60):
        mid = (lo + hi) / 2
        if stratified_z(groups, mid) > q:
            lo = mid
        else:
            hi = mid
    return (lo + hi) / 2


def evaluate(
    cells: Mapping[CellKey, Batches], margin: float, alpha: float, cell_alpha: float, episodes: int
) -> dict[str, Any]:
    """The one look of the unpaired gate: every test, Holm across them, the decision; JSON-ready (schema's `look`)."""
    keys = sorted(k for k, b in cells.items() if b.n_base and b.n_cand)
    if not keys:
        return {"look": 1, "episodes_per_cell": max(episodes, 1), "pairs": 0, "decision": "continue",
                "reason": "no cell with episodes on both sides"}  # fmt: skip
    groups: dict[str, list[Batches]] = {"pooled": [cells[k] for k in keys]}
    splits = sorted({k[4] for k in keys})
    if len(splits) >= 2:
        groups.update({f"split:{s}": [cells[k] for k in keys if k[4] == s] for s in splits})
    if len(keys) >= 2:
        groups.update({cell_id(k): [cells[k]] for k in keys})
    weights = sequential.base_weights(keys, False, cell_alpha)
    t = {h: alpha * w for h, w in weights.items() if h in groups}
    p = {h: p_value(g, margin, "greater") for h, g in groups.items()}
    decided = sequential.holm(p, t)
    regressed = [h for h, (rej, _) in decided.items() if rej]
    p_ni = p_value(groups["pooled"], margin, "less")
    certified = p_ni < alpha
    tests = []
    for h, g in groups.items():
        thr = decided[h][1] if h in decided else alpha * weights.get(h, 0.0)
        total = sum(g, Batches())
        test = {
            "id": h,
            "kind": h.split(":")[0],
            "pairs": total.n_base + total.n_cand,
            "drop": round(total.drop, 6),
            "p": float(f"{p[h]:.6g}"),
            "threshold": float(f"{thr:.6g}"),
            "tested": h in decided,
            "rejected": bool(h in decided and decided[h][0]),
            "test": TEST_NAME if len(g) == 1 else POOLED_NAME,
        }
        if 0 < thr < 0.5:
            test["level"] = round(1.0 - thr, 8)
            test["lcb"], test["ucb"] = round(bound(g, 1.0 - thr, "lower"), 6), round(bound(g, 1.0 - thr, "upper"), 6)
        tests.append(test)
    pooled = sum(groups["pooled"], Batches())
    by_id = {x["id"]: x for x in tests}
    return {
        "look": 1,
        "episodes_per_cell": max(episodes, 1),
        "pairs": pooled.n_base + pooled.n_cand,
        "baseline_only": 0,
        "candidate_only": 0,
        "alpha_spent": float(f"{sum(t.values()):.6g}"),
        "tests": tests,
        "mean": {
            "value": round(pooled.drop, 6),
            "lcb": by_id["pooled"].get("lcb"),
            "ucb": round(bound(groups["pooled"], 1.0 - alpha, "upper"), 6),
        },
        "iqm": {"value": round(pooled.drop, 6), "lcb": None, "ucb": None, "used": False},
        "certify": {"level": round(1.0 - alpha, 8), "certified": bool(certified), "p": float(f"{p_ni:.6g}")},
        "regressed": regressed,
        "decision": "regression" if regressed else "no_regression" if certified else "continue",
    }


def _rates(b: Batches) -> dict[str, object]:
    return {
        "pairs": b.n_base + b.n_cand,
        "baseline": round(b.x_base / b.n_base, 6),
        "candidate": round(b.x_cand / b.n_cand, 6),
        "drop": round(b.drop, 6),
        "episodes_baseline": b.n_base,
        "episodes_candidate": b.n_cand,
    }


def _columns(t: Mapping[str, Any]) -> dict[str, object]:
    return {
        "p": t.get("p"),
        "level": t.get("level"),
        "drop_lcb": t.get("lcb"),
        "drop_ucb": t.get("ucb"),
        "tested": bool(t.get("tested", False)),
        "regressed": bool(t.get("rejected", False)),
        "test": t.get("test"),
    }


def cell_rows(cells: Mapping[CellKey, Batches], look: Mapping[str, Any]) -> list[dict[str, object]]:
    """Per-cell rows of the verdict (`pairs` = episodes of both sides; no lost/won pairs: 0)."""
    tests = {t["id"]: t for t in look.get("tests", [])}
    rows = []
    for k, b in sorted(cells.items()):
        t = tests.get(cell_id(k), tests.get("pooled", {}) if len(cells) == 1 else {})
        rows.append({"task": k[0], "robot": k[1], "env": k[2], "condition": k[3], "split": k[4], **_rates(b),
                     "baseline_only": 0, "candidate_only": 0, **_columns(t)})  # fmt: skip
    return rows


def split_rows(cells: Mapping[CellKey, Batches], look: Mapping[str, Any]) -> list[dict[str, object]]:
    """Per-split rows of the verdict."""
    tests = {t["id"]: t for t in look.get("tests", [])}
    splits = sorted({k[4] for k in cells})
    rows = []
    for s in splits:
        b = sum((v for k, v in cells.items() if k[4] == s), Batches())
        t = tests.get(f"split:{s}", tests.get("pooled", {}) if len(splits) == 1 else {})
        rows.append({"split": s, "cells": sum(k[4] == s for k in cells), **_rates(b), **_columns(t)})
    return rows


def rule(margin: float, alpha: float, cell_alpha: float, n_cells: int, metric: str) -> str:
    """The unpaired gate's decision rule in words, for the verdict document."""
    return (
        f"unpaired: regression if a one-sided test finds the drop (baseline - candidate) in {metric} above margin "
        f"{margin}: per cell ({n_cells} cells, {cell_alpha:g} of alpha) by Chan's exact unconditional test "
        "(Farrington-Manning score, p maximised over the boundary rate), per split and pooled over all cells by the "
        "stratified Farrington-Manning score with Mantel-Haenszel weights (normal; exact with one cell); weighted "
        f"Holm across the tests at alpha {alpha}, one look; no regression if the pooled non-inferiority test "
        f"(drop < margin, same statistic) has p below alpha {alpha}"
    )

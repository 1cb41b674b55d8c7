"""Statistics of the regression gate (`bench regress`): paired tests pooled, per split and per cell.

Pure functions over paired outcome counts: no records, files or simulators. `bench.board.gate.pairs`
pairs the episodes and `bench.cli.regress` calls `evaluate_look` after each batch; `bench.board.gate.power`
computes the budget a power target needs with the same thresholds; `benchmarks/bench_gate.py`
drives these functions on synthetic outcomes to measure the error rates.

drop = baseline success − candidate success. Every test asks "is the drop above `margin`?"
(H0: drop <= margin, one-sided):

    pooled    all pairs together              Tango's score test for paired binary outcomes
    iqm       IQM of the per-cell rates        smoothed Bayesian bootstrap of the pairs (one
                                               pseudo-pair lost and one won per cell, recentred:
                                               `scoring.paired_binary_stat_samples`); only with
                                               >= 4 cells and >= IQM_MIN_PAIRS pairs in every cell
    split:S   the pairs of split S's cells     Tango; only when both splits are in the run
    cell:C    the pairs of one cell            Tango; only with >= 2 cells

Error control (a false alarm = any true H0 rejected): alpha / L per look (Bonferroni over the
L looks of the schedule, so early stopping is paid for), and within a look a weighted Holm
procedure over the tests (a closed testing procedure: the gate's false-alarm rate is at most
alpha whatever the number of cells). Weights: `cell_alpha` (default 1/2) of the alpha goes to
the per-cell tests in equal shares, the rest to the aggregate tests (pooled 1/2, IQM 1/4,
splits 1/4; an absent one's share goes to the pooled test). A Tango test that cannot reach
its threshold with the pairs it has (all n pairs lost still gives p > threshold; Tarone's
rule, decided by the pair counts alone, never by outcomes) is left out of that look and its
weight shared among the others: with 5 pairs per cell the per-cell tests cannot fire, so the
pooled test gets their alpha at the first looks.

"no regression" is certified when the upper bounds of the pooled drop (and of the IQM drop
when it is used) are below `margin`, each at one-sided level 1 − alpha / (m · L) (m = the
number of those statistics); cells and splits cannot be certified on a CI budget (20 pairs
with no lost one still leave an upper bound near 0.2), so they only ever fail a gate.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

from bench.scoring import stats as scoring

IQM_MIN_PAIRS = 10  # pairs per cell before the IQM bootstrap bound may decide (fewer: the trimming is noise)
IQM_MIN_CELLS = 4  # with fewer cells the IQM trims nothing: it is the mean of the cell rates
CellKey = tuple[str, str, str, str, str]  # (task, robot, env, condition, split)
TIE = 1e-9  # IQM drops are differences of means of a few ratios: one exactly at the margin is not above it

if TYPE_CHECKING:
    from typing_extensions import NotRequired  # typing's own from Python 3.11


class GateTest(TypedDict):
    """One test at a look (`evaluate_look`): a drop (baseline - candidate), its p-value and Holm threshold;
    with bounds, the one-sided `level` of its bounds `lcb` / `ucb`."""

    id: str  # "pooled", "iqm", "split:NAME" or a cell id
    kind: str
    pairs: int
    drop: float
    p: float
    threshold: float
    tested: bool
    rejected: bool
    level: NotRequired[float]
    lcb: NotRequired[float]
    ucb: NotRequired[float]


class Look(TypedDict, total=False):
    """A look's tests and decision (`evaluate_look`), as the verdict document holds it."""

    pairs: int
    reason: str  # no paired episode yet
    baseline_only: int
    candidate_only: int
    alpha_spent: float
    tests: list[GateTest]
    regressed: list[str]
    mean: dict[str, object]
    iqm: dict[str, object]
    certify: dict[str, object]
    decision: str


@dataclass(frozen=True)
class Pairs:
    """Paired outcomes of a group of episodes as counts of (baseline, candidate) = (1,1), (1,0), (0,1), (0,0)."""

    n11: int = 0
    n10: int = 0
    n01: int = 0
    n00: int = 0

    @property
    def n(self) -> int:
        return self.n11 + self.n10 + self.n01 + self.n00

    @property
    def drop(self) -> float:
        return (self.n10 - self.n01) / self.n if self.n else 0.0

    def __add__(self, other: Pairs) -> Pairs:
        return Pairs(self.n11 + other.n11, self.n10 + other.n10, self.n01 + other.n01, self.n00 + other.n00)

    def as_row(self) -> list[int]:
        return [self.n11, self.n10, self.n01, self.n00]


def pairs_of(baseline: Sequence[float], candidate: Sequence[float]) -> Pairs:
    """Counts of paired 0/1 outcomes (position i of both sequences is one pair)."""
    b, c = np.asarray(baseline, dtype=bool), np.asarray(candidate, dtype=bool)
    return Pairs(int((b & c).sum()), int((b & ~c).sum()), int((~b & c).sum()), int((~b & ~c).sum()))


@dataclass(frozen=True)
class Design:
    """The gate's error budget and what it is spent on: margin, alpha and its share, looks, cells.

    Everything here is fixed before the first episode (the planned cells and schedule, never
    outcomes), which is what makes the alpha allocation valid.
    """

    margin: float = 0.05  # tolerated drop before a test calls it a regression
    alpha: float = 0.05  # false-alarm rate over all looks and tests
    cell_alpha: float = 0.5  # share of alpha spent on the per-cell tests (0 = aggregate tests only)
    schedule: tuple[int, ...] = (20,)  # planned episodes (pairs) per cell at each look
    cells: tuple[CellKey, ...] = ()  # the planned cells

    @property
    def looks(self) -> int:
        return len(self.schedule)

    @cached_property
    def thresholds(self) -> list[dict[str, float]]:
        """Per look, each test's p-value threshold (see `spend`)."""
        return spend(self)


def looks_schedule(episodes: int, batch: int) -> list[int]:
    """Episodes per cell at each look: batch, 2·batch, ..., episodes (one look when batch is 0)."""
    if batch <= 0 or batch >= episodes:
        return [episodes]
    return sorted({min(k * batch, episodes) for k in range(1, math.ceil(episodes / batch) + 1)})


def cell_id(key: CellKey) -> str:
    """`cell:Lift/Panda/default` (plus `/condition` when it is not nominal): a test's id in the verdict."""
    task, robot, env, condition = key[:4]
    return f"cell:{task}/{robot}/{env}" + ("" if condition == "nominal" else f"/{condition}")


def iqm_used(pairs_per_cell: Sequence[int]) -> bool:
    """Whether the IQM bootstrap may decide: enough cells to trim, enough pairs in each not to be fooled."""
    return len(pairs_per_cell) >= IQM_MIN_CELLS and min(pairs_per_cell) >= IQM_MIN_PAIRS


def base_weights(cells: Sequence[CellKey], use_iqm: bool, cell_alpha: float) -> dict[str, float]:
    """Each test's share of alpha before the infeasible ones are dropped (sums to 1)."""
    splits = sorted({k[4] for k in cells})
    cells_on = len(cells) >= 2 and cell_alpha > 0
    aggregate = 1.0 - cell_alpha if cells_on else 1.0
    w = {"pooled": aggregate * (0.5 + (0.0 if use_iqm else 0.25) + (0.0 if len(splits) >= 2 else 0.25))}
    if use_iqm:
        w["iqm"] = aggregate * 0.25
    if len(splits) >= 2:
        w.update({f"split:{s}": aggregate * 0.25 / len(splits) for s in splits})
    if cells_on:
        w.update({cell_id(k): cell_alpha / len(cells) for k in cells})
    return w


def min_p(n: int | np.ndarray, margin: float) -> np.ndarray:
    """The smallest p-value Tango's test can give with n pairs (every pair lost by the candidate)."""
    from scipy.stats import norm  # scipy: loaded only when this estimate is computed

    return norm.sf(scoring.paired_score_z(n, 0, n, margin))


def planned_pairs(design: Design, look: int) -> dict[str, int]:
    """Pairs behind each Tango test at look `look` (0-based) if every planned episode pairs."""
    n = design.schedule[look]
    out = {"pooled": n * len(design.cells)}
    for s in {k[4] for k in design.cells}:
        out[f"split:{s}"] = n * sum(k[4] == s for k in design.cells)
    out.update({cell_id(k): n for k in design.cells})
    return out


def spend(design: Design) -> list[dict[str, float]]:
    """Alpha spent on (test, look): per look, {test: threshold its p-value must go below}.

    Test h gets alpha · w_h in all (`base_weights`), spent over the looks at which it can reject
    in proportion to the episodes per cell each of them has seen (later looks, which see more,
    get more): a Tango test from the first look k0 where even n lost pairs out of n reach its
    threshold there (Tarone's rule: decided by pair counts, never by outcomes); the IQM at the
    looks where it is used. A test that can reject at no look gives its weight to the others.
    The thresholds sum to alpha over all tests and looks (Bonferroni over looks and tests;
    within a look `holm` then recycles the alpha of rejected tests).
    """
    L = design.looks
    usable_iqm = [iqm_used([design.schedule[k]] * len(design.cells)) for k in range(L)]
    weights = base_weights(list(design.cells), any(usable_iqm), design.cell_alpha)
    pairs = [planned_pairs(design, k) for k in range(L)]
    while True:
        looks_of: dict[str, list[int]] = {}
        for h, w in weights.items():
            if h == "iqm":
                looks_of[h] = [k for k in range(L) if usable_iqm[k]]
                continue
            first = next(
                (
                    k0
                    for k0 in range(L)
                    if pairs[k0][h] > 0
                    and float(min_p(pairs[k0][h], design.margin))
                    < design.alpha * w * design.schedule[k0] / sum(design.schedule[k0:])
                ),
                None,
            )
            looks_of[h] = [] if first is None else list(range(first, L))
        dead = [h for h in weights if not looks_of[h]]
        if not dead or len(dead) == len(weights):
            break
        total = sum(w for h, w in weights.items() if h not in dead)
        weights = {h: w / total for h, w in weights.items() if h not in dead}
    out: list[dict[str, float]] = [{} for _ in range(L)]
    for h, ks in looks_of.items():
        seen = np.array([design.schedule[k] for k in ks], dtype=float)
        for k, share in zip(ks, seen / seen.sum()):
            out[k][h] = design.alpha * weights[h] * float(share)
    return out


def holm(p: Mapping[str, float], t: Mapping[str, float]) -> dict[str, tuple[bool, float]]:
    """Weighted Holm over one look's tests: {test: (rejected, threshold its p-value was held to)}.

    `t` holds each test's Bonferroni threshold (its weight times the look's alpha, which is their
    sum). Tests in increasing p / t; each is rejected while p < t · (look's alpha) / (thresholds
    of the tests not yet rejected). A test past the first acceptance keeps the threshold it
    would have had there.
    """
    order = sorted((h for h in t if t[h] > 0), key=lambda h: (p[h] / t[h], h))
    a = remaining = sum(t[h] for h in order)
    out: dict[str, tuple[bool, float]] = {}
    stopped = False
    for h in order:
        thr = a * t[h] / remaining
        if not stopped and p[h] < thr:
            out[h] = (True, thr)
            remaining -= t[h]
        else:
            stopped = True
            out[h] = (False, thr)
    return out


def n_boot_needed(design: Design, given: int) -> int:
    """Bootstrap resamples for the IQM test: enough that ~50 fall below its smallest threshold."""
    smallest = min((t["iqm"] for t in design.thresholds if "iqm" in t), default=None)
    return int(given) if smallest is None else max(int(given), math.ceil(50 / smallest))


def evaluate_look(
    cells: Mapping[CellKey, Pairs],
    design: Design,
    look: int,
    rng: np.random.Generator,
    n_boot: int,
    bounds: bool = True,
) -> Look:
    """All tests at look `look` (0-based) and its decision: "regression", "no_regression" or "continue".

    Args:
        cells: paired counts per cell (cells without pairs are left out).
        design: the planned cells and schedule; its `thresholds[look]` say which tests are made.
        bounds: also compute every test's confidence bounds (reporting only: the decision uses
            p-values and a closed-form certification, so the simulations may skip them).

    Returns:
        A JSON-ready dict: pairs, discordant counts, `tests` (one per test: id, kind, pairs, drop, p,
        threshold, tested, rejected, and with bounds the one-sided `level` of lcb/ucb), `mean`
        and `iqm` summaries and `certify` (with bounds), `regressed` (ids of the rejected tests),
        `decision`.
    """
    from scipy.stats import norm  # scipy: loaded only when this estimate is computed

    cells = {k: v for k, v in cells.items() if v.n > 0}
    if not cells:
        return {"pairs": 0, "decision": "continue", "reason": "no paired episodes without errors"}
    keys = sorted(cells)
    pooled = sum((cells[k] for k in keys), Pairs())
    splits: dict[str, Pairs] = {}
    for k in keys:
        splits[k[4]] = splits.get(k[4], Pairs()) + cells[k]
    groups: dict[str, Pairs] = {"pooled": pooled}
    if len(splits) >= 2:
        groups.update({f"split:{s}": v for s, v in sorted(splits.items())})
    if len(keys) >= 2:
        groups.update({cell_id(k): cells[k] for k in keys})
    planned = design.thresholds[look]
    use_iqm = "iqm" in planned and iqm_used([cells[k].n for k in keys])
    t_look = {h: t for h, t in planned.items() if h in groups or (h == "iqm" and use_iqm)}

    ids = list(groups)
    counts = np.array([groups[h].as_row() for h in ids], dtype=float)
    z = scoring.paired_score_z(counts[:, 1], counts[:, 2], counts.sum(axis=1), design.margin)
    p = {h: float(v) for h, v in zip(ids, norm.sf(z))}
    samples: np.ndarray | None = None
    iqm_point = 0.0
    if use_iqm or bounds:
        iqm_point, samples = scoring.paired_binary_stat_samples(
            np.array([cells[k].as_row() for k in keys]), rng, "iqm", n_boot
        )
        p["iqm"] = float(np.mean(samples <= design.margin + TIE))
    decided = holm(p, t_look)
    regressed = [h for h, (rej, _) in decided.items() if rej]

    # certification ("no regression"): upper bounds of the pooled (and used IQM) drop below the margin
    a_cert = design.alpha / ((2 if use_iqm else 1) * design.looks)
    pooled_ok = float(norm.cdf(z[0])) < a_cert  # Tango UCB at 1 - a_cert below the margin, in closed form
    iqm_ucb = _quantile(samples, 1.0 - a_cert) if samples is not None else None
    certified = pooled_ok and (not use_iqm or (iqm_ucb is not None and iqm_ucb < design.margin - TIE))
    decision = "regression" if regressed else "no_regression" if certified else "continue"

    fallback = base_weights(list(design.cells) or keys, True, design.cell_alpha)  # bounds of untested tests
    tests: list[GateTest] = []
    for h in ids + (["iqm"] if samples is not None else []):
        tested = h in decided
        thr = decided[h][1] if tested else design.alpha * fallback.get(h, 0.0) / design.looks
        g = groups.get(h)
        t: GateTest = {
            "id": h,
            "kind": h.split(":")[0],
            "pairs": g.n if g else pooled.n,
            "drop": round(g.drop if g else iqm_point, 6),
            "p": float(f"{p[h]:.6g}"),
            "threshold": float(f"{thr:.6g}"),
            "tested": tested,
            "rejected": bool(tested and decided[h][0]),
        }
        if bounds and thr > 0:
            level = 1.0 - thr
            if g is not None:
                lcb = scoring.paired_score_bound(g.n10, g.n01, g.n, level, "lower")
                ucb = scoring.paired_score_bound(g.n10, g.n01, g.n, level, "upper")
            elif samples is not None:
                lcb, ucb = _quantile(samples, thr), _quantile(samples, level)
            t["level"], t["lcb"], t["ucb"] = round(level, 8), round(lcb, 6), round(ucb, 6)
        tests.append(t)
    out: Look = {
        "pairs": pooled.n,
        "baseline_only": pooled.n10,
        "candidate_only": pooled.n01,
        "alpha_spent": float(f"{sum(t_look.values()):.6g}"),
        "tests": tests,
        "regressed": regressed,
    }
    if bounds:
        by_id = {t["id"]: t for t in tests}
        pooled_ucb = scoring.paired_score_bound(pooled.n10, pooled.n01, pooled.n, 1.0 - a_cert, "upper")
        out["mean"] = {"value": round(pooled.drop, 6), "lcb": by_id["pooled"].get("lcb"), "ucb": round(pooled_ucb, 6)}
        out["iqm"] = {
            "value": round(iqm_point, 6),
            "lcb": by_id["iqm"].get("lcb"),
            "ucb": None if iqm_ucb is None else round(iqm_ucb, 6),
            "used": use_iqm,
        }
        out["certify"] = {"level": round(1.0 - a_cert, 8), "certified": bool(certified)}
    out["decision"] = decision
    return out


def _quantile(samples: np.ndarray, q: float) -> float:
    # inverted_cdf: the lower bound at level 1 - a exceeds the margin exactly when fewer than a·B samples are below it
    return float(np.quantile(samples, q, method="inverted_cdf"))


def decide(looks: Sequence[Mapping[str, object]], strict: bool) -> tuple[str, int]:
    """Final verdict and exit code from the looks taken so far (the last one decides)."""
    last = looks[-1]["decision"] if looks else "continue"
    if last == "regression":
        return "regression", 1
    if last == "no_regression":
        return "no_regression", 0
    return "inconclusive", 1 if strict else 0


def _rates(g: Pairs) -> dict[str, float]:
    """A verdict row's pair count, success rates and drop (`g` has pairs)."""
    return {
        "pairs": g.n,
        "baseline": round((g.n11 + g.n10) / g.n, 6),
        "candidate": round((g.n11 + g.n01) / g.n, 6),
        "drop": round(g.drop, 6),
    }


def _test_columns(t: Mapping[str, object]) -> dict[str, object]:
    """A verdict row's test at the look (p, level, bounds on the drop, tested, regressed); `t` may be {}."""
    return {
        "p": t.get("p"),
        "level": t.get("level"),
        "drop_lcb": t.get("lcb"),
        "drop_ucb": t.get("ucb"),
        "tested": bool(t.get("tested", False)),
        "regressed": bool(t.get("rejected", False)),
    }


def cell_rows(cells: Mapping[CellKey, Pairs], look: Mapping[str, Any]) -> list[dict[str, object]]:  # look: JSON
    """Per-cell table of the verdict: rates, drop, the cell's test at the look (p, bounds, regressed)."""
    tests = {t["id"]: t for t in look.get("tests", [])}
    rows = []
    for k, g in sorted(cells.items()):
        if g.n == 0:
            continue
        t = tests.get(cell_id(k), tests.get("pooled", {}) if len(cells) == 1 else {})
        rows.append(
            {
                "task": k[0],
                "robot": k[1],
                "env": k[2],
                "condition": k[3],
                "split": k[4],
                **_rates(g),
                "baseline_only": g.n10,
                "candidate_only": g.n01,
                **_test_columns(t),
            }
        )
    return rows


def split_rows(cells: Mapping[CellKey, Pairs], look: Mapping[str, Any]) -> list[dict[str, object]]:  # look: JSON
    """Per-split table of the verdict (pooled over each split's cells)."""
    tests = {t["id"]: t for t in look.get("tests", [])}
    splits: dict[str, Pairs] = {}
    for k, g in cells.items():
        splits[k[4]] = splits.get(k[4], Pairs()) + g
    rows = []
    for s, g in sorted(splits.items()):
        if g.n == 0:
            continue
        t = tests.get(f"split:{s}", tests.get("pooled", {}) if len(splits) == 1 else {})
        rows.append(
            {
                "split": s,
                "cells": sum(1 for k in cells if k[4] == s and cells[k].n),
                **_rates(g),
                **_test_columns(t),
            }
        )
    return rows


def rule(design: Design, metric: str) -> str:
    """The decision rule in words, for the verdict document."""
    return (
        f"regression if a one-sided paired test finds the drop (baseline - candidate) in {metric} above margin "
        f"{design.margin}: pooled over all pairs (Tango score test), in the IQM of the per-cell rates (smoothed "
        f"Bayesian bootstrap of the pairs, with >= {IQM_MIN_CELLS} cells of >= {IQM_MIN_PAIRS} pairs), per split, or per cell "
        f"({len(design.cells)} cells, {design.cell_alpha:g} of alpha); alpha {design.alpha} spent over "
        f"{design.looks} look(s) and the tests (Bonferroni), weighted Holm within a look; no regression if the "
        f"upper bounds of the pooled (and IQM) drop are below the margin"
    )


def regressed_entry(test: GateTest) -> dict[str, object]:
    """A rejected test as the verdict's `regressed` list names it: what, its drop, its bounds."""
    names = {"pooled": "all cells", "iqm": "IQM across cells"}
    return {
        "id": test["id"],
        "kind": test["kind"],
        "name": names.get(test["id"], test["id"].split(":", 1)[-1]),
        "pairs": test["pairs"],
        "drop": test["drop"],
        "lcb": test["lcb"],
        "ucb": test["ucb"],
        "level": test["level"],
        "p": test["p"],
    }

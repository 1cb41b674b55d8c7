"""Interactions of combined perturbations (`perturb.combine`): does a combination hurt more than its parts add up to?

For a combination C of single-axis conditions A, B, ... of the same run, over the (cell, episode seed) pairs
completed under nominal, under every part and under C (the same initial state in all of them):

    drop(C) = nominal - C        sum = (nominal - A) + (nominal - B) + ...        interaction = drop(C) - sum

each the mean of its per-seed values. drop(C) and each single drop carry the paired interval the sensitivity
table uses (`bench.scoring.stats.paired_gap`). The sum and the interaction, whose per-seed values are not 0/1,
carry the wider of two intervals: a paired bootstrap over episode seeds (resampled jointly across cells, one
resample for both), and Newcombe's MOVER combination of the drops' own intervals (Zou & Donner 2008), which
ignores the correlation between conditions but keeps a sample in which every seed agrees (12 of 12 lost together,
none alone) from collapsing to a zero-width bootstrap interval.

Reading: an interaction whose interval is above 0 means the axes together hurt more than the sum of their single
drops (they compound); below 0, less (one masks the other, or success hit its floor: a drop cannot exceed nominal
success, so once the single drops add up to more than that, the sum overshoots); across 0, the combination is
additive as far as these episodes tell. Entries are JSON-able with no NaN: what cannot be computed is null with a
reason.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Sequence

import numpy as np

from bench.protocols.suite import Condition
from bench.records import EpisodeRecord, dedupe
from bench.scoring import stats as scoring
from bench.sims.perturb.axes import AXES
from bench.sims.perturb.combine import SEP, most_severe, part_names

Done = dict[str, dict[str, dict[int, EpisodeRecord]]]  # condition -> cell key -> episode index -> completed record


Bounds = tuple[float, float, float]  # value, low, high


def _bounds(est: scoring.EstimateJSON) -> Bounds:
    ci = est["ci"]
    assert est["value"] is not None and ci is not None, "an estimate over at least one pair"
    return est["value"], ci[0], ci[1]


def _mover(terms: Sequence[tuple[float, Bounds]]) -> Bounds:
    """sum(sign x term) with the MOVER interval from the terms' own intervals, taken as independent."""
    value = sum(sign * v for sign, (v, _, _) in terms)
    below = math.sqrt(sum((v - lo if sign > 0 else hi - v) ** 2 for sign, (v, lo, hi) in terms))
    above = math.sqrt(sum((hi - v if sign > 0 else v - lo) ** 2 for sign, (v, lo, hi) in terms))
    return value, value - below, value + above


def _wider(values: np.ndarray, idx: np.ndarray, mover: Bounds, confidence: float) -> scoring.EstimateJSON:
    """The mean of per-seed `values` (cells, episodes) with the wider of the percentile interval of its resamples
    `idx` (the same resampled seeds in every cell) and the `mover` interval."""
    boot = values[:, idx].mean(axis=(0, 2))
    alpha = (1.0 - confidence) / 2.0
    lo, hi = np.quantile(boot, [alpha, 1.0 - alpha])
    return scoring.Estimate(float(values.mean()), min(float(lo), mover[1]), max(float(hi), mover[2])).to_dict()


def _aligned(done: Done, names: Sequence[str], attr: str) -> list[np.ndarray]:
    """One (cells, episodes) outcome array per condition in `names`, over the pairs completed under all of them;
    rectangular when every cell has the same episodes (seeds resampled jointly across cells), else one row."""
    cells = sorted(set.intersection(*(set(done.get(n, {})) for n in names)))
    per_cell = {c: sorted(set.intersection(*(set(done[n][c]) for n in names))) for c in cells}
    per_cell = {c: eps for c, eps in per_cell.items() if eps}
    if len({tuple(eps) for eps in per_cell.values()}) <= 1:
        rows = [[(c, e) for e in eps] for c, eps in per_cell.items()]
    else:
        rows = [[(c, e) for c, eps in per_cell.items() for e in eps]]
    if not rows:
        return [np.zeros((1, 0)) for _ in names]
    return [np.array([[float(getattr(done[n][c][e], attr)) for c, e in row] for row in rows]) for n in names]


def _all_at_once(parts: Sequence[str], first: dict[str, EpisodeRecord]) -> bool:
    """Whether every part is its axis' most severe level among the run's single-axis conditions."""
    for p in parts:
        rec = first.get(p)
        if rec is None or rec.axis is None:
            return False
        levels = [Condition(n, r.axis, r.level) for n, r in first.items() if r.axis == rec.axis]
        if most_severe(AXES.get(rec.axis), levels).name != p:
            return False
    return True


def reading(entry: dict[str, object]) -> str:
    """How to read an entry's interaction, in a few words (from its interval)."""
    inter = entry.get("interaction")
    ci = inter.get("ci") if isinstance(inter, dict) else None
    if not ci:
        return "no interaction computed"
    if ci[0] > 0:
        return "more than the sum of single drops"
    if ci[1] < 0:
        return "less than the sum of single drops"
    return "not distinguishable from the sum of single drops"


def interactions(
    records: Sequence[EpisodeRecord],
    rng: np.random.Generator,
    metric: str = "success_once",
    n_boot: int = 2000,
    confidence: float = 0.95,
) -> list[dict[str, object]]:
    """One entry per combined condition of a run (`perturb.combine`), pooled over its cells, in name order.

    Args:
        records: a run's episode records (nominal, the single-axis conditions and the combinations).
        rng: generator for the intervals (seeded from the run seed by the caller).
        metric: `success_once`, `success_at_end` or `return`.

    Returns:
        {condition, axes, parts, all_at_once, metric, n (pairs), drop, single_drops, sum_of_single_drops,
        interaction, reading}: drops are nominal - condition (positive = it hurts), estimates {value, ci} or a
        null value with a reason.
    """
    attr = "return_" if metric == "return" else metric
    done: Done = defaultdict(lambda: defaultdict(dict))
    first: dict[str, EpisodeRecord] = {}
    for r in dedupe(records):
        first.setdefault(r.condition, r)
        if r.error is None:
            done[r.condition][f"{r.task}/{r.robot}/{r.env}"][r.episode] = r
    singles = {n: r for n, r in first.items() if r.axis is not None and SEP not in n}
    out: list[dict[str, object]] = []
    for name in sorted(n for n in first if SEP in n):
        parts = part_names(name)
        entry: dict[str, object] = {
            "condition": name,
            "axes": str(first[name].axis).split(SEP),
            "parts": parts,
            "all_at_once": _all_at_once(parts, singles),
            "metric": metric,
        }
        missing = [p for p in ["nominal", *parts] if p not in first]
        arrays = _aligned(done, ["nominal", name, *parts], attr) if not missing else [np.zeros((1, 0))]
        n = int(arrays[0].size)
        if missing or n == 0:
            why = (
                f"no record of {', '.join(missing)} in this run"
                if missing
                else "no episode seed completed under nominal, every part and the combination"
            )
            null = {"value": None, "ci": None, "reason": why}
            out.append(
                {**entry, "n": 0, "drop": null, "single_drops": [], "sum_of_single_drops": null, "interaction": null}
            )
            out[-1]["reading"] = reading(out[-1])
            continue
        nom, comb, *each = arrays
        singles_sum = np.sum([nom - a for a in each], axis=0)  # (cells, episodes): the single drops per seed, added
        drop = scoring.paired_gap(nom, comb, rng, n_boot=n_boot, confidence=confidence).to_dict()
        single = [scoring.paired_gap(nom, a, rng, n_boot=n_boot, confidence=confidence).to_dict() for a in each]
        total = _mover([(1.0, _bounds(s)) for s in single])
        idx = rng.integers(0, nom.shape[1], size=(n_boot, nom.shape[1]))
        entry.update(
            {
                "n": n,
                "drop": drop,
                "single_drops": [{"condition": p, **s} for p, s in zip(parts, single)],
                "sum_of_single_drops": _wider(singles_sum, idx, total, confidence),
                "interaction": _wider(
                    (nom - comb) - singles_sum, idx, _mover([(1.0, _bounds(drop)), (-1.0, total)]), confidence
                ),
            }
        )
        entry["reading"] = reading(entry)
        out.append(entry)
    return out


def _est(est: object) -> str:
    if not isinstance(est, dict) or est.get("value") is None:
        return "n/a"
    ci = est.get("ci")
    return f"{est['value']:+.2f} [{ci[0]:+.2f}, {ci[1]:+.2f}]" if ci else f"{est['value']:+.2f}"


def sentence(entry: dict[str, object]) -> str:
    """One line for the console and the report: the combination's drop, the sum of its single drops and the
    interaction with their intervals, and how to read it."""
    parts = entry.get("parts")
    what = " with ".join(parts) if isinstance(parts, list) else str(entry["condition"])
    head = f"{what}{' (all at once)' if entry.get('all_at_once') else ''}"
    inter = entry.get("interaction")
    if not isinstance(inter, dict) or inter.get("value") is None:
        return f"{head}: no interaction ({inter.get('reason') if isinstance(inter, dict) else 'not computed'})"
    return (
        f"{head}: drop {_est(entry['drop'])}; sum of single drops {_est(entry['sum_of_single_drops'])}; "
        f"interaction {_est(inter)} ({entry['reading']}; {entry['metric']}, {entry['n']} pairs)"
    )

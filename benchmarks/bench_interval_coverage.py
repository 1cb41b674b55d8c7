"""Coverage of every interval the harness prints, by simulation with known truth (issue 38, item 0).

    python benchmarks/bench_interval_coverage.py              # 2000 simulated runs per row (~2 min on 2 cores)
    python benchmarks/bench_interval_coverage.py --reps 500   # quicker, noisier

Each row draws `reps` synthetic runs of 0/1 outcomes (or returns) from known per-cell rates, computes the
interval with the very function the harness calls (`bench.scoring.stats`, `bench.board.gate`'s bounds), and
counts how often it contains the truth. Scenarios cross rates near 0, 0.5 and 1 (all cells alike, or spread
across cells), few and many cells, few and more episodes per cell. Printed per row: the nominal level, the
coverage with its Monte-Carlo standard error, and for the aggregates, gaps and drops the coverage of the method
they replaced (a bootstrap of per-cell Jeffreys draws widened to contain the estimate, a percentile paired
bootstrap, a percentile bootstrap of returns; kept here only as the "before" column). `tests/test_interval_coverage.py` holds a smaller table.

The truth is a property of the fixed cells (the benchmark's cells are not a sample of robots): the mean (IQM) of
their true rates, or its difference between two groups / two conditions.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bench.records import EpisodeRecord
from bench.scoring import stats
from bench.scoring.interactions import interactions

CONF = 0.95
NOMINAL_GATE = 0.95  # the one-sided level of the gate bounds checked here


@dataclass(frozen=True)
class Scenario:
    """Known truth: `cells` cells of `episodes` episodes; rates around `rate` (`spread` 0: all equal)."""

    rate: float
    cells: int
    episodes: int
    spread: float = 0.0
    drop: float = 0.0  # the target's rates are the reference's minus this (gaps and paired drops)

    def label(self) -> str:
        spread = f" spread {self.spread:g}" if self.spread else ""
        drop = f" drop {self.drop:g}" if self.drop else ""
        return f"p={self.rate:g} {self.cells}x{self.episodes}{spread}{drop}"

    def rates(self, rng: np.random.Generator) -> np.ndarray:
        width = self.spread * min(self.rate, 1.0 - self.rate)
        return np.clip(self.rate + rng.uniform(-1.0, 1.0, self.cells) * width, 0.0, 1.0)


SCENARIOS = tuple(
    Scenario(rate, cells, episodes, spread)
    for rate in (0.02, 0.5, 0.98)
    for cells, episodes in ((2, 10), (12, 5), (12, 20))
    for spread in (0.0, 1.0)
)
DROPS = tuple(
    Scenario(rate, cells, episodes, 0.0, drop)
    for rate, drop in ((0.98, 0.0), (0.98, 0.3), (0.5, 0.0), (0.5, 0.2), (0.1, 0.05))
    for cells, episodes in ((2, 10), (12, 10))
)


def _cells(rates: np.ndarray, n: int, rng: np.random.Generator) -> list[np.ndarray]:
    return [rng.binomial(1, p, n).astype(float) for p in rates]


def _pairs(ref: np.ndarray, tgt: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(cells, n) paired outcomes: the two conditions share the episode's uniform draw half of the time."""
    u = rng.uniform(size=(len(ref), n))
    v = np.where(rng.uniform(size=(len(ref), n)) < 0.5, u, rng.uniform(size=(len(ref), n)))
    return (u < ref[:, None]).astype(float), (v < tgt[:, None]).astype(float)


# -- the replaced methods ("before" column) ------------------------------------------------------
def _before_aggregate(cells: list[np.ndarray], rng: np.random.Generator, statistic: str) -> tuple[float, float]:
    stat = stats.STATISTICS[statistic]
    draws = np.column_stack([rng.beta(c.sum() + 0.5, len(c) - c.sum() + 0.5, 1000) for c in cells])
    point = float(stat(np.array([c.mean() for c in cells])))
    lo, hi = np.quantile(stat(draws), [0.025, 0.975])
    return min(lo, point), max(hi, point)


def _before_gap(ref: list[np.ndarray], tgt: list[np.ndarray], rng: np.random.Generator) -> tuple[float, float]:
    draw = lambda cs: np.column_stack([rng.beta(c.sum() + 0.5, len(c) - c.sum() + 0.5, 1000) for c in cs])  # noqa: E731
    point = float(np.mean([c.mean() for c in ref]) - np.mean([c.mean() for c in tgt]))
    lo, hi = np.quantile(draw(ref).mean(axis=1) - draw(tgt).mean(axis=1), [0.025, 0.975])
    return min(lo, point), max(hi, point)


def _before_paired(ref: np.ndarray, tgt: np.ndarray, rng: np.random.Generator) -> tuple[float, float]:
    diff = ref - tgt
    idx = rng.integers(0, diff.shape[1], size=(1000, diff.shape[1]))
    lo, hi = np.quantile(diff[:, idx].mean(axis=(0, 2)), [0.025, 0.975])
    return float(lo), float(hi)


# -- one row: how often an interval contains the truth ----------------------------------------------
Check = Callable[[Scenario, np.random.Generator], tuple[bool, bool | None]]


def per_cell(sc: Scenario, rng: np.random.Generator) -> tuple[bool, bool | None]:
    p = sc.rates(rng)[:1]
    est = stats.wilson(int(rng.binomial(sc.episodes, p[0])), sc.episodes, CONF)
    return bool(est.lo <= p[0] <= est.hi), None


def aggregate(statistic: str) -> Check:
    def check(sc: Scenario, rng: np.random.Generator) -> tuple[bool, bool | None]:
        rates = sc.rates(rng)
        truth = float(stats.STATISTICS[statistic](rates))
        cells = _cells(rates, sc.episodes, rng)
        est = stats.aggregate(cells, rng, stats.Boot(statistic, 1000, CONF))
        lo, hi = _before_aggregate(cells, rng, statistic)
        return bool(est.lo <= truth <= est.hi), bool(lo <= truth <= hi)

    return check


def gap(sc: Scenario, rng: np.random.Generator) -> tuple[bool, bool | None]:
    ref = sc.rates(rng)
    tgt = np.clip(ref - sc.drop, 0.0, 1.0)
    truth = float(ref.mean() - tgt.mean())
    a, b = _cells(ref, sc.episodes, rng), _cells(tgt, sc.episodes, rng)
    est = stats.gap(a, b, rng, stats.Boot("mean", 1000, CONF))
    lo, hi = _before_gap(a, b, rng)
    return bool(est.lo <= truth <= est.hi), bool(lo <= truth <= hi)


def paired_drop(sc: Scenario, rng: np.random.Generator) -> tuple[bool, bool | None]:
    ref = sc.rates(rng)
    tgt = np.clip(ref - sc.drop, 0.0, 1.0)
    truth = float(ref.mean() - tgt.mean())
    a, b = _pairs(ref, tgt, sc.episodes, rng)
    est = stats.paired_gap(a, b, rng, 1000, CONF)
    lo, hi = _before_paired(a, b, rng)
    return bool(est.lo <= truth <= est.hi), bool(lo <= truth <= hi)


def gate_pooled_upper(sc: Scenario, rng: np.random.Generator) -> tuple[bool, bool | None]:
    """The gate's certification bound: Tango's one-sided upper bound on the pooled drop."""
    ref = sc.rates(rng)
    tgt = np.clip(ref - sc.drop, 0.0, 1.0)
    a, b = _pairs(ref, tgt, sc.episodes, rng)
    d = a - b
    ucb = stats.paired_score_bound(int((d > 0).sum()), int((d < 0).sum()), d.size, NOMINAL_GATE, "upper")
    return bool(float(ref.mean() - tgt.mean()) <= ucb), None


def gate_iqm_upper(sc: Scenario, rng: np.random.Generator) -> tuple[bool, bool | None]:
    """The gate's IQM bound: the paired bootstrap's upper quantile (used with >= 4 cells of >= 10 pairs)."""
    ref = sc.rates(rng)
    tgt = np.clip(ref - sc.drop, 0.0, 1.0)
    a, b = _pairs(ref, tgt, sc.episodes, rng)
    counts = np.column_stack([(a * b).sum(1), (a * (1 - b)).sum(1), ((1 - a) * b).sum(1), ((1 - a) * (1 - b)).sum(1)])
    _, samples = stats.paired_binary_stat_samples(counts, rng, "iqm", 1000)
    truth = float(stats.iqm(ref) - stats.iqm(tgt))
    return bool(truth <= float(np.quantile(samples, NOMINAL_GATE))), None


def _record(condition: str, axis: str | None, level: object, robot: str, episode: int, ok: bool) -> EpisodeRecord:
    return EpisodeRecord(
        **{
            **dict(run_id="r", suite="s", suite_version="1", task="T", env="e", split="seen", params={}),
            **dict(init_state_hash="h", return_=0.0, length=1, steps_to_success=None, error=None, policy="p"),
            **dict(checkpoint_sha256=None, backend="b", wall_s=0.0, finished_at=0.0, worker_pid=0),
            "condition": condition,
            "axis": axis,
            "level": level,
            "robot": robot,
            "episode": episode,
            "seed": episode,
            "success_once": ok,
            "success_at_end": ok,
            "job_id": f"T/{robot}/e|{condition}|{episode}",
        }
    )


def interaction(sc: Scenario, rng: np.random.Generator) -> tuple[bool, bool | None]:
    """`perturb.combine`'s interaction (bench.scoring.interactions): nominal at `rate`, each of two axes alone
    losing `drop`, both together losing 3 x `drop` (an interaction of + `drop`), on shared per-seed draws."""
    rates = {"nominal": sc.rate, "a=2": sc.rate - sc.drop, "b=2": sc.rate - sc.drop, "a=2&b=2": sc.rate - 3 * sc.drop}
    meta = {"nominal": (None, None), "a=2": ("a", 2.0), "b=2": ("b", 2.0), "a=2&b=2": ("a&b", {"a": 2.0, "b": 2.0})}
    records = []
    for c in range(sc.cells):
        u = rng.uniform(size=sc.episodes)  # the episode's initial state, shared by every condition
        for name, p in rates.items():
            v = np.where(rng.uniform(size=sc.episodes) < 0.5, u, rng.uniform(size=sc.episodes))
            for e in range(sc.episodes):
                records.append(_record(name, meta[name][0], meta[name][1], f"R{c}", e, bool(v[e] < p)))
    (entry,) = interactions(records, rng, n_boot=1000)
    lo, hi = entry["interaction"]["ci"]
    truth = (rates["nominal"] - rates["a=2&b=2"]) - 2 * (rates["nominal"] - rates["a=2"])
    return bool(lo <= truth <= hi), None


def returns_mean(sc: Scenario, rng: np.random.Generator) -> tuple[bool, bool | None]:
    """Mean return of cells (stratified bootstrap): skewed returns, lognormal around a cell's level."""
    levels = 1.0 + sc.rates(rng) * 10.0
    cells = [lv * rng.lognormal(0.0, 0.75, sc.episodes) for lv in levels]
    truth = float(np.mean(levels) * np.exp(0.75**2 / 2))
    est = stats.aggregate(cells, rng, stats.Boot("mean", 1000, CONF, binary=False))
    boot = np.column_stack([c[rng.integers(0, len(c), (1000, len(c)))].mean(axis=1) for c in cells]).mean(axis=1)
    lo, hi = np.quantile(boot, [0.025, 0.975])  # before: the percentile bootstrap of episodes within cells
    return bool(est.lo <= truth <= est.hi), bool(lo <= truth <= hi)


def coverage(check: Check, sc: Scenario, reps: int, seed: int) -> tuple[float, float | None]:
    """Share of `reps` simulated runs whose interval contains the truth (and the "before" method's share)."""
    rng = np.random.default_rng([seed, sc.cells, sc.episodes, int(sc.rate * 1000), int(sc.drop * 1000)])
    now, before = 0, 0
    has_before = False
    for _ in range(reps):
        hit, old = check(sc, rng)
        now += hit
        if old is not None:
            has_before = True
            before += old
    return now / reps, (before / reps if has_before else None)


ROWS: tuple[tuple[str, Check, tuple[Scenario, ...], float], ...] = (
    ("per-cell rate (Wilson)", per_cell, tuple(s for s in SCENARIOS if not s.spread), CONF),
    ("mean of cell rates (stratified Wilson)", aggregate("mean"), SCENARIOS, CONF),
    ("IQM of cell rates (Wilson over kept cells)", aggregate("iqm"), SCENARIOS, CONF),
    ("seen - unseen gap (MOVER)", gap, DROPS, CONF),
    ("paired drop vs nominal (Tango)", paired_drop, DROPS, CONF),
    ("gate: pooled drop upper bound (Tango, one-sided)", gate_pooled_upper, DROPS, NOMINAL_GATE),
    (
        "gate: IQM drop upper bound (paired bootstrap)",
        gate_iqm_upper,
        tuple(s for s in DROPS if s.cells >= 4),
        NOMINAL_GATE,
    ),
    (
        "combined axes: interaction (wider of paired bootstrap and MOVER)",
        interaction,
        (Scenario(0.9, 2, 10, 0.0, 0.1), Scenario(0.9, 12, 10, 0.0, 0.1), Scenario(0.5, 4, 10, 0.0, 0.05)),
        CONF,
    ),
    ("mean return of cells (stratified t)", returns_mean, tuple(s for s in SCENARIOS if s.rate == 0.5), CONF),
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=2000, help="simulated runs per row (default 2000)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    worst: dict[str, float] = {}
    for name, check, scenarios, nominal in ROWS:
        print(f"\n{name}  (nominal {nominal:.0%}, {args.reps} runs per row)")
        print(f"  {'scenario':<34} {'coverage':>9} {'± MC se':>8} {'before':>7}")
        for sc in scenarios:
            cov, before = coverage(check, sc, args.reps, args.seed)
            se = (cov * (1 - cov) / args.reps) ** 0.5
            old = f"{before:7.3f}" if before is not None else "      –"
            print(f"  {sc.label():<34} {cov:9.3f} {se:8.3f} {old}")
            worst[name] = min(worst.get(name, 1.0), cov)
    print("\nlowest coverage per interval:")
    for name, low in worst.items():
        print(f"  {name:<50} {low:.3f}")
    print(f"\n{time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

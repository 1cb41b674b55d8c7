"""Coverage of every interval the harness prints, by simulation with known truth (issue 38, item 0).

    python benchmarks/bench_interval_coverage.py              # 2000 simulated runs per row
    python benchmarks/bench_interval_coverage.py --reps 500   # quicker, noisier
    python benchmarks/bench_interval_coverage.py --only "gate: IQM"   # one interval's rows

Each row draws `reps` synthetic runs of 0/1 outcomes (or returns) from known per-cell rates, computes the
interval with the very function the harness calls (`bench.scoring.stats`, `bench.board.gate`'s bounds), and
counts how often it contains the truth. Scenarios cross rates near 0, 0.5 and 1 (all cells alike, or spread
across cells), few and many cells, few and more episodes per cell. Printed per row: the nominal level, the
coverage with its Monte-Carlo standard error, and for the aggregates, gaps and drops the coverage of the method
they replaced (a bootstrap of per-cell Jeffreys draws widened to contain the estimate, a percentile paired
bootstrap, the gate's plain bootstrap of pairs, the stratified t of returns without skewness correction; kept
here only as the "before" column). `tests/test_interval_coverage.py` holds a smaller table.

The truth is a property of the fixed cells (the benchmark's cells are not a sample of robots): the mean (IQM) of
their true rates, or its difference between two groups / two conditions.
"""

from __future__ import annotations

import argparse
import dataclasses
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


RETURNS = tuple(
    Scenario(0.5, cells, episodes, spread)
    for cells, episodes in ((1, 20), (2, 10), (2, 20), (12, 5), (12, 20))
    for spread in (0.0, 1.0)
    if cells > 1 or not spread
)
GATE_IQM = tuple(  # the IQM is used with >= 4 cells of >= 10 pairs
    Scenario(rate, cells, episodes, spread, drop)
    for rate, drop, spread in (
        (0.02, 0.0, 0.0),
        (0.05, 0.05, 0.0),
        (0.1, 0.05, 0.0),
        (0.5, 0.0, 0.0),
        (0.5, 0.2, 1.0),
        (0.9, 0.1, 1.0),
        (0.98, 0.0, 0.0),
        (0.98, 0.3, 0.0),
    )
    for cells, episodes in ((4, 10), (12, 10), (12, 20))
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


def _before_iqm_samples(counts: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The replaced gate IQM bootstrap: pairs resampled within each cell, i.e. multinomial counts of the 4 pair
    types, drawn as a chain of binomials (vectorised over cells)."""
    n = counts.sum(axis=1)
    left, mass, drawn = np.broadcast_to(n, (1000, len(n))).copy(), np.ones(len(n)), []
    for j in range(3):
        share = np.divide(counts[:, j] / n, mass, out=np.zeros(len(n)), where=mass > 1e-12).clip(0.0, 1.0)
        drawn.append(rng.binomial(left, share))
        left -= drawn[-1]
        mass = mass - counts[:, j] / n
    return stats.iqm((drawn[0] + drawn[1]) / n) - stats.iqm((drawn[0] + drawn[2]) / n)


def gate_iqm(side: str) -> Check:
    """The gate's IQM bounds (`stats.paired_binary_stat_samples`, used with >= 4 cells of >= 10 pairs): the upper
    one certifies "no regression", the lower one is the regression test's."""

    def check(sc: Scenario, rng: np.random.Generator) -> tuple[bool, bool | None]:
        ref = sc.rates(rng)
        tgt = np.clip(ref - sc.drop, 0.0, 1.0)
        a, b = _pairs(ref, tgt, sc.episodes, rng)
        counts = np.column_stack(
            [(a * b).sum(1), (a * (1 - b)).sum(1), ((1 - a) * b).sum(1), ((1 - a) * (1 - b)).sum(1)]
        ).astype(int)
        _, samples = stats.paired_binary_stat_samples(counts, rng, "iqm", 1000)
        before = _before_iqm_samples(counts, rng)
        truth = float(stats.iqm(ref) - stats.iqm(tgt))
        if side == "upper":
            return bool(truth <= np.quantile(samples, NOMINAL_GATE)), bool(truth <= np.quantile(before, NOMINAL_GATE))
        q = 1.0 - NOMINAL_GATE
        return bool(truth >= np.quantile(samples, q)), bool(truth >= np.quantile(before, q))

    return check


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


def _before_returns(cells: list[np.ndarray], minus: list[np.ndarray] | None = None) -> tuple[float, float]:
    """The replaced returns interval: the stratified Welch t (of the mean of `cells`, or of its difference with
    the mean of `minus`), no skewness correction."""
    from scipy.special import stdtrit  # scipy: only this "before" column needs it

    groups = [cells] if minus is None else [cells, minus]
    shares = np.concatenate([[c.var(ddof=1) / len(c) / len(g) ** 2 for c in g] for g in groups])
    dof = np.concatenate([[len(c) - 1.0 for c in g] for g in groups])
    var = float(shares.sum())
    df = var**2 / float(np.sum(shares**2 / dof))
    point = float(np.mean([c.mean() for c in cells]) - (0.0 if minus is None else np.mean([c.mean() for c in minus])))
    half = float(stdtrit(df, 0.5 + CONF / 2)) * var**0.5
    return point - half, point + half


def returns_mean(sc: Scenario, rng: np.random.Generator) -> tuple[bool, bool | None]:
    """Mean return of cells: skewed returns, lognormal (sigma 0.75: skewness 2.9) around a cell's level."""
    levels = 1.0 + sc.rates(rng) * 10.0
    cells = [lv * rng.lognormal(0.0, 0.75, sc.episodes) for lv in levels]
    truth = float(np.mean(levels) * np.exp(0.75**2 / 2))
    est = stats.aggregate(cells, rng, stats.Boot("mean", 1000, CONF, binary=False))
    lo, hi = _before_returns(cells)
    return bool(est.lo <= truth <= est.hi), bool(lo <= truth <= hi)


def returns_gap(sc: Scenario, rng: np.random.Generator) -> tuple[bool, bool | None]:
    """Seen - unseen gap of mean returns: two groups of `cells` lognormal cells, the second's levels lower by
    10 x `drop`."""
    levels = 1.0 + sc.rates(rng) * 10.0
    shift = np.exp(0.75**2 / 2)
    ref = [lv * rng.lognormal(0.0, 0.75, sc.episodes) for lv in levels]
    tgt = [(lv - 10.0 * sc.drop) * rng.lognormal(0.0, 0.75, sc.episodes) for lv in levels]
    est = stats.gap(ref, tgt, rng, stats.Boot("mean", 1000, CONF, binary=False))
    truth = 10.0 * sc.drop * shift
    r, t = stats._cell_moments(ref, "mean"), stats._cell_moments(tgt, "mean")
    assert r is not None and t is not None
    skewed = stats._hall_t(dataclasses.replace(r.minus(t), kappa3=r.kappa3 - t.kappa3), CONF)
    return bool(est.lo <= truth <= est.hi), bool(skewed.lo <= truth <= skewed.hi)


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
    ("gate: IQM drop upper bound (smoothed Bayesian bootstrap)", gate_iqm("upper"), GATE_IQM, NOMINAL_GATE),
    ("gate: IQM drop lower bound (smoothed Bayesian bootstrap)", gate_iqm("lower"), GATE_IQM, NOMINAL_GATE),
    (
        "combined axes: interaction (wider of paired bootstrap and MOVER)",
        interaction,
        (Scenario(0.9, 2, 10, 0.0, 0.1), Scenario(0.9, 12, 10, 0.0, 0.1), Scenario(0.5, 4, 10, 0.0, 0.05)),
        CONF,
    ),
    ("mean return of cells (stratified t, Hall's skewness correction)", returns_mean, RETURNS, CONF),
    (
        "seen - unseen gap of mean returns (stratified t; before: with Hall's correction)",
        returns_gap,
        tuple(Scenario(0.5, s.cells, s.episodes, s.spread, 0.3) for s in RETURNS if s.cells > 1),
        CONF,
    ),
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=2000, help="simulated runs per row (default 2000)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", default="", help="only the intervals whose name contains this text (e.g. 'gate: IQM')")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    worst: dict[str, float] = {}
    for name, check, scenarios, nominal in ROWS:
        if args.only not in name:
            continue
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

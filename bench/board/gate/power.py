"""Budget advice for the regression gate (`bench regress plan=true`): episodes per cell for a stated power.

Method (exact, no simulation): the gate's Tango test on n paired binary outcomes depends only
on the counts (b, c) of pairs the candidate lost and won. Under a scenario, each new pair is
lost with probability p10 = r·(1 − r') and won with p01 = (1 − r)·r' (baseline success r,
candidate r' = r − drop; the two outcomes of a pair taken as independent, which is the
conservative case: a shared initial state only adds agreement). The distribution of (b, c) is
carried from look to look by convolving with the trinomial law of the next batch; at each
look the region where the test rejects (p < its threshold, the very thresholds
`bench.board.gate.sequential` uses: alpha / L per look, the test's Holm weight after Tarone's rule) is
added to the power and removed (the gate stops there).

Two scenarios:
    one cell    one cell falls from r to r − drop, the others stay: power of that cell's
                own test (the chance the verdict names the cell);
    every cell  every cell falls by `drop`: power of the pooled test.
Both are lower bounds on the gate's chance to fail: the other tests (splits, IQM, pooled)
and Holm's later steps can only add rejections. They ignore the early "no regression"
stop, which needs the pooled drop certified below the margin and so is rare when a
collapse moves the pooled drop by drop / cells >= margin; benchmarks/bench_gate.py checks
the calculation against simulated gates.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bench.board.gate import sequential
from bench.scoring import stats as scoring

MAX_EPISODES = 2000  # per cell: the search gives up beyond (a CI budget this large is not a plan)


def _kernel(d: int, p10: float, p01: float) -> np.ndarray:
    """(d+1, d+1) law of (lost, won) pairs among d new pairs: lost+won ~ Bin(d, p10+p01), lost | both ~ Bin."""
    from scipy.stats import binom  # scipy: loaded only when this estimate is computed

    k = np.zeros((d + 1, d + 1))
    pd = p10 + p01
    s = np.arange(d + 1)
    ps = binom.pmf(s, d, pd)
    theta = p10 / pd if pd > 0 else 0.0
    for si in s:
        i = np.arange(si + 1)
        k[i, si - i] = ps[si] * binom.pmf(i, si, theta)
    return k


def sequential_power(pairs: Sequence[int], thresholds: Sequence[float], p10: float, p01: float, margin: float) -> float:
    """P(a Tango test of "drop > margin" rejects at some look), look k seeing pairs[k] pairs.

    Args:
        pairs: cumulative pairs at each look (increasing).
        thresholds: the p-value threshold at each look (0: the test is not made at that look).
        p10, p01: per-pair probabilities that only the baseline / only the candidate succeeds.
    """
    from scipy.signal import fftconvolve  # scipy: loaded only when this estimate is computed
    from scipy.stats import norm  # scipy: loaded only when this estimate is computed

    dist = np.ones((1, 1))
    b0 = c0 = 0  # dist[i, j] is the probability of (b0 + i lost, c0 + j won) pairs still running
    prev, power = 0, 0.0
    for n, thr in zip(pairs, thresholds):
        if n > prev:
            dist = fftconvolve(dist, _kernel(n - prev, p10, p01))
            dist[dist < 1e-300] = 0.0  # FFT round-off
            dist, b0, c0 = _crop(dist, b0, c0)
        prev = n
        if thr <= 0:
            continue
        b = b0 + np.arange(dist.shape[0])[:, None]
        c = c0 + np.arange(dist.shape[1])[None, :]
        reject = (b + c <= n) & (norm.sf(scoring.paired_score_z(b, c, n, margin)) < thr)
        power += float(dist[reject].sum())
        dist = np.where(reject, 0.0, dist)
    return min(power, 1.0)


def _crop(dist: np.ndarray, b0: int, c0: int, eps: float = 1e-15) -> tuple[np.ndarray, int, int]:
    """Drop edge rows/columns holding less than `eps` of probability (keeps the grid near the mass)."""
    rows, cols = dist.sum(axis=1), dist.sum(axis=0)
    r = np.flatnonzero(np.cumsum(rows) > eps / 2)
    rr = np.flatnonzero(np.cumsum(rows[::-1]) > eps / 2)
    k = np.flatnonzero(np.cumsum(cols) > eps / 2)
    kk = np.flatnonzero(np.cumsum(cols[::-1]) > eps / 2)
    if not len(r) or not len(k):
        return dist, b0, c0
    r0, r1 = r[0], dist.shape[0] - rr[0]
    k0, k1 = k[0], dist.shape[1] - kk[0]
    return dist[r0:r1, k0:k1], b0 + int(r0), c0 + int(k0)


def _cells(n_cells: int, splits: Sequence[str] | None) -> list[sequential.CellKey]:
    splits = list(splits) if splits else ["seen"] * n_cells
    return [("task", f"cell{i}", "env", "nominal", splits[i]) for i in range(n_cells)]


def scenario_power(scenario: str, episodes: int, b: Budget, splits: Sequence[str] | None = None) -> float:
    """Power of the gate's test for `scenario` ("cell" or "all") with up to `episodes` per cell in looks of `b.batch`
    (the budget's own `episodes` and `power` are not used)."""
    schedule = sequential.looks_schedule(episodes, b.batch)
    keys = _cells(b.n_cells, splits)
    d = sequential.Design(b.design.margin, b.design.alpha, b.design.cell_alpha, tuple(schedule), tuple(keys))
    # the collapsed cell is the first; with one cell its test is the pooled one
    target = sequential.cell_id(keys[0]) if scenario == "cell" and b.n_cells >= 2 else "pooled"
    thresholds = [t.get(target, 0.0) for t in d.thresholds]
    pairs = [n if target != "pooled" else n * b.n_cells for n in schedule]
    r2 = b.rate - b.drop
    return sequential_power(pairs, thresholds, b.rate * (1 - r2), (1 - b.rate) * r2, b.design.margin)


def episodes_needed(scenario: str, b: Budget, splits: Sequence[str] | None = None) -> tuple[int | None, float]:
    """Smallest budget (episodes per cell; a multiple of `b.batch` when it is > 0) reaching `b.power`, and its power.

    Doubling then bisection over the number of looks (power grows with the budget up to the
    discreteness of the test); None when even MAX_EPISODES per cell fall short.
    """
    step = b.batch if b.batch > 0 else 1

    def pw(k: int) -> float:
        return scenario_power(scenario, k * step, b, splits)

    lo, hi = 0, 1
    while pw(hi) < b.power:
        lo, hi = hi, hi * 2
        if hi * step > MAX_EPISODES:
            hi = MAX_EPISODES // step
            if pw(hi) < b.power:
                return None, pw(hi)
            break
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if pw(mid) >= b.power:
            hi = mid
        else:
            lo = mid
    return hi * step, pw(hi)


@dataclass(frozen=True)
class Budget:
    """What `bench regress plan=true` is asked: the power wanted against a drop from a success rate."""

    power: float  # target power
    rate: float  # the baseline's success rate per cell
    drop: float  # the drop in that rate the gate should catch
    n_cells: int  # cells (x conditions) compared; 0 = count those the forwarded bench run keys select
    batch: int  # episodes per cell between looks; 0 = one look at the end
    design: sequential.Design  # margin, alpha and its per-cell share
    episodes: int  # the budget the user has in mind (power is also printed at this many episodes per cell)


def plan_text(b: Budget, splits: Sequence[str] | None = None, cells_from: str = "") -> str:
    """The report `bench regress plan=true` prints."""
    split_note = ""
    if splits and len(set(splits)) > 1:
        split_note = " (" + ", ".join(f"{s}: {list(splits).count(s)}" for s in sorted(set(splits))) + ")"
    looks = f"looks every {b.batch} episodes per cell" if b.batch > 0 else "one look at the end"
    lines = [
        f"budget plan: {b.n_cells} cells{split_note}{cells_from}; margin {b.design.margin}, alpha {b.design.alpha} "
        f"({b.design.cell_alpha:g} of it to the per-cell tests, Holm); {looks}; target power {b.power:g}",
        "method: exact law of the lost/won pair counts carried over the looks, each test at the gate's own "
        "thresholds; outcomes of a pair independent (conservative); lower bounds (other tests only add power)",
        "",
        f"  {'scenario':<34} {'episodes/cell':>13} {'looks':>5} {'power':>6}   power at episodes={b.episodes}",
    ]
    for scenario, label in (
        ("cell", f"one cell {b.rate:.2f} -> {b.rate - b.drop:.2f}"),
        ("all", f"every cell {b.rate:.2f} -> {b.rate - b.drop:.2f}"),
    ):
        if scenario == "cell" and b.n_cells < 2:
            label += " (1 cell: pooled test)"
        need, got = episodes_needed(scenario, b, splits)
        at = scenario_power(scenario, b.episodes, b, splits)
        if need is None:
            lines.append(f"  {label:<34} {'> ' + str(MAX_EPISODES):>13} {'':>5} {got:>6.3f}   {at:.3f}")
        else:
            lines.append(
                f"  {label:<34} {need:>13} {len(sequential.looks_schedule(need, b.batch)):>5} {got:>6.3f}   {at:.3f}"
            )
    lines.append("")
    lines.append(
        f"run: bench regress candidate=... baseline=... episodes=N batch={b.batch} margin={b.design.margin} "
        f"alpha={b.design.alpha}"
    )
    return "\n".join(lines) + "\n"

"""`bench predict` by simulation with known truth, and on SIMPLER's published per-policy real/sim tables.

    python benchmarks/bench_predict.py              # 2000 simulated evaluations per row (~2 min on 2 cores)
    python benchmarks/bench_predict.py --reps 300   # quicker, noisier

Part 1 (episodes paired by seed). Each row draws `reps` evaluations: n real trials, each paired with the sim
episode of the same initial state, whose outcomes (Y, S) are Bernoulli(p_real), Bernoulli(p_sim) with
correlation rho (clipped to what the two margins allow), plus N other sim episodes; some rows leave half the
real trials unpaired, some spread them over 4 strata of different rates. The interval is the one `bench predict`
prints (`bench.scoring.predict.ppi.predict`). Printed: its coverage of p_real with the Monte-Carlo standard
error, the real-only Wilson interval's coverage on the same draws (Wilson's own coverage oscillates below 0.95
at n = 10 near 0 and 1; the PPI interval is held to the smaller of the two), both mean widths, their ratio
and the mean lambda.

Part 2 (SIMPLER, Li et al. 2024): results/references/simpler/{real,sim}.csv are aggregate rates, one per
policy x task, so nothing pairs by episode: at level=episode every real stratum is its own estimate and the
simulator cannot narrow it (lambda 0; printed). At level=unit each policy x task is one unit: the estimand is
the mean real rate over all 42 units, the real rates of a random k of them are "measured", the sim rates of all
are known. Repeated over random subsets, the coverage of the true mean (known here: every real rate is
published) and the widths are printed.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.scoring.predict.ppi import Stratum, predict, trials_for_width
from bench.scoring.predict.tables import Row, load_table, pair, unit_strata

CONF = 0.95
SIMPLER = Path(__file__).resolve().parents[1] / "results" / "references" / "simpler"


@dataclass(frozen=True)
class Scenario:
    """Known truth: real rate p_real, sim rate p_sim, their per-episode correlation rho."""

    p_real: float
    p_sim: float
    rho: float
    n: int  # real trials
    sim: int = 1000  # sim episodes not paired with a real trial
    paired: float = 1.0  # share of the real trials paired with a sim episode
    strata: int = 1  # strata of different rates (p_real ± 0.2 across them, p_sim shifted alike)

    def label(self) -> str:
        extra = (f" paired {self.paired:g}" if self.paired < 1 else "") + (
            f" {self.strata} strata" if self.strata > 1 else ""
        )
        return f"p={self.p_real:g} sim={self.p_sim:g} rho={self.rho:+g} n={self.n}{extra}"


def pairs(rng: np.random.Generator, n: int, pr: float, ps: float, rho: float) -> tuple[np.ndarray, np.ndarray]:
    """n draws of (Y, S): Bernoulli margins pr, ps with correlation rho (clipped into the feasible range)."""
    sd = np.sqrt(pr * (1 - pr) * ps * (1 - ps))
    p11 = float(np.clip(pr * ps + rho * sd, max(0.0, pr + ps - 1), min(pr, ps)))
    probs = np.array([p11, pr - p11, ps - p11, 1 - pr - ps + p11]).clip(0, 1)
    k = rng.choice(4, size=n, p=probs / probs.sum())
    return (k <= 1).astype(float), ((k == 0) | (k == 2)).astype(float)


def _strata(sc: Scenario, rng: np.random.Generator) -> tuple[list[Stratum], float]:
    offsets = np.linspace(-0.2, 0.2, sc.strata) if sc.strata > 1 else np.zeros(1)
    out, truth = [], []
    for j, off in enumerate(offsets):
        pr, ps = float(np.clip(sc.p_real + off, 0.01, 0.99)), float(np.clip(sc.p_sim + off, 0.01, 0.99))
        n = sc.n // sc.strata
        y, s = pairs(rng, n, pr, ps, sc.rho)
        k = int(round(sc.paired * n))
        sim = rng.random(sc.sim // sc.strata) < ps
        m = float(sim.mean())
        out.append(Stratum(f"s{j}", 1 / sc.strata, y[:k], s[:k], y[k:], m, m * (1 - m) / len(sim), float(len(sim))))
        truth.append(pr)
    return out, float(np.mean(truth))


def run(sc: Scenario, reps: int, seed: int = 0) -> dict[str, float]:
    """Coverage and widths of the PPI and real-only intervals over `reps` simulated evaluations."""
    rng = np.random.default_rng(seed)
    cov = cov_real = width = width_real = lam = 0.0
    for _ in range(reps):
        strata, truth = _strata(sc, rng)
        r = predict(strata, CONF)
        cov += r.lo <= truth <= r.hi
        cov_real += r.real_lo <= truth <= r.real_hi
        width += r.width
        width_real += r.real_width
        lam += r.lam
    return {
        "coverage": cov / reps,
        "se": float(np.sqrt(CONF * (1 - CONF) / reps)),
        "coverage_real": cov_real / reps,
        "width": width / reps,
        "width_real": width_real / reps,
        "lambda": lam / reps,
    }


SCENARIOS = tuple(
    Scenario(p, min(max(p + bias, 0.02), 0.98), rho, n)
    for p in (0.1, 0.5, 0.9)
    for bias in (0.0, -0.2)
    for rho in (-0.5, 0.0, 0.5, 0.9, 1.0)
    for n in (10, 30, 100)
) + (
    Scenario(0.5, 0.5, 0.9, 30, paired=0.5),
    Scenario(0.7, 0.5, 0.9, 40, paired=0.5),
    Scenario(0.5, 0.5, 0.9, 40, strata=4),
    Scenario(0.5, 0.4, 0.0, 40, strata=4),
    Scenario(0.7, 0.6, 0.9, 100, strata=4),
)


def simpler_units(k: int, reps: int, seed: int = 0) -> dict[str, float]:
    """Coverage of the mean real rate over SIMPLER's 42 policy x task units when k of them are measured."""
    real, sim = load_table(SIMPLER / "real.csv", "real"), load_table(SIMPLER / "sim.csv", "sim")
    truth = float(np.mean([(r.successes or 0) / (r.trials or 1) for r in real]))
    rng = np.random.default_rng(seed)
    out = {"coverage": 0.0, "coverage_real": 0.0, "width": 0.0, "width_real": 0.0, "lambda": 0.0, "truth": truth}
    for _ in range(reps):
        chosen: list[Row] = [real[i] for i in rng.choice(len(real), size=k, replace=False)]
        r = predict(unit_strata(pair(sim, chosen, "sim")), CONF, pseudo=0.0, unit=True)
        out["coverage"] += (r.lo <= truth <= r.hi) / reps
        out["coverage_real"] += (r.real_lo <= truth <= r.real_hi) / reps
        out["width"] += r.width / reps
        out["width_real"] += r.real_width / reps
        out["lambda"] += r.lam / reps
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=2000)
    args = ap.parse_args()
    t0 = time.perf_counter()
    print(f"Part 1: paired episodes, {args.reps} simulated evaluations per row, nominal {CONF}")
    print(f"{'scenario':<44} {'PPI cov':>8} {'real cov':>8} {'PPI w':>7} {'real w':>7} {'ratio':>6} {'lambda':>6}")
    worst = 1.0
    for sc in SCENARIOS:
        m = run(sc, args.reps)
        worst = min(worst, m["coverage"] - min(CONF, m["coverage_real"]))
        print(
            f"{sc.label():<44} {m['coverage']:>8.3f} {m['coverage_real']:>8.3f} {m['width']:>7.3f} "
            f"{m['width_real']:>7.3f} {m['width'] / m['width_real']:>6.2f} {m['lambda']:>6.2f}"
        )
    print(
        f"(Monte-Carlo s.e. of a coverage ~{np.sqrt(CONF * (1 - CONF) / args.reps):.3f}; "
        f"worst PPI coverage minus min(0.95, Wilson's): {worst:+.3f})"
    )
    rng = np.random.default_rng(1)
    strata, _ = _strata(Scenario(0.5, 0.5, 0.9, 30), rng)
    with_sim, real_only = trials_for_width(strata, 0.15, CONF)
    print(
        f"\nreal trials for a 0.15-wide interval at p=0.5, rho=0.9 (one draw of 30 pairs): {with_sim} with the sim, {real_only} real only"
    )

    print("\nPart 2: SIMPLER (aggregate per policy x task; results/references/simpler)")
    real, sim = load_table(SIMPLER / "real.csv", "real"), load_table(SIMPLER / "sim.csv", "sim")
    from bench.scoring.predict.tables import episode_strata

    r = predict(episode_strata(pair(sim, real, "sim")), CONF)
    print(
        f"level=episode, all 42 strata: {r.value:.3f} [{r.lo:.3f}, {r.hi:.3f}], real only [{r.real_lo:.3f}, "
        f"{r.real_hi:.3f}], lambda {r.lam:.2f}: no trial pairs with a sim episode, so the sim cannot help"
    )
    reps = max(args.reps // 4, 100)
    print(f"level=unit, k of 42 units measured on the real robot, {reps} random subsets each:")
    print(f"{'k':>3} {'PPI cov':>8} {'real cov':>8} {'PPI w':>7} {'real w':>7} {'ratio':>6} {'lambda':>6}")
    for k in (10, 15, 20, 30):
        m = simpler_units(k, reps)
        print(
            f"{k:>3} {m['coverage']:>8.3f} {m['coverage_real']:>8.3f} {m['width']:>7.3f} {m['width_real']:>7.3f} "
            f"{m['width'] / m['width_real']:>6.2f} {m['lambda']:>6.2f}"
        )
    print(f"(truth: the mean of the 42 published real rates, {m['truth']:.4f})")
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()

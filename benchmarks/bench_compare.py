"""Error rates and episode savings of `bench compare`'s sequential design, and the regression gate's saving, simulated.

    python benchmarks/bench_compare.py                    # 1000 comparisons per scenario, 1000 gates per gate scenario
    python benchmarks/bench_compare.py --n 300 --gates 0  # quicker, comparisons only

Synthetic comparisons (a simulation of the statistical procedure, not of robots): paired 0/1 outcomes
are drawn per cell (A's uniform draw is B's with probability rho, else independent) and fed look by look
to the very functions `bench compare` calls (`bench.board.compare.looks.evaluate_look`, `verdict_of`),
with the design it sizes (`design.size_cap`: alpha 0.05, beta 0.2, delta 0.2, looks every 5 episodes
per cell). Printed per scenario: the share of each answer, the error it measures (type-I: naming a
policy when d = 0, must be <= alpha; power: naming A when d >= delta, must be >= 1 - beta; a wrong
"equivalent" when |d| >= delta, <= beta) with a 95% Wilson interval, the mean pairs used, the
fixed-N design's pairs at equal errors (`design.fixed_pairs`) and the saving 1 - mean / fixed. For
homogeneous cells the exact figures of `design.operating` are printed beside.

The gate (`bench regress`): for its two power scenarios (one cell 0.9 -> 0.3; every cell 0.9 -> 0.75)
the budget `plan=true` gives for power 0.8 with looks every 5 episodes and with one look
(`bench.board.gate.power.episodes_needed`) are the sequential cap and the fixed-N design at equal
errors; gates are simulated with the cap through `benchmarks/bench_gate.py`'s `one_gate` (the functions
`bench regress` calls) under the alternative and under no drop, and the mean episodes per cell used
is set against the fixed design's.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
ALPHA, BETA, DELTA, BATCH = 0.05, 0.2, 0.2, 5


def one_comparison(rng, ra: np.ndarray, rb: np.ndarray, rho: float, design, keys) -> tuple[str, int]:
    """One synthetic comparison through bench.board.compare.looks: (answer, pooled pairs used)."""
    from bench.board.compare import looks as sl  # bench: importable once main() has put the repo on sys.path
    from bench.board.gate.sequential import pairs_of  # bench: as above

    cells, cap = len(keys), design.schedule[-1]
    u = rng.random((cells, cap))
    v = np.where(rng.random((cells, cap)) < rho, u, rng.random((cells, cap)))
    a, b = u < ra[:, None], v < rb[:, None]
    looks = []
    for k, n in enumerate(design.schedule):
        counts = {key: pairs_of(a[j, :n], b[j, :n]) for j, key in enumerate(keys)}
        looks.append(sl.evaluate_look(counts, design, k, cells, bounds=False))
        if looks[-1]["answer"] != "continue":
            break
    return sl.verdict_of(looks), int(looks[-1]["pairs"])


def wilson(k: int, n: int) -> tuple[float, float]:
    from bench.scoring.stats import wilson as w  # bench: importable once main() has put the repo on sys.path

    est = w(k, n)
    return float(est.lo), float(est.hi)


def comparisons(n: int, cells: int, seed: int) -> None:
    from bench.board.compare import design as sd  # bench: importable once main() has put the repo on sys.path

    cap, planned_power = sd.size_cap(ALPHA, BETA, DELTA, cells, BATCH)
    assert cap is not None
    design = sd.Design(ALPHA, BETA, DELTA, tuple(sd.looks_schedule(cap, BATCH)))
    fixed, fixed_power = sd.fixed_pairs(ALPHA, BETA, DELTA)
    keys = [("Lift", f"cell{j}", "default", "nominal", "seen") for j in range(cells)]
    spread = np.linspace(0.3, 0.9, cells) if cells > 1 else np.array([0.6])
    scenarios = [  # label, A rates, B rates, rho, what is measured
        ("d=0 at 0.5, independent", np.full(cells, 0.5), np.full(cells, 0.5), 0.0, "type1"),
        ("d=0 at 0.8, rho 0.5", np.full(cells, 0.8), np.full(cells, 0.8), 0.5, "type1"),
        ("d=0 at 0.95, independent", np.full(cells, 0.95), np.full(cells, 0.95), 0.0, "type1"),
        ("d=0, rates 0.3..0.9, rho 0.5", spread, spread, 0.5, "type1"),
        ("d=+delta 0.6/0.4 (the plan)", np.full(cells, 0.6), np.full(cells, 0.4), 0.0, "power"),
        ("d=+delta 0.7/0.5, rho 0.5", np.full(cells, 0.7), np.full(cells, 0.5), 0.5, "power"),
        ("d=-delta 0.4/0.6", np.full(cells, 0.4), np.full(cells, 0.6), 0.0, "power_b"),
        ("d=+2 delta 0.7/0.3", np.full(cells, 0.7), np.full(cells, 0.3), 0.0, "power"),
        ("d=+delta/2 0.55/0.45", np.full(cells, 0.55), np.full(cells, 0.45), 0.0, "none"),
    ]
    print(
        f"\ncomparisons: {cells} cell(s), alpha {ALPHA}, beta {BETA}, delta {DELTA}, looks every {BATCH} episodes "
        f"per cell up to the sized cap {cap} ({cap * cells} pairs; planned power {planned_power:.3f}); fixed-N design at "
        f"equal errors {fixed} pairs (power {fixed_power:.3f}); {n} comparisons per scenario"
    )
    print(
        f"  {'scenario':<30} {'A':>6} {'B':>6} {'equiv':>6} {'inconc':>6}   {'error measured':<24} {'[95% CI]':>15} "
        f"{'exact':>6} {'pairs':>6} {'saving':>7}"
    )
    for s, (label, ra, rb, rho, what) in enumerate(scenarios):
        rng = np.random.default_rng([seed, cells, s])
        t0 = time.time()
        got = {"a_better": 0, "b_better": 0, "equivalent": 0, "inconclusive": 0}
        used = []
        for _ in range(n):
            ans, pairs = one_comparison(rng, ra, rb, rho, design, keys)
            got[ans] += 1
            used.append(pairs)
        share = {k: v / n for k, v in got.items()}
        k_err, name = {
            "type1": (got["a_better"] + got["b_better"], "type-I (<= alpha)"),
            "power": (got["a_better"], "power (>= 1 - beta)"),
            "power_b": (got["b_better"], "power, B (>= 1 - beta)"),
            "none": (got["a_better"], "P(A) below delta"),
        }[what]
        lo, hi = wilson(k_err, n)
        exact = ""
        if rho == 0.0 and len(set(ra)) == 1 and len(set(rb)) == 1:
            p10, p01 = ra[0] * (1 - rb[0]), (1 - ra[0]) * rb[0]
            op = sd.operating(design, p10, p01, cells)
            ex = {"type1": op.a_better + op.b_better, "power": op.a_better, "power_b": op.b_better}.get(
                what, op.a_better
            )
            exact = f"{ex:.3f}"
        mean = float(np.mean(used))
        print(
            f"  {label:<30} {share['a_better']:>6.3f} {share['b_better']:>6.3f} {share['equivalent']:>6.3f} "
            f"{share['inconclusive']:>6.3f}   {name:<24} {k_err / n:.3f} [{lo:.3f}, {hi:.3f}] {exact:>6} "
            f"{mean:>6.1f} {1 - mean / fixed:>+7.1%}   ({time.time() - t0:.0f} s)",
            flush=True,
        )


GATE_SCENARIOS = {"cell": ("one cell 0.9 -> 0.3", 0.6), "all": ("every cell 0.9 -> 0.75", 0.15)}


def gate_savings(
    gates: int,
    seed: int,
    scenarios: tuple[str, ...] = tuple(GATE_SCENARIOS),
    truths: tuple[str, ...] = ("drop", "none"),
) -> None:
    """The regression gate's expected saving: simulated episodes per cell against its one-look design at equal power
    (`scenarios`: keys of GATE_SCENARIOS; `truths`: "drop" the scenario's drop, "none" no drop; each row keeps its
    own random stream, so a row run alone prints what it prints in a run of all)."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    import bench_gate as bg  # the gate's simulation: importable once benchmarks/ is on sys.path

    from bench.board.gate import power, sequential  # bench: importable once main() has put the repo on sys.path

    cells = 7
    keys = tuple(("Lift", bg.ROBOTS[j], "default", "nominal", bg.SPLITS[j]) for j in range(cells))
    print(
        f"\nregression gate: {cells} cells (held_out_robots' shape), margin 0.05, alpha 0.05, cell_alpha 0.5, power "
        f"target 0.8; the cap of looks every {BATCH} vs one look, both from `plan=true`'s exact calculation; {gates} "
        "gates per scenario"
    )
    print(
        f"  {'scenario':<34} {'cap':>4} {'fixed':>5} {'fail':>6} {'pass':>6} {'inconc':>6} {'ep/cell':>7} {'saving':>7}"
    )
    rates = np.full(cells, 0.9)
    for s, (scenario, (label, drop)) in enumerate(GATE_SCENARIOS.items()):
        if scenario not in scenarios:
            continue
        d0 = sequential.Design(0.05, 0.05, 0.5)
        seq_b = power.Budget(0.8, 0.9, drop, cells, BATCH, d0, 20)
        fix_b = power.Budget(0.8, 0.9, drop, cells, 0, d0, 20)
        cap, _ = power.episodes_needed(scenario, seq_b, bg.SPLITS[:cells])
        fixed, _ = power.episodes_needed(scenario, fix_b, bg.SPLITS[:cells])
        assert cap is not None and fixed is not None
        design = sequential.Design(0.05, 0.05, 0.5, tuple(sequential.looks_schedule(cap, BATCH)), keys)
        n_boot = sequential.n_boot_needed(design, 2000)
        cand_alt = rates.copy()
        if scenario == "cell":
            cand_alt[0] -= drop
        else:
            cand_alt -= drop
        for sub, cand in ((s, c) for t, s, c in (("drop", "", cand_alt), ("none", ", no drop", rates)) if t in truths):
            rng = np.random.default_rng([seed, 77, s, len(sub)])
            t0 = time.time()
            verdicts, used = [], []
            for _ in range(gates):
                v, _, n_used = bg.one_gate(rng, rates, cand, 0.0, design, n_boot)
                verdicts.append(v)
                used.append(n_used)
            mean = float(np.mean(used))
            print(
                f"  {label + sub:<34} {cap:>4} {fixed:>5} {verdicts.count('regression') / gates:>6.3f} "
                f"{verdicts.count('no_regression') / gates:>6.3f} {verdicts.count('inconclusive') / gates:>6.3f} "
                f"{mean:>7.1f} {1 - mean / fixed:>+7.1%}   ({time.time() - t0:.0f} s)",
                flush=True,
            )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1000, help="comparisons per scenario (0: none)")
    ap.add_argument("--cells", default="7,1", help="cell counts of the comparison tables")
    ap.add_argument("--gates", type=int, default=1000, help="gates per gate scenario (0: none)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--gate-scenarios",
        default=",".join(GATE_SCENARIOS),
        help="gate scenarios to simulate: cell (one cell 0.9 -> 0.3), all (every cell 0.9 -> 0.75; its cap of 55 "
        "episodes per cell takes about 2 s per gate on one core)",
    )
    ap.add_argument("--gate-truths", default="drop,none", help="rows per gate scenario: drop, none (no drop)")
    a = ap.parse_args()
    truths = tuple(x.strip() for x in a.gate_truths.split(",") if x.strip())
    if not truths or any(x not in ("drop", "none") for x in truths):
        ap.error(f"--gate-truths {a.gate_truths!r}: a comma list of drop, none")
    chosen = tuple(x.strip() for x in a.gate_scenarios.split(",") if x.strip())
    if not chosen or any(x not in GATE_SCENARIOS for x in chosen):
        ap.error(f"--gate-scenarios {a.gate_scenarios!r}: a comma list of {', '.join(GATE_SCENARIOS)}")
    t0 = time.time()
    if a.n:
        for cells in (int(c) for c in a.cells.split(",")):
            comparisons(a.n, cells, a.seed)
    if a.gates:
        gate_savings(a.gates, a.seed, chosen, truths)
    print(f"\ntotal {time.time() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(REPO))
    raise SystemExit(main())

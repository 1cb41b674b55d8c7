"""Error rates of the regression gate's decision rule (`bench.board.gate.sequential`), and one real gate on a one-robot collapse.

    python benchmarks/bench_gate.py                      # 1000 synthetic gates per scenario, default budget
    python benchmarks/bench_gate.py --gates 300 --budget 7x10/5
    python benchmarks/bench_gate.py --gates 0 --real     # only the real-rollout check

Synthetic gates (a simulation of the statistical procedure, not of robots): paired 0/1 outcomes
are drawn for 7 cells shaped like held_out_robots (3 seen robots, 4 unseen) and fed, look by
look, to the very functions `bench regress` calls (`sequential.Design`, `sequential.evaluate_look`,
`sequential.decide`), with the default margin 0.05, alpha 0.05, cell_alpha 0.5 and the bootstrap size
the gate uses. Outcomes of a pair share their initial state with probability rho (the
candidate's uniform draw is the baseline's), else are independent. Printed per scenario: the
share of gates that fail (regression), pass certified (no regression) or end inconclusive, the
share naming the collapsed cell, the share naming a cell whose true drop is within the margin
(a false cell claim), episodes per cell used, and a 95% Wilson interval on the failure rate.
Null scenarios (no cell drops by more than the margin) measure the false-alarm rate, which must
stay at most alpha; the others measure power. The one-cell collapse is also computed exactly by
`bench.board.gate.power` (the `plan=true` calculation) to check it against the simulation.

--real: one gate on real rollouts. The baseline is the committed behaviour-cloning run
results/runs/held_out_robots-bc-s0 (7 robots x 10 episodes, seed 0). The candidate is the same
run with one robot's episodes replaced by a fresh `bench run` of the random policy on that
robot with the same seed (10 real episodes, a collapse on one robot), written as a run
directory; `bench regress` then compares the two recorded runs (nothing else is simulated) and
must name that robot.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
RATES = np.array([0.9, 0.8, 0.7, 0.6, 0.5, 0.95, 0.3])  # Panda, Sawyer, IIWA (seen); UR5e, Kinova3, Jaco, XArm7
SPLITS = ["seen"] * 3 + ["unseen"] * 4
ROBOTS = ["Panda", "Sawyer", "IIWA", "UR5e", "Kinova3", "Jaco", "XArm7"]


def one_gate(rng: np.random.Generator, pb: np.ndarray, pc: np.ndarray, rho: float, design, n_boot: int):
    """One synthetic gate through bench.board.gate.sequential: (verdict, rejected test ids at the last look, episodes per cell used)."""
    from bench.board.gate import sequential

    k, e = len(pb), design.schedule[-1]
    u = rng.random((k, e))
    v = np.where(rng.random((k, e)) < rho, u, rng.random((k, e)))
    base, cand = u < pb[:, None], v < pc[:, None]
    looks = []
    for i, n in enumerate(design.schedule):
        counts = {key: sequential.pairs_of(base[j, :n], cand[j, :n]) for j, key in enumerate(design.cells)}
        looks.append(sequential.evaluate_look(counts, design, i, rng, n_boot, bounds=False))
        if looks[-1]["decision"] != "continue":
            break
    return sequential.decide(looks, False)[0], looks[-1].get("regressed", []), design.schedule[len(looks) - 1]


def wilson(k: int, n: int) -> tuple[float, float]:
    from bench.scoring.stats import wilson as w

    est = w(k, n)
    return float(est.lo), float(est.hi)


def synthetic(gates: int, cells: int, episodes: int, batch: int, seed: int) -> dict[str, float]:
    from bench.board.gate import sequential

    keys = tuple(("Lift", ROBOTS[j], "default", "nominal", SPLITS[j]) for j in range(cells))
    design = sequential.Design(0.05, 0.05, 0.5, tuple(sequential.looks_schedule(episodes, batch)), keys)
    n_boot = sequential.n_boot_needed(design, 2000)
    pb = RATES[:cells]
    collapse = pb.copy()
    collapse[0] = 0.3
    unseen = np.where(np.array(SPLITS[:cells]) == "unseen", pb - 0.2, pb)
    scenarios = [  # label, candidate rates, rho, null?
        ("equal, independent", pb, 0.0, True),
        ("equal, rho 0.5", pb, 0.5, True),
        ("every cell drop = margin", pb - 0.05, 0.5, True),
        ("every cell 1.00 -> 0.95", None, 0.0, True),
        ("Panda 0.9 -> 0.3, rho 0", collapse, 0.0, False),
        ("Panda 0.9 -> 0.3, rho 0.5", collapse, 0.5, False),
        ("unseen cells drop 0.2", unseen, 0.5, False),
        ("every cell drop 0.15", pb - 0.15, 0.5, False),
    ]
    print(
        f"\nsynthetic gates: {cells} cells x up to {episodes} episodes, looks every {batch} ({design.schedule}); "
        f"margin 0.05, alpha 0.05, cell_alpha 0.5; {gates} gates per scenario; bootstrap {n_boot}"
    )
    print(
        f"  {'scenario':<27} {'fail':>6} {'[95% CI]':>15} {'pass':>6} {'inconcl':>7} {'names Panda':>11} "
        f"{'false cell':>10} {'ep/cell':>7}"
    )
    out = {}
    for s, (label, pc, rho, null) in enumerate(scenarios):
        rng = np.random.default_rng([seed, s])
        base_rates = np.ones(cells) if pc is None else pb
        cand_rates = np.full(cells, 0.95) if pc is None else pc
        verdicts, named, false_cell, used = [], 0, 0, []
        t0 = time.time()
        true_drop = base_rates - cand_rates
        for _ in range(gates):
            v, rejected, n = one_gate(rng, base_rates, cand_rates, rho, design, n_boot)
            verdicts.append(v)
            used.append(n)
            named += sequential.cell_id(keys[0]) in rejected
            false_cell += any(
                sequential.cell_id(k) in rejected for j, k in enumerate(keys) if true_drop[j] <= 0.05 + 1e-9
            )
        fail = verdicts.count("regression")
        lo, hi = wilson(fail, gates)
        out[label] = fail / gates
        passed = verdicts.count("no_regression") / gates
        print(
            f"  {label:<27} {fail / gates:>6.3f} [{lo:.3f}, {hi:.3f}] {passed:>6.3f} "
            f"{verdicts.count('inconclusive') / gates:>7.3f} {named / gates:>11.3f} {false_cell / gates:>10.3f} "
            f"{np.mean(used):>7.1f}   ({time.time() - t0:.0f} s){'  [null: fail <= alpha]' if null else ''}",
            flush=True,
        )
    return out


def plan_check(cells: int, episodes: int, batch: int, simulated: dict[str, float]) -> None:
    """The exact power of `bench regress plan=true` against the simulated gates (rho 0 = its assumption)."""
    from bench.board.gate import power, sequential

    d = sequential.Design(0.05, 0.05, 0.5)
    budget = power.Budget(power=0.8, rate=0.9, drop=0.6, n_cells=cells, batch=batch, design=d, episodes=episodes)
    exact = power.scenario_power("cell", episodes, budget, SPLITS[:cells])
    need, got = power.episodes_needed("cell", budget, SPLITS[:cells])
    sim = simulated.get("Panda 0.9 -> 0.3, rho 0")
    print(
        f"\nplan check (one cell 0.9 -> 0.3, outcomes independent): exact power of the cell's own test "
        f"{exact:.3f} (a lower bound); simulated share of gates failing {sim:.3f}. plan=true says "
        f"{need} episodes per cell for power 0.8 (exact {got:.3f} there)."
    )


def real(work: Path, robot: str) -> None:
    """One gate on recorded rollouts: the committed BC run vs the same run with `robot` played by the random policy."""
    from bench import api
    from bench.cli import regress
    from bench.records import RecordWriter, read_records
    from bench.scoring.summary import load_run

    base_dir = REPO / "results" / "runs" / "held_out_robots-bc-s0"
    records, meta = load_run(base_dir)
    cfg = meta["config"]
    print(
        f"\nreal gate: baseline {base_dir.relative_to(REPO)} ({len(records)} episodes, seed {cfg['seed']}); "
        f"candidate: the same run with {robot} played by the random policy"
    )
    if work.exists():
        shutil.rmtree(work)
    t0 = time.time()
    bad = api.run(
        api.RunConfig(
            suite=cfg["suite"],
            policy="random",
            robots=[robot],
            episodes=cfg["episodes"],
            seed=cfg["seed"],
            horizon=cfg["horizon"],
            workers=1,
            out=str(work),
            run_id=f"random-{robot}",
        )
    )
    print(
        f"  bench run policy=random robots=[{robot}] episodes={cfg['episodes']} seed={cfg['seed']}: "
        f"{len(bad.records)} episodes in {time.time() - t0:.0f} s, success "
        f"{np.mean([r.success_once for r in bad.records]):.2f}"
    )
    cand = work / "collapsed"
    cand.mkdir()
    kept = [r for r in read_records(base_dir / "episodes.jsonl") if r.robot != robot]
    with RecordWriter(cand / "episodes.jsonl") as writer:
        for r in kept + list(bad.records):
            writer.write(dataclasses.replace(r, run_id="collapsed"))
    # a mixture of two policies: no single checkpoint identifies it
    cand_meta = {
        **meta,
        "run_id": "collapsed",
        "policy": {"name": f"bc (episodes of {robot}: random)", "checkpoint": None, "checkpoint_sha256": None},
    }
    (cand / "run.json").write_text(json.dumps(cand_meta, indent=2))
    verdict = work / "verdict.json"
    code = regress.main(
        [f"candidate={cand}", f"baseline={base_dir}", f"runs={work / 'gates'}", "run_id=real", f"out={verdict}"]
    )
    doc = json.loads(verdict.read_text())
    print(
        f"  exit {code}, verdict {doc['verdict']}; regressed: "
        + "; ".join(
            f"{r['kind']} {r['name']} drop {r['drop']:+.2f} [{r['lcb']:+.2f}, {r['ucb']:+.2f}]"
            for r in doc["regressed"]
        )
    )
    print(f"  JUnit {verdict.with_suffix('.junit.xml')}, Markdown {verdict.with_suffix('.md')}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gates", type=int, default=1000, help="synthetic gates per scenario (0: none)")
    ap.add_argument("--budget", default="7x20/5", help="CELLSxEPISODES/BATCH of the synthetic gates")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--real", action="store_true", help="also run the real-rollout check (10 robosuite episodes)")
    ap.add_argument("--robot", default="Panda", help="robot whose episodes collapse in the real check")
    ap.add_argument("--work", default="/tmp/bench_gate", help="scratch folder of the real check")
    a = ap.parse_args()
    t0 = time.time()
    cells_eps, batch = a.budget.split("/")
    cells, episodes = (int(x) for x in cells_eps.split("x"))
    if a.gates:
        sim = synthetic(a.gates, cells, episodes, int(batch), a.seed)
        plan_check(cells, episodes, int(batch), sim)
    if a.real:
        real(Path(a.work), a.robot)
    print(f"\ntotal {time.time() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(REPO))
    raise SystemExit(main())

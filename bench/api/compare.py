"""`bench compare` from Python: which of two policies is better, with as few episodes as it takes.

Both policies play the same suite cells with the same episode seeds (as `bench regress`'s two sides: a
policy name, a checkpoint, or a recorded run directory whose episodes are reused, `bench.api.gate.sides`),
in looks of `batch` episodes per cell; after each look the group-sequential test of
`bench.board.compare.design` answers A better, B better, equivalent within delta, or goes on; at the cap
the answer is inconclusive. Errors hold at every look: naming a policy when they are equal <= alpha,
missing a difference of delta (or calling it equivalent) <= beta at the planned discordance; per cell at
alpha / C and beta / C. The cap (episodes per cell) is sized for power 1 - beta unless `episodes=` is
given (or a recorded run fixes it); the document reports the pairs used against the fixed-N design at
equal errors. Two recorded runs are compared look by look over their recorded episodes, nothing run.
`paired=false` compares two recorded runs on other seeds as unpaired batches (Boschloo's exact test,
Fisher's beside it; one look). See docs/compare.md.

Exit codes: 0 an answer or inconclusive, 2 bad input, 3 nothing measured (a side completed no episode of a cell).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any, Optional

import numpy as np

import bench.sims.perturb.axes as axes
from bench.api import config_from_argv, finish, load_suite, start
from bench.api.gate.sides import (
    SHARED_KEYS,
    Side,
    check_sides_pairable,
    describe_side,
    input_paths,
    live_plan,
    prepare_live,
    recorded_settings,
    run_look,
)
from bench.board.compare import design as sd
from bench.board.compare import looks as sl
from bench.board.gate.inputs import BINARY_METRICS, cells_of_jobs, cells_of_records, check_outputs, resolve
from bench.board.gate.pairs import cell_counts, pair_records, unmeasured
from bench.board.gate.sequential import CellKey
from bench.core import config as config_mod
from bench.core.errors import ConfigError
from bench.core.io import write_atomic
from bench.core.schema import validate
from bench.protocols import NumArray
from bench.protocols.suite import select_cells
from bench.records import EpisodeRecord

__all__ = ["CompareConfig", "Comparison", "check_compare", "compare"]

SCHEMA_ID = "bench.compare/1"


@dataclass(frozen=True)
class CompareConfig:
    """Keys of `bench compare` besides the `bench run` keys it forwards."""

    a: Optional[str] = None  # policy A: a checkpoint (.safetensors/.pt), registered policy name, or recorded run dir
    b: Optional[str] = None  # policy B: the same kinds
    alpha: float = 0.05  # chance of naming a better policy when they are equal (all looks, both directions)
    beta: float = 0.2  # chance of missing a difference of delta, or calling it equivalent (power 1 - beta)
    delta: float = 0.2  # the difference in success rate that matters; |A - B| < delta is "equivalent"
    batch: int = 5  # episodes per cell between looks; 0 = one look at the cap
    paired: bool = True  # false: two recorded runs on other seeds, compared unpaired (Boschloo's exact test)
    allow_spec_change: bool = False  # pair episodes of runs whose suite options or simulator versions differ
    out: Optional[str] = None  # comparison JSON; default RUNS/RUN_ID/comparison.json
    runs: str = "runs"  # parent folder of the comparison's run directories
    run_id: Optional[str] = None  # folder name; default compare-<timestamp>


@dataclass(frozen=True)
class Comparison:
    """The answer and what was written: the document (schema bench.compare/1), exit code, its path."""

    run_id: str
    doc: dict[str, Any]
    exit_code: int
    path: Path
    nothing_measured: str | None = None


def check_compare(cfg: CompareConfig) -> None:
    """The ranges of the comparison's own keys (one line naming the key and what is valid)."""
    for key in ("alpha", "beta"):
        v = getattr(cfg, key)
        if not 0.0 < v < 0.5:
            raise ConfigError(f"{key}={v}: must be in (0, 0.5)")
    if not 0.0 < cfg.delta < 1.0:
        raise ConfigError(f"delta={cfg.delta}: must be in (0, 1) (a difference in success rate)")
    if cfg.batch < 0:
        raise ConfigError(f"batch={cfg.batch}: must be >= 0 (0 = a single look)")
    if cfg.run_id is not None and (not cfg.run_id or "/" in cfg.run_id or cfg.run_id.startswith(".")):
        raise ConfigError(f"run_id={cfg.run_id!r}: must be a plain folder name")
    if cfg.a and cfg.b and _same(cfg.a, cfg.b):
        raise ConfigError(f"a={cfg.a!r} and b={cfg.b!r} are the same policy: nothing to compare")


def _same(a: str, b: str) -> bool:
    pa, pb = Path(a), Path(b)
    if pa.exists() and pb.exists():
        return pa.resolve() == pb.resolve()
    return a == b


def _sized_cap(cfg: CompareConfig, forwarded: list[str]) -> int:
    """Episodes per cell for power 1 - beta at delta, with the cells the `bench run` keys select."""
    rc = config_from_argv(forwarded)
    cells = select_cells(load_suite(rc.suite, **rc.suite_options), rc)
    n_cells = len(cells) * len(axes.conditions_from_config(rc.perturb))
    if not n_cells:
        raise ConfigError("the selection (robots/tasks/envs/splits) leaves no cell")
    cap, got = sd.size_cap(cfg.alpha, cfg.beta, cfg.delta, n_cells, cfg.batch)
    if cap is None:
        raise ConfigError(
            f"delta={cfg.delta}: power {1 - cfg.beta:g} needs more than {sd.MAX_PAIRS} pairs; give a larger delta "
            "or episodes= (the power at that cap is reported)"
        )
    return cap


def _check_settings(sides: list[Side]) -> None:
    """Two recorded runs, or a live side and a recorded run, must agree on the keys that decide the episodes."""
    rec = [s.meta.get("suite", {}) for s in sides if not s.live]
    if len(rec) == 2 and (rec[0].get("name"), rec[0].get("version")) != (rec[1].get("name"), rec[1].get("version")):
        raise ConfigError(
            f"A is suite {rec[0].get('name')} v{rec[0].get('version')}, B is {rec[1].get('name')} "
            f"v{rec[1].get('version')}: episodes of different suites do not pair"
        )
    c1, c2 = (live_plan(s).config_dict() if s.live else s.meta["config"] for s in sides)
    for k in SHARED_KEYS:
        if k in c1 and k in c2 and c1[k] != c2[k]:
            raise ConfigError(
                f"{k} differs between A and B ({c1[k]!r} vs {c2[k]!r}): paired episodes need the same settings"
                + ("; paired=false compares two recorded runs as unpaired batches" if k == "seed" else "")
            )


def _outcomes(records: list[EpisodeRecord], metric: str, max_episode: int) -> dict[CellKey, NumArray]:
    by: dict[CellKey, list[float]] = {}
    for r in records:
        if r.episode < max_episode:
            ok = r.error is None and bool(getattr(r, metric))
            by.setdefault((r.task, r.robot, r.env, r.condition, r.split), []).append(float(ok))
    return {k: np.array(v) for k, v in by.items()}


def compare(cfg: CompareConfig, run_keys: Sequence[str] = (), console: Any = None) -> Comparison:
    """Compare `cfg.a` with `cfg.b` (`bench compare`) on the cells and seeds the `bench run` keys `run_keys` select,
    in looks until the answer is reached; writes the comparison JSON and shows the looks on `console`."""
    if console is None:
        from rich.console import Console  # rich: loaded only when something is drawn on the terminal

        console = Console(stderr=True)
    check_compare(cfg)
    forwarded = list(run_keys)
    user_keys = {config_mod.top_key(f): f for f in forwarded}
    info_a, info_b = resolve(cfg.a, "a"), resolve(cfg.b, "b")
    run_id = cfg.run_id or f"compare-{datetime.now().strftime('%Y%m%d-%H%M%S')}"
    parent = Path(cfg.runs) / run_id
    out = Path(cfg.out) if cfg.out else parent / "comparison.json"
    if out.suffix != ".json":
        raise ConfigError(f"out={cfg.out!r}: the comparison file must end in .json")
    side_a, side_b = Side("A", info_a), Side("B", info_b)
    ref, shared, episodes = recorded_settings((side_a, side_b), user_keys, lambda: _sized_cap(cfg, forwarded))
    recorded = [s for s in (side_a, side_b) if s.info["kind"] == "run"]
    if not cfg.paired and len(recorded) < 2:
        raise ConfigError("paired=false compares two recorded runs (a= and b= run directories)")
    forwarded = [f for f in forwarded if not f.startswith("episodes=")] + [f"episodes={episodes}"]
    for side in (side_a, side_b):
        if not side.info["kind"] == "run":
            prepare_live(side, shared, forwarded, f"{run_id}-{side.role.lower()}", parent)
    if cfg.paired:
        _check_settings([side_a, side_b])
    live = [s for s in (side_a, side_b) if s.live]
    plans = [live_plan(s) for s in live]
    metric = plans[0].config.metric if plans else recorded[0].meta["config"].get("metric", "success_once")
    if metric not in BINARY_METRICS:
        raise ConfigError(f"metric={metric!r}: compare needs a success metric; valid: {', '.join(BINARY_METRICS)}")
    wanted = {r.job_id for r in ref.records} if ref is not None else None
    for side in live:
        side.wanted = wanted if wanted is not None else {j.job_id for j in live_plan(side).jobs}
        if not any(j.job_id in side.wanted for j in live_plan(side).jobs):
            raise ConfigError("the recorded run has no episode of the selected cells; nothing to pair")
    if ref is not None and cfg.paired:
        try:
            check_sides_pairable(ref, [s for s in (side_a, side_b) if s is not ref])
        except ConfigError as e:
            hint = "; paired=false compares two recorded runs as unpaired batches" if "seeds" in str(e) else ""
            raise ConfigError(f"{e}{hint}") from None
    if len(recorded) == 2 and not cfg.paired:
        cells_a, cells_b = cells_of_records(side_a.records), cells_of_records(side_b.records)
        if cells_a != cells_b:
            raise ConfigError(
                f"the runs hold other cells ({len(cells_a - cells_b)} only in A, {len(cells_b - cells_a)} only in B): "
                "even unpaired, a comparison needs the same cells"
            )
    check_outputs({"verdict": out}, input_paths([side_a, side_b]))
    planned = sorted(cells_of_jobs(plans[0].jobs, live[0].wanted) if live else cells_of_records(recorded[0].records))
    schedule = sd.looks_schedule(episodes, cfg.batch) if cfg.paired else [episodes]
    design = sd.Design(cfg.alpha, cfg.beta, cfg.delta, tuple(schedule))
    fixed, _ = sd.fixed_pairs(cfg.alpha, cfg.beta, cfg.delta)
    plan_op = sd.operating(design, *sd.planned_pairs(cfg.delta), cells=len(planned))
    base_doc: dict[str, Any] = {
        "schema": SCHEMA_ID,
        "alpha": cfg.alpha,
        "beta": cfg.beta,
        "delta": cfg.delta,
        "paired": cfg.paired,
        "metric": metric,
        "episodes_max": episodes,
        "schedule": schedule,
        "cells_planned": len(planned),
        "design": {
            "method": "group-sequential, Lan-DeMets O'Brien-Fleming spending (Jennison & Turnbull 2000, ch. 5)"
            if cfg.paired
            else "unpaired, one look: Boschloo's exact test, Newcombe's interval",
            "efficacy_bounds": [sl.finite(c) for c in design.efficacy],
            "equivalence_bounds": [sl.finite(e) for e in design.equivalence],
            "power_at_delta_planned": round(plan_op.a_better, 4),
            "fixed_n_pairs": fixed,
            "rule": sl.rule(design, len(planned)),
        },
        "a": describe_side(side_a, None),
        "b": describe_side(side_b, None),
    }
    if not cfg.paired:
        a_cells = _outcomes(side_a.records, metric, episodes)
        b_cells = _outcomes(side_b.records, metric, episodes)
        tests = sl.unpaired(a_cells, b_cells, cfg.alpha, cfg.beta, cfg.delta)
        doc = {**base_doc, "answer": tests[0]["answer"], "tests": tests, "looks": []}
        validate(doc, "comparison")  # the shipped schema bench.compare/1, before the file is written
        write_atomic(out, doc)
        console.print(_summary_line(doc), soft_wrap=True)
        return Comparison(run_id, doc, 0, out)

    workers = plans[0].workers if plans else 1
    for side in live:
        side.meta, _ = start(live_plan(side), workers)
    console.print(
        f"compare {run_id}: A {side_a.info['spec']} vs B {side_b.info['spec']}; {len(planned)} cells; looks at "
        f"{schedule} episodes per cell; alpha {cfg.alpha}, beta {cfg.beta}, delta {cfg.delta} "
        f"(power at delta {plan_op.a_better:.2f}; fixed-N design {fixed} pairs)"
    )
    t0 = time.time()
    looks: list[dict[str, Any]] = []
    empty = None
    for k, n_eps in enumerate(schedule):
        for side in live:
            run_look(side, n_eps, workers)
        paired = pair_records(side_b.records, side_a.records, max_episode=n_eps)  # (baseline, candidate) = (A, B)
        counts = cell_counts(paired["cells"], metric)
        look = {"look": k + 1, "episodes_per_cell": n_eps, **sl.evaluate_look(counts, design, k, len(planned))}
        looks.append(look)
        console.print(_look_line(look, len(schedule)), soft_wrap=True)
        empty, dead = unmeasured({"A": side_a.records, "B": side_b.records}, planned, n_eps)
        if look["answer"] != "continue" or dead:
            break
    for side in live:
        finish(live_plan(side), side.meta, workers)
    answer = sl.verdict_of(looks)
    code = 0
    if empty:
        answer, code = "nothing_measured", 3
    used = int(looks[-1].get("pairs", 0))
    doc = {
        **base_doc,
        "answer": answer,
        "note": f"nothing measured: {empty}" if empty else None,
        "stopped_early": len(looks) < len(schedule),
        "pairs_used": used,
        "pairs_cap": episodes * len(planned),
        "saving_vs_fixed_n": round(1.0 - used / fixed, 4),
        "underpowered": plan_op.a_better < 1.0 - cfg.beta,  # the cap given is below the sized design's
        "a": describe_side(side_a, None),
        "b": describe_side(side_b, None),
        "looks": looks,
        "tests": list(sl.cell_answers(looks).values()),
        "wall_s": round(time.time() - t0, 2),
    }
    validate(doc, "comparison")
    write_atomic(out, doc)
    console.print(_summary_line(doc), soft_wrap=True)
    return Comparison(run_id, doc, code, out, empty)


def _look_line(look: dict[str, Any], n_looks: int) -> str:
    if "tests" not in look:
        return f"look {look['look']}/{n_looks}: {look.get('reason', 'no pairs')}"
    t = look["tests"][0]
    cells = [f"{c['id'][5:]} {sl.WORDS[c['answer']]}" for c in look["tests"][1:] if c["answer"] != "continue"]
    return (
        f"look {look['look']}/{n_looks} ({look['episodes_per_cell']} ep/cell, {t['pairs']} pairs): A {t['a']:.3f} "
        f"B {t['b']:.3f}, d {t['diff']:+.3f} [{t['lo']:+.3f}, {t['hi']:+.3f}] z {t['z_a']}/{t['z_b']} (bound {t['bound']})"
        + (f"; cells: {', '.join(cells)}" if cells else "")
        + f" -> {look['answer']}"
    )


def _summary_line(doc: dict[str, Any]) -> str:
    t = doc["tests"][0] if doc["tests"] else {}
    head = f"{sl.WORDS[doc['answer']]}: A {doc['a']['spec']} vs B {doc['b']['spec']}"
    if not doc["paired"]:
        return (
            f"{head} (unpaired): A {t['a']:.3f} B {t['b']:.3f}, d {t['diff']:+.3f} [{t['lo']:+.3f}, {t['hi']:+.3f}] "
            f"at {t['level']:.0%}; Boschloo p {t['boschloo_p']:.4g} (Fisher p {t['fisher_p']:.4g}), alpha {doc['alpha']}"
        )
    if not t:
        return head
    return (
        f"{head}: d {t['diff']:+.3f} [{t['lo']:+.3f}, {t['hi']:+.3f}] over {doc['pairs_used']} pairs "
        f"(cap {doc['pairs_cap']}; fixed-N design at equal errors {doc['design']['fixed_n_pairs']}: "
        f"saving {doc['saving_vs_fixed_n']:+.0%})"
        + (
            f"; the cap gives power {doc['design']['power_at_delta_planned']:.2f} at delta, below 1 - beta"
            if doc["underpowered"]
            else ""
        )
    )

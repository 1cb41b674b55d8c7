"""`bench regress` from Python: the CI regression gate — does the candidate transfer worse than the baseline?

Both policies run the same suite cells with the same episode seeds
(`bench.protocols.suite.episode_seed`), so every candidate episode has a baseline twin that
started from the same initial state; outcomes are compared pair by pair. A
baseline given as a recorded run directory is not re-run: its episodes are reused
and the candidate runs with that run's settings.

Rule (drop = baseline − candidate success; the statistics are in `bench.board.gate.sequential`):
    regression     if a one-sided test finds the drop above `margin` — pooled over all
                   pairs, in the IQM of the per-cell rates, in a split, or in one cell
                   (weighted Holm across those tests: the verdict names what regressed);
    no regression  if the upper bounds of the pooled (and IQM) drop are below `margin`;
    inconclusive   otherwise, once the episode budget is spent: passes with a
                   warning (exit 0), or fails with `strict=true`.
Episodes run in batches (`batch` per cell) and the rule is applied after each batch,
stopping as soon as the verdict is certain; alpha is spent over tests and looks
(Bonferroni across looks), so the chance of any false alarm when no drop exceeds
`margin` is at most `alpha` whatever the number of cells. An errored or timed-out episode
counts as a failure of its side; pairs where both sides errored are left out.
Identical checkpoints (same sha256) are not simulated: they cannot regress.

Outputs: the verdict JSON (schema bench.regress/2, with both checkpoints' sha256, size and
training metadata) and, beside it, JUnit XML and a Markdown summary (`bench.board.gate.outputs`).
`plan=true` prints the episodes per cell a power target needs (`bench.board.gate.power`; `regress_budget`). The
command line is checked by `bench.cli.regress_args`, episodes are paired by `bench.board.gate.pairs`.
See docs/ci-sequential.md.

Exit codes: 0 no regression (or inconclusive, not strict), 1 regression, 2 bad input, 3 nothing
measured: a side completed no episode of some cell (verdict `nothing_measured`; a CI job fails).
The two sides of the comparison (planned, run a look at a time, checked, described) are `bench.api.gate.sides`'.
`paired=false` compares two recorded runs with other seeds unpaired instead (`bench.api.gate.unpaired`).
"""

from __future__ import annotations

import dataclasses
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
    check_same_settings,
    check_sides_pairable,
    describe_side,
    episodes_of,
    input_paths,
    live_plan,
    prepare_live,
    recorded_settings,
    run_look,
    side_provenance,
)
from bench.api.gate.unpaired import run_unpaired
from bench.board.gate import outputs, power, sequential
from bench.board.gate.inputs import (
    cells_of_jobs,
    cells_of_records,
    check_outputs,
    require_binary,
    resolve,
)
from bench.board.gate.pairs import cell_counts, pair_records, unmeasured
from bench.core import config as config_mod
from bench.core import provenance
from bench.core.errors import ConfigError, NothingMeasured
from bench.protocols.suite import SuiteSpec, select_cells

__all__ = [
    "DEFAULT_EPISODES",
    "FORBIDDEN_KEYS",
    "RegressConfig",
    "Verdict",
    "check_regress",
    "episodes_of",
    "regress",
    "regress_budget",
]

DEFAULT_EPISODES = 20
FORBIDDEN_KEYS = {"policy": "candidate=/baseline=", "checkpoint": "candidate=/baseline=", "record": None}


@dataclass(frozen=True)
class RegressConfig:
    """Keys of `bench regress` besides the `bench run` keys it forwards."""

    candidate: Optional[str] = None  # checkpoint (.safetensors/.pt), registered policy name, or a recorded run dir
    baseline: Optional[str] = None  # checkpoint file, policy name, or a recorded run dir (its episodes are reused)
    margin: float = 0.05  # tolerated drop in success (baseline - candidate) before it is a regression
    alpha: float = 0.05  # false-alarm rate when no drop exceeds margin (over all looks, tests and cells)
    cell_alpha: float = 0.5  # share of alpha for the per-cell tests (Holm); 0 = pooled statistics only
    batch: int = 5  # episodes per cell between looks (early stopping); 0 = one look at the end
    strict: bool = False  # inconclusive (budget spent, nothing certain) fails with exit 1
    allow_spec_change: bool = False  # pair episodes of runs whose suite options or simulator versions differ
    out: Optional[str] = None  # verdict JSON (X.junit.xml, X.md beside it); default RUNS/RUN_ID/verdict.json
    runs: str = "runs"  # parent folder of the gate's run directories
    run_id: Optional[str] = None  # gate folder name; default regress-<timestamp>
    plan: bool = False  # print the episodes per cell needed for `power` and exit (runs nothing)
    power: float = 0.8  # plan: target chance to flag the drop below
    drop: float = 0.6  # plan: the drop to detect (one cell falls from rate to rate - drop)
    rate: float = 0.9  # plan: baseline success rate of the cell(s) that drop
    cells: int = 0  # plan: number of cells; 0 = those the suite/robots/tasks/envs/perturb keys select
    paired: bool = True  # false: two recorded runs with other seeds, compared unpaired (exact tests, one look)


def check_regress(cfg: RegressConfig) -> None:
    """The ranges of the gate's own keys (one line naming the key and what is valid)."""
    for key, lo, hi, what in (
        ("margin", 0.0, 1.0, "[0, 1)"),
        ("alpha", 0.0, 0.5, "(0, 0.5)"),
        ("cell_alpha", 0.0, 1.0, "[0, 1)"),
        ("power", 0.0, 1.0, "(0, 1)"),
        ("drop", 0.0, 1.0, "(0, 1]"),
        ("rate", 0.0, 1.0, "(0, 1]"),
    ):
        v = getattr(cfg, key)
        closed_lo, closed_hi = what[0] == "[", what[-1] == "]"
        if not ((lo <= v if closed_lo else lo < v) and (v <= hi if closed_hi else v < hi)):
            raise ConfigError(f"{key}={v}: must be in {what}")
    if cfg.batch < 0:
        raise ConfigError(f"batch={cfg.batch}: must be >= 0 (0 = a single look)")
    if cfg.cells < 0:
        raise ConfigError(f"cells={cfg.cells}: must be >= 0 (0 = count the suite selection's cells)")
    if cfg.run_id is not None and (not cfg.run_id or "/" in cfg.run_id or cfg.run_id.startswith(".")):
        raise ConfigError(f"run_id={cfg.run_id!r}: must be a plain folder name")


@dataclass(frozen=True)
class Verdict:
    """What the gate decided and wrote: the verdict document (schema bench.regress/2), the exit code `bench regress`
    ends with (0 no regression or inconclusive, 1 regression, 3 nothing measured), and the files written."""

    gate_id: str  # the gate's folder name under runs=
    doc: dict[str, Any]
    exit_code: int
    paths: dict[str, Path]  # verdict, junit, markdown
    nothing_measured: str | None = None  # which side completed no episode of which cell (exit code 3)


SCHEMA_ID = "bench.regress/2"
VERDICT_FILE = "verdict.json"


def regress(cfg: RegressConfig, run_keys: Sequence[str] = (), console: Any = None) -> Verdict:
    """The gate of `cfg.candidate` against `cfg.baseline` (`bench regress`): both run on the cells and episode seeds
    the `bench run` keys `run_keys` select (`key=value` strings: suite=, robots=, episodes= ...), in looks of
    `cfg.batch` episodes per cell until the verdict is certain; writes the verdict JSON, its JUnit XML and its
    Markdown summary, and shows the looks and the verdict on `console` (default: a rich Console on stderr).
    A side that completed no episode of some cell makes the verdict `nothing_measured` (`Verdict.nothing_measured`).
    """
    if console is None:
        from rich.console import Console  # rich: loaded only when something is drawn on the terminal

        console = Console(stderr=True)
    check_regress(cfg)
    forwarded = list(run_keys)
    user_keys = {config_mod.top_key(f): f for f in forwarded}
    cand_info, base_info = resolve(cfg.candidate, "candidate"), resolve(cfg.baseline, "baseline")
    gate_id = cfg.run_id or f"regress-{datetime.now().strftime('%Y%m%d-%H%M%S')}"
    parent = Path(cfg.runs) / gate_id
    verdict_path = Path(cfg.out) if cfg.out else parent / VERDICT_FILE
    if verdict_path.suffix != ".json":
        raise ConfigError(f"out={cfg.out!r}: the verdict file must end in .json")
    cand, base = Side("candidate", cand_info), Side("baseline", base_info)
    if not cfg.paired:  # two recorded runs whose episodes do not pair: bench.api.gate.unpaired
        doc, code, paths = run_unpaired(cfg, cand, base, forwarded, verdict_path, SCHEMA_ID, console)
        return Verdict(gate_id, doc, code, paths)

    # 1. settings both sides share: from the recorded baseline (or candidate) run, else from the keys given
    ref, shared, episodes = recorded_settings((base, cand), user_keys, lambda: DEFAULT_EPISODES)
    recorded = [s for s in (base, cand) if s.info["kind"] == "run"]
    forwarded = [f for f in forwarded if not f.startswith("episodes=")] + [f"episodes={episodes}"]

    # 2. live sides: prepared by bench.cli.run (checks everything, writes nothing yet)
    for side in (cand, base):
        if side.info["kind"] != "run":
            prepare_live(side, shared, forwarded, f"{gate_id}-{side.role}", parent)
            if ref is not None:
                check_same_settings(live_plan(side).config_dict(), ref.meta["config"], user_keys, ref.info["run_dir"])
    if len(recorded) == 2:
        a, b = (s.meta["config"] for s in recorded)
        diff = [k for k in SHARED_KEYS if a.get(k) != b.get(k)]
        if diff:
            raise ConfigError(
                f"candidate and baseline runs differ in {diff[0]} ({a.get(diff[0])!r} vs "
                f"{b.get(diff[0])!r}): paired episodes need the same settings"
                + ("; paired=false compares the two runs unpaired" if diff[0] == "seed" else "")
            )
    live = [s for s in (cand, base) if s.live]
    plans = [live_plan(s) for s in live]
    any_cfg = plans[0].config if plans else None
    metric = any_cfg.metric if any_cfg else recorded[0].meta["config"].get("metric", "success_once")
    seed = any_cfg.seed if any_cfg else int(recorded[0].meta["config"].get("seed", 0))
    suite_desc = plans[0].suite.describe() if plans else recorded[0].meta["suite"]
    specs = [(s.role, SuiteSpec.of(live_plan(s).suite.describe(), provenance.package_versions())) for s in live] + [
        (s.role, SuiteSpec.of(s.meta["suite"], s.meta.get("provenance", {}).get("packages"))) for s in recorded
    ]
    for role, spec in specs[1:]:
        why = specs[0][1].differs(spec)
        if why and not cfg.allow_spec_change:
            raise ConfigError(
                f"{role} and {specs[0][0]} ran different suite specs ({why}): their episodes do not pair "
                "(allow_spec_change=true compares them anyway)"
            )
    for side in recorded:
        if side.meta["suite"].get("version") != suite_desc.get("version") or side.meta["suite"].get(
            "name"
        ) != suite_desc.get("name"):
            raise ConfigError(
                f"{side.role} run {side.info['run_dir']} is suite {side.meta['suite'].get('name')} "
                f"v{side.meta['suite'].get('version')}, the comparison is {suite_desc.get('name')} "
                f"v{suite_desc.get('version')}: episodes of different suite versions do not pair"
            )
    # a live side runs only the episodes the recorded side has (nothing to pair otherwise)
    wanted = None
    if recorded:
        wanted = {r.job_id for r in recorded[0].records}
    for side in live:
        side.wanted = wanted if wanted is not None else {j.job_id for j in live_plan(side).jobs}
        if not any(j.job_id in side.wanted for j in live_plan(side).jobs):
            raise ConfigError("the recorded run has no episode of the selected cells; nothing to pair")

    # 3. checks of this gate (before anything is written), provenance, identical checkpoints
    metric = require_binary(metric)
    if ref is not None:
        check_sides_pairable(ref, [s for s in (cand, base) if s is not ref])
    paths = outputs.output_paths(verdict_path)
    check_outputs(paths, input_paths([cand, base]))
    planned = sorted(cells_of_jobs(plans[0].jobs, live[0].wanted) if live else cells_of_records(recorded[0].records))
    prov = {s.role: side_provenance(s) for s in (cand, base)}
    shas = [(prov[r] or {}).get("sha256") for r in ("candidate", "baseline")]
    schedule = sequential.looks_schedule(episodes, cfg.batch) if live else [episodes]
    design = sequential.Design(cfg.margin, cfg.alpha, cfg.cell_alpha, tuple(schedule), tuple(planned))
    base_doc = {
        "schema": SCHEMA_ID,
        "margin": cfg.margin,
        "alpha": cfg.alpha,
        "cell_alpha": cfg.cell_alpha,
        "metric": metric,
        "strict": cfg.strict,
        "suite": {"name": suite_desc.get("name"), "version": suite_desc.get("version")},
        "seed": seed,
        "episodes_max": episodes,
        "schedule": schedule,
        "rule": sequential.rule(design, metric),
    }
    if shas[0] is not None and shas[0] == shas[1]:
        note = (
            f"candidate and baseline are the same checkpoint (sha256 {shas[0]}): identical policies cannot "
            "regress; no episode was run"
        )
        doc = {
            **base_doc,
            "verdict": "no_regression",
            "exit_code": 0,
            "identical": True,
            "note": note,
            "stopped_early": False,
            "candidate": describe_side(cand, prov["candidate"]),
            "baseline": describe_side(base, prov["baseline"]),
            "looks": [],
            "cells": [],
            "splits": [],
            "regressed": [],
            "planned_cells": [sequential.cell_id(k)[5:] + f" ({k[4]})" for k in planned],
            "errors": {"candidate": 0, "baseline": 0, "both": 0},
            "unpaired": 0,
            "wall_s": 0.0,
        }
        outputs.write(doc, paths, console)
        return Verdict(gate_id, doc, 0, paths)

    # 4. looks
    n_boot = sequential.n_boot_needed(design, int(any_cfg.n_boot if any_cfg else 2000))
    workers = plans[0].workers if plans else 1  # workers=, computed once by `plan`
    for side in live:
        side.meta, _ = start(live_plan(side), workers)
    console.print(
        f"regress {gate_id}: candidate {cand.info['spec']} vs baseline {base.info['spec']} "
        f"(reused: {', '.join(s.role for s in recorded) or 'none'}); {len(planned)} cells; looks at "
        f"{schedule} episodes per cell; alpha {cfg.alpha} ({cfg.cell_alpha:g} to the per-cell tests)"
    )
    t0 = time.time()
    looks: list[dict[str, Any]] = []
    paired: dict[str, Any] = {"cells": {}, "errors": {"candidate": 0, "baseline": 0, "both": 0}, "unpaired": 0}
    counts: dict[sequential.CellKey, sequential.Pairs] = {}
    for k, n_eps in enumerate(schedule):
        for side in live:
            run_look(side, n_eps, workers)
        paired = pair_records(cand.records, base.records, max_episode=n_eps)
        counts = cell_counts(paired["cells"], metric)
        rng = np.random.default_rng([int(seed), 6007, k])
        look = {"look": k + 1, "episodes_per_cell": n_eps, **sequential.evaluate_look(counts, design, k, rng, n_boot)}
        looks.append(look)
        console.print(outputs.look_line(look, len(schedule)), soft_wrap=True)
        sides = {"candidate": cand.records, "baseline": base.records}
        empty, dead = unmeasured(sides, planned, n_eps)
        if look["decision"] != "continue" or dead:  # a side that completed nothing will not start now
            break
    verdict, code = sequential.decide(looks, cfg.strict)
    if empty:  # a cell compared against nothing: exit 3, whatever the statistics said
        verdict, code = "nothing_measured", NothingMeasured.exit_code
    for side in live:
        finish(live_plan(side), side.meta, workers)  # summary.json of each live run, for the leaderboard/report

    last = looks[-1]
    tests = {t["id"]: t for t in last.get("tests", [])}
    doc = {
        **base_doc,
        "verdict": verdict,
        "exit_code": code,
        "identical": False,
        "note": f"nothing measured: {empty}" if empty else None,
        "stopped_early": len(looks) < len(schedule),
        "candidate": describe_side(cand, prov["candidate"]),
        "baseline": describe_side(base, prov["baseline"]),
        "looks": looks,
        "cells": sequential.cell_rows(counts, last),
        "splits": sequential.split_rows(counts, last),
        "regressed": [sequential.regressed_entry(tests[h]) for h in sorted(last.get("regressed", []), key=_kind_order)],
        "errors": paired["errors"],
        "unpaired": paired["unpaired"],
        "wall_s": round(time.time() - t0, 2),
    }
    outputs.write(doc, paths, console)
    return Verdict(gate_id, doc, code, paths, empty or None)


def _kind_order(test_id: str) -> tuple[int, str]:
    return ("cell split pooled iqm".split().index(test_id.split(":")[0]), test_id)  # cells first: what users act on


def regress_budget(cfg: RegressConfig, run_keys: Sequence[str] = ()) -> str:
    """`bench regress plan=true`: the budget table (episodes per cell for `cfg.power` to flag a drop of `cfg.drop`
    from `cfg.rate`); runs and writes nothing.

    `cfg.cells == 0` counts the cells (x perturbation conditions) that the `bench run` keys `run_keys` (suite,
    robots, tasks, envs, splits, perturb.*, as `key=value` strings) select.
    """
    check_regress(cfg)
    forwarded = list(run_keys)
    design = sequential.Design(cfg.margin, cfg.alpha, cfg.cell_alpha)
    episodes = episodes_of({config_mod.top_key(f): f for f in forwarded}, DEFAULT_EPISODES)
    b = power.Budget(cfg.power, cfg.rate, cfg.drop, cfg.cells, cfg.batch, design, episodes)
    if b.episodes < 1:
        raise ConfigError(f"episodes={b.episodes}: must be >= 1")
    if b.drop <= b.design.margin:
        raise ConfigError(
            f"drop={b.drop}: must exceed margin={b.design.margin} (a drop within the margin is tolerated)"
        )
    if b.drop > b.rate:
        raise ConfigError(f"drop={b.drop} exceeds rate={b.rate}: the candidate's success rate would be negative")
    splits, source = None, ""
    if not b.n_cells:
        rc = config_from_argv(forwarded)
        suite = load_suite(rc.suite, **rc.suite_options)
        conditions = axes.conditions_from_config(rc.perturb)
        cells = select_cells(suite, rc)
        if not cells:
            raise ConfigError("the selection (robots/tasks/envs/splits) leaves no cell")
        splits = [c.split for c in cells for _ in conditions]
        b = dataclasses.replace(b, n_cells=len(splits))
        source = f" (suite {rc.suite}: {len(cells)} cells x {len(conditions)} condition(s))"
    text: str = power.plan_text(b, splits, source)
    return text

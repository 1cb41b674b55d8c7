"""`bench regress`: the CI regression gate — does the candidate transfer worse than the baseline?

Both policies run the same suite cells with the same episode seeds
(`bench.suite.episode_seed`), so every candidate episode has a baseline twin that
started from the same initial state; outcomes are compared pair by pair. A
baseline given as a recorded run directory is not re-run: its episodes are reused
and the candidate runs with that run's settings.

Rule (drop = baseline − candidate success; the statistics are in `bench.gate`):
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
training metadata) and, beside it, JUnit XML and a Markdown summary (`bench.gate_outputs`).
`plan=true` prints the episodes per cell a power target needs (`bench.gate_power`). See
docs/ci-gate.md.

Exit codes: 0 no regression (or inconclusive, not strict), 1 regression, 2 bad input.
"""

from __future__ import annotations

import json
import os
import time
from collections import defaultdict
from dataclasses import dataclass, fields
from datetime import datetime
from pathlib import Path
from typing import Any, Optional

import numpy as np

from bench import config as config_mod
from bench import gate
from bench.errors import ConfigError, DataError, did_you_mean
from bench.gate_inputs import cells_of_jobs, cells_of_records, check_outputs, check_pairable, load_recorded, resolve
from bench.runner import LocalExecutor

SCHEMA_ID = "bench.regress/2"
VERDICT_FILE = "verdict.json"
DEFAULT_EPISODES = 20
# run keys that must be equal for candidate and baseline (they decide which episodes are played)
SHARED_KEYS = (
    "suite",
    "seed",
    "horizon",
    "timeout",
    "robots",
    "tasks",
    "envs",
    "splits",
    "metric",
    "perturb",
    "env_id",
    "n_boot",
    "confidence",
    "allow_split_violation",
)
FORBIDDEN_KEYS = {"policy": "candidate=/baseline=", "checkpoint": "candidate=/baseline=", "record": None}
BINARY_METRICS = ("success_once", "success_at_end")


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
    out: Optional[str] = None  # verdict JSON (X.junit.xml, X.md beside it); default RUNS/RUN_ID/verdict.json
    runs: str = "runs"  # parent folder of the gate's run directories
    run_id: Optional[str] = None  # gate folder name; default regress-<timestamp>
    plan: bool = False  # print the episodes per cell needed for `power` and exit (runs nothing)
    power: float = 0.8  # plan: target chance to flag the drop below
    drop: float = 0.6  # plan: the drop to detect (one cell falls from rate to rate - drop)
    rate: float = 0.9  # plan: baseline success rate of the cell(s) that drop
    cells: int = 0  # plan: number of cells; 0 = those the suite/robots/tasks/envs/perturb keys select


def help_text() -> str:
    return config_mod.command_help(
        "usage: bench regress candidate=X baseline=Y [key=value ...]\n"
        "       bench regress plan=true [cells=N] [power=0.8 drop=0.6 rate=0.9] [margin= alpha= batch= episodes=]",
        "CI regression gate: runs candidate and baseline on the same suite cells with the same episode\n"
        "seeds, pairs outcomes by (cell, episode), and fails when the candidate is confidently worse by\n"
        "more than `margin`: pooled over all pairs, in the IQM across cells, in a split, or in any one cell\n"
        "(one-sided paired tests, weighted Holm across them, alpha spent over the looks). Episodes run in\n"
        "batches and stop once the verdict is certain. A baseline run directory is reused (the candidate\n"
        "runs with its settings; different cells, horizon or seeds are refused). Identical checkpoints\n"
        "(same sha256) are not simulated.",
        RegressConfig,
        notes=(
            "  (and the `bench run` keys suite, episodes (default 20), seed, workers, horizon, timeout, robots,\n"
            "   tasks, envs, splits, metric, n_boot, confidence, perturb.*, the suite's own keys; bench run --help)\n\n"
            "exit: 0 no regression (inconclusive passes unless strict=true), 1 regression, 2 bad input.\n"
            "writes: RUNS/RUN_ID/RUN_ID-candidate/ (and -baseline/ unless reused) run dirs, the verdict JSON\n"
            "(schema bench.regress/2: verdict, regressed cells with drops and bounds, looks, checkpoint sha256,\n"
            "size and training metadata), and beside it X.junit.xml (one test case per cell) and X.md (a\n"
            "Markdown summary for a CI step summary). plan=true prints a budget table and writes nothing."
        ),
        examples=[
            "bench regress candidate=ckpt/new.safetensors baseline=ckpt/old.safetensors robots=[Panda,UR5e]",
            "bench regress candidate=ckpt/new.safetensors baseline=results/runs/<run_id> out=gate/verdict.json",
            "bench regress candidate=random baseline=scripted episodes=4 batch=2",
            "bench regress plan=true suite=held_out_robots power=0.9 drop=0.6 rate=0.9",
        ],
    )


def _override(key: str, value: Any) -> str:
    return f"{key}={json.dumps(value)}"  # JSON is valid YAML flow, which the override grammar parses


def _split_overrides(argv: list[str]) -> tuple[RegressConfig, list[str], dict[str, str]]:
    """Own keys -> RegressConfig; `bench run` keys (the runner's and the suite's) forwarded verbatim."""
    from bench import registry
    from bench.protocols import Suite, option_keys
    from bench.run_config import RUNNER_KEYS, RunConfig

    positional, overrides = config_mod.split_args(argv)
    if positional:
        raise ConfigError(
            f"unexpected argument {positional[0]!r}; bench regress takes key=value only (see bench regress --help)"
        )
    own_names = {f.name for f in fields(RegressConfig)}
    suite = config_mod.build(RunConfig, [o for o in overrides if config_mod.top_key(o) == "suite"]).suite
    suite_cls: type[Suite] = registry.suite_class(suite)
    run_names = set(RUNNER_KEYS) | set(option_keys(suite_cls.Options))
    own, forwarded, by_key = [], [], {}
    for item in overrides:
        key = item.split("=", 1)[0]
        top = key.split(".")[0]
        if top in own_names:
            own.append(item)
        elif top in FORBIDDEN_KEYS:
            hint = f"; use {FORBIDDEN_KEYS[top]}" if FORBIDDEN_KEYS[top] else ""
            raise ConfigError(f"key {top!r} is not valid for bench regress{hint}")
        elif top in run_names:
            forwarded.append(item)
            by_key[top] = item
        else:
            valid = sorted(own_names | (run_names - set(FORBIDDEN_KEYS) - {"out", "run_id"}))
            raise ConfigError(f"unknown key {key!r}; valid keys: {', '.join(valid)}.{did_you_mean(top, valid)}")
    cfg: RegressConfig = config_mod.build(RegressConfig, own)
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
    return cfg, forwarded, by_key


def parse_args(argv: list[str]) -> tuple[RegressConfig, list[str], dict[str, str]]:
    """Every key of a `bench regress` command line checked (names, types, ranges); nothing is run or read.

    Returns the gate's own config, the `bench run` overrides it forwards, and those by key.
    The forwarded keys are typed by the runner's and the suite's configs (bench.api).
    """
    from bench import api

    cfg, forwarded, by_key = _split_overrides(argv)
    api.config_from_argv(forwarded)
    return cfg, forwarded, by_key


# -- pairing and statistics ----------------------------------------------------------------------
def _key(r) -> tuple:
    return (r.task, r.robot, r.env, r.condition, r.episode)


def pair_records(candidate: list, baseline: list, max_episode: int | None = None) -> dict[str, Any]:
    """Pair records by (cell, condition, episode); check they started from the same state.

    An errored or timed-out episode counts as a failure of its side (a candidate that crashes the
    simulator has regressed); pairs where both sides errored are left out.

    Returns cells {(task, robot, env, condition, split): [(baseline record, candidate record)]},
    the count of unpaired episodes and of errored episodes per side.

    Raises:
        DataError: paired episodes with different seeds or initial states (the runs are not comparable).
    """
    from bench.records import dedupe

    cand = {_key(r): r for r in dedupe(candidate) if max_episode is None or r.episode < max_episode}
    base = {_key(r): r for r in dedupe(baseline) if max_episode is None or r.episode < max_episode}
    cells: dict[tuple, list[tuple]] = defaultdict(list)
    errors = {"candidate": 0, "baseline": 0, "both": 0}
    unpaired = 0
    for k in sorted(set(cand) | set(base)):
        c, b = cand.get(k), base.get(k)
        if c is None or b is None:
            unpaired += 1
            continue
        where = f"{k[0]}/{k[1]}/{k[2]} {k[3]} episode {k[4]}"
        if c.seed != b.seed:
            raise DataError(f"{where}: seeds differ (candidate {c.seed}, baseline {b.seed}); runs are not paired")
        if c.init_state_hash and b.init_state_hash and c.init_state_hash != b.init_state_hash:
            raise DataError(
                f"{where}: initial states differ (init_state_hash {c.init_state_hash} vs "
                f"{b.init_state_hash}); the runs are not paired (other simulator/package versions?)"
            )
        if c.error is not None and b.error is not None:
            errors["both"] += 1
            continue
        errors["candidate"] += c.error is not None
        errors["baseline"] += b.error is not None
        cells[(k[0], k[1], k[2], k[3], c.split)].append((b, c))  # an errored side has success False
    return {"cells": dict(cells), "errors": errors, "unpaired": unpaired}


def cell_counts(cells: dict[tuple, list[tuple]], metric: str) -> dict[gate.CellKey, gate.Pairs]:
    """Paired (baseline, candidate) records per cell -> counts of the four outcome pairs in `metric`."""
    return {
        k: gate.pairs_of([bool(getattr(b, metric)) for b, _ in prs], [bool(getattr(c, metric)) for _, c in prs])
        for k, prs in cells.items()
    }


# -- running -----------------------------------------------------------------------------------
class _Side:
    """One side of the comparison: a live run (prepared by bench.run) or recorded episodes."""

    def __init__(self, role: str, info: dict[str, Any]):
        self.role, self.info = role, info
        self.p: Any = None  # a bench.api.Plan for a live side
        self.meta: dict[str, Any] = {}  # run metadata: loaded for a recorded side, from start() for a live one
        self.ctx = None
        self.records: list = []
        self.wanted: set[str] = set()  # job ids a live side runs (those the recorded side has)

    @property
    def live(self) -> bool:
        return self.p is not None

    def describe(self) -> dict[str, Any]:
        meta = self.meta or {}
        pol = meta.get("policy", {})
        run_dir = self.p.run_dir if self.p is not None else self.info.get("run_dir")
        return {
            "spec": self.info["spec"],
            "kind": self.info["kind"],
            "policy": pol.get("name"),
            "checkpoint": pol.get("checkpoint"),
            "checkpoint_sha256": pol.get("checkpoint_sha256"),
            "run_id": meta.get("run_id"),
            "run_dir": str(run_dir) if run_dir else None,
            "reused": not self.live,
        }


def _prepare_live(side: _Side, shared: list[str], forwarded: list[str], run_id: str, parent: Path) -> None:
    from bench import api

    given = {config_mod.top_key(f) for f in forwarded}  # a key the user gave wins; the settings check names it
    argv = [
        *(o for o in shared if config_mod.top_key(o) not in given),
        *forwarded,
        f"policy={side.info['policy']}",
        f"out={parent}",
        f"run_id={run_id}",
    ]
    if side.info.get("checkpoint"):
        argv.append(f"checkpoint={side.info['checkpoint']}")
    side.p = api.plan(api.config_from_argv(argv))


def _run_look(side: _Side, n_episodes: int, workers: int, console) -> None:
    from bench import api

    wanted = side.wanted
    result = api.run(
        side.p,
        only=lambda j: j.episode < n_episodes and j.job_id in wanted,
        summarize=False,
        executor=LocalExecutor(workers),
    )
    side.records = result.records


def _check_same_settings(
    cand_cfg: dict[str, Any], base_config: dict[str, Any], user_keys: dict[str, str], base_dir: Path
) -> None:
    mine = {k: cand_cfg.get(k) for k in SHARED_KEYS}
    for k in (k for k in SHARED_KEYS if k in base_config):  # keys an older run.json lacks are not compared
        if mine.get(k) != base_config.get(k):
            given = f" (you gave {user_keys[k]})" if k in user_keys else ""
            raise ConfigError(
                f"{k}={mine.get(k)!r} differs from the baseline run {base_dir} ({k}="
                f"{base_config.get(k)!r}){given}: paired episodes need the same settings"
            )


# -- checks before anything runs -----------------------------------------------------------------
def _check_pairable(ref: _Side, others: list[_Side]) -> None:
    """The recorded `ref` run holds the cells and seeds the other side plays (else ConfigError naming it)."""
    for side in others:
        cells = cells_of_jobs(side.p.jobs) if side.live else cells_of_records(side.records)
        seeds = {j.job_id: j.seed for j in side.p.jobs} if side.live else {r.job_id: r.seed for r in side.records}
        check_pairable(ref.records, f"the {ref.role} run {ref.info['run_dir']}", side.role, cells, seeds, side.live)


def _input_paths(sides: list[_Side]) -> list[tuple[Path, str]]:
    """Files and folders the gate reads, which no output may overwrite or lie inside."""
    inputs: list[tuple[Path, str]] = []
    for side in sides:
        if side.info["kind"] == "run":
            inputs.append((Path(side.info["run_dir"]).resolve(), f"the {side.role} run directory"))
        elif side.info.get("checkpoint"):
            ck = Path(side.info["checkpoint"]).resolve()
            inputs += [(ck, f"the {side.role} checkpoint"), (ck.with_suffix(".json"), f"the {side.role} spec")]
    return inputs


def _checkpoint_of(side: _Side) -> tuple[str | None, str | None]:
    """(checkpoint path, sha256) of a side's policy: from the live plan, or as its run recorded it."""
    if side.live:
        return side.p.identity.checkpoint, side.p.identity.checkpoint_sha256
    pol = (side.meta or {}).get("policy", {})
    return pol.get("checkpoint"), pol.get("checkpoint_sha256")


def _describe(side: _Side, provenance: dict[str, Any] | None) -> dict[str, Any]:
    d = side.describe()
    if d["policy"] is None:
        d["policy"] = side.p.config.policy if side.live else side.info.get("policy")
    path, sha = _checkpoint_of(side)
    d["checkpoint"], d["checkpoint_sha256"] = d["checkpoint"] or path, d["checkpoint_sha256"] or sha
    return {**d, "provenance": provenance}


@dataclass(frozen=True)
class _Episodes:
    """Parses the forwarded `episodes=` value (typed like bench run's)."""

    episodes: int = DEFAULT_EPISODES


def _episodes(user_keys: dict[str, str], default: int) -> int:
    return int(config_mod.build(_Episodes, [user_keys["episodes"]]).episodes) if "episodes" in user_keys else default


def main(argv: list[str]) -> int:
    if argv and argv[0] in ("-h", "--help"):
        print(help_text())
        return 0
    from rich.console import Console

    from bench import gate_outputs
    from bench.api import finish, start

    if not argv:
        print(help_text())
        return 2
    cfg, forwarded, user_keys = parse_args(argv)
    if cfg.plan:
        from bench import gate_power

        return gate_power.plan_command(
            cfg.power,
            cfg.rate,
            cfg.drop,
            cfg.cells,
            cfg.batch,
            gate.Design(cfg.margin, cfg.alpha, cfg.cell_alpha),
            _episodes(user_keys, DEFAULT_EPISODES),
            forwarded,
            unused=bool(cfg.candidate or cfg.baseline),
        )
    cand_info, base_info = resolve(cfg.candidate, "candidate"), resolve(cfg.baseline, "baseline")
    gate_id = cfg.run_id or f"regress-{datetime.now().strftime('%Y%m%d-%H%M%S')}"
    parent = Path(cfg.runs) / gate_id
    verdict_path = Path(cfg.out) if cfg.out else parent / VERDICT_FILE
    if verdict_path.suffix != ".json":
        raise ConfigError(f"out={cfg.out!r}: the verdict file must end in .json")
    cand, base = _Side("candidate", cand_info), _Side("baseline", base_info)

    # 1. settings both sides share: from the recorded baseline (or candidate) run, else from the keys given
    recorded = [s for s in (base, cand) if s.info["kind"] == "run"]
    shared: list[str] = []
    for side in recorded:
        side.records, side.meta = load_recorded(side.info["run_dir"], side.role)
    ref = recorded[0] if recorded else None
    if ref is not None:
        rc = ref.meta["config"]
        shared = [_override(k, rc[k]) for k in SHARED_KEYS if rc.get(k) is not None]
        max_eps = int(rc.get("episodes", 0)) or max(r.episode for r in ref.records) + 1
        episodes = (
            int(config_mod.build(_Episodes, [user_keys["episodes"]]).episodes) if "episodes" in user_keys else max_eps
        )
        if episodes > max_eps:
            raise ConfigError(
                f"episodes={episodes}: the recorded {ref.role} run {ref.info['run_dir']} has only {max_eps} per cell"
            )
    else:
        episodes = (
            int(config_mod.build(_Episodes, [user_keys["episodes"]]).episodes)
            if "episodes" in user_keys
            else DEFAULT_EPISODES
        )
    if episodes < 1:
        raise ConfigError(f"episodes={episodes}: must be >= 1")
    forwarded = [f for f in forwarded if not f.startswith("episodes=")] + [f"episodes={episodes}"]

    # 2. live sides: prepared by bench.run (checks everything, writes nothing yet)
    for side in (cand, base):
        if side.info["kind"] != "run":
            _prepare_live(side, shared, forwarded, f"{gate_id}-{side.role}", parent)
            if ref is not None:
                _check_same_settings(side.p.config_dict(), ref.meta["config"], user_keys, ref.info["run_dir"])
    if len(recorded) == 2:
        a, b = (s.meta["config"] for s in recorded)
        diff = [k for k in SHARED_KEYS if a.get(k) != b.get(k)]
        if diff:
            raise ConfigError(
                f"candidate and baseline runs differ in {diff[0]} ({a.get(diff[0])!r} vs "
                f"{b.get(diff[0])!r}): paired episodes need the same settings"
            )
    live = [s for s in (cand, base) if s.live]
    any_cfg = live[0].p.config if live else None
    metric = any_cfg.metric if any_cfg else recorded[0].meta["config"].get("metric", "success_once")
    seed = any_cfg.seed if any_cfg else int(recorded[0].meta["config"].get("seed", 0))
    suite_desc = live[0].p.suite.describe() if live else recorded[0].meta["suite"]
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
        side.wanted = wanted if wanted is not None else {j.job_id for j in side.p.jobs}
        if not any(j.job_id in side.wanted for j in side.p.jobs):
            raise ConfigError("the recorded run has no episode of the selected cells; nothing to pair")

    # 3. checks of this gate (before anything is written), provenance, identical checkpoints
    if metric not in BINARY_METRICS:
        raise ConfigError(f"metric={metric!r}: the gate compares success; valid: {', '.join(BINARY_METRICS)}")
    if ref is not None:
        _check_pairable(ref, [s for s in (cand, base) if s is not ref])
    paths = gate_outputs.output_paths(verdict_path)
    check_outputs(paths, _input_paths([cand, base]))
    planned = sorted(cells_of_jobs(live[0].p.jobs, live[0].wanted) if live else cells_of_records(recorded[0].records))
    prov = {s.role: _provenance(s) for s in (cand, base)}
    shas = [(prov[r] or {}).get("sha256") for r in ("candidate", "baseline")]
    schedule = gate.looks_schedule(episodes, cfg.batch) if live else [episodes]
    design = gate.Design(cfg.margin, cfg.alpha, cfg.cell_alpha, tuple(schedule), tuple(planned))
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
        "rule": gate.rule(design, metric),
    }
    console = Console(stderr=True)
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
            "candidate": _describe(cand, prov["candidate"]),
            "baseline": _describe(base, prov["baseline"]),
            "looks": [],
            "cells": [],
            "splits": [],
            "regressed": [],
            "planned_cells": [gate.cell_id(k)[5:] + f" ({k[4]})" for k in planned],
            "errors": {"candidate": 0, "baseline": 0, "both": 0},
            "unpaired": 0,
            "wall_s": 0.0,
        }
        gate_outputs.write(doc, paths, console)
        return 0

    # 4. looks
    n_boot = gate.n_boot_needed(design, int(any_cfg.n_boot if any_cfg else 2000))
    workers = 1
    if live:
        assert any_cfg is not None, "a live side has its run config"
        workers = any_cfg.workers or os.cpu_count() or 1
        for side in live:
            side.meta, side.ctx = start(side.p, workers)
    console.print(
        f"regress {gate_id}: candidate {cand.info['spec']} vs baseline {base.info['spec']} "
        f"(reused: {', '.join(s.role for s in recorded) or 'none'}); {len(planned)} cells; looks at "
        f"{schedule} episodes per cell; alpha {cfg.alpha} ({cfg.cell_alpha:g} to the per-cell tests)"
    )
    t0 = time.time()
    looks: list[dict[str, Any]] = []
    paired: dict[str, Any] = {"cells": {}, "errors": {"candidate": 0, "baseline": 0, "both": 0}, "unpaired": 0}
    counts: dict[gate.CellKey, gate.Pairs] = {}
    for k, n_eps in enumerate(schedule):
        for side in live:
            _run_look(side, n_eps, workers, console)
        paired = pair_records(cand.records, base.records, max_episode=n_eps)
        counts = cell_counts(paired["cells"], metric)
        rng = np.random.default_rng([int(seed), 6007, k])
        look = {"look": k + 1, "episodes_per_cell": n_eps, **gate.evaluate_look(counts, design, k, rng, n_boot)}
        looks.append(look)
        console.print(gate_outputs.look_line(look, len(schedule)), soft_wrap=True)
        if look["decision"] != "continue":
            break
    verdict, code = gate.decide(looks, cfg.strict)
    for side in live:
        finish(side.p, side.meta, workers)  # summary.json of each live run, for the leaderboard/report

    last = looks[-1]
    tests = {t["id"]: t for t in last.get("tests", [])}
    doc = {
        **base_doc,
        "verdict": verdict,
        "exit_code": code,
        "identical": False,
        "note": None,
        "stopped_early": len(looks) < len(schedule),
        "candidate": _describe(cand, prov["candidate"]),
        "baseline": _describe(base, prov["baseline"]),
        "looks": looks,
        "cells": gate.cell_rows(counts, last),
        "splits": gate.split_rows(counts, last),
        "regressed": [gate.regressed_entry(tests[h]) for h in sorted(last.get("regressed", []), key=_kind_order)],
        "errors": paired["errors"],
        "unpaired": paired["unpaired"],
        "wall_s": round(time.time() - t0, 2),
    }
    gate_outputs.write(doc, paths, console)
    return code


def _kind_order(test_id: str) -> tuple[int, str]:
    return ("cell split pooled iqm".split().index(test_id.split(":")[0]), test_id)  # cells first: what users act on


def _provenance(side: _Side) -> dict[str, Any] | None:
    from bench.provenance import checkpoint_provenance

    path, sha = _checkpoint_of(side)
    if not path:
        return None
    return checkpoint_provenance(path, sha, hash_file=not side.live)  # a live side's plan has just hashed it

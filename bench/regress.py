"""`bench regress`: the CI regression gate — does the candidate transfer worse than the baseline?

Both policies run the same suite cells with the same episode seeds
(`bench.suite.episode_seed`), so every candidate episode has a baseline twin that
started from the same initial state; outcomes are compared pair by pair. A
baseline given as a recorded run directory is not re-run: its episodes are reused
and the candidate runs with that run's settings.

Rule (drop = baseline − candidate success, pooled over all pairs; and the drop in
the IQM of per-cell success rates across cells):
    regression     if a one-sided lower bound of the drop exceeds `margin`
                   (we are confident the candidate lost more than `margin`);
    no regression  if the upper bounds of both drops are below `margin`
                   (we are confident it did not);
    inconclusive   otherwise, once the episode budget is spent: passes with a
                   warning (exit 0), or fails with `strict=true`.
The pooled drop uses Tango's score bound for paired binary outcomes (honest with
few discordant pairs); the IQM drop a paired bootstrap. Episodes run in batches
(`batch` per cell) and the rule is applied after each batch, stopping as soon as
the verdict is certain. Multiple looks and the two statistics are accounted for
with Bonferroni: each bound is taken at level 1 − alpha / (2 · looks), so the
chance of a false alarm when the true drop is at most `margin` is at most `alpha`
(0.05: at most 1 gate in 20 cries wolf). Identical deterministic policies give
identical paired outcomes and never fail. An errored or timed-out episode counts as a
failure of its side (a candidate that crashes the simulator has regressed); pairs where
both sides errored are left out. See docs/ci-gate.md.

Exit codes: 0 no regression (or inconclusive, not strict), 1 regression, 2 bad input.
"""
from __future__ import annotations

import json
import math
import os
import time
from collections import defaultdict
from dataclasses import dataclass, fields
from datetime import datetime
from pathlib import Path
from typing import Any, Optional

import numpy as np

from bench import config as config_mod
from bench.errors import ConfigError, DataError, did_you_mean
from bench.runner import LocalExecutor

SCHEMA_ID = "bench.regress/1"
VERDICT_FILE = "verdict.json"
DEFAULT_EPISODES = 20
# run keys that must be equal for candidate and baseline (they decide which episodes are played)
SHARED_KEYS = ("suite", "seed", "horizon", "timeout", "robots", "tasks", "envs", "splits", "metric", "perturb",
               "env_id", "n_boot", "confidence", "allow_split_violation")
FORBIDDEN_KEYS = {"policy": "candidate=/baseline=", "checkpoint": "candidate=/baseline=", "record": None}
CHECKPOINT_SUFFIXES = (".safetensors", ".pt")
IQM_MIN_PAIRS = 10  # pairs per cell before the IQM bootstrap bound may decide (see evaluate)


@dataclass(frozen=True)
class RegressConfig:
    """Keys of `bench regress` besides the `bench run` keys it forwards."""

    candidate: Optional[str] = None   # checkpoint file (.safetensors/.pt), registered policy name, or a recorded run dir
    baseline: Optional[str] = None    # checkpoint file, policy name, or a recorded run dir (its episodes are reused)
    margin: float = 0.05              # tolerated drop in success (baseline - candidate) before it is a regression
    alpha: float = 0.05               # false-alarm rate when the true drop <= margin (over all looks and statistics)
    batch: int = 5                    # episodes per cell between looks (early stopping); 0 = one look at the end
    strict: bool = False              # inconclusive (budget spent, nothing certain) fails with exit 1
    out: Optional[str] = None         # verdict JSON file; default RUNS/RUN_ID/verdict.json
    runs: str = "runs"                # parent folder of the gate's run directories
    run_id: Optional[str] = None      # gate folder name; default regress-<timestamp>


def help_text() -> str:
    keys = config_mod.key_help(RegressConfig)
    return (
        "usage: bench regress candidate=X baseline=Y [key=value ...]\n\n"
        "CI regression gate: runs candidate and baseline on the same suite cells with the same episode\n"
        "seeds, pairs outcomes by (cell, episode), and fails when the candidate is confidently worse by\n"
        "more than `margin` (one-sided bound of the paired drop in success and in the IQM across cells,\n"
        "Bonferroni over looks). Episodes run in batches and stop once the verdict is certain.\n"
        "A baseline run directory is reused (the candidate runs with its settings).\n\n"
        f"keys:\n{keys}\n"
        "  (and the `bench run` keys suite, episodes (default 20), seed, workers, horizon, timeout, robots,\n"
        "   tasks, envs, splits, metric, n_boot, confidence, perturb.*, env_id; see bench run --help)\n\n"
        "exit: 0 no regression (inconclusive passes unless strict=true), 1 regression, 2 bad input.\n"
        "writes: RUNS/RUN_ID/RUN_ID-candidate/ (and -baseline/ unless reused) run dirs, and the verdict JSON.\n\n"
        "examples:\n"
        "  bench regress candidate=ckpt/new.safetensors baseline=ckpt/old.safetensors robots=[Panda,UR5e]\n"
        "  bench regress candidate=ckpt/new.safetensors baseline=results/runs/<run_id> out=verdict.json\n"
        "  bench regress candidate=random baseline=scripted episodes=4 batch=2\n"
    )


# -- inputs ------------------------------------------------------------------------------------
def resolve(value: Optional[str], role: str) -> dict[str, Any]:
    """Classify a candidate/baseline argument: a recorded run dir, a checkpoint file, or a policy name."""
    from bench import registry

    if not value:
        raise ConfigError(f"{role}= is required: a checkpoint file, a registered policy name or a run directory")
    path = Path(value)
    if path.is_file() and path.name in ("run.json", "summary.json", "episodes.jsonl"):
        path = path.parent  # a file of a run directory: the run directory
    if path.is_dir():
        if not (path / "run.json").is_file():
            raise ConfigError(f"{role}={value!r}: directory has no run.json; give a run directory written by bench run")
        return {"kind": "run", "spec": value, "run_dir": path}
    if path.suffix in CHECKPOINT_SUFFIXES or path.is_file():
        if not path.is_file():
            raise ConfigError(f"{role}={value!r}: no such file")
        if path.suffix not in CHECKPOINT_SUFFIXES:
            raise DataError(f"{role}={value!r}: not a checkpoint ({', '.join(CHECKPOINT_SUFFIXES)}) nor a run "
                            "directory's run.json/summary.json/episodes.jsonl")
        return {"kind": "checkpoint", "spec": value, "policy": "checkpoint", "checkpoint": str(path)}
    if "/" in value or value.endswith(".json"):
        raise ConfigError(f"{role}={value!r}: no such file or directory")
    registry.load_policy(value)  # RegistryError with the valid names
    return {"kind": "policy", "spec": value, "policy": value, "checkpoint": None}


def load_recorded(run_dir: Path, role: str):
    """Records and run.json of a recorded run; foreign or corrupt files are a one-line DataError."""
    from bench.summary import load_run

    records, meta = load_run(run_dir)
    for key in ("run_id", "suite", "policy", "config"):
        if not isinstance(meta, dict) or key not in meta:
            raise DataError(f"{run_dir / 'run.json'}: not a bench run.json (missing field {key!r})")
    if not records:
        raise DataError(f"{role}={str(run_dir)!r}: episodes.jsonl has no records")
    return records, meta


def _override(key: str, value: Any) -> str:
    return f"{key}={json.dumps(value)}"  # JSON is valid YAML flow, which the override grammar parses


def _split_overrides(argv: list[str]) -> tuple[RegressConfig, list[str], dict[str, str]]:
    """Own keys -> RegressConfig; `bench run` keys (the runner's and the suite's) forwarded verbatim."""
    from bench import registry
    from bench.api import RUNNER_KEYS, RunConfig
    from bench.protocols import option_keys

    positional, overrides = config_mod.split_args(argv)
    if positional:
        raise ConfigError(f"unexpected argument {positional[0]!r}; bench regress takes key=value only "
                          "(see bench regress --help)")
    own_names = {f.name for f in fields(RegressConfig)}
    suite = config_mod.build(RunConfig, [o for o in overrides if config_mod.top_key(o) == "suite"]).suite
    run_names = set(RUNNER_KEYS) | set(option_keys(registry.suite_class(suite).Options))
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
    if not 0 <= cfg.margin < 1:
        raise ConfigError(f"margin={cfg.margin}: must be in [0, 1)")
    if not 0 < cfg.alpha < 0.5:
        raise ConfigError(f"alpha={cfg.alpha}: must be in (0, 0.5)")
    if cfg.batch < 0:
        raise ConfigError(f"batch={cfg.batch}: must be >= 0 (0 = a single look)")
    if cfg.run_id is not None and (not cfg.run_id or "/" in cfg.run_id or cfg.run_id.startswith(".")):
        raise ConfigError(f"run_id={cfg.run_id!r}: must be a plain folder name")
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
            raise DataError(f"{where}: initial states differ (init_state_hash {c.init_state_hash} vs "
                            f"{b.init_state_hash}); the runs are not paired (other simulator/package versions?)")
        if c.error is not None and b.error is not None:
            errors["both"] += 1
            continue
        errors["candidate"] += c.error is not None
        errors["baseline"] += b.error is not None
        cells[(k[0], k[1], k[2], k[3], c.split)].append((b, c))  # an errored side has success False
    return {"cells": dict(cells), "errors": errors, "unpaired": unpaired}


def evaluate(cells: dict[tuple, list[tuple]], metric: str, margin: float, level: float,
             rng: np.random.Generator, n_boot: int) -> dict[str, Any]:
    """Drops (baseline − candidate) with one-sided bounds at `level`, and the decision for one look.

    Args:
        cells: {(task, robot, env, condition, split): [(baseline record, candidate record), ...]}.
        level: one-sided confidence of each bound (already corrected for looks and statistics).
    """
    from bench import scoring

    base_cells = [np.array([getattr(b, metric) for b, _ in prs], float) for prs in cells.values()]
    cand_cells = [np.array([getattr(c, metric) for _, c in prs], float) for prs in cells.values()]
    n = int(sum(len(x) for x in base_cells))
    if n == 0:
        return {"pairs": 0, "decision": "continue", "reason": "no paired episodes without errors"}
    bo = int(sum(((x == 1) & (y == 0)).sum() for x, y in zip(base_cells, cand_cells)))
    co = int(sum(((x == 0) & (y == 1)).sum() for x, y in zip(base_cells, cand_cells)))
    mean = {"value": (bo - co) / n, "lcb": scoring.paired_score_bound(bo, co, n, level, "lower"),
            "ucb": scoring.paired_score_bound(bo, co, n, level, "upper")}
    point, samples = scoring.paired_stat_samples(base_cells, cand_cells, rng, "iqm", n_boot)
    iqm = {"value": point, "lcb": scoring.one_sided_lower(samples, level),
           "ucb": scoring.one_sided_upper(samples, level)}
    # a percentile bootstrap of a few 0/1 pairs claims certainty it does not have (2 lost pairs -> LCB 1.0):
    # the IQM bound takes part in the decision only once every cell has IQM_MIN_PAIRS pairs
    iqm_used = min(len(x) for x in base_cells) >= IQM_MIN_PAIRS
    if mean["lcb"] > margin or (iqm_used and iqm["lcb"] > margin):
        decision = "regression"
    elif mean["ucb"] < margin and (not iqm_used or iqm["ucb"] < margin):
        decision = "no_regression"
    else:
        decision = "continue"
    rnd = lambda d: {k: round(float(v), 6) for k, v in d.items()}  # noqa: E731
    return {"pairs": n, "baseline_only": bo, "candidate_only": co, "mean": rnd(mean),
            "iqm": {**rnd(iqm), "used": iqm_used}, "decision": decision}


def cell_table(cells: dict[tuple, list[tuple]], metric: str, level: float) -> list[dict[str, Any]]:
    """Per-cell rates and drop with a one-sided Tango lower bound (informative; not the verdict)."""
    from bench import scoring

    out = []
    for (task, robot, env, cond, split), prs in cells.items():
        b = np.array([getattr(x, metric) for x, _ in prs], bool)
        c = np.array([getattr(y, metric) for _, y in prs], bool)
        bo, co, n = int((b & ~c).sum()), int((~b & c).sum()), len(prs)
        out.append({"task": task, "robot": robot, "env": env, "condition": cond, "split": split, "pairs": n,
                    "baseline": round(float(b.mean()), 6), "candidate": round(float(c.mean()), 6),
                    "drop": round((bo - co) / n, 6), "baseline_only": bo, "candidate_only": co,
                    "drop_lcb": round(scoring.paired_score_bound(bo, co, n, level, "lower"), 6)})
    return out


def looks_schedule(episodes: int, batch: int) -> list[int]:
    """Episodes per cell at each look: batch, 2·batch, ..., episodes (one look when batch is 0)."""
    if batch <= 0 or batch >= episodes:
        return [episodes]
    return sorted({min(k * batch, episodes) for k in range(1, math.ceil(episodes / batch) + 1)})


def decide(looks: list[dict[str, Any]], strict: bool) -> tuple[str, int]:
    """Final verdict and exit code from the looks taken so far (the last one decides)."""
    last = looks[-1]["decision"] if looks else "continue"
    if last == "regression":
        return "regression", 1
    if last == "no_regression":
        return "no_regression", 0
    return "inconclusive", 1 if strict else 0


# -- running -----------------------------------------------------------------------------------
class _Side:
    """One side of the comparison: a live run (prepared by bench.run) or recorded episodes."""

    def __init__(self, role: str, info: dict[str, Any]):
        self.role, self.info = role, info
        self.p: Any = None  # a bench.api.Plan for a live side
        self.meta: dict[str, Any] | None = None
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
        return {"spec": self.info["spec"], "kind": self.info["kind"], "policy": pol.get("name"),
                "checkpoint": pol.get("checkpoint"), "checkpoint_sha256": pol.get("checkpoint_sha256"),
                "run_id": meta.get("run_id"), "run_dir": str(run_dir) if run_dir else None,
                "reused": not self.live}


def _prepare_live(side: _Side, shared: list[str], forwarded: list[str], run_id: str, parent: Path) -> None:
    from bench import api

    given = {config_mod.top_key(f) for f in forwarded}  # a key the user gave wins; the settings check names it
    argv = [*(o for o in shared if config_mod.top_key(o) not in given), *forwarded, f"policy={side.info['policy']}",
            f"out={parent}", f"run_id={run_id}"]
    if side.info.get("checkpoint"):
        argv.append(f"checkpoint={side.info['checkpoint']}")
    side.p = api.plan(api.config_from_argv(argv))


def _run_look(side: _Side, n_episodes: int, workers: int, console) -> None:
    from bench import api

    wanted = side.wanted
    result = api.run(side.p, only=lambda j: j.episode < n_episodes and j.job_id in wanted, summarize=False,
                     executor=LocalExecutor(workers))
    side.records = result.records


def _check_same_settings(cand_cfg: dict[str, Any], base_config: dict[str, Any], user_keys: dict[str, str],
                         base_dir: Path) -> None:
    mine = {k: cand_cfg.get(k) for k in SHARED_KEYS}
    for k in (k for k in SHARED_KEYS if k in base_config):  # keys an older run.json lacks are not compared
        if mine.get(k) != base_config.get(k):
            given = f" (you gave {user_keys[k]})" if k in user_keys else ""
            raise ConfigError(f"{k}={mine.get(k)!r} differs from the baseline run {base_dir} ({k}="
                              f"{base_config.get(k)!r}){given}: paired episodes need the same settings")


@dataclass(frozen=True)
class _Episodes:
    """Parses the forwarded `episodes=` value (typed like bench run's)."""

    episodes: int = DEFAULT_EPISODES


def main(argv: list[str]) -> int:
    if argv and argv[0] in ("-h", "--help"):
        print(help_text())
        return 0
    from rich.console import Console

    from bench.api import finish, start
    from bench.io import write_atomic
    from bench.schema import validate

    if not argv:
        print(help_text())
        return 2
    cfg, forwarded, user_keys = _split_overrides(argv)
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
        episodes = int(config_mod.build(_Episodes, [user_keys["episodes"]]).episodes) if "episodes" in user_keys \
            else max_eps
        if episodes > max_eps:
            raise ConfigError(f"episodes={episodes}: the recorded {ref.role} run {ref.info['run_dir']} has only "
                              f"{max_eps} per cell")
    else:
        episodes = int(config_mod.build(_Episodes, [user_keys["episodes"]]).episodes) if "episodes" in user_keys \
            else DEFAULT_EPISODES
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
            raise ConfigError(f"candidate and baseline runs differ in {diff[0]} ({a.get(diff[0])!r} vs "
                              f"{b.get(diff[0])!r}): paired episodes need the same settings")
    live = [s for s in (cand, base) if s.live]
    any_cfg = live[0].p.config if live else None
    metric = any_cfg.metric if any_cfg else recorded[0].meta["config"].get("metric", "success_once")
    seed = any_cfg.seed if any_cfg else int(recorded[0].meta["config"].get("seed", 0))
    suite_desc = live[0].p.suite.describe() if live else recorded[0].meta["suite"]
    for side in recorded:
        if side.meta["suite"].get("version") != suite_desc.get("version") or \
                side.meta["suite"].get("name") != suite_desc.get("name"):
            raise ConfigError(f"{side.role} run {side.info['run_dir']} is suite {side.meta['suite'].get('name')} "
                              f"v{side.meta['suite'].get('version')}, the comparison is {suite_desc.get('name')} "
                              f"v{suite_desc.get('version')}: episodes of different suite versions do not pair")
    # a live side runs only the episodes the recorded side has (nothing to pair otherwise)
    wanted = None
    if recorded:
        wanted = {r.job_id for r in recorded[0].records}
    for side in live:
        side.wanted = wanted if wanted is not None else {j.job_id for j in side.p.jobs}
        if not any(j.job_id in side.wanted for j in side.p.jobs):
            raise ConfigError("the recorded run has no episode of the selected cells; nothing to pair")

    schedule = looks_schedule(episodes, cfg.batch) if live else [episodes]
    level = 1.0 - cfg.alpha / (2 * len(schedule))
    n_boot = max(int(any_cfg.n_boot if any_cfg else 2000), math.ceil(50 / (1.0 - level)))
    console = Console(stderr=True)
    workers = 1
    if live:
        workers = any_cfg.workers or os.cpu_count() or 1
        for side in live:
            side.meta, side.ctx = start(side.p, workers)
    label = {"candidate": cand.info["spec"], "baseline": base.info["spec"]}
    console.print(f"regress {gate_id}: candidate {label['candidate']} vs baseline {label['baseline']} "
                  f"(reused: {', '.join(s.role for s in recorded) or 'none'}); looks at {schedule} episodes per "
                  f"cell; each bound at {level:.4f}")

    # 3. looks
    t0 = time.time()
    looks: list[dict[str, Any]] = []
    paired: dict[str, Any] = {"cells": {}, "errors": {"candidate": 0, "baseline": 0, "both": 0}, "unpaired": 0}
    for k, n_eps in enumerate(schedule):
        for side in live:
            _run_look(side, n_eps, workers, console)
        paired = pair_records(cand.records, base.records, max_episode=n_eps)
        rng = np.random.default_rng([int(seed), 6007, k])
        look = {"look": k + 1, "episodes_per_cell": n_eps,
                **evaluate(paired["cells"], metric, cfg.margin, level, rng, n_boot)}
        looks.append(look)
        console.print(_look_line(look, len(schedule)))
        if look["decision"] != "continue":
            break
    verdict, code = decide(looks, cfg.strict)
    for side in live:
        finish(side.p, side.meta, workers)  # summary.json of each live run, for the leaderboard/report

    doc = {
        "schema": SCHEMA_ID,
        "verdict": verdict,
        "exit_code": code,
        "rule": (f"regression if a one-sided {level:.4f} lower bound of the drop (baseline - candidate) in "
                 f"{metric} or in its IQM across cells exceeds margin {cfg.margin}; no regression if both upper "
                 f"bounds are below it; Bonferroni over {len(schedule)} look(s) x 2 statistics at alpha {cfg.alpha}"),
        "margin": cfg.margin, "alpha": cfg.alpha, "level": round(level, 6), "metric": metric, "strict": cfg.strict,
        "suite": {"name": suite_desc.get("name"), "version": suite_desc.get("version")},
        "seed": seed, "episodes_max": episodes, "schedule": schedule,
        "stopped_early": len(looks) < len(schedule),
        "candidate": cand.describe(), "baseline": base.describe(),
        "looks": looks,
        "cells": cell_table(paired["cells"], metric, level) if paired["cells"] else [],
        "errors": paired["errors"], "unpaired": paired["unpaired"],
        "wall_s": round(time.time() - t0, 2),
    }
    validate(doc, "verdict")
    write_atomic(verdict_path, doc)
    render(doc)
    console.print(f"verdict: {verdict_path}")
    return code


def _look_line(look: dict[str, Any], n_looks: int) -> str:
    if "mean" not in look:
        return f"look {look['look']}/{n_looks}: {look.get('reason', 'no pairs')}"
    m, q = look["mean"], look["iqm"]
    return (f"look {look['look']}/{n_looks} ({look['episodes_per_cell']} ep/cell, {look['pairs']} pairs): "
            f"drop {m['value']:+.3f} [{m['lcb']:+.3f}, {m['ucb']:+.3f}], IQM drop {q['value']:+.3f} "
            f"[{q['lcb']:+.3f}, {q['ucb']:+.3f}] -> {look['decision']}")


def render(doc: dict[str, Any], console=None) -> None:
    """The per-cell table, the looks and the verdict, in the terminal."""
    from rich.console import Console
    from rich.table import Table

    console = console or Console(width=None if Console().is_terminal else 120)
    t = Table(title=f"regress · {doc['suite']['name']} v{doc['suite']['version']} · metric {doc['metric']} · "
                    f"candidate {doc['candidate']['spec']} vs baseline {doc['baseline']['spec']}",
              title_justify="left")
    for col in ("task", "robot", "condition", "split", "pairs", "baseline", "candidate", "drop",
                f"drop LCB ({doc['level'] * 100:.1f}%)", "lost / gained"):
        t.add_column(col, justify="left" if col in ("task", "robot", "condition", "split") else "right")
    for c in doc["cells"]:
        style = "red" if c["drop_lcb"] > doc["margin"] else None
        t.add_row(c["task"], c["robot"], c["condition"], c["split"], str(c["pairs"]), f"{c['baseline'] * 100:.0f}%",
                  f"{c['candidate'] * 100:.0f}%", f"{c['drop']:+.2f}", f"{c['drop_lcb']:+.2f}",
                  f"{c['baseline_only']} / {c['candidate_only']}", style=style)
    console.print(t)
    lk = Table(title=f"looks (margin {doc['margin']}, alpha {doc['alpha']}, one-sided bounds at {doc['level']:.4f})",
               title_justify="left")
    for col in ("look", "ep/cell", "pairs", "drop [LCB, UCB]", "IQM drop [LCB, UCB]", "decision"):
        lk.add_column(col)
    for look in doc["looks"]:
        if "mean" not in look:
            lk.add_row(str(look["look"]), str(look["episodes_per_cell"]), "0", "n/a", "n/a", look["decision"])
            continue
        m, q = look["mean"], look["iqm"]
        lk.add_row(str(look["look"]), str(look["episodes_per_cell"]), str(look["pairs"]),
                   f"{m['value']:+.3f} [{m['lcb']:+.3f}, {m['ucb']:+.3f}]",
                   f"{q['value']:+.3f} [{q['lcb']:+.3f}, {q['ucb']:+.3f}]", look["decision"])
    console.print(lk)
    colour = {"regression": "bold red", "no_regression": "bold green", "inconclusive": "bold yellow"}[doc["verdict"]]
    extra = ""
    if doc["verdict"] == "inconclusive":
        extra = (" — the budget could not certify either way; " +
                 ("strict=true: failing" if doc["strict"] else "passing (strict=true would fail); raise episodes="))
    err = doc["errors"]
    if any(err.values()):
        extra += (f" (errored episodes, counted as failures: candidate {err['candidate']}, baseline "
                  f"{err['baseline']}; {err['both']} pair(s) where both errored left out)")
    console.print(f"[{colour}]{doc['verdict'].upper().replace('_', ' ')}[/] (exit {doc['exit_code']}){extra}")

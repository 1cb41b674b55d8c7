"""The coverage sweep: does wider training coverage buy held-out success? (an experiment on bench.api)

Records scripted demonstrations (`bench.api.run` with `record=`), trains the behaviour-cloning
baseline (`baselines.bc`) on nested training sets of increasing coverage — 1, 2, 3 seen robots at a
fixed demonstration budget; domain-randomisation widths on one perturbation axis — evaluates every
checkpoint on the suite's cells with the same seeds, and reports held-out success and the transfer
gap against coverage with intervals, the fitted slope with a paired bootstrap interval
(`bench.scoring.trend`), a plot, and the surrogate-data question (adding mismatched data to a fixed
in-domain set). Coverage metrics are `bench.cli.coverage`'s; rollouts, records and intervals are the
harness's. Everything under `workdir` is reused on a rerun.

    python -m baselines.coverage_sweep out=results/coverage workdir=/tmp/coverage-sweep
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import sys
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from baselines.coverage_sweep_config import (
    SweepConfig,
    check_sweep,
    dr_condition_names,
    per_robot,
    surrogate_condition,
    sweep_help,
)
from baselines.coverage_sweep_stats import (  # noqa: F401  (render_sweep, plot_sweep: public here too)
    coverage_summary,
    per_seed_cells,
    plot_sweep,
    render_sweep,
    series_summary,
    training_summary,
)
from bench.api import ConfigError, DataError, RunConfig
from bench.api.stats import SeriesBootstrap, initial_states_from_suite


def _run(cfg: RunConfig) -> None:
    from bench import api

    api.run(cfg, progress=True)


def _record_demos(cfg: SweepConfig, work: Path, log) -> list[Path]:
    """Record the demonstrations every part needs; returns the dataset folders in selection order.

    `base`: every robot of `order`, `min(per-robot need)` nominal episodes each, plus the DR
    conditions (one run: the same seeds under every condition). `extra_R`: for a robot that
    needs more nominal episodes (or the surrogate target, for the strongly perturbed
    condition), one more run with seed demo_seed+1, so no episode is recorded twice.
    """
    parts = set(cfg.parts)
    k_max = len(cfg.order)
    need: dict[str, int] = {}
    for k in range(1, k_max + 1) if "robots" in parts else [k_max]:
        for r in cfg.order[:k]:
            need[r] = max(need.get(r, 0), per_robot(cfg, k))
    if "surrogate" in parts:
        need[cfg.surrogate_target] = max(need[cfg.surrogate_target], cfg.surrogate_in_domain)
        others = [r for r in cfg.order if r != cfg.surrogate_target]
        for r in others:
            need[r] = max(need[r], cfg.surrogate_episodes // len(others))
    base_n = per_robot(cfg, k_max)
    dr = "dr" in parts and bool(cfg.dr_axis)
    common: dict[str, Any] = dict(
        suite=cfg.suite, policy="scripted", workers=cfg.workers, horizon=cfg.horizon, out=str(work / "runs")
    )
    sources = []
    perturb = {cfg.dr_axis: [t for _, _, t in dr_condition_names(cfg)]} if dr else {}
    base = RunConfig(
        **common, robots=list(cfg.order), episodes=base_n, seed=cfg.demo_seed, run_id="demos-base", perturb=perturb
    )
    sources.append(_recorded(work / "demos" / "base", base, log))
    for r in cfg.order:
        extra = max(0, need.get(r, 0) - base_n)
        strong = "surrogate" in parts and r == cfg.surrogate_target
        n = max(extra, cfg.surrogate_episodes if strong else 0)
        if n == 0:
            continue
        perturb = {}
        if strong:
            axis, level = cfg.surrogate_perturb.split("=", 1)
            perturb = {axis.strip(): [surrogate_condition(cfg.surrogate_perturb).level]}
        run = RunConfig(
            **common, robots=[r], episodes=n, seed=cfg.demo_seed + 1, run_id=f"demos-extra-{r}", perturb=perturb
        )
        sources.append(_recorded(work / "demos" / f"extra-{r}", run, log))
    return sources


def _recorded(dataset: Path, run: RunConfig, log) -> Path:
    """Run `run` with record=DATASET unless the dataset is already there (recorded with the same config)."""
    stamp = dataset.parent / f"{dataset.name}.run.json"
    wanted = json.loads(json.dumps(dataclasses.asdict(run)))
    if (dataset / "meta" / "info.json").is_file() and stamp.is_file() and json.loads(stamp.read_text()) == wanted:
        log(f"demonstrations: reusing {dataset}")
        return dataset
    if dataset.exists() and any(dataset.iterdir()):
        raise ConfigError(f"workdir: {dataset} exists but was recorded with other arguments; give a new workdir")
    log(f"demonstrations: {run.suite} {run.policy} robots={run.robots} episodes={run.episodes} -> {dataset}")
    _run(dataclasses.replace(run, record=str(dataset)))
    dataset.parent.mkdir(parents=True, exist_ok=True)
    stamp.write_text(json.dumps(wanted))
    return dataset


def _select(sources: Sequence[Path], want: Sequence[tuple[str, str, int]], successful_only: bool = True):
    """Demos of the first n episodes of (robot, condition) for each (robot, condition, n), across sources in order.

    `successful_only` applies to nominal demonstrations only. Under a perturbation every episode
    is kept: the expert's command is still the label of the state it saw, and keeping only the
    draws where it succeeded would truncate the randomisation range towards its easy end (under
    gain~U(0.7,1.3) the Lift expert succeeds in about 60-90% of the episodes, depending on the arm).
    """
    from baselines.bc import Demos, load_demos

    out: Demos | None = None
    for robot, cond, n in want:
        d = load_demos(
            [str(s) for s in sources],
            robots=[robot],
            conditions=[cond],
            max_episodes=n,
            successful_only=successful_only and cond == "nominal",
        )
        if len(d.episodes) < n:
            raise DataError(
                f"sweep: only {len(d.episodes)} usable {robot} demonstrations under {cond}, {n} wanted "
                f"(successful_only={successful_only})"
            )
        out = d if out is None else out + d
    assert out is not None
    return out


def _demo_stats(sources: Sequence[Path]) -> dict[str, Any]:
    """Expert success per robot and condition in the recorded demonstrations (from the episode meta)."""
    from bench.api.datasets import read_dataset

    counts: dict[str, list[int]] = {}
    for src in sources:
        for ep in read_dataset(src).episodes:
            m = ep.meta or {}
            c = counts.setdefault(f"{m.get('robot')}|{m.get('condition', 'nominal')}", [0, 0])
            c[0] += int(bool(m.get("success_once")))
            c[1] += 1
    return {k: {"successes": v[0], "episodes": v[1]} for k, v in sorted(counts.items())}


def _fingerprint(demos, args) -> str:
    h = hashlib.sha256()
    h.update(json.dumps([[e["source"], e["index"]] for e in demos.episodes]).encode())
    h.update(json.dumps(dataclasses.asdict(args), sort_keys=True).encode())
    return h.hexdigest()[:16]


def _bc_args(cfg: SweepConfig, seed: int):
    from baselines.bc import Args

    return Args(data=[], seed=int(seed), **cfg.bc)


def _train(name: str, demos, cfg: SweepConfig, seed: int, work: Path, log) -> tuple[Path, dict[str, Any]]:
    """Train (or reuse) the BC checkpoint of one training set and seed; returns (path, training info)."""
    from baselines.bc import train

    args = _bc_args(cfg, seed)
    path = work / "checkpoints" / name / "policy.safetensors"
    info_path = path.with_name("train.json")
    fp = _fingerprint(demos, args)
    if path.is_file() and info_path.is_file():
        info = json.loads(info_path.read_text())
        if info.get("fingerprint") == fp:
            log(f"checkpoint {name}: reusing {path}")
            return path, info
    args = dataclasses.replace(args, out=str(path))
    t0 = time.perf_counter()
    path, info = train(args, demos)
    info = {k: v for k, v in info.items() if k != "history"}
    info.update(
        fingerprint=fp,
        name=name,
        total_wall_s=round(time.perf_counter() - t0, 3),
        robots_episodes=dict(Counter(f"{e['robot']}|{e['condition']}" for e in demos.episodes)),
    )
    info_path.write_text(json.dumps(info, indent=2))
    log(f"checkpoint {name}: {info['episodes']} episodes, {info['frames']} frames, {info['train_wall_s']:.1f} s")
    return path, info


def _evaluate(
    name: str, ckpt: Path, cfg: SweepConfig, work: Path, episodes: int, robots: Sequence[str] | None, log
) -> dict[str, np.ndarray]:
    """The checkpoint on the suite's cells (or `robots`); cell key -> 0/1 outcomes by episode."""
    from bench.api.data import EPISODES, dedupe, read_records

    run_id = f"eval-{name}" + (f"-{'-'.join(robots)}-n{episodes}" if robots else "")
    run = RunConfig(
        suite=cfg.suite,
        policy="checkpoint",
        policy_options={"checkpoint": str(ckpt)},
        episodes=episodes,
        seed=cfg.eval_seed,
        workers=cfg.workers,
        horizon=cfg.horizon,
        out=str(work / "runs"),
        run_id=run_id,
        n_boot=cfg.n_boot,
        robots=list(robots) if robots else None,
    )
    run_dir = work / "runs" / run_id
    if (run_dir / "run.json").is_file():
        old = json.loads((run_dir / "run.json").read_text())
        if old.get("policy", {}).get("checkpoint_sha256") != _sha256(ckpt):
            raise ConfigError(f"workdir: {run_dir} evaluated another checkpoint; give a new workdir")
    log(f"evaluate {name}: checkpoint {ckpt} on {robots or 'every robot'}, {episodes} episodes per cell")
    _run(run)
    records = dedupe(read_records(run_dir / EPISODES))
    cells: dict[str, list] = {}
    for r in sorted(records, key=lambda r: r.episode):
        if r.error is None and r.condition == "nominal":
            cells.setdefault(f"{r.task}/{r.robot}/{r.env}", []).append(float(r.success_once))
    return {k: np.asarray(v) for k, v in cells.items()}


def _sha256(path: Path) -> str:
    from bench.api.data import sha256_file

    return sha256_file(Path(path))


def main(argv: list[str]) -> int:
    """`python -m baselines.coverage_sweep ...`: see `sweep_help()`."""
    if argv and argv[0] in ("-h", "--help"):
        print(sweep_help())
        return 0
    from rich.console import Console

    from bench.api.scripts import build_from_argv
    from bench.protocols import registry

    cfg: SweepConfig = build_from_argv(SweepConfig, argv, "python -m baselines.coverage_sweep")
    suite = registry.make_suite(cfg.suite)
    check_sweep(cfg, suite)
    console = Console(stderr=True)
    log = lambda msg: console.print(f"[bold]sweep[/] {msg}")  # noqa: E731
    work, out = Path(cfg.workdir), Path(cfg.out)
    t_start = time.perf_counter()
    doc = run_sweep(cfg, suite, work, log)
    doc["invocation_wall_s"] = round(time.perf_counter() - t_start, 1)  # reused artifacts cost nothing here
    from bench.api.data import write_atomic

    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "sweep.json", doc)
    plot_sweep(doc, out / "sweep.png")
    render_sweep(doc)
    log(f"wrote {out / 'sweep.json'} and {out / 'sweep.png'} ({doc['invocation_wall_s']:.0f} s)")
    return 0


def run_sweep(cfg: SweepConfig, suite, work: Path, log) -> dict[str, Any]:
    """Record, train, evaluate and score every part of the sweep; returns the sweep document."""
    from bench.api.sims import conditions_from_config
    from bench.protocols.suite import NOMINAL

    rng = np.random.default_rng([cfg.eval_seed, 4242])
    parts = set(cfg.parts)
    cells = suite.all_cells()
    unseen_keys = [c.key for c in cells if c.split == "unseen"]
    key_of = {c.robot: c.key for c in cells}
    sources = _record_demos(cfg, work, log)
    log("evaluation initial states: resetting the unseen cells' envs with the evaluation seeds")
    unseen_cells = [c for c in cells if c.split == "unseen"]
    states, groups = initial_states_from_suite(suite, unseen_cells, cfg.eval_seed, cfg.eval_episodes, cfg.horizon)
    doc: dict[str, Any] = {
        "schema": "bench.coverage-sweep/1",
        "suite": suite.describe(),
        "config": dataclasses.asdict(cfg),
        "demonstrations": [str(s) for s in sources],
        "expert_success": _demo_stats(sources),
        "metric": "success_once",
        "confidence": cfg.confidence,
        "seeds": list(cfg.seeds),
    }
    successful_only = bool(cfg.bc.get("successful_only", True))
    trained: dict[str, tuple[Path, dict]] = {}

    def model(name: str, want: list[tuple[str, str, int]]):
        """(demos, [(checkpoint, info) per training seed]) of one training set."""
        demos = _select(sources, want, successful_only)
        out = []
        for seed in cfg.seeds:
            key = f"{name}-s{seed}"
            if key not in trained:
                fp = _fingerprint(demos, _bc_args(cfg, seed))
                same = next((v for v in trained.values() if v[1]["fingerprint"] == fp), None)
                if same is not None:  # the same episodes and arguments train the same weights: reuse them
                    log(f"checkpoint {key}: same training set as {same[1]['name']}, reusing {same[0]}")
                trained[key] = same or _train(key, demos, cfg, seed, work, log)
            out.append(trained[key])
        return demos, out

    def evaluate(name: str, models, episodes: int, robots=None) -> list[dict[str, np.ndarray]]:
        return [
            _evaluate(f"{name}-s{seed}", ckpt, cfg, work, episodes, robots, log)
            for seed, (ckpt, _) in zip(cfg.seeds, models)
        ]

    def series(entries: list[dict], xlabel: str) -> dict[str, Any]:
        return series_summary(entries, xlabel, unseen_keys, rng, cfg)

    k_max = len(cfg.order)
    entries: dict[str, dict] = {}
    if "robots" in parts or "dr" in parts:
        for k in range(1, k_max + 1) if "robots" in parts else [k_max]:
            robots = cfg.order[:k]
            name = f"robots{k}"
            demos, models = model(name, [(r, "nominal", per_robot(cfg, k)) for r in robots])
            entries[name] = {
                "name": name,
                "x": float(k),
                "train_keys": [key_of[r] for r in robots],
                "outcomes": evaluate(name, models, cfg.eval_episodes),
                "training": training_summary([m[1] for m in models]),
                "coverage": coverage_summary(demos, cells, suite.manifest, [NOMINAL], states, groups),
            }
        if "robots" in parts:
            doc["robots"] = series(
                [entries[f"robots{k}"] for k in range(1, k_max + 1)], "number of seen robots in the training set"
            )
    if "dr" in parts and cfg.dr_axis:
        n = per_robot(cfg, k_max)
        dr_conds = dr_condition_names(cfg)
        eval_conds = conditions_from_config({cfg.dr_axis: [t for _, _, t in dr_conds]})
        base = dict(entries[f"robots{k_max}"], x=0.0)
        demos0 = _select(sources, [(r, "nominal", n) for r in cfg.order], successful_only)
        base["coverage"] = coverage_summary(demos0, cells, suite.manifest, eval_conds, states, groups)
        dr_entries = [base]
        for w, cond, _ in dr_conds:
            name = f"dr-{cfg.dr_axis}-{w:g}"
            demos, models = model(name, [(r, cond, n) for r in cfg.order])
            dr_entries.append(
                {
                    "name": name,
                    "x": w,
                    "train_keys": [key_of[r] for r in cfg.order],
                    "outcomes": evaluate(name, models, cfg.eval_episodes),
                    "training": training_summary([m[1] for m in models]),
                    "coverage": coverage_summary(demos, cells, suite.manifest, eval_conds, states, groups),
                }
            )
        doc["dr"] = series(dr_entries, f"domain-randomisation width on {cfg.dr_axis} (uniform(1-w, 1+w))")
    if "surrogate" in parts:
        doc["surrogate"] = _surrogate(cfg, model, evaluate, key_of, rng)
    return doc


def _surrogate(cfg: SweepConfig, model, evaluate, key_of: dict, rng) -> dict[str, Any]:
    """In-domain alone vs + other robots' data vs + strongly perturbed simulator data, on the target robot."""
    target = cfg.surrogate_target
    others = [r for r in cfg.order if r != target]
    strong = surrogate_condition(cfg.surrogate_perturb)
    base = [(target, "nominal", cfg.surrogate_in_domain)]
    variants = {"in_domain": base}
    if others:
        per_other = cfg.surrogate_episodes // len(others)
        variants["plus_other_robots"] = base + [(r, "nominal", per_other) for r in others]
    variants["plus_perturbed_sim"] = base + [(target, strong.name, cfg.surrogate_episodes)]
    key = key_of[target]
    names, outcomes, trainings = list(variants), [], []
    for name in names:
        _, models = model(f"surrogate-{name}", variants[name])
        outcomes.append(evaluate(f"surrogate-{name}", models, cfg.surrogate_eval_episodes, [target]))
        trainings.append(training_summary([m[1] for m in models]))
    boot = SeriesBootstrap(outcomes, rng, cfg.n_boot, cfg.confidence)
    results: dict[str, Any] = {}
    base_v, base_r = boot.mean(0, [key])
    for k, name in enumerate(names):
        v, r = boot.mean(k, [key])
        results[name] = {
            "training": trainings[k],
            "success": boot.estimate(v, r),
            "cells": per_seed_cells(outcomes[k], cfg),
        }
        if k == 0:
            continue
        if v is None or base_v is None:
            d = {"value": None, "ci": None, "reason": "no completed episodes"}
        else:
            d = boot.estimate(v - base_v, r - base_r)
        a = np.concatenate([o.get(key, np.zeros(0)) for o in outcomes[k]])
        b = np.concatenate([o.get(key, np.zeros(0)) for o in outcomes[0]])
        if len(a) == len(b):  # episode pairs (same seed index and training-seed slot)
            d.update(gained=int(np.sum((a == 1) & (b == 0))), lost=int(np.sum((a == 0) & (b == 1))))
        ci = d.get("ci")
        d["verdict"] = (
            "helps" if ci and ci[0] > 0 else "hurts" if ci and ci[1] < 0 else "no detectable effect" if ci else "n/a"
        )
        results[name]["vs_in_domain"] = d
    return {
        "target": key,
        "in_domain_episodes": cfg.surrogate_in_domain,
        "surrogate_episodes": cfg.surrogate_episodes,
        "perturbed_condition": strong.name,
        "other_robots": others,
        "eval_episodes": cfg.surrogate_eval_episodes,
        "variants": results,
    }


if __name__ == "__main__":
    from bench.api.scripts import guarded  # bad input: one line, exit 2; never a traceback

    raise SystemExit(guarded(lambda: main(sys.argv[1:])))

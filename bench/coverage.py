"""Data coverage: how much of a suite's evaluation conditions a training dataset covers, and what it buys.

`bench coverage data=DIR suite=NAME` compares a LeRobot v3 training dataset (e.g. demonstrations
recorded with `bench run ... record=DIR`) with the cells and conditions a suite evaluates:

- **support**: which robots / tasks / envs (scenes) the data holds vs which are evaluated, per
  split, and whether the data contains anything the suite holds out (`unseen`);
- **state coverage**: for each evaluation initial state (the suite's envs reset with the run's
  episode seeds, or the first frames of a recorded evaluation run), the distance to the nearest
  training state, in units of the training data's per-dimension std, as an RMS over dimensions;
  an evaluation state counts as covered when that distance is within the reference radius, the
  `quantile` (0.95) of the same distance for the training episodes' own initial states to the
  *other* training episodes (leave one episode out). In-distribution evaluation states are then
  covered at about that rate; far-away ones are not;
- **parameter-range coverage** for each evaluated perturbation axis (`perturb.*`, the grammar of
  `bench run`): the fraction of the evaluated interval (nominal included) that the values
  recorded in the training episodes' `params` span, linear and (for positive scales) in log space.

`bench coverage sweep ...` measures what coverage buys: it records demonstrations with the
suite's scripted expert (`bench run ... record=`), trains the behaviour-cloning baseline
(`baselines.bc`) on nested training sets of increasing coverage (1, 2, 3 seen robots at a fixed
demonstration budget; domain-randomisation widths on one perturbation axis), evaluates every
checkpoint with `bench run policy=checkpoint`, and reports held-out success and the transfer gap
against coverage with intervals, the fitted slope with a paired bootstrap interval, a plot, and
the surrogate-data question (adding mismatched data to a fixed in-domain set). Rollouts, intervals
and records are `bench.run` / `bench.scoring`'s; nothing here steps a simulator except the
initial-state resets.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import time
import warnings
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from bench import scoring
from bench.errors import ConfigError, DataError, did_you_mean

AXES_OF_CELLS = (("robots", "robot"), ("tasks", "task"), ("envs", "env"))
MIN_SCALE = 1e-3  # floor of the per-dimension std used to normalise states (observation units)
# the level that means "unperturbed" on each axis (model axes are scales of nominal: 1)
NOMINAL_LEVEL = {"latency": 0.0, "action_noise": 0.0, "obs_noise": 0.0, "action_hold": 1.0}


# ============================================================================ metrics (pure)
def support(train_meta: Sequence[dict], cells: Sequence, manifest: dict | None = None) -> dict[str, Any]:
    """Robots / tasks / envs present in the training episodes vs evaluated in `cells`.

    Args:
        train_meta: per training episode, a dict with `robot`, `task`, `env` (dataset meta).
        cells: the evaluated `bench.suite.Cell`s.
        manifest: the suite's split manifest; values the data holds from its `unseen` lists
            are reported under `unseen_in_training` (held-out data leaked into training).
    """
    manifest = manifest or {}
    out: dict[str, Any] = {}
    for axis, attr in AXES_OF_CELLS:
        counts = Counter(str(m.get(attr)) for m in train_meta if m.get(attr) is not None)
        evaluated = sorted({getattr(c, attr) for c in cells})
        covered = [v for v in evaluated if v in counts]
        by_split = {}
        for split in sorted({c.split for c in cells}):
            ev = sorted({getattr(c, attr) for c in cells if c.split == split})
            cov = [v for v in ev if v in counts]
            by_split[split] = {"evaluated": ev, "covered": cov, "fraction": len(cov) / len(ev) if ev else None}
        out[axis] = {
            "evaluated": evaluated, "present": sorted(counts), "covered": covered,
            "missing": [v for v in evaluated if v not in counts],
            "fraction": len(covered) / len(evaluated) if evaluated else None,
            "episodes": dict(sorted(counts.items())), "by_split": by_split,
            "unseen_in_training": sorted(set(counts) & set(manifest.get(axis, {}).get("unseen", []))),
        }
    keys = Counter(f"{m.get('task')}/{m.get('robot')}/{m.get('env')}" for m in train_meta)
    ev_cells = [c.key for c in cells]
    out["cells"] = {"evaluated": len(ev_cells), "covered": sum(k in keys for k in ev_cells),
                    "fraction": sum(k in keys for k in ev_cells) / len(ev_cells) if ev_cells else None,
                    "missing": [k for k in ev_cells if k not in keys]}
    return out


def state_scale(train_states: np.ndarray, min_scale: float = MIN_SCALE) -> np.ndarray:
    """Per-dimension std of the training states, floored at `min_scale` (constant dims stay finite)."""
    return np.maximum(np.asarray(train_states, float).std(axis=0), min_scale)


def _distance_summary(d: np.ndarray, radius: float | None) -> dict[str, Any]:
    out: dict[str, Any] = {"n": int(len(d))}
    if not len(d):
        return {**out, "mean": None, "median": None, "max": None, "covered": None, "reason": "no states"}
    out.update(mean=round(float(d.mean()), 6), median=round(float(np.median(d)), 6), max=round(float(d.max()), 6))
    if radius is None:
        out.update(covered=None, reason="no reference radius (the training data has fewer than 2 episodes)")
    else:
        out["covered"] = round(float(np.mean(d <= radius)), 6)
    return out


def state_coverage(train_states: np.ndarray, train_episode: np.ndarray, eval_states: np.ndarray,
                   eval_groups: Sequence[str] | None = None, quantile: float = 0.95,
                   scale: np.ndarray | None = None) -> dict[str, Any]:
    """Distance from each evaluation state to its nearest training state, normalised, and coverage.

    Distance = RMS over dimensions of (eval - nearest train) / scale, scale = the training
    std per dimension (floored). The reference radius is the `quantile` of the same distance
    from each training episode's first state to the states of the *other* episodes; an
    evaluation state within it is "covered".

    Args:
        train_states: (N, D) every training frame.
        train_episode: (N,) episode id of each frame (its first frame is the episode's initial state).
        eval_states: (M, D) evaluation initial states.
        eval_groups: (M,) group label of each (e.g. cell key) for per-group summaries.
        quantile: level of the reference radius.
        scale: override the per-dimension scale (D,).
    """
    from scipy.spatial import cKDTree

    x = np.asarray(train_states, float)
    ep = np.asarray(train_episode)
    e = np.asarray(eval_states, float)
    if x.ndim != 2 or e.ndim != 2 or x.shape[1] != e.shape[1]:
        raise DataError(f"state coverage: training states {x.shape} and evaluation states {e.shape} differ in width")
    if len(x) == 0:
        raise DataError("state coverage: no training states")
    if len(ep) != len(x):
        raise DataError(f"state coverage: {len(ep)} episode ids for {len(x)} training states")
    s = state_scale(x) if scale is None else np.asarray(scale, float)
    dim = x.shape[1]
    tree = cKDTree(x / s)
    d_eval = tree.query(e / s, k=1)[0] / np.sqrt(dim) if len(e) else np.zeros(0)
    # leave-one-episode-out distances of the training initial states (first frame of each episode)
    _, first = np.unique(ep, return_index=True)
    radius = None
    ref = np.zeros(0)
    if len(first) >= 2:
        ref = np.full(len(first), np.inf)
        pending = np.arange(len(first))
        k = min(len(x), 64)
        while len(pending):
            dist, idx = tree.query(x[first[pending]] / s, k=k)
            dist, idx = dist.reshape(len(pending), -1), idx.reshape(len(pending), -1)
            other = ep[idx] != ep[first[pending]][:, None]
            found = other.any(axis=1)
            ref[pending[found]] = dist[found, other[found].argmax(axis=1)]
            pending = pending[~found]
            if k >= len(x):
                break
            k = min(len(x), k * 4)
        ref = ref / np.sqrt(dim)
        radius = float(np.quantile(ref, quantile))
    out: dict[str, Any] = {
        "metric": "RMS over dimensions of (eval - nearest training state) / training std",
        "dims": int(dim), "training_states": int(len(x)), "training_episodes": int(len(np.unique(ep))),
        "quantile": quantile, "reference_radius": None if radius is None else round(radius, 6),
        "reference": _distance_summary(ref, radius) if len(ref) else None,
        "overall": _distance_summary(d_eval, radius),
    }
    if eval_groups is not None:
        groups = np.asarray(list(eval_groups))
        if len(groups) != len(e):
            raise DataError(f"state coverage: {len(groups)} group labels for {len(e)} evaluation states")
        out["groups"] = {str(g): _distance_summary(d_eval[groups == g], radius) for g in dict.fromkeys(groups.tolist())}
    out["distances"] = [round(float(v), 6) for v in d_eval]
    return out


def _nominal_level(axis: str) -> float:
    return float(NOMINAL_LEVEL.get(axis, 1.0))


def _overlap(lo: float, hi: float, tlo: float, thi: float) -> float:
    if hi <= lo:
        return 1.0 if tlo <= lo <= thi else 0.0
    return max(0.0, min(hi, thi) - max(lo, tlo)) / (hi - lo)


def param_coverage(train_params: Sequence[dict], conditions: Sequence) -> dict[str, Any]:
    """Fraction of each evaluated perturbation range that the training episodes' values span.

    The evaluated interval of an axis runs over the nominal level, every grid level and every
    range [low, high] of its conditions. A training episode without a value for the axis ran
    at the nominal level. Coverage = |evaluated ∩ [min, max] of training values| / |evaluated|
    (a single evaluated value: 1 if inside the training span, else 0); `coverage_log` is the
    same on a log scale when every bound is positive (scales of nominal).

    Args:
        train_params: per training episode its `params` dict (e.g. {"gain": 1.07}) or {}.
        conditions: the evaluated `bench.suite.Condition`s (nominal is skipped).
    """
    by_axis: dict[str, list] = {}
    for c in conditions:
        if c.axis is not None:
            by_axis.setdefault(c.axis, []).append(c)
    out: dict[str, Any] = {}
    for axis, conds in by_axis.items():
        nominal = _nominal_level(axis)
        points = [nominal]
        for c in conds:
            points += [float(v) for v in c.level] if isinstance(c.level, (list, tuple)) else [float(c.level)]
        lo, hi = min(points), max(points)
        values = np.array([float((p or {}).get(axis, nominal)) for p in train_params], float)
        if not len(values):
            out[axis] = {"evaluated": [lo, hi], "training": None, "coverage": None, "reason": "no training episodes"}
            continue
        tlo, thi = float(values.min()), float(values.max())
        levels = sorted(set(points))
        entry = {
            "evaluated": [lo, hi], "nominal": nominal, "conditions": [c.name for c in conds],
            "training": [tlo, thi], "training_episodes_off_nominal": int(np.sum(values != nominal)),
            "coverage": round(_overlap(lo, hi, tlo, thi), 6),
            "levels_inside": round(float(np.mean([tlo <= v <= thi for v in levels])), 6),
        }
        if lo > 0 and tlo > 0:
            entry["coverage_log"] = round(_overlap(np.log(lo), np.log(hi), np.log(tlo), np.log(thi)), 6)
        out[axis] = entry
    return out


# ============================================================================ inputs
@dataclass
class TrainingData:
    """What the metrics need from a training dataset: every frame, its episode, episode metadata."""

    states: np.ndarray
    episode: np.ndarray
    meta: list[dict]
    obs_names: list[str]


def read_training(paths: Sequence[str | Path]) -> TrainingData:
    """Frames (`observation.state`) and per-episode meta of one or more LeRobot v3 datasets."""
    from bench.logs import read_dataset

    states, epi, meta = [], [], []
    names: list[str] | None = None
    for path in paths:
        if not Path(path).is_dir():
            raise ConfigError(f"data: {str(path)!r} is not a dataset folder")
        ds = read_dataset(path)
        if "observation.state" not in ds.features:
            raise DataError(f"{path}: feature 'observation.state' is missing; coverage compares observation states")
        n = list(ds.features["observation.state"].get("names") or [])
        if names is None:
            names = n
        elif n != names:
            raise DataError(f"{path}: observation.state names differ from {paths[0]}'s")
        for ep in ds.episodes:
            m = dict(ep.meta or {})
            if "task" not in m and ep.tasks:  # a dataset not written by bench: task string "Task/Robot/env"
                parts = ep.tasks[0].split("/")
                m.update(dict(zip(("task", "robot", "env"), parts)))
            states.append(np.asarray(ep.data["observation.state"], float))
            epi.append(np.full(len(states[-1]), len(meta)))
            meta.append(m)
    if not meta:
        raise DataError(f"data: {list(map(str, paths))} hold no episodes")
    return TrainingData(np.concatenate(states), np.concatenate(epi), meta, names or [])


def initial_states_from_suite(suite, cells: Sequence, seed: int, episodes: int, horizon: int = 0
                              ) -> tuple[np.ndarray, list[str]]:
    """The observation right after reset for each cell and episode seed of a run (`bench.suite.episode_seed`).

    Builds each cell's env once (robosuite: a few seconds) and resets it with the same seeds
    `bench run seed=SEED episodes=N` uses, under the nominal condition.
    """
    from bench.suite import episode_seed

    states, groups = [], []
    for cell in cells:
        env = suite.make_env(cell, horizon or suite.default_horizon)
        try:
            for i in range(episodes):
                states.append(np.asarray(env.reset(episode_seed(seed, i))["state"], float))
                groups.append(cell.key)
        finally:
            env.close()
    return np.asarray(states), groups


def initial_states_from_dataset(path: str | Path, cells: Sequence | None = None) -> tuple[np.ndarray, list[str]]:
    """First frame of each episode of a recorded evaluation run, labelled by cell key (only `cells` if given)."""
    from bench.logs import read_dataset

    ds = read_dataset(path)
    wanted = {c.key for c in cells} if cells is not None else None
    states, groups = [], []
    for ep in ds.episodes:
        m = ep.meta or {}
        # the task string is the cell key (bench.recording); the meta fields are the fallback
        key = ep.tasks[0] if ep.tasks else f"{m.get('task')}/{m.get('robot')}/{m.get('env')}"
        if wanted is not None and key not in wanted:
            continue
        states.append(np.asarray(ep.data["observation.state"][0], float))
        groups.append(key)
    if not states:
        raise DataError(f"eval_data={str(path)!r}: no episode of the evaluated cells "
                        f"({', '.join(sorted(wanted or []))})")
    return np.asarray(states), groups


def coverage_report(train: TrainingData, cells: Sequence, manifest: dict, conditions: Sequence,
                    eval_states: np.ndarray, eval_groups: Sequence[str], quantile: float = 0.95) -> dict[str, Any]:
    """All three metrics for one training set, plus per-split state coverage."""
    sc = state_coverage(train.states, train.episode, eval_states, eval_groups, quantile)
    split_of = {c.key: c.split for c in cells}
    d = np.asarray(sc["distances"])
    groups = np.asarray(list(eval_groups))
    radius = sc["reference_radius"]
    sc["splits"] = {s: _distance_summary(d[np.array([split_of.get(g) == s for g in groups], bool)], radius)
                    for s in sorted({c.split for c in cells})}
    return {
        "training": {"episodes": len(train.meta), "frames": int(len(train.states)),
                     "robots": sorted({str(m.get("robot")) for m in train.meta}),
                     "conditions": sorted({str(m.get("condition", "nominal")) for m in train.meta})},
        "support": support(train.meta, cells, manifest),
        "state": sc,
        "params": param_coverage([m.get("params") or {} for m in train.meta], conditions),
    }


# ============================================================================ bench coverage
@dataclass(frozen=True)
class CoverageConfig:
    """Keys of `bench coverage` (see `bench coverage --help`)."""

    data: list[str] = field(default_factory=list)  # training dataset folder(s) (LeRobot v3), e.g. data=demos/seen
    suite: str = "held_out_robots"          # the suite whose evaluation the data is compared with
    robots: Optional[list[str]] = None      # evaluated robots (default: every robot of the suite)
    tasks: Optional[list[str]] = None       # evaluated tasks
    envs: Optional[list[str]] = None        # evaluated environments/scenes
    splits: Optional[list[str]] = None      # evaluated splits: seen, unseen
    seed: int = 0                           # evaluation run seed: the initial states are its episode seeds'
    episodes: int = 10                      # evaluation episodes per cell (initial states per cell)
    horizon: int = 0                        # env horizon when building envs (0 = suite default)
    eval_data: Optional[str] = None         # recorded evaluation dataset: initial states = first frames (no env built)
    perturb: dict[str, Any] = field(default_factory=dict)  # evaluated perturbation axes, grammar of bench run
    quantile: float = 0.95                  # reference radius quantile (training initial states, leave-one-episode-out)
    out: Optional[str] = None               # write the JSON report here


def _list_arg(argv: list[str], key: str) -> list[str]:
    """Accept `key=DIR` as well as `key=[A,B]` for a list-valued key (wraps a bare value)."""
    out = []
    for a in argv:
        if a.startswith(f"{key}=") and not a[len(key) + 1:].lstrip().startswith("["):
            a = f"{key}=[{a[len(key) + 1:]}]"
        out.append(a)
    return out


def _help(schema: type, usage: str, intro: str, examples: str) -> str:
    from bench.config import key_help

    return f"{usage}\n\n{intro}\n\nkeys:\n{key_help(schema)}\n\nexamples:\n{examples}\n"


def help_text() -> str:
    return _help(
        CoverageConfig, "usage: bench coverage data=DIR [suite=NAME] [key=value ...]\n"
                        "       bench coverage sweep [key=value ...]   (bench coverage sweep --help)",
        "Coverage of a training dataset against a suite's evaluation: support (robots/tasks/envs present\n"
        "vs evaluated, per split), state coverage (distance from the evaluation initial states to the\n"
        "nearest training state in training-std units; covered = within the leave-one-episode-out\n"
        "reference radius of the training data itself), and parameter-range coverage of perturb.* axes.\n"
        "Prints a table; out=FILE writes the JSON.",
        "  bench coverage data=demos/seen suite=held_out_robots episodes=10 seed=1\n"
        "  bench coverage data=[demos/a,demos/b] splits=[unseen] out=coverage.json\n"
        "  bench coverage data=demos/dr perturb.gain=uniform(0.5,1.5) eval_data=runs/eval/dataset")


def _check_common(suite_name: str, quantile: float) -> Any:
    from bench import registry

    if not 0 < quantile < 1:
        raise ConfigError(f"quantile={quantile}: must be in (0, 1)")
    return registry.make_suite(suite_name)


def _eval_cells(suite, cfg) -> list:
    for s in cfg.splits or []:
        if s not in ("seen", "unseen"):
            raise ConfigError(f"splits: {s!r} is not a split; valid: seen, unseen")
    from bench.suite import select_cells

    cells = select_cells(suite, cfg)
    if not cells:
        raise ConfigError("the selection (robots/tasks/envs/splits) leaves no cell to evaluate")
    return cells


def main(argv: list[str]) -> int:
    """`bench coverage ...` and `bench coverage sweep ...`."""
    if argv and argv[0] == "sweep":
        return sweep_main(argv[1:])
    if argv and argv[0] in ("-h", "--help"):
        print(help_text())
        return 0
    from bench import config as config_mod
    from bench import perturb

    positional, overrides = config_mod.split_args(_list_arg(argv, "data"))
    if positional:
        raise ConfigError(f"unexpected argument {positional[0]!r}; valid: key=value, or the subcommand 'sweep'."
                          f"{did_you_mean(positional[0], ['sweep'])}")
    cfg: CoverageConfig = config_mod.build(CoverageConfig, overrides)
    if not cfg.data:
        raise ConfigError("data: give the training dataset folder(s), e.g. data=demos/seen")
    if cfg.episodes < 1:
        raise ConfigError(f"episodes={cfg.episodes}: must be >= 1")
    suite = _check_common(cfg.suite, cfg.quantile)
    cells = _eval_cells(suite, cfg)
    conditions = perturb.conditions_from_config(cfg.perturb)
    if cfg.eval_data and not Path(cfg.eval_data).is_dir():
        raise ConfigError(f"eval_data={cfg.eval_data!r}: not a dataset folder")
    train = read_training(cfg.data)
    if cfg.eval_data:
        states, groups = initial_states_from_dataset(cfg.eval_data, cells)
        source = {"eval_data": cfg.eval_data}
    else:
        states, groups = initial_states_from_suite(suite, cells, cfg.seed, cfg.episodes, cfg.horizon)
        source = {"seed": cfg.seed, "episodes": cfg.episodes}
    report = coverage_report(train, cells, suite.manifest, conditions, states, groups, cfg.quantile)
    doc = {"schema": "bench.coverage/1", "suite": suite.describe(), "data": list(cfg.data),
           "evaluation": {"cells": [c.key for c in cells], **source, "conditions": [c.name for c in conditions]},
           **report}
    render(doc)
    if cfg.out:
        from bench.io import write_atomic

        write_atomic(Path(cfg.out), doc)
        print(f"wrote {cfg.out}")
    return 0


def _pct(v: float | None) -> str:
    return "n/a" if v is None else f"{100 * v:.0f}%"


def render(doc: dict[str, Any], console=None) -> None:
    """Print the support, state-coverage and parameter-coverage tables of a coverage report."""
    from rich.console import Console
    from rich.table import Table

    console = console or Console(width=None if Console().is_terminal else 120)
    t = Table(title=f"support: training data vs evaluated ({doc['suite']['name']})", title_justify="left")
    for col in ("axis", "evaluated", "covered", "missing", "held-out values in training"):
        t.add_column(col)
    for axis, _ in AXES_OF_CELLS:
        s = doc["support"][axis]
        split_txt = ", ".join(f"{k} {len(v['covered'])}/{len(v['evaluated'])}" for k, v in s["by_split"].items())
        t.add_row(axis, str(len(s["evaluated"])), f"{len(s['covered'])} ({_pct(s['fraction'])}; {split_txt})",
                  ", ".join(s["missing"]) or "-", ", ".join(s["unseen_in_training"]) or "-")
    console.print(t)
    sc = doc["state"]
    st = Table(title=f"state coverage: evaluation initial states -> nearest training state (RMS z, "
                     f"radius {sc['reference_radius']} = q{int(sc['quantile'] * 100)} of training, leave-one-episode-out)",
               title_justify="left")
    for col in ("cell", "n", "mean dist", "median", "max", "covered"):
        st.add_column(col, justify="left" if col == "cell" else "right")
    rows = list((sc.get("groups") or {}).items()) + [(f"[bold]{k}[/]", v) for k, v in sc.get("splits", {}).items()]
    rows.append(("[bold]all[/]", sc["overall"]))
    for name, g in rows:
        st.add_row(name, str(g["n"]), *(f"{g[k]:.3f}" if g.get(k) is not None else "n/a" for k in ("mean", "median", "max")),
                   _pct(g.get("covered")))
    console.print(st)
    if doc.get("params"):
        pt = Table(title="parameter-range coverage (perturb.*)", title_justify="left")
        for col in ("axis", "evaluated", "training span", "coverage", "log-scale", "levels inside"):
            pt.add_column(col)
        for axis, p in doc["params"].items():
            pt.add_row(axis, f"[{p['evaluated'][0]:g}, {p['evaluated'][1]:g}]",
                       f"[{p['training'][0]:g}, {p['training'][1]:g}]" if p.get("training") else "n/a",
                       _pct(p.get("coverage")), _pct(p.get("coverage_log")), _pct(p.get("levels_inside")))
        console.print(pt)


# ============================================================================ slope with an interval
def wls_slope(x: Sequence[float], y: Sequence[float], var: Sequence[float]) -> tuple[float, float]:
    """Weighted least-squares line y = a + b x with weights 1/var; returns (slope b, intercept a)."""
    x, y, w = np.asarray(x, float), np.asarray(y, float), 1.0 / np.asarray(var, float)
    if len(x) < 2 or np.ptp(x) == 0:
        raise ValueError("a slope needs at least two distinct x values")
    xm, ym = np.sum(w * x) / w.sum(), np.sum(w * y) / w.sum()
    b = np.sum(w * (x - xm) * (y - ym)) / np.sum(w * (x - xm) ** 2)
    return float(b), float(ym - b * xm)


class SeriesBootstrap:
    """Bootstrap replicates for models evaluated on the same cells with the same episode seeds.

    A point is one training set; it has one outcome dict per training seed (cell key -> 0/1
    outcomes by episode index). A replicate resamples (a) episode indices within each cell,
    jointly for every point and seed, since they share initial states (common random numbers
    cancel in differences and slopes), and (b) the training seeds of each point independently,
    so every interval also carries the seed-to-seed spread of training, which for closed-loop
    behaviour cloning is as large as the evaluation noise. Missing outcomes (errored episodes)
    are NaN and skipped. With one seed per point (b) is a no-op.
    """

    def __init__(self, points: Sequence[Sequence[dict[str, np.ndarray]]], rng: np.random.Generator,
                 n_boot: int = 2000, confidence: float = 0.95):
        self.points = [[{k: np.asarray(v, float) for k, v in seed.items()} for seed in pt] for pt in points]
        if not self.points or any(len(pt) == 0 for pt in self.points):
            raise ValueError("every point needs at least one seed's outcomes")
        n_by_cell: dict[str, int] = {}
        for pt in self.points:
            for seed in pt:
                for k, v in seed.items():
                    n_by_cell[k] = max(n_by_cell.get(k, 0), len(v))
        self.n_boot, self.confidence = int(n_boot), float(confidence)
        self.ep_idx = {k: rng.integers(0, n, (n_boot, n)) for k, n in sorted(n_by_cell.items()) if n}
        self.seed_idx = [rng.integers(0, len(pt), (n_boot, len(pt))) for pt in self.points]
        self.n_by_cell = n_by_cell

    def _padded(self, outcomes: np.ndarray, key: str) -> np.ndarray:
        x = np.full(self.n_by_cell[key], np.nan)
        x[:len(outcomes)] = outcomes
        return x

    def mean(self, k: int, keys: Sequence[str]) -> tuple[float | None, np.ndarray | None]:
        """Point value and replicates of the mean over seeds of the mean over `keys` of point k's cell rates."""
        seeds = self.points[k]
        keys = [key for key in keys if all(len(s.get(key, ())) for s in seeds)]
        if not keys:
            return None, None
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            point = float(np.mean([np.mean([np.nanmean(s[key]) for key in keys]) for s in seeds]))
            per_seed = np.stack([np.nanmean([np.nanmean(self._padded(s[key], key)[self.ep_idx[key]], axis=1)
                                             for key in keys], axis=0) for s in seeds])  # (S, n_boot)
        reps = per_seed[self.seed_idx[k], np.arange(self.n_boot)[:, None]].mean(axis=1)
        return point, reps

    def interval(self, reps: np.ndarray) -> list[float]:
        a = (1 - self.confidence) / 2
        lo, hi = np.nanquantile(reps, [a, 1 - a])
        return [round(float(lo), 6), round(float(hi), 6)]

    def estimate(self, point: float | None, reps: np.ndarray | None, reason: str = "no completed episodes") -> dict:
        """{"value", "ci"} (or value None with a reason): the JSON form of `bench.scoring.Estimate`."""
        if point is None or reps is None:
            return {"value": None, "ci": None, "reason": reason}
        return {"value": round(point, 6), "ci": self.interval(reps)}


def _smoothed_var(p: float, n: int) -> float:
    """Binomial variance of a rate from n outcomes, Laplace-smoothed so it is never 0."""
    q = (p * n + 1) / (n + 2)
    return q * (1 - q) / max(n, 1)


def slope_with_interval(x: Sequence[float], values: Sequence[float], reps: Sequence[np.ndarray],
                        n_outcomes: Sequence[int], confidence: float = 0.95) -> dict[str, Any]:
    """WLS slope of `values` against `x` with a percentile interval from bootstrap replicates.

    Weights are 1/variance per point: the replicates' variance, floored by the smoothed binomial
    variance of its `n_outcomes` so that a point at 0% or 100% cannot take all the weight. The
    weights stay fixed; the slope is refitted on every replicate (rows of `reps` line up across
    points because the replicates were drawn together, see `SeriesBootstrap`).
    """
    x = [float(v) for v in x]
    if len(x) < 2 or len(set(x)) < 2:
        return {"value": None, "ci": None, "reason": "a slope needs at least two points with distinct coverage"}
    if any(v is None for v in values) or any(r is None for r in reps):
        return {"value": None, "ci": None, "reason": "a point has no completed episodes"}
    reps = np.stack([np.asarray(r, float) for r in reps], axis=1)  # (n_boot, K)
    var = [max(float(np.nanvar(reps[:, k])), _smoothed_var(values[k], n_outcomes[k])) for k in range(len(x))]
    b, a = wls_slope(x, values, var)
    boot = np.array([wls_slope(x, row, var)[0] for row in reps if np.all(np.isfinite(row))])
    lo, hi = np.quantile(boot, [(1 - confidence) / 2, 1 - (1 - confidence) / 2])
    return {"value": round(b, 6), "ci": [round(float(lo), 6), round(float(hi), 6)], "intercept": round(a, 6),
            "method": "weighted least squares (1/var), percentile bootstrap over training seeds and episodes",
            "points": [{"x": xx, "y": round(yy, 6), "var": round(vv, 8)} for xx, yy, vv in zip(x, values, var)]}


# ============================================================================ bench coverage sweep
@dataclass(frozen=True)
class SweepConfig:
    """Keys of `bench coverage sweep` (see `bench coverage sweep --help`)."""

    suite: str = "held_out_robots"          # suite with a scripted expert and a seen/unseen robot split
    order: list[str] = field(default_factory=lambda: ["Panda", "Sawyer", "IIWA"])  # seen robots, added one at a time
    total_episodes: int = 36                # demonstrations per training set (budget=fixed), split evenly over robots
    budget: str = "fixed"                   # fixed: total_episodes over the set's robots; per_robot: total_episodes each
    dr_axis: str = "gain"                   # domain-randomisation axis ('' skips the DR part)
    dr_widths: list[float] = field(default_factory=lambda: [0.1, 0.3])  # DR widths w besides 0: uniform(1-w, 1+w)
    surrogate_target: str = "Panda"         # in-domain robot of the surrogate-data experiment
    surrogate_in_domain: int = 12           # fixed in-domain demonstrations (target robot, nominal)
    surrogate_episodes: int = 24            # mismatched demonstrations added to them
    surrogate_perturb: str = "latency=4"    # strongly perturbed simulator on the target robot: AXIS=LEVEL
    surrogate_eval_episodes: int = 30       # evaluation episodes on the target robot per surrogate model
    eval_episodes: int = 10                 # evaluation episodes per cell (all robots) per sweep model
    demo_seed: int = 0                      # seed of the demonstration runs (the extra run uses demo_seed+1)
    eval_seed: int = 1                      # seed of every evaluation run (same initial states for every model)
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2])  # BC training seeds per training set (spread enters every interval)
    workers: int = 2                        # worker processes of each bench run
    horizon: int = 0                        # control steps per episode, demonstrations and evaluations (0 = suite default)
    parts: list[str] = field(default_factory=lambda: ["robots", "dr", "surrogate"])  # experiments to run
    bc: dict[str, Any] = field(default_factory=dict)  # baselines.bc Args overrides, e.g. bc.epochs=50
    workdir: str = "runs/coverage"          # demonstrations, checkpoints, evaluation runs (reused when present)
    out: str = "results/coverage"           # sweep.json and sweep.png go here
    n_boot: int = 2000                      # bootstrap resamples
    confidence: float = 0.95                # two-sided interval level


PARTS = ("robots", "dr", "surrogate")
BUDGETS = ("fixed", "per_robot")


def sweep_help() -> str:
    return _help(
        SweepConfig, "usage: bench coverage sweep [key=value ...]",
        "Does wider training coverage buy held-out success? Records scripted demonstrations\n"
        "(bench run ... record=), trains baselines.bc on nested training sets — 1, 2, 3 seen robots at a\n"
        "fixed demonstration budget (robots); domain randomisation of one axis at widths 0, ±w (dr) —\n"
        "evaluates each checkpoint on every cell with bench run policy=checkpoint (same seeds for all),\n"
        "and reports held-out (unseen) success, in-distribution success on the training robots and the\n"
        "transfer gap against coverage, with intervals, the WLS slope with a paired bootstrap interval,\n"
        "and a plot. surrogate: a fixed in-domain set (target robot) alone, plus other robots' data, plus\n"
        "data from a strongly perturbed simulator; success on the target robot, paired differences.\n"
        "Everything under workdir is reused on a rerun (runs resume; datasets and checkpoints are kept\n"
        "when their inputs match), so an interrupted sweep continues where it stopped.",
        "  bench coverage sweep out=results/coverage workdir=/tmp/coverage\n"
        "  bench coverage sweep parts=[robots] total_episodes=24 eval_episodes=5 workers=2\n"
        "  bench coverage sweep dr_axis=friction dr_widths=[0.5] bc.epochs=60")


def _check_sweep(cfg: SweepConfig, suite) -> None:
    for p in cfg.parts:
        if p not in PARTS:
            raise ConfigError(f"parts: {p!r} is not a part; valid: {', '.join(PARTS)}.{did_you_mean(p, PARTS)}")
    if cfg.budget not in BUDGETS:
        raise ConfigError(f"budget={cfg.budget!r}: valid: {', '.join(BUDGETS)}")
    robots = suite.manifest.get("robots", {})
    seen, unseen = robots.get("seen", []), robots.get("unseen", [])
    if not seen or not unseen:
        raise ConfigError(f"suite {suite.name!r} has no seen/unseen robot split; the sweep needs one")
    if not cfg.order:
        raise ConfigError("order: give the seen robots to add one at a time, e.g. order=[Panda,Sawyer,IIWA]")
    if not cfg.seeds or len(set(cfg.seeds)) != len(cfg.seeds):
        raise ConfigError(f"seeds={cfg.seeds}: give one or more distinct training seeds, e.g. seeds=[0,1,2]")
    for r in cfg.order + [cfg.surrogate_target]:
        if r not in seen:
            raise ConfigError(f"order/surrogate_target: {r!r} is not a seen robot of {suite.name!r}; valid: "
                              f"{', '.join(seen)}.{did_you_mean(r, seen)}")
    if len(set(cfg.order)) != len(cfg.order):
        raise ConfigError(f"order={cfg.order}: repeats a robot")
    for key in ("total_episodes", "eval_episodes", "surrogate_in_domain", "surrogate_episodes",
                "surrogate_eval_episodes", "workers"):
        if getattr(cfg, key) < 1:
            raise ConfigError(f"{key}={getattr(cfg, key)}: must be >= 1")
    if cfg.budget == "fixed" and cfg.total_episodes < len(cfg.order):
        raise ConfigError(f"total_episodes={cfg.total_episodes}: must be >= len(order)={len(cfg.order)} (budget=fixed)")
    if "dr" in cfg.parts and cfg.dr_axis:
        from bench.perturb import AXES

        if cfg.dr_axis not in AXES:
            raise ConfigError(f"dr_axis={cfg.dr_axis!r}: valid: {', '.join(AXES)}.{did_you_mean(cfg.dr_axis, AXES)}")
        if AXES[cfg.dr_axis].kind != "model":
            raise ConfigError(f"dr_axis={cfg.dr_axis!r}: DR widths are scales of nominal; valid: model axes "
                              f"({', '.join(a for a, v in AXES.items() if v.kind == 'model')})")
        for w in cfg.dr_widths:
            if not 0 < w < 1:
                raise ConfigError(f"dr_widths: {w} must be in (0, 1): the range is uniform(1-w, 1+w)")
    if "surrogate" in cfg.parts:
        _surrogate_condition(cfg.surrogate_perturb)
    if not 0.5 <= cfg.confidence < 1:
        raise ConfigError(f"confidence={cfg.confidence}: must be in [0.5, 1)")
    if cfg.n_boot < 100:
        raise ConfigError(f"n_boot={cfg.n_boot}: must be >= 100")
    from baselines.bc import Args

    valid = [f.name for f in dataclasses.fields(Args)]
    for k in cfg.bc:
        if k not in valid or k in ("data", "out", "robots", "conditions", "max_episodes"):
            raise ConfigError(f"bc.{k}: not a training argument the sweep passes on; valid: "
                              f"{', '.join(v for v in valid if v not in ('data', 'out', 'robots', 'conditions', 'max_episodes'))}"
                              f".{did_you_mean(k, valid)}")


def _surrogate_condition(text: str):
    """The Condition of `surrogate_perturb` ("AXIS=LEVEL"), checked with bench.perturb's grammar."""
    from bench.perturb import conditions_from_config

    if "=" not in text:
        raise ConfigError(f"surrogate_perturb={text!r}: write AXIS=LEVEL, e.g. latency=4 or gain=0.6")
    axis, level = text.split("=", 1)
    try:
        value: Any = float(level)
    except ValueError:
        value = level
    conds = conditions_from_config({axis.strip(): [value]})
    if len(conds) != 2 or conds[1].level is None or isinstance(conds[1].level, list):
        raise ConfigError(f"surrogate_perturb={text!r}: give one level, e.g. latency=4")
    return conds[1]


def _dr_condition_names(cfg: SweepConfig) -> list[tuple[float, str, str]]:
    """(width, condition name, perturb grammar) per DR width, names as bench.perturb forms them."""
    from bench.perturb import conditions_from_config

    out = []
    for w in cfg.dr_widths:
        text = f"uniform({1 - w:g},{1 + w:g})"
        name = conditions_from_config({cfg.dr_axis: [text]})[1].name
        out.append((float(w), name, text))
    return out


def _per_robot(cfg: SweepConfig, k: int) -> int:
    return cfg.total_episodes // k if cfg.budget == "fixed" else cfg.total_episodes


def _run_bench(argv: list[str]) -> None:
    from bench.run import main as run_main

    rc = run_main(argv)
    if rc:
        raise DataError(f"bench run {' '.join(argv)} exited {rc}")


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
    for k in (range(1, k_max + 1) if "robots" in parts else [k_max]):
        for r in cfg.order[:k]:
            need[r] = max(need.get(r, 0), _per_robot(cfg, k))
    if "surrogate" in parts:
        need[cfg.surrogate_target] = max(need[cfg.surrogate_target], cfg.surrogate_in_domain)
        others = [r for r in cfg.order if r != cfg.surrogate_target]
        for r in others:
            need[r] = max(need[r], cfg.surrogate_episodes // len(others))
    base_n = _per_robot(cfg, k_max)
    dr = "dr" in parts and bool(cfg.dr_axis)
    sources = []
    argv = [f"suite={cfg.suite}", "policy=scripted", f"robots=[{','.join(cfg.order)}]", f"episodes={base_n}",
            f"seed={cfg.demo_seed}", f"workers={cfg.workers}", f"horizon={cfg.horizon}", f"out={work / 'runs'}",
            "run_id=demos-base"]
    if dr:
        argv.append(f"perturb.{cfg.dr_axis}=[" + ",".join(f"'{t}'" for _, _, t in _dr_condition_names(cfg)) + "]")
    sources.append(_recorded(work / "demos" / "base", argv, log))
    for r in cfg.order:
        extra = max(0, need.get(r, 0) - base_n)
        strong = "surrogate" in parts and r == cfg.surrogate_target
        n = max(extra, cfg.surrogate_episodes if strong else 0)
        if n == 0:
            continue
        argv = [f"suite={cfg.suite}", "policy=scripted", f"robots=[{r}]", f"episodes={n}", f"seed={cfg.demo_seed + 1}",
                f"workers={cfg.workers}", f"horizon={cfg.horizon}", f"out={work / 'runs'}", f"run_id=demos-extra-{r}"]
        if strong:
            axis, level = cfg.surrogate_perturb.split("=", 1)
            argv.append(f"perturb.{axis.strip()}=[{level.strip()}]")
        sources.append(_recorded(work / "demos" / f"extra-{r}", argv, log))
    return sources


def _recorded(dataset: Path, argv: list[str], log) -> Path:
    """Run `bench run ARGV record=DATASET` unless the dataset is already there (same arguments)."""
    stamp = dataset.parent / f"{dataset.name}.argv.json"
    if (dataset / "meta" / "info.json").is_file() and stamp.is_file() and json.loads(stamp.read_text()) == argv:
        log(f"demonstrations: reusing {dataset}")
        return dataset
    if dataset.exists() and any(dataset.iterdir()):
        raise ConfigError(f"workdir: {dataset} exists but was recorded with other arguments; give a new workdir")
    log(f"demonstrations: bench run {' '.join(argv)} record={dataset}")
    _run_bench(argv + [f"record={dataset}"])
    dataset.parent.mkdir(parents=True, exist_ok=True)
    stamp.write_text(json.dumps(argv))
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
        d = load_demos([str(s) for s in sources], robots=[robot], conditions=[cond], max_episodes=n,
                       successful_only=successful_only and cond == "nominal")
        if len(d.episodes) < n:
            raise DataError(f"sweep: only {len(d.episodes)} usable {robot} demonstrations under {cond}, {n} wanted "
                            f"(successful_only={successful_only})")
        out = d if out is None else out + d
    assert out is not None
    return out


def _demo_stats(sources: Sequence[Path]) -> dict[str, Any]:
    """Expert success per robot and condition in the recorded demonstrations (from the episode meta)."""
    from bench.logs import read_dataset

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
    info.update(fingerprint=fp, name=name, total_wall_s=round(time.perf_counter() - t0, 3),
                robots_episodes=dict(Counter(f"{e['robot']}|{e['condition']}" for e in demos.episodes)))
    info_path.write_text(json.dumps(info, indent=2))
    log(f"checkpoint {name}: {info['episodes']} episodes, {info['frames']} frames, {info['train_wall_s']:.1f} s")
    return path, info


def _evaluate(name: str, ckpt: Path, cfg: SweepConfig, work: Path, episodes: int, robots: Sequence[str] | None,
              log) -> dict[str, np.ndarray]:
    """`bench run policy=checkpoint` on the suite's cells (or `robots`); cell key -> 0/1 outcomes by episode."""
    from bench.records import EPISODES, dedupe, read_records

    run_id = f"eval-{name}" + (f"-{'-'.join(robots)}-n{episodes}" if robots else "")
    argv = [f"suite={cfg.suite}", "policy=checkpoint", f"checkpoint={ckpt}", f"episodes={episodes}",
            f"seed={cfg.eval_seed}", f"workers={cfg.workers}", f"horizon={cfg.horizon}", f"out={work / 'runs'}",
            f"run_id={run_id}",
            f"n_boot={cfg.n_boot}"]
    if robots:
        argv.append(f"robots=[{','.join(robots)}]")
    run_dir = work / "runs" / run_id
    if (run_dir / "run.json").is_file():
        old = json.loads((run_dir / "run.json").read_text())
        if old.get("policy", {}).get("checkpoint_sha256") != _sha256(ckpt):
            raise ConfigError(f"workdir: {run_dir} evaluated another checkpoint; give a new workdir")
    log(f"evaluate {name}: bench run {' '.join(argv)}")
    _run_bench(argv)
    records = dedupe(read_records(run_dir / EPISODES))
    cells: dict[str, list] = {}
    for r in sorted(records, key=lambda r: r.episode):
        if r.error is None and r.condition == "nominal":
            cells.setdefault(f"{r.task}/{r.robot}/{r.env}", []).append(float(r.success_once))
    return {k: np.asarray(v) for k, v in cells.items()}


def _sha256(path: Path) -> str:
    from bench.io import sha256_file

    return sha256_file(Path(path))



def _training_summary(infos: Sequence[dict]) -> dict[str, Any]:
    return {"episodes": infos[0]["episodes"], "frames": infos[0]["frames"],
            "robots_episodes": infos[0].get("robots_episodes"),
            "train_wall_s": [round(float(i["train_wall_s"]), 3) for i in infos]}


def _per_seed_cells(outcomes: Sequence[dict[str, np.ndarray]], cfg: SweepConfig) -> dict[str, Any]:
    """Per cell: successes and episodes pooled over the training seeds, with a Wilson interval."""
    out = {}
    for key in outcomes[0]:
        k = int(sum(int(o[key].sum()) for o in outcomes if key in o))
        n = int(sum(len(o[key]) for o in outcomes if key in o))
        out[key] = {"n": n, "successes": k, "per_seed": [int(o[key].sum()) if key in o else None for o in outcomes],
                    **scoring.wilson(k, n, cfg.confidence).to_dict()}
    return out


def _coverage_summary(demos, cells, manifest, conditions, states, groups) -> dict[str, Any]:
    train = TrainingData(demos.obs.astype(float), demos.episode,
                         [{"task": e.get("task"), "robot": e["robot"], "env": e.get("env"),
                           "condition": e["condition"], "params": e["params"]} for e in demos.episodes], [])
    rep = coverage_report(train, cells, manifest, conditions, states, groups)
    held = rep["state"]["splits"].get("unseen", {})
    out = {"robots_covered": rep["support"]["robots"]["covered"],
           "state_unseen_mean_distance": held.get("mean"), "state_unseen_covered": held.get("covered"),
           "reference_radius": rep["state"]["reference_radius"],
           "state_by_cell": {k: {"mean_distance": v.get("mean"), "covered": v.get("covered")}
                             for k, v in (rep["state"].get("groups") or {}).items()}}
    if rep["params"]:
        out["params"] = rep["params"]
    return out


def sweep_main(argv: list[str]) -> int:
    """`bench coverage sweep ...`: see `sweep_help()`."""
    if argv and argv[0] in ("-h", "--help"):
        print(sweep_help())
        return 0
    from rich.console import Console

    from bench import config as config_mod
    from bench import registry

    cfg: SweepConfig = config_mod.build_from_argv(SweepConfig, argv, "bench coverage sweep")
    suite = registry.make_suite(cfg.suite)
    _check_sweep(cfg, suite)
    console = Console(stderr=True)
    log = lambda msg: console.print(f"[bold]sweep[/] {msg}")  # noqa: E731
    work, out = Path(cfg.workdir), Path(cfg.out)
    t_start = time.perf_counter()
    doc = run_sweep(cfg, suite, work, log)
    doc["invocation_wall_s"] = round(time.perf_counter() - t_start, 1)  # reused artifacts cost nothing here
    from bench.io import write_atomic

    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "sweep.json", doc)
    plot_sweep(doc, out / "sweep.png")
    render_sweep(doc)
    log(f"wrote {out / 'sweep.json'} and {out / 'sweep.png'} ({doc['invocation_wall_s']:.0f} s)")
    return 0



def run_sweep(cfg: SweepConfig, suite, work: Path, log) -> dict[str, Any]:
    """Record, train, evaluate and score every part of the sweep; returns the sweep document."""
    from bench.perturb import conditions_from_config
    from bench.suite import NOMINAL

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
        "schema": "bench.coverage-sweep/1", "suite": suite.describe(), "config": dataclasses.asdict(cfg),
        "demonstrations": [str(s) for s in sources], "expert_success": _demo_stats(sources),
        "metric": "success_once", "confidence": cfg.confidence, "seeds": list(cfg.seeds),
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
        return [_evaluate(f"{name}-s{seed}", ckpt, cfg, work, episodes, robots, log)
                for seed, (ckpt, _) in zip(cfg.seeds, models)]

    def series(entries: list[dict], xlabel: str) -> dict[str, Any]:
        return _series(entries, xlabel, unseen_keys, rng, cfg)

    k_max = len(cfg.order)
    entries: dict[str, dict] = {}
    if "robots" in parts or "dr" in parts:
        for k in (range(1, k_max + 1) if "robots" in parts else [k_max]):
            robots = cfg.order[:k]
            name = f"robots{k}"
            demos, models = model(name, [(r, "nominal", _per_robot(cfg, k)) for r in robots])
            entries[name] = {"name": name, "x": float(k), "train_keys": [key_of[r] for r in robots],
                             "outcomes": evaluate(name, models, cfg.eval_episodes),
                             "training": _training_summary([m[1] for m in models]),
                             "coverage": _coverage_summary(demos, cells, suite.manifest, [NOMINAL], states, groups)}
        if "robots" in parts:
            doc["robots"] = series([entries[f"robots{k}"] for k in range(1, k_max + 1)],
                                   "number of seen robots in the training set")
    if "dr" in parts and cfg.dr_axis:
        n = _per_robot(cfg, k_max)
        dr_conds = _dr_condition_names(cfg)
        eval_conds = conditions_from_config({cfg.dr_axis: [t for _, _, t in dr_conds]})
        base = dict(entries[f"robots{k_max}"], x=0.0)
        demos0 = _select(sources, [(r, "nominal", n) for r in cfg.order], successful_only)
        base["coverage"] = _coverage_summary(demos0, cells, suite.manifest, eval_conds, states, groups)
        dr_entries = [base]
        for w, cond, _ in dr_conds:
            name = f"dr-{cfg.dr_axis}-{w:g}"
            demos, models = model(name, [(r, cond, n) for r in cfg.order])
            dr_entries.append({"name": name, "x": w, "train_keys": [key_of[r] for r in cfg.order],
                               "outcomes": evaluate(name, models, cfg.eval_episodes),
                               "training": _training_summary([m[1] for m in models]),
                               "coverage": _coverage_summary(demos, cells, suite.manifest, eval_conds, states, groups)})
        doc["dr"] = series(dr_entries, f"domain-randomisation width on {cfg.dr_axis} (uniform(1-w, 1+w))")
    if "surrogate" in parts:
        doc["surrogate"] = _surrogate(cfg, model, evaluate, key_of, rng)
    return doc


def _series(entries: list[dict], xlabel: str, unseen_keys: Sequence[str], rng, cfg: SweepConfig) -> dict[str, Any]:
    """Held-out and in-distribution success, gap, difference to the first point, and slopes of one series."""
    boot = SeriesBootstrap([e["outcomes"] for e in entries], rng, cfg.n_boot, cfg.confidence)
    points, held, held_reps, gaps, gap_reps, n_held, n_gap = [], [], [], [], [], [], []
    for k, e in enumerate(entries):
        h, h_r = boot.mean(k, unseen_keys)
        i, i_r = boot.mean(k, e["train_keys"])
        g, g_r = (None, None) if h is None or i is None else (i - h, i_r - h_r)
        nh = sum(len(o.get(key, ())) for o in e["outcomes"] for key in unseen_keys)
        ni = sum(len(o.get(key, ())) for o in e["outcomes"] for key in e["train_keys"])
        point = {
            "name": e["name"], "x": e["x"], "train_robots": sorted({key.split("/")[1] for key in e["train_keys"]}),
            "seeds": list(cfg.seeds), "held_out": boot.estimate(h, h_r), "in_distribution": boot.estimate(i, i_r),
            "gap": boot.estimate(g, g_r), "cells": _per_seed_cells(e["outcomes"], cfg),
            "training": e["training"], "coverage": e["coverage"],
        }
        if k > 0 and h is not None and held[0] is not None:
            d = boot.estimate(h - held[0], h_r - held_reps[0])
            point["held_out_vs_first"] = {"reference": entries[0]["name"], **d}
        points.append(point)
        held.append(h)
        held_reps.append(h_r)
        gaps.append(g)
        gap_reps.append(g_r)
        n_held.append(nh)
        n_gap.append(min(nh, ni))
    xs = [e["x"] for e in entries]
    return {"x_label": xlabel, "points": points,
            "held_out_slope": slope_with_interval(xs, held, held_reps, n_held, cfg.confidence),
            "gap_slope": slope_with_interval(xs, gaps, gap_reps, n_gap, cfg.confidence)}


def _surrogate(cfg: SweepConfig, model, evaluate, key_of: dict, rng) -> dict[str, Any]:
    """In-domain alone vs + other robots' data vs + strongly perturbed simulator data, on the target robot."""
    target = cfg.surrogate_target
    others = [r for r in cfg.order if r != target]
    strong = _surrogate_condition(cfg.surrogate_perturb)
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
        trainings.append(_training_summary([m[1] for m in models]))
    boot = SeriesBootstrap(outcomes, rng, cfg.n_boot, cfg.confidence)
    results: dict[str, Any] = {}
    base_v, base_r = boot.mean(0, [key])
    for k, name in enumerate(names):
        v, r = boot.mean(k, [key])
        results[name] = {"training": trainings[k], "success": boot.estimate(v, r),
                         "cells": _per_seed_cells(outcomes[k], cfg)}
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
        d["verdict"] = ("helps" if ci and ci[0] > 0 else "hurts" if ci and ci[1] < 0 else
                        "no detectable effect" if ci else "n/a")
        results[name]["vs_in_domain"] = d
    return {"target": key, "in_domain_episodes": cfg.surrogate_in_domain, "surrogate_episodes": cfg.surrogate_episodes,
            "perturbed_condition": strong.name, "other_robots": others, "eval_episodes": cfg.surrogate_eval_episodes,
            "variants": results}


# ---------------------------------------------------------------------------- output
def render_sweep(doc: dict[str, Any], console=None) -> None:
    """Print the sweep's tables: each series with its slope, then the surrogate comparison."""
    from rich.console import Console
    from rich.table import Table

    from bench.summary import fmt_estimate

    console = console or Console(width=None if Console().is_terminal else 140)
    conf = int(round(100 * doc.get("confidence", 0.95)))
    for part in ("robots", "dr"):
        s = doc.get(part)
        if not s:
            continue
        t = Table(title=f"{part}: {s['x_label']} ({conf}% intervals)", title_justify="left")
        for col in ("model", "x", "train robots", "episodes", "held-out success", "vs first (paired)",
                    "in-distribution", "gap", "unseen states covered", "train s"):
            t.add_column(col)
        for p in s["points"]:
            c = p["coverage"]
            t.add_row(p["name"], f"{p['x']:g}", ",".join(p["train_robots"]), str(p["training"]["episodes"]),
                      fmt_estimate(p["held_out"]), fmt_estimate(p.get("held_out_vs_first"), pct=False) if "held_out_vs_first" in p else "-",
                      fmt_estimate(p["in_distribution"]), fmt_estimate(p["gap"], pct=False),
                      _pct(c.get("state_unseen_covered")),
                      "/".join(f"{w:.0f}" for w in np.atleast_1d(p["training"]["train_wall_s"])))
        console.print(t)
        console.print(f"  held-out success slope per unit x: {fmt_estimate(s['held_out_slope'], pct=False)}; "
                      f"gap slope: {fmt_estimate(s['gap_slope'], pct=False)}")
    sg = doc.get("surrogate")
    if sg:
        t = Table(title=f"surrogate data: {sg['in_domain_episodes']} in-domain episodes on {sg['target']} "
                        f"+ {sg['surrogate_episodes']} mismatched ({conf}% intervals)", title_justify="left")
        for col in ("training set", "episodes", "success on target", "difference vs in-domain (paired)", "verdict"):
            t.add_column(col)
        for name, v in sg["variants"].items():
            d = v.get("vs_in_domain")
            t.add_row(name, str(v["training"]["episodes"]), fmt_estimate(v["success"]), fmt_estimate(d, pct=False) if d else "-",
                      d.get("verdict", "") if d else "")
        console.print(t)


def plot_sweep(doc: dict[str, Any], path: Path) -> Path:
    """PNG: held-out and in-distribution success against coverage with intervals and the WLS line; surrogate bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [p for p in ("robots", "dr", "surrogate") if doc.get(p)]
    fig, axes = plt.subplots(1, max(1, len(panels)), figsize=(5.2 * max(1, len(panels)), 4.2), squeeze=False)
    for ax, part in zip(axes[0], panels):
        if part == "surrogate":
            sg = doc[part]
            names = list(sg["variants"])
            vals = [sg["variants"][n]["success"] for n in names]
            y = [v["value"] or 0 for v in vals]
            err = [[max(0.0, (v["value"] or 0) - v["ci"][0]) if v.get("ci") else 0 for v in vals],
                   [max(0.0, v["ci"][1] - (v["value"] or 0)) if v.get("ci") else 0 for v in vals]]
            ax.bar(range(len(names)), y, yerr=err, capsize=4, color=["#4c72b0", "#dd8452", "#55a868"][:len(names)])
            ax.set_xticks(range(len(names)), [n.replace("_", "\n") for n in names], fontsize=8)
            ax.set_ylim(0, 1.05)
            ax.set_ylabel(f"success on {sg['target'].split('/')[1]}")
            ax.set_title(f"surrogate data (+{sg['surrogate_episodes']} eps to {sg['in_domain_episodes']} in-domain)",
                         fontsize=9)
            continue
        s = doc[part]
        xs = np.array([p["x"] for p in s["points"]])
        nudge = 0.015 * (np.ptp(xs) or 1.0)  # side by side, so the intervals do not hide each other
        for key, label, color, off in (("held_out", "held-out (unseen robots)", "#c44e52", -nudge),
                                       ("in_distribution", "in-distribution (training robots)", "#4c72b0", nudge)):
            ys = np.array([p[key]["value"] if p[key]["value"] is not None else np.nan for p in s["points"]])
            lo = np.array([p[key]["ci"][0] if p[key].get("ci") else np.nan for p in s["points"]])
            hi = np.array([p[key]["ci"][1] if p[key].get("ci") else np.nan for p in s["points"]])
            ax.errorbar(xs + off, ys, yerr=[ys - lo, hi - ys], fmt="o", color=color, capsize=4, label=label)
        sl = s["held_out_slope"]
        if sl.get("value") is not None:
            grid = np.linspace(xs.min(), xs.max(), 20)
            ax.plot(grid, sl["intercept"] + sl["value"] * grid, "--", color="#c44e52",
                    label=f"WLS slope {sl['value']:+.3f} [{sl['ci'][0]:+.3f}, {sl['ci'][1]:+.3f}]")
        ax.set_xlabel(s["x_label"], fontsize=9)
        ax.set_ylabel("success rate (success_once)")
        ax.set_ylim(-0.02, 1.05)
        ax.set_xticks(xs)
        ax.legend(fontsize=7, loc="best")
        ax.set_title({"robots": "robot coverage (fixed demo budget)", "dr": "domain-randomisation width"}[part],
                     fontsize=10)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path

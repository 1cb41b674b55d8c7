"""Data coverage metrics: how much of a suite's evaluation conditions a training dataset covers.

`bench coverage data=DIR suite=NAME` (`bench.cli.coverage`) compares a LeRobot v3 training dataset (e.g. demonstrations
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

What coverage buys is measured by an experiment built on these metrics and on `bench.api`:
`python -m baselines.coverage_sweep` (nested training sets, behaviour cloning, evaluation,
slopes with intervals from `bench.scoring.trend`).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

from bench.core.errors import ConfigError, DataError
from bench.logs import read_dataset
from bench.protocols import Suite
from bench.protocols.suite import SPLIT_AXES, Cell, Condition, episode_seed
from bench.sims.perturb.axes import AXES

if TYPE_CHECKING:
    from typing_extensions import NotRequired  # typing's own from Python 3.11

MIN_SCALE = 1e-3  # floor of the per-dimension std used to normalise states (observation units)
Manifest = Mapping[str, Mapping[str, Sequence[str]]]  # a suite's split manifest: axis -> split -> values


class StateCoverage(TypedDict):
    """`state_coverage`'s report (distances in training-std units, RMS over dimensions)."""

    metric: str
    dims: int
    training_states: int
    training_episodes: int
    quantile: float
    reference_radius: float | None
    reference: dict[str, object] | None
    overall: dict[str, object]
    groups: NotRequired[dict[str, dict[str, object]]]
    distances: NotRequired[list[float]]  # set last (after `groups`), as the report lists it
    splits: NotRequired[dict[str, dict[str, object]]]  # added by `coverage_report`


# ============================================================================ metrics (pure)
def support(
    train_meta: Sequence[Mapping[str, object]], cells: Sequence[Cell], manifest: Manifest | None = None
) -> dict[str, object]:
    """Robots / tasks / envs present in the training episodes vs evaluated in `cells`.

    Args:
        train_meta: per training episode, a dict with `robot`, `task`, `env` (dataset meta).
        cells: the evaluated `bench.protocols.suite.Cell`s.
        manifest: the suite's split manifest; values the data holds from its `unseen` lists
            are reported under `unseen_in_training` (held-out data leaked into training).
    """
    manifest = manifest or {}
    out: dict[str, object] = {}
    for axis, attr in SPLIT_AXES.items():
        counts = Counter(str(m.get(attr)) for m in train_meta if m.get(attr) is not None)
        evaluated = sorted({getattr(c, attr) for c in cells})
        covered = [v for v in evaluated if v in counts]
        by_split = {}
        for split in sorted({c.split for c in cells}):
            ev = sorted({getattr(c, attr) for c in cells if c.split == split})
            cov = [v for v in ev if v in counts]
            by_split[split] = {"evaluated": ev, "covered": cov, "fraction": len(cov) / len(ev) if ev else None}
        out[axis] = {
            "evaluated": evaluated,
            "present": sorted(counts),
            "covered": covered,
            "missing": [v for v in evaluated if v not in counts],
            "fraction": len(covered) / len(evaluated) if evaluated else None,
            "episodes": dict(sorted(counts.items())),
            "by_split": by_split,
            "unseen_in_training": sorted(set(counts) & set(manifest.get(axis, {}).get("unseen", []))),
        }
    keys = Counter(f"{m.get('task')}/{m.get('robot')}/{m.get('env')}" for m in train_meta)
    ev_cells = [c.key for c in cells]
    out["cells"] = {
        "evaluated": len(ev_cells),
        "covered": sum(k in keys for k in ev_cells),
        "fraction": sum(k in keys for k in ev_cells) / len(ev_cells) if ev_cells else None,
        "missing": [k for k in ev_cells if k not in keys],
    }
    return out


def state_scale(train_states: np.ndarray, min_scale: float = MIN_SCALE) -> np.ndarray:
    """Per-dimension std of the training states, floored at `min_scale` (constant dims stay finite)."""
    return np.maximum(np.asarray(train_states, float).std(axis=0), min_scale)


def _distance_summary(d: np.ndarray, radius: float | None) -> dict[str, object]:
    out: dict[str, object] = {"n": int(len(d))}
    if not len(d):
        return {**out, "mean": None, "median": None, "max": None, "covered": None, "reason": "no states"}
    out.update(mean=round(float(d.mean()), 6), median=round(float(np.median(d)), 6), max=round(float(d.max()), 6))
    if radius is None:
        out.update(covered=None, reason="no reference radius (the training data has fewer than 2 episodes)")
    else:
        out["covered"] = round(float(np.mean(d <= radius)), 6)
    return out


def state_coverage(
    train_states: np.ndarray,
    train_episode: np.ndarray,
    eval_states: np.ndarray,
    eval_groups: Sequence[str] | None = None,
    quantile: float = 0.95,
    scale: np.ndarray | None = None,
) -> StateCoverage:
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
    from scipy.spatial import cKDTree  # scipy: loaded only when this estimate is computed

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
    out: StateCoverage = {
        "metric": "RMS over dimensions of (eval - nearest training state) / training std",
        "dims": int(dim),
        "training_states": int(len(x)),
        "training_episodes": int(len(np.unique(ep))),
        "quantile": quantile,
        "reference_radius": None if radius is None else round(radius, 6),
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
    return float(AXES[axis].nominal) if axis in AXES else 1.0


def _overlap(lo: float, hi: float, tlo: float, thi: float) -> float:
    if hi <= lo:
        return 1.0 if tlo <= lo <= thi else 0.0
    return max(0.0, min(hi, thi) - max(lo, tlo)) / (hi - lo)


def param_coverage(
    train_params: Sequence[Mapping[str, float]], conditions: Sequence[Condition]
) -> dict[str, dict[str, object]]:
    """Fraction of each evaluated perturbation range that the training episodes' values span.

    The evaluated interval of an axis runs over the nominal level, every grid level and every
    range [low, high] of its conditions. A training episode without a value for the axis ran
    at the nominal level. Coverage = |evaluated ∩ [min, max] of training values| / |evaluated|
    (a single evaluated value: 1 if inside the training span, else 0); `coverage_log` is the
    same on a log scale when every bound is positive (scales of nominal).

    Args:
        train_params: per training episode its `params` dict (e.g. {"gain": 1.07}) or {}.
        conditions: the evaluated `bench.protocols.suite.Condition`s (nominal is skipped).
    """
    by_axis: dict[str, list[Condition]] = {}
    for c in conditions:
        if c.axis is not None:
            by_axis.setdefault(c.axis, []).append(c)
    out: dict[str, dict[str, object]] = {}
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
        entry: dict[str, object] = {
            "evaluated": [lo, hi],
            "nominal": nominal,
            "conditions": [c.name for c in conds],
            "training": [tlo, thi],
            "training_episodes_off_nominal": int(np.sum(values != nominal)),
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
    states: list[np.ndarray] = []
    epi: list[np.ndarray] = []
    meta: list[dict] = []
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


def initial_states_from_suite(
    suite: Suite, cells: Sequence[Cell], seed: int, episodes: int, horizon: int = 0
) -> tuple[np.ndarray, list[str]]:
    """The observation right after reset for each cell and episode seed of a run (`bench.protocols.suite.episode_seed`).

    Builds each cell's env once (robosuite: a few seconds) and resets it with the same seeds
    `bench run seed=SEED episodes=N` uses, under the nominal condition.
    """
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


def initial_states_from_dataset(path: str | Path, cells: Sequence[Cell] | None = None) -> tuple[np.ndarray, list[str]]:
    """First frame of each episode of a recorded evaluation run, labelled by cell key (only `cells` if given)."""
    ds = read_dataset(path)
    wanted = {c.key for c in cells} if cells is not None else None
    states, groups = [], []
    for ep in ds.episodes:
        m = ep.meta or {}
        # the task string is the cell key (bench.execution.recording); the meta fields are the fallback
        key = ep.tasks[0] if ep.tasks else f"{m.get('task')}/{m.get('robot')}/{m.get('env')}"
        if wanted is not None and key not in wanted:
            continue
        states.append(np.asarray(ep.data["observation.state"][0], float))
        groups.append(key)
    if not states:
        raise DataError(
            f"eval_data={str(path)!r}: no episode of the evaluated cells ({', '.join(sorted(wanted or []))})"
        )
    return np.asarray(states), groups


def coverage_report(
    train: TrainingData,
    cells: Sequence[Cell],
    manifest: Manifest,
    conditions: Sequence[Condition],
    eval_states: np.ndarray,
    eval_groups: Sequence[str],
    quantile: float = 0.95,
) -> dict[str, Any]:  # JSON: coverage.json, which its readers take apart by key
    """All three metrics for one training set, plus per-split state coverage."""
    sc = state_coverage(train.states, train.episode, eval_states, eval_groups, quantile)
    split_of = {c.key: c.split for c in cells}
    d = np.asarray(sc["distances"])
    groups = np.asarray(list(eval_groups))
    radius = sc["reference_radius"]
    sc["splits"] = {
        s: _distance_summary(d[np.array([split_of.get(g) == s for g in groups], bool)], radius)
        for s in sorted({c.split for c in cells})
    }
    return {
        "training": {
            "episodes": len(train.meta),
            "frames": int(len(train.states)),
            "robots": sorted({str(m.get("robot")) for m in train.meta}),
            "conditions": sorted({str(m.get("condition", "nominal")) for m in train.meta}),
        },
        "support": support(train.meta, cells, manifest),
        "state": sc,
        "params": param_coverage([m.get("params") or {} for m in train.meta], conditions),
    }


def fmt_pct(v: float | None) -> str:
    """A fraction as a whole percentage (`82%`), or n/a."""
    return "n/a" if v is None else f"{100 * v:.0f}%"

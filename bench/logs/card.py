"""A data card for a log: how many episodes it holds, and how many of them are worth having.

    N_eff = N (1 - d) (1 - n) (1 - c)

- N: episodes in the log.
- d: near-duplicate share. Each episode's `observation.state` trajectory is resampled to
  `POINTS` instants over its duration and standardised by the log's per-channel spread; an
  episode whose RMS distance to an earlier kept episode is below `dup_tol` is a near-duplicate
  (replaying the same demonstration twice adds no information).
- n: noise share. Per channel, the white-noise variance sigma^2 = var(x[t+1] - 2 x[t] + x[t-1]) / 6
  (a smooth signal has almost no second difference; white noise of variance sigma^2 gives 6 sigma^2),
  divided by the channel's variance over the log; the mean over channels, clipped to [0, 1].
- c: overlap with a suite's evaluation: for each episode, whether its first observation is within
  `overlap_tol` (RMS, standardised) of an initial observation the suite's own evaluation would
  start from (`bench run suite=NAME episodes=K seed=S`: the same cells, episode seeds 0..K-1; the
  CLI builds them, `starts`). Data that starts where the evaluation starts leaks the test set into
  training. Without them, c is not measured (0, said so).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bench.core.errors import DataError
from bench.logs.dataset import LogDataset

POINTS = 32
STATE = "observation.state"


def _trajectories(eps: list, key: str) -> list[np.ndarray]:
    out = []
    for ep in eps:
        if key not in ep.data:
            raise DataError(f"episode {ep.index} has no {key!r} column; a data card needs the observed state")
        x = np.asarray(ep.data[key], dtype=np.float64)
        out.append(x[:, None] if x.ndim == 1 else x.reshape(len(x), -1))
    return out


def _resampled(x: np.ndarray) -> np.ndarray:
    t = np.linspace(0.0, 1.0, len(x))
    grid = np.linspace(0.0, 1.0, POINTS)
    return np.stack(
        [np.interp(grid, t, x[:, c]) if len(x) > 1 else np.full(POINTS, x[0, c]) for c in range(x.shape[1])], axis=1
    )


def near_duplicates(trajs: list[np.ndarray], scale: np.ndarray, tol: float) -> list[tuple[int, int, float]]:
    """(episode, earlier episode it duplicates, RMS distance) for every near-duplicate, greedy in log order."""
    feats = np.stack([(_resampled(x) / scale).ravel() for x in trajs])
    kept: list[int] = []
    out = []
    for i, f in enumerate(feats):
        if kept:
            dist = np.sqrt(np.mean((feats[kept] - f) ** 2, axis=1))
            j = int(np.argmin(dist))
            if dist[j] < tol:
                out.append((i, kept[j], float(dist[j])))
                continue
        kept.append(i)
    return out


def noise_share(trajs: list[np.ndarray]) -> tuple[float, np.ndarray]:
    """The mean over channels of white-noise variance / total variance, and the per-channel shares."""
    total = np.concatenate(trajs).var(axis=0)
    second = [np.diff(x, n=2, axis=0) for x in trajs if len(x) >= 3]
    if not second:
        return 0.0, np.zeros(len(total))
    noise = np.concatenate(second).var(axis=0) / 6.0
    share = np.where(total > 1e-12, np.clip(noise / np.maximum(total, 1e-300), 0.0, 1.0), 0.0)
    return float(share.mean()), share


def card(
    ds: LogDataset,
    *,
    starts: dict[str, np.ndarray] | None = None,
    where: str = "",
    dup_tol: float = 0.05,
    overlap_tol: float = 0.01,
) -> dict[str, Any]:
    """The data card of a dataset (a `bench.logs` Dataset): N, d, n, c, N_eff and what each found.

    `starts`: the initial observations of an evaluation per cell key (an episode's cell is its task
    string, as `bench run record=` writes it); `where` says which evaluation they are.
    """
    eps = list(ds.episodes)
    if not eps:
        raise DataError("the log holds no episodes")
    trajs = _trajectories(eps, STATE)
    scale = np.maximum(np.concatenate(trajs).std(axis=0), 1e-9)
    dups = near_duplicates(trajs, scale, dup_tol)
    n_share, per_channel = noise_share(trajs)
    overlap: list[dict[str, object]] = []
    c, note = 0.0, "no suite= given: overlap with an evaluation not measured (c = 0)"
    if starts is not None:
        for ep, x in zip(eps, trajs):
            key = ep.tasks[0] if ep.tasks else ""
            if key not in starts:
                continue
            if starts[key].shape[1] != x.shape[1]:
                raise DataError(
                    f"episode {ep.index}: observation.state has width {x.shape[1]}, the evaluation's "
                    f"{starts[key].shape[1]} ({where}); was the log recorded with this suite?"
                )
            dist = np.sqrt(np.mean(((starts[key] - x[0]) / scale) ** 2, axis=1))
            j = int(np.argmin(dist))
            if dist[j] < overlap_tol:
                overlap.append({"episode": int(ep.index), "cell": key, "eval_episode": j, "distance": float(dist[j])})
        c = len(overlap) / len(eps)
        note = f"overlap measured against {where}"
    n_total = len(eps)
    d = len(dups) / n_total
    return {
        "schema": "bench.logs_card/1",
        "N": n_total,
        "d": d,
        "n": n_share,
        "c": c,
        "N_eff": n_total * (1.0 - d) * (1.0 - n_share) * (1.0 - c),
        "frames": int(sum(len(x) for x in trajs)),
        "duplicates": [
            {"episode": int(eps[i].index), "of": int(eps[j].index), "distance": dist} for i, j, dist in dups
        ],
        "noise_per_channel": [float(v) for v in per_channel],
        "overlap": overlap,
        "settings": {"dup_tol": dup_tol, "overlap_tol": overlap_tol, "points": POINTS, "evaluation": where or None},
        "notes": [note],
    }


def format_card(doc: dict[str, Any]) -> str:
    lines = [
        f"N     {doc['N']:>8d}   episodes ({doc['frames']} frames)",
        f"d     {doc['d']:8.3f}   near-duplicate share ({len(doc['duplicates'])} episode(s) repeat an earlier one)",
        f"n     {doc['n']:8.3f}   noise share (white-noise variance / variance, mean over state channels)",
        f"c     {doc['c']:8.3f}   overlap with the evaluation's initial states ({len(doc['overlap'])} episode(s))",
        f"N_eff {doc['N_eff']:8.1f}   = N (1 - d) (1 - n) (1 - c)",
    ]
    return "\n".join(lines + [f"note: {n}" for n in doc["notes"]])

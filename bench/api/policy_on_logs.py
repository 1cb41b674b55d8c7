"""`bench actions` from Python: a policy fed logged observations, its actions compared with the logged ones.

For each episode of a LeRobot v3 dataset the policy is reset, then given the logged
`observation.state` frame by frame (open loop: the log, not the policy, decides what
happens next); its action is compared with the logged `action`. Reported per action
dimension: mean absolute error and RMSE, each with a bootstrap interval that resamples
whole episodes (frames within an episode are not independent).

The policy is made exactly as `bench run` makes it, for the suite cell named by the
episode's task string (datasets written by `bench run record=` use the cell key, e.g.
`Lift/Panda/default`), so checkpoints and scripted experts are checked against the same
observation layout: the dataset's observation names must match the env's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
from numpy.typing import NDArray

from bench.core import config as config_mod
from bench.core import outputs
from bench.core.config import MAX_N_BOOT, MAX_SEED, ranged
from bench.core.errors import ConfigError, DataError
from bench.core.io import write_atomic
from bench.execution.recording import episode_cell
from bench.logs import read_dataset
from bench.protocols import STATE, PolicyContext, registry
from bench.remote.latency import pool

__all__ = ["ActionsConfig", "actions", "evaluate"]

Floats = NDArray[np.float64]


@dataclass(frozen=True)
class ActionsConfig:
    """Keys of `bench actions`."""

    logs: Optional[str] = None  # LeRobot v3 dataset folder
    policy: str = "scripted"  # registered policy name or package.module:attr (its own keys are accepted too)
    suite: str = "held_out_robots"  # suite whose cells name the episodes' tasks
    episodes: Optional[list[int]] = None  # only these episode indices
    seed: int = ranged(0, 0, MAX_SEED)  # bootstrap seed
    n_boot: int = ranged(2000, 1, MAX_N_BOOT)  # bootstrap resamples (over episodes)
    confidence: float = ranged(0.95, 0, 1, lo_open=True, hi_open=True)  # interval level
    out: Optional[str] = None  # write the JSON result here (never an input)
    overwrite: bool = False  # replace an existing out= file that bench wrote


def _expand(obs_names: list[tuple[str, int]]) -> list[str]:
    return [n if w == 1 else f"{n}_{i}" for n, w in obs_names for i in range(w)]


def _first_action(out: Any) -> Floats:
    """A policy's action for this frame: the action, or the first row of an action chunk."""
    arr = np.asarray(out, np.float64)
    return arr[0] if arr.ndim == 2 else arr


def _bootstrap(
    per_episode: Floats, weights: Floats, rng: np.random.Generator, n_boot: int, conf: float
) -> tuple[Floats, tuple[Floats, Floats] | None]:
    """Frame-weighted mean over episodes with an episode-level bootstrap interval: (value, (lo, hi)) per dim."""
    value = (per_episode * weights[:, None]).sum(0) / weights.sum()
    if len(per_episode) < 2:
        return value, None
    idx = rng.integers(0, len(per_episode), size=(n_boot, len(per_episode)))
    w = weights[idx]
    boot = (per_episode[idx] * w[..., None]).sum(1) / w.sum(1)[:, None]
    a = (1 - conf) / 2
    return value, (np.quantile(boot, a, axis=0), np.quantile(boot, 1 - a, axis=0))


def evaluate(cfg: ActionsConfig, policy_options: Any = None) -> dict[str, Any]:
    """Action errors of `cfg.policy` (built with `policy_options`) on the logged observations of `cfg.logs`."""
    if not cfg.logs:
        raise ConfigError("logs= is required (a LeRobot v3 dataset folder)")
    ds = read_dataset(cfg.logs)
    for feat in ("observation.state", "action"):
        if feat not in ds.features:
            raise DataError(f"{cfg.logs}: feature {feat!r} missing; bench actions needs observation.state and action")
    suite = registry.make_suite(cfg.suite)
    plugin = registry.load_policy(cfg.policy)
    options = policy_options if policy_options is not None else config_mod.build(plugin.Options, [])
    needs = [k for k in plugin.obs_keys(options) if k != STATE]
    if needs:
        raise ConfigError(f"policy {cfg.policy!r} needs observation keys {needs}; the logs give {STATE!r} only")
    identity = plugin.identity(options)
    cells = {c.key: c for c in suite.all_cells()}
    episodes = ds.episodes if cfg.episodes is None else [e for e in ds.episodes if e.index in set(cfg.episodes)]
    if not episodes:
        raise ConfigError(f"episodes={cfg.episodes}: none of these indices is in {cfg.logs}")
    built: dict[str, tuple[Any, Any]] = {}
    mae: list[Floats] = []
    mse: list[Floats] = []
    frames: list[int] = []
    stats: list[dict[str, Any]] = []
    action_names = ds.features["action"].get("names")
    ctx = PolicyContext(options, suite, cfg.seed, suite.default_horizon)
    try:
        for ep in episodes:
            key = episode_cell(cells, ep, cfg.logs, cfg.suite).key
            if key not in built:
                env = suite.make_env(cells[key], suite.default_horizon)
                names = ds.features["observation.state"].get("names")
                fields = list(env.obs_spec[STATE].fields)
                if names and list(names) != _expand(fields):
                    env.close()
                    raise DataError(
                        f"{cfg.logs}: observation.state names do not match suite {cfg.suite!r}'s "
                        f"observation ({names[:3]}... vs {_expand(fields)[:3]}...)"
                    )
                built[key] = (env, plugin.make(cells[key], env, ctx))
            env, policy = built[key]
            obs, act = ep.data["observation.state"], ep.data["action"]
            policy.reset(int(ep.meta.get("seed", 0)) if isinstance(ep.meta, dict) else 0)
            pred = np.stack([_first_action(policy.act({STATE: np.asarray(o, np.float32)})) for o in obs])
            if pred.shape != act.shape:
                raise DataError(f"{cfg.logs}: policy actions have shape {pred.shape[1:]}, logged {act.shape[1:]}")
            if plugin.reports_stats:  # e.g. a remote policy's round-trip latencies
                stats.append(policy.episode_stats())
            err = pred - act
            mae.append(np.abs(err).mean(0))
            mse.append((err**2).mean(0))
            frames.append(len(obs))
    finally:
        for env, _ in built.values():
            env.close()
    rng = np.random.default_rng(cfg.seed)
    w = np.asarray(frames, float)
    m, mci = _bootstrap(np.array(mae), w, rng, cfg.n_boot, cfg.confidence)
    s, sci = _bootstrap(np.array(mse), w, rng, cfg.n_boot, cfg.confidence)
    dims = action_names or [f"a{i}" for i in range(len(m))]
    per_dim = []
    for i, name in enumerate(dims):
        per_dim.append(
            {
                "dim": name,
                "mae": {"value": float(m[i]), "ci": None if mci is None else [float(mci[0][i]), float(mci[1][i])]},
                "rmse": {
                    "value": float(np.sqrt(s[i])),
                    "ci": None if sci is None else [float(np.sqrt(sci[0][i])), float(np.sqrt(sci[1][i]))],
                },
            }
        )
    reason = None if len(episodes) > 1 else "one episode: no interval"
    out: dict[str, Any] = {
        "schema": "bench.actions/1",
        "logs": str(cfg.logs),
        "policy": cfg.policy,
        "checkpoint": identity.checkpoint,
        "suite": cfg.suite,
        "episodes": len(episodes),
        "frames": int(w.sum()),
        "confidence": cfg.confidence,
        "interval": "bootstrap over episodes" if reason is None else reason,
        "per_dim": per_dim,
    }
    if stats:
        pooled = pool(stats)
        if pooled is not None:
            out["policy_latency"] = {k: v for k, v in pooled.items() if k != "bins"}
    return out


def actions(cfg: ActionsConfig, policy_options: Any = None) -> dict[str, Any]:
    """`evaluate`, with `cfg.out` checked first (never an input) and the result written there (schema bench.actions/1).

    `policy_options`: an instance of the policy plugin's Options (its own keys, e.g. checkpoint=); None = defaults.
    """
    if not cfg.logs:
        raise ConfigError("logs= is required (a LeRobot v3 dataset folder)")
    if cfg.out:
        outputs.check(
            "out",
            cfg.out,
            {"logs": cfg.logs, "checkpoint": getattr(policy_options, "checkpoint", None)},
            kind="file",
            overwrite=cfg.overwrite,
        )
    result = evaluate(cfg, policy_options)
    if cfg.out:
        write_atomic(Path(cfg.out), result)
    return result

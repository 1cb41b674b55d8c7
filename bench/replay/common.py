"""What both replay backends share: the config, reading and selecting episodes, the error summary."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from bench.core.config import ranged
from bench.core.errors import ConfigError, DataError
from bench.core.io import finite_or_none as finite
from bench.logs import read_dataset

SCHEMA = "bench.replay/1"
HORIZON_LABELS = {"one_step": "one-step", "k_step": "k-step", "free_run": "free run"}
STATIC = 1e-9  # a joint whose logged position spreads less than this has no NRMSE
COMMANDS = ("ctrl", "action")
BACKENDS = ("mujoco", "mjx")
CTRL = "action.ctrl"
ROLLOUT_BYTES = 256 * 2**20  # states returned by one mujoco.rollout call, at most


@dataclass(frozen=True)
class ReplayConfig:
    """Keys of `bench replay`."""

    logs: Optional[str] = None  # LeRobot v3 dataset folder
    spec: Optional[str] = None  # signal map (YAML/JSON; a calibration spec is one): MJCF model, log columns
    suite: Optional[str] = None  # instead of spec: suite whose env replays a `bench run record=` dataset
    k: int = ranged(10, 1, 100_000)  # frames per k-step horizon
    episodes: Optional[list[int]] = None  # dataset episode indices (default: all)
    out: Optional[str] = None  # folder for replay.json and replay.png (never an input or inside one)
    overwrite: bool = False  # replace an existing out= folder that bench wrote
    plot: int = ranged(2, 0, 50)  # episodes drawn in replay.png (0: no plot)
    threads: int = ranged(1, 1, 256)  # mujoco.rollout threads (results do not depend on it)
    commands: Optional[str] = None  # suite logs: ctrl (batched) | action (env step loop); default ctrl if logged
    backend: str = (
        "mujoco"  # spec replays: mujoco (mujoco.rollout on CPU threads) | mjx (one batched MJX call; the mjx extra)
    )
    perturb: dict[str, Any] = field(
        default_factory=dict
    )  # spec replays: physical-axis sweep, e.g. perturb.damping=[0.5,2] (docs/mjx.md)
    worlds: int = ranged(1, 1, 100_000)  # draws per perturb.AXIS=uniform(lo,hi) range (a grid level is one world)
    seed: int = ranged(0, 0)  # seed of the sweep's draws


@dataclass
class Replay:
    """What a replay measured: the JSON document plus the traces behind it (for the plot)."""

    doc: dict[str, Any]
    errors: dict  # horizon -> bench.replay.metrics.HorizonErrors
    qpos: np.ndarray  # (N, nq) logged positions of the replayed episodes, concatenated
    offsets: np.ndarray  # (E + 1,)
    fps: float
    joints: list[str]
    episodes: list[int]  # dataset indices, in replay order


# --- shared: reading, selecting, summarising ---------------------------------------------------------
def read_logs(cfg: ReplayConfig):
    path = Path(str(cfg.logs)).expanduser()
    if not path.exists():
        raise DataError(f"logs folder {str(path)!r} does not exist")
    ds = read_dataset(path, videos=False)  # replay needs the numeric features only: do not decode camera videos
    if not ds.episodes:
        raise DataError(f"{path}: the dataset holds no episodes")
    if cfg.episodes is None:
        return ds, list(ds.episodes)
    have = {ep.index: ep for ep in ds.episodes}
    missing = [i for i in cfg.episodes if i not in have]
    if missing:
        raise ConfigError(
            f"episodes={list(cfg.episodes)}: episode {missing[0]} is not in {path}; valid: "
            f"{min(have)}..{max(have)} ({len(have)} episodes)"
        )
    if len(set(cfg.episodes)) != len(cfg.episodes):
        raise ConfigError(f"episodes={list(cfg.episodes)}: an episode is listed twice")
    return ds, [have[i] for i in cfg.episodes]


def check_config(cfg: ReplayConfig) -> None:
    if not cfg.logs:
        raise ConfigError("logs= is required (a LeRobot v3 dataset folder)")
    if cfg.spec and cfg.suite:
        raise ConfigError("give spec= (MJCF replay) or suite= (replay of a `bench run record=` dataset), not both")
    if not cfg.spec and not cfg.suite:
        raise ConfigError(
            "spec= is required (a signal map naming the MJCF model and the log columns, "
            "docs/replay.md); for datasets written by `bench run record=`, give suite=NAME"
        )
    if cfg.episodes is not None and not cfg.episodes:
        raise ConfigError("episodes=[] selects nothing; list dataset episode indices, e.g. episodes=[0,3], or omit it")
    if cfg.k < 1:
        raise ConfigError(f"k must be an integer >= 1 (frames per k-step horizon); got {cfg.k}")
    if cfg.plot < 0:
        raise ConfigError(f"plot must be an integer >= 0 (episodes drawn); got {cfg.plot}")
    if not 1 <= cfg.threads <= 64:
        raise ConfigError(f"threads must be an integer in [1, 64]; got {cfg.threads}")
    if cfg.commands is not None and cfg.commands not in COMMANDS:
        raise ConfigError(f"commands is {cfg.commands!r}; valid: {', '.join(COMMANDS)} (suite logs only)")
    if cfg.backend not in BACKENDS:
        raise ConfigError(f"key 'backend': {cfg.backend!r} is not a replay backend; valid: {', '.join(BACKENDS)}")
    if cfg.suite and (cfg.backend != "mujoco" or cfg.perturb or cfg.worlds != 1):
        raise ConfigError(
            "backend=, perturb.* and worlds= apply to MJCF replays (spec=); a suite replay (suite=) runs in the "
            "suite's own env"
        )
    if cfg.commands is not None and not cfg.suite:
        raise ConfigError(
            "commands= applies to suite= replays of `bench run record=` datasets; an MJCF replay "
            "(spec=) applies the ctrl columns the spec names"
        )


def episode_of(offsets: np.ndarray, start: np.ndarray) -> np.ndarray:
    return np.searchsorted(offsets, start, side="right") - 1


def summarise(
    errors: dict, qpos: np.ndarray, offsets: np.ndarray, joints: list[str], episodes: list[int], k: int
) -> tuple[dict, list[dict]]:
    """JSON-able per-horizon (per joint) and per-episode errors; NRMSE is null for joints that never move.

    Per-episode NRMSE divides by the spread over all replayed episodes, so episodes compare.
    """
    spread = qpos.std(axis=0)
    moving = spread > STATIC
    horizons: dict[str, dict] = {}
    for label, e in errors.items():
        per_joint = {}
        for j, name in enumerate(joints):
            entry: dict[str, object] = {"rmse": finite(e.rmse[j]), "nrmse": finite(e.nrmse[j]) if moving[j] else None}
            if not moving[j]:
                entry["nrmse_reason"] = "the joint does not move in the replayed logs (position std 0)"
            per_joint[name] = entry
        horizons[label] = {
            "k": 1 if label == "one_step" else k if label == "k_step" else None,
            "segments": int(len(e.start)),
            "frames": int(e.mask.sum()),
            "rmse": finite(float(e.rmse.mean())),
            "nrmse": finite(float(e.nrmse[moving].mean())) if moving.any() else None,
            "per_joint": per_joint,
        }
    per_episode = []
    for i, index in enumerate(episodes):
        row: dict[str, object] = {"episode": int(index), "frames": int(offsets[i + 1] - offsets[i])}
        for label, e in errors.items():
            sel = episode_of(offsets, e.start) == i
            m = e.mask[sel]
            n = max(int(m.sum()), 1)
            err = np.where(m[..., None], e.pred[sel] - e.target[sel], 0.0)
            rmse = np.sqrt((err**2).sum(axis=(0, 1)) / n)
            row[f"{label}_rmse"] = finite(float(rmse.mean()))
            row[f"{label}_nrmse"] = finite(float((rmse[moving] / spread[moving]).mean())) if moving.any() else None
        per_episode.append(row)
    return horizons, per_episode


def measured(
    cfg: ReplayConfig,
    traces: Replay,
    backend: str,
    frames: int,
    steps: int,
    t0: float,
    notes: list[str],
    rows: list[dict[str, object]] | None = None,
    **extra: object,
) -> Replay:
    """`traces` (its doc empty) with its replay.json document (schema bench.replay/1): the errors summarised
    (`summarise`; `rows` adds fields to the per-episode rows), fields common to both backends, then `extra`."""
    horizons, per_episode = summarise(traces.errors, traces.qpos, traces.offsets, traces.joints, traces.episodes, cfg.k)
    short = int(np.sum(np.diff(traces.offsets) - 1 < cfg.k))
    if short:
        notes = [
            *notes,
            f"{short} of {len(traces.episodes)} episode(s) are shorter than k = {cfg.k} frames: their k-step "
            "horizon runs to the episode's end (as their free run does)",
        ]
    for row, more in zip(per_episode, rows or []):
        row.update(more)
    doc = {
        "schema": SCHEMA,
        "backend": backend,
        "logs": str(cfg.logs),
        **extra,
        "fps": float(traces.fps),
        "k": int(cfg.k),
        "episodes": [int(i) for i in traces.episodes],
        "frames": int(frames),
        "joints": traces.joints,
        "horizons": horizons,
        "per_episode": per_episode,
        "sim_steps": int(steps),
        "wall_s": round(time.perf_counter() - t0, 4),
        "notes": notes,
    }
    return dataclasses.replace(traces, doc=doc)

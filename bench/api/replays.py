"""`bench replay` from Python: logged commands replayed open loop in the simulator, per-joint RMSE/NRMSE at three
horizons (`bench.replay`; docs/replay.md), and OUT/replay.json with its plot."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.core import outputs
from bench.core.io import write_atomic
from bench.replay import replay_logs
from bench.replay.common import HORIZON_LABELS, Replay, ReplayConfig, episode_of

__all__ = ["HORIZON_LABELS", "Replay", "ReplayConfig", "ReplayResult", "plot", "replay", "write"]


@dataclass(frozen=True)
class ReplayResult:
    """What `replay` measured (`replay.doc` is replay.json's document) and where it wrote it (None: no out=)."""

    replay: Replay
    path: Path | None  # OUT/replay.json


def plot(rep: Replay, path: Path, n_episodes: int) -> Path | None:
    """Logged vs replayed (free run and k-step) positions per joint for the first `n_episodes` episodes."""
    import matplotlib  # matplotlib: loaded only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # matplotlib: loaded only when a figure is drawn

    n_ep = min(n_episodes, len(rep.episodes))
    if n_ep == 0:
        return None
    nj = len(rep.joints)
    fig, axes = plt.subplots(
        nj, n_ep, figsize=(6.0 * n_ep, 1.9 * nj + 0.8), sharex="col", squeeze=False, layout="constrained"
    )
    free, kst = rep.errors["free_run"], rep.errors["k_step"]
    for c in range(n_ep):
        a, b = int(rep.offsets[c]), int(rep.offsets[c + 1])
        t = np.arange(b - a) / rep.fps
        fsel = np.flatnonzero(episode_of(rep.offsets, free.start) == c)
        ksel = np.flatnonzero(episode_of(rep.offsets, kst.start) == c)
        for j in range(nj):
            ax = axes[j, c]
            ax.plot(t, rep.qpos[a:b, j], color="black", lw=1.4, label="logged")
            for s in ksel:  # each k-step segment starts from the logged state
                f0 = int(kst.start[s]) - a
                m = kst.mask[s]
                ax.plot(
                    t[f0 : f0 + 1 + int(m.sum())],
                    np.r_[rep.qpos[a + f0, j], kst.pred[s, m, j]],
                    color="tab:orange",
                    lw=1.0,
                    label="k-step" if s == ksel[0] else None,
                )
                ax.plot(t[f0], rep.qpos[a + f0, j], ".", color="tab:orange", ms=3)
            for s in fsel:
                m = free.mask[s]
                ax.plot(
                    t[: 1 + int(m.sum())],
                    np.r_[rep.qpos[a, j], free.pred[s, m, j]],
                    color="tab:blue",
                    lw=1.2,
                    ls="--",
                    label="free run",
                )
            if c == 0:
                ax.set_ylabel(rep.joints[j])
            if j == 0:
                ax.set_title(f"episode {rep.episodes[c]}")
        axes[-1, c].set_xlabel("time [s]")
    axes[0, 0].legend(loc="best", fontsize=8)
    fig.suptitle(f"logged vs replayed joint positions (k = {rep.doc['k']} frames)")
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def write(rep: Replay, out: Path, n_plot: int) -> Path:
    """OUT/replay.json (atomically, no NaN) and OUT/replay.png."""
    out.mkdir(parents=True, exist_ok=True)
    png = plot(rep, out / "replay.png", n_plot)
    rep.doc["plot"] = png.name if png else None
    path = out / "replay.json"
    write_atomic(path, rep.doc)
    return path


def replay(cfg: ReplayConfig) -> ReplayResult:
    """Replay `cfg.logs` (with `cfg.spec`'s model, or `cfg.suite`'s env); with `cfg.out`, OUT/replay.json and
    OUT/replay.png (the folder checked before the replay, swapped in whole after it)."""
    out = None
    if cfg.out:
        out = outputs.check("out", cfg.out, {"logs": cfg.logs, "spec": cfg.spec}, overwrite=cfg.overwrite)
    rep = replay_logs(cfg)
    if out is None:
        return ReplayResult(rep, None)
    outputs.replace_dir(out, lambda tmp: write(rep, tmp, cfg.plot))
    return ReplayResult(rep, out / "replay.json")

"""Errors of a simulated model against the logs: one-step, k-step and free-run, per joint.

All errors are on positions. NRMSE divides each joint's RMSE by the spread (std) of its logged
position over the same frames; R² is 1 - NRMSE².
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.replay.data import Recording, Window
from bench.replay.simulate import Segments, Simulator, Variant, free_runs, horizons, logged

HORIZONS = ("one_step", "k_step", "free_run")


def _per_joint(
    pred: np.ndarray, target: np.ndarray, mask: np.ndarray, spread: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RMSE, NRMSE and R² per channel over the masked frames."""
    err = np.where(mask[..., None], pred - target, 0.0)
    n = max(int(mask.sum()), 1)
    rmse = np.sqrt((err**2).sum(axis=(0, 1)) / n)
    nrmse = rmse / spread
    r2 = 1.0 - (rmse / spread) ** 2
    return rmse, nrmse, r2


@dataclass(frozen=True)
class HorizonErrors:
    """Per-joint position errors of one horizon kind, with the traces they were computed from."""

    rmse: np.ndarray  # (nq,)
    nrmse: np.ndarray  # (nq,) RMSE / std of the logged position over the same windows
    r2: np.ndarray  # (nq,)
    pred: np.ndarray  # (n, length, nq) simulated positions at the frames each segment predicts
    target: np.ndarray  # (n, length, nq) logged positions at those frames
    mask: np.ndarray  # (n, length) frames that exist
    start: np.ndarray  # (n,) global frame each segment starts from


def horizon_segments(rec: Recording, windows: list[Window], k: int) -> dict[str, Segments]:
    """The segments of each horizon kind: one-step, k-step and free-run."""
    return {
        "one_step": horizons(rec, windows, 1),
        "k_step": horizons(rec, windows, k),
        "free_run": free_runs(rec, windows),
    }


def segment_errors(pred: np.ndarray, rec: Recording, segs: Segments, spread: np.ndarray) -> HorizonErrors:
    """Per-joint errors of simulated positions `pred` (n, length, nq) against the logged ones."""
    target = logged(rec, segs)[..., : pred.shape[-1]]
    mask = segs.mask if segs.mask is not None else np.ones((len(segs), segs.length), bool)
    rmse, nrmse, r2 = _per_joint(pred, target, mask, spread)
    return HorizonErrors(rmse, nrmse, r2, pred, target, mask, segs.start)


def horizon_errors(
    sim: Simulator, variant: Variant, rec: Recording, windows: list[Window], k: int
) -> dict[str, HorizonErrors]:
    """One-step, k-step (re-initialised from the log every k frames) and free-run errors of one variant.

    Every segment starts from the logged state and is driven by the logged command; all segments of
    one horizon kind run in one batched rollout.
    """
    nq = rec.qpos.shape[1]
    spread = np.maximum(rec.qpos[rec.frames(windows)].std(axis=0), 1e-12)
    return {
        label: segment_errors(sim.run([variant], segs)[0][..., :nq], rec, segs, spread)
        for label, segs in horizon_segments(rec, windows, k).items()
    }

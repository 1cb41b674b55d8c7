"""Held-out errors of a simulated model against the logs: one-step, k-step and free-run, per joint.

All errors are on positions. NRMSE divides each joint's RMSE by the spread (std) of its logged
position over the same frames; the summary is the mean over joints. R² is the free-run one.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench.calibrate.data import Recording, Window
from bench.calibrate.model import Layout, Variant
from bench.calibrate.simulate import Segments, Simulator, free_runs, horizons, logged


def _clean(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def _per_joint(pred: np.ndarray, target: np.ndarray, mask: np.ndarray, spread: np.ndarray) \
        -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RMSE, NRMSE and R² per channel over the masked frames."""
    err = np.where(mask[..., None], pred - target, 0.0)
    n = max(int(mask.sum()), 1)
    rmse = np.sqrt((err ** 2).sum(axis=(0, 1)) / n)
    nrmse = rmse / spread
    r2 = 1.0 - (rmse / spread) ** 2
    return rmse, nrmse, r2


HORIZONS = ("one_step", "k_step", "free_run")


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


def horizon_errors(sim: Simulator, variant: Variant, rec: Recording, windows: list[Window], k: int) \
        -> dict[str, HorizonErrors]:
    """One-step, k-step (re-initialised from the log every k frames) and free-run errors of one variant.

    Every segment starts from the logged state and is driven by the logged command; all segments of
    one horizon kind run in one batched rollout.
    """
    nq = rec.qpos.shape[1]
    spread = np.maximum(rec.qpos[rec.frames(windows)].std(axis=0), 1e-12)
    return {label: segment_errors(sim.run([variant], segs)[0][..., :nq], rec, segs, spread)
            for label, segs in horizon_segments(rec, windows, k).items()}


def horizon_segments(rec: Recording, windows: list[Window], k: int) -> dict[str, Segments]:
    """The segments of each horizon kind: one-step, k-step and free-run."""
    return {"one_step": horizons(rec, windows, 1), "k_step": horizons(rec, windows, k),
            "free_run": free_runs(rec, windows)}


def segment_errors(pred: np.ndarray, rec: Recording, segs: Segments, spread: np.ndarray) -> HorizonErrors:
    """Per-joint errors of simulated positions `pred` (n, length, nq) against the logged ones."""
    target = logged(rec, segs)[..., : pred.shape[-1]]
    mask = segs.mask if segs.mask is not None else np.ones((len(segs), segs.length), bool)
    rmse, nrmse, r2 = _per_joint(pred, target, mask, spread)
    return HorizonErrors(rmse, nrmse, r2, pred, target, mask, segs.start)


def evaluate(sim: Simulator, layout: Layout, x: np.ndarray, rec: Recording, windows: list[Window], k: int,
             names: list[str]) -> tuple[dict, dict[str, np.ndarray]]:
    """Error summary (JSON-able) and the free-run traces (for plots) of parameter vector x."""
    out: dict = {}
    traces: dict[str, np.ndarray] = {}
    for label, e in horizon_errors(sim, layout.realise(x), rec, windows, k).items():
        out[f"{label}_nrmse"] = _clean(float(e.nrmse.mean()))
        out[f"{label}_rmse"] = _clean(float(e.rmse.mean()))
        if label == "free_run":
            out["r2"] = _clean(float(e.r2.mean()))
            out["per_joint"] = {nm: {"free_run_rmse": _clean(a), "free_run_nrmse": _clean(b), "r2": _clean(c)}
                                for nm, a, b, c in zip(names, e.rmse, e.nrmse, e.r2)}
            traces = {"pred": e.pred, "target": e.target, "mask": e.mask, "start": e.start}
    out["k"] = k
    return out, traces


def heldout_errors(sim: Simulator, pairs: list[tuple[Layout, np.ndarray]], segs: Segments, rec: Recording,
                   scale: np.ndarray, channels: np.ndarray) -> list[float]:
    """RMS of the normalised k-step residual (the fit objective) of several (layout, vector) pairs."""
    if not pairs:
        return []
    pred = sim.run([layout.realise(x) for layout, x in pairs], segs)[..., channels]
    r = (pred - logged(rec, segs)[None][..., channels]) / scale[channels]
    return [float(np.sqrt(np.mean(ri ** 2))) for ri in r]


def kstep_error(sim: Simulator, layout: Layout, x: np.ndarray, segs: Segments, rec: Recording,
                scale: np.ndarray, channels: np.ndarray) -> float:
    """RMS of the normalised k-step residual of one parameter vector."""
    return heldout_errors(sim, [(layout, x)], segs, rec, scale, channels)[0]

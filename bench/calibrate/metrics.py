"""Held-out errors of a simulated model against the logs: one-step, k-step and free-run, per joint.

All errors are on positions. NRMSE divides each joint's RMSE by the spread (std) of its logged
position over the same frames; the summary is the mean over joints. R² is the free-run one.
"""
from __future__ import annotations

import math

import numpy as np

from bench.calibrate.data import Recording, Window
from bench.calibrate.model import Layout
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


def evaluate(sim: Simulator, layout: Layout, x: np.ndarray, rec: Recording, windows: list[Window], k: int,
             names: list[str]) -> tuple[dict, dict[str, np.ndarray]]:
    """Error summary (JSON-able) and the free-run traces (for plots) of parameter vector x."""
    nq = rec.qpos.shape[1]
    frames = rec.frames(windows)
    spread = np.maximum(rec.qpos[frames].std(axis=0), 1e-12)
    variant = layout.realise(x)
    out: dict = {}
    traces: dict[str, np.ndarray] = {}
    for label, segs in (("one_step", horizons(rec, windows, 1)), ("k_step", horizons(rec, windows, k)),
                        ("free_run", free_runs(rec, windows))):
        pred = sim.run([variant], segs)[0][..., :nq]
        target = logged(rec, segs)[..., :nq]
        mask = segs.mask if segs.mask is not None else np.ones((len(segs), segs.length), bool)
        rmse, nrmse, r2 = _per_joint(pred, target, mask, spread)
        out[f"{label}_nrmse"] = _clean(float(nrmse.mean()))
        out[f"{label}_rmse"] = _clean(float(rmse.mean()))
        if label == "free_run":
            out["r2"] = _clean(float(r2.mean()))
            out["per_joint"] = {nm: {"free_run_rmse": _clean(a), "free_run_nrmse": _clean(b), "r2": _clean(c)}
                                for nm, a, b, c in zip(names, rmse, nrmse, r2)}
            traces = {"pred": pred, "target": target, "mask": mask, "start": segs.start}
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

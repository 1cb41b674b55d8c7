"""Held-out errors of a calibrated model: the report's error summary and the loop's k-step objective.

The per-joint errors themselves (one-step, k-step, free run) are replay's (`bench.replay.metrics`).
"""

from __future__ import annotations

import numpy as np

from bench.calibrate.model import Layout
from bench.core.io import finite_or_none as finite
from bench.replay.data import Recording, Window
from bench.replay.metrics import horizon_errors
from bench.replay.simulate import Segments, Simulator, logged


def evaluate(
    sim: Simulator, layout: Layout, x: np.ndarray, rec: Recording, windows: list[Window], k: int, names: list[str]
) -> tuple[dict, dict[str, np.ndarray]]:
    """Error summary (JSON-able) and the free-run traces (for plots) of parameter vector x."""
    out: dict = {}
    traces: dict[str, np.ndarray] = {}
    for label, e in horizon_errors(sim, layout.realise(x), rec, windows, k).items():
        out[f"{label}_nrmse"] = finite(float(e.nrmse.mean()))
        out[f"{label}_rmse"] = finite(float(e.rmse.mean()))
        if label == "free_run":
            out["r2"] = finite(float(e.r2.mean()))
            out["per_joint"] = {
                nm: {"free_run_rmse": finite(a), "free_run_nrmse": finite(b), "r2": finite(c)}
                for nm, a, b, c in zip(names, e.rmse, e.nrmse, e.r2)
            }
            traces = {"pred": e.pred, "target": e.target, "mask": e.mask, "start": e.start}
    out["k"] = k
    return out, traces


def heldout_errors(
    sim: Simulator,
    pairs: list[tuple[Layout, np.ndarray]],
    segs: Segments,
    rec: Recording,
    scale: np.ndarray,
    channels: np.ndarray,
) -> list[float]:
    """RMS of the normalised k-step residual (the fit objective) of several (layout, vector) pairs."""
    if not pairs:
        return []
    pred = sim.run([layout.realise(x) for layout, x in pairs], segs)[..., channels]
    r = (pred - logged(rec, segs)[None][..., channels]) / scale[channels]
    return [float(np.sqrt(np.mean(ri**2))) for ri in r]


def kstep_error(
    sim: Simulator,
    layout: Layout,
    x: np.ndarray,
    segs: Segments,
    rec: Recording,
    scale: np.ndarray,
    channels: np.ndarray,
) -> float:
    """RMS of the normalised k-step residual of one parameter vector."""
    return heldout_errors(sim, [(layout, x)], segs, rec, scale, channels)[0]

"""Held-out errors of a calibrated model: the report's error summary, the loop's k-step objective, the
repeat baseline (memory of the fitted log, `bench.calibrate.novelty`) scored beside it, and the `trust` verdict.

The per-joint errors themselves (one-step, k-step, free run) are replay's (`bench.replay.metrics`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TypedDict

import numpy as np

from bench.calibrate import novelty
from bench.calibrate.model import Layout
from bench.core.io import finite_or_none as finite
from bench.replay.data import Recording, Window
from bench.replay.metrics import horizon_errors, segment_errors
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


class Memory(TypedDict, total=False):
    """One repeat baseline scored on the held-out horizons; `covered_share` for the period one."""

    k_step_nrmse: float
    k_step_rmse: float
    what: str
    covered_share: float


class ForwardCheck(TypedDict):
    criterion: str
    declared: float | None
    calibrated: float | None
    simulates_better: bool
    rose: list[str]


class Trust(TypedDict):
    """calibration.json's `trust` section of a suite or MJCF calibration (`trust`)."""

    heldout: dict[str, object]
    repeat_baseline_nrmse: float | None
    beats_repeat: bool
    forward: ForwardCheck
    simulates_better: bool


def repeat_baseline(rec: Recording, hold: Segments, period: float | None) -> dict[str, object]:
    """Memory on the held-out k-step horizons `hold`, scored like the models (`segment_errors`, the same spread).

    `nearest`: each horizon continues like the fitted horizon whose start state ([qpos, qvel] over their
    spread) is nearest (`novelty.nearest_motion`); `period` (when a period is known): like the motion one
    period earlier where that stretch was fitted, the nearest fitted horizon elsewhere. A model is called
    better than memory only if its k-step NRMSE is below the better of the two (`best`).
    """
    length = hold.length
    feats = np.concatenate([rec.qpos, rec.qvel], axis=1)
    scale = novelty.spread(feats)
    fit_starts = novelty.horizon_starts(rec.offsets, rec.train, length)
    if len(hold) == 0 or len(fit_starts) == 0:
        return {"k_step_nrmse": None, "best": None, "what": f"no fitted stretch of {length} frames to remember"}
    spread = np.maximum(rec.qpos[rec.frames(rec.holdout)].std(axis=0), 1e-12)
    near = novelty.nearest_motion(rec.qpos, feats, hold.start, fit_starts, length + 1, scale)[:, 1:]
    out: dict[str, Memory] = {}

    def score(pred: np.ndarray, what: str, covered_share: float | None = None) -> Memory:
        e = segment_errors(pred, rec, hold, spread)
        m: Memory = {"k_step_nrmse": float(e.nrmse.mean()), "k_step_rmse": float(e.rmse.mean()), "what": what}
        if covered_share is not None:
            m["covered_share"] = covered_share
        return m

    out["nearest"] = score(near, "positions continue like the fitted horizon of the nearest logged state")
    if period:
        pred, covered = _period_motion(rec, hold, period)
        pred[~covered] = near[~covered]
        out["period"] = score(
            pred,
            f"positions continue like the logged motion one period ({period:.4g} s) earlier where that was fitted, "
            "the nearest fitted horizon elsewhere",
            covered_share=float(covered.mean()),
        )
    best = min((key for key in ("nearest", "period") if key in out), key=lambda key: out[key]["k_step_nrmse"])
    return {
        "k_step_nrmse": out[best]["k_step_nrmse"],
        "k_step_rmse": out[best]["k_step_rmse"],
        "best": best,
        "what": "the repeat baseline (memory of the fitted log): " + out[best]["what"],
        "k": length,
        **out,
    }


def _period_motion(rec: Recording, hold: Segments, period: float) -> tuple[np.ndarray, np.ndarray]:
    """Positions each held-out horizon reaches if it moves as the log did one period earlier (n, length, nq), and
    which horizons had that stretch fitted (n,)."""
    length, nq = hold.length, rec.qpos.shape[1]
    pred = np.zeros((len(hold), length, nq))
    covered = np.zeros(len(hold), bool)
    episode = np.searchsorted(rec.offsets, hold.start, side="right") - 1
    mask = hold.mask if hold.mask is not None else np.ones((len(hold), length), bool)
    for e in np.unique(episode):
        a, b = int(rec.offsets[e]), int(rec.offsets[e + 1])
        fitted = np.zeros(b - a, bool)
        for w in rec.train:
            if w.episode == e:
                fitted[w.start : w.stop] = True
        sel = np.flatnonzero(episode == e)
        rows = np.minimum(hold.start[sel, None] - a + np.arange(length + 1)[None, :], b - a - 1)
        t = np.arange(b - a) / rec.fps
        past = novelty.period_signal(rec.qpos[a:b], t, period, fitted, rows.ravel()).reshape(len(sel), length + 1, nq)
        pred[sel] = rec.qpos[hold.start[sel]][:, None, :] + past[:, 1:] - past[:, :1]
        ok = np.isfinite(past[:, 0, 0]) & np.all(np.isfinite(past[:, 1:, 0]) | ~mask[sel], axis=1)
        covered[sel] = ok
    return pred, covered


def trust(heldout: novelty.Heldout, errors: dict[str, dict]) -> Trust:
    """calibration.json's `trust` section (shaped like the arm calibration's): how new the held-out data are,
    whether the final model beats memory (the repeat baseline) and simulates them at least as well as the model
    as given on every horizon (`bench run ... calibration=` reads `simulates_better` and `heldout.repeat_share`)."""
    nominal, final, repeat = errors["nominal"], errors["final"], errors.get("repeat", {})
    rose = []
    for name, key in (("k-step", "k_step_nrmse"), ("free run", "free_run_nrmse")):
        a, b = nominal.get(key), final.get(key)
        if b is None or (a is not None and b > a * 1.001):
            rose.append(f"{name}: {a if a is None else round(a, 5)} -> {b if b is None else round(b, 5)}")
    base, k1 = repeat.get("k_step_nrmse"), final.get("k_step_nrmse")
    forward: ForwardCheck = {
        "criterion": "held-out free-run and k-step position NRMSE",
        "declared": nominal.get("free_run_nrmse"),
        "calibrated": final.get("free_run_nrmse"),
        "simulates_better": not rose,
        "rose": rose,
    }
    return {
        "heldout": heldout.to_json(),
        "repeat_baseline_nrmse": base,
        "beats_repeat": bool(base is not None and k1 is not None and k1 < base),
        "forward": forward,
        "simulates_better": forward["simulates_better"],
    }


def against_memory(errors: dict[str, dict], verdict: Mapping[str, object]) -> str:
    """'k-step 0.0042 against 0.42 for the repeat baseline (beats it)': the final model beside memory, for the log."""
    fmt = lambda v: "n/a" if v is None else f"{v:.4g}"  # noqa: E731
    rep = errors.get("repeat", {}).get("k_step_nrmse")
    beats = "beats it" if verdict["beats_repeat"] else "does not beat it"
    return f"k-step {fmt(errors['final'].get('k_step_nrmse'))} against {fmt(rep)} for the repeat baseline ({beats})"


def trust_warnings(heldout: novelty.Heldout, errors: dict[str, dict], verdict: Trust) -> list[str]:
    """What the `trust` section says that a user must not miss: nothing new held out, memory as good as the
    model, a model that simulates worse than the one given."""
    out = [heldout.sentence()] if heldout.nothing_new else []
    rep, k1 = errors.get("repeat", {}), errors["final"].get("k_step_nrmse")
    if rep.get("k_step_nrmse") is not None and not verdict["beats_repeat"]:
        out.append(
            f"the calibrated model does not beat the repeat baseline on the held-out horizons (k-step NRMSE "
            f"{k1 if k1 is None else f'{k1:.4g}'} against {rep['k_step_nrmse']:.4g} for {rep[rep['best']]['what']}): "
            "its held-out error says nothing a memory of the log would not"
        )
    if not verdict["simulates_better"]:
        out.append(
            "the calibrated model simulates the held-out data worse than the model as given ("
            + "; ".join(verdict["forward"]["rose"])
            + "): trust.simulates_better is false"
        )
    return out

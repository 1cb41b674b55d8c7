"""`bench predict` from Python: a policy's real success rate from a sim run plus a few real trials
(prediction-powered inference, `bench.scoring.predict`; docs/predict.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from bench.core import outputs
from bench.core.config import ranged
from bench.core.errors import ConfigError, DataError
from bench.core.io import write_atomic
from bench.scoring.predict.ppi import AGRESTI_MIN, Prediction, predict, trials_for_width
from bench.scoring.predict.tables import episode_strata, load_table, pair, rows_of_run, unit_strata
from bench.scoring.summary import load_run

__all__ = ["PredictConfig", "predict_real"]

LEVELS = ("episode", "unit")


@dataclass(frozen=True)
class PredictConfig:
    """Keys of `bench predict`."""

    sim: Optional[str] = (
        None  # a `bench run` directory of the policy, or a sim outcome table (CSV/JSON, docs/predict.md)
    )
    real: Optional[str] = (
        None  # the real outcome table: cell, condition, seed or episode (pairs), success (docs/predict.md)
    )
    metric: Optional[str] = None  # success_once | success_at_end (default: the run's metric, else success_once)
    level: str = (
        "episode"  # episode: trials paired by seed; unit: each (policy, cell, condition) one unit, its rate the outcome
    )
    confidence: float = ranged(0.95, 0, 1, lo_open=True, hi_open=True)  # two-sided coverage of the intervals
    width: Optional[float] = ranged(
        None, 0, 1, lo_open=True, hi_open=True
    )  # target interval width: real trials needed for it
    out: Optional[str] = None  # also write the report as JSON
    overwrite: bool = False  # replace an existing out= file that bench wrote


def _sim_rows(cfg: PredictConfig) -> tuple[list[Any], str, str]:
    """(sim rows, metric, how the sim is named in errors)."""
    path = Path(str(cfg.sim))
    if path.is_dir():
        records, meta = load_run(path)
        metric = cfg.metric or meta.get("config", {}).get("metric") or "success_once"
        if metric not in ("success_once", "success_at_end"):
            metric = "success_once"  # a run scored by return still records both successes
        policy = str(meta.get("policy", {}).get("name") or "")
        rows = rows_of_run(records, policy, metric)
        if not rows:
            raise DataError(f"sim={path}: no completed episode to predict from")
        return rows, metric, f"the sim run {path}"
    if cfg.metric:
        raise ConfigError(f"metric={cfg.metric!r} applies to a sim run directory; sim={path} is a table")
    return load_table(path, "sim"), "success", f"sim={path}"


def _estimate(lo: float, value: float, hi: float) -> dict[str, Any]:
    return {"value": round(value, 6), "ci": [round(lo, 6), round(hi, 6)]}


def _finite(x: float) -> float | None:
    return None if not math.isfinite(x) else round(x, 3)


def report_of(res: Prediction) -> dict[str, Any]:
    """The numbers of a prediction as the report holds them (undefined ones null)."""
    return {
        "estimate": _estimate(res.lo, res.value, res.hi),
        "real_only": _estimate(res.real_lo, res.real_value, res.real_hi),
        "width": round(res.width, 6),
        "real_only_width": round(res.real_width, 6),
        "width_ratio": round(res.width / res.real_width, 4) if res.real_width > 0 else None,
        "lambda": round(res.lam, 4),
        "effective_real_trials": round(res.n_eff, 2),
        "real_only_trials": round(res.n_ref, 2),
        "real_trials": {"paired": res.n_paired, "unpaired": res.n_unpaired},
        "sim_episodes_unpaired": _finite(res.sim_n),
    }


def predict_real(cfg: PredictConfig) -> dict[str, Any]:
    """The report (schema bench.predict/1): the real success rate with its prediction-powered interval, the
    real-only Wilson interval, their widths, PPI++'s λ, and with `width=` the real trials needed for it.

    Raises:
        ConfigError / DataError: missing keys, an unknown level, tables that do not match the sim run.
    """
    for key in ("sim", "real"):
        if not getattr(cfg, key):
            raise ConfigError(f"missing key {key!r}: bench predict sim=RUN_DIR real=TABLE")
    if cfg.level not in LEVELS:
        raise ConfigError(f"level={cfg.level!r} is not valid; valid: {', '.join(LEVELS)}")
    real_path = str(cfg.real)
    if cfg.out:
        outputs.check("out", cfg.out, {"sim": str(cfg.sim), "real": real_path}, kind="file", overwrite=cfg.overwrite)
    sim_rows, metric, sim_name = _sim_rows(cfg)
    real_rows = load_table(real_path, "real")
    matched = pair(sim_rows, real_rows, sim_name)
    unit = cfg.level == "unit"
    strata = unit_strata(matched) if unit else episode_strata(matched)
    pseudo = 0.0 if unit else AGRESTI_MIN
    res = predict(strata, cfg.confidence, pseudo=pseudo, unit=unit)
    doc: dict[str, Any] = {
        "schema": "bench.predict/1",
        "sim": str(cfg.sim),
        "real": real_path,
        "metric": metric,
        "level": cfg.level,
        "confidence": cfg.confidence,
        "method": "PPI++ (Angelopoulos et al. 2023), Agresti-Min paired moments, Wilson score at n_eff",
        **report_of(res),
        "strata": [
            {
                "key": st.key,
                "real_trials": st.n,
                "paired": len(st.y_paired),
                "real_rate": round(float((st.y_paired.sum() + st.y_unpaired.sum()) / st.n), 6),
                "sim_rate": None if st.sim_mean is None else round(st.sim_mean, 6),
            }
            for st in strata
        ],
        "units": len(matched.all_keys) if unit else None,
    }
    if cfg.width is not None:
        with_sim, real_only = trials_for_width(strata, cfg.width, cfg.confidence, pseudo=pseudo, unit=unit)
        doc["target"] = {"width": cfg.width, "real_trials_with_sim": with_sim, "real_trials_real_only": real_only}
    if cfg.out:
        write_atomic(Path(cfg.out), doc)
    return doc

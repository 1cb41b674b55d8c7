"""Sim-real agreement: does the simulator rank policies the way the real robot does?

Input: two per-policy outcome tables (sim and real), each rows of {policy, trials, successes}.
Output: Pearson, Spearman and Kendall correlations of the success rates and MMRV (mean maximum
rank violation, SIMPLER, Li et al. 2024), each with a bootstrap interval that resamples the
trials on both sides.

MMRV is not symmetric. For N policies with real rates R and simulated rates S,

    MMRV = 1/N * sum_i max_j |R_i - R_j| * 1[(S_i < S_j) != (R_i < R_j)]

a pair ranked differently by sim and real costs the *real* gap between the two policies: a swap
of two policies that are equally good on the robot is free, a swap that hides a real difference
is not. Swapping the arguments weights by the simulated gap instead, a different number, and the
published helper `mean_maximum_rank_violation(perf_sim, perf_real)` is easy to call the wrong
way round: `mmrv` here takes keyword-only `sim=` and `real=`. With ties, the strict `<` of the
paper is kept: a sim tie over a real difference is charged to the policy that is worse on the
real robot (SIMPLER's code uses `>` and charges the better one; identical without ties).
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from bench.core.errors import ConfigError, DataError, did_you_mean

STATISTICS = ("pearson", "spearman", "kendall", "mmrv")


@dataclass(frozen=True)
class Outcome:
    """Trials and successes of one policy in one setting."""

    trials: int
    successes: int

    @property
    def rate(self) -> float:
        return self.successes / self.trials


# ----------------------------------------------------------------------------- tables


def _int(value: object, where: str, field: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise DataError(f"{where}: field {field!r} is {value!r}; expected a non-negative integer")
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise DataError(f"{where}: field {field!r} is {value!r}; expected a non-negative integer") from None
    if not math.isfinite(f) or f != int(f) or f < 0:
        raise DataError(f"{where}: field {field!r} is {value!r}; expected a non-negative integer")
    return int(f)


def load_outcomes(path: str | Path) -> dict[str, Outcome]:
    """Read a per-policy outcome table from JSON or CSV.

    JSON: a list of {"policy", "trials", "successes"} rows, the same under a "policies" key, or
    {policy: {"trials", "successes"}}. CSV: a header row with columns policy, trials, successes.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: file is missing")
    rows: list[dict] = []
    if path.suffix.lower() == ".json":
        try:
            doc = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise DataError(f"{path}: not valid JSON: {str(exc).splitlines()[0]}") from None
        if isinstance(doc, dict) and isinstance(doc.get("policies"), list):
            doc = doc["policies"]
        if isinstance(doc, dict):
            rows = [{"policy": k, **v} if isinstance(v, dict) else {"policy": k, "bad": v} for k, v in doc.items()]
        elif isinstance(doc, list):
            rows = doc
        else:
            raise DataError(f"{path}: expected a list of {{policy, trials, successes}} rows")
    else:
        try:
            with path.open(newline="") as f:
                rows = list(csv.DictReader(f))
        except (OSError, UnicodeDecodeError, csv.Error) as exc:
            raise DataError(f"{path}: cannot read CSV: {exc}") from None
    table: dict[str, Outcome] = {}
    for i, row in enumerate(rows):
        where = f"{path}: row {i}"
        if not isinstance(row, dict):
            raise DataError(f"{where}: expected an object with policy, trials, successes")
        for key in ("policy", "trials", "successes"):
            if row.get(key) in (None, ""):
                raise DataError(f"{where}: field {key!r} is missing")
        name = str(row["policy"]).strip()
        trials, successes = _int(row["trials"], where, "trials"), _int(row["successes"], where, "successes")
        if trials == 0:
            raise DataError(f"{where}: field 'trials' is 0 for policy {name!r}; need at least one trial")
        if successes > trials:
            raise DataError(f"{where}: field 'successes' is {successes} > trials {trials} for policy {name!r}")
        if name in table:
            raise DataError(f"{where}: policy {name!r} appears twice")
        table[name] = Outcome(trials, successes)
    if not table:
        raise DataError(f"{path}: no policies")
    return table


def pair_tables(
    sim: dict[str, Outcome], real: dict[str, Outcome], sim_name: str = "sim", real_name: str = "real"
) -> list[str]:
    """Policies present in both tables (in the sim table's order); a policy in only one is a DataError."""
    for name in sim:
        if name not in real:
            raise DataError(f"{real_name}: policy {name!r} is in {sim_name} but not here.{did_you_mean(name, real)}")
    for name in real:
        if name not in sim:
            raise DataError(f"{sim_name}: policy {name!r} is in {real_name} but not here.{did_you_mean(name, sim)}")
    if len(sim) < 2:
        raise DataError(f"{sim_name}: {len(sim)} policy; agreement needs at least 2")
    return list(sim)


# ----------------------------------------------------------------------------- statistics


def mmrv(*, sim: npt.ArrayLike, real: npt.ArrayLike) -> float:
    """Mean maximum rank violation of simulated rates `sim` against real rates `real` (lower is better).

    Each policy i is charged the largest real gap |real_i - real_j| over the policies j that sim
    orders differently from real; MMRV is the mean charge. Keyword-only: the result weights by
    the real gaps, so mmrv(sim=a, real=b) != mmrv(sim=b, real=a) in general.
    """
    s, r = np.asarray(sim, dtype=np.float64), np.asarray(real, dtype=np.float64)
    if s.shape != r.shape or s.ndim != 1:
        raise DataError(f"mmrv: sim and real must be 1-D of equal length, got {s.shape} and {r.shape}")
    return float(_mmrv_batch(s[None], r[None])[0])


def _mmrv_batch(s: np.ndarray, r: np.ndarray) -> np.ndarray:
    """MMRV of each row of (B, N) sim and real rates."""
    violated = (s[:, :, None] < s[:, None, :]) != (r[:, :, None] < r[:, None, :])
    cost = np.abs(r[:, :, None] - r[:, None, :]) * violated
    return cost.max(axis=2).mean(axis=1)


def _pearson_batch(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Pearson r of each row; NaN where a row is constant (undefined)."""
    dx = x - x.mean(axis=1, keepdims=True)
    dy = y - y.mean(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = (dx * dy).sum(axis=1) / np.sqrt((dx * dx).sum(axis=1) * (dy * dy).sum(axis=1))
    r[(np.ptp(x, axis=1) == 0) | (np.ptp(y, axis=1) == 0)] = np.nan
    return np.clip(r, -1.0, 1.0)


def _ranks_batch(x: np.ndarray) -> np.ndarray:
    from scipy.stats import rankdata  # scipy: loaded only when this estimate is computed

    return rankdata(x, axis=1)  # average ranks for ties, as scipy.stats.spearmanr


def _kendall_batch(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Kendall tau-b of each row (scipy's default variant); NaN where undefined."""
    i, j = np.triu_indices(x.shape[1], k=1)
    sx, sy = np.sign(x[:, i] - x[:, j]), np.sign(y[:, i] - y[:, j])
    with np.errstate(invalid="ignore", divide="ignore"):
        return (sx * sy).sum(axis=1) / np.sqrt((sx * sx).sum(axis=1) * (sy * sy).sum(axis=1))


def _batch(name: str, s: np.ndarray, r: np.ndarray) -> np.ndarray:
    if name == "pearson":
        return _pearson_batch(s, r)
    if name == "spearman":
        return _pearson_batch(_ranks_batch(s), _ranks_batch(r))
    if name == "kendall":
        return _kendall_batch(s, r)
    return _mmrv_batch(s, r)


def point_estimates(sim: np.ndarray, real: np.ndarray) -> dict[str, float | None]:
    """Pearson, Spearman, Kendall (scipy.stats) and MMRV of two rate vectors; None where undefined."""
    from scipy import stats  # scipy: loaded only when this estimate is computed

    sim, real = np.asarray(sim, dtype=np.float64), np.asarray(real, dtype=np.float64)
    out: dict[str, float | None] = {}
    constant = np.ptp(sim) == 0 or np.ptp(real) == 0
    for name, fn in (("pearson", stats.pearsonr), ("spearman", stats.spearmanr), ("kendall", stats.kendalltau)):
        out[name] = None if constant else float(fn(sim, real)[0])
    out["mmrv"] = mmrv(sim=sim, real=real)
    return out


def _undefined_reason(sim: np.ndarray, real: np.ndarray) -> str:
    which = [n for n, v in (("sim", sim), ("real", real)) if np.ptp(v) == 0]
    return f"undefined: every policy has the same {' and '.join(which)} success rate"


def agreement(
    sim: dict[str, Outcome],
    real: dict[str, Outcome],
    *,
    n_boot: int = 2000,
    seed: int = 0,
    level: float = 0.95,
    sim_name: str = "sim",
    real_name: str = "real",
) -> dict:
    """Agreement statistics with percentile bootstrap intervals.

    Each bootstrap replicate redraws every policy's trials with replacement, independently in sim
    and in real: successes ~ Binomial(trials, observed rate), which is exactly resampling the
    observed 0/1 outcomes. Replicates where a correlation is undefined (all rates equal) are left
    out of that statistic's interval and counted.

    Returns:
        A JSON-ready dict: {"policies": [{policy, sim: {...}, real: {...}}], "statistics": {name:
        {"value", "ci": [lo, hi], "n_boot_defined", "reason"}}, "n_boot", "seed", "level"};
        undefined values are None with a reason, never NaN.
    """
    if n_boot < 1:
        raise ConfigError(f"n_boot is {n_boot}; expected a positive integer")
    if not 0 < level < 1:
        raise ConfigError(f"level is {level}; expected a number in (0, 1)")
    names = pair_tables(sim, real, sim_name, real_name)
    n_sim = np.asarray([sim[p].trials for p in names])
    n_real = np.asarray([real[p].trials for p in names])
    p_sim = np.asarray([sim[p].rate for p in names])
    p_real = np.asarray([real[p].rate for p in names])
    point = point_estimates(p_sim, p_real)

    rng = np.random.default_rng(seed)
    boot_sim = rng.binomial(n_sim, p_sim, size=(n_boot, len(names))) / n_sim
    boot_real = rng.binomial(n_real, p_real, size=(n_boot, len(names))) / n_real
    alpha = (1 - level) / 2
    statistics: dict[str, dict[str, object]] = {}
    for name in STATISTICS:
        values = _batch(name, boot_sim, boot_real)
        ok = values[np.isfinite(values)]
        entry: dict[str, object] = {"value": point[name], "ci": None, "n_boot_defined": int(ok.size), "reason": None}
        if point[name] is None:
            entry["reason"] = _undefined_reason(p_sim, p_real)
        if ok.size:
            lo, hi = np.quantile(ok, [alpha, 1 - alpha])
            entry["ci"] = [float(lo), float(hi)]
        else:
            entry["reason"] = entry["reason"] or "undefined in every bootstrap replicate"
        statistics[name] = entry
    return {
        "policies": [
            {
                "policy": p,
                "sim": {"trials": sim[p].trials, "successes": sim[p].successes, "rate": sim[p].rate},
                "real": {"trials": real[p].trials, "successes": real[p].successes, "rate": real[p].rate},
            }
            for p in names
        ],
        "statistics": statistics,
        "n_boot": int(n_boot),
        "seed": int(seed),
        "level": float(level),
    }


# ----------------------------------------------------------------------------- CLI

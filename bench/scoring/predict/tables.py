"""The outcome tables `bench predict` reads, and the strata that pair real trials with simulated episodes.

A table is CSV (a header row) or JSON (a list of row objects, or {"rows": [...]}); its columns:

    policy      optional: the policy the row is about (must be the sim run's policy; a key of tabled sims)
    cell        TASK/ROBOT/ENV as `bench run` prints it; optional when the sim has a single cell
    condition   optional, default "nominal"
    seed        optional: the episode seed of the sim episode this real trial started from (pairs them)
    episode     optional: the episode index in the cell instead of the seed (pairs them)
    success     0/1 (true/false): one trial per row
    trials, successes   instead of success: a batch of unpaired trials in one row
    rate        sim tables only: a simulated success rate without trial counts (taken as exact)

A real row pairs with the sim episode of the same (policy, cell, condition) and seed/episode; rows without
either are unpaired. A row whose policy, cell or condition the sim lacks, or whose seed has no sim episode,
is a DataError (one line naming the row, the value and what the sim has).
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench.core.errors import DataError, did_you_mean
from bench.records import SUCCESS_METRICS
from bench.scoring.predict.ppi import Stratum

COLUMNS = ("policy", "cell", "condition", "seed", "episode", "success", "trials", "successes", "rate")
Key = tuple[str, str, str]  # (policy, cell, condition)


@dataclass(frozen=True)
class Row:
    """One row of an outcome table (or one sim episode of a run)."""

    where: str
    policy: str
    cell: str
    condition: str
    seed: int | None = None
    episode: int | None = None
    success: float | None = None
    trials: int | None = None
    successes: int | None = None
    rate: float | None = None


def _int(v: Any, where: str, field: str) -> int | None:
    if v is None or v == "":
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        f = math.nan
    if isinstance(v, bool) or not math.isfinite(f) or f != int(f) or f < 0:
        raise DataError(f"{where}: {field}={v!r}; expected a non-negative integer")
    return int(f)


def _success(v: Any, where: str) -> float | None:
    if v is None or v == "":
        return None
    text = str(v).strip().lower()
    if text in ("1", "1.0", "true"):
        return 1.0
    if text in ("0", "0.0", "false"):
        return 0.0
    raise DataError(f"{where}: success={v!r}; expected 0 or 1 (true or false)")


def _rate(v: Any, where: str) -> float | None:
    if v is None or v == "":
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        f = math.nan
    if isinstance(v, bool) or not 0.0 <= f <= 1.0:
        raise DataError(f"{where}: rate={v!r}; expected a number in [0, 1]")
    return f


def load_table(path: str | Path, role: str) -> list[Row]:
    """The rows of an outcome table (see the module docstring); `role` ("real", "sim") names it in errors."""
    path = Path(path)
    name = f"{role}={path}"
    if not path.is_file():
        raise DataError(f"{name}: file is missing")
    try:
        if path.suffix.lower() == ".json":
            doc = json.loads(path.read_text(encoding="utf-8"))
            rows = doc.get("rows") if isinstance(doc, dict) else doc
            if not isinstance(rows, list):
                raise DataError(f"{name}: expected a list of rows, or an object with a 'rows' list")
        else:
            with path.open(newline="", encoding="utf-8") as f:
                rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, csv.Error, RecursionError) as exc:
        raise DataError(f"{name}: cannot read it ({str(exc).splitlines()[0][:160]})") from None
    out = []
    for i, raw in enumerate(rows):
        where = f"{name} row {i + 1}"
        if not isinstance(raw, dict):
            raise DataError(f"{where}: expected an object with columns {', '.join(COLUMNS)}")
        for col in raw:
            if col not in COLUMNS:
                raise DataError(
                    f"{where}: unknown column {col!r}; valid: {', '.join(COLUMNS)}{did_you_mean(str(col), COLUMNS)}"
                )
        row = Row(
            where=where,
            policy=str(raw.get("policy") or "").strip(),
            cell=str(raw.get("cell") or "").strip(),
            condition=str(raw.get("condition") or "").strip() or "nominal",
            seed=_int(raw.get("seed"), where, "seed"),
            episode=_int(raw.get("episode"), where, "episode"),
            success=_success(raw.get("success"), where),
            trials=_int(raw.get("trials"), where, "trials"),
            successes=_int(raw.get("successes"), where, "successes"),
            rate=_rate(raw.get("rate"), where),
        )
        kinds = sum(x is not None for x in (row.success, row.trials, row.rate))
        if kinds != 1 or (row.trials is None) != (row.successes is None):
            raise DataError(f"{where}: give exactly one of success, trials+successes, rate")
        if row.trials is not None and (row.trials == 0 or (row.successes or 0) > row.trials):
            raise DataError(
                f"{where}: successes={row.successes} with trials={row.trials}; need 0 <= successes <= trials, trials >= 1"
            )
        if row.rate is not None and role == "real":
            raise DataError(
                f"{where}: a real row needs success or trials+successes (a rate without counts is for sim tables)"
            )
        if (row.seed is not None or row.episode is not None) and row.success is None:
            raise DataError(f"{where}: a row with a seed or episode is one trial: give success, not trials/rate")
        out.append(row)
    if not out:
        raise DataError(f"{name}: no rows")
    return out


def rows_of_run(records: list[Any], policy: str, metric: str) -> list[Row]:
    """A sim run's completed episodes as rows (`metric`: success_once or success_at_end)."""
    if metric not in SUCCESS_METRICS:
        raise DataError(f"metric={metric!r} is not a success metric; valid: {', '.join(SUCCESS_METRICS)}")
    return [
        Row(
            where=f"episode {r.job_id}",
            policy=policy,
            cell=f"{r.task}/{r.robot}/{r.env}",
            condition=r.condition,
            seed=r.seed,
            episode=r.episode,
            success=float(getattr(r, metric)),
        )
        for r in records
        if r.error is None
    ]


def _fill(row: Row, policies: list[str], cells: list[str]) -> Key:
    """The row's stratum key, with policy/cell taken from the sim where the row leaves them out and it has one."""
    policy, cell = row.policy, row.cell
    if not policy:
        if len(policies) != 1:
            raise DataError(f"{row.where}: policy is missing; the sim has several: {', '.join(policies)}")
        policy = policies[0]
    if not cell:
        if len(cells) != 1:
            raise DataError(f"{row.where}: cell is missing; the sim has several: {', '.join(cells[:8])}")
        cell = cells[0]
    return policy, cell, row.condition


def _check_key(row: Row, key: Key, sim_keys: set[Key], sim_name: str) -> None:
    if key in sim_keys:
        return
    policies = sorted({k[0] for k in sim_keys})
    cells = sorted({k[1] for k in sim_keys if k[0] == key[0]})
    conds = sorted({k[2] for k in sim_keys if k[:2] == key[:2]})
    for field, value, valid in (("policy", key[0], policies), ("cell", key[1], cells), ("condition", key[2], conds)):
        if value not in valid:
            raise DataError(
                f"{row.where}: {field} {value!r} does not match {sim_name} (its {field.replace('y', 'ie')}s: "
                f"{', '.join(valid[:8])}{', ...' if len(valid) > 8 else ''}){did_you_mean(value, valid)}"
            )


def _outcomes(rows: list[Row]) -> np.ndarray:
    """Every trial of unpaired rows as 0/1 outcomes (a batch row expanded)."""
    out: list[float] = []
    for r in rows:
        if r.success is not None:
            out.append(r.success)
        else:
            k, n = int(r.successes or 0), int(r.trials or 0)
            out += [1.0] * k + [0.0] * (n - k)
    return np.array(out, dtype=float)


@dataclass(frozen=True)
class Paired:
    """Real rows matched to the sim: per covered stratum its real trials (paired or not) and sim episodes."""

    keys: list[Key]  # the strata the real rows cover, in the sim's order
    all_keys: list[Key]  # every stratum of the sim
    sim: dict[Key, list[Row]]
    paired: dict[Key, list[tuple[Row, Row]]]  # (real, sim) pairs
    unpaired: dict[Key, list[Row]]


def pair(sim_rows: list[Row], real_rows: list[Row], sim_name: str) -> Paired:
    """Match the real rows to the sim's strata and episodes (DataError on a mismatch, naming the row)."""
    sim: dict[Key, list[Row]] = {}
    for r in sim_rows:
        sim.setdefault((r.policy, r.cell, r.condition), []).append(r)
    policies = sorted({k[0] for k in sim})
    cells = sorted({k[1] for k in sim})
    paired: dict[Key, list[tuple[Row, Row]]] = {}
    unpaired: dict[Key, list[Row]] = {}
    used: dict[tuple[Key, str, int], str] = {}
    for row in real_rows:
        key = _fill(row, policies, cells)
        _check_key(row, key, set(sim), sim_name)
        if row.seed is None and row.episode is None:
            unpaired.setdefault(key, []).append(row)
            continue
        field, value = ("seed", row.seed) if row.seed is not None else ("episode", row.episode)
        match = [s for s in sim[key] if getattr(s, field) == value and s.success is not None]
        if not match:
            raise DataError(
                f"{row.where}: {field} {value} has no sim episode in {key[1]} {key[2]} of {sim_name}; leave {field} empty for an unpaired trial"
            )
        if (key, field, int(value or 0)) in used:
            raise DataError(
                f"{row.where}: {field} {value} is already paired ({used[(key, field, int(value or 0))]}); one real trial per sim episode"
            )
        used[(key, field, int(value or 0))] = row.where
        paired.setdefault(key, []).append((row, match[0]))
    covered = [k for k in sim if k in paired or k in unpaired]
    return Paired(covered, list(sim), sim, paired, unpaired)


def _sim_stats(rows: list[Row], exclude: set[int]) -> tuple[float | None, float, float]:
    """(mean, variance of the mean, count) of a stratum's sim outcomes left after removing the paired ones."""
    rates = [r.rate for r in rows if r.rate is not None]
    if rates:
        return float(np.mean(rates)), 0.0, math.inf
    left = _outcomes([r for r in rows if id(r) not in exclude])
    if len(left) == 0:
        return None, 0.0, 0.0
    m = float(left.mean())
    return m, m * (1.0 - m) / len(left), float(len(left))


def episode_strata(p: Paired) -> list[Stratum]:
    """One stratum per (policy, cell, condition) the real rows cover, each weighted equally (the mean of the
    strata's rates, as `bench run` reports the mean of cell rates)."""
    out = []
    for key in p.keys:
        pairs = p.paired.get(key, [])
        mean, var, n = _sim_stats(p.sim[key], {id(s) for _, s in pairs})
        out.append(
            Stratum(
                key="/".join(key),
                weight=1.0 / len(p.keys),
                y_paired=np.array([float(r.success or 0.0) for r, _ in pairs]),
                s_paired=np.array([float(s.success or 0.0) for _, s in pairs]),
                y_unpaired=_outcomes(p.unpaired.get(key, [])),
                sim_mean=mean,
                sim_var_of_mean=var,
                sim_n=n,
            )
        )
    return out


def _rate_of(rows: list[Row]) -> float:
    rates = [r.rate for r in rows if r.rate is not None]
    return float(np.mean(rates)) if rates else float(_outcomes(rows).mean())


def unit_strata(p: Paired) -> list[Stratum]:
    """The strata as units (level=unit): one pseudo-trial per unit with the real rate as outcome and the sim
    rate as prediction; the units without real rows are the unlabelled sample. Estimand: the mean real rate
    over every unit of the sim table."""
    if len(p.keys) < 2:
        raise DataError(
            f"level=unit needs real rows for at least 2 units (policy, cell, condition); they cover {len(p.keys)}"
        )
    real = {k: [r for r, _ in p.paired.get(k, [])] + p.unpaired.get(k, []) for k in p.keys}
    left = [_rate_of(p.sim[k]) for k in p.all_keys if k not in real]
    n_left = len(left)
    return [
        Stratum(
            key="units",
            weight=1.0,
            y_paired=np.array([_rate_of(real[k]) for k in p.keys]),
            s_paired=np.array([_rate_of(p.sim[k]) for k in p.keys]),
            y_unpaired=np.zeros(0),
            sim_mean=float(np.mean(left)) if n_left else None,
            sim_var_of_mean=float(np.var(left, ddof=1)) / n_left if n_left >= 2 else 0.0,
            sim_n=float(n_left),
        )
    ]

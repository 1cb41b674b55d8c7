"""Pairing the regression gate's two sides: candidate and baseline episode records matched by
(cell, condition, episode), checked to start from the same state, and counted per cell for the
statistics of `bench.board.gate.sequential`.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from typing import Any

from bench.board.gate import sequential
from bench.core.errors import DataError
from bench.records import dedupe


def _key(r) -> tuple:
    return (r.task, r.robot, r.env, r.condition, r.episode)


def pair_records(candidate: list, baseline: list, max_episode: int | None = None) -> dict[str, Any]:
    """Pair records by (cell, condition, episode); check they started from the same state.

    An errored or timed-out episode counts as a failure of its side (a candidate that crashes the
    simulator has regressed); pairs where both sides errored are left out.

    Returns cells {(task, robot, env, condition, split): [(baseline record, candidate record)]},
    the count of unpaired episodes and of errored episodes per side.

    Raises:
        DataError: paired episodes with different seeds or initial states (the runs are not comparable).
    """
    cand = {_key(r): r for r in dedupe(candidate) if max_episode is None or r.episode < max_episode}
    base = {_key(r): r for r in dedupe(baseline) if max_episode is None or r.episode < max_episode}
    cells: dict[tuple, list[tuple]] = defaultdict(list)
    errors = {"candidate": 0, "baseline": 0, "both": 0}
    unpaired = 0
    for k in sorted(set(cand) | set(base)):
        c, b = cand.get(k), base.get(k)
        if c is None or b is None:
            unpaired += 1
            continue
        where = f"{k[0]}/{k[1]}/{k[2]} {k[3]} episode {k[4]}"
        if c.seed != b.seed:
            raise DataError(f"{where}: seeds differ (candidate {c.seed}, baseline {b.seed}); runs are not paired")
        if c.init_state_hash and b.init_state_hash and c.init_state_hash != b.init_state_hash:
            raise DataError(
                f"{where}: initial states differ (init_state_hash {c.init_state_hash} vs "
                f"{b.init_state_hash}); the runs are not paired (other simulator/package versions?)"
            )
        if c.error is not None and b.error is not None:
            errors["both"] += 1
            continue
        errors["candidate"] += c.error is not None
        errors["baseline"] += b.error is not None
        cells[(k[0], k[1], k[2], k[3], c.split)].append((b, c))  # an errored side has success False
    return {"cells": dict(cells), "errors": errors, "unpaired": unpaired}


def cell_counts(cells: dict[tuple, list[tuple]], metric: str) -> dict[sequential.CellKey, sequential.Pairs]:
    """Paired (baseline, candidate) records per cell -> counts of the four outcome pairs in `metric`."""
    return {
        k: sequential.pairs_of([bool(getattr(b, metric)) for b, _ in prs], [bool(getattr(c, metric)) for _, c in prs])
        for k, prs in cells.items()
    }


def unmeasured(sides: dict[str, list], planned: list[tuple], max_episode: int) -> tuple[str | None, bool]:
    """(why the comparison measured nothing, whether a side completed no episode at all), or (None, False).

    A side that completed no episode of a planned cell (episodes below `max_episode`) leaves that
    cell's comparison empty: its failures would decide the verdict (a baseline that could not run
    passes any candidate). The line names the side, the cells and the most frequent error there.
    """
    for role, records in sides.items():
        recs = [r for r in dedupe(records) if r.episode < max_episode]
        done = {(r.task, r.robot, r.env, r.condition, r.split) for r in recs if r.error is None}
        empty = [k for k in planned if k not in done]
        if not empty:
            continue
        names = [f"{k[0]}/{k[1]}/{k[2]}" + ("" if k[3] == "nominal" else f" {k[3]}") for k in empty]
        listed = ", ".join(names[:6]) + (f" and {len(names) - 6} more" if len(names) > 6 else "")
        where = "in any cell" if len(empty) == len(planned) else f"in {len(empty)} of {len(planned)} cells ({listed})"
        errors = Counter(
            " ".join(str(r.error).split())
            for r in recs
            if r.error is not None and (r.task, r.robot, r.env, r.condition, r.split) in set(empty)
        )
        why = f"; error: {errors.most_common(1)[0][0][:300]}" if errors else ""
        return f"the {role} completed no episode {where}{why}", len(empty) == len(planned)
    return None, False

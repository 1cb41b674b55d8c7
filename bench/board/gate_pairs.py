"""Pairing the regression gate's two sides: candidate and baseline episode records matched by
(cell, condition, episode), checked to start from the same state, and counted per cell for the
statistics of `bench.board.gate`.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Any

from bench.board import gate
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


def cell_counts(cells: dict[tuple, list[tuple]], metric: str) -> dict[gate.CellKey, gate.Pairs]:
    """Paired (baseline, candidate) records per cell -> counts of the four outcome pairs in `metric`."""
    return {
        k: gate.pairs_of([bool(getattr(b, metric)) for b, _ in prs], [bool(getattr(c, metric)) for _, c in prs])
        for k, prs in cells.items()
    }

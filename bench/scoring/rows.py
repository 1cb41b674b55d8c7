"""Summary rows built from episode records: one cell's counts, then its success rates with Wilson intervals.

The run summary (`bench.scoring.summary`) and the per-axis sensitivity table (`bench.scoring.sensitivity`)
open every row the same way; this module is the one place that does it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from bench.records import SUCCESS_METRICS, EpisodeRecord
from bench.scoring import stats as scoring


def cell_row(
    head: Mapping[str, object],
    records: Sequence[EpisodeRecord],
    confidence: float,
    extra: Callable[[list[EpisodeRecord]], Mapping[str, object]] = lambda completed: {},
) -> dict[str, object]:
    """One cell's summary row, in the order summaries hold it: `head` (what names the cell), the
    counts (completed episodes `n`, `errors`, the completed episodes' `mean_return`, None when there
    are none), `extra(completed)`, then per success metric its successes and Wilson interval."""
    ok = [r for r in records if r.error is None]
    row: dict[str, object] = {
        **head,
        "n": len(ok),
        "errors": len(records) - len(ok),
        "mean_return": round(float(np.mean([r.return_ for r in ok])), 6) if ok else None,
        **extra(ok),
    }
    row.update(success_rates(ok, confidence))
    return row


def success_rates(completed: Sequence[EpisodeRecord], confidence: float) -> dict[str, dict[str, object]]:
    """Per success metric (`SUCCESS_METRICS`): the successes among `completed` records and the rate's
    Wilson interval, as summary rows hold them."""
    out: dict[str, dict[str, object]] = {}
    for m in SUCCESS_METRICS:
        k = int(sum(getattr(r, m) for r in completed))
        out[m] = {"successes": k, **scoring.wilson(k, len(completed), confidence).to_dict()}
    return out

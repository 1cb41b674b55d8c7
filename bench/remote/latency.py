"""Round-trip latency of a remote policy: per-episode statistics and their pooling over a run.

Each episode record of a `policy=remote` run carries, under `extras["policy"]`:

    requests        inference round trips in the episode (one per executed chunk)
    rtt_ms          {p50, p90, p99, max, mean} of the round trips, in milliseconds, measured by the
                    client from encoding the observation to decoding the answer
    server_ms       {p50, max} of the server's own inference time (`server_timing.infer_ms`), when
                    the server reports it
    rtt_steps_p50   the median round trip in control steps of the env (rtt x fps): the delay a
    rtt_steps_p95   real robot at that rate would add (docs/remote-policies.md, "latency")
    fps             the env's control rate
    rtt_hist        {start_ms, per_decade, bins: [[i, count], ...]}: a log-spaced histogram of every
                    round trip; bin i covers [start_ms * 10**(i/per_decade), next); sparse

The histograms add exactly, so a run's latency distribution (`pool`) is the sum of its episodes'
and its quantiles are exact to within one bin (12% at 20 bins per decade).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np

from bench.records import EpisodeRecord

START_MS = 1e-3  # lowest bin edge: 1 microsecond
PER_DECADE = 20


def _bin(ms: float) -> int:
    return max(0, int(math.floor(PER_DECADE * math.log10(max(ms, START_MS) / START_MS))))


def edge(i: float) -> float:
    """Lower edge (ms) of histogram bin i."""
    return START_MS * 10 ** (i / PER_DECADE)


def _q(values: np.ndarray, q: float) -> float:
    return round(float(np.quantile(values, q)), 4)


def episode_stats(rtt_s: Iterable[float], server_ms: Iterable[float], fps: float) -> dict[str, object]:
    """The JSON-able latency statistics of one episode (empty when no request was made)."""
    rtt = np.asarray(list(rtt_s), np.float64) * 1000.0
    if rtt.size == 0:
        return {"requests": 0}
    counts: dict[int, int] = {}
    for ms in rtt:
        b = _bin(float(ms))
        counts[b] = counts.get(b, 0) + 1
    out: dict[str, object] = {
        "requests": int(rtt.size),
        "rtt_ms": {
            "p50": _q(rtt, 0.5),
            "p90": _q(rtt, 0.9),
            "p99": _q(rtt, 0.99),
            "max": round(float(rtt.max()), 4),
            "mean": round(float(rtt.mean()), 4),
        },
    }
    srv = np.asarray(list(server_ms), np.float64)
    srv = srv[np.isfinite(srv)]
    if srv.size:
        out["server_ms"] = {"p50": _q(srv, 0.5), "max": round(float(srv.max()), 4)}
    if fps and fps > 0:
        out["fps"] = float(fps)
        out["rtt_steps_p50"] = round(float(np.quantile(rtt, 0.5)) * fps / 1000.0, 4)
        out["rtt_steps_p95"] = round(float(np.quantile(rtt, 0.95)) * fps / 1000.0, 4)
    bins = sorted([k, v] for k, v in counts.items())
    out["rtt_hist"] = {"start_ms": START_MS, "per_decade": PER_DECADE, "bins": bins}
    return out


def pool(stats: Iterable[dict[str, Any]]) -> dict[str, Any] | None:  # JSON: episodes' stats, read by key
    """Pool per-episode statistics: total requests, the summed histogram and its quantiles; None if none.

    Quantiles are read off the histogram (the geometric middle of the bin holding the quantile);
    the maximum is the largest episode maximum.
    """
    counts: dict[int, int] = {}
    episodes, fps, top = 0, None, 0.0
    for s in stats:
        hist = s.get("rtt_hist") if isinstance(s, dict) else None
        if not hist or hist.get("start_ms") != START_MS or hist.get("per_decade") != PER_DECADE:
            continue
        episodes += 1
        fps = s.get("fps", fps)
        top = max(top, float((s.get("rtt_ms") or {}).get("max", 0.0)))
        for i, n in hist.get("bins", []):
            counts[int(i)] = counts.get(int(i), 0) + int(n)
    total = sum(counts.values())
    if not total:
        return None
    bins = sorted(counts)
    cum = np.cumsum([counts[b] for b in bins])

    def quantile(q: float) -> float:
        i = bins[int(np.searchsorted(cum, q * total, side="left"))]
        return round(math.sqrt(edge(i) * edge(i + 1)), 4)

    out: dict[str, Any] = {
        "episodes": episodes,
        "requests": total,
        "rtt_ms": {
            "p50": quantile(0.5),
            "p90": quantile(0.9),
            "p99": quantile(0.99),
            "max": round(top, 4) or round(edge(bins[-1] + 1), 4),
        },
        "bins": [[b, counts[b]] for b in bins],
    }
    if fps:
        out["fps"] = fps
        out["rtt_steps"] = {k: round(v * fps / 1000.0, 4) for k, v in out["rtt_ms"].items()}
    return out


def run_latency(records: Iterable[EpisodeRecord]) -> dict[str, Any] | None:
    """The `policy_latency` block of a run's summary: pooled over the run and per condition; None without stats.

    Per condition, `injected_steps` is the mean `latency` the perturbation applied (perturb.latency,
    control steps; 0 without one) and `effective_steps` = injected + measured round trip in control
    steps (rtt x fps): the command delay a real robot at the env's rate would see if the policy ran
    as fast as here. Simulated time stands still during a round trip, so the measured latency never
    changes the rollout itself (docs/remote-policies.md, "latency").
    """
    by_condition: dict[str, list[tuple[dict[str, Any], float]]] = {}
    for r in records:
        stats = (getattr(r, "extras", None) or {}).get("policy")
        if not isinstance(stats, dict) or "rtt_hist" not in stats or getattr(r, "error", None) is not None:
            continue
        injected = float((getattr(r, "params", None) or {}).get("latency", 0) or 0)
        by_condition.setdefault(str(r.condition), []).append((stats, injected))
    everything = pool(s for rows in by_condition.values() for s, _ in rows)
    if everything is None:
        return None
    out = dict(everything)
    out["conditions"] = []
    for name, rows in sorted(by_condition.items(), key=lambda kv: (kv[0] != "nominal", kv[0])):
        pooled = pool(s for s, _ in rows)
        if pooled is None:
            continue
        injected = round(float(np.mean([k for _, k in rows])), 4)
        entry = {"condition": name, "injected_steps": injected, **pooled}
        if "rtt_steps" in pooled:
            entry["effective_steps"] = {k: round(injected + v, 4) for k, v in pooled["rtt_steps"].items()}
        out["conditions"].append(entry)
    return out

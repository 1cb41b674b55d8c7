"""The remote-policy section of `bench report`: a run's round-trip latency distribution, per condition.

Reads the summary's `policy_latency` block (`bench.remote.latency.run_latency`): a histogram of every
round trip of the run (log-spaced bins), one line per condition, with the control period of the env
(1000 / fps ms) marked, since a round trip longer than it is a whole control step of delay on a real
robot; and a table with the measured quantiles, the injected `perturb.latency` and the effective delay
(injected + measured) in control steps.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bench.board.report.figures import pyplot, save_figure
from bench.board.report.html import esc, img_tag, table_html
from bench.remote import latency


def fig_latency(block: dict[str, Any], path: Path) -> bool:
    """Round-trip histogram (fraction of requests per log bin) of the run, and a line per condition when several."""
    bins = block.get("bins") or []
    if not bins:
        return False
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 3.0))
    total = sum(n for _, n in bins)
    lo, hi = min(b for b, _ in bins), max(b for b, _ in bins) + 1
    edges = [latency.edge(i) for i in range(lo, hi + 1)]
    counts = dict((int(b), int(n)) for b, n in bins)
    ax.stairs(
        [counts.get(i, 0) / total for i in range(lo, hi)],
        edges,
        fill=True,
        alpha=0.35,
        color="#3b6fb6",
        label=f"all ({total} requests)",
    )
    conditions = block.get("conditions") or []
    if len(conditions) > 1:
        colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for k, c in enumerate(conditions):
            n = sum(m for _, m in c.get("bins", [])) or 1
            cc = {int(b): int(m) for b, m in c.get("bins", [])}
            ax.stairs(
                [cc.get(i, 0) / n for i in range(lo, hi)],
                edges,
                lw=1,
                color=colours[(k + 1) % len(colours)],
                label=f"{c['condition']} ({c['requests']})",
            )
    p50 = block["rtt_ms"]["p50"]
    ax.axvline(p50, color="#3b6fb6", lw=1, ls=":", label=f"median {p50:.3g} ms")
    fps = block.get("fps")
    if fps:
        ax.axvline(1000.0 / fps, color="#b23a48", lw=1, ls="--", label=f"one control step ({1000.0 / fps:.3g} ms)")
    ax.set_xscale("log")
    ax.set_xlabel("round trip (ms, log scale)")
    ax.set_ylabel("fraction of requests")
    ax.set_title("policy round-trip latency", fontsize=9, loc="left")
    ax.legend(fontsize=7, frameon=False)
    save_figure(fig, path)
    return True


def latency_section(summary: dict[str, Any], tmp: Path) -> str:
    """HTML of the section ('' when the run has no remote-policy latency)."""
    block = summary.get("policy_latency")
    if not block:
        return ""
    parts = ["<h2>Policy latency (remote policy)</h2>"]
    if fig_latency(block, tmp / "latency.png"):
        parts.append(img_tag("latency.png", "policy round-trip latency"))
    fmt = lambda q: f"{q['p50']:.3g} / {q['p90']:.3g} / {q['p99']:.3g} / {q['max']:.3g}"  # noqa: E731
    rows = []
    for c in block.get("conditions", []):
        steps, eff = c.get("rtt_steps"), c.get("effective_steps")
        rows.append(
            [
                esc(c["condition"]),
                str(c["requests"]),
                fmt(c["rtt_ms"]),
                fmt(steps) if steps else "n/a",
                f"{c['injected_steps']:g}",
                fmt(eff) if eff else "n/a",
            ]
        )
    parts.append(
        table_html(
            [
                "condition",
                "requests",
                "round trip ms p50 / p90 / p99 / max",
                "in control steps",
                "injected (perturb.latency)",
                "effective steps (injected + measured)",
            ],
            rows,
            {1, 4},
        )
    )
    parts.append(
        "<p class='note'>Measured by the client from encoding the observation to decoding the answer. "
        "Simulated time stands still during a round trip, so it does not change the rollouts; the effective "
        "delay is what a robot at the env's control rate would see. docs/remote-policies.md</p>"
    )
    return "".join(parts)

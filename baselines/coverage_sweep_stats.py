"""The coverage sweep's analysis and output: per-cell tallies, series with bootstrap slopes, the
coverage summary of a training set, the terminal table and the plot (`baselines.coverage_sweep`
runs the experiment; this module only reads what it produced).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from bench.api.stats import SeriesBootstrap, TrainingData, coverage_report, fmt_pct, slope_with_interval, wilson


class SweepConfig(Protocol):
    """What the analysis reads of the sweep's config (`baselines.coverage_sweep_config.SweepConfig`)."""

    @property
    def seeds(self) -> Sequence[int]: ...
    @property
    def n_boot(self) -> int: ...
    @property
    def confidence(self) -> float: ...


def training_summary(infos: Sequence[dict]) -> dict[str, Any]:
    return {
        "episodes": infos[0]["episodes"],
        "frames": infos[0]["frames"],
        "robots_episodes": infos[0].get("robots_episodes"),
        "train_wall_s": [round(float(i["train_wall_s"]), 3) for i in infos],
    }


def per_seed_cells(outcomes: Sequence[dict[str, np.ndarray]], cfg: SweepConfig) -> dict[str, Any]:
    """Per cell: successes and episodes pooled over the training seeds, with a Wilson interval."""
    out = {}
    for key in outcomes[0]:
        k = int(sum(int(o[key].sum()) for o in outcomes if key in o))
        n = int(sum(len(o[key]) for o in outcomes if key in o))
        out[key] = {
            "n": n,
            "successes": k,
            "per_seed": [int(o[key].sum()) if key in o else None for o in outcomes],
            **wilson(k, n, cfg.confidence).to_dict(),
        }
    return out


def coverage_summary(demos, cells, manifest, conditions, states, groups) -> dict[str, Any]:
    train = TrainingData(
        demos.obs.astype(float),
        demos.episode,
        [
            {
                "task": e.get("task"),
                "robot": e["robot"],
                "env": e.get("env"),
                "condition": e["condition"],
                "params": e["params"],
            }
            for e in demos.episodes
        ],
        [],
    )
    rep = coverage_report(train, cells, manifest, conditions, states, groups)
    held = rep["state"]["splits"].get("unseen", {})
    out = {
        "robots_covered": rep["support"]["robots"]["covered"],
        "state_unseen_mean_distance": held.get("mean"),
        "state_unseen_covered": held.get("covered"),
        "reference_radius": rep["state"]["reference_radius"],
        "state_by_cell": {
            k: {"mean_distance": v.get("mean"), "covered": v.get("covered")}
            for k, v in (rep["state"].get("groups") or {}).items()
        },
    }
    if rep["params"]:
        out["params"] = rep["params"]
    return out


def series_summary(
    entries: list[dict], xlabel: str, unseen_keys: Sequence[str], rng, cfg: SweepConfig
) -> dict[str, Any]:
    """Held-out and in-distribution success, gap, difference to the first point, and slopes of one series."""
    boot = SeriesBootstrap([e["outcomes"] for e in entries], rng, cfg.n_boot, cfg.confidence)
    points, held, held_reps, gaps, gap_reps, n_held, n_gap = [], [], [], [], [], [], []
    for k, e in enumerate(entries):
        h, h_r = boot.mean(k, unseen_keys)
        i, i_r = boot.mean(k, e["train_keys"])
        g, g_r = (None, None) if h is None or i is None else (i - h, i_r - h_r)
        nh = sum(len(o.get(key, ())) for o in e["outcomes"] for key in unseen_keys)
        ni = sum(len(o.get(key, ())) for o in e["outcomes"] for key in e["train_keys"])
        point = {
            "name": e["name"],
            "x": e["x"],
            "train_robots": sorted({key.split("/")[1] for key in e["train_keys"]}),
            "seeds": list(cfg.seeds),
            "held_out": boot.estimate(h, h_r),
            "in_distribution": boot.estimate(i, i_r),
            "gap": boot.estimate(g, g_r),
            "cells": per_seed_cells(e["outcomes"], cfg),
            "training": e["training"],
            "coverage": e["coverage"],
        }
        if k > 0 and h is not None and held[0] is not None:
            d = boot.estimate(h - held[0], h_r - held_reps[0])
            point["held_out_vs_first"] = {"reference": entries[0]["name"], **d}
        points.append(point)
        held.append(h)
        held_reps.append(h_r)
        gaps.append(g)
        gap_reps.append(g_r)
        n_held.append(nh)
        n_gap.append(min(nh, ni))
    xs = [e["x"] for e in entries]
    return {
        "x_label": xlabel,
        "points": points,
        "held_out_slope": slope_with_interval(xs, held, held_reps, n_held, cfg.confidence),
        "gap_slope": slope_with_interval(xs, gaps, gap_reps, n_gap, cfg.confidence),
    }


def render_sweep(doc: dict[str, Any], console=None) -> None:
    """Print the sweep's tables: each series with its slope, then the surrogate comparison."""
    from rich.console import Console
    from rich.table import Table

    from bench.api.stats import fmt_estimate

    console = console or Console(width=None if Console().is_terminal else 140)
    conf = int(round(100 * doc.get("confidence", 0.95)))
    for part in ("robots", "dr"):
        s = doc.get(part)
        if not s:
            continue
        t = Table(title=f"{part}: {s['x_label']} ({conf}% intervals)", title_justify="left")
        for col in (
            "model",
            "x",
            "train robots",
            "episodes",
            "held-out success",
            "vs first (paired)",
            "in-distribution",
            "gap",
            "unseen states covered",
            "train s",
        ):
            t.add_column(col)
        for p in s["points"]:
            c = p["coverage"]
            t.add_row(
                p["name"],
                f"{p['x']:g}",
                ",".join(p["train_robots"]),
                str(p["training"]["episodes"]),
                fmt_estimate(p["held_out"]),
                fmt_estimate(p.get("held_out_vs_first"), pct=False) if "held_out_vs_first" in p else "-",
                fmt_estimate(p["in_distribution"]),
                fmt_estimate(p["gap"], pct=False),
                fmt_pct(c.get("state_unseen_covered")),
                "/".join(f"{w:.0f}" for w in np.atleast_1d(p["training"]["train_wall_s"])),
            )
        console.print(t)
        console.print(
            f"  held-out success slope per unit x: {fmt_estimate(s['held_out_slope'], pct=False)}; "
            f"gap slope: {fmt_estimate(s['gap_slope'], pct=False)}"
        )
    sg = doc.get("surrogate")
    if sg:
        t = Table(
            title=f"surrogate data: {sg['in_domain_episodes']} in-domain episodes on {sg['target']} "
            f"+ {sg['surrogate_episodes']} mismatched ({conf}% intervals)",
            title_justify="left",
        )
        for col in ("training set", "episodes", "success on target", "difference vs in-domain (paired)", "verdict"):
            t.add_column(col)
        for name, v in sg["variants"].items():
            d = v.get("vs_in_domain")
            t.add_row(
                name,
                str(v["training"]["episodes"]),
                fmt_estimate(v["success"]),
                fmt_estimate(d, pct=False) if d else "-",
                d.get("verdict", "") if d else "",
            )
        console.print(t)


def plot_sweep(doc: dict[str, Any], path: Path) -> Path:
    """PNG: held-out and in-distribution success against coverage with intervals and the WLS line; surrogate bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [p for p in ("robots", "dr", "surrogate") if doc.get(p)]
    fig, axes = plt.subplots(1, max(1, len(panels)), figsize=(5.2 * max(1, len(panels)), 4.2), squeeze=False)
    for ax, part in zip(axes[0], panels):
        if part == "surrogate":
            sg = doc[part]
            names = list(sg["variants"])
            vals = [sg["variants"][n]["success"] for n in names]
            y = [v["value"] or 0 for v in vals]
            err = [
                [max(0.0, (v["value"] or 0) - v["ci"][0]) if v.get("ci") else 0 for v in vals],
                [max(0.0, v["ci"][1] - (v["value"] or 0)) if v.get("ci") else 0 for v in vals],
            ]
            ax.bar(range(len(names)), y, yerr=err, capsize=4, color=["#4c72b0", "#dd8452", "#55a868"][: len(names)])
            ax.set_xticks(range(len(names)), [n.replace("_", "\n") for n in names], fontsize=8)
            ax.set_ylim(0, 1.05)
            ax.set_ylabel(f"success on {sg['target'].split('/')[1]}")
            ax.set_title(
                f"surrogate data (+{sg['surrogate_episodes']} eps to {sg['in_domain_episodes']} in-domain)", fontsize=9
            )
            continue
        s = doc[part]
        xs = np.array([p["x"] for p in s["points"]])
        nudge = 0.015 * (np.ptp(xs) or 1.0)  # side by side, so the intervals do not hide each other
        for key, label, color, off in (
            ("held_out", "held-out (unseen robots)", "#c44e52", -nudge),
            ("in_distribution", "in-distribution (training robots)", "#4c72b0", nudge),
        ):
            ys = np.array([p[key]["value"] if p[key]["value"] is not None else np.nan for p in s["points"]])
            lo = np.array([p[key]["ci"][0] if p[key].get("ci") else np.nan for p in s["points"]])
            hi = np.array([p[key]["ci"][1] if p[key].get("ci") else np.nan for p in s["points"]])
            ax.errorbar(xs + off, ys, yerr=[ys - lo, hi - ys], fmt="o", color=color, capsize=4, label=label)
        sl = s["held_out_slope"]
        if sl.get("value") is not None:
            grid = np.linspace(xs.min(), xs.max(), 20)
            ax.plot(
                grid,
                sl["intercept"] + sl["value"] * grid,
                "--",
                color="#c44e52",
                label=f"WLS slope {sl['value']:+.3f} [{sl['ci'][0]:+.3f}, {sl['ci'][1]:+.3f}]",
            )
        ax.set_xlabel(s["x_label"], fontsize=9)
        ax.set_ylabel("success rate (success_once)")
        ax.set_ylim(-0.02, 1.05)
        ax.set_xticks(xs)
        ax.legend(fontsize=7, loc="best")
        ax.set_title(
            {"robots": "robot coverage (fixed demo budget)", "dr": "domain-randomisation width"}[part], fontsize=10
        )
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path

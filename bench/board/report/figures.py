"""The figures of `bench report` (matplotlib, Agg): cells, split means and gaps, sensitivity curves,
leaderboard, calibration errors, checkpoint sweeps. Each `fig_*` writes one PNG and says whether it drew anything.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

SEEN, UNSEEN = "#3b6fb6", "#e07b28"
COLOURS = {"seen": SEEN, "unseen": UNSEEN}


def labelled_bar(ax: Axes, x: float, est: Sequence[float], colour: str, width: float, by_return: bool) -> None:
    """One bar with its interval (`est` = value, minus, plus) and its value written above (below, if negative)."""
    ax.bar(x, est[0], width=width, color=colour, alpha=0.85)
    ax.errorbar(x, est[0], yerr=[[est[1]], [est[2]]], color="black", capsize=3, lw=1)
    top = est[0] + est[2] if est[0] >= 0 else est[0] - est[1]
    ax.annotate(
        f"{est[0]:.4g}" if by_return else f"{est[0] * 100:.0f}%",
        (x, top),
        xytext=(0, 2 if est[0] >= 0 else -2),
        textcoords="offset points",
        ha="center",
        va="bottom" if est[0] >= 0 else "top",
        fontsize=7,
    )


def pyplot():
    import matplotlib  # matplotlib: loaded only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # matplotlib: loaded only when a figure is drawn

    plt.rcParams.update({"figure.dpi": 110, "font.size": 9, "axes.spines.top": False, "axes.spines.right": False})
    return plt


def save_figure(fig: Figure, path: Path, rect: tuple[float, float, float, float] | None = None) -> None:
    """Lay out, write and close one figure (closed figures free their memory in long report runs)."""
    import matplotlib.pyplot as plt  # matplotlib: loaded only when a figure is drawn

    fig.tight_layout(rect=rect)
    fig.savefig(path)
    plt.close(fig)


def _err(est: dict | None) -> tuple[float, float, float] | None:
    """(value, minus, plus) of an estimate with an interval, or None."""
    if not est or est.get("value") is None:
        return None
    v = est["value"]
    lo, hi = est["ci"] if est.get("ci") else (v, v)
    return v, max(v - lo, 0.0), max(hi - v, 0.0)


def _score(c: dict, metric: str) -> dict | None:
    """A cell's headline estimate: its success rate, or for a run scored by return its mean return."""
    return c.get("return") if metric == "return" else c.get(metric)


def fig_cells(summary: dict, path: Path) -> bool:
    """Success (or, for a run scored by return, mean return) per task, robot/env with intervals; seen then unseen."""
    plt = pyplot()
    metric = summary["metric"]
    by_return = metric == "return"
    other = "success_at_end" if metric == "success_once" else "success_once"
    cells = [c for c in summary["cells"] if c["condition"] == "nominal"]
    if not cells:
        return False
    tasks = sorted({c["task"] for c in cells})
    envs = len({c["env"] for c in cells}) > 1
    fig, axes = plt.subplots(
        len(tasks),
        1,
        figsize=(
            max(6.0, (1.1 if envs else 0.75) * max(len([c for c in cells if c["task"] == t]) for t in tasks) + 2),
            2.8 * len(tasks),
        ),
        squeeze=False,
    )
    conf = int(summary["confidence"] * 100)
    for ax, task in zip(axes[:, 0], tasks):
        rows = sorted(
            (c for c in cells if c["task"] == task), key=lambda c: (c["split"] != "seen", c["robot"], c["env"])
        )
        xs = range(len(rows))
        for x, c in zip(xs, rows):
            e = _err(_score(c, metric))
            if e:
                labelled_bar(ax, x, e, COLOURS[c["split"]], 0.65, by_return)
            o = None if by_return else _err(c[other])
            if o:
                ax.plot(x, o[0], marker="_", ms=16, mew=2, color="black", alpha=0.6)
        ax.set_xticks(list(xs))
        ax.set_xticklabels([f"{c['robot']}\n{c['env']}" if envs else c["robot"] for c in rows], fontsize=8)
        n_seen = sum(c["split"] == "seen" for c in rows)
        if 0 < n_seen < len(rows):
            ax.axvline(n_seen - 0.5, color="grey", ls=":", lw=1)
        if by_return:
            ax.axhline(0, color="grey", lw=0.8)
            ax.margins(y=0.15)
            ax.set_ylabel("mean return")
            title = f"{task}: mean return per cell ({conf}% bootstrap)"
        else:
            ax.set_ylim(0, 1.15)
            ax.set_ylabel(f"{metric}")
            title = f"{task}: success per cell ({conf}% Wilson); bar = {metric}, tick = {other}"
        ax.set_title(title, fontsize=9, loc="left")
    handles = [plt.Rectangle((0, 0), 1, 1, color=COLOURS[s]) for s in ("seen", "unseen")]
    axes[0, 0].legend(handles, ["seen", "unseen"], fontsize=8, frameon=False, loc="upper left", bbox_to_anchor=(1, 1))
    save_figure(fig, path)
    return True


def fig_splits_gaps(summary: dict, path: Path) -> bool:
    """Split means/IQM (left) and transfer gaps (right), with their intervals (bench.scoring.stats)."""
    plt = pyplot()
    metric = summary["metric"]
    splits = summary["splits"]
    gaps = [g for g in summary["gaps"] if g.get("value") is not None]
    if not splits and not gaps:
        return False
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 2.8), gridspec_kw={"width_ratios": [1.3, 1]})
    labels, i = [], 0
    for split in ("seen", "unseen"):
        for stat in ("mean", "iqm"):
            e = _err(splits.get(split, {}).get(metric, {}).get(stat))
            if e:
                a1.barh(i, e[0], color=COLOURS[split], alpha=0.85 if stat == "mean" else 0.45, height=0.6)
                a1.errorbar(e[0], i, xerr=[[e[1]], [e[2]]], color="black", capsize=3, lw=1)
                labels.append(f"{split} {stat}")
                i += 1
    a1.set_yticks(range(len(labels)))
    a1.set_yticklabels(labels)
    a1.invert_yaxis()
    if metric == "return":  # returns have the env's own scale (HalfCheetah: hundreds, negative)
        a1.axvline(0, color="grey", lw=0.8)
        a1.margins(x=0.1)
    else:
        a1.set_xlim(0, 1.02)
    a1.set_title(f"{metric} over nominal cells", fontsize=9, loc="left")
    for j, g in enumerate(gaps):
        e = _err(g)
        assert e is not None, "gaps keeps only estimates with a value"
        a2.errorbar(e[0], j, xerr=[[e[1]], [e[2]]], fmt="o", color="black", capsize=3)
    a2.axvline(0, color="grey", lw=1)
    if not gaps:
        reason = next((g.get("reason") for g in summary["gaps"] if g.get("reason")), "no seen/unseen pair of groups")
        a2.text(
            0.5,
            0.5,
            f"no gap computable:\n{reason}",
            ha="center",
            va="center",
            fontsize=8,
            color="grey",
            transform=a2.transAxes,
            backgroundcolor="white",
        )
    a2.set_yticks(range(len(gaps)))
    a2.set_yticklabels([f"{g['reference']}→{g['target']}\n{g['metric']}" for g in gaps], fontsize=8)
    a2.invert_yaxis()
    if metric == "return" or any(g["metric"] == "return" for g in gaps):
        a2.margins(x=0.1)
    else:
        a2.set_xlim(-1.02, 1.02)
    a2.set_title("transfer gap (reference − target)", fontsize=9, loc="left")
    save_figure(fig, path)
    return True


def _level_x(level: object) -> tuple[float, float] | None:
    """(x, half-width) of a perturbation level: a scale, or the midpoint of a [low, high] range."""
    if isinstance(level, bool):
        return None
    if isinstance(level, (int, float)):
        return float(level), 0.0
    if isinstance(level, list) and len(level) == 2 and all(isinstance(v, (int, float)) for v in level):
        return (level[0] + level[1]) / 2.0, abs(level[1] - level[0]) / 2.0
    return None


def fig_sensitivity(summary: dict, path: Path) -> list[str]:
    """One panel per axis: success vs level (pooled, with Wilson intervals; thin lines per cell)."""
    entries = summary.get("sensitivity") or []
    metric = summary["metric"]
    axes_names = sorted({e["axis"] for e in entries if e.get("axis") and _level_x(e["level"])})  # a combination: none
    if not axes_names:
        return []
    plt = pyplot()
    nominal = next((e for e in entries if e.get("axis") is None and e.get("scope") == "all"), None)
    ncol = min(3, len(axes_names))
    nrow = (len(axes_names) + ncol - 1) // ncol
    fig, axs = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.0 * nrow), squeeze=False)
    for k, axis in enumerate(axes_names):
        ax = axs[k // ncol, k % ncol]
        pooled = sorted(
            (
                (lx, e)
                for e in entries
                if e.get("axis") == axis and e.get("scope") == "all" and (lx := _level_x(e["level"]))
            ),
            key=lambda t: t[0][0],
        )
        per_cell: dict[tuple, list] = {}
        for e in entries:
            if e.get("axis") == axis and e.get("scope") == "cell" and _level_x(e["level"]):
                per_cell.setdefault((e.get("task"), e.get("robot"), e.get("env")), []).append(e)
        for key, es in sorted(per_cell.items()):
            pts = sorted(
                (lx[0], e[metric]["value"])
                for e in es
                if e[metric].get("value") is not None and (lx := _level_x(e["level"]))
            )
            if pts:
                ax.plot([p[0] for p in pts], [p[1] for p in pts], lw=0.8, alpha=0.35, color="grey")
                ax.annotate(key[1], pts[-1], fontsize=6, color="grey", xytext=(2, 0), textcoords="offset points")
        xs: list[float] = []
        ys: list[float] = []
        lo: list[float] = []
        hi: list[float] = []
        xerr: list[float] = []
        for (x, half), e in pooled:
            est = _err(e[metric])
            if est:
                xs.append(x)
                ys.append(est[0])
                lo.append(est[1])
                hi.append(est[2])
                xerr.append(half)
        ax.errorbar(
            xs,
            ys,
            yerr=[lo, hi],
            xerr=xerr if any(xerr) else None,
            fmt="o-",
            color="#b23a48",
            capsize=3,
            label="all cells",
        )
        if nominal and nominal[metric].get("value") is not None:
            ax.axhline(nominal[metric]["value"], color="black", ls="--", lw=1, label="nominal")
        ax.set_ylim(-0.02, 1.05)
        ax.set_xlabel(f"{axis} level")
        ax.set_ylabel(metric)
        if xs and min(xs) > 0 and max(xs) / min(xs) > 20:
            ax.set_xscale("log")
        ax.set_title(f"sensitivity: {axis}", fontsize=9, loc="left")
        ax.legend(fontsize=7, frameon=False)
    for k in range(len(axes_names), nrow * ncol):
        axs[k // ncol, k % ncol].axis("off")
    save_figure(fig, path)
    return axes_names


def fig_leaderboard(board: dict, path: Path) -> bool:
    """Per entry: seen and unseen means side by side with intervals, in ranking order per group.

    Entries scored by success share one panel (0..100%); entries scored by return (e.g. HalfCheetah,
    whose returns are in the hundreds and negative) get a panel of their own, in the env's units.
    """
    plt = pyplot()
    entries = board["entries"]
    if not entries:
        return False
    panels = [
        (kind, [e for e in entries if (e["metric"] == "return") == (kind == "return")])
        for kind in ("success", "return")
    ]
    panels = [(kind, es) for kind, es in panels if es]
    fig, axs = plt.subplots(
        1,
        len(panels),
        figsize=(max(6.0, 1.5 * len(entries) + 2.5), 3.8),
        squeeze=False,
        gridspec_kw={"width_ratios": [max(len(es), 1.5) for _, es in panels]},
    )
    width = 0.38
    for ax, (kind, es) in zip(axs[0], panels):
        labels = []
        for i, e in enumerate(es):
            m = e["metric"]
            for j, split in enumerate(("seen", "unseen")):
                est = _err(e["splits"].get(split, {}).get(m, {}).get("mean"))
                if est:
                    x = i + (j - 0.5) * width
                    labelled_bar(ax, x, est, COLOURS[split], width, kind == "return")
            sha = e["policy"].get("checkpoint_sha256")
            labels.append(
                f"#{e['rank'] or '–'} {e['policy']['name']}"
                + (f"\n{sha[:8]}" if sha else "")
                + f"\n{e['suite']['name']}"
            )
        ax.set_xticks(range(len(es)))
        ax.set_xlim(-0.7, len(es) - 0.3)
        ax.set_xticklabels(labels, fontsize=7, rotation=30, ha="right", rotation_mode="anchor")
        groups = [e["group"] for e in es]
        for i in range(1, len(es)):
            if groups[i] != groups[i - 1]:
                ax.axvline(i - 0.5, color="grey", ls=":", lw=1)
        if kind == "return":
            ax.axhline(0, color="grey", lw=0.8)
            ax.margins(y=0.15)
            ax.set_ylabel("mean return (env units)")
            ax.set_title("scored by return", fontsize=9, loc="left")
        else:
            ax.set_ylim(0, 1.15)
            ax.set_ylabel("mean success")
            ax.set_title("seen vs unseen mean success per entry (intervals from each run)", fontsize=9, loc="left")
    handles = [plt.Rectangle((0, 0), 1, 1, color=COLOURS[s]) for s in ("seen", "unseen")]
    axs[0, -1].legend(handles, ["seen", "unseen"], fontsize=8, frameon=False, loc="upper left", bbox_to_anchor=(1, 1))
    save_figure(fig, path)
    return True


NRMSE_KEYS = (("one_step_nrmse", "one-step"), ("k_step_nrmse", "k-step"), ("free_run_nrmse", "free-run"))


def fig_calibration(cal: dict, path: Path) -> bool:
    """Held-out NRMSE per horizon for the nominal model, the declared fit and the final model."""
    plt = pyplot()
    stages = [s for s in ("nominal", "declared", "final") if isinstance(cal["errors"].get(s), dict)]
    fig, ax = plt.subplots(figsize=(6.5, 2.8))
    width = 0.8 / len(stages)
    colours = {"nominal": "#9aa0a6", "declared": "#3b6fb6", "final": "#2e8b57"}
    for j, stage in enumerate(stages):
        vals = [cal["errors"][stage].get(k) for k, _ in NRMSE_KEYS]
        xs = [i + (j - (len(stages) - 1) / 2) * width for i in range(len(NRMSE_KEYS))]
        ax.bar(
            [x for x, v in zip(xs, vals) if v is not None],
            [v for v in vals if v is not None],
            width=width,
            color=colours[stage],
            label=stage,
        )
    ax.set_xticks(range(len(NRMSE_KEYS)))
    ax.set_xticklabels([lbl for _, lbl in NRMSE_KEYS])
    ax.set_ylabel("held-out NRMSE")
    ax.legend(fontsize=8, frameon=False)
    ax.set_title("calibration: error before → after (held-out)", fontsize=9, loc="left")
    save_figure(fig, path)
    return True


# -- HTML ---------------------------------------------------------------------------------------


def fig_curves(summary: dict, path: Path) -> int:
    """One panel per range condition: the fitted success against the drawn factor with its bootstrap band, half of
    nominal (dashed) and the breaking point with its interval (shaded); the number of panels drawn."""
    entries = [c for c in summary.get("curves") or [] if c.get("band")]
    if not entries:
        return 0
    plt = pyplot()
    ncol = min(3, len(entries))
    nrow = (len(entries) + ncol - 1) // ncol
    fig, axs = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.0 * nrow), squeeze=False)
    for k, c in enumerate(entries):
        ax = axs[k // ncol, k % ncol]
        band = c["band"]
        xs = [b["x"] for b in band]
        ax.fill_between(xs, [b["lo"] for b in band], [b["hi"] for b in band], color=COLOURS["unseen"], alpha=0.25)
        ax.plot(xs, [b["p"] for b in band], color=COLOURS["unseen"], lw=1.5)
        ax.axhline(c["nominal"] / 2, color="grey", ls="--", lw=0.8)
        if c.get("breaks_at") is not None:
            lo, hi = c["ci"]
            ax.axvspan(xs[0] if lo is None else lo, xs[-1] if hi is None else hi, color="black", alpha=0.08)
            ax.axvline(c["breaks_at"], color="black", lw=1)
        if c.get("scale") == "log":
            ax.set_xscale("log")
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlabel(f"{c['axis']} (drawn per episode)")
        ax.set_ylabel(c["metric"])
        ax.set_title(c["condition"], fontsize=8)
    for k in range(len(entries), nrow * ncol):
        axs[k // ncol, k % ncol].axis("off")
    save_figure(fig, path)
    return len(entries)


def fig_sweep(sweep: dict, path: Path) -> bool:
    """A checkpoint sweep (`bench sweep`): success against training step with simultaneous intervals, the best
    set filled and the selected checkpoint starred."""
    rows = [r for r in sweep.get("checkpoints", []) if r["success"].get("value") is not None]
    if not rows:
        return False
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.0, 3.4))
    for r in rows:
        v, minus, plus = _err(r["success"]) or (0.0, 0.0, 0.0)
        best = r["in_best_set"]
        ax.errorbar(
            r["step"],
            v,
            yerr=[[minus], [plus]],
            fmt="o",
            color=SEEN if best else "grey",
            mfc=SEEN if best else "white",
            capsize=3,
            lw=1,
        )
        if r["name"] == sweep.get("selected"):
            ax.plot(r["step"], v, marker="*", ms=14, color=UNSEEN, zorder=3)
    ax.plot([r["step"] for r in rows], [r["success"]["value"] for r in rows], color="grey", lw=0.8, zorder=0)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel(f"training step ({sweep.get('step_source', 'step')})")
    ax.set_ylabel(f"{sweep.get('metric', 'success')} (mean of cell rates)")
    ax.set_title(
        f"{sweep.get('simultaneous_confidence', 0.95):.3g} simultaneous intervals; filled: best set; star: selected",
        fontsize=8,
    )
    save_figure(fig, path)
    return True

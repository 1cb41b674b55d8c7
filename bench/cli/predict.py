"""`bench predict sim=RUN real=TABLE`: its help, the printed report and the command over `bench.api.predict_real`."""

from __future__ import annotations

import sys
from typing import Any

from bench.api.predict import PredictConfig, predict_real
from bench.core.config import build_from_argv, command_help


def help_text() -> str:
    return command_help(
        "usage: bench predict sim=RUN_DIR real=TABLE [width=0.2 confidence=0.95 level=episode out=FILE.json]",
        "The policy's REAL success rate from its simulated episodes plus a few real trials, with a\n"
        "prediction-powered interval (PPI++, Angelopoulos et al. 2023): real trials paired with the sim\n"
        "episode of the same cell, condition and seed correct the simulator's bias, and the simulator's\n"
        "many episodes narrow the interval as far as the pairs show it tracks the real robot. Valid whatever\n"
        "the sim-real correlation: a simulator that carries no information gets weight 0 (lambda) and the\n"
        "interval is the real-only Wilson interval, printed beside it. width= adds the real trials needed\n"
        "for an interval that wide, with the simulator and without.",
        PredictConfig,
        [
            "bench predict sim=runs/my_run real=real.csv width=0.15",
            "bench predict sim=results/references/simpler/sim.csv real=results/references/simpler/real_subset.csv level=unit",
        ],
        notes="The real table (CSV or JSON): columns cell (TASK/ROBOT/ENV), condition (default nominal), seed or\n"
        "episode (pairs the trial with that sim episode; empty: unpaired), success (0/1), or trials+successes\n"
        "for a batch of unpaired trials; policy (optional) must be the run's. A cell, condition or policy the\n"
        "sim run lacks is an error (exit 2, nothing written). docs/predict.md has the format and the method.",
    )


def format_report(doc: dict[str, Any]) -> str:
    """Plain aligned text: the two estimates, the widths, lambda, the trials."""
    pct = round(100 * doc["confidence"])
    est, real = doc["estimate"], doc["real_only"]
    trials = doc["real_trials"]
    sim_n = doc["sim_episodes_unpaired"]
    what = "units" if doc["level"] == "unit" else "real trials"
    lines = [
        f"real success ({doc['metric']}, {len(doc['strata'])} strata)"
        if doc["level"] == "episode"
        else f"mean real success over {doc['units']} units (policy, cell, condition)",
        f"  with sim (PPI++)  {est['value']:.3f}  {pct}% [{est['ci'][0]:.3f}, {est['ci'][1]:.3f}]  width {doc['width']:.3f}",
        f"  real only         {real['value']:.3f}  {pct}% [{real['ci'][0]:.3f}, {real['ci'][1]:.3f}]  width {doc['real_only_width']:.3f}",
        f"  lambda {doc['lambda']:.2f}; {what}: {trials['paired']} paired, {trials['unpaired']} unpaired; "
        f"sim {'units' if doc['level'] == 'unit' else 'episodes'} unpaired: {'rates given' if sim_n is None else int(sim_n)}",
        f"  the interval is worth {doc['effective_real_trials']:g} {what} (real only: {doc['real_only_trials']:g})",
    ]
    if doc["lambda"] == 0:
        lines.append("  the simulator did not narrow the interval here (lambda 0): this is the real-only interval")
    target = doc.get("target")
    if target:
        fmt = lambda n: "more than 10,000,000" if n is None else f"{n}"  # noqa: E731
        lines.append(
            f"  for width {target['width']:g}: {fmt(target['real_trials_with_sim'])} {what} with the simulator, "
            f"{fmt(target['real_trials_real_only'])} real only"
        )
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    """`bench predict sim=RUN_DIR real=TABLE [width= confidence= level= metric= out=]`."""
    if not argv or any(a in ("-h", "--help", "help") for a in argv):
        print(help_text(), end="")
        return 0
    cfg: PredictConfig = build_from_argv(PredictConfig, argv, "bench predict")
    doc = predict_real(cfg)
    print(format_report(doc))
    if cfg.out:
        print(f"wrote {cfg.out}", file=sys.stderr)
    return 0

"""`bench correlate sim=FILE real=FILE`: its help, the printed report and the command over `bench.api.correlate`."""

from __future__ import annotations

import sys
from typing import Any

from bench.api.agreement import CorrelateConfig, correlate
from bench.core.config import build_from_argv, command_help


def help_text() -> str:
    return command_help(
        "usage: bench correlate sim=FILE real=FILE [seed=0 n_boot=2000 level=0.95 out=FILE.json]",
        "Sim-real agreement across policies: Pearson, Spearman, Kendall and MMRV (mean maximum\n"
        "rank violation; lower is better) of the per-policy success rates, each with a percentile\n"
        "bootstrap interval that resamples the trials of every policy in sim and in real.",
        CorrelateConfig,
        ["bench correlate sim=sim.csv real=real.csv out=agreement.json"],
        notes="MMRV weights each rank violation by the REAL gap between the two policies, so sim= and\n"
        "real= are not interchangeable.",
    )


def format_report(report: dict[str, Any]) -> str:
    """Plain aligned text: the per-policy rates, then one line per statistic."""
    lines = []
    width = max(6, *(len(p["policy"]) for p in report["policies"]))
    cell = lambda o: f"{o['successes']:>5}/{o['trials']:<5}{o['rate']:5.2f}"  # noqa: E731
    lines.append(f"{'policy'.ljust(width)}  {'sim':>15}  {'real':>15}")
    for p in report["policies"]:
        lines.append(f"{p['policy'].ljust(width)}  {cell(p['sim'])}  {cell(p['real'])}")
    pct = round(100 * report["level"])
    lines.append("")
    lines.append(f"{'statistic':<10}  {'value':>7}  {f'{pct}% interval':<18}  note")
    for name, st in report["statistics"].items():
        value = "n/a" if st["value"] is None else f"{st['value']:.3f}"
        ci = "n/a" if st["ci"] is None else f"[{st['ci'][0]:.3f}, {st['ci'][1]:.3f}]"
        note = st["reason"] or ("lower is better" if name == "mmrv" else "")
        if st["ci"] is not None and st["n_boot_defined"] < report["n_boot"]:
            note = f"{note}; " if note else ""
            note += f"{report['n_boot'] - st['n_boot_defined']} replicates undefined (equal rates), left out"
        lines.append(f"{name:<10}  {value:>7}  {ci:<18}  {note}".rstrip())
    lines.append(f"(bootstrap: {report['n_boot']} replicates, seed {report['seed']})")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    """`bench correlate sim=FILE real=FILE [seed=0 n_boot=2000 level=0.95 out=FILE.json]`."""
    if not argv or any(a in ("-h", "--help", "help") for a in argv):
        print(help_text(), end="")
        return 0
    cfg: CorrelateConfig = build_from_argv(CorrelateConfig, argv, "bench correlate")
    report = correlate(cfg)
    print(format_report(report))
    if cfg.out:
        print(f"wrote {cfg.out}", file=sys.stderr)
    return 0

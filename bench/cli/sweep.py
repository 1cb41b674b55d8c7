"""`bench sweep checkpoints=[...]`: its help, the printed verdict and exit codes, over `bench.api.sweep`."""

from __future__ import annotations

import dataclasses
import sys
from typing import Any

from bench.api.sweep import SweepConfig, sweep
from bench.core.config import build, command_help, split_args, top_key
from bench.core.errors import ConfigError


def help_text() -> str:
    return command_help(
        "usage: bench sweep checkpoints=[A,B,...]|DIR suite=NAME [alpha=0.05 min_success= out=DIR] [bench run keys]",
        "Run a suite once per training checkpoint on common seeds (the same episodes for every checkpoint),\n"
        "plot success against training step with simultaneous intervals, and select the best checkpoint\n"
        "with Hsu's multiple comparison with the best (paired, Bonferroni): the best set holds every\n"
        "checkpoint no other beats by a paired one-sided bound at 1 - alpha/(K-1); it contains the truly\n"
        "best with probability >= 1 - alpha however many checkpoints were looked at. Every other key is a\n"
        "`bench run` key, the same for every checkpoint (episodes=, seed=, robots=, horizon=, workers=, ...).",
        SweepConfig,
        [
            "bench sweep checkpoints=train/ckpts suite=held_out_robots episodes=20 out=runs/sweep",
            "bench sweep checkpoints=[ckpt/step_1000.safetensors,ckpt/step_2000.safetensors] suite=held_out_robots min_success=0.5",
        ],
        notes="The training step comes from the checkpoint spec's meta (step, global_step, train_step,\n"
        "iteration), else from the file name (the number after step/iter/it, else its last number), else the\n"
        "checkpoints' order; sweep.json says which. Checkpoints of different architectures (spec architecture,\n"
        "kwargs, observation or action names) are refused. Exit codes: 0 a checkpoint selected; 1 min_success=\n"
        "given and the selected checkpoint's lower bound is below it; 2 bad input (nothing written); 3 a\n"
        "checkpoint measured nothing. Writes OUT/runs/<checkpoint>/ (each a leaderboard entry),\n"
        "OUT/leaderboard.json, OUT/sweep.json and OUT/sweep.png; rerunning resumes.",
    )


def split(argv: list[str]) -> tuple[SweepConfig, list[str]]:
    """The sweep's own keys into a SweepConfig; the rest are forwarded to every run."""
    positional, overrides = split_args(argv)
    if positional:
        raise ConfigError(f"unexpected argument {positional[0]!r}; bench sweep takes key=value only")
    own = {f.name for f in dataclasses.fields(SweepConfig)}
    if any(top_key(o) == "checkpoints" and o.split("=", 1)[1].replace(" ", "") == "[]" for o in overrides):
        raise ConfigError("checkpoints=[]: the checkpoint list is empty; give checkpoint files or a folder of them")
    mine = [o for o in overrides if top_key(o) in own]
    return build(SweepConfig, mine), [o for o in overrides if top_key(o) not in own]


def format_verdict(doc: dict[str, Any]) -> str:
    pct = f"{doc['simultaneous_confidence'] * 100:.3g}%"
    lines = [f"{'checkpoint':<28} {'step':>10}  {doc['metric'] + ' (' + pct + ' simultaneous)':<34}  best set"]
    for r in doc["checkpoints"]:
        s = r["success"]
        value = "n/a" if s["value"] is None else f"{s['value']:.3f} [{s['ci'][0]:.3f}, {s['ci'][1]:.3f}]"
        mark = (
            "yes" if r["in_best_set"] else f"no (beaten by {r['beaten_by']['checkpoint']})" if r["beaten_by"] else "no"
        )
        star = " *" if r["name"] == doc["selected"] else ""
        lines.append(f"{r['name'][:28]:<28} {r['step']:>10g}  {value:<34}  {mark}{star}")
    lines.append(f"steps from: {doc['step_source']}")
    n = len(doc["best_set"])
    if doc["selected"]:
        lines.append(
            f"selected: {doc['selected']} (* ; highest estimate in the best set)"
            + (
                f"; {n - 1} other checkpoint(s) cannot be told apart from it at alpha={doc['alpha']:g}"
                if n > 1
                else f"; it beats every other checkpoint at family-wise alpha={doc['alpha']:g}"
            )
        )
    if doc["exit_code"] == 1:
        lines.append(f"FAIL: the selected checkpoint's lower bound is below min_success={doc['min_success']:g}")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    """`bench sweep checkpoints=... [run keys]`."""
    if not argv or any(a in ("-h", "--help", "help") for a in argv):
        print(help_text(), end="")
        return 0 if argv else 2
    cfg, run_keys = split(argv)
    result = sweep(cfg, run_keys, progress=lambda m: print(m, file=sys.stderr))
    print(format_verdict(result.doc))
    print(
        f"wrote {result.out}/sweep.json, leaderboard.json, {', '.join(result.figures) or 'no figure'}", file=sys.stderr
    )
    if result.exit_code == 3:
        print("nothing measured for: " + ", ".join(r["name"] for r in result.doc["checkpoints"] if not r["episodes"]))
    return result.exit_code

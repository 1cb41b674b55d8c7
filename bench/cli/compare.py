"""`bench compare`: the command line of the two-policy comparison (parsing, help, exit codes).

What it does — pairing, the group-sequential test, the outputs — is `bench.api.compare`'s; the `bench run`
keys it forwards are typed by the runner's and the suite's configs (bench.api) before anything runs.
"""

from __future__ import annotations

from bench import api
from bench.api.compare import CompareConfig, check_compare, compare
from bench.cli.forwarding import split_keys
from bench.core import config as config_mod
from bench.core.errors import NothingMeasured

FORBIDDEN = {"policy": "a=/b=", "checkpoint": "a=/b=", "record": None}


def help_text() -> str:
    return config_mod.command_help(
        "usage: bench compare a=X b=Y [alpha=0.05 beta=0.2 delta=0.2 batch=5] [key=value ...]",
        "Which of two policies is better, with as few episodes as it takes: A and B play the same suite\n"
        "cells with the same episode seeds, in looks of `batch` episodes per cell, and stop at the first look\n"
        "that reaches an answer (a group-sequential test on the paired difference d = A - B in success,\n"
        "Lan-DeMets O'Brien-Fleming error spending; docs/compare.md). Answers:\n"
        "  A better / B better   the paired test names it; when A and B are equal this happens with\n"
        "                        probability <= alpha (both directions, all looks together)\n"
        "  equivalent            |d| < delta is shown (two one-sided tests); when |d| >= delta this\n"
        "                        happens with probability <= beta\n"
        "  inconclusive          the cap was reached first\n"
        "A difference of delta is named with probability >= 1 - beta at the planned (most discordant)\n"
        "outcomes. The cap (episodes per cell) is sized for that unless episodes= is given. Each cell is\n"
        "answered too (alpha / cells, beta / cells); the pooled answer decides when to stop. X and Y: a\n"
        "registered policy, a checkpoint, or a recorded run directory (its episodes are reused; two run\n"
        "directories are compared look by look, nothing run). paired=false compares two recorded runs on\n"
        "other seeds as unpaired batches: Boschloo's exact test (Fisher's beside), one look.",
        CompareConfig,
        notes=(
            "  (and the `bench run` keys suite, episodes (the cap), seed, workers, horizon, timeout, robots, tasks,\n"
            "   envs, splits, metric, perturb.*, the suite's own keys; bench run --help)\n\n"
            "exit: 0 an answer (or inconclusive), 2 bad input, 3 nothing measured.\n"
            "writes: RUNS/RUN_ID/RUN_ID-a/ and -b/ run dirs (unless reused) and the comparison JSON (schema\n"
            "bench.compare/1: answer, per-look and per-cell tests with repeated confidence intervals, the pairs\n"
            "used against the cap and the fixed-N design at equal errors)."
        ),
        examples=[
            "bench compare a=scripted b=random robots=[Panda] batch=2",
            "bench compare a=ckpt/new.safetensors b=ckpt/old.safetensors delta=0.1 beta=0.1",
            "bench compare a=runs/new_run b=runs/old_run",
            "bench compare a=runs/seed0_run b=runs/seed1_run paired=false",
        ],
    )


def parse_args(argv: list[str]) -> tuple[CompareConfig, list[str]]:
    """Own keys -> CompareConfig; `bench run` keys (the runner's and the suite's) checked and forwarded."""
    own, forwarded, _ = split_keys(argv, CompareConfig, FORBIDDEN, "compare")
    cfg: CompareConfig = config_mod.build(CompareConfig, own)
    check_compare(cfg)
    api.config_from_argv(forwarded)
    return cfg, forwarded


def main(argv: list[str]) -> int:
    if argv and argv[0] in ("-h", "--help"):
        print(help_text(), end="")
        return 0
    if not argv:
        print(help_text(), end="")
        return 2
    cfg, forwarded = parse_args(argv)
    result = compare(cfg, forwarded)
    if result.nothing_measured:
        raise NothingMeasured(f"compare {result.run_id}: {result.nothing_measured}")
    return result.exit_code

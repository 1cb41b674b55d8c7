"""The command line of `bench regress`: its help, and the `bench run` keys it forwards, every one checked (names,
types, ranges) before anything is read or run; the gate's own keys are `bench.api.RegressConfig`.
"""

from __future__ import annotations

from bench import api
from bench.api.gate import FORBIDDEN_KEYS, RegressConfig, check_regress
from bench.cli.forwarding import split_keys
from bench.core import config as config_mod


def help_text() -> str:
    return config_mod.command_help(
        "usage: bench regress candidate=X baseline=Y [key=value ...]\n"
        "       bench regress plan=true [cells=N] [power=0.8 drop=0.6 rate=0.9] [margin= alpha= batch= episodes=]",
        "CI regression gate: runs candidate and baseline on the same suite cells with the same episode\n"
        "seeds, pairs outcomes by (cell, episode), and fails when the candidate is confidently worse by\n"
        "more than `margin`: pooled over all pairs, in the IQM across cells, in a split, or in any one cell\n"
        "(one-sided paired tests, weighted Holm across them, alpha spent over the looks). Episodes run in\n"
        "batches and stop once the verdict is certain. A baseline run directory is reused (the candidate\n"
        "runs with its settings; different cells, horizon or seeds are refused). Identical checkpoints\n"
        "(same sha256) are not simulated. paired=false compares two recorded runs whose seeds differ\n"
        "(unpaired): one look, Chan's exact unconditional test per cell, a stratified score test per split\n"
        "and pooled, weighted Holm across them (docs/ci-gate.md, Unpaired runs).",
        RegressConfig,
        notes=(
            "  (and the `bench run` keys suite, episodes (default 20), seed, workers, horizon, timeout, robots,\n"
            "   tasks, envs, splits, metric, n_boot, confidence, perturb.*, the suite's own keys; bench run --help)\n\n"
            "exit: 0 no regression (inconclusive passes unless strict=true), 1 regression, 2 bad input,\n"
            "3 nothing measured (a side completed no episode of some cell: verdict nothing_measured).\n"
            "writes: RUNS/RUN_ID/RUN_ID-candidate/ (and -baseline/ unless reused) run dirs, the verdict JSON\n"
            "(schema bench.regress/2: verdict, regressed cells with drops and bounds, looks, checkpoint sha256,\n"
            "size and training metadata), and beside it X.junit.xml (one test case per cell) and X.md (a\n"
            "Markdown summary for a CI step summary). plan=true prints a budget table and writes nothing."
        ),
        examples=[
            "bench regress candidate=ckpt/new.safetensors baseline=ckpt/old.safetensors robots=[Panda,UR5e]",
            "bench regress candidate=ckpt/new.safetensors baseline=results/runs/<run_id> out=gate/verdict.json",
            "bench regress candidate=random baseline=scripted episodes=4 batch=2",
            "bench regress candidate=results/runs/<new> baseline=results/runs/<old> paired=false",
            "bench regress plan=true suite=held_out_robots power=0.9 drop=0.6 rate=0.9",
        ],
    )


def _split_overrides(argv: list[str]) -> tuple[RegressConfig, list[str], dict[str, str]]:
    """Own keys -> RegressConfig; `bench run` keys (the runner's and the suite's) forwarded verbatim."""
    own, forwarded, by_key = split_keys(argv, RegressConfig, FORBIDDEN_KEYS, "regress")
    cfg: RegressConfig = config_mod.build(RegressConfig, own)
    check_regress(cfg)
    return cfg, forwarded, by_key


def parse_args(argv: list[str]) -> tuple[RegressConfig, list[str], dict[str, str]]:
    """Every key of a `bench regress` command line checked (names, types, ranges); nothing is run or read.

    Returns the gate's own config, the `bench run` overrides it forwards, and those by key.
    The forwarded keys are typed by the runner's and the suite's configs (bench.api).
    """
    cfg, forwarded, by_key = _split_overrides(argv)
    api.config_from_argv(forwarded)
    return cfg, forwarded, by_key

"""`bench leaderboard`: validate result files, merge runs into a leaderboard, show one (over `bench.api.board`)."""

from __future__ import annotations

import textwrap
from collections.abc import Callable

from bench.api.board import MergeConfig, leaderboard_merge, leaderboard_show, leaderboard_validate, render_leaderboard
from bench.core import config
from bench.core.errors import ConfigError, valid_choices

USAGE = "usage: bench leaderboard validate FILE... | merge RUN... out=FILE | show FILE"
VALIDATE_USAGE = "usage: bench leaderboard validate FILE..."
VALIDATE_ABOUT = (
    'Checks result files (summary.json, leaderboard.json, verdict.json) against the JSON Schema their "schema" '
    "field names; exit 0 when all are valid, 2 otherwise. It takes no keys."
)
MERGE_USAGE = "usage: bench leaderboard merge RUN... out=FILE [overwrite=false]"
MERGE_ABOUT = (
    "One leaderboard (bench.leaderboard/1) from run directories, summary.json files or other leaderboards: "
    "one entry per policy x checkpoint x suite version (the run with the most episodes wins; the others are "
    "listed as superseded). Refuses inputs with the same suite but another version or split manifest. Every "
    "input is validated before anything is written; OUT is replaced atomically. To add a run to a "
    "leaderboard, pass the leaderboard as an input and write a new file (OUT is never an input)."
)
MERGE_EXAMPLES = [
    "bench leaderboard merge results/runs/* out=results/leaderboard.json",
    "bench leaderboard merge results/leaderboard.json runs/my_run out=leaderboard-new.json",
]
SHOW_USAGE = "usage: bench leaderboard show FILE"
SHOW_ABOUT = (
    "The leaderboard as terminal tables, one per group (suite, version, metric, selected cells), ranked by "
    "the lower bound of the score: mean success on the unseen split (seen when the suite has none), with "
    "intervals. It takes no keys."
)


def _wrap(text: str, indent: int = 0) -> str:
    """A paragraph wrapped at 100 columns, lines after the first indented by `indent`."""
    return textwrap.fill(text, 100, subsequent_indent=" " * indent, break_on_hyphens=False)


def help_text() -> str:
    """`bench leaderboard --help`: what each subcommand does, merge's keys."""
    subcommands = [
        ("validate FILE...", VALIDATE_ABOUT),
        ("merge RUN... out=FILE", MERGE_ABOUT),
        ("show FILE", SHOW_ABOUT),
    ]
    return config.command_help(
        USAGE,
        "\n".join(_wrap(f"  {name:<22}  {about}", 26) for name, about in subcommands),
        notes=f"merge keys:\n{config.key_help(MergeConfig)}\n\n"
        "`bench leaderboard SUBCOMMAND --help` describes each subcommand.",
        examples=[*MERGE_EXAMPLES, "bench leaderboard show results/leaderboard.json"],
    )


def _merge(argv: list[str]) -> int:
    inputs, overrides = config.split_args(argv)
    cfg: MergeConfig = config.build(MergeConfig, overrides)
    board = leaderboard_merge(inputs, cfg)
    render_leaderboard(board)
    print(f"{len(board['entries'])} entries from {len(inputs)} input(s) -> {cfg.out}")
    return 0


def _validate(files: list[str]) -> int:
    if not files:
        raise ConfigError("leaderboard validate: give at least one FILE")
    for f in files:
        print(f"{f}: valid ({leaderboard_validate(f)})")
    return 0


def _show(files: list[str]) -> int:
    if len(files) != 1:
        raise ConfigError("leaderboard show: give exactly one FILE")
    render_leaderboard(leaderboard_show(files[0]))
    return 0


# subcommand -> (handler, its --help)
SUBCOMMANDS: dict[str, tuple[Callable[[list[str]], int], Callable[[], str]]] = {
    "validate": (_validate, lambda: config.command_help(VALIDATE_USAGE, _wrap(VALIDATE_ABOUT))),
    "merge": (_merge, lambda: config.command_help(MERGE_USAGE, _wrap(MERGE_ABOUT), MergeConfig, MERGE_EXAMPLES)),
    "show": (_show, lambda: config.command_help(SHOW_USAGE, _wrap(SHOW_ABOUT))),
}


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(help_text(), end="")
        return 0 if argv else 2
    cmd, rest = argv[0], argv[1:]
    if cmd not in SUBCOMMANDS:
        raise ConfigError(f"leaderboard: unknown subcommand {cmd!r}; {valid_choices(cmd, SUBCOMMANDS)}")
    handler, help_of = SUBCOMMANDS[cmd]
    if any(a in ("-h", "--help") for a in rest):
        print(help_of(), end="")
        return 0
    return handler(rest)

"""Every command's `--help` lists every key its config dataclass accepts (help built by `config.command_help`).

The table below names the dataclasses of each command and subcommand; it must cover the CLI's command
table and the subcommand tables of `bench logs`, `bench leaderboard` and `bench calibrate`, so a new
command or subcommand fails here until its help is checked too.
"""

from __future__ import annotations

import dataclasses
import re

import pytest

from bench.cli import COMMANDS, main


def _keys(*schemas: type) -> list[str]:
    return [f.name for schema in schemas for f in dataclasses.fields(schema)]


def _table() -> dict[tuple[str, ...], list[str]]:
    from bench.api.calibration import CalibrateConfig, DesignConfig, GenerateConfig, SuiteCalibrateConfig
    from bench.cli.actions import ActionsConfig
    from bench.cli.check import CheckConfig
    from bench.cli.compare import CompareConfig
    from bench.cli.correlate import CorrelateConfig
    from bench.cli.coverage import CoverageConfig
    from bench.cli.leaderboard import MergeConfig
    from bench.cli.logs import FORMATS, CardConfig, ImportConfig, RankConfig
    from bench.cli.perf import PerfConfig
    from bench.cli.predict import PredictConfig
    from bench.cli.regress_args import RegressConfig
    from bench.cli.report import ReportConfig
    from bench.cli.sweep import SweepConfig
    from bench.execution import run_config
    from bench.remote.server import ServeConfig
    from bench.replay.common import ReplayConfig

    return {
        ("run",): list(
            run_config.RUNNER_KEYS
        ),  # suite_options / policy_options are filled by the suite's and policy's keys
        ("list",): [],
        ("check",): _keys(CheckConfig),
        ("score",): [],
        ("leaderboard",): _keys(MergeConfig),
        ("leaderboard", "validate"): [],
        ("leaderboard", "merge"): _keys(MergeConfig),
        ("leaderboard", "show"): [],
        ("perf",): _keys(PerfConfig),
        ("logs",): [],
        ("logs", "info"): [],
        ("logs", "verify"): [],
        ("logs", "import"): _keys(ImportConfig, *FORMATS.values()),
        ("logs", "card"): _keys(CardConfig),
        ("logs", "rank"): _keys(RankConfig),
        ("replay",): _keys(ReplayConfig),
        ("serve",): _keys(ServeConfig),
        ("actions",): _keys(ActionsConfig),
        ("correlate",): _keys(CorrelateConfig),
        ("calibrate",): _keys(CalibrateConfig, SuiteCalibrateConfig, GenerateConfig),
        ("calibrate", "generate"): _keys(GenerateConfig),
        ("calibrate", "design"): _keys(DesignConfig),
        ("calibrate", "effects"): [],
        ("regress",): _keys(RegressConfig),
        ("compare",): _keys(CompareConfig),
        ("report",): _keys(ReportConfig),
        ("coverage",): _keys(CoverageConfig),
        ("predict",): _keys(PredictConfig),
        ("sweep",): _keys(SweepConfig),
    }


TABLE = _table()


def test_the_table_covers_every_command_and_subcommand():
    from bench.cli.calibrate import SUBCOMMANDS as CALIBRATE
    from bench.cli.leaderboard import SUBCOMMANDS as BOARD
    from bench.cli.logs import SUBCOMMANDS as LOGS

    assert {argv[0] for argv in TABLE} == set(COMMANDS)
    for command, subs in (("logs", LOGS), ("leaderboard", BOARD), ("calibrate", CALIBRATE)):
        assert {argv[1] for argv in TABLE if argv[0] == command and len(argv) > 1} == set(subs), command


@pytest.mark.parametrize("argv", sorted(TABLE), ids=" ".join)
def test_help_lists_every_key_and_exits_0(argv, capsys):
    assert main([*argv, "--help"]) == 0
    out, err = capsys.readouterr()
    assert out.startswith("usage: bench " + argv[0]) and not err, err
    missing = [key for key in TABLE[argv] if not re.search(rf"^  {re.escape(key)}\b", out, re.M)]
    assert not missing, f"bench {' '.join(argv)} --help lacks the keys {missing}"


def test_list_names_the_policy_bench_run_uses_by_default(capsys):
    """`bench list` names each suite's default policy: the one `bench run suite=NAME` runs without policy=."""
    from bench.protocols import registry

    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "held_out_robots (v1, default policy: bc, reference policy: scripted)" in out
    for name in registry.names(registry.SUITES):
        cls = registry.suite_class(name)
        used = cls.default_policy or cls.reference_policy  # as bench.execution.run_config.config_from_argv picks it
        assert re.search(rf"^  {re.escape(name)} \(v\S+, default policy: {re.escape(used)}[,)]", out, re.M), name


def _registered_suites() -> list[str]:
    from bench.protocols import registry

    return registry.names(registry.SUITES)


@pytest.mark.parametrize("suite", _registered_suites())
def test_run_help_lists_the_suite_keys_bench_list_shows(suite, capsys):
    """`bench run suite=NAME --help` and `bench list` list a suite's keys from one owner (`option_keys`: every field
    of its Options, inherited ones too, e.g. the camera keys of the robosuite suites' RobosuiteOptions)."""
    from bench.core.errors import RegistryError
    from bench.protocols import option_keys, registry

    try:
        keys = option_keys(registry.suite_class(suite).Options)
    except RegistryError as exc:
        pytest.skip(f"suite {suite} cannot be loaded here: {exc}")
    assert main(["run", f"suite={suite}", "--help"]) == 0
    out = capsys.readouterr().out
    section = out.split(f"keys of suite {suite}:\n", 1)[1].split("\n\n", 1)[0]
    in_help = [] if section.strip() == "(none)" else [re.match(r"  (\w+)", ln).group(1) for ln in section.splitlines()]
    assert main(["list"]) == 0
    listed = re.search(rf"^  {re.escape(suite)} \(.*?(?:\[keys: (.*)\])?$", capsys.readouterr().out, re.M)
    assert listed, suite
    assert in_help == keys == (listed.group(1).split(", ") if listed.group(1) else [])

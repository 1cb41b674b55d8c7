"""`bench check`: its help and command line over `bench.api.check`."""

from __future__ import annotations

from dataclasses import fields

from bench.api.checks import CheckConfig, CheckReport, check
from bench.api.plugins import option_keys, suite_options_type
from bench.core import config as config_mod
from bench.core.errors import ConfigError


def help_text() -> str:
    return config_mod.command_help(
        "usage: bench check [suite=NAME] [key=value ...]",
        'Checks that "unseen really is unseen" and that suites honour the plugin contract:\n'
        "  - seen/unseen manifests disjoint on every axis, cells consistent with the manifest,\n"
        "  - episode seeds distinct; initial-state hashes: no two seeds with the same initial state\n"
        "    (seed wrap-around) and no initial state shared by a seen and an unseen cell,\n"
        "  - the suite against the Suite protocol, and on one cell its env against EnvAdapter: declared\n"
        "    observation spec, spaces, reset/step/success, finite numbers, same seed -> same trajectory.\n"
        "Exit 0 when clean, 2 when a problem is found. `bench run` runs the manifest/seed part first.\n"
        "A suite's own keys (e.g. env_id= for suite=gym) are accepted when suite= names it; checking\n"
        "every suite skips those whose required keys are not given.",
        CheckConfig,
        [
            "bench check suite=held_out_robots robots=[Panda,UR5e]",
            "bench check suite=gym env_id=CartPole-v1",
            "bench check manifest=metaworld:ML25",
            "bench check suite=held_out_robots robots=[Panda] wrap_seeds=2 contract=false",
        ],
    )


def main(argv: list[str]) -> int:
    if argv and argv[0] in ("-h", "--help"):
        print(help_text(), end="")
        return 0

    positional, overrides = config_mod.split_args(argv)
    if positional:
        raise ConfigError(f"unexpected argument {positional[0]!r}; bench check takes key=value only")
    own = [f.name for f in fields(CheckConfig)]
    head = config_mod.build(CheckConfig, [o for o in overrides if config_mod.top_key(o) == "suite"])
    suite_keys = option_keys(suite_options_type(head.suite)) if head.suite else []
    parts = config_mod.partition(overrides, {"check": own, f"suite {head.suite}": suite_keys}, "bench check")
    cfg: CheckConfig = config_mod.build(CheckConfig, parts["check"])
    return _report(check(cfg, parts.get(f"suite {head.suite}", []), note=print))


def _report(report: CheckReport) -> int:
    for p in report.problems:
        print(f"  [{p.kind}] {p.message}")
    print(f"{'clean' if report.clean else f'{len(report.problems)} problem(s)'} ({report.wall_s:.1f} s)")
    return 0 if report.clean else 2

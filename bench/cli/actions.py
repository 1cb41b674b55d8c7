"""`bench actions`: a policy fed logged observations, its actions compared with the logged ones — the command line
and the table over `bench.api.actions` (`bench.api.policy_on_logs` says how the comparison is made).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from bench.api.plugins import option_keys, policy_options_type
from bench.api.policy_on_logs import ActionsConfig, actions
from bench.core import config as config_mod
from bench.core.console import table_console
from bench.core.errors import ConfigError


def help_text() -> str:
    return config_mod.command_help(
        "usage: bench actions logs=DIR [policy=scripted] [suite=held_out_robots] [out=FILE] [policy keys ...]",
        "Policy on logs: feeds each episode's logged observation.state to the policy (open loop) and\n"
        "compares its actions with the logged action, per dimension: mean absolute error and RMSE with\n"
        "a bootstrap interval over episodes. Episodes name their suite cell in the task string\n"
        "(`Lift/Panda/default`, as `bench run record=` writes). The policy's own keys (e.g.\n"
        "checkpoint= for policy=checkpoint) are accepted too.",
        ActionsConfig,
        [
            "bench actions logs=demos policy=scripted",
            "bench actions logs=demos policy=checkpoint checkpoint=bc/policy.safetensors out=actions.json",
        ],
    )


def parse_args(argv: list[str]) -> tuple[ActionsConfig, Any]:
    """The command's own keys and the policy plugin's (e.g. checkpoint=), each typed by its owner."""
    positional, overrides = config_mod.split_args(argv)
    if positional:
        raise ConfigError(f"unexpected argument {positional[0]!r}; bench actions takes key=value only")
    head = config_mod.build(ActionsConfig, [o for o in overrides if config_mod.top_key(o) == "policy"])
    options = policy_options_type(head.policy)
    own = [f.name for f in dataclasses.fields(ActionsConfig)]
    parts = config_mod.partition(
        overrides, {"actions": own, f"policy {head.policy}": option_keys(options)}, "bench actions"
    )
    return config_mod.build(ActionsConfig, parts["actions"]), config_mod.build(options, parts[f"policy {head.policy}"])


def main(argv: list[str]) -> int:
    if argv and argv[0] in ("-h", "--help"):
        print(help_text(), end="")
        return 0
    cfg, policy_options = parse_args(argv)
    result = actions(cfg, policy_options)
    from rich.table import Table  # rich: loaded only when something is drawn on the terminal

    conf = int(round(cfg.confidence * 100))
    t = Table(
        title=f"policy {cfg.policy} on {result['episodes']} logged episodes ({result['frames']} frames)",
        title_justify="left",
    )
    for col in ("action dim", f"MAE [{conf}% CI]", f"RMSE [{conf}% CI]"):
        t.add_column(col)
    fmt = lambda e: f"{e['value']:.4f}" + (f" [{e['ci'][0]:.4f}, {e['ci'][1]:.4f}]" if e["ci"] else "")  # noqa: E731
    for row in result["per_dim"]:
        t.add_row(row["dim"], fmt(row["mae"]), fmt(row["rmse"]))
    table_console().print(t)
    lat = result.get("policy_latency")
    if lat:  # a remote policy: its round trips, one per logged frame
        ms = lat["rtt_ms"]
        print(
            f"round trips: {lat['requests']}, median {ms['p50']:.3g} ms, p90 {ms['p90']:.3g} ms, max {ms['max']:.3g} ms"
        )
    if cfg.out:
        print(f"wrote {cfg.out}")
    return 0

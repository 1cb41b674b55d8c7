"""`bench serve`: its help and command line over `bench.api.serve` (a policy served over openpi's protocol)."""

from __future__ import annotations

import dataclasses
import sys
import time
from typing import Any

from bench.api.plugins import option_keys, policy_options_type, suite_options_type
from bench.api.serving import ServeConfig, check_serve, serve
from bench.core import config as config_mod
from bench.core.errors import ConfigError


def help_text() -> str:
    return config_mod.command_help(
        "usage: bench serve [policy=scripted] [host=127.0.0.1] [port=8000] [suite=...] [policy keys ...]",
        "Serves a bench policy over openpi's websocket protocol (msgpack-numpy, metadata on connect,\n"
        'infer(obs) -> {"actions": (T, A)}), so `bench run policy=remote` or openpi\'s client can use it\n'
        "from another process, venv or machine. Bench clients name their suite, cell and seeds (records\n"
        "equal in-process ones); other clients get the policy of suite=/cell=. Malformed requests get a\n"
        "one-line text answer and the server goes on. The served policy's own keys (checkpoint= ...) and\n"
        "its suite's are accepted too. Ctrl-C or SIGTERM stops it. docs/remote-policies.md",
        ServeConfig,
        [
            "bench serve policy=scripted",
            "bench serve policy=checkpoint checkpoint=bc/policy.safetensors port=8001",
            "bench serve policy=scripted suite=held_out_envs host=0.0.0.0   # reachable from other machines",
        ],
    )


def parse_args(argv: list[str]) -> tuple[ServeConfig, Any, Any]:
    """(serve config, the suite's options, the policy's options), each key routed to its owner."""
    positional, overrides = config_mod.split_args(argv)
    if positional:
        raise ConfigError(
            f"unexpected argument {positional[0]!r}; bench serve takes key=value only (bench serve --help)"
        )
    head = config_mod.build(ServeConfig, [o for o in overrides if config_mod.top_key(o) in ("policy", "suite")])
    policy_options = policy_options_type(head.policy)
    suite_options = suite_options_type(head.suite)
    owners = {
        "serve": [f.name for f in dataclasses.fields(ServeConfig)],
        f"suite {head.suite}": option_keys(suite_options),
        f"policy {head.policy}": option_keys(policy_options),
    }
    context = f"bench serve policy={head.policy} suite={head.suite}"
    parts = list(config_mod.partition(overrides, owners, context).values())
    cfg = config_mod.build(ServeConfig, parts[0])
    check_serve(cfg)
    return cfg, config_mod.build(suite_options, parts[1]), config_mod.build(policy_options, parts[2])


def main(argv: list[str]) -> int:
    if argv and argv[0] in ("-h", "--help"):
        print(help_text(), end="")
        return 0
    cfg, suite_options, policy_options = parse_args(argv)

    def log(text: str) -> None:
        print(f"[{time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)

    serve(cfg, suite_options, policy_options, log)
    return 0

"""`bench serve`: its help, its command line and the command that starts `bench.remote.server.PolicyServer`."""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from typing import Any

from bench.core import config as config_mod
from bench.core.errors import ConfigError
from bench.protocols import option_keys, registry
from bench.remote.server import MAX_HORIZON, PolicyServer, ServeConfig
from bench.remote.serving import AddressInUse


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
    plugin = registry.load_policy(head.policy)
    suite_cls: Any = registry.suite_class(head.suite)
    owners = {
        "serve": [f.name for f in dataclasses.fields(ServeConfig)],
        f"suite {head.suite}": option_keys(suite_cls.Options),
        f"policy {head.policy}": option_keys(plugin.Options),
    }
    context = f"bench serve policy={head.policy} suite={head.suite}"
    parts = list(config_mod.partition(overrides, owners, context).values())
    cfg = config_mod.build(ServeConfig, parts[0])
    if not 0 <= cfg.port <= 65535:
        raise ConfigError(f"port={cfg.port}: must be in [0, 65535] (0 = any free port)")
    if not (math.isfinite(cfg.max_message_mb) and 0 < cfg.max_message_mb <= 4096):
        raise ConfigError(f"max_message_mb={cfg.max_message_mb}: must be in (0, 4096]")
    if not 1 <= cfg.batch <= 1024:
        raise ConfigError(f"batch={cfg.batch}: must be in [1, 1024] (1 = answer each request alone)")
    if not (math.isfinite(cfg.batch_wait_ms) and 0 <= cfg.batch_wait_ms <= 1000):
        raise ConfigError(f"batch_wait_ms={cfg.batch_wait_ms}: must be in [0, 1000]")
    if not 0 <= cfg.prepare <= 1024:
        raise ConfigError(f"prepare={cfg.prepare}: must be in [0, 1024] (0 = build envs on first reset only)")
    if not 0 <= cfg.horizon <= MAX_HORIZON or cfg.seed < 0:
        raise ConfigError(f"horizon={cfg.horizon} seed={cfg.seed}: horizon in [0, {MAX_HORIZON}], seed >= 0")
    return cfg, config_mod.build(suite_cls.Options, parts[1]), config_mod.build(plugin.Options, parts[2])


def main(argv: list[str]) -> int:
    if argv and argv[0] in ("-h", "--help"):
        print(help_text(), end="")
        return 0
    cfg, suite_options, policy_options = parse_args(argv)

    def log(text: str) -> None:
        print(f"[{time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)

    server = PolicyServer(cfg, suite_options, policy_options, log)
    suite = server.suite_cls(suite_options)
    cell = next(c for c in suite.all_cells() if c.key == server.default_cell)
    server.plugin.preflight(policy_options, suite, [cell], server.default_horizon)  # e.g. checkpoint names
    ws = server.websocket()
    try:
        port = ws.bind()
    except AddressInUse as exc:
        raise ConfigError(
            f"host={cfg.host} port={cfg.port}: cannot listen there ({exc.strerror}); pick another "
            "port (port=0 = any free one)"
        ) from None
    where = f"[{cfg.host}]" if ":" in cfg.host else cfg.host

    try:
        ws.serve_until_stopped(
            f"bench serve: policy {cfg.policy} on ws://{where}:{port} (suite {suite.name}, "
            f"default cell {server.default_cell}); Ctrl-C stops",
            "bench serve",
        )
    finally:
        server.close()
    return 0

"""Serving policies over openpi's websocket protocol: `serve` is `bench serve` (a bench policy, for `policy=remote`
runs or openpi's client in another process, venv or machine; docs/remote-policies.md), and the parts for serving a
policy from another stack.

`WebsocketServer` answers metadata on connect and one reply per request for any handler; `wire` is
the msgpack-numpy encoding, checked on the way in. `baselines/lerobot_adapter.py` serves a lerobot
policy with them from lerobot's own environment.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from bench.core.errors import ConfigError
from bench.remote import wire
from bench.remote.server import MAX_HORIZON, PolicyServer, ServeConfig
from bench.remote.serving import AddressInUse, RequestError, WebsocketServer

__all__ = ["RequestError", "ServeConfig", "WebsocketServer", "check_serve", "serve", "wire"]


def check_serve(cfg: ServeConfig) -> None:
    """The ranges of `bench serve`'s own keys (one line naming the key and what is valid)."""
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


def serve(
    cfg: ServeConfig,
    suite_options: Any = None,
    policy_options: Any = None,
    log: Callable[[str], None] | None = None,
) -> None:
    """Serve `cfg.policy` on `cfg.host`:`cfg.port` until Ctrl-C or SIGTERM (prints its address, then `stopped`).

    `suite_options` / `policy_options`: instances of the suite's and the policy's Options (None: their defaults);
    `log`: where the server's events go (`bench serve`: timestamped lines on stderr). The policy's preflight runs
    (e.g. a checkpoint's file is checked) and the port is bound before the first request is accepted.
    """
    check_serve(cfg)
    server = PolicyServer(cfg, suite_options, policy_options, log)
    suite = server.suite_cls(server.suite_options)
    cell = next(c for c in suite.all_cells() if c.key == server.default_cell)
    server.plugin.preflight(server.policy_options, suite, [cell], server.default_horizon)  # e.g. checkpoint names
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

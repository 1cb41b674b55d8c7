"""Serving a policy from another stack over openpi's websocket protocol (what `bench serve` speaks).

`WebsocketServer` answers metadata on connect and one reply per request for any handler; `wire` is
the msgpack-numpy encoding, checked on the way in. `baselines/lerobot_adapter.py` serves a lerobot
policy with them from lerobot's own environment.
"""

from __future__ import annotations

from bench.remote import wire
from bench.remote.serving import RequestError, WebsocketServer

__all__ = ["RequestError", "WebsocketServer", "wire"]

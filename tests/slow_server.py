"""A real policy server that is slow to set up, or hangs: what `policy=remote`'s warm-up is tested against.

    python tests/slow_server.py [--first 20] [--change 20] [--hang connect|request] [--port 0]

It is `bench serve policy=scripted suite=tests.toy_suite:ToySuite` (bench's own sessions: the scripted
expert on the toy suite) behind bench's websocket server on 127.0.0.1, with sleeps where a real VLA server
pays its set-up:

- `--first S`: the first request of every connection sleeps S seconds (loading a model, a JIT compile);
- `--change S`: a reset that names another cell than the connection's current one (at first the server's
  default cell, the suite's first) sleeps S seconds (building the new cell's simulator);
- `--hang connect`: accept TCP connections and never answer the websocket handshake;
  `--hang request`: send the metadata, then never answer any request.

The first stdout line is `listening on 127.0.0.1:PORT`. It runs until killed.
"""

from __future__ import annotations

import argparse
import socket
import sys
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.toy_suite, from this checkout

from bench.remote import wire  # noqa: E402
from bench.remote.server import PolicyServer, ServeConfig, Session  # noqa: E402

TOY = "tests.toy_suite:ToySuite"


class SlowSession:
    """bench's own session, with the set-up sleeps of a slow server (see the module docstring)."""

    def __init__(self, inner: Session, default_cell: str, first_s: float, change_s: float, hang: bool):
        self.inner, self.cell = inner, default_cell
        self.first_s, self.change_s, self.hang = first_s, change_s, hang
        self.requests = 0

    def handle(self, msg: dict[str, Any]) -> dict[str, Any]:
        self.requests += 1
        if self.hang:
            threading.Event().wait()  # forever
        if self.requests == 1:
            time.sleep(self.first_s)
        body = msg.get(wire.CONTROL)
        if isinstance(body, dict) and body.get("op") == "reset" and body.get("cell") != self.cell:
            time.sleep(self.change_s)
            self.cell = body.get("cell")
        return self.inner.handle(msg)

    def close(self) -> None:
        self.inner.close()


def serve(first_s: float, change_s: float, hang: str | None, port: int) -> None:
    if hang == "connect":  # the kernel accepts connections into the backlog; nobody ever reads them
        sock = socket.create_server(("127.0.0.1", port), backlog=64)
        print(f"listening on 127.0.0.1:{sock.getsockname()[1]}", flush=True)
        threading.Event().wait()
        return
    server = PolicyServer(ServeConfig(policy="scripted", suite=TOY, host="127.0.0.1", port=port), None, None)
    ws = server.websocket()
    ws.open_session = lambda: SlowSession(Session(server), server.default_cell, first_s, change_s, hang == "request")
    bound = ws.bind()
    print(f"listening on 127.0.0.1:{bound}", flush=True)
    ws.serve_until_stopped(f"slow server on 127.0.0.1:{bound}", "slow server")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--first", type=float, default=20.0, help="seconds the first request of a connection sleeps")
    ap.add_argument("--change", type=float, default=20.0, help="seconds a reset that changes cell sleeps")
    ap.add_argument("--hang", choices=("connect", "request"), default=None)
    ap.add_argument("--port", type=int, default=0)
    args = ap.parse_args(argv)
    serve(args.first, args.change, args.hang, args.port)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

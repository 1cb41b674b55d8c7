"""The server half of the protocol, for any handler: metadata on connect, one answer per request.

`WebsocketServer(open_session, metadata)` listens (127.0.0.1 unless told otherwise), sends
`metadata` to each new connection, then answers every request frame with
`session.handle(request)`, encoded as msgpack-numpy. A handler that raises `RequestError`
(or a frame that is not a msgpack map) gets a one-line text frame back (openpi's error
convention) and the connection goes on; so does any other exception, prefixed with
`failure_prefix`. It answers `GET /healthz` like openpi's server.

This module needs only numpy, msgpack and websockets, so an adapter running in another
venv (e.g. `baselines/lerobot_server.py` in lerobot's) serves with the same code as
`bench serve`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any, Protocol

from bench.remote import wire


class RequestError(Exception):
    """A request the server refuses (answered with a one-line text frame; the connection goes on)."""


class Session(Protocol):
    """One connection's state."""

    def handle(self, request: dict[str, Any]) -> dict[str, Any]: ...

    def close(self) -> None: ...


class AddressInUse(OSError):
    """The address cannot be listened on (in use, or not this machine's)."""


class WebsocketServer:
    """A websocket policy server: one thread and one session per connection."""

    def __init__(
        self,
        open_session: Callable[[], Session],
        metadata: dict[str, Any],
        host: str = "127.0.0.1",
        port: int = 8000,
        max_message_bytes: int = 64 * 2**20,
        log: Callable[[str], None] | None = None,
        failure_prefix: str = "the policy failed",
    ):
        self.open_session, self.metadata = open_session, metadata
        self.host, self.port, self.max_message_bytes = host, int(port), int(max_message_bytes)
        self.log = log or (lambda text: None)
        self.failure_prefix = failure_prefix
        self._server: Any = None
        self._metadata_frame = wire.encode(metadata)

    def bind(self) -> int:
        """Open the listening socket and return its port (AddressInUse when that fails)."""
        from websockets.sync.server import serve

        try:
            self._server = serve(
                self._handle,
                self.host,
                self.port,
                compression=None,
                max_size=self.max_message_bytes,
                ping_interval=None,
                process_request=_health,
                logger=_quiet_logger(),
            )
        except OSError as exc:
            raise AddressInUse(exc.errno, exc.strerror or str(exc)) from None
        return int(self._server.socket.getsockname()[1])

    def serve_forever(self) -> None:
        self._server.serve_forever()

    def serve_until_stopped(self, banner: str, label: str) -> None:
        """Print `banner`, serve until Ctrl-C or SIGTERM, shut down, and say so (`label: stopped`)."""
        import signal

        def stop(signum: int, frame: Any) -> None:
            raise KeyboardInterrupt

        signal.signal(signal.SIGTERM, stop)
        print(banner, flush=True)
        try:
            self.serve_forever()
        except KeyboardInterrupt:
            pass
        finally:
            self.shutdown()
        print(f"{label}: stopped", flush=True)

    def start(self) -> int:
        """Bind and serve from a background thread (tests, benchmarks); returns the port."""
        port = self.bind()
        threading.Thread(target=self.serve_forever, name="bench-serve", daemon=True).start()
        return port

    def shutdown(self) -> None:
        """Stop listening, close every connection and wait for their threads."""
        if self._server is not None:
            self._server.shutdown()

    def _handle(self, ws: Any) -> None:
        from websockets.exceptions import ConnectionClosed

        peer = _peer(ws)
        session = self.open_session()
        requests = 0
        self.log(f"client {peer} connected")
        try:
            ws.send(self._metadata_frame)
            while True:
                try:
                    frame = ws.recv()
                except ConnectionClosed:
                    break
                requests += 1
                try:
                    answer: bytes | str = wire.encode(session.handle(wire.decode(frame, "the request")))
                except (RequestError, wire.WireError) as exc:
                    answer = wire.error_line(str(exc))
                    self.log(f"client {peer}: refused request {requests}: {answer[7:]}")
                except Exception as exc:  # the policy or its env failed: report it, keep serving
                    answer = wire.error_line(f"{self.failure_prefix}: {type(exc).__name__}: {exc}")
                    self.log(f"client {peer}: request {requests}: {answer[7:]}")
                try:
                    ws.send(answer)
                except ConnectionClosed:
                    break
        except ConnectionClosed:
            pass
        finally:
            session.close()
            self.log(f"client {peer} disconnected after {requests} request(s)")


def _peer(ws: Any) -> str:
    try:
        host, port = ws.remote_address[:2]
        return f"{host}:{port}"
    except Exception:
        return "?"


def _health(connection: Any, request: Any) -> Any:
    """`GET /healthz` -> 200 OK (as openpi's server); anything else goes on to the websocket handshake."""
    if request.path == "/healthz":
        from http import HTTPStatus

        return connection.respond(HTTPStatus.OK, "OK\n")
    return None


def _quiet_logger() -> Any:
    """websockets' logger silenced: clients dropping mid-handshake are not worth a traceback (we log one line)."""
    import logging

    logger = logging.getLogger("bench.serve.websockets")
    logger.setLevel(logging.CRITICAL)
    return logger

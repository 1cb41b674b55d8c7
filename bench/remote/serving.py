"""The server half of the protocol, for any handler: metadata on connect, one answer per request.

`WebsocketServer(open_session, metadata)` listens (127.0.0.1 unless told otherwise), sends
`metadata` to each new connection, then answers every request frame with
`session.handle(request)`, encoded as msgpack-numpy. A handler that raises `RequestError`
(or a frame that is not a msgpack map) gets a one-line text frame back (openpi's error
convention) and the connection goes on; so does any other exception, prefixed with
`failure_prefix`. It answers `GET /healthz` like openpi's server.

This module needs only numpy, msgpack and websockets (its Sans-I/O protocol), so an adapter running in another
venv (e.g. `baselines/lerobot_server.py` in lerobot's) serves with the same code as
`bench serve`.
"""

from __future__ import annotations

import selectors
import signal
import socket
import threading
import time
from collections.abc import Callable
from http import HTTPStatus
from types import FrameType
from typing import TYPE_CHECKING, Protocol

from bench.remote import link, wire

if TYPE_CHECKING:
    from websockets.http11 import Request, Response
    from websockets.server import ServerProtocol


class RequestError(Exception):
    """A request the server refuses (answered with a one-line text frame; the connection goes on)."""


class Session(Protocol):
    """One connection's state."""

    def handle(self, request: wire.Message) -> wire.Message: ...

    def close(self) -> None: ...


class AddressInUse(OSError):
    """The address cannot be listened on (in use, or not this machine's)."""


class WebsocketServer:
    """A websocket policy server: one thread and one session per connection (`bench.remote.link`, no reader threads)."""

    def __init__(
        self,
        open_session: Callable[[], Session],
        metadata: wire.Message,
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
        self._listener: socket.socket | None = None
        self._wake_r, self._wake_w = socket.socketpair()
        self._stopping = threading.Event()
        self._lock = threading.Lock()
        self._links: set[socket.socket] = set()
        self._threads: set[threading.Thread] = set()
        self._metadata_frame = wire.encode(metadata)

    def bind(self) -> int:
        """Open the listening socket and return its port (AddressInUse when that fails)."""
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        try:
            self._listener = socket.create_server((self.host.strip("[]"), self.port), family=family, backlog=64)
        except OSError as exc:
            raise AddressInUse(exc.errno, exc.strerror or str(exc)) from None
        return int(self._listener.getsockname()[1])

    def serve_forever(self) -> None:
        """Accept connections until `shutdown()` (each served by its own thread)."""
        listener = self._listener
        if listener is None:
            raise RuntimeError("bind() first")
        with selectors.DefaultSelector() as sel:
            sel.register(listener, selectors.EVENT_READ)
            sel.register(self._wake_r, selectors.EVENT_READ)
            while not self._stopping.is_set():
                ready = [key.fileobj for key, _ in sel.select()]
                if self._wake_r in ready or self._stopping.is_set():
                    break
                try:
                    sock, _ = listener.accept()
                except OSError:
                    continue
                sock.setblocking(True)
                thread = threading.Thread(target=self._connection, args=(sock,), name="bench-serve-conn", daemon=True)
                with self._lock:
                    self._links.add(sock)
                    self._threads.add(thread)
                thread.start()

    def serve_until_stopped(self, banner: str, label: str) -> None:
        """Print `banner`, serve until Ctrl-C or SIGTERM, shut down, and say so (`label: stopped`)."""

        def stop(signum: int, frame: FrameType | None) -> None:
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

    def shutdown(self, wait_s: float = 10.0) -> None:
        """Stop listening, close every connection and wait (up to `wait_s`) for their threads."""
        self._stopping.set()
        try:
            self._wake_w.send(b"x")
        except OSError:
            pass
        if self._listener is not None:
            self._listener.close()
        with self._lock:
            links, threads = list(self._links), list(self._threads)
        for sock in links:  # wakes the connection threads blocked in recv
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        deadline = time.monotonic() + wait_s
        for thread in threads:
            if thread is not threading.current_thread():
                thread.join(max(deadline - time.monotonic(), 0.0))

    def _connection(self, sock: socket.socket) -> None:
        try:
            ws = link.accept(sock, self.max_message_bytes, _health)
            if ws is not None:
                self._serve(ws)
        finally:
            try:
                sock.close()
            except OSError:
                pass
            with self._lock:
                self._links.discard(sock)
                self._threads.discard(threading.current_thread())

    def _serve(self, ws: link.Link) -> None:
        peer = _peer(ws.sock)
        session = self.open_session()
        requests = 0
        self.log(f"client {peer} connected")
        try:
            ws.send(self._metadata_frame)
            while True:
                frame = ws.recv()
                requests += 1
                try:
                    answer: bytes | str = wire.encode(session.handle(wire.decode(frame, "the request")))
                except (RequestError, wire.WireError) as exc:
                    answer = wire.error_line(str(exc))
                    self.log(f"client {peer}: refused request {requests}: {answer[7:]}")
                except Exception as exc:  # the policy or its env failed: report it, keep serving
                    answer = wire.error_line(f"{self.failure_prefix}: {type(exc).__name__}: {exc}")
                    self.log(f"client {peer}: request {requests}: {answer[7:]}")
                ws.send(answer)
        except (link.Closed, OSError):
            pass
        finally:
            ws.close()
            session.close()
            self.log(f"client {peer} disconnected after {requests} request(s)")


def _peer(sock: socket.socket) -> str:
    try:
        host, port = sock.getpeername()[:2]
        return f"{host}:{port}"
    except Exception:
        return "?"


def _health(protocol: ServerProtocol, request: Request) -> Response | None:
    """`GET /healthz` -> 200 OK (as openpi's server); anything else goes on to the websocket handshake."""
    if request.path == "/healthz":
        return protocol.reject(HTTPStatus.OK, "OK\n")
    return None

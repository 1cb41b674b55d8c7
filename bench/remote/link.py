"""One websocket over a blocking socket, driven by the thread that uses it.

websockets' Sans-I/O protocol objects (`ClientProtocol`, `ServerProtocol`) do everything the
RFC asks — the opening handshake and its checks, framing, masking, size limits, ping/pong and
the closing handshake — and this module only moves their bytes. websockets' own `sync` API
runs a reader thread per connection and hands every message across threads on both sides;
a policy round trip is one `sendall` and one `recv` in the thread that waits for the answer,
which takes ~0.1 ms off each round trip on localhost (benchmarks/bench_remote.py): what lets
`policy=remote` keep up with an in-process policy.

Any peer speaking RFC 6455 interoperates: openpi's servers and `openpi-client`, lerobot's
adapter, browsers. Extensions (permessage-deflate) are never negotiated: policy messages are
mostly float arrays and camera frames, which compress poorly and slowly.
"""

from __future__ import annotations

import socket
import time
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from websockets.http11 import Request, Response
    from websockets.protocol import Event, Protocol
    from websockets.server import ServerProtocol

BUFSIZE = 2**18
HANDSHAKE_TIMEOUT_S = 10.0


class Closed(ConnectionError):
    """The peer closed the connection, or it broke (the reason in words)."""


class HandshakeFailed(ConnectionError):
    """The opening handshake failed: the peer is not a websocket endpoint, or refused the upgrade."""


class Link:
    """A websocket connection: `send(bytes | str)`, `recv(timeout) -> bytes | str`, `close()`.

    Not thread-safe: one thread uses a link (the runner's worker, or a server's connection thread).
    """

    def __init__(self, sock: socket.socket, protocol: Protocol):
        self.sock, self.protocol = sock, protocol
        self._messages: deque[bytes | str] = deque()
        self._parts: list[bytes | bytearray | memoryview] = []
        self._text = False
        self._timeout: float | None = -1.0  # the socket's current timeout (-1: unknown)

    # -- bytes in and out ---------------------------------------------------------------------
    def _flush(self) -> None:
        """Write what the protocol has queued (answers to pings and closes included)."""
        for data in self.protocol.data_to_send():
            if data:
                try:
                    self.sock.sendall(data)
                except OSError as exc:
                    raise Closed(f"the connection broke while sending ({_words(exc)})") from None
            else:  # the protocol asks for end-of-file on our side
                try:
                    self.sock.shutdown(socket.SHUT_WR)
                except OSError:
                    pass

    def _settimeout(self, timeout: float | None) -> None:
        if timeout != self._timeout:
            self.sock.settimeout(timeout)
            self._timeout = timeout

    def _pump(self, deadline: float | None) -> list[Event]:
        """Read once from the socket (TimeoutError past `deadline`) and return the protocol's events."""
        if deadline is None:
            self._settimeout(None)
        else:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("timed out")
            self._settimeout(left)
        try:
            data = self.sock.recv(BUFSIZE)
        except TimeoutError:
            raise
        except OSError as exc:
            raise Closed(f"the connection broke ({_words(exc)})") from None
        if data:
            self.protocol.receive_data(data)
        else:
            self.protocol.receive_eof()
        events = self.protocol.events_received()
        self._flush()
        return events

    def _take(self, events: list[Event]) -> None:
        """Queue the complete data messages among `events` (fragments joined; control frames are the protocol's)."""
        from websockets.frames import (  # websockets: loaded only when a remote policy connects or is served
            Frame,
            Opcode,
        )

        for event in events:
            if not isinstance(event, Frame):
                continue
            if event.opcode in (Opcode.TEXT, Opcode.BINARY):
                self._parts, self._text = [event.data], event.opcode is Opcode.TEXT
            elif event.opcode is Opcode.CONT:
                self._parts.append(event.data)
            else:
                continue
            if event.fin:
                data = b"".join(self._parts)
                self._parts = []
                self._messages.append(data.decode("utf-8") if self._text else data)

    # -- the API --------------------------------------------------------------------------------
    def send(self, message: bytes | str) -> None:
        """Send one message: bytes as a binary frame, str as a text frame."""
        from websockets.exceptions import (
            InvalidState,  # websockets: loaded only when a remote policy connects or is served
        )

        try:
            if isinstance(message, str):
                self.protocol.send_text(message.encode("utf-8"))
            else:
                self.protocol.send_binary(message)
        except InvalidState:
            raise Closed(self._reason()) from None
        self._flush()

    def recv(self, timeout: float | None = None) -> bytes | str:
        """The next message (bytes or str); TimeoutError after `timeout` seconds, Closed when the peer is gone."""
        from websockets.protocol import State  # websockets: loaded only when a remote policy connects or is served

        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._messages:
            if self.protocol.state in (State.CLOSING, State.CLOSED):
                raise Closed(self._reason())
            self._take(self._pump(deadline))
        return self._messages.popleft()

    def _reason(self) -> str:
        from websockets.protocol import State  # websockets: loaded only when a remote policy connects or is served

        p = self.protocol
        if p.state is State.CLOSED:
            return _words(p.close_exc)
        frame = p.close_rcvd or p.close_sent
        return f"closing ({frame})" if frame is not None else "the connection is closing"

    def close(self) -> None:
        """Start the closing handshake (when still open) and close the socket; never raises."""
        from websockets.protocol import State  # websockets: loaded only when a remote policy connects or is served

        try:
            if self.protocol.state is State.OPEN:
                self.protocol.send_close(1000)
                self._flush()
        except Exception:
            pass
        try:
            self.sock.close()
        except OSError:
            pass


def _words(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _nodelay(sock: socket.socket) -> None:
    try:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    except OSError:  # not a TCP socket
        pass


def connect(uri: str, timeout: float, max_size: int | None) -> Link:
    """Open a websocket to `uri` (`ws://host:port`) within `timeout` seconds.

    Raises ValueError (not a ws:// address), OSError (nothing listening, unreachable host),
    TimeoutError, or HandshakeFailed.
    """
    from websockets.client import ClientProtocol  # websockets: loaded only when a remote policy connects or is served
    from websockets.exceptions import InvalidURI  # websockets: loaded only when a remote policy connects or is served
    from websockets.http11 import Response  # websockets: loaded only when a remote policy connects or is served
    from websockets.uri import parse_uri  # websockets: loaded only when a remote policy connects or is served

    try:
        wsuri = parse_uri(uri)
    except (InvalidURI, ValueError) as exc:
        raise ValueError(f"{uri!r} is not a websocket address ({exc})") from None
    deadline = time.monotonic() + timeout
    sock = socket.create_connection((wsuri.host, wsuri.port), timeout=max(timeout, 0.001))
    _nodelay(sock)
    protocol = ClientProtocol(wsuri, max_size=max_size)
    link = Link(sock, protocol)
    try:
        protocol.send_request(protocol.connect())
        link._flush()
        while True:
            events = link._pump(deadline)
            response = next((e for e in events if isinstance(e, Response)), None)
            if protocol.handshake_exc is not None:
                raise HandshakeFailed(_words(protocol.handshake_exc))
            if response is not None:
                link._take(events)
                return link
            from websockets.protocol import State  # websockets: loaded only when a remote policy connects or is served

            if protocol.state is State.CLOSED:
                raise HandshakeFailed("the server closed the connection during the handshake")
    except BaseException:
        link.close()
        raise


def accept(
    sock: socket.socket,
    max_size: int | None,
    respond: Callable[[ServerProtocol, Request], Response | None] | None = None,
    timeout: float = HANDSHAKE_TIMEOUT_S,
) -> Link | None:
    """The server side of the opening handshake on an accepted socket.

    `respond(protocol, request)` may answer a plain HTTP request itself (e.g. `GET /healthz`)
    by returning `protocol.reject(status, text)`; None goes on to the websocket upgrade.
    Returns the open link, or None when the handshake failed or was answered (the socket is closed).
    """
    from websockets.http11 import Request  # websockets: loaded only when a remote policy connects or is served
    from websockets.protocol import State  # websockets: loaded only when a remote policy connects or is served
    from websockets.server import ServerProtocol  # websockets: loaded only when a remote policy connects or is served

    _nodelay(sock)
    protocol = ServerProtocol(max_size=max_size)
    link = Link(sock, protocol)
    deadline = time.monotonic() + timeout
    try:
        while True:
            events = link._pump(deadline)
            request = next((e for e in events if isinstance(e, Request)), None)
            if request is not None:
                break
            if protocol.handshake_exc is not None or protocol.state is State.CLOSED:
                link.close()
                return None
        response = respond(protocol, request) if respond is not None else None
        if response is None:
            response = protocol.accept(request)
        protocol.send_response(response)
        link._flush()
        if response.status_code != 101:
            link.close()
            return None
        link._take(events)
        return link
    except (TimeoutError, Closed, OSError):
        link.close()
        return None

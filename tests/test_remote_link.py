"""bench.remote.link: the thread-free websocket both `policy=remote` and `bench serve` use.

Checked against websockets' own threaded implementation on the other end (a reference RFC 6455
peer): fragmented messages, pings, the closing handshake, size limits, non-websocket peers, and a
server shut down under a connected client. Everything listens on 127.0.0.1.
"""

from __future__ import annotations

import socket
import threading
import time

import pytest

from bench.remote import link
from bench.remote.serving import WebsocketServer


class Echo:
    """A session that answers every request with the same map (the server's request/answer loop)."""

    def handle(self, request):
        return {"echo": request}

    def close(self):
        pass


@pytest.fixture
def echo_server():
    server = WebsocketServer(Echo, {"hello": "metadata"}, "127.0.0.1", 0, max_message_bytes=4096)
    port = server.start()
    yield port
    server.shutdown()


def reference_server(handler):
    """websockets' threaded server running `handler(ws)`; returns (server, port)."""
    from websockets.sync.server import serve

    server = serve(handler, "127.0.0.1", 0, compression=None)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, server.socket.getsockname()[1]


def test_fragments_are_joined_and_pings_answered():
    def handler(ws):
        ws.ping(b"are you there")
        ws.send([b"ab", b"cd", b"ef"])  # one binary message in three frames
        ws.send(["te", "xt"])  # one text message in two frames
        ws.send(ws.recv())  # echo what the client sends

    server, port = reference_server(handler)
    try:
        ws = link.connect(f"ws://127.0.0.1:{port}", 5.0, None)
        assert ws.recv(5.0) == b"abcdef"
        assert ws.recv(5.0) == "text"
        ws.send(b"\x00" * 100_000)  # larger than one read
        assert ws.recv(5.0) == b"\x00" * 100_000
        ws.close()
    finally:
        server.shutdown()


def test_a_closed_peer_is_closed_not_a_hang():
    server, port = reference_server(lambda ws: ws.close(1001, "going away"))
    try:
        ws = link.connect(f"ws://127.0.0.1:{port}", 5.0, None)
        t0 = time.monotonic()
        with pytest.raises(link.Closed, match="1001|going away|closing"):
            ws.recv(5.0)
        assert time.monotonic() - t0 < 4.0
        ws.close()
    finally:
        server.shutdown()


def test_recv_times_out():
    server, port = reference_server(lambda ws: time.sleep(3))
    try:
        ws = link.connect(f"ws://127.0.0.1:{port}", 5.0, None)
        t0 = time.monotonic()
        with pytest.raises(TimeoutError):
            ws.recv(0.2)
        assert 0.15 < time.monotonic() - t0 < 2.0
        ws.close()
    finally:
        server.shutdown()


def test_a_non_websocket_peer_fails_the_handshake():
    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]

    def http_404():
        conn, _ = listener.accept()
        conn.recv(4096)
        conn.sendall(b"HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\n\r\n")
        conn.close()

    threading.Thread(target=http_404, daemon=True).start()
    try:
        with pytest.raises(link.HandshakeFailed, match="404"):
            link.connect(f"ws://127.0.0.1:{port}", 5.0, None)
    finally:
        listener.close()


def test_bad_addresses_are_value_errors():
    with pytest.raises(ValueError, match="not a websocket address"):
        link.connect("http://127.0.0.1:1", 1.0, None)


def test_server_answers_and_refuses_oversized_requests_per_connection(echo_server):
    from websockets.sync.client import connect

    from bench.remote import wire

    big = wire.encode({"x": b"\x00" * 10_000})  # over the server's 4096-byte limit
    with connect(f"ws://127.0.0.1:{echo_server}", compression=None, proxy=None) as ws:
        assert wire.decode(ws.recv(timeout=5)) == {"hello": "metadata"}
        ws.send(wire.encode({"a": 1}))
        assert wire.decode(ws.recv(timeout=5)) == {"echo": {"a": 1}}
        ws.send(big)
        with pytest.raises(Exception) as info:
            ws.recv(timeout=5)
        assert "1009" in str(info.value) or "too big" in str(info.value).lower()
    with connect(f"ws://127.0.0.1:{echo_server}", compression=None, proxy=None) as ws:  # still serving
        ws.recv(timeout=5)
        ws.send(wire.encode({"b": 2}))
        assert wire.decode(ws.recv(timeout=5)) == {"echo": {"b": 2}}


def test_shutdown_closes_connected_clients():
    server = WebsocketServer(Echo, {}, "127.0.0.1", 0)
    port = server.start()
    ws = link.connect(f"ws://127.0.0.1:{port}", 5.0, None)
    ws.recv(5.0)  # metadata
    t0 = time.monotonic()
    server.shutdown()
    assert time.monotonic() - t0 < 5.0
    with pytest.raises((link.Closed, TimeoutError)):
        ws.recv(2.0)
    ws.close()
    with pytest.raises(OSError):  # no longer listening
        link.connect(f"ws://127.0.0.1:{port}", 0.5, None)

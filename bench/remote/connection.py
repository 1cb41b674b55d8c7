"""One websocket to a policy server: connecting with backoff, bounded requests and answers, the server's metadata.

What `policy=remote` (`bench.remote.client`) talks through; every failure is a `RemoteError` with the
reason, and a socket that failed mid-request is closed so a late answer is never taken for the next one.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from bench.core.errors import BenchError
from bench.remote import link, wire

MAX_REPLY_BYTES = 256 * 2**20


BACKOFF_FIRST_S, BACKOFF_MAX_S = 0.05, 1.0


class RemoteError(BenchError):
    """A policy server that cannot be reached, is too slow, or answers outside the protocol.

    `answered`: the server did answer (a refusal, or an answer outside the protocol), so it is up.
    """

    def __init__(self, message: str, answered: bool = False):
        super().__init__(message)
        self.answered = answered


def address(host: str, port: int) -> str:
    return f"[{host}]:{port}" if ":" in host and not host.startswith("[") else f"{host}:{port}"


WAIT_NOTE_S = 2.0  # a wait longer than this is reported (to the run's progress, or stderr before the run)


_lost: set[str] = set()  # servers this process failed to (re)connect to: connecting is bounded by timeout_s


class _Wait:
    """Reports what a connection waits for once the wait has lasted WAIT_NOTE_S: quick answers say nothing."""

    def __init__(self, report: Callable[[str | None], None] | None, text: str):
        self.report, self.text, self.shown = report, text, False
        self.timer: threading.Timer | None = None

    def __enter__(self) -> _Wait:
        if self.report is not None:
            self.timer = threading.Timer(WAIT_NOTE_S, self._show)
            self.timer.daemon = True
            self.timer.start()
        return self

    def _show(self) -> None:
        self.shown = True
        if self.report is not None:
            self.report(self.text)

    def __exit__(self, *exc: object) -> None:
        if self.timer is not None:
            self.timer.cancel()
        if self.shown and self.report is not None:
            self.report(None)


class Connection:
    """One websocket to a policy server: connect with backoff, bounded request/answer, metadata.

    Any failure during a request closes the socket, so a late answer can never be taken for
    the answer to the next request. `warmup_s` bounds the first connection and the answers a caller
    asks for with `warm=True`; `timeout_s` reconnecting and every other answer. `report` hears what a
    long wait is for (see `_Wait`).
    """

    def __init__(
        self,
        host: str,
        port: int,
        timeout_s: float,
        warmup_s: float | None = None,
        report: Callable[[str | None], None] | None = None,
    ):
        self.host, self.port, self.timeout_s = host, int(port), float(timeout_s)
        self.warmup_s = float(timeout_s if warmup_s is None else warmup_s)
        self.report = report
        self.where = address(host, port)
        self.uri = f"ws://{self.where}"
        self.ws: link.Link | None = None
        self.metadata: wire.Message = {}
        self.cell: str | None = None  # the cell of the last acknowledged reset on this connection
        self.reached = False  # connected before: a reconnect (after a lost connection) is bounded by timeout_s

    @property
    def connected(self) -> bool:
        return self.ws is not None

    @property
    def bench(self) -> wire.Message | None:
        """The bench part of the server's metadata, when it speaks bench's protocol extension."""
        meta = self.metadata.get("bench")
        return meta if isinstance(meta, dict) and meta.get("protocol") == wire.PROTOCOL else None

    def connect(self) -> wire.Message:
        """Open the socket and read the server's metadata, retrying with backoff.

        The first connection is bounded by `warmup_s` (a server may still be loading its model before
        it listens); a reconnect, or any connection to a server this process already failed to reach,
        by `timeout_s`: a server that went away mid-run fails episodes quickly until it is back.
        """
        self.close()
        self.cell = None
        first = not self.reached and self.where not in _lost
        limit, key = (self.warmup_s, "warmup_s") if first else (self.timeout_s, "timeout_s")
        deadline = time.monotonic() + limit
        delay, attempts, last = BACKOFF_FIRST_S, 0, "no attempt"
        silent = False  # the last attempt's TCP connection was accepted, and then nothing came
        with _Wait(self.report if first else None, f"the policy server at {self.where} (up to {key}={limit:g} s)"):
            while True:
                attempts += 1
                left = deadline - time.monotonic()
                try:
                    ws = link.connect(self.uri, max(left, 0.01), MAX_REPLY_BYTES)
                except ValueError as exc:  # not a ws:// address
                    raise RemoteError(f"host={self.host!r} port={self.port}: not a valid address ({exc})") from None
                except (OSError, TimeoutError, EOFError) as exc:  # link.HandshakeFailed is an OSError
                    last, silent = _reason(exc), isinstance(exc, TimeoutError)
                else:
                    try:
                        self.metadata = self._metadata(ws, deadline, key, limit)
                    except BaseException:
                        ws.close()
                        _lost.add(self.where)
                        raise
                    self.ws, self.reached = ws, True
                    _lost.discard(self.where)
                    return self.metadata
                left = deadline - time.monotonic()
                if left <= 0:
                    _lost.add(self.where)
                    if silent:
                        raise RemoteError(
                            f"the server at {self.where} accepted the connection but did not answer the websocket "
                            f"handshake within {key}={limit:g} s (is it hung, or not a websocket policy server?)"
                        )
                    raise RemoteError(
                        f"no policy server at {self.where}: {last} ({attempts} attempt(s) in "
                        f"{key}={limit:g} s; is bench serve or the server running?)"
                    )
                time.sleep(min(delay, left))
                delay = min(delay * 2, BACKOFF_MAX_S)

    def _metadata(self, ws: link.Link, deadline: float, key: str, limit: float) -> wire.Message:
        try:
            frame = ws.recv(timeout=max(deadline - time.monotonic(), 0.01))
        except TimeoutError:
            raise RemoteError(
                f"the server at {self.where} accepted the connection but sent no metadata within "
                f"{key}={limit:g} s (is it a websocket policy server?)"
            ) from None
        except Exception as exc:
            raise RemoteError(f"the server at {self.where} closed before sending metadata: {_reason(exc)}") from None
        try:
            return wire.decode(frame, "the server's metadata")
        except wire.WireError as exc:
            raise RemoteError(f"server at {self.where}: {exc}") from None

    def request(self, message: wire.Message, warm: bool = False) -> wire.Message:
        """Send one message and return the decoded answer; RemoteError (and a closed socket) on any failure.

        `warm`: the answer may pay the server's set-up (bounded by `warmup_s`, and reported if long).
        """
        limit = self.warmup_s if warm else self.timeout_s
        with _Wait(
            self.report if warm else None,
            f"the policy server at {self.where} to warm up (up to warmup_s={limit:g} s)",
        ):
            self.send(message)
            return self.receive(warm)

    def send(self, message: wire.Message) -> None:
        """Send one message without waiting for its answer (`receive` reads it): the caller works meanwhile."""
        if self.ws is None:
            raise RemoteError(f"not connected to {self.where}")
        try:
            frame = wire.encode(message)
        except wire.WireError as exc:
            raise RemoteError(f"observation for {self.where}: {exc}") from None
        ok = False
        try:
            self.ws.send(frame)
            ok = True
        except (link.Closed, OSError) as exc:
            raise RemoteError(f"the server at {self.where} closed the connection ({_reason(exc)})") from None
        finally:
            if not ok:
                self.close()

    def receive(self, warm: bool = False) -> wire.Message:
        """The decoded answer to the message sent last; RemoteError (and a closed socket) on any failure."""
        if self.ws is None:
            raise RemoteError(f"the connection to {self.where} was lost")
        limit, key = (self.warmup_s, "warmup_s") if warm else (self.timeout_s, "timeout_s")
        ok = False
        try:
            answer = self.ws.recv(timeout=limit)
            ok = True
        except TimeoutError:
            raise RemoteError(f"the server at {self.where} did not answer within {key}={limit:g} s") from None
        except (link.Closed, OSError) as exc:
            raise RemoteError(f"the server at {self.where} closed the connection ({_reason(exc)})") from None
        finally:
            if not ok:  # includes the episode's own timeout interrupting recv: never reuse this socket
                self.close()
        if isinstance(answer, str):
            text = " ".join(answer.split())[:400]
            raise RemoteError(f"the server at {self.where} refused the request: {text}", answered=True)
        try:
            return wire.decode(answer, "the server's answer")
        except wire.WireError as exc:
            self.close()  # it does not speak the protocol: start clean next time
            raise RemoteError(f"server at {self.where}: {exc}", answered=True) from None

    def close(self) -> None:
        ws, self.ws = self.ws, None
        if ws is not None:
            try:
                ws.close()
            except Exception:
                pass


def _reason(exc: BaseException) -> str:
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused (nothing listening)"
    text = " ".join(str(exc).split()) or type(exc).__name__
    return f"{type(exc).__name__}: {text}"[:300]


def forget_failure(where: str) -> None:
    """Let the next first connection to `where` wait up to its `warmup_s` again (a new run: the server
    may be setting up again, whatever an earlier run in this process saw)."""
    _lost.discard(where)

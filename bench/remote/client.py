"""`policy=remote`: a policy served over openpi's websocket protocol (bench serve, openpi, lerobot adapter).

    bench run suite=held_out_robots policy=remote host=127.0.0.1 port=8000 replan_every=5

Each `act(obs)` is one round trip: the observation (selected and renamed by `obs_map=`) goes
out as msgpack-numpy, the server's `{"actions": (T, A)}` comes back, and the runner executes the
first `replan_every` rows open loop (all of them with 0) before asking again. `reset(seed)`
starts an episode: towards a bench server it tells the server the episode's seed and cell so the
served policy resets exactly as it would in process.

Two bounds. A server pays its set-up on a connection's first answers: loading a model, a JIT
compile, building a cell's simulator (tens of seconds for real VLA servers). `warmup_s` (default
300 s) bounds that: a policy's first connection (retrying with exponential backoff while nothing
listens yet), the server's metadata, the reset that builds a cell (and any reset that changes
cell), and one warm-up inference on a zero observation of the cell's spec (its answer is not used).
The policy warms its connection up when it is made, before the worker starts episodes, and says
through `PolicyContext.status` (the run's progress) what it is waiting for. `timeout_s`
(default 10 s) bounds every other answer, and reconnecting to a server that went away mid-run: a
dead server, or an answer that is not a finite (T, A) action chunk of the env's width, fails that
episode with the reason (the run goes on, and the next episode reconnects and warms up again).
Round-trip latencies are recorded per episode (`bench.remote.latency`); warm-up answers are not.

Before any worker starts, the plugin connects once (`identity`/`preflight`): nothing listening
within `warmup_s` is one line naming host:port (exit 2); a bench server also checks that it can
serve the run's suite and cells.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Optional

import numpy as np

from bench.core.errors import ConfigError
from bench.core.io import jsonable
from bench.protocols import Cell, EnvAdapter, Obs, ObsSpec, PolicyContext, PolicyIdentity, PolicyPlugin, Suite
from bench.remote import latency, wire
from bench.remote import obs_map as obs_map_mod
from bench.remote.connection import Connection, RemoteError, forget_failure

MAX_TIMEOUT_S = 3600.0


def check_actions(reply: wire.Message, dim: int, where: str) -> np.ndarray:
    """The action chunk (T, dim) of a server's answer; RemoteError naming what is wrong."""
    if wire.ACTIONS not in reply:
        raise RemoteError(f"the answer of {where} has no {wire.ACTIONS!r} entry (keys: {sorted(reply)[:8]})")
    raw = reply[wire.ACTIONS]
    try:
        actions = np.asarray(raw)
    except Exception:
        actions = np.asarray([])
    if actions.dtype.kind not in "fiu":
        raise RemoteError(f"{where} answered actions of type {type(raw).__name__}/{actions.dtype}, not numbers")
    if actions.ndim == 1:
        actions = actions[None, :]
    if actions.ndim != 2 or actions.shape[0] < 1 or actions.shape[1] != dim:
        raise RemoteError(
            f"{where} answered actions of shape {list(np.shape(raw))}; this env needs ({dim},) or a chunk (T, {dim})"
        )
    if not np.all(np.isfinite(actions)):
        raise RemoteError(f"{where} answered a non-finite action (NaN or inf)")
    return actions


class RemotePolicy:
    """One cell's policy behind a server: warmed up when made, `reset(seed)` per episode, `act(obs)` one round trip."""

    def __init__(self, options: RemoteOptions, cell: Cell, env: EnvAdapter, ctx: PolicyContext):
        self.options, self.cell, self.ctx = options, cell, ctx
        self.dim, self.fps = int(env.action_spec.dim), float(env.fps)
        entries = obs_map_mod.parse(options.obs_map)
        self.map = obs_map_mod.ClientMap(entries, env.obs_spec, cell.task)
        self.zero = self.map(zero_observation(env.obs_spec, cell.task))
        self.conn = Connection(options.host, options.port, options.timeout_s, options.warmup_s, ctx.status)
        weakref.finalize(self, self.conn.close)  # the runner drops policies without closing them
        self._rtt: list[float] = []
        self._server_ms: list[float] = []
        self._steps = 0  # env steps the actions returned so far cover (the step the next act() answers)
        self._obs_steps: list[int] = []  # per chunk: the step whose observation the server saw
        self._pending: float | None = None  # overlap: when the prefetched request went out
        self._sent: float | None = None  # when the request `receive` reads the answer of went out
        try:
            self.warm_up(0)  # before any episode: the server's set-up is not an episode's time
        except BaseException:
            self.conn.close()
            raise

    def _reset_message(self, seed: int) -> wire.Message:
        suite = self.ctx.suite
        return {
            wire.CONTROL: {
                "op": "reset",
                "seed": int(seed),
                "cell": self.cell.key,
                **suite_ref(suite),
                "run_seed": int(self.ctx.seed),
                "horizon": int(self.ctx.horizon),
            }
        }

    def warm_up(self, seed: int) -> None:
        """Connect and wait for the server's set-up, each answer bounded by `warmup_s`.

        A bench server builds the cell's env and policy at its first reset; any server may load or
        compile its model at its first inference, made here on a zero observation of the cell's spec.
        Its answer is not used: any answer, a refusal or one outside the protocol included, means the
        server is ready (the episodes say what is wrong with its answers); only no answer fails.
        """
        self.conn.connect()
        if self.conn.bench is not None:
            _control(self.conn, self._reset_message(seed), warm=True)
        try:
            self.conn.request(self.zero, warm=True)
        except RemoteError as exc:
            if not exc.answered:
                raise
            if not self.conn.connected:  # its answer closed the connection: the episode starts on a fresh one
                self.conn.connect()
                if self.conn.bench is not None:
                    _control(self.conn, self._reset_message(seed))

    def reset(self, seed: int) -> None:
        self._rtt, self._server_ms = [], []
        self._steps, self._obs_steps = 0, []
        if self._pending is not None or self._sent is not None:  # an answer nobody read: start clean
            self._pending = self._sent = None
            self.conn.close()
        for attempt in (0, 1):
            if not self.conn.connected:
                self.warm_up(seed)  # a new connection: the server sets it up again (the reset included)
                return
            if self.conn.bench is None:
                return  # openpi servers keep no per-episode state we could reset
            try:
                _control(self.conn, self._reset_message(seed), warm=self.conn.cell != self.cell.key)
                return
            except RemoteError:
                if attempt:
                    raise
                self.conn.close()  # the server may have restarted since the last episode: reconnect once

    def act(self, obs: Obs) -> np.ndarray:
        self.send(obs)
        return self.receive()

    def send(self, obs: Obs) -> None:
        """`act`'s request, its answer read by `receive` (`bench.protocols.SplitPolicy`): a vectorised run sends every
        env's observation before it reads an answer, so a server with `batch=N` answers them in one forward pass.
        Nothing is sent when a prefetched request (`overlap=true`) already carries this step's answer."""
        if not self.conn.connected:
            raise RemoteError(f"the connection to {self.conn.where} was lost during the episode")
        if self._pending is not None:
            return
        message = self.map(obs)
        self._sent = time.perf_counter()
        self.conn.send(message)

    def receive(self) -> np.ndarray:
        """The rows to execute from the answer to `send` (or to the prefetched request)."""
        if self._pending is not None:
            return self._collect()
        sent, self._sent = self._sent, None
        if sent is None:
            raise RemoteError(f"no request to {self.conn.where} is waiting for its answer (send first)")
        reply = self.conn.receive()
        self._rtt.append(time.perf_counter() - sent)
        self._obs_steps.append(self._steps)
        chunk = self._chunk(reply)
        n = self.options.replan_every
        rows = chunk[:n] if n else chunk
        self._steps += len(rows)
        return rows

    def _chunk(self, reply: wire.Message) -> np.ndarray:
        timing = reply.get("server_timing")
        if isinstance(timing, dict) and isinstance(timing.get("infer_ms"), (int, float)):
            self._server_ms.append(float(timing["infer_ms"]))
        return check_actions(reply, self.dim, self.conn.where)

    def prefetch(self, obs: Obs, t: int) -> bool:
        """`overlap=true`: send the next chunk's request now, from step `t`'s observation, while the env steps.

        Called by the rollout as the current chunk's last row is about to execute (at step `t`); the next
        `act` then reads that answer instead of sending its own observation. The server's chunk starts at
        step `t` (its first row is the action for the observation it saw), so rows 1 .. replan_every are
        executed from step t + 1 on: the same timing as without overlap, one step of observation older.
        """
        if not self.options.overlap or not self.conn.connected or self._pending is not None:
            return False
        self.conn.send(self.map(obs))
        self._pending = time.perf_counter()
        self._obs_steps.append(int(t))
        return True

    def _collect(self) -> np.ndarray:
        sent, self._pending = self._pending, None
        assert sent is not None
        reply = self.conn.receive()
        self._rtt.append(time.perf_counter() - sent)  # the round trip, mostly hidden behind the env's step
        chunk = self._chunk(reply)
        n = self.options.replan_every
        if len(chunk) <= n:
            raise RemoteError(
                f"overlap=true executes rows 1..{n} of each chunk (replan_every={n}), but {self.conn.where} "
                f"answered {len(chunk)} row(s): give a replan_every below the chunk length, or overlap=false"
            )
        rows = chunk[1 : 1 + n]
        self._steps += len(rows)
        return rows

    def episode_stats(self) -> dict[str, object]:
        stats = latency.episode_stats(self._rtt, self._server_ms, self.fps)
        # which observation the server saw for each chunk: the step it was taken at (overlap: one step early)
        stats["obs_steps"] = list(self._obs_steps)
        stats["overlap"] = bool(self.options.overlap)
        return stats

    def close(self) -> None:
        self.conn.close()


def zero_observation(spec: ObsSpec, task: str) -> Obs:
    """An observation of `spec` made of zeros (the task name for text entries): the warm-up inference's input."""
    return {
        key: task if feat.dtype == "str" else np.zeros(feat.shape, dtype=np.dtype(feat.dtype))
        for key, feat in spec.items()
    }


def suite_ref(suite: Suite) -> dict[str, object]:
    """How a client names its suite to a bench server: name, class path and options (JSON)."""
    cls = type(suite)
    opts = getattr(suite, "options", None)
    return {
        "suite": str(getattr(suite, "name", cls.__name__)),
        "suite_class": f"{cls.__module__}:{cls.__qualname__}",
        "suite_options": _jsonable(dataclasses.asdict(opts))
        if dataclasses.is_dataclass(opts) and not isinstance(opts, type)
        else {},
    }


def _jsonable(x: object) -> object:
    return jsonable(x)


def _control(conn: Connection, message: wire.Message, warm: bool = False) -> wire.Message:
    """Send a bench control message and check the acknowledgement (`warm`: it may pay the server's set-up)."""
    reply = conn.request(message, warm=warm)
    body = reply.get(wire.CONTROL)
    if not isinstance(body, dict) or not body.get("ok"):
        raise RemoteError(
            f"the server at {conn.where} did not acknowledge {message[wire.CONTROL]['op']!r}: {str(body)[:200]}"
        )
    if message[wire.CONTROL]["op"] == "reset":
        conn.cell = message[wire.CONTROL].get("cell")
    return body


@dataclass(frozen=True)
class RemoteOptions:
    """Keys of policy=remote."""

    host: str = "127.0.0.1"  # the policy server's address (bench serve, openpi, the lerobot adapter)
    port: int = 8000  # its port (8000 is openpi's and bench serve's default)
    timeout_s: float = 10.0  # bound on each answer in an episode (and on reconnecting mid-run); then it fails
    warmup_s: float = 300.0  # bound on connecting and on the server's set-up: first answers of a connection
    replan_every: int = 0  # rows of each action chunk executed before asking again; 0 = the whole chunk
    overlap: bool = (
        False  # ask for the next chunk one step early, while the env steps (needs 1 <= replan_every < chunk length)
    )
    obs_map: Optional[list[str]] = None  # WIRE_KEY:SOURCE entries, e.g. [observation/state:state,prompt:task]


def validate(options: RemoteOptions) -> None:
    """One-line ConfigError for a value no run could use."""
    if not options.host or any(c.isspace() for c in options.host) or "/" in options.host:
        raise ConfigError(f"host={options.host!r}: give a host name or IP address (e.g. 127.0.0.1)")
    if not 1 <= options.port <= 65535:
        raise ConfigError(f"port={options.port}: must be in [1, 65535]")
    for key in ("timeout_s", "warmup_s"):
        value = getattr(options, key)
        if not (math.isfinite(value) and 0 < value <= MAX_TIMEOUT_S):
            raise ConfigError(f"{key}={value}: must be > 0 and at most {MAX_TIMEOUT_S:g} s")
    if options.replan_every < 0:
        raise ConfigError(f"replan_every={options.replan_every}: must be >= 0 (0 = execute the whole chunk)")
    if options.overlap and options.replan_every < 1:
        raise ConfigError(
            "overlap=true: give replan_every >= 1 (and below the server's chunk length); the next chunk is "
            "requested while row replan_every of the current one executes"
        )
    obs_map_mod.parse(options.obs_map)


class RemotePlugin(PolicyPlugin):
    """`policy=remote` (entry point `bench.policies: remote`): the client side of the policy server protocol."""

    Options = RemoteOptions
    reports_stats = True

    def __init__(self) -> None:
        self._meta: dict[tuple[str, int], wire.Message] = {}

    def obs_keys(self, options: RemoteOptions) -> tuple[str, ...]:
        return obs_map_mod.env_keys(obs_map_mod.parse(options.obs_map))

    def _metadata(self, options: RemoteOptions) -> wire.Message:
        key = (options.host, options.port)
        if key not in self._meta:
            validate(options)
            conn = Connection(options.host, options.port, options.timeout_s, options.warmup_s, _to_stderr)
            forget_failure(conn.where)  # a new run waits for a server's set-up again, whatever an earlier one saw
            try:
                self._meta[key] = conn.connect()
            except RemoteError as exc:
                raise RemoteError(f"policy=remote: {exc}") from None
            finally:
                conn.close()
        return self._meta[key]

    def identity(self, options: RemoteOptions) -> PolicyIdentity:
        """The served checkpoint and its sha256 when the server is a bench server that reports them."""
        bench = self._metadata(options).get("bench")
        if isinstance(bench, dict) and bench.get("protocol") == wire.PROTOCOL:
            ckpt, sha = bench.get("checkpoint"), bench.get("checkpoint_sha256")
            return PolicyIdentity(str(ckpt) if ckpt else None, str(sha) if sha else None)
        return PolicyIdentity()

    def preflight(self, options: RemoteOptions, suite: Suite, cells: Sequence[Cell], horizon: int) -> None:
        """Reachable server, obs_map sources in every cell's observation, and a bench server able to serve them."""
        validate(options)
        entries = obs_map_mod.parse(options.obs_map)
        for cell in cells:
            obs_map_mod.check(entries, suite.obs_spec(cell), f"suite {suite.name!r} cell {cell.key}")
        self._metadata(options)
        conn = Connection(options.host, options.port, options.timeout_s, options.warmup_s, _to_stderr)
        try:
            conn.connect()
            if conn.bench is not None:
                first = cells[0] if cells else None
                sends = obs_map_mod.wire_spec(entries, suite.obs_spec(first)) if first is not None else {}
                check = {
                    "op": "check",
                    **suite_ref(suite),
                    "cells": [c.key for c in cells],
                    "sends": sends,
                    "horizon": int(horizon),  # the server builds these cells' envs while the workers start
                }
                _control(conn, {wire.CONTROL: check}, warm=True)
        except RemoteError as exc:
            raise RemoteError(f"policy=remote: {exc}") from None
        finally:
            conn.close()

    def make(self, cell: Cell, env: EnvAdapter, ctx: PolicyContext) -> RemotePolicy:
        return RemotePolicy(ctx.options, cell, env, ctx)


def _to_stderr(text: str | None) -> None:
    """Before the run (no progress yet): what the plan waits for, on stderr (a long wait is not a hang)."""
    if text is not None:
        print(f"waiting for {text}; Ctrl-C stops", file=sys.stderr, flush=True)

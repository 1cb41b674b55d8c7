"""`bench serve`: any bench policy behind openpi's websocket protocol.

    bench serve policy=scripted                         # ws://127.0.0.1:8000
    bench serve policy=checkpoint checkpoint=bc/policy.safetensors port=8001
    bench serve policy=my_pkg.policies:make suite=held_out_envs host=0.0.0.0

One harness can then evaluate a policy that lives in another venv or on another machine
(`bench run policy=remote host=... port=...`), and openpi's own client can query it. Each
connection gets its own policies (one per cell it asks for, made exactly as a `bench run`
worker makes them: `plugin.make(cell, env, ctx)` on the cell's env), so concurrent workers
never share episode state. A bench client names its suite, cell, run seed and episode seed in
a `reset` control message, which is what makes remote records equal in-process ones; any other
client (openpi's) gets the policy of `suite=`/`cell=` reset with `seed=` when it connects.

A request that is not msgpack, lacks an observation entry the policy needs, or has the wrong
shape or dtype is answered with a one-line text frame (openpi's error convention) and the
connection stays usable; nothing a client sends is unpickled or imported: suites are the
server's registered ones or its own `suite=`. The server listens on 127.0.0.1 unless `host=`
says otherwise, answers `GET /healthz`, and stops cleanly on Ctrl-C or SIGTERM.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from bench import __version__
from bench.core import config as config_mod
from bench.core.errors import BenchError, ConfigError, did_you_mean
from bench.core.io import jsonable
from bench.protocols import TASK, EnvAdapter, Feature, Obs, Policy, PolicyContext, Suite, batchable, registry
from bench.remote import obs_map as obs_map_mod
from bench.remote import wire
from bench.remote.batching import Batcher
from bench.remote.serving import RequestError, WebsocketServer

MAX_HORIZON = 100_000


@dataclass(frozen=True)
class ServeConfig:
    """Keys of `bench serve` (the served policy's own keys, and its suite's, are accepted too)."""

    policy: str = "scripted"  # registered policy name or package.module:attr, as in bench run
    suite: str = "held_out_robots"  # suite for clients that name none (openpi's); bench clients name theirs
    cell: Optional[str] = None  # that suite's cell TASK/ROBOT/ENV for such clients; default: its first cell
    seed: int = 0  # run seed and episode seed for such clients
    horizon: int = 0  # horizon given to policy factories for such clients; 0 = the suite's default
    host: str = "127.0.0.1"  # address to listen on (0.0.0.0: every interface, i.e. other machines too)
    port: int = 8000  # port to listen on; 0 = any free port (printed at start)
    obs_map: Optional[list[str]] = None  # WIRE_KEY:BENCH_KEY renames of incoming entries: [observation/state:state]
    max_message_mb: float = 64.0  # largest request accepted, in MiB
    prepare: int = 8  # envs built ahead, in the background, for the cells a bench client announces (0 = none)
    batch: int = 1  # answer up to N connections' requests in one forward pass (policies with act_batch); 1 = off
    batch_wait_ms: float = 2.0  # with batch > 1: how long the first request of a batch waits for more, at most


@dataclass
class Served:
    """One cell's env and policy in a session."""

    env: EnvAdapter
    policy: Policy
    spec: dict[str, Feature]


def class_path(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


class PolicyServer:
    """Serves one bench policy plugin over websockets (one thread and one `Session` per connection)."""

    def __init__(
        self, cfg: ServeConfig, suite_options: Any, policy_options: Any, log: Callable[[str], None] | None = None
    ):
        self.cfg = cfg
        self.log = log or (lambda text: None)
        self.plugin = registry.load_policy(cfg.policy)
        if policy_options is None:
            policy_options = config_mod.build(self.plugin.Options, [])
        self.policy_options = policy_options
        self.suite_cls: type[Suite] = registry.suite_class(cfg.suite)
        self.suite_options = suite_options
        self.map = obs_map_mod.server_map(obs_map_mod.parse(cfg.obs_map))
        self.needs = tuple(self.plugin.obs_keys(policy_options))
        suite = self.suite_cls(suite_options)
        cells = {c.key: c for c in suite.all_cells()}
        if cfg.cell is not None and cfg.cell not in cells:
            raise ConfigError(
                f"cell={cfg.cell!r} is not a cell of suite {cfg.suite!r}; valid: {', '.join(cells)}."
                f"{did_you_mean(cfg.cell, cells)}"
            )
        self.default_cell = cfg.cell or next(iter(cells))
        self.default_horizon = cfg.horizon or suite.default_horizon
        self.identity = self.plugin.identity(policy_options)
        self.metadata = {
            "bench": {
                "protocol": wire.PROTOCOL,
                "policy": cfg.policy,
                "policy_options": _json(policy_options),
                "checkpoint": self.identity.checkpoint,
                "checkpoint_sha256": self.identity.checkpoint_sha256,
                "suite": suite.name,
                "cell": self.default_cell,
                "obs_keys": list(self.needs),
                "obs_map": list(cfg.obs_map) if cfg.obs_map else None,
                "bench_version": str(__version__),
            }
        }
        self._suites: dict[str, Suite] = {}  # suites clients named, by class path and options (built once)
        self._lock = threading.Lock()
        self.prepared = Prepared(cfg.prepare, log=self.log)
        self.sessions = 0  # open connections (a batch need not wait for more requests than there are clients)
        self.batcher = Batcher(cfg.batch, cfg.batch_wait_ms / 1000.0, lambda: self.sessions) if cfg.batch > 1 else None

    # -- suites and cells, resolved from what a client names ------------------------------
    def suite_for(self, name: object, path: object, options: object) -> Suite:
        """The suite a client names: registered on this server, or this server's own `suite=` (never imported)."""
        if not isinstance(name, str) or not isinstance(path, str):
            raise RequestError("suite and suite_class must be strings")
        candidates = [self.suite_cls]
        if ":" not in name and name in registry.names(registry.SUITES):
            candidates.append(registry.suite_class(name))
        cls = next((c for c in candidates if class_path(c) == path), None)
        if cls is None:
            raise RequestError(
                f"suite {name!r} ({path}) is not served here: this server serves registered suites "
                f"and suite={self.cfg.suite}; restart it with suite={path}"
            )
        if not isinstance(options, dict):
            raise RequestError("suite_options must be a map")
        key = json.dumps([path, options], sort_keys=True, default=str)
        with self._lock:
            if key not in self._suites:
                try:
                    self._suites[key] = cls(config_mod.build(cls.Options, [], base=options) if options else None)
                except BenchError as exc:
                    raise RequestError(f"suite {name!r}: {exc}") from None
            return self._suites[key]

    def build(self, suite: Suite, cell_key: object, run_seed: int, horizon: int) -> Served:
        """The cell's env and policy, made as a bench worker makes them (the env prepared ahead if it was)."""
        cells = {c.key: c for c in suite.all_cells()}
        if cell_key not in cells:
            raise RequestError(f"cell {cell_key!r} is not a cell of suite {suite.name!r}")
        cell = next(c for key, c in cells.items() if key == cell_key)
        env = self.prepared.take(env_key(suite, cell_key, horizon))
        if env is None:
            env = suite.make_env(cell, horizon)
        try:
            missing = [k for k in self.needs if k not in env.obs_spec]
            if missing:
                raise RequestError(
                    f"policy {self.cfg.policy!r} needs observation keys {missing}; cell {cell_key} "
                    f"gives {sorted(env.obs_spec)}"
                )
            ctx = PolicyContext(self.policy_options, suite, int(run_seed), int(horizon))
            policy = self.plugin.make(cell, env, ctx)
        except BaseException:
            env.close()
            raise
        return Served(env, policy, dict(env.obs_spec))

    def prepare(self, suite: Suite, cells: list[str], horizon: int) -> None:
        """Start building the envs of `cells` in the background (a client announced its run)."""
        by_key = {c.key: c for c in suite.all_cells()}
        for key in cells:
            self.prepared.add(env_key(suite, key, horizon), functools.partial(suite.make_env, by_key[key], horizon))

    def close(self) -> None:
        self.prepared.close()
        if self.batcher is not None:
            self.batcher.close()

    # -- serving --------------------------------------------------------------------------
    def websocket(self) -> WebsocketServer:
        """The websocket server of this policy (not yet listening)."""
        return WebsocketServer(
            lambda: Session(self),
            self.metadata,
            self.cfg.host,
            self.cfg.port,
            int(self.cfg.max_message_mb * 2**20),
            self.log,
            f"policy {self.cfg.policy!r} failed",
        )

    def start(self) -> tuple[WebsocketServer, int]:
        """Listen and serve from a background thread (tests, benchmarks): (server, port)."""
        ws = self.websocket()
        return ws, ws.start()


class Session:
    """One connection's state: the policies made for it and the one in use."""

    def __init__(self, server: PolicyServer):
        self.server = server
        self.served: dict[str, Served] = {}
        self.current: Served | None = None
        with server._lock:
            server.sessions += 1

    def handle(self, msg: wire.Message) -> wire.Message:
        if wire.CONTROL in msg:
            if len(msg) != 1:
                raise RequestError(f"a control request holds only the {wire.CONTROL!r} entry")
            return self.control(msg[wire.CONTROL])
        return self.infer(msg)

    def _get(self, suite: Suite, cell: object, run_seed: object, horizon: object) -> Served:
        seed, steps = _bounded("run_seed", run_seed, 0, 2**63 - 1), _bounded("horizon", horizon, 1, MAX_HORIZON)
        key = json.dumps([class_path(type(suite)), _json(getattr(suite, "options", None)), cell, seed, steps])
        if key not in self.served:
            self.served[key] = self.server.build(suite, cell, seed, steps)
        return self.served[key]

    def control(self, body: object) -> wire.Message:
        if not isinstance(body, dict):
            raise RequestError(f"{wire.CONTROL} must be a map with an 'op'")
        op = body.get("op")
        if op not in ("reset", "check"):
            raise RequestError(f"control op {op!r} is unknown; valid: reset, check")
        suite = self.server.suite_for(body.get("suite"), body.get("suite_class"), body.get("suite_options", {}))
        if op == "check":
            cells = {c.key for c in suite.all_cells()}
            asked = body.get("cells") or []
            missing = [c for c in asked if c not in cells] if isinstance(asked, list) else ["(cells is not a list)"]
            if missing:
                raise RequestError(f"suite {suite.name!r} on this server has no cell {missing[0]!r}")
            horizon = body.get("horizon")
            if isinstance(horizon, int) and not isinstance(horizon, bool) and 1 <= horizon <= MAX_HORIZON:
                self.server.prepare(suite, list(asked), horizon)  # built while the client starts its workers
            return {wire.CONTROL: {"ok": True, "op": "check"}}
        seed = body.get("seed")
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise RequestError(f"reset: seed={seed!r} must be a non-negative integer")
        served = self._get(suite, body.get("cell"), body.get("run_seed"), body.get("horizon"))
        served.policy.reset(seed)
        self.current = served
        return {wire.CONTROL: {"ok": True, "op": "reset"}}

    def _default(self) -> Served:
        srv = self.server
        served = self._get(srv.suite_cls(srv.suite_options), srv.default_cell, srv.cfg.seed, srv.default_horizon)
        served.policy.reset(srv.cfg.seed)
        return served

    def infer(self, msg: wire.Message) -> wire.Message:
        if self.current is None:
            self.current = self._default()
        obs = self.observation(msg, self.current.spec)
        policy, batcher = self.current.policy, self.server.batcher
        timing: dict[str, object] = {}
        if batcher is not None and batchable(policy):
            actions, infer_ms, timing["batch"] = batcher.submit(policy, obs)
        else:
            t0 = time.perf_counter()
            actions = np.asarray(policy.act(obs))
            infer_ms = (time.perf_counter() - t0) * 1000.0
        if actions.ndim == 1:
            actions = actions[None, :]  # openpi clients index rows of a chunk
        return {wire.ACTIONS: actions, "server_timing": {"infer_ms": infer_ms, **timing}}

    def observation(self, msg: wire.Message, spec: dict[str, Feature]) -> Obs:
        """The bench observation in a request: renamed, restricted to the cell's spec, shapes and dtypes checked."""
        mapping = self.server.map
        if mapping is not None:
            named = {bench: msg[w] for w, bench in mapping.items() if w in msg}
        else:
            named = {k: v for k, v in msg.items() if k in spec or k == TASK}
        missing = [k for k in self.server.needs if k not in named]
        if missing:
            raise RequestError(
                f"the observation lacks {missing} (policy {self.server.cfg.policy!r} needs "
                f"{list(self.server.needs)}; the request has {sorted(msg)[:12]})"
            )
        obs: Obs = {}
        for key, value in named.items():
            feat = spec.get(key)
            if feat is None or feat.dtype == "str":
                if key == TASK or (feat is not None and feat.dtype == "str"):
                    if not isinstance(value, str):
                        raise RequestError(f"obs[{key!r}] must be a string, got {type(value).__name__}")
                    obs[key] = value
                continue
            arr = value if isinstance(value, np.ndarray) else np.asarray(value)
            want = np.dtype(feat.dtype)
            if arr.shape != feat.shape:
                raise RequestError(
                    f"obs[{key!r}] has shape {list(arr.shape)}; this cell's {key} is {list(feat.shape)} {feat.dtype}"
                )
            if arr.dtype != want:
                if arr.dtype.kind not in "biuf" or not np.can_cast(arr.dtype, want, "same_kind"):
                    raise RequestError(f"obs[{key!r}] has dtype {arr.dtype}; this cell's {key} is {feat.dtype}")
                arr = arr.astype(want)
            obs[key] = arr
        return obs

    def close(self) -> None:
        with self.server._lock:
            self.server.sessions -= 1
        for served in self.served.values():
            try:
                served.env.close()
            except Exception:
                pass
        self.served.clear()


def _bounded(name: str, v: object, lo: int, hi: int) -> int:
    """`v`, an integer in [lo, hi] a client sent; else the one-line error it gets back."""
    if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
        raise RequestError(f"{name}={v!r}: must be an integer in [{lo}, {hi}]")
    return v


def env_key(suite: Suite, cell: object, horizon: int) -> str:
    """What makes two envs of a suite interchangeable: its class and options, the cell and the horizon."""
    return json.dumps([class_path(type(suite)), _json(getattr(suite, "options", None)), cell, horizon], default=str)


class Prepared:
    """Envs built ahead by one background thread, in the order asked, at most `limit` at a time.

    `take(key)` hands over a ready env (waiting for it if its build is under way) or None when there is
    none, so the caller builds its own. Envs nobody took are closed with the server.
    """

    def __init__(self, limit: int, log: Callable[[str], None] | None = None):
        self.limit = max(0, int(limit))
        self.log = log or (lambda text: None)
        self._cond = threading.Condition()
        self._todo: list[tuple[str, Callable[[], EnvAdapter]]] = []
        self._ready: dict[str, list[EnvAdapter]] = {}
        self._building: str | None = None
        self._count = 0  # asked for, not yet taken or closed
        self._closed = False
        self._thread: threading.Thread | None = None

    def add(self, key: str, make: Callable[[], EnvAdapter]) -> None:
        with self._cond:
            if self._closed or self._count >= self.limit:
                return
            if key in self._ready or key == self._building or any(k == key for k, _ in self._todo):
                return  # one env per cell ahead: a second connection to the same cell builds its own
            self._todo.append((key, make))
            self._count += 1
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="bench-serve-prepare", daemon=True)
                self._thread.start()

    def _run(self) -> None:
        while True:
            with self._cond:
                if self._closed or not self._todo:
                    self._thread = None
                    return
                key, make = self._todo.pop(0)
                self._building = key
            env: EnvAdapter | None = None
            try:
                env = make()
            except Exception as exc:  # the client's own reset builds it again and reports the failure
                self.log(f"building an env ahead failed: {type(exc).__name__}: {exc}")
            with self._cond:
                self._building = None
                if env is not None and not self._closed:
                    self._ready.setdefault(key, []).append(env)
                else:
                    self._count -= 1
                    if env is not None:
                        env.close()
                self._cond.notify_all()

    def take(self, key: str) -> EnvAdapter | None:
        with self._cond:
            while self._building == key or any(k == key for k, _ in self._todo):
                if key != self._building:  # not started yet: the caller builds it itself, now
                    self._todo = [(k, m) for k, m in self._todo if k != key]
                    self._count -= 1
                    return None
                self._cond.wait(0.5)
            envs = self._ready.get(key)
            if not envs:
                return None
            env = envs.pop()
            if not envs:
                del self._ready[key]
            self._count -= 1
            return env

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._todo.clear()
            envs = [e for v in self._ready.values() for e in v]
            self._ready.clear()
        for env in envs:
            try:
                env.close()
            except Exception:
                pass


def _json(options: object) -> object:  # a plugin's Options instance as JSON
    if dataclasses.is_dataclass(options) and not isinstance(options, type):
        return jsonable(dataclasses.asdict(options))
    return {}

"""The plugin contract: what a suite, an env adapter, a policy and a policy plugin provide.

Everything the runner needs from a plugin is written here as a `typing.Protocol`; nothing
is probed with `hasattr`. Optional capabilities are declared explicitly: an env adapter
sets `mujoco` / `inputs` to a handle or to None, a suite lists what it offers in
`capabilities`. `bench check` verifies a suite against this contract (`check_suite`,
`check_env` in `bench.execution.check`).

Observations are a dict of named entries with a declared spec (`ObsSpec`):

    state           float32 (D,)        proprioception + object state, fields named in the spec
    rgb.<camera>    uint8 (H, W, 3)     a camera image
    depth.<camera>  float32 (H, W)      metres
    task            str                 the task instruction

A policy's `act(obs)` returns one action (A,) or an action chunk (T, A); the runner
executes a chunk open loop, one row per step, and asks again when it is used up.
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, TypeGuard, runtime_checkable

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    import mujoco  # MuJoCo ships no type information: its MjModel and MjData are opaque to mypy

# An observation: entry name -> a numpy array, or the task instruction (str), as its `ObsSpec` declares. The
# values are left untyped on purpose: which entry is text is the spec's to say, and a policy reads `obs["state"]`
# as the array its spec promises without narrowing a union at every use.
Obs = dict[str, Any]
# numbers of any dtype: a policy's action (the rollout checks that they are finite numbers), a simulator's state
NumArray = npt.NDArray[np.generic]
FloatArray = npt.NDArray[np.floating[Any]]  # floats of any precision (numpy's precision parameter)

STATE = "state"
TASK = "task"
RGB = "rgb."  # prefix of camera-image keys: "rgb.agentview"
DEPTH = "depth."  # prefix of depth-image keys


@dataclass(frozen=True)
class Cell:
    """One (task, robot, env) cell of a suite and the split it belongs to (`seen` or `unseen`)."""

    suite: str
    task: str
    robot: str
    env: str
    split: str
    # the suite's own per-cell settings (JSON-able; `cell_to_dict` writes them), read by the suite that set them
    options: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)

    @property
    def key(self) -> str:
        return f"{self.task}/{self.robot}/{self.env}"


@dataclass(frozen=True)
class Feature:
    """One observation entry: array shape and dtype (dtype "str" for the task instruction).

    `fields` names consecutive runs of a state vector, e.g. (("eef_pos", 3), ("gripper", 1)),
    so a policy or a recorded dataset finds a quantity by name on every robot and backend.
    """

    shape: tuple[int, ...]
    dtype: str
    fields: tuple[tuple[str, int], ...] = ()

    @staticmethod
    def state(fields: Sequence[tuple[str, int]]) -> Feature:
        """A float32 state vector made of named fields."""
        named = tuple((str(n), int(w)) for n, w in fields)
        return Feature((sum(w for _, w in named),), "float32", named)

    @staticmethod
    def rgb(height: int, width: int) -> Feature:
        return Feature((int(height), int(width), 3), "uint8")

    @staticmethod
    def depth(height: int, width: int) -> Feature:
        return Feature((int(height), int(width)), "float32")

    @staticmethod
    def text() -> Feature:
        return Feature((), "str")

    def to_json(self) -> dict[str, object]:
        out: dict[str, object] = {"shape": list(self.shape), "dtype": self.dtype}
        if self.fields:
            out["fields"] = [list(f) for f in self.fields]
        return out


ObsSpec = Mapping[str, Feature]


def describe_spec(spec: ObsSpec) -> str:
    """`state(18) float32, rgb.agentview(128x128x3) uint8`: for error messages."""
    return ", ".join(f"{k}({'x'.join(map(str, f.shape))}) {f.dtype}" for k, f in spec.items())


def check_obs(spec: ObsSpec, obs: object) -> str | None:
    """Why `obs` does not match `spec` (one line), or None when it does."""
    if not isinstance(obs, dict):
        return f"observation is a {type(obs).__name__}, not a dict of named entries"
    missing = [k for k in spec if k not in obs]
    extra = [k for k in obs if k not in spec]
    if missing or extra:
        return f"observation keys {sorted(obs)} differ from the declared {sorted(spec)}"
    for key, feat in spec.items():
        value = obs[key]
        if feat.dtype == "str":
            if not isinstance(value, str):
                return f"obs[{key!r}] is a {type(value).__name__}, declared str"
            continue
        arr = np.asarray(value)
        if arr.shape != feat.shape or arr.dtype != np.dtype(feat.dtype):
            return f"obs[{key!r}] is {arr.shape} {arr.dtype}, declared {feat.shape} {feat.dtype}"
    return None


@dataclass(frozen=True)
class ActionSpec:
    """Names and bounds of the flat action vector."""

    names: tuple[str, ...]
    low: FloatArray = field(compare=False)  # float32 from `box`; an adapter may give float64
    high: FloatArray = field(compare=False)

    @staticmethod
    def box(names: Sequence[str], low: npt.ArrayLike, high: npt.ArrayLike) -> ActionSpec:
        n = len(names)
        lo = np.broadcast_to(np.asarray(low, np.float32), (n,)).copy()
        hi = np.broadcast_to(np.asarray(high, np.float32), (n,)).copy()
        return ActionSpec(tuple(str(a) for a in names), lo, hi)

    @property
    def dim(self) -> int:
        return len(self.names)


@dataclass(eq=False)  # identity semantics: a handle is hashable (perturb caches nominal values per handle)
class MujocoHandle:
    """Capability of MuJoCo-backed adapters: the live model and data (perturbations, replay, recording).

    Attributes:
        model, data: the `mujoco.MjModel` / `MjData` the env steps.
        object_bodies: bodies of the manipulated object(s); `perturb.mass` scales these by default.
        cameras: the env's `bench.sims.camera.CameraRig` when it can render its cameras (image observations,
            episode videos, visual perturbations), else None. Set by `bench.sims.camera_env.CameraEnv`.
        arm_joints: the robot arm's joints (hinge or slide, no gripper); `perturb.init_qpos` offsets these by default.
    """

    model: mujoco.MjModel
    data: mujoco.MjData
    object_bodies: tuple[str, ...] = ()
    # a `bench.sims.camera.CameraRig` (sims sits above this layer, so the contract cannot name its type)
    cameras: Any = None
    arm_joints: tuple[str, ...] = ()

    def forward(self) -> None:
        """Recompute derived quantities after the model or state was edited."""
        import mujoco  # MuJoCo's native library: loaded only when a model is simulated

        mujoco.mj_forward(self.model, self.data)


class InputLog:
    """Capability of MuJoCo adapters whose controller runs in Python: the inputs of every physics step.

    `spec` is an `mjtState` mask of the inputs the env drives (CTRL, plus MOCAP_POS | MOCAP_QUAT
    for Meta-World). While `active`, the adapter appends one row per physics step, as
    `mj_getState(model, data, row, spec)` gives it; `take()` returns the rows of the last control
    step. `record=` stores them as `action.ctrl`, and `bench replay` re-applies them batched.
    """

    def __init__(self, model: mujoco.MjModel, spec: int):
        import mujoco  # MuJoCo's native library: loaded only when a model is simulated

        self.spec = int(spec)
        self.size = int(mujoco.mj_stateSize(model, self.spec))
        self.rows: list[npt.NDArray[np.float64]] | None = None

    @property
    def active(self) -> bool:
        return self.rows is not None

    def start(self) -> None:
        self.rows = []

    def stop(self) -> None:
        self.rows = None

    def take(self) -> npt.NDArray[np.float64]:
        """(substeps, size) inputs applied since the last call; empties the log."""
        if self.rows is None:
            raise RuntimeError("InputLog.take: call start() first")
        out = np.array(self.rows, dtype=np.float64).reshape(-1, self.size)
        self.rows.clear()
        return out


class ModelAxes(Protocol):
    """Capability of non-MuJoCo backends (e.g. PhysX through SAPIEN): model perturbation axes.

    MuJoCo backends need none: `bench.sims.perturb.reset` edits the `MjModel` of their `MujocoHandle`.
    `apply` scales the axis' nominal values (cached by the implementation) by `scale` on the
    named targets ({"bodies": [...], "joints": [...], ...}; empty = the axis' default targets);
    `restore` puts every nominal value back. Both are called before the episode's reset.
    """

    axes: frozenset[str]

    def restore(self) -> None: ...

    def apply(self, axis: str, scale: float, targets: Mapping[str, Sequence[str]]) -> None: ...


@runtime_checkable
class WritesDraws(ModelAxes, Protocol):
    """Optional capability of a non-MuJoCo backend's `ModelAxes` (e.g. the MJX Lift worlds): `perturb.AXIS=
    from(CALIBRATION)` writes one bootstrap draw of a calibration into it (`bench.sims.perturb.reset`).

    `write_draw(axis, keys, values)` writes the absolute `values` of the draw's `field:element[:column]` keys and
    returns the mean ratio of the drawn values to the nominal ones (what perturb records); it raises ConfigError
    naming an element the backend lacks. `restore` puts the nominal values back, as after `apply`.
    """

    def write_draw(self, axis: str, keys: Sequence[str], values: Sequence[float]) -> float: ...


@runtime_checkable
class EnvAdapter(Protocol):
    """One simulator instance of one suite cell, built once per worker and reset per episode.

    Attributes:
        backend: simulator name and versions, e.g. "robosuite-1.5.2/mujoco-3.3.0".
        horizon: control steps in one episode.
        fps: control steps per second (0 when the env has no notion of time).
        obs_spec: the entries `reset` and `step` return.
        action_spec: names and bounds of the action.
        mujoco: a `MujocoHandle` for MuJoCo backends, else None.
        inputs: an `InputLog` when the env can log its per-physics-step inputs, else None.
        model_axes: a `ModelAxes` for non-MuJoCo backends that support model perturbations, else None.
    """

    backend: str
    horizon: int
    fps: float
    obs_spec: ObsSpec
    action_spec: ActionSpec
    mujoco: MujocoHandle | None
    inputs: InputLog | None
    model_axes: ModelAxes | None

    def reset(self, seed: int) -> Obs:
        """Reset to the initial state determined by `seed` alone; return the observation."""
        ...

    def step(self, action: NumArray) -> tuple[Obs, float, bool, bool, dict[str, object]]:
        """Apply one control step: (obs, reward, terminated, truncated, info)."""
        ...

    def success(self) -> bool:
        """The task's success predicate in the current state."""
        ...

    def init_state(self) -> NumArray:
        """The simulator state right after reset (hashed to check that seeds give distinct starts)."""
        ...

    def close(self) -> None:
        """Release the simulator (and any renderer)."""
        ...


@runtime_checkable
class Policy(Protocol):
    """What the rollout calls: `reset(seed)` before each episode, `act(obs)` every step."""

    def reset(self, seed: int) -> None: ...

    def act(self, obs: Obs) -> NumArray:
        """One action (A,) or an action chunk (T, A) executed open loop."""
        ...


class BatchPolicy(Protocol):
    """A policy that answers several observations in one call (`bench run vector=N`, `bench serve batch=N`).

    Policies with equal `batch_key`s are interchangeable (the same weights, spec, bounds and chunking) and keep no
    state an answer changes, so one `act_batch(observations)` call on any of them answers for all of them: one
    answer per observation, in order, each bit for bit what `act` would answer for it alone ((A,) or a chunk
    (T, A)), so a vectorised run's records equal `vector=1`'s. The answers are a sequence, or an array (N, A) or
    (N, T, A). A `batch_key` of None declares nothing (`batchable`).
    """

    batch_key: Hashable

    def act_batch(self, observations: list[Obs]) -> Sequence[npt.ArrayLike] | NumArray: ...


def batchable(policy: object) -> TypeGuard[BatchPolicy]:
    """`policy` declares batches: an `act_batch` method and a `batch_key` that is not None."""
    return callable(getattr(policy, "act_batch", None)) and getattr(policy, "batch_key", None) is not None


@runtime_checkable
class SplitPolicy(Protocol):
    """A policy whose answer can be asked for before it is read (a remote one): `send(obs)` then `receive()` is
    `act(obs)`. A vectorised rollout sends every env's observation before it reads an answer, so a server that
    batches (`bench serve batch=N`) answers them in one forward pass."""

    def send(self, obs: Obs) -> None: ...

    def receive(self) -> NumArray: ...


@runtime_checkable
class ReportsStats(Protocol):
    """A policy made by a plugin with `reports_stats = True`: JSON-able statistics after every episode."""

    def episode_stats(self) -> Mapping[str, object]: ...


CAPABILITIES = ("expert",)  # what a suite may declare in `capabilities`


@runtime_checkable
class Suite(Protocol):
    """A named set of cells with a declared seen/unseen manifest (see docs/plugins.md).

    Class attributes: `name`, `version`, `Options` (a frozen dataclass of the suite's own
    `key=value` keys, e.g. gym's `env_id`; fields without a default are required),
    `reference_policy` (its expert), `default_policy` (what `bench run` runs without
    `policy=`), `default_horizon`, `max_horizon` (None = no limit), `default_metric`
    (success_once | success_at_end | return), `manifest` ({axis: {"seen": [...],
    "unseen": [...]}} over robots / envs / tasks), `capabilities` (a subset of
    `CAPABILITIES`) and `instructions` (its paraphrase data file, or None). A suite is constructed with an
    instance of its `Options`.
    """

    name: ClassVar[str]
    version: ClassVar[str]
    Options: ClassVar[type]
    reference_policy: str
    default_policy: str
    default_horizon: int
    max_horizon: int | None
    default_metric: str
    manifest: Mapping[str, Mapping[str, Sequence[str]]]
    capabilities: frozenset[str]
    # the suite's paraphrase data for `perturb.instruction` (a JSON file it ships: `bench.sims.perturb.language`), or None
    instructions: str | None
    # an instance of the suite's own `Options` dataclass, whose type is the plugin's: a suite declares `options:
    # MyOptions`, which the contract's attribute must accept (a protocol's attributes are invariant)
    options: Any

    def __init__(self, options: Any) -> None:
        """Build the suite with an instance of its `Options`."""
        ...

    def all_cells(self) -> list[Cell]:
        """Every cell of the suite (the runner selects among them)."""
        ...

    def obs_spec(self, cell: Cell) -> ObsSpec:
        """The observation a cell's env will return, declared without building it."""
        ...

    def make_env(self, cell: Cell, horizon: int) -> EnvAdapter:
        """Build the cell's env (called once per worker and cell)."""
        ...

    def action_names(self, cell: Cell) -> Sequence[str] | None:
        """The action names a cell's env will take, declared without building it; None when only a built env
        can tell (`SuiteBase`'s default)."""
        ...

    def make_expert(self, cell: Cell, env: EnvAdapter) -> Policy:
        """The suite's scripted expert for a cell (only with the "expert" capability)."""
        ...

    @classmethod
    def preload(cls) -> None:
        """Import what building the suite's envs needs (its simulator), in a worker process started while
        the parent still plans; `SuiteBase`'s default imports nothing."""
        ...

    def describe(self) -> dict[str, Any]:
        """JSON-able identity: name, version, manifest and the options that change results."""
        ...

    def check_worlds(self, cells: list[Cell], vector: int, workers: int) -> None:
        """Before a run writes anything: refuse (ConfigError, one line) `vector` envs of each of `cells` in each
        of `workers` workers when they cannot fit (a batched simulator's memory per world); `SuiteBase`'s default
        accepts any count."""
        ...


@dataclass(frozen=True)
class PolicyContext:
    """What a policy factory gets besides the cell and its env."""

    options: Any  # an instance of the plugin's Options (its type is the plugin's, read as such by its `make`)
    suite: Suite
    seed: int  # the run seed
    horizon: int
    # while the policy waits for something outside any episode (a policy server warming up): called with
    # what it waits for, then with None; the run's progress shows it. None: nobody listens.
    status: Callable[[str | None], None] | None = field(default=None, compare=False)


@dataclass(frozen=True)
class PolicyIdentity:
    """What records say about the policy: a checkpoint file and its sha256, when there is one."""

    checkpoint: str | None = None
    checkpoint_sha256: str | None = None


@dataclass(frozen=True)
class NoOptions:
    """A plugin that takes no keys of its own."""


class PolicyPlugin(ABC):
    """Base of policy plugins (entry points `bench.policies`, or `policy=module:Class`).

    Override what differs: `Options` (the policy's own keys, e.g. `checkpoint=`), `obs_keys`
    (the observation entries it reads, checked against the suite's declared spec before any
    worker starts), `identity` (checkpoint + sha256 for the records), `preflight` (checks in
    the parent before any worker starts), `make` (one policy per cell and worker) and
    `preload` (heavy imports `make` needs, done by workers started while the parent plans).
    A plain function `factory(cell, env, ctx) -> Policy` is accepted too (`FactoryPlugin`).

    With `reports_stats = True`, the policies it makes implement `episode_stats() -> dict`
    (JSON-able, finite numbers), called once at the end of every episode and stored in the
    episode record under `extras["policy"]` (e.g. a remote policy's round-trip latencies).
    """

    Options: ClassVar[type] = NoOptions
    reports_stats: ClassVar[bool] = False

    # `options` below is an instance of the plugin's `Options`, untyped here so a plugin's override takes it typed
    def obs_keys(self, options: Any) -> tuple[str, ...]:
        return (STATE,)

    def identity(self, options: Any) -> PolicyIdentity:
        return PolicyIdentity()

    def preflight(self, options: Any, suite: Suite, cells: Sequence[Cell], horizon: int) -> None:
        """Raise a BenchError (exit 2) for anything that would fail every episode."""
        return None  # a hook: nothing to check by default

    @abstractmethod
    def make(self, cell: Cell, env: EnvAdapter, ctx: PolicyContext) -> Policy: ...

    def preload(self) -> None:
        """Import what `make` needs (torch, say), in a worker process started while the parent still plans;
        nothing by default. Errors are the build's to report: a worker ignores them here."""
        return None  # a hook


class FactoryPlugin(PolicyPlugin):
    """A plain factory function `f(cell, env, ctx) -> Policy` as a plugin (state observation, no keys)."""

    def __init__(self, factory: Callable[[Cell, EnvAdapter, PolicyContext], Policy]):
        self.factory = factory

    def make(self, cell: Cell, env: EnvAdapter, ctx: PolicyContext) -> Policy:
        return self.factory(cell, env, ctx)


def option_keys(options_type: type) -> list[str]:
    """The `key=value` keys an Options dataclass declares."""
    return [f.name for f in dataclasses.fields(options_type)] if dataclasses.is_dataclass(options_type) else []

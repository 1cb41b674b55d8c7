"""Helpers for env adapters (the contract itself is `bench.protocols.EnvAdapter`).

`AdapterBase` holds the contract's defaults (an adapter sets what it has and inherits the rest);
`AdapterWrapper` forwards the whole contract to an inner adapter, so a wrapper (cameras, a perturbed
interface) overrides only what it changes. `obs_slices` finds a named field in a state vector,
`state_hash` fingerprints initial states, `mj_input_names` names the MuJoCo inputs an `InputLog`
records.
"""

from __future__ import annotations

import hashlib
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from bench.protocols import ActionSpec, EnvAdapter, InputLog, ModelAxes, MujocoHandle, NumArray, Obs, ObsSpec

if TYPE_CHECKING:
    import mujoco  # no type information: MjModel is opaque to mypy

# the contract's attributes, which `AdapterWrapper` copies from its inner adapter
ATTRIBUTES = ("backend", "horizon", "fps", "obs_spec", "action_spec", "mujoco", "inputs", "model_axes")


class AdapterBase(ABC):
    """Defaults of the `EnvAdapter` contract: an adapter sets `backend`, `horizon`, `obs_spec` and
    `action_spec` and implements `reset`, `step` and `success`; the rest has a default here (no
    notion of time, no MuJoCo model, no input log, no non-MuJoCo model axes, the MuJoCo state as
    the initial state, nothing to close)."""

    backend: str = "unknown"
    horizon: int = 0
    fps: float = 0.0
    obs_spec: ObsSpec
    action_spec: ActionSpec
    mujoco: MujocoHandle | None = None
    inputs: InputLog | None = None
    model_axes: ModelAxes | None = None

    @abstractmethod
    def reset(self, seed: int) -> Obs: ...

    @abstractmethod
    def step(self, action: NumArray) -> tuple[Obs, float, bool, bool, dict[str, object]]: ...

    @abstractmethod
    def success(self) -> bool: ...

    def init_state(self) -> NumArray:
        """The MuJoCo state after reset (qpos, qvel); an adapter without MuJoCo overrides it."""
        if self.mujoco is None:
            raise NotImplementedError(f"{type(self).__name__} has no MuJoCo state: implement init_state")
        data = self.mujoco.data
        state: npt.NDArray[np.float64] = np.concatenate([data.qpos, data.qvel]).astype(np.float64)
        return state

    def edit_start(self, edit: Callable[[], None]) -> Obs:
        """Start the episode from the state `edit` makes of the one `reset` left; its observation.

        An optional capability (pose perturbations, `bench.sims.perturb.pose`): called right after `reset`,
        it applies `edit` (which writes the MuJoCo state: joint positions, object poses), recomputes what the
        simulator derives from the state, brings the env's own state in line with it (controller goals,
        mocap targets, what observations are relative to, the state `init_state` reports) and returns the
        observation of the edited state, as `reset` would have. Raises NotImplementedError where the
        adapter cannot (the default)."""
        raise NotImplementedError(f"{type(self).__name__} cannot start an episode from an edited state")

    def hold_action(self) -> NumArray | None:
        """The action that holds the env where it is now (absolute position goals: the goals the servos hold after
        `reset` / `edit_start`), or None where the zero action does (delta or torque actions: the default).
        `perturb.latency` fills its first frames with it, as a delayed servo keeps its last goal."""
        return None

    def close(self) -> None:
        """Nothing to release."""
        return None  # a hook


class CachedStateAdapter(AdapterBase):
    """An adapter that works out success in `step` and its initial state in `reset`, and keeps them for
    `success()` and `init_state()`: `reset` sets `_init_state` (and `_success` back to False), `step`
    sets `_success`."""

    _success: bool = False
    _init_state: NumArray = np.zeros(0)

    def success(self) -> bool:
        return self._success

    def init_state(self) -> NumArray:
        return self._init_state


class AdapterWrapper(AdapterBase):
    """An adapter around another: the contract forwarded to `inner`, attributes copied once at
    construction (no `__getattr__` forwarding), methods calling through. Override what changes."""

    def __init__(self, inner: EnvAdapter) -> None:
        self.inner = inner
        for name in ATTRIBUTES:
            setattr(self, name, getattr(inner, name))

    def reset(self, seed: int) -> Obs:
        return self.inner.reset(seed)

    def step(self, action: NumArray) -> tuple[Obs, float, bool, bool, dict[str, object]]:
        return self.inner.step(action)

    def success(self) -> bool:
        return bool(self.inner.success())

    def init_state(self) -> NumArray:
        return self.inner.init_state()

    def edit_start(self, edit: Callable[[], None]) -> Obs:
        if not isinstance(self.inner, AdapterBase):  # an adapter of the bare protocol: no such capability
            raise NotImplementedError(f"{type(self.inner).__name__} cannot start an episode from an edited state")
        return self.inner.edit_start(edit)

    def hold_action(self) -> NumArray | None:
        return self.inner.hold_action() if isinstance(self.inner, AdapterBase) else None

    def close(self) -> None:
        self.inner.close()


def unwrap(env: EnvAdapter) -> EnvAdapter:
    """The innermost adapter under any number of wrappers (an expert needs the concrete env)."""
    while isinstance(env, AdapterWrapper):
        env = env.inner
    return env


def obs_slices(obs_names: list[tuple[str, int]]) -> dict[str, slice]:
    """Map each observation field name to its slice of the flat vector."""
    out, start = {}, 0
    for name, width in obs_names:
        out[name] = slice(start, start + width)
        start += width
    return out


def state_hash(state: npt.ArrayLike, decimals: int = 6) -> str:
    """A short, platform-stable hash of a state vector, rounded so float noise does not matter."""
    arr = np.round(np.asarray(state, dtype=np.float64), decimals) + 0.0  # +0.0 folds -0.0 into 0.0
    return hashlib.sha256(arr.tobytes()).hexdigest()[:16]


# the input parts of an mjtState mask a logged `action.ctrl` may hold, in mj_getState order
_INPUT_PARTS = (("CTRL", None), ("MOCAP_POS", "xyz"), ("MOCAP_QUAT", "wxyz"))


def mj_input_names(model: mujoco.MjModel, spec: int) -> list[str]:
    """Element names of `mj_getState(model, data, out, spec)` for an input-only mask.

    CTRL -> actuator names; MOCAP_POS -> `<body>.mocap_x|y|z`; MOCAP_QUAT -> `<body>.mocap_qw|qx|qy|qz`.
    """
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    names: list[str] = []
    left = int(spec)
    for part, axes in _INPUT_PARTS:
        bit = int(getattr(mujoco.mjtState, f"mjSTATE_{part}"))
        if not left & bit:
            continue
        left &= ~bit
        if axes is None:
            names += [model.actuator(a).name or f"actuator{a}" for a in range(model.nu)]
            continue
        mocap_bodies = [b for b in range(model.nbody) if model.body_mocapid[b] >= 0]
        mocap_bodies.sort(key=lambda b: int(model.body_mocapid[b]))
        prefix = "q" if part == "MOCAP_QUAT" else ""
        for b in mocap_bodies:
            body = model.body(b).name or f"body{b}"
            names += [f"{body}.mocap_{prefix}{a}" for a in axes]
    if left:
        raise ValueError(f"mjtState mask {spec} holds parts other than CTRL, MOCAP_POS, MOCAP_QUAT")
    return names

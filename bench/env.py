"""The simulator-adapter contract every suite's environment follows.

A suite builds one `Env` per (task cell, worker) and reuses it across episodes.
Observations and actions are flat float32 vectors whose layout is named by
`obs_names` / `action_names`, so a policy (or a dataset recorded from it) can
find its fields by name on every robot and backend.
"""
from __future__ import annotations

import hashlib
from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Env(Protocol):
    """What the rollout needs from a simulator adapter.

    Attributes:
        backend: simulator name and version, e.g. "robosuite-1.5.2/mujoco-3.3.0".
        obs_names: (field name, width) pairs in order; their widths sum to the obs size.
        action_names: one name per action dimension.
        action_low, action_high: bounds of the action vector.
        horizon: number of control steps in one episode.
        model, data: the `mujoco.MjModel` / `MjData` for MuJoCo backends, else None.

    Optional, for MuJoCo backends whose controller runs in Python (robosuite's OSC, Meta-World's
    mocap action): `ctrl_spec`, an `mjtState` mask of the inputs the env drives (CTRL, plus
    MOCAP_POS | MOCAP_QUAT for Meta-World); `log_ctrl(on: bool)` starts/stops logging those inputs
    at every physics step; `take_ctrl()` returns the (substeps, size) inputs applied during the last
    `step`, each row as `mj_getState(model, data, row, ctrl_spec)` gives it. `record=` stores them
    as `action.ctrl`, and `bench replay` re-applies them batched in `mujoco.rollout`.
    """

    backend: str
    obs_names: list[tuple[str, int]]
    action_names: list[str]
    action_low: np.ndarray
    action_high: np.ndarray
    horizon: int
    model: Any
    data: Any

    def reset(self, seed: int) -> np.ndarray:
        """Reset to the initial state determined by `seed` alone; return the observation."""

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, dict]:
        """Apply one control step; `info["success"]` is the task's success predicate now."""

    def init_state(self) -> np.ndarray:
        """The simulator state right after reset (for initial-state hashing)."""

    def close(self) -> None:
        """Release the simulator."""


def obs_slices(obs_names: list[tuple[str, int]]) -> dict[str, slice]:
    """Map each observation field name to its slice of the flat vector."""
    out, start = {}, 0
    for name, width in obs_names:
        out[name] = slice(start, start + width)
        start += width
    return out


def state_hash(state: np.ndarray, decimals: int = 6) -> str:
    """A short, platform-stable hash of a state vector, rounded so float noise does not matter."""
    arr = np.round(np.asarray(state, dtype=np.float64), decimals) + 0.0  # +0.0 folds -0.0 into 0.0
    return hashlib.sha256(arr.tobytes()).hexdigest()[:16]


class InputLogging:
    """`log_ctrl` / `take_ctrl` of the Env contract for MuJoCo adapters.

    The adapter sets `ctrl_spec` and `_ctrl_size` (mj_stateSize of that mask), starts with
    `_ctrl_log = None`, and appends one row per physics step to `_ctrl_log` while it is a list.
    """

    ctrl_spec: int
    _ctrl_size: int
    _ctrl_log: list | None = None

    def log_ctrl(self, on: bool) -> None:
        """Start (empty) or stop logging the inputs (ctrl_spec) of every physics step."""
        self._ctrl_log = [] if on else None

    def take_ctrl(self) -> np.ndarray:
        """(substeps, size) inputs applied since the last call, rows as mj_getState(ctrl_spec); empties the log."""
        if self._ctrl_log is None:
            raise RuntimeError("take_ctrl: call log_ctrl(True) first")
        out = np.array(self._ctrl_log, dtype=np.float64).reshape(-1, self._ctrl_size)
        self._ctrl_log.clear()
        return out


# the input parts of an mjtState mask a logged `action.ctrl` may hold, in mj_getState order
_INPUT_PARTS = (("CTRL", None), ("MOCAP_POS", "xyz"), ("MOCAP_QUAT", "wxyz"))


def mj_input_names(model, spec: int) -> list[str]:
    """Element names of `mj_getState(model, data, out, spec)` for an input-only mask.

    CTRL -> actuator names; MOCAP_POS -> `<body>.mocap_x|y|z`; MOCAP_QUAT -> `<body>.mocap_qw|qx|qy|qz`.
    """
    import mujoco

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

"""Helpers for env adapters (the contract itself is `bench.protocols.EnvAdapter`).

`obs_slices` finds a named field in a state vector, `state_hash` fingerprints initial
states, `mj_input_names` names the MuJoCo inputs an `InputLog` records.
"""

from __future__ import annotations

import hashlib

import numpy as np


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


# the input parts of an mjtState mask a logged `action.ctrl` may hold, in mj_getState order
_INPUT_PARTS = (("CTRL", None), ("MOCAP_POS", "xyz"), ("MOCAP_QUAT", "wxyz"))


def mj_input_names(model, spec: int) -> list[str]:
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

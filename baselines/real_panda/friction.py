"""Gaz et al.'s identified friction law beside the calibration's, on a velocity grid and the held-out velocities."""

from __future__ import annotations

from typing import Any

import numpy as np

# Gaz et al. (2019), friction parameters of the identified model, per joint: FI_1 (A), FI_2 (a), FI_3 (s)
# as published with the paper's code (marcocognetti/FrankaEmikaPandaDynModel, get_FrictionTorque.m)
GAZ = {
    "A": [0.54615, 0.87224, 0.64068, 1.2794, 0.83904, 0.30301, 0.56489],
    "a": [5.1181, 9.0657, 10.136, 5.5903, 8.3469, 17.133, 10.336],
    "s": [0.039533, 0.025882, -0.04607, 0.036194, 0.026226, -0.021047, 0.0035526],
}


def gaz_friction(dq: np.ndarray) -> np.ndarray:
    """Gaz et al.'s friction torque (N·m) at joint velocities dq (N, 7)."""
    a, b, s = (np.asarray(GAZ[k]) for k in ("A", "a", "s"))
    return a / (1 + np.exp(-b * (dq + s))) - a / (1 + np.exp(-b * s))


def ours(params: list[dict], joints: list[str], dq: np.ndarray) -> np.ndarray:
    """The calibration's friction torque (Coulomb tanh(dq / 0.02), viscous, offset) at dq (N, 7)."""
    val = {p["name"]: p["value"] for p in params}
    out = np.zeros_like(dq)
    for j, jn in enumerate(joints):
        fc, fv, off = (val.get(f"{jn}.{k}", 0.0) for k in ("coulomb", "viscous", "offset"))
        out[:, j] = fc * np.tanh(dq[:, j] / 0.02) + fv * dq[:, j] + off
    return out


def friction_table(cal: dict, dq_hold: np.ndarray) -> dict[str, Any]:
    joints = cal["model"]["joints"]
    grid = np.array([-1.0, -0.5, -0.1, -0.02, 0.02, 0.1, 0.5, 1.0])
    g = np.repeat(grid[:, None], 7, axis=1)
    mine, theirs = ours(cal["parameters"], joints, g), gaz_friction(g)
    h_mine, h_theirs = ours(cal["parameters"], joints, dq_hold), gaz_friction(dq_hold)
    return {
        "velocities": grid.tolist(),
        "ours": mine.T.tolist(),
        "gaz": theirs.T.tolist(),
        "heldout_rms": {
            "ours": np.sqrt((h_mine**2).mean(0)).tolist(),
            "gaz": np.sqrt((h_theirs**2).mean(0)).tolist(),
            "difference": np.sqrt(((h_mine - h_theirs) ** 2).mean(0)).tolist(),
        },
        "note": "ours includes the constant offset the fit found (a torque-sensor offset); Gaz et al.'s model "
        "is zero at rest by construction",
    }

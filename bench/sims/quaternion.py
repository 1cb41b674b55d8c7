"""Quaternion arithmetic for suites and their experts (through `bench.api.sims`), numpy only.

Simulators disagree on the order: MuJoCo, SAPIEN and gym-aloha write (w, x, y, z), robosuite (x, y, z, w);
`w_first` says which a call's quaternions are in (the result is in the same).
"""

from __future__ import annotations

import numpy as np


def quat_mul(a: np.ndarray, b: np.ndarray, w_first: bool = True) -> np.ndarray:
    """The Hamilton product a * b."""
    if w_first:
        aw, ax, ay, az = a
        bw, bx, by, bz = b
    else:
        ax, ay, az, aw = a
        bx, by, bz, bw = b
    w = aw * bw - ax * bx - ay * by - az * bz
    x = aw * bx + ax * bw + ay * bz - az * by
    y = aw * by - ax * bz + ay * bw + az * bx
    z = aw * bz + ax * by - ay * bx + az * bw
    return np.array([w, x, y, z] if w_first else [x, y, z, w])


def quat_conj(q: np.ndarray, w_first: bool = True) -> np.ndarray:
    """The conjugate (the inverse rotation of a unit quaternion)."""
    return np.array([q[0], -q[1], -q[2], -q[3]] if w_first else [-q[0], -q[1], -q[2], q[3]])

"""Primitive transforms of the drive command and the friction force, shared by the calibration rollouts and
the data generator: a dead band, a saturation and the Stribeck excess."""

from __future__ import annotations

import numpy as np


def deadband(u: np.ndarray, width: np.ndarray | float) -> np.ndarray:
    """Command with a dead band of half-width `width` around zero (lost motion of a drive with play)."""
    return np.sign(u) * np.maximum(np.abs(u) - width, 0.0)


def saturate(u: np.ndarray, limit: np.ndarray | float) -> np.ndarray:
    """Command clipped to +-limit (torque saturation of the drive)."""
    return np.clip(u, -limit, limit)


def stribeck_force(v: np.ndarray, fs: np.ndarray | float, vs: np.ndarray | float) -> np.ndarray:
    """Generalised force that turns a friction loss of fc + fs into the Stribeck curve.

    MuJoCo's friction loss supplies the static level fc + fs (and true sticking); this force gives
    back fs * (1 - exp(-(v/vs)^2)) once sliding, so the kinetic friction falls to fc. It is
    continuous at v = 0, which keeps finite differences and the integrator well behaved.
    """
    return fs * (1.0 - np.exp(-np.square(v / vs))) * np.sign(v)

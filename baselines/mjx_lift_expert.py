"""A scripted pick-and-lift expert over a batch of observations (numpy), for the MJX Lift suite.

Stateless, so one call answers any number of worlds (`bench.protocols.BatchPolicy`: `vector=N` asks it once per
step for all of them) and a world's answer depends on its observation only (records equal `vector=1`'s). The phase
is read from the observation of `suites/lift.py` (OBS_FIELDS): holding (the fingers closed on the cube, the cube
between them) -> lift; centred above the cube -> descend, at its height -> close; otherwise hover above it with the
hand open. Position action = clip(gain * error, -limit, limit); rotation deltas 0; gripper +1 closes.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from bench.protocols import STATE, Obs
from bench.protocols.env import obs_slices

HOVER = 0.08  # m above the cube before descending
LIFT_Z = 0.25  # m above the cube's resting height to lift it to
GAIN = 10.0  # action per metre of error
LIFT_SPEED = 0.4  # action limit while lifting (a gentle lift keeps the grip)
CENTRED = 0.015  # m: the hand is above the cube (xy)
AT_HEIGHT = 0.01  # m: the hand is at the cube's height (z)
HOLDING = (0.05, 0.6)  # gripper opening between these, cube within NEAR: it is held (0 = closed on nothing)
NEAR = 0.03  # m
REST_Z = 0.82  # the cube's resting centre height in the MJX Lift scene (table 0.8 m + 2 cm)


class BatchLiftExpert:
    """The expert (module docstring); `act` for one observation, `act_batch` for many."""

    batch_key = "mjx_lift_expert"

    def __init__(self, obs_names: Sequence[tuple[str, int]], action_dim: int = 7) -> None:
        self._s = obs_slices(list(obs_names))
        self.action_dim = action_dim

    def reset(self, seed: int | None = None) -> None:
        return None  # stateless

    def act(self, observation: Obs) -> np.ndarray:
        return self.act_batch([observation])[0]

    def act_batch(self, observations: list[Obs]) -> np.ndarray:
        s = self._s
        x = np.stack([np.asarray(o[STATE], np.float64) for o in observations])
        eef, obj, opening = x[:, s["eef_pos"]], x[:, s["object_pos"]], x[:, s["gripper_opening"]][:, 0]
        err = obj - eef
        xy = np.linalg.norm(err[:, :2], axis=1)
        holding = (opening > HOLDING[0]) & (opening < HOLDING[1]) & (np.linalg.norm(err, axis=1) < NEAR)
        centred = xy < CENTRED
        at_height = np.abs(err[:, 2]) < AT_HEIGHT
        target = obj + [0.0, 0.0, HOVER]  # hover
        target = np.where((centred & ~holding)[:, None], obj, target)  # descend / close
        lift = np.column_stack([obj[:, :2], np.full(len(x), REST_Z + LIFT_Z)])
        target = np.where(holding[:, None], lift, target)
        grip = np.where(holding | (centred & at_height), 1.0, -1.0)
        limit = np.where(holding, LIFT_SPEED, 1.0)[:, None]
        out = np.zeros((len(x), self.action_dim), np.float32)
        out[:, :3] = np.clip(GAIN * (target - eef), -limit, limit)
        out[:, -1] = grip
        return out

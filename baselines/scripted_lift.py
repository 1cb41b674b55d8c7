"""Scripted pick-and-lift expert that reads only the embodiment-agnostic observation.

Phases: hover above the object -> descend to it -> close while still commanding
the grasp position (zero deltas let the hand drift) until the fingers stop ->
lift. Position action = clip(gain * error, -1, 1); rotation deltas 0; gripper
+1 closes, -1 opens. If the object falls out of the hand while lifting, it starts
over. Works unchanged on all 7 robosuite single arms because it uses nothing
robot-specific (see `suites/lift.py`, OBS_FIELDS).
"""

from __future__ import annotations

import numpy as np

from bench.protocols import STATE, Obs
from bench.protocols.env import obs_slices


class LiftExpert:
    """Stateful per episode; `reset()` before each one."""

    hover = 0.08  # m above the object before descending
    lift_to = 0.25  # m above the grasp height
    lift_speed = 0.4  # action limit while lifting (1.0 = the controller's full step)
    gain = 10.0  # action per metre of error (saturates at 10 cm)

    def __init__(self, obs_names: list[tuple[str, int]], action_dim: int = 7):
        self._s = obs_slices(obs_names)
        self.action_dim = action_dim
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        self.phase, self.steps_in_phase = "hover", 0
        self._openings: list[float] = []
        self._grasp_pos = None

    def _go(self, phase: str) -> None:
        self.phase, self.steps_in_phase = phase, 0

    def act(self, observation: Obs) -> np.ndarray:
        s, obs = self._s, observation[STATE]
        eef, obj = obs[s["eef_pos"]].astype(np.float64), obs[s["object_pos"]].astype(np.float64)
        opening = float(obs[s["gripper_opening"]][0])
        grip = -1.0
        self.steps_in_phase += 1
        if self.phase == "hover":
            target = obj + [0.0, 0.0, self.hover]
            err = target - eef
            if np.linalg.norm(err[:2]) < 0.01 and abs(err[2]) < 0.02:
                self._go("descend")
        if self.phase == "descend":
            target = obj.copy()
            err = target - eef
            if np.linalg.norm(err[:2]) > 0.03:  # object moved away: hover again
                self._go("hover")
                target = obj + [0.0, 0.0, self.hover]
            elif abs(err[2]) < 0.01 and (np.linalg.norm(err[:2]) < 0.004 or self.steps_in_phase > 40):
                self._go("close")  # centred, or as centred as this arm's controller gets
                self._openings = []
        if self.phase == "close":
            target, grip = obj.copy(), 1.0
            self._openings.append(opening)
            recent = self._openings[-6:]
            # at least 12 steps: hands lag when the command reverses (Jaco), which looks like "stopped"
            if len(self._openings) >= 12 and max(recent) - min(recent) < 0.01:
                self._grasp_pos = eef.copy()
                self._go("lift")
        if self.phase == "lift":
            grip = 1.0
            target = self._grasp_pos + [0.0, 0.0, self.lift_to]  # fixed: the held object lags the hand
            if np.linalg.norm(obj - eef) > 0.06:  # dropped it: start over
                self._go("hover")
                grip, target = -1.0, obj + [0.0, 0.0, self.hover]
        action = np.zeros(self.action_dim, dtype=np.float32)
        limit = self.lift_speed if self.phase == "lift" else 1.0  # a gentle lift keeps the grip
        action[:3] = np.clip(self.gain * (target - eef), -limit, limit)
        action[-1] = grip
        return action

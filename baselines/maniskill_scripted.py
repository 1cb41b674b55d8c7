"""Scripted experts for maniskill_held_out_robots, reading only the embodiment-agnostic observation.

Both act through the agnostic action (world-frame TCP displacement, 1.0 = 0.1 m; gripper +1
closes), so one expert runs unchanged on every robot (see `suites.maniskill_agnostic`).

- `PickPlaceExpert` (PickCube): hover above the cube, descend, close while holding the grasp
  position until the fingers stop, carry the cube to the goal and hold it there still (ManiSkill's
  success also asks the robot to be static). Starts over if the cube is dropped.
- `PushExpert` (PushCube, PullCube): go to the cube's far side from the goal with the gripper
  closed (above it first, then down), then push it along the cube-goal line until it is inside the
  goal region; pulling is the same motion seen from the other side.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from bench.protocols import STATE
from bench.protocols.env import obs_slices


class _Expert:
    gain = 10.0  # action per metre of error: saturates at 10 cm

    def __init__(self, obs_names: Sequence[tuple[str, int]]) -> None:
        self._s = obs_slices(list(obs_names))
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        self.phase, self.steps_in_phase = "start", 0
        self._heights: list[float] = []

    def _go(self, phase: str) -> None:
        self.phase, self.steps_in_phase = phase, 0
        self._heights = []

    def _stalled(self, eef: np.ndarray) -> bool:
        """The hand stopped going down (fingers on the table: it cannot reach the commanded height)."""
        self._heights.append(float(eef[2]))
        return len(self._heights) >= 4 and self._heights[-4] - self._heights[-1] < 0.002

    def _read(self, obs: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        s = np.asarray(obs[STATE], dtype=np.float64)
        at = self._s
        return s[at["eef_pos"]], s[at["object_pos"]], s[at["goal_pos"]], float(s[at["gripper_opening"]][0])

    def _action(self, target: np.ndarray, eef: np.ndarray, grip: float, limit: float = 1.0) -> np.ndarray:
        out = np.zeros(4, dtype=np.float32)
        out[:3] = np.clip(self.gain * (target - eef), -limit, limit)
        out[3] = grip
        return out


class PickPlaceExpert(_Expert):
    """PickCube: grasp from above, carry to the goal, hold still."""

    hover = 0.06

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self._openings: list[float] = []
        self._offset = np.zeros(3)
        self._grasp = np.zeros(3)

    def act(self, obs: dict[str, Any]) -> np.ndarray:
        eef, obj, goal, opening = self._read(obs)
        self.steps_in_phase += 1
        if self.phase == "start":
            self._go("hover")
        if self.phase == "hover":
            target, grip = obj + [0.0, 0.0, self.hover], -1.0
            if np.linalg.norm((target - eef)[:2]) < 0.005 and abs(target[2] - eef[2]) < 0.01:
                self._go("descend")
        if self.phase == "descend":
            target, grip = obj.copy(), -1.0
            if np.linalg.norm((obj - eef)[:2]) > 0.02:
                self._go("hover")
                target = obj + [0.0, 0.0, self.hover]
            elif abs(obj[2] - eef[2]) < 0.005 or self._stalled(eef):
                self._go("close")
                self._openings, self._grasp = [], eef.copy()
        if self.phase == "close":  # hold the hand where the grasp started: chasing the cube pushes it away
            target, grip = self._grasp, 1.0
            self._openings.append(opening)
            recent = self._openings[-4:]
            if len(self._openings) >= 6 and max(recent) - min(recent) < 0.005:
                self._offset = eef - obj  # where the hand holds the cube
                self._go("carry")
        if self.phase == "carry":
            grip = 1.0
            target = goal + self._offset
            if np.linalg.norm(obj - eef - (-self._offset)) > 0.03:  # dropped it: start over
                self._go("hover")
                target, grip = obj + [0.0, 0.0, self.hover], -1.0
        limit = 0.5 if self.phase == "carry" else 1.0  # a gentle carry keeps the grip and settles still
        return self._action(target, eef, grip, limit)


class PushExpert(_Expert):
    """PushCube / PullCube: push the cube from its far side along the line to the goal."""

    standoff = 0.05  # TCP distance behind the cube's centre while pushing
    clear = 0.06  # height above the cube's centre while moving behind it
    done_within = 0.03

    def act(self, obs: dict[str, Any]) -> np.ndarray:
        eef, obj, goal, _ = self._read(obs)
        self.steps_in_phase += 1
        line = goal[:2] - obj[:2]
        dist = float(np.linalg.norm(line))
        u = line / dist if dist > 1e-6 else np.zeros(2)
        behind = np.append(obj[:2] - u * self.standoff, obj[2])
        if self.phase == "start":
            self._go("above")
        if self.phase == "above":
            target = behind + [0.0, 0.0, self.clear]
            if np.linalg.norm(target - eef) < 0.01:
                self._go("down")
        if self.phase == "down":
            target = behind
            if abs(eef[2] - behind[2]) < 0.01 or self._stalled(eef):
                self._go("push")
        if self.phase == "push":
            # aim the TCP at the point that puts the cube's centre on the goal, and stop there
            target = np.append(goal[:2] - u * self.standoff, eef[2]) if dist > self.done_within else eef.copy()
            off_line = np.linalg.norm((eef[:2] - obj[:2]) - np.dot(eef[:2] - obj[:2], -u) * -u) if dist > 1e-6 else 0
            if off_line > 0.02 or float(np.dot(eef[:2] - obj[:2], u)) > 0:  # lost the cube: go round again
                self._go("above")
                target = behind + [0.0, 0.0, self.clear]
        return self._action(target, eef, 1.0, 0.5 if self.phase == "push" else 1.0)


def make_expert(task: str, obs_names: Sequence[tuple[str, int]]) -> PickPlaceExpert | PushExpert:
    """The scripted expert of a maniskill_held_out_robots task, reading a state laid out as `obs_names`."""
    if task == "PickCube":
        return PickPlaceExpert(obs_names)
    if task in ("PushCube", "PullCube"):
        return PushExpert(obs_names)
    raise ValueError(f"no scripted expert for task {task!r}; experts: PickCube, PushCube, PullCube")

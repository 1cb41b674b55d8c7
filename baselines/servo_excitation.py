"""Goals that excite every servo of an arm for its calibration (`bench calibrate`, `method: servo_arm`).

A task's scripted policy moves each joint once, slowly: too little to identify a servo. This policy moves from the
start to an arm's excitation pose in one second, then sends, per joint, a sum of two sines (0.3 to 1.5 Hz) plus steps
held 8 to 20 control steps, scaled by the joint's amplitude: large errors (saturation, stiffness), reversals (Coulomb
friction) and accelerations (armature). Each arm's pose keeps its gripper clear of the floor and the scene's objects
(baselines/so101_scripted.py, baselines/koch_scripted.py). Every draw comes from the episode's seed (`reset`).
"""

from __future__ import annotations

import numpy as np

HOLD = (8, 20)  # control steps each step goal is held (drawn between these)


class ServoExcitation:
    """The excitation about `pose` (rad, one per action) with `amplitude` per joint, at `fps` control steps/s."""

    def __init__(self, pose: np.ndarray, amplitude: np.ndarray, fps: float = 30.0):
        self.pose, self.amplitude = np.asarray(pose, np.float64), np.asarray(amplitude, np.float64)
        self.fps = fps
        self._goals: np.ndarray | None = None
        self._rng = np.random.default_rng(0)
        self._t = 0

    def reset(self, seed: int) -> None:
        self._rng = np.random.default_rng(int(seed))
        self._goals, self._t = None, 0

    def plan(self, start: np.ndarray, steps: int = 400) -> np.ndarray:
        rng, n = self._rng, len(self.pose)
        t = np.arange(steps) / self.fps
        freq = rng.uniform(0.3, 1.5, (2, n))
        phase = rng.uniform(0, 2 * np.pi, (2, n))
        sines = sum(np.sin(2 * np.pi * freq[i] * t[:, None] + phase[i]) for i in range(2)) / 2
        held = np.zeros((steps, n))
        k = 0
        while k < steps:
            length = int(rng.integers(*HOLD))
            held[k : k + length] = rng.uniform(-1, 1, n)
            k += length
        goals = self.pose + self.amplitude * (0.5 * sines + 0.5 * held)
        ramp = np.clip(t / 1.0, 0, 1)[:, None]  # one second from the start pose into the excitation
        return (1 - ramp) * start[None, :n] + ramp * goals

    def act(self, obs: dict) -> np.ndarray:
        if self._goals is None:
            if "state" not in obs:
                raise ValueError("the servo excitation reads the start pose from obs['state'] (obs=state or state+rgb)")
            self._goals = self.plan(np.asarray(obs["state"], np.float64)[: len(self.pose)])
        step = self._goals[min(self._t, len(self._goals) - 1)]
        self._t += 1
        return step.astype(np.float32)

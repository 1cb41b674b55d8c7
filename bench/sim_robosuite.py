"""robosuite adapter: one arm, one task, an embodiment-agnostic observation.

The observation is the same 18 numbers on every arm (see `OBS_NAMES`):
end-effector position (world), end-effector orientation relative to its own
orientation at reset (robosuite's eef frames differ per arm, so only relative
orientation compares), gripper opening normalised to 1 = fully open, 0 = fully closed in free
air (both measured once when the env is built), object pose, and the
gripper-to-object vector. The action is what robosuite's default controller takes
on all 7 single arms: 6 OSC end-effector deltas (position in the world frame,
rotation) and a gripper command (+1 closes, -1 opens).

Envs are built once and soft-reset (`hard_reset=False`, ~2 ms instead of ~1 s);
reseeding sets both `env.rng` and the placement sampler's generator, which is
what fixes the object's initial pose (robosuite's own `seed` only works at make).
"""
from __future__ import annotations

import logging
import os
import sys
import types
from typing import Any

import numpy as np

OBS_NAMES: list[tuple[str, int]] = [
    ("eef_pos", 3),
    ("eef_quat_rel", 4),
    ("gripper_opening", 1),
    ("object_pos", 3),
    ("object_quat", 4),
    ("gripper_to_object", 3),
]
ACTION_NAMES = ["dx", "dy", "dz", "droll", "dpitch", "dyaw", "gripper"]
ARMS = ("Panda", "Sawyer", "IIWA", "UR5e", "Kinova3", "Jaco", "XArm7")
_OBJECT = {"Lift": "cube", "Stack": "cubeA"}


def _quiet_robosuite() -> None:
    """Keep robosuite's import-time INFO/WARNING chatter out of the user's terminal.

    robosuite reads overrides from `robosuite.macros_private` (its documented private
    macro file); providing that module in-process before the first import sets its
    console log level to ERROR without writing into site-packages.
    """
    os.environ.setdefault("MUJOCO_GL", "disable")
    if "robosuite" not in sys.modules and "robosuite.macros_private" not in sys.modules:
        private = types.ModuleType("robosuite.macros_private")
        private.CONSOLE_LOGGING_LEVEL = "ERROR"
        sys.modules["robosuite.macros_private"] = private
    logging.getLogger("robosuite_logs").setLevel(logging.ERROR)


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (x, y, z, w) quaternions (robosuite's convention)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ])


def _quat_conj(q: np.ndarray) -> np.ndarray:
    return np.array([-q[0], -q[1], -q[2], q[3]])


class RobosuiteEnv:
    """A robosuite manipulation env behind the `bench.env.Env` contract."""

    def __init__(self, task: str, robot: str, horizon: int, env_kwargs: dict[str, Any] | None = None):
        _quiet_robosuite()
        import mujoco
        import robosuite

        if task not in _OBJECT:
            raise ValueError(f"task {task!r} not supported; valid: {sorted(_OBJECT)}")
        self.task, self.robot, self.horizon = task, robot, int(horizon)
        self._object = _OBJECT[task]
        self._env = robosuite.make(
            task,
            robots=robot,
            has_renderer=False,
            has_offscreen_renderer=False,
            use_camera_obs=False,
            hard_reset=False,
            ignore_done=True,
            reward_shaping=True,
            horizon=self.horizon,
            seed=0,
            **(env_kwargs or {}),
        )
        self.model = self._env.sim.model._model
        self.data = self._env.sim.data._data
        self.backend = f"robosuite-{robosuite.__version__}/mujoco-{mujoco.__version__}"
        self.obs_names = list(OBS_NAMES)
        self.action_names = list(ACTION_NAMES)
        low, high = self._env.action_spec
        self.action_low, self.action_high = np.asarray(low, np.float32), np.asarray(high, np.float32)
        if len(self.action_low) != len(ACTION_NAMES):
            raise ValueError(f"{robot}: action size {len(self.action_low)}, expected {len(ACTION_NAMES)}")
        self._grip_idx = np.asarray(self._env.robots[0]._ref_gripper_joint_pos_indexes["right"])
        self._grip_open = self._grip_closed = None
        self._calibrate_gripper()

    # -- gripper normalisation -------------------------------------------------------------
    def _calibrate_gripper(self) -> None:
        """Measure the finger joints fully open and fully closed in free air, once per build.

        Reset poses are not fully open on every hand (Jaco starts half-closed), so both
        ends are driven to; Jaco's three fingers need ~105 steps each way.
        """
        self._raw_reset(0)
        command = np.zeros(len(ACTION_NAMES))
        ends = []
        for grip in (-1.0, 1.0):
            command[-1] = grip
            for _ in range(130):
                self._env.step(command)
            ends.append(self.data.qpos[self._grip_idx].copy())
        self._grip_open, self._grip_closed = ends
        self._grip_mask = np.abs(self._grip_open - self._grip_closed) > 1e-3  # joints that move

    def _opening(self) -> float:
        q = self.data.qpos[self._grip_idx][self._grip_mask]
        o, c = self._grip_open[self._grip_mask], self._grip_closed[self._grip_mask]
        return float(np.clip(np.mean((q - c) / (o - c)), 0.0, 1.0))

    # -- contract ----------------------------------------------------------------------------
    def _raw_reset(self, seed: int) -> dict:
        env = self._env
        env.rng = np.random.default_rng(seed)
        if getattr(env, "placement_initializer", None) is not None:
            env.placement_initializer.rng = env.rng
            for sampler in getattr(env.placement_initializer, "samplers", {}).values():
                sampler.rng = env.rng
        return env.reset()

    def reset(self, seed: int) -> np.ndarray:
        raw = self._raw_reset(int(seed))
        self._quat0 = np.asarray(raw["robot0_eef_quat"], dtype=np.float64)
        self._init_state = np.concatenate([self.data.qpos, self.data.qvel]).copy()
        return self._obs(raw)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, dict]:
        raw, reward, done, info = self._env.step(np.asarray(action, dtype=np.float64))
        info = dict(info)
        info["success"] = bool(self._env._check_success())
        return self._obs(raw), float(reward), bool(done), info

    def init_state(self) -> np.ndarray:
        return self._init_state

    def sim_forward(self) -> None:
        """Recompute derived quantities after the model was edited (perturbations)."""
        self._env.sim.forward()

    def close(self) -> None:
        self._env.close()

    def _obs(self, raw: dict) -> np.ndarray:
        obj = self._object
        quat_rel = _quat_mul(_quat_conj(self._quat0), np.asarray(raw["robot0_eef_quat"], dtype=np.float64))
        if quat_rel[3] < 0:  # one hemisphere, so the same rotation reads the same
            quat_rel = -quat_rel
        parts = [
            raw["robot0_eef_pos"],
            quat_rel,
            [self._opening()],
            raw[f"{obj}_pos"],
            raw[f"{obj}_quat"],
            np.asarray(raw[f"{obj}_pos"]) - np.asarray(raw["robot0_eef_pos"]),
        ]
        return np.concatenate([np.asarray(p, dtype=np.float32).ravel() for p in parts])

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

from bench.env import InputLogging

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
# Scene keys `env_kwargs` may carry besides robosuite's own (table_full_size, table_friction):
#   table_offset (x, y, z): table-top centre in metres (robosuite hard-codes (0, 0, 0.8));
#   placement_x_range / placement_y_range (lo, hi): object spawn region, metres relative to
#     the table-top centre (robosuite's default sampler uses (-0.03, 0.03) on both);
#   table_contact_priority (int): MuJoCo contact priority of the table's collision geom; with 1
#     the table's own friction governs object-table contacts instead of max(table, object).
SCENE_KEYS = ("table_offset", "placement_x_range", "placement_y_range", "table_contact_priority")


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


def _scene_env_name(task: str) -> str:
    """Register (once per process) a subclass of robosuite `task` that also takes `SCENE_KEYS`.

    robosuite's table tasks fix the table height in `__init__` and build their placement
    sampler in `_load_model`; the subclass sets both just around that call, so a hard
    reset rebuilds the same scene. Registered by robosuite's own metaclass as "<task>Scene".
    """
    from robosuite.environments.base import REGISTERED_ENVS

    name = f"{task}Scene"
    if name in REGISTERED_ENVS:
        return name
    base = REGISTERED_ENVS[task]

    def __init__(self, *args, table_offset=None, placement_x_range=None, placement_y_range=None,
                 table_contact_priority=None, **kwargs):
        self._scene = dict(table_offset=table_offset, x_range=placement_x_range, y_range=placement_y_range,
                           priority=table_contact_priority)
        base.__init__(self, *args, **kwargs)

    def _load_model(self):
        scene = self._scene
        if scene["table_offset"] is not None:
            self.table_offset = np.array(scene["table_offset"], dtype=np.float64)
        base._load_model(self)
        if scene["priority"] is not None:
            self.model.mujoco_arena.table_collision.set("priority", str(int(scene["priority"])))
        for key in ("x_range", "y_range"):
            if scene[key] is not None:
                setattr(self.placement_initializer, key, [float(v) for v in scene[key]])

    type(base)(name, (base,), {"__init__": __init__, "_load_model": _load_model})
    return name


class RobosuiteEnv(InputLogging):
    """A robosuite manipulation env behind the `bench.env.Env` contract."""

    def __init__(self, task: str, robot: str, horizon: int, env_kwargs: dict[str, Any] | None = None):
        _quiet_robosuite()
        import mujoco
        import robosuite

        if task not in _OBJECT:
            raise ValueError(f"task {task!r} not supported; valid: {sorted(_OBJECT)}")
        self.task, self.robot, self.horizon = task, robot, int(horizon)
        self._object = _OBJECT[task]
        env_kwargs = dict(env_kwargs or {})
        scene = {k: env_kwargs.pop(k) for k in SCENE_KEYS if k in env_kwargs}
        # the scene is part of the initial state: two scenes with the same joint state are not the same start
        described = {**{k: v for k, v in env_kwargs.items() if k in ("table_full_size", "table_friction")}, **scene}
        self._scene_vec = np.concatenate([np.ravel(np.asarray(described[k], dtype=np.float64)) for k in sorted(described)]
                                         ) if described else np.zeros(0)
        self._env = robosuite.make(
            _scene_env_name(task) if scene else task,
            **scene,
            robots=robot,
            has_renderer=False,
            has_offscreen_renderer=False,
            use_camera_obs=False,
            hard_reset=False,
            ignore_done=True,
            reward_shaping=True,
            horizon=self.horizon,
            seed=0,
            **env_kwargs,
        )
        self.model = self._env.sim.model._model
        self.data = self._env.sim.data._data
        # bodies of the manipulated object (bench.perturb: perturb.mass scales these by default)
        self.object_bodies = [getattr(self._env, self._object).root_body]
        self.backend = f"robosuite-{robosuite.__version__}/mujoco-{mujoco.__version__}"
        self.fps = float(self._env.control_freq)  # control steps per second
        self.obs_names = list(OBS_NAMES)
        self.action_names = list(ACTION_NAMES)
        low, high = self._env.action_spec
        self.action_low, self.action_high = np.asarray(low, np.float32), np.asarray(high, np.float32)
        if len(self.action_low) != len(ACTION_NAMES):
            raise ValueError(f"{robot}: action size {len(self.action_low)}, expected {len(ACTION_NAMES)}")
        self.ctrl_spec = int(mujoco.mjtState.mjSTATE_CTRL)  # robosuite drives actuators only
        self._ctrl_size = self.model.nu
        self._ctrl_log: list[np.ndarray] | None = None
        self._wrap_physics_steps()
        self._grip_idx = np.asarray(self._env.robots[0]._ref_gripper_joint_pos_indexes["right"])
        self._grip_open = self._grip_closed = None
        self._calibrate_gripper()

    # -- actuator commands at every physics step (for batched replay) -------------------------
    def _wrap_physics_steps(self) -> None:
        """Note `data.ctrl` just before each physics step, when logging is on.

        robosuite's controller writes ctrl between `sim.step1()` and `sim.step2()` (or before
        `sim.step()`), once per physics step; `mj_step` with the noted ctrl from the same state
        reproduces the step exactly (checked in tests/test_replay.py).
        """
        sim, data = self._env.sim, self.data
        for name in ("step", "step2"):
            original = getattr(sim, name)

            def stepped(*args, _original=original, **kwargs):
                if self._ctrl_log is not None:
                    self._ctrl_log.append(data.ctrl.copy())
                return _original(*args, **kwargs)

            setattr(sim, name, stepped)

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
            last = self.data.qpos[self._grip_idx].copy()
            still = 0
            for _ in range(300):  # Jaco needs ~200 steps from open to closed
                self._env.step(command)
                q = self.data.qpos[self._grip_idx].copy()
                still = still + 1 if np.max(np.abs(q - last)) < 1e-4 else 0
                last = q
                if still >= 10:  # the fingers reached their end
                    break
            ends.append(last)
        self._grip_open, self._grip_closed = ends
        self._grip_mask = np.abs(self._grip_open - self._grip_closed) > 1e-3  # joints that move
        # per-step opening = mean((q - closed) / (open - closed)) over the moving joints
        self._grip_qidx = self._grip_idx[self._grip_mask]
        self._grip_c = self._grip_closed[self._grip_mask]
        self._grip_inv_span = 1.0 / (self._grip_open - self._grip_closed)[self._grip_mask]

    def _opening(self) -> float:
        frac = float(((self.data.qpos[self._grip_qidx] - self._grip_c) * self._grip_inv_span).mean())
        return min(1.0, max(0.0, frac))

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
        self._quat0_conj = _quat_conj(np.asarray(raw["robot0_eef_quat"], dtype=np.float64))
        self._init_state = np.concatenate([self.data.qpos, self.data.qvel, self._scene_vec]).copy()
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
        out = np.empty(18, dtype=np.float32)  # layout: OBS_NAMES
        eef, pos = raw["robot0_eef_pos"], raw[f"{obj}_pos"]
        quat_rel = _quat_mul(self._quat0_conj, raw["robot0_eef_quat"])
        out[0:3] = eef
        out[3:7] = quat_rel if quat_rel[3] >= 0 else -quat_rel  # one hemisphere: same rotation, same numbers
        out[7] = self._opening()
        out[8:11] = pos
        out[11:15] = raw[f"{obj}_quat"]
        out[15:18] = pos - eef
        return out

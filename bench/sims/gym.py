"""Gymnasium adapter: any registered env id behind the `bench.protocols.env.Env` contract.

Observations are flattened to one float32 vector (`gymnasium.spaces.flatten`; a Dict
space keeps one named field per key). Box actions are flattened the same way. A
Discrete(n) action is one number in [start - 0.5, start + n - 0.5] rounded to the
nearest integer, so a policy that samples uniformly within the bounds picks every
action with equal probability (MultiDiscrete: the same per dimension).
`reset(seed)` passes the seed to Gymnasium's `reset(seed=...)`, which reseeds the
env's generator and so fixes the initial state. Success is `info["success"]` or
`info["is_success"]` when the env reports one, else False (most control tasks
have no success predicate; their score is the return). MuJoCo-backed envs expose
`env.unwrapped.model` / `.data` (the `mujoco` capability), so the model perturbation axes
work on them.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import numpy as np

from bench.protocols import STATE, ActionSpec, Feature, MujocoHandle, Obs
from bench.protocols.env import CachedStateAdapter

if TYPE_CHECKING:
    import mujoco


class GymEnv(CachedStateAdapter):
    """One Gymnasium env, built once and reset with a seed per episode."""

    def __init__(self, env_id: str, horizon: int, env_kwargs: Mapping[str, object] | None = None):
        import gymnasium as gym  # gymnasium: loaded only when a Gymnasium env is made
        from gymnasium import spaces  # gymnasium: loaded only when a Gymnasium env is made

        self.env_id, self.horizon = env_id, int(horizon)
        self._env = gym.make(env_id, max_episode_steps=self.horizon, disable_env_checker=True, **(env_kwargs or {}))
        self._spaces = spaces
        obs_space, act_space = self._env.observation_space, self._env.action_space
        self._obs_space = obs_space
        if isinstance(obs_space, spaces.Dict):
            fields = [(str(k), int(spaces.flatdim(s))) for k, s in obs_space.spaces.items()]
        else:
            fields = [("obs", int(spaces.flatdim(obs_space)))]
        self.obs_spec = {STATE: Feature.state(fields)}
        self._act_space = act_space
        if isinstance(act_space, spaces.Box):
            low = np.asarray(act_space.low, np.float32).ravel()
            self.action_spec = ActionSpec.box(
                [f"a{i}" for i in range(low.size)], low, np.asarray(act_space.high, np.float32).ravel()
            )
        elif isinstance(act_space, spaces.Discrete):
            start, n = int(act_space.start), int(act_space.n)
            self.action_spec = ActionSpec.box(["action"], start - 0.5, start + n - 0.5)
        elif isinstance(act_space, spaces.MultiDiscrete):
            nvec = np.asarray(act_space.nvec).ravel()
            starts = np.asarray(getattr(act_space, "start", np.zeros_like(nvec))).ravel()
            self.action_spec = ActionSpec.box([f"a{i}" for i in range(nvec.size)], starts - 0.5, starts + nvec - 0.5)
        else:
            self._env.close()
            raise ValueError(
                f"{env_id}: action space {type(act_space).__name__} is not supported (Box, Discrete, MultiDiscrete are)"
            )
        unwrapped = self._env.unwrapped
        model, data = getattr(unwrapped, "model", None), getattr(unwrapped, "data", None)  # MuJoCo-backed envs
        self.mujoco: MujocoHandle | None = None
        self.backend = f"gymnasium-{gym.__version__}"
        try:
            import mujoco  # MuJoCo's native library: loaded only when a model is simulated

            if isinstance(model, mujoco.MjModel) and isinstance(data, mujoco.MjData):
                # no manipulated object declared; the arm's joints: those an actuator drives
                self.mujoco = MujocoHandle(model, data, arm_joints=_driven_joints(model))
                self.backend += f"/mujoco-{mujoco.__version__}"
        except ImportError:
            pass
        dt = getattr(unwrapped, "dt", None)
        self.fps = 1.0 / float(dt) if isinstance(dt, (int, float)) and dt > 0 else 0.0
        self._low, self._high = self.action_spec.low, self.action_spec.high
        self._success = False
        self._init_state = np.zeros(0)

    def _flat_obs(self, obs: object) -> np.ndarray:
        return np.asarray(self._spaces.flatten(self._obs_space, obs), dtype=np.float32).ravel()

    def _action(self, action: np.ndarray) -> np.ndarray | int:
        a = np.asarray(action, dtype=np.float64).ravel()
        space = self._act_space
        if isinstance(space, self._spaces.Box):
            return np.clip(a, self._low, self._high).astype(space.dtype).reshape(space.shape)
        rounded = np.clip(np.rint(a), self._low + 0.5, self._high - 0.5).astype(np.int64)
        if isinstance(space, self._spaces.Discrete):
            return int(rounded[0])
        return rounded.reshape(space.shape)

    def _state(self, obs: np.ndarray) -> np.ndarray:
        if self.mujoco is not None:
            return np.concatenate([self.mujoco.data.qpos, self.mujoco.data.qvel]).copy()
        return np.asarray(obs, dtype=np.float64).copy()

    def reset(self, seed: int) -> Obs:
        obs, _ = self._env.reset(seed=int(seed))
        flat = self._flat_obs(obs)
        self._init_state = self._state(flat)
        self._success = False
        return {STATE: flat}

    def edit_start(self, edit: Callable[[], None]) -> Obs:
        """The episode started from the state `edit` makes of the reset one (`AdapterBase.edit_start`).

        Gymnasium has no public call for "the observation of the current state": a MuJoCo env's own
        `_get_obs` (every `gymnasium.envs.mujoco` env has one) gives it, when no observation wrapper sits
        between it and this adapter. Anything else raises NotImplementedError.
        """
        from gymnasium import ObservationWrapper, Wrapper  # gymnasium: loaded only when a Gymnasium env is made

        layer = self._env
        while isinstance(layer, Wrapper):
            if isinstance(layer, ObservationWrapper):
                raise NotImplementedError(f"{self.env_id}: observation wrapper {type(layer).__name__} is in the way")
            layer = layer.env
        get_obs = getattr(layer, "_get_obs", None)  # Gymnasium MuJoCo envs' convention, not its API
        if self.mujoco is None or not callable(get_obs):
            raise NotImplementedError(f"{self.env_id} is not a Gymnasium MuJoCo env with an observation of its state")
        edit()
        self.mujoco.forward()
        flat = self._flat_obs(get_obs())
        self._init_state = self._state(flat)
        return {STATE: flat}

    def step(self, action: np.ndarray) -> tuple[Obs, float, bool, bool, dict[str, object]]:
        obs, reward, terminated, truncated, info = self._env.step(self._action(action))
        info = dict(info)
        self._success = bool(info.get("success", info.get("is_success", False)))
        return {STATE: self._flat_obs(obs)}, float(reward), bool(terminated), bool(truncated), info

    def close(self) -> None:
        self._env.close()


def _driven_joints(model: mujoco.MjModel) -> tuple[str, ...]:
    """Names of the hinge and slide joints an actuator drives, in the model's order."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    one_dof = (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)
    by_joint = mujoco.mjtTrn.mjTRN_JOINT
    driven = sorted({int(model.actuator_trnid[a, 0]) for a in range(model.nu) if model.actuator_trntype[a] == by_joint})
    named = [(j, mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j)) for j in driven]
    return tuple(name for j, name in named if name and model.jnt_type[j] in one_dof)

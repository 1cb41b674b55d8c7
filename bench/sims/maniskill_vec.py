"""N parallel ManiSkill envs of one cell in one PhysX scene (`num_envs=N`, for `sim_backend="physx_cuda"`).

The GPU path: one worker steps N episodes of the same cell and condition at once. Each env keeps
the harness's seed semantics: env i is reset alone (ManiSkill's partial reset, `env_idx=[i]`)
with its episode's seed, which fixes its initial state by that seed only (ManiSkill seeds the
torch generator of a reset with its first seed, so one batched reset with N seeds would make
every env's start depend on the batch). Observations, rewards and success come back per env as
the one-env adapter gives them, through the same `ManiSkillInterface` (`bench.sims.maniskill`).

Not yet wired into the runner (it runs one episode per `EnvAdapter`); what the runner needs is in
docs/maniskill.md. ManiSkill's CPU backend holds one env, so on CPU this runs with N=1 (the tests
do); on a GPU the same code runs N envs. PhysX parameters cannot be edited between steps on the
GPU backend, so the model perturbation axes are unavailable here; the interface axes apply per env.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from bench.core.errors import ConfigError
from bench.protocols import STATE, Obs
from bench.sims.maniskill import ManiSkillInterface, MsObs, NativeInterface, check_backend, check_buildable
from bench.sims.sapien_novulkan import prepare

if TYPE_CHECKING:
    from mani_skill.envs.sapien_env import BaseEnv


class ManiSkillVecEnv:
    """`num_envs` envs of one ManiSkill task; reset per env by seed, stepped together."""

    base: BaseEnv  # the unwrapped ManiSkill env

    def __init__(
        self,
        env_id: str,
        robot: str,
        num_envs: int,
        *,
        interface: ManiSkillInterface | None = None,
        sim_backend: str = "physx_cuda",
        env_kwargs: dict | None = None,
    ):
        check_backend(sim_backend)
        if num_envs < 1:
            raise ConfigError(f"num_envs={num_envs}: must be >= 1")
        if sim_backend == "physx_cpu" and num_envs != 1:
            raise ConfigError(
                f"num_envs={num_envs}: ManiSkill's physx_cpu backend holds one env; use sim_backend=physx_cuda for more"
            )
        check_buildable(env_id, robot)
        import gymnasium as gym  # gymnasium: loaded only when a Gymnasium env is made
        import mani_skill.envs  # noqa: F401

        self.render = prepare(cameras=False)
        self.interface: ManiSkillInterface = interface or NativeInterface()
        if not self.interface.uses_ms_state:
            raise ConfigError(
                "ManiSkillVecEnv reads ManiSkill's batched state observation; "
                "interfaces that compute the state from the scene are one-env only"
            )
        self.num_envs, self.env_id, self.robot = int(num_envs), env_id, robot
        self._gym = gym.make(
            env_id,
            robot_uids=robot,
            num_envs=self.num_envs,
            obs_mode="state",
            control_mode=self.interface.control_mode,
            sim_backend=sim_backend,
            render_backend="none",
            **(env_kwargs or {}),
        )
        self.base = self._gym.unwrapped
        self.interface.bind(self)
        self.action_spec = self.interface.action_spec
        self.device = self.base.device
        self._obs: MsObs = None

    def reset(self, seeds: Sequence[int], envs: Sequence[int] | None = None) -> list[Obs]:
        """Reset env `envs[k]` (default: all, in order) with `seeds[k]`; returns every env's observation."""
        import torch  # torch: loaded only when a network is built or run

        envs = list(range(self.num_envs)) if envs is None else list(envs)
        if len(seeds) != len(envs):
            raise ValueError(f"{len(seeds)} seeds for {len(envs)} envs")
        for i, seed in zip(envs, seeds):
            idx = torch.tensor([i], device=self.device)
            raw, _ = self.base.reset(seed=int(seed), options={"env_idx": idx})
            self._obs = raw
        return self._split(self._obs)

    def step(self, actions: np.ndarray) -> tuple[list[Obs], np.ndarray, np.ndarray]:
        """Step every env with its row of `actions` (N, A); returns (observations, rewards (N,), success (N,))."""
        import torch  # torch: loaded only when a network is built or run

        acts = np.asarray(actions, dtype=np.float32).reshape(self.num_envs, -1)
        batch = torch.as_tensor(acts, device=self.device)
        raw, reward, _, _, info = self.base.step(batch if self.num_envs > 1 else batch[0])
        self._obs = raw
        return (
            self._split(raw),
            reward.reshape(-1).cpu().numpy().astype(np.float64),
            info["success"].reshape(-1).cpu().numpy().astype(bool),
        )

    def init_states(self) -> np.ndarray:
        """(N, S) simulator states (hashed per env for the records' init_state_hash)."""
        return self.base.get_state().cpu().numpy().astype(np.float64)

    def close(self) -> None:
        self._gym.close()

    def _split(self, raw: MsObs) -> list[Obs]:
        state = raw.reshape(self.num_envs, -1).cpu().numpy().astype(np.float32)
        return [{STATE: state[i]} for i in range(self.num_envs)]

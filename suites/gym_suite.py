"""gym: any Gymnasium environment as a one-cell suite (`suite=gym env_id=HalfCheetah-v5`).

Task:
    the Gymnasium env named by `env_id` (any registered id, e.g. HalfCheetah-v5,
    InvertedPendulum-v5, CartPole-v1), through `bench.sims.gym.GymEnv`.
Split:
    one cell, split `seen`; the suite declares no held-out axis (its manifest is empty).
    Use it to measure sensitivity to physics and interface perturbations.
Conditions:
    nominal; `perturb.*` interface axes on every env; model axes (friction, link_mass,
    damping, armature, gain, gravity, ...) when the env is MuJoCo-backed
    (`env.unwrapped.model`). There is no manipulated object: `perturb.mass` needs
    `perturb.mass.bodies=[...]`. Visual axes on the images of envs with cameras.
Cameras:
    `obs=rgb|state+rgb` renders the model's cameras (default: its first, e.g. HalfCheetah's
    `track`); envs without a camera refuse it.
Success:
    `info["success"]` or `info["is_success"]` when the env reports one, else False.
Metric:
    the return (mean per episode with a bootstrap interval; `metric=return`, the default),
    and the success rate with a Wilson interval for envs that report success
    (`metric=success_once`); per-axis sensitivity paired by episode seed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional

from bench.api import ConfigError, did_you_mean
from bench.api.sims import CameraOptions, check_options
from bench.protocols import ObsSpec
from bench.protocols.suite import Cell, SuiteBase


@dataclass(frozen=True)
class GymOptions:
    """Keys of suite=gym (the camera keys as `bench.sims.camera_env.CameraOptions`, after env_id so that
    `GymOptions("HalfCheetah-v5")` keeps working; default camera: the model's first)."""

    env_id: str  # Gymnasium env id, e.g. HalfCheetah-v5, or module:Env-v0 to import the module that registers it
    obs: str = CameraOptions.obs  # state | rgb | state+rgb: the state vector, camera images (rgb.<camera>), or both
    cameras: Optional[list[str]] = None  # cameras rendered as rgb.<camera>; default: the model's first camera
    image_size: int = CameraOptions.image_size  # image height and width in pixels, in [16, 1024]


class GymSuite(SuiteBase):
    """Any Gymnasium env id as a one-cell suite (env_id=...); reference policy: random."""

    name = "gym"
    version = "1"
    Options = GymOptions
    reference_policy = "random"
    default_horizon = 1000
    default_metric = "return"  # most Gymnasium envs have no success predicate
    manifest: dict[str, dict[str, list[str]]] = {}

    def __init__(self, options: Any = None) -> None:
        if options is None:
            raise ConfigError("env_id: suite=gym needs a Gymnasium env id, e.g. env_id=HalfCheetah-v5")
        super().__init__(options)
        check_options(options)  # camera names are checked against the env's model when it is built
        self.env_id = str(options.env_id)
        self.default_horizon = int(_spec(self.env_id).max_episode_steps or type(self).default_horizon)
        self._obs_spec: ObsSpec | None = None

    def all_cells(self) -> list[Cell]:
        return [Cell(self.name, self.env_id, "default", "default", "seen")]

    def obs_spec(self, cell: Cell) -> ObsSpec:
        if self._obs_spec is None:  # the space is only known once the env is made (cheap for Gymnasium envs)
            env = self.make_env(cell, 1)
            try:
                self._obs_spec = dict(env.obs_spec)
            finally:
                env.close()
        return self._obs_spec

    def make_env(self, cell: Cell, horizon: int):
        from bench.api.sims import GymEnv, camera_names, with_cameras

        env = GymEnv(cell.task, horizon)  # the cell's task is the env id
        defaults = camera_names(env.mujoco.model)[:1] if env.mujoco is not None else []
        return with_cameras(env, self.options, defaults, cell.task)


def _spec(env_id: str):
    """Gymnasium's spec of `env_id`; `module:Env-v0` imports `module` first (as `gymnasium.make` does)."""
    import gymnasium as gym

    from bench.protocols.registry import import_module

    module, _, name = env_id.rpartition(":")
    if module:
        import_module(module, "env_id")
    try:
        return gym.spec(name)
    except gym.error.Error as exc:
        valid = sorted(gym.registry)
        raise ConfigError(
            f"env_id={env_id!r}: not a registered Gymnasium env ({type(exc).__name__}).{did_you_mean(name, valid)}"
        ) from None

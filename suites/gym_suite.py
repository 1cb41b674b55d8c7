"""gym: any Gymnasium environment as a one-cell suite (`suite=gym env_id=HalfCheetah-v5`).

Task:
    the Gymnasium env named by `env_id` (any registered id, e.g. HalfCheetah-v5,
    InvertedPendulum-v5, CartPole-v1), through `bench.sim_gym.GymEnv`.
Split:
    one cell, split `seen`; the suite declares no held-out axis (its manifest is empty).
    Use it to measure sensitivity to physics and interface perturbations.
Conditions:
    nominal; `perturb.*` interface axes on every env; model axes (friction, link_mass,
    damping, armature, gain, gravity, ...) when the env is MuJoCo-backed
    (`env.unwrapped.model`). There is no manipulated object: `perturb.mass` needs
    `perturb.mass.bodies=[...]`.
Success:
    `info["success"]` or `info["is_success"]` when the env reports one, else False.
Metric:
    success rate with a Wilson interval, and the return (mean_return in the summary);
    per-axis sensitivity paired by episode seed.
"""
from __future__ import annotations

from typing import Any

from bench.errors import ConfigError, did_you_mean
from bench.suite import Cell, Suite


class GymSuite(Suite):
    """Any Gymnasium env id as a one-cell suite (env_id=...); reference policy: random."""

    name = "gym"
    version = "1"
    reference_policy = "random"
    default_horizon = 1000
    manifest: dict[str, dict[str, list[str]]] = {}

    def __init__(self) -> None:
        self.env_id: str | None = None

    def configure(self, cfg) -> None:
        """Read `env_id` (required) and take the default horizon from the env's registered spec."""
        env_id = getattr(cfg, "env_id", None)
        if not env_id:
            raise ConfigError("env_id: suite=gym needs a Gymnasium env id, e.g. env_id=HalfCheetah-v5")
        import gymnasium as gym

        try:
            spec = gym.spec(env_id)
        except gym.error.Error as exc:
            valid = sorted(gym.registry)
            raise ConfigError(f"env_id={env_id!r}: not a registered Gymnasium env ({type(exc).__name__})."
                              f"{did_you_mean(env_id, valid)}") from None
        self.env_id = env_id
        self.default_horizon = int(spec.max_episode_steps or type(self).default_horizon)

    def all_cells(self) -> list[Cell]:
        if not self.env_id:
            raise ConfigError("env_id: suite=gym needs a Gymnasium env id, e.g. env_id=HalfCheetah-v5")
        return [Cell(self.name, self.env_id, "default", "default", "seen")]

    def make_env(self, cell: Cell, horizon: int):
        from bench.sim_gym import GymEnv

        return GymEnv(cell.task, horizon)  # the cell's task is the env id: workers need no configure()

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "env_id": self.env_id}

"""pusht: lerobot's PushT (`gym-pusht`), with held-out blocks, goals and colours.

Task:
    `PushT-v0` of gym-pusht 0.1.8, the environment lerobot's diffusion and ACT PushT policies are
    trained and evaluated on (`lerobot-eval --env.type=pusht`): a round agent (pymunk, PD-driven to
    the commanded point) pushes a T-shaped block onto a T-shaped goal zone; 10 Hz, 300 steps
    (lerobot's `episode_length`); the agent and block start where `reset(seed=)` puts them.
    Instruction (lerobot's PushT datasets): "Push the T-shaped block onto the T-shaped target."
Split (scenes = the env axis):
    seen region: goal within 30 px and 0.3 rad of gym-pusht's (256, 256, pi/4), block scale in
                 [0.9, 1.1], centre of gravity where gym-pusht puts it, gym-pusht's colours
    seen   = nominal; goal_nudged (goal at (236, 276, pi/4 + 0.25))
    unseen = goal_moved (goal at (200, 300, pi/4 + 1.2)); big_block (the T 1.3x larger, so the
             goal zone too); off_centre_mass (the block's centre of gravity 40 px down its stem:
             it turns differently under the same push); recoloured (block, goal and background
             colours changed: only image policies can notice)
    Cells: task `PushT-v0` x robot `agent` x scene; cell.options = the scene's parameters.
Observation (as lerobot's policies get it):
    state      agent_pos (2, px) then env_state (16: the T's 8 keypoints x, y; lerobot's
               `observation.environment_state` with `--env.obs_type=environment_state_agent_pos`), float32
    rgb.top    with `obs=state+rgb` or `obs=rgb`: the 96 x 96 image gym-pusht renders (lerobot's
               `observation.image`; `image_size=` another size)
    task       the instruction above (lerobot-eval itself passes "")
Action:
    the agent's target point (x, y) in [0, 512] px, as gym-pusht takes it (lerobot's `action`).
Conditions:
    nominal; interface axes (latency, action_noise, obs_noise, action_hold). The model axes
    need a MuJoCo model; PushT is pymunk, so its physics is varied by the scenes above.
Success:
    gym-pusht's: the block covers more than 95% of the goal zone; the episode ends there
    (terminated), so success_once = lerobot-eval's `success`. The reward is the coverage / 0.95
    clipped to 1 (the return sums it).
Metric:
    success rate per cell with Wilson intervals (and the return); mean over seen and unseen scenes
    with a stratified bootstrap interval; transfer gap = seen - unseen.
Policies:
    `scripted` (baselines/pusht_scripted.py): a pushing controller that reads the keypoints.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench.api import ConfigError, did_you_mean
from bench.api.sims import installed_version
from bench.protocols import RGB, STATE, TASK, ActionSpec, Feature, Obs, ObsSpec
from bench.protocols.env import CachedStateAdapter
from bench.protocols.suite import Cell, SuiteBase, declared_scene, scene_cells

TASK_ID = "PushT-v0"
ROBOT = "agent"
INSTRUCTION = "Push the T-shaped block onto the T-shaped target."
EXTRA = "lerobot-sims"
OBS_MODES = ("state", "rgb", "state+rgb")
NOMINAL: dict[str, Any] = {
    "goal": [256.0, 256.0, float(np.pi / 4)],
    "scale": 1.0,
    "cog_shift": 0.0,  # px down the stem from gym-pusht's centre of gravity
    "colors": {"block": "LightSlateGray", "goal": "LightGreen", "background": "White"},
}
SEEN_SCENES: dict[str, dict[str, Any]] = {
    "nominal": {},
    "goal_nudged": {"goal": [236.0, 276.0, float(np.pi / 4 + 0.25)]},
}
UNSEEN_SCENES: dict[str, dict[str, Any]] = {
    "goal_moved": {"goal": [200.0, 300.0, float(np.pi / 4 + 1.2)]},
    "big_block": {"scale": 1.3},
    "off_centre_mass": {"cog_shift": 40.0},
    "recoloured": {"colors": {"block": "DarkOrange", "goal": "LightSkyBlue", "background": "Gainsboro"}},
}


def scene_params(name: str) -> dict[str, Any]:
    """A declared scene's full parameters (gym-pusht's values where it changes nothing)."""
    return declared_scene(name, NOMINAL, SEEN_SCENES, UNSEEN_SCENES)


def in_seen_region(params: dict[str, Any]) -> bool:
    """The split's declared rule (docstring): whether a scene lies in the seen region."""
    (gx, gy, ga), (nx, ny, na) = params["goal"], NOMINAL["goal"]
    return (
        float(np.hypot(gx - nx, gy - ny)) <= 30
        and abs(ga - na) <= 0.3
        and 0.9 <= params["scale"] <= 1.1
        and params["cog_shift"] == 0
        and params["colors"] == NOMINAL["colors"]
    )


@dataclass(frozen=True)
class PushTOptions:
    """Keys of suite=pusht."""

    obs: str = "state"  # state | rgb | state+rgb: the state vector, the rendered image (rgb.top), or both
    image_size: int = 96  # image height and width in pixels (gym-pusht's observation size), in [16, 1024]


class PushTEnv(CachedStateAdapter):
    """gym-pusht's PushTEnv (a subclass that draws the scene's goal and colours) behind the EnvAdapter contract."""

    def __init__(self, params: dict[str, Any], horizon: int, obs: str, image_size: int):
        import gym_pusht  # gym-pusht: loaded only when a PushT env is made (it imports pygame and pymunk)
        import pymunk  # pymunk: loaded only when a PushT env is made

        self.horizon, self.fps, self.mode = int(horizon), 10.0, obs
        self._env = _scene_env_class()(params, image_size)
        self.backend = f"gym-pusht-{installed_version('gym-pusht', gym_pusht)}/pymunk-{pymunk.version}"
        spec: dict[str, Feature] = {}
        if obs != "rgb":
            spec[STATE] = Feature.state([("agent_pos", 2), ("env_state", 16)])
        if obs != "state":
            spec[f"{RGB}top"] = Feature.rgb(image_size, image_size)
        spec[TASK] = Feature.text()
        self.obs_spec: ObsSpec = spec
        self.action_spec = ActionSpec.box(["x", "y"], 0.0, 512.0)  # no MuJoCo model, input log or model axes

    @property
    def local_keypoints(self) -> np.ndarray:
        """The T's 8 keypoints in the block's own frame (for the scripted expert)."""
        return np.array([list(v) for s in self._env._block_shapes for v in s.get_vertices()], dtype=np.float64)

    @property
    def goal(self) -> np.ndarray:
        return np.asarray(self._env.goal_pose, dtype=np.float64)

    @property
    def cog(self) -> np.ndarray:
        return np.asarray(self._env.block.center_of_gravity, dtype=np.float64)

    def _obs(self, raw: dict) -> Obs:
        out: Obs = {}
        if self.mode != "rgb":
            out[STATE] = np.concatenate([raw["agent_pos"], raw["environment_state"]]).astype(np.float32)
        if self.mode != "state":
            out[f"{RGB}top"] = self._env._render()
        out[TASK] = INSTRUCTION
        return out

    def reset(self, seed: int) -> Obs:
        raw, _ = self._env.reset(seed=int(seed))
        self._success = False
        self._init_state = self._state()
        return self._obs(raw)

    def _state(self) -> np.ndarray:
        """The start, and the scene it plays in (goal, block size and centre of gravity, colours): scenes share
        starts, so `bench check` tells a held-out scene from a copy of a seen one by the rest."""
        import pygame  # pygame: loaded only when a PushT env is made

        e, p = self._env, self._env.params
        colors = [c / 255.0 for name in ("block", "goal", "background") for c in pygame.Color(p["colors"][name])[:3]]
        scene = [*e.goal_pose, p["scale"], p["cog_shift"], *colors]
        return np.array([*e.agent.position, *e.block.position, e.block.angle, *scene], dtype=np.float64)

    def step(self, action: np.ndarray) -> tuple[Obs, float, bool, bool, dict]:
        raw, reward, terminated, truncated, info = self._env.step(np.asarray(action, dtype=np.float32).ravel())
        self._success = bool(info["is_success"])
        return self._obs(raw), float(reward), bool(terminated), bool(truncated), {"coverage": float(info["coverage"])}

    def close(self) -> None:
        self._env.close()


_SCENE_ENV: Any = None


def _scene_env_class() -> type:
    """gym-pusht's PushTEnv with the scene's goal pose, block size, centre of gravity and colours."""
    global _SCENE_ENV
    if _SCENE_ENV is not None:
        return _SCENE_ENV
    import pygame  # pygame: loaded only when a PushT env is made (gym-pusht draws with it)
    import pymunk  # pymunk: loaded only when a PushT env is made
    import pymunk.pygame_util  # pymunk: loaded only when a PushT env is made
    from gym_pusht.envs.pusht import PushTEnv as Base  # gym-pusht: loaded only when a PushT env is made
    from gym_pusht.envs.pymunk_override import DrawOptions  # gym-pusht: loaded only when a PushT env is made

    class SceneEnv(Base):
        def __init__(self, params: dict[str, Any], image_size: int):
            super().__init__(
                obs_type="environment_state_agent_pos", observation_width=image_size, observation_height=image_size
            )
            self.params = params

        def _setup(self) -> None:
            super()._setup()
            p = self.params
            if p["scale"] != 1.0 or p["colors"]["block"] != NOMINAL["colors"]["block"]:
                self.space.remove(self.block, *self._block_shapes)
                self.block, self._block_shapes = self.add_tee(
                    self.space, (256, 300), 0, scale=30 * p["scale"], color=p["colors"]["block"]
                )
            self.goal_pose = np.array(p["goal"], dtype=np.float64)
            if p["cog_shift"]:
                cog = self.block.center_of_gravity
                self.block.center_of_gravity = (cog[0], cog[1] + p["cog_shift"])

        def _draw(self) -> Any:  # gym-pusht's, with the scene's goal and background colours
            screen = pygame.Surface((512, 512))
            screen.fill(pygame.Color(self.params["colors"]["background"]))
            draw_options = DrawOptions(screen)
            goal_body = self.get_goal_pose_body(self.goal_pose)
            for shape in self.block.shapes:
                points = [goal_body.local_to_world(v) for v in shape.get_vertices()]
                points = [pymunk.pygame_util.to_pygame(q, draw_options.surface) for q in points]
                pygame.draw.polygon(screen, pygame.Color(self.params["colors"]["goal"]), [*points, points[0]])
            self.space.debug_draw(draw_options)
            return screen

    _SCENE_ENV = SceneEnv
    return SceneEnv


class PushT(SuiteBase):
    """gym-pusht's PushT (lerobot's PushT sim); 2 seen, 4 held-out scenes (goal, block size, mass centre, colours)."""

    name = "pusht"
    version = "1"
    Options = PushTOptions
    reference_policy = "scripted"
    default_horizon = 300
    default_metric = "success_once"
    manifest = {"envs": {"seen": list(SEEN_SCENES), "unseen": list(UNSEEN_SCENES)}}
    capabilities = frozenset({"expert"})
    instructions = str(Path(__file__).with_name("instructions") / "pusht.json")  # `perturb.instruction`

    @classmethod
    def unavailable(cls) -> str | None:
        """Why gym-pusht cannot run here (one line), or None."""
        if importlib.util.find_spec("gym_pusht") is None:
            return f"suite pusht needs gym-pusht: pip install -e '.[{EXTRA}]' (gym_pusht is missing)"
        return None

    def __init__(self, options: Any = None) -> None:
        super().__init__(options)  # refused here while `unavailable()`
        if self.options.obs not in OBS_MODES:
            raise ConfigError(
                f"obs: {self.options.obs!r} is not an observation mode; valid: {', '.join(OBS_MODES)}."
                f"{did_you_mean(str(self.options.obs), OBS_MODES)}"
            )
        if not 16 <= int(self.options.image_size) <= 1024:
            raise ConfigError(f"image_size: {self.options.image_size!r} is invalid; whole pixels in [16, 1024]")

    def all_cells(self) -> list[Cell]:
        return scene_cells(self.name, TASK_ID, ROBOT, SEEN_SCENES, UNSEEN_SCENES, scene_params)

    def obs_spec(self, cell: Cell) -> ObsSpec:
        spec: dict[str, Feature] = {}
        if self.options.obs != "rgb":
            spec[STATE] = Feature.state([("agent_pos", 2), ("env_state", 16)])
        if self.options.obs != "state":
            spec[f"{RGB}top"] = Feature.rgb(self.options.image_size, self.options.image_size)
        spec[TASK] = Feature.text()
        return spec

    def make_env(self, cell: Cell, horizon: int):
        return PushTEnv(scene_params(cell.env), horizon, self.options.obs, int(self.options.image_size))

    def make_expert(self, cell: Cell, env):
        from baselines.pusht_scripted import PushExpert

        return PushExpert(env)

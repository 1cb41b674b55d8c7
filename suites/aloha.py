"""aloha: lerobot's simulated ALOHA tasks (`gym-aloha`), with held-out physics.

Task:
    the two bimanual ViperX 300 tasks of gym-aloha 0.1.5, the environments lerobot's ACT and
    diffusion ALOHA policies are trained and evaluated on (`lerobot-eval --env.type=aloha`);
    task names are their Gymnasium ids:
    AlohaTransferCube-v0   the right arm picks the red cube up and hands it to the left arm
                           ("Pick up the cube with the right arm and transfer it to the left arm.")
    AlohaInsertion-v0      the arms pick up the peg and the socket and insert one into the other
                           ("Insert the peg into the socket.")
    The physics is gym-aloha's own (its MJCF, dm_control's `control.Environment`, 50 Hz, 10
    substeps of 2 ms); the initial object poses are gym-aloha's `sample_box_pose(seed)` /
    `sample_insertion_pose(seed)`, so an episode seed gives the start `gym.make(...).reset(seed=)` gives.
Split (scenes = the env axis; levels are scales of gym-aloha's values, set with the harness's
model axes, `bench.sims.perturb.reset.set_nominal`):
    seen region: every level within [0.5, 2] (training data may cover it)
    seen   = nominal; light_object (object mass x0.5); grippy (friction of every geom x1.5)
    unseen = heavy_object (mass x4); slippery (friction x0.3); weak_servos (actuator gain x0.4:
             the position servos' stiffness); stiff_joints (joint dry friction, frictionloss, x4)
    Cells: task x robot `vx300s_bimanual` x scene; select with `tasks=[AlohaTransferCube-v0]`,
    `envs=[nominal,slippery]`.
Observation (as lerobot's policies get it, `--env.obs_type=pixels_agent_pos`):
    state      agent_pos (14: per arm 6 joint angles and the normalised gripper opening, 0 closed,
               1 open), then env_state (gym-aloha's object pose: cube xyz + quat wxyz, 7; for
               insertion peg then socket, 14), float32. lerobot's `observation.state` is
               `state.agent_pos`, a state-based policy's `observation.environment_state` `state.env_state`.
    rgb.top    with `obs=state+rgb`: the `top` camera at 480 x 640, rendered with MuJoCo's default
               scene settings as dm_control renders it for gym-aloha (bit-identical images);
               lerobot's `observation.images.top`. `cameras=` picks others (angle, front_close,
               left_pillar, right_pillar), `image_size=` another size.
    task       the instruction string of lerobot's ALOHA datasets (above); lerobot-eval itself
               passes "" for these envs, which have no task attribute.
Action:
    14 absolute targets, as gym-aloha takes them: per arm 6 joint angles (rad) and the gripper
    opening (normalised, 0 closed .. 1 open); lerobot's `action`.
Conditions:
    nominal; `perturb.*` model axes on the MuJoCo model (friction, mass [the cube, or peg and
    socket], link_mass, frictionloss, armature, gain, gravity; the model has no joint damping, so
    `perturb.damping` is refused: use frictionloss), interface axes (latency, action_noise,
    obs_noise, action_hold; latency's first steps command the neutral action, here the zero joint
    pose: AlohaEnv declares no `hold_action`, which the committed latency results were measured without) and, with `obs=state+rgb`, the visual axes on the images: light, light_dir, camera_pos,
    camera_rot, object_color, table_color, background (not texture: the table has none; not
    distractors: the table is a mesh, not a box to stand them on).
Success:
    gym-aloha's reward reaches its maximum, 4 (cube held by the left gripper off the table;
    peg touching the socket's pin); the episode ends there, as gym-aloha's does (terminated),
    so success_once = lerobot-eval's `success`. Horizon 400 steps (lerobot's `episode_length`).
Metric:
    success rate per cell with Wilson intervals; mean over seen and unseen scenes with a
    stratified bootstrap interval; transfer gap = seen - unseen.
Policies:
    `scripted` (baselines/aloha_scripted.py): ACT's scripted end-effector trajectories, solved in
    gym-aloha's mocap model and replayed as joint targets, as the ACT datasets were made.
    lerobot policies are served by baselines/lerobot_adapter.py to `policy=remote`
    (docs/remote-policies.md, "lerobot").
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from bench.api.sims import (
    RENDERER_DEFAULTS,
    CameraOptions,
    camera_spec,
    check_options,
    installed_version,
    set_nominal,
    unwrap,
    with_cameras,
)
from bench.protocols import STATE, TASK, ActionSpec, Feature, MujocoHandle, Obs, ObsSpec
from bench.protocols.suite import Cell, SuiteBase

ROBOT = "vx300s_bimanual"
FPS = 50.0
HORIZON = 400  # lerobot's AlohaEnv.episode_length
IMAGE_SIZE = (480, 640)  # gym-aloha's observation size (height, width)
CAMERAS = ("top", "angle", "front_close", "left_pillar", "right_pillar")
EXTRA = "lerobot-sims"


@dataclass(frozen=True)
class AlohaTask:
    """One gym-aloha task: its model file, objects and the instruction of lerobot's datasets."""

    kind: str  # gym-aloha's task name
    xml: str
    objects: tuple[str, ...]  # bodies of the manipulated objects (`perturb.mass` scales them)
    instruction: str


TASKS: dict[str, AlohaTask] = {
    "AlohaTransferCube-v0": AlohaTask(
        "transfer_cube",
        "bimanual_viperx_transfer_cube.xml",
        ("box",),
        "Pick up the cube with the right arm and transfer it to the left arm.",
    ),
    "AlohaInsertion-v0": AlohaTask(
        "insertion", "bimanual_viperx_insertion.xml", ("peg", "socket"), "Insert the peg into the socket."
    ),
}
SEEN_REGION = (0.5, 2.0)  # every level of a seen scene lies here; an unseen scene has one outside
SEEN_SCENES: dict[str, dict[str, float]] = {
    "nominal": {},
    "light_object": {"mass": 0.5},
    "grippy": {"friction": 1.5},
}
UNSEEN_SCENES: dict[str, dict[str, float]] = {
    "heavy_object": {"mass": 4.0},
    "slippery": {"friction": 0.3},
    "weak_servos": {"gain": 0.4},
    "stiff_joints": {"frictionloss": 4.0},
}
ARM_JOINTS = ("waist", "shoulder", "elbow", "forearm_roll", "wrist_angle", "wrist_rotate")
ACTION_NAMES = tuple(f"{side}_{j}" for side in ("left", "right") for j in (*ARM_JOINTS, "gripper"))


def in_seen_region(levels: dict[str, float]) -> bool:
    """Whether every level of a scene lies in `SEEN_REGION` (the split's declared rule)."""
    lo, hi = SEEN_REGION
    return all(lo <= v <= hi for v in levels.values())


@dataclass(frozen=True)
class AlohaOptions:
    """Keys of suite=aloha (the camera keys of `bench.sims.camera_env.CameraOptions`, gym-aloha's defaults)."""

    obs: str = CameraOptions.obs  # state | rgb | state+rgb: the state vector, camera images (rgb.<camera>), or both
    cameras: Optional[list[str]] = None  # cameras rendered as rgb.<camera>; default: top (lerobot's)
    image_size: Any = field(default_factory=lambda: list(IMAGE_SIZE))  # [height, width] (or one size), px


def state_feature(task: str) -> Feature:
    """agent_pos (14) then env_state (the objects' poses, 7 per object)."""
    return Feature.state([("agent_pos", 14), ("env_state", 7 * len(TASKS[task].objects))])


class AlohaEnv:
    """gym-aloha's physics and task, stepped as `gym_aloha.env.AlohaEnv` steps them, without its images.

    gym-aloha renders three 480 x 640 cameras at every step whatever the policy reads (~70 ms each
    on a CPU); here the task's observation skips them and bench's camera rig renders only the
    cameras asked for, with the same renderer settings (the images are identical).
    """

    def __init__(self, task: str, horizon: int, scene: dict[str, float], where: str = ""):
        import dm_control  # dm_control: loaded only when an ALOHA env is made (it imports MuJoCo)
        import gym_aloha  # gym-aloha: loaded only when an ALOHA env is made
        import mujoco  # MuJoCo's native library: loaded only when a model is simulated
        from dm_control import mujoco as dm_mujoco  # dm_control: loaded only when an ALOHA env is made
        from dm_control.rl import control  # dm_control: loaded only when an ALOHA env is made
        from gym_aloha import constants, utils  # gym-aloha: loaded only when an ALOHA env is made
        from gym_aloha.tasks import sim  # gym-aloha: loaded only when an ALOHA env is made

        spec = TASKS[task]
        self.task_id, self.kind, self.horizon, self.fps = task, spec.kind, int(horizon), FPS
        self._sim, self._utils = sim, utils
        base = sim.TransferCubeTask if spec.kind == "transfer_cube" else sim.InsertionTask
        self._task = _without_images(base)()
        self._physics = dm_mujoco.Physics.from_xml_path(str(constants.ASSETS_DIR / spec.xml))
        self._env = control.Environment(
            self._physics,
            self._task,
            time_limit=float("inf"),
            control_timestep=constants.DT,
            n_sub_steps=None,
            flat_observation=False,
        )
        self.instruction = spec.instruction
        self.obs_spec: ObsSpec = {STATE: state_feature(task), TASK: Feature.text()}
        model = self._physics.model.ptr
        arm_lo = np.asarray(model.actuator_ctrlrange[:, 0], np.float32)
        arm_hi = np.asarray(model.actuator_ctrlrange[:, 1], np.float32)
        # actuators: per arm 6 joints then 2 fingers; the action's gripper is normalised 0..1
        lo = np.concatenate([arm_lo[0:6], [0.0], arm_lo[8:14], [0.0]])
        hi = np.concatenate([arm_hi[0:6], [1.0], arm_hi[8:14], [1.0]])
        self.action_spec = ActionSpec.box(ACTION_NAMES, lo, hi)
        self.mujoco: MujocoHandle | None = MujocoHandle(model, self._physics.data.ptr, object_bodies=spec.objects)
        self.inputs = None
        self.model_axes = None
        self.backend = (
            f"gym-aloha-{installed_version('gym-aloha', gym_aloha)}"
            f"/dm-control-{installed_version('dm-control', dm_control)}"
            f"/mujoco-{mujoco.__version__}"
        )
        set_nominal(self.mujoco, scene, where or task)
        self._reward = 0.0
        self._init = np.zeros(0)

    def _obs(self, observation: dict) -> Obs:
        state = np.concatenate([observation["qpos"], observation["env_state"]]).astype(np.float32)
        return {STATE: state, TASK: self.instruction}

    def reset(self, seed: int) -> Obs:
        seed = int(seed)
        # gym_aloha.env.AlohaEnv.reset: the task's generators and the objects' start poses from the seed
        self._task.random.seed(seed)
        self._task._random = np.random.RandomState(seed)
        if self.kind == "transfer_cube":
            self._sim.BOX_POSE[0] = self._utils.sample_box_pose(seed)
        else:
            self._sim.BOX_POSE[0] = np.concatenate(self._utils.sample_insertion_pose(seed))
        ts = self._env.reset()
        self._reward = 0.0
        data, model = self._physics.data, self._physics.model.ptr
        # the start and the physics it evolves under: scenes share starts but not dynamics (`bench check` tells
        # a held-out scene from a copy of a seen one by this)
        physics = [model.body_mass, model.geom_friction[:, 0], model.actuator_gainprm[:, 0], model.dof_frictionloss]
        self._init = np.concatenate([data.qpos, data.qvel, *physics]).copy()
        return self._obs(ts.observation)

    def step(self, action: np.ndarray) -> tuple[Obs, float, bool, bool, dict]:
        ts = self._env.step(np.asarray(action, dtype=np.float32).ravel())  # gym-aloha's action space is float32
        self._reward = float(ts.reward)
        success = self._reward == self._task.max_reward
        return self._obs(ts.observation), self._reward, success, False, {"is_success": success}

    def success(self) -> bool:
        return self._reward == self._task.max_reward

    def init_state(self) -> np.ndarray:
        return self._init

    def close(self) -> None:
        self._physics.free()


def _without_images(base: type) -> type:
    """gym-aloha's task class whose observation holds no images (bench's camera rig renders those)."""

    class Task(base):  # type: ignore[misc, valid-type]
        def get_observation(self, physics: Any) -> dict:
            return {"qpos": self.get_qpos(physics), "env_state": self.get_env_state(physics)}

    Task.__name__ = base.__name__
    return Task


class Aloha(SuiteBase):
    """gym-aloha's transfer-cube and insertion (lerobot's ALOHA sim); 3 seen, 4 held-out physics scenes."""

    name = "aloha"
    version = "1"
    Options = AlohaOptions
    reference_policy = "scripted"
    default_horizon = HORIZON
    manifest = {"envs": {"seen": list(SEEN_SCENES), "unseen": list(UNSEEN_SCENES)}}
    capabilities = frozenset({"expert"})
    instructions = str(Path(__file__).with_name("instructions") / "aloha.json")  # `perturb.instruction`

    @classmethod
    def unavailable(cls) -> str | None:
        """Why gym-aloha cannot run here (one line), or None."""
        for module in ("gym_aloha", "dm_control"):
            if importlib.util.find_spec(module) is None:
                return f"suite aloha needs gym-aloha and dm-control: pip install -e '.[{EXTRA}]' ({module} is missing)"
        return None

    def __init__(self, options: Any = None) -> None:
        super().__init__(options)  # refused here while `unavailable()`
        check_options(self.options, CAMERAS, "gym-aloha")

    def all_cells(self) -> list[Cell]:
        return [
            Cell(self.name, task, ROBOT, scene, split, options=dict(levels))
            for task in TASKS
            for split, scenes in (("seen", SEEN_SCENES), ("unseen", UNSEEN_SCENES))
            for scene, levels in scenes.items()
        ]

    def obs_spec(self, cell: Cell) -> ObsSpec:
        return camera_spec({STATE: state_feature(cell.task), TASK: Feature.text()}, self.options, ["top"])

    def action_names(self, cell: Cell) -> list[str]:
        return list(ACTION_NAMES)  # both arms' joints and grippers, as AlohaEnv's action_spec

    def make_env(self, cell: Cell, horizon: int):
        scene = SEEN_SCENES.get(cell.env, UNSEEN_SCENES.get(cell.env, {}))
        env = AlohaEnv(cell.task, horizon, scene, where=cell.key)
        return with_cameras(env, self.options, ["top"], cell.key, scene_flags=RENDERER_DEFAULTS)

    def make_expert(self, cell: Cell, env):
        from baselines.aloha_scripted import AlohaExpert

        return AlohaExpert(unwrap(env))

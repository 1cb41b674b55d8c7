"""maniskill_tasks: transfer to ManiSkill3 table-top tasks the policy never trained on.

Task:
    eleven ManiSkill3 table-top tasks that build offline (no asset download), each on the robot
    its motion-planning solution is written for (Panda; Panda with wrist camera for
    PegInsertionSide), simulated on PhysX (CPU by default: no GPU or Vulkan needed).
Split:
    seen   = PickCube, PushCube, PullCube, StackCube, LiftPegUpright, PlaceSphere — grasp, place,
             push, pull, stack and re-orient single rigid objects.
    unseen = PegInsertionSide, StackPyramid, PlugCharger, PokeCube, RollBall — compositions and
             skills the seen tasks do not show: millimetre insertion (peg, charger), a longer
             stacking sequence, tool use (poke a cube with a peg), and a dynamic strike (roll a ball
             ~1.4 m into a target).
Observation:
    `state`: ManiSkill's own state observation (`obs_mode="state"`: joint positions and
    velocities, TCP pose, task-specific object poses; fields named after ManiSkill's state dict,
    widths differ per task), `task`: the instruction, and with `obs=rgb` / `obs=state+rgb` one
    `rgb.<camera>` image per camera (`base_camera`; PegInsertionSide's robot adds `hand_camera`);
    cameras need a Vulkan device (`scripts/fetch_lavapipe.sh` gives a software one on CPU).
Action:
    the control mode's own action (`control_mode=`, default `pd_joint_pos`: 7 joint targets +
    gripper, +1 open / -1 closed, ManiSkill's convention).
Conditions:
    nominal; `perturb.*`: friction, mass, link_mass, damping, gain, gravity through PhysX
    (`bench.sims.perturb.physx`), and the interface axes (latency, action/obs noise, action_hold).
Success:
    ManiSkill's `info["success"]` (task-specific, most require the robot to be static);
    success_once = at any step, success_at_end = at the last step (horizon 250 steps, 20 Hz).
    RollBall's success is the ball inside the target, which a rolling ball passes through: use
    success_once there.
Metric:
    success rate per task with Wilson intervals; mean over seen and unseen tasks with a
    stratified bootstrap interval; transfer gap = seen - unseen.
Policies:
    `scripted` (the reference): ManiSkill's own motion-planning solutions, plus ours for PokeCube
    and RollBall (baselines/maniskill_solutions.py), run closed loop through the harness
    (baselines/maniskill_mp.py; needs control_mode=pd_joint_pos).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional

from bench.protocols import EnvAdapter, ObsSpec, Policy
from bench.protocols.suite import Cell
from suites.maniskill_common import TASKS, ManiSkillSuite, check_control_mode, obs_spec

SEEN = ["PickCube", "PushCube", "PullCube", "StackCube", "LiftPegUpright", "PlaceSphere"]
UNSEEN = ["PegInsertionSide", "StackPyramid", "PlugCharger", "PokeCube", "RollBall"]
# ManiSkill's state layout per task (obs_mode="state" with a Panda), declared without building the env
STATE_FIELDS: dict[str, tuple[tuple[str, int], ...]] = {
    "PickCube": (("tcp_pose", 7), ("goal_pos", 3), ("obj_pose", 7), ("tcp_to_obj_pos", 3), ("obj_to_goal_pos", 3)),
    "PushCube": (("tcp_pose", 7), ("goal_pos", 3), ("obj_pose", 7)),
    "PullCube": (("tcp_pose", 7), ("goal_pos", 3), ("obj_pose", 7)),
    "StackCube": (
        ("tcp_pose", 7),
        ("cubeA_pose", 7),
        ("cubeB_pose", 7),
        ("tcp_to_cubeA_pos", 3),
        ("tcp_to_cubeB_pos", 3),
        ("cubeA_to_cubeB_pos", 3),
    ),
    "LiftPegUpright": (("tcp_pose", 7), ("obj_pose", 7)),
    "PlaceSphere": (("tcp_pose", 7), ("bin_pos", 3), ("obj_pose", 7), ("tcp_to_obj_pos", 3)),
    "PegInsertionSide": (
        ("tcp_pose", 7),
        ("peg_pose", 7),
        ("peg_half_size", 3),
        ("box_hole_pose", 7),
        ("box_hole_radius", 1),
    ),
    "StackPyramid": (
        ("tcp_pose", 7),
        ("cubeA_pose", 7),
        ("cubeB_pose", 7),
        ("cubeC_pose", 7),
        ("tcp_to_cubeA_pos", 3),
        ("tcp_to_cubeB_pos", 3),
        ("tcp_to_cubeC_pos", 3),
        ("cubeA_to_cubeB_pos", 3),
        ("cubeB_to_cubeC_pos", 3),
        ("cubeA_to_cubeC_pos", 3),
    ),
    "PlugCharger": (("tcp_pose", 7), ("charger_pose", 7), ("receptacle_pose", 7), ("goal_pose", 7)),
    "PokeCube": (
        ("tcp_pose", 7),
        ("cube_pose", 7),
        ("peg_pose", 7),
        ("goal_pos", 3),
        ("tcp_to_peg_pos", 3),
        ("peg_to_cube_pos", 3),
        ("cube_to_goal_pos", 3),
        ("peghead_to_cube_pos", 3),
    ),
    "RollBall": (
        ("tcp_pose", 7),
        ("goal_pos", 3),
        ("ball_pose", 7),
        ("ball_vel", 3),
        ("tcp_to_ball_pos", 3),
        ("ball_to_goal_pos", 3),
    ),
}
IS_GRASPED = ("PickCube", "PlaceSphere")  # tasks whose state starts the extras with is_grasped (1)
# control modes whose controller keeps a target, which ManiSkill adds to the state after qvel
TARGET_STATE = {
    "pd_joint_target_delta_pos": ("controller.arm.target_qpos", 7),
    "pd_ee_target_delta_pos": ("controller.arm.target_pose", 7),
    "pd_ee_target_delta_pose": ("controller.arm.target_pose", 7),
}


@dataclass(frozen=True)
class ManiSkillTasksOptions:
    """Keys of suite=maniskill_tasks."""

    obs: str = "state"  # state | rgb | state+rgb (rgb needs a Vulkan device)
    cameras: Optional[list[str]] = None  # cameras for rgb (default: every camera of the cell)
    image_size: int = 128  # camera width = height in pixels, 16..1024
    control_mode: str = "pd_joint_pos"  # ManiSkill control mode; the scripted expert needs pd_joint_pos
    sim_backend: str = "physx_cpu"  # physx_cpu, or physx_cuda on a machine with a CUDA GPU
    reset: str = "rebuild"  # rebuild: same seed+actions -> same trajectory; soft: ManiSkill's reset


def state_fields(task: str, control_mode: str) -> tuple[tuple[str, int], ...]:
    """The task's state layout under `control_mode` (qpos, qvel, [controller target], [is_grasped], extras)."""
    fields: list[tuple[str, int]] = [("qpos", 9), ("qvel", 9)]
    if control_mode in TARGET_STATE:
        fields.append(TARGET_STATE[control_mode])
    if task in IS_GRASPED:
        fields.append(("is_grasped", 1))
    return tuple(fields) + STATE_FIELDS[task]


class ManiSkillTasks(ManiSkillSuite):
    """Eleven ManiSkill3 table-top tasks on PhysX (CPU); 6 seen, 5 held out; motion-planning expert."""

    name = "maniskill_tasks"
    version = "1"
    Options = ManiSkillTasksOptions
    default_horizon = 250
    manifest = {"tasks": {"seen": SEEN, "unseen": UNSEEN}}

    def __init__(self, options: Any = None) -> None:
        super().__init__(options)
        for task in TASKS.values():
            check_control_mode(self.options.control_mode, task.robot)

    def all_cells(self) -> list[Cell]:
        return [
            Cell(self.name, t, TASKS[t].robot, "table", split)
            for split, tasks in (("seen", SEEN), ("unseen", UNSEEN))
            for t in tasks
        ]

    def obs_spec(self, cell: Cell) -> ObsSpec:
        o = self.options
        return obs_spec(state_fields(cell.task, o.control_mode), cell.robot, o.obs, o.cameras, o.image_size)

    def make_env(self, cell: Cell, horizon: int) -> EnvAdapter:
        from bench.api.sims import NativeInterface

        return self._env(cell, horizon, NativeInterface(self.options.control_mode))

    def make_expert(self, cell: Cell, env: Any) -> Policy:
        from baselines.maniskill_mp import MotionPlanExpert
        from baselines.maniskill_solutions import solutions

        return MotionPlanExpert(env, solutions()[TASKS[cell.task].env_id], cell.task)

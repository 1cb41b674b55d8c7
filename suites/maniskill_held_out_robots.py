"""maniskill_held_out_robots: transfer to robots the policy never saw, on ManiSkill3 (PhysX).

Task:
    ManiSkill3 PickCube (grasp the cube, bring it to a goal point in the air), PushCube and
    PullCube (slide the cube onto a target on the table), simulated on PhysX (CPU by default).
    Robots that build offline: Panda, Panda with wrist camera, Fetch (a mobile manipulator: 7-DOF
    arm on a torso and a wheeled base) and SO-100 (a low-cost 5-DOF arm with a one-sided jaw).
    SO-100 runs PickCube only: ManiSkill places PushCube's and PullCube's cube ~0.7 m from its
    base, beyond its reach (ManiSkill's own PickCube config brings the cube within it).
Split:
    seen   = panda, panda_wristcam — the Franka arm and gripper that dominate public datasets,
             with and without a wrist camera (identical in state, different in images).
    unseen = fetch, so100 — new kinematics, a different parallel gripper on a mobile base, and a
             small arm whose jaw sweeps from one side.
Observation (the same 24 numbers on every robot, `suites.maniskill_agnostic`):
    eef_pos (3), eef_quat_rel (4, relative to the pose at reset), gripper_opening (1; 1 = open),
    object_pos (3), object_quat (4), gripper_to_object (3), goal_pos (3), object_to_goal (3);
    `task`: the instruction; with `obs=rgb` / `state+rgb` one `rgb.<camera>` per camera
    (`base_camera`; `hand_camera` on panda_wristcam; `fetch_head`, `fetch_hand` on fetch).
Action (the same on every robot):
    a world-frame TCP displacement (dx, dy, dz; 1.0 = 0.1 m per step) and a gripper command
    (+1 closes, -1 opens), as held_out_robots; ManiSkill's Cartesian controller on the Pandas,
    a damped-least-squares step on joint targets on Fetch and SO-100.
Conditions:
    nominal; `perturb.*`: friction, mass, link_mass, damping, gain, gravity through PhysX and the
    interface axes (latency, action/obs noise, action_hold).
Success:
    ManiSkill's `info["success"]` (PickCube: the cube within 2.5 cm of the goal and the robot
    static; Push/PullCube: the cube inside the target); success_once / success_at_end over
    100 steps at 20 Hz.
Metric:
    success rate per (task, robot) with Wilson intervals; mean over seen and unseen robots with a
    stratified bootstrap interval; transfer gap = seen - unseen.
Policies:
    `scripted` (the reference, baselines/maniskill_scripted.py) reads only the agnostic
    observation and succeeds on the seen robots; it does not transfer to the unseen ones (their
    reach and hands differ), which is what the suite measures.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional

from bench.protocols import EnvAdapter, ObsSpec, Policy
from bench.protocols.suite import Cell
from suites.maniskill_common import ManiSkillSuite, obs_spec

SEEN = ["panda", "panda_wristcam"]
UNSEEN = ["fetch", "so100"]
# task -> (robots it runs on, the task's object and goal attributes in ManiSkill)
CELLS: dict[str, tuple[tuple[str, ...], str, str]] = {
    "PickCube": (("panda", "panda_wristcam", "fetch", "so100"), "cube", "goal_site"),
    "PushCube": (("panda", "panda_wristcam", "fetch"), "obj", "goal_region"),
    "PullCube": (("panda", "panda_wristcam", "fetch"), "obj", "goal_region"),
}


@dataclass(frozen=True)
class ManiSkillRobotsOptions:
    """Keys of suite=maniskill_held_out_robots."""

    obs: str = "state"  # state | rgb | state+rgb (rgb needs a Vulkan device)
    cameras: Optional[list[str]] = None  # cameras for rgb (default: every camera of the cell)
    image_size: int = 128  # camera width = height in pixels, 16..1024
    sim_backend: str = "physx_cpu"  # physx_cpu, or physx_cuda on a machine with a CUDA GPU
    reset: str = "rebuild"  # rebuild: same seed+actions -> same trajectory; soft: ManiSkill's reset


class ManiSkillHeldOutRobots(ManiSkillSuite):
    """PickCube/PushCube/PullCube on 4 ManiSkill robots; panda(+wristcam) seen, fetch and so100 held out."""

    name = "maniskill_held_out_robots"
    version = "1"
    Options = ManiSkillRobotsOptions
    default_horizon = 100
    manifest = {"robots": {"seen": SEEN, "unseen": UNSEEN}}

    def all_cells(self) -> list[Cell]:
        return [
            Cell(self.name, task, robot, "table", "seen" if robot in SEEN else "unseen")
            for task, (robots, _, _) in CELLS.items()
            for robot in robots
        ]

    def obs_spec(self, cell: Cell) -> ObsSpec:
        from suites.maniskill_agnostic import STATE_FIELDS

        o = self.options
        return obs_spec(STATE_FIELDS, cell.robot, o.obs, o.cameras, o.image_size)

    def make_env(self, cell: Cell, horizon: int) -> EnvAdapter:
        from suites.maniskill_agnostic import AgnosticInterface

        _, obj, goal = CELLS[cell.task]
        return self._env(cell, horizon, AgnosticInterface(cell.robot, obj, goal))

    def make_expert(self, cell: Cell, env: Any) -> Policy:
        from baselines.maniskill_scripted import make_expert
        from suites.maniskill_agnostic import STATE_FIELDS

        return make_expert(cell.task, STATE_FIELDS)

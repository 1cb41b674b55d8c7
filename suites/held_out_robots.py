"""held_out_robots: RoboNet-style transfer to whole robots the policy never saw.

Task:
    robosuite `Lift` (pick the cube up) on the 7 single arms robosuite ships:
    Panda, Sawyer, IIWA, UR5e, Kinova3, Jaco, XArm7.
Split:
    seen   = Panda, Sawyer, IIWA — 7-DOF arms with parallel-jaw grippers, the kind
             that dominate public multi-robot datasets (RoboNet's Franka, Sawyer, Kuka).
    unseen = UR5e, Kinova3, Jaco, XArm7 — a 6-DOF arm (UR5e) with a Robotiq linkage
             gripper, Kinova's Gen3 and Jaco (a three-finger hand that closes ~3x
             slower), and the xArm 7 with its own gripper: new kinematics, new hands.
    A policy trained on the seen arms must transfer across kinematic structure and
    gripper mechanism, which is the RoboNet question.
Observation (the same 18 numbers on every arm):
    eef_pos (3), eef_quat_rel (4, relative to the pose at reset), gripper_opening
    (1; 1 = fully open, 0 = fully closed), object_pos (3), object_quat (4),
    gripper_to_object (3).
Action:
    robosuite's default OSC_POSE delta controller: 6 end-effector deltas in [-1, 1]
    (position deltas are world-frame on every arm) + gripper (+1 close, -1 open).
Observation with cameras (`obs=rgb` or `obs=state+rgb`):
    rgb.agentview (front view of the table) and rgb.robot0_eye_in_hand (wrist camera),
    `image_size` x `image_size` uint8; `cameras=[...]` picks others among frontview,
    birdview, agentview, sideview, robot0_robotview, robot0_eye_in_hand.
Conditions:
    nominal; perturbations via `perturb.*` act on the MuJoCo model; visual axes
    (light, camera pose, colours, textures, background, distractors) on the cameras' images.
Success:
    success_once = the cube was lifted 4 cm above the table at any step;
    success_at_end = it is still lifted at the last step (horizon 250 steps, 20 Hz).
Metric:
    success rate per (task, robot) with Wilson intervals; mean over seen and unseen
    robots with a stratified bootstrap interval; transfer gap = seen - unseen.
Policies:
    `scripted` (the reference expert, suites/lift.py) succeeds on every arm; the default,
    `bc`, is the committed behaviour-cloning checkpoint trained on the seen arms only
    (results/coverage), so the default run shows a real seen -> unseen transfer gap.
"""

from __future__ import annotations

from bench.protocols.suite import Cell
from suites.lift import LiftSuite, make_env

SEEN = ["Panda", "Sawyer", "IIWA"]
UNSEEN = ["UR5e", "Kinova3", "Jaco", "XArm7"]


class HeldOutRobots(LiftSuite):
    """Lift on 7 robosuite arms; 3 seen, 4 held out (RoboNet style)."""

    name = "held_out_robots"
    version = "1"
    default_policy = "bc"
    manifest = {"robots": {"seen": SEEN, "unseen": UNSEEN}}

    def all_cells(self) -> list[Cell]:
        return [Cell(self.name, "Lift", r, "default", "seen") for r in SEEN] + [
            Cell(self.name, "Lift", r, "default", "unseen") for r in UNSEEN
        ]

    def make_env(self, cell: Cell, horizon: int):
        return make_env(cell.task, cell.robot, horizon, options=self.options, where=cell.key)

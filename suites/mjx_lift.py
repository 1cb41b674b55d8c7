"""mjx_lift: held_out_robots' Lift on MJX, N worlds of one cell stepped in one compiled call.

Task:
    pick the cube up, as robosuite's `Lift` (held_out_robots, suites/lift.py): one of robosuite's arms (its
    robot.xml dynamics, mounted where robosuite mounts it) with a two-finger hand built here (the same on every
    arm, at the grip offset of the arm's robosuite gripper), a table and a 4 cm cube placed uniformly in
    [-3, 3] cm (x, y) with a random yaw from the episode seed. MJX steps it (`bench.sims.mjx_lift`, docs/mjx.md),
    on whatever device JAX finds.
Split (held_out_robots'):
    seen = Panda, Sawyer, IIWA; unseen = UR5e, Kinova3, Jaco, XArm7 (robosuite's arm models; their grippers are
    not: the hand is this suite's own on every arm, so the arms differ in kinematics and inertia).
Observation:
    the 18 numbers of suites/lift.py's OBS_FIELDS (eef pose, gripper opening, cube pose, gripper-to-cube).
Action:
    OSC_POSE-style deltas (3 position x 5 cm, 3 rotation x 0.5 rad) + gripper (+1 close), executed by a JAX
    controller: a damped-least-squares IK step over the arm's joints and joint impedance (`bench.sims.mjx_lift`).
Conditions:
    nominal; per world: `perturb.mass` and `perturb.friction` scale the cube's, `perturb.damping` and
    `perturb.link_mass` the arm's joints' damping and links' mass and inertia; `perturb.damping=from(CAL)` and
    `perturb.link_mass=from(CAL)` give each world its own draw of a calibration of the Panda (robosuite names,
    e.g. results/real_panda/calibration). Other model axes (friction loss: constraint rows the compiled model
    lacks; armature, gains) and the image axes are refused before the run.
Success:
    the cube's centre above table + 4 cm (robosuite Lift's `_check_success`); horizon 250 steps at 20 Hz.
    Reward: 1 while lifted (robosuite's sparse reward is 2.25).
Vectorised:
    `bench run suite=mjx_lift vector=N` makes the N envs of a cell N worlds of one batch, stepped in one call per
    control step (`bench.execution.vector.step_batches`); each world is one episode with its own record.
Policies:
    `scripted` is baselines/mjx_lift_expert.py's batched, stateless expert, in JAX (one jitted call per step).
"""

from __future__ import annotations

from typing import Any

from bench.api.mjx_lift import ACTION_NAMES, OBS_FIELDS, LiftBatch, World, check_worlds
from bench.protocols import STATE, Feature, ObsSpec, Policy
from bench.protocols.suite import Cell, SuiteBase

SEEN = ["Panda", "Sawyer", "IIWA"]
UNSEEN = ["UR5e", "Kinova3", "Jaco", "XArm7"]


class MjxLift(SuiteBase):
    """Lift on MJX on robosuite's arms; each env a world of one batch per cell."""

    name = "mjx_lift"
    version = "3"  # 3: the impedance's damping integrated implicitly (docs/mjx.md); records differ from 2's
    reference_policy = "scripted"
    default_horizon = 250
    capabilities = frozenset({"expert"})
    manifest = {"robots": {"seen": SEEN, "unseen": UNSEEN}}

    def __init__(self, options: Any = None) -> None:
        super().__init__(options)
        self._batches: dict[str, LiftBatch] = {}

    def all_cells(self) -> list[Cell]:
        return [Cell(self.name, "Lift", r, "default", "seen") for r in SEEN] + [
            Cell(self.name, "Lift", r, "default", "unseen") for r in UNSEEN
        ]

    def obs_spec(self, cell: Cell) -> ObsSpec:
        return {STATE: Feature.state(OBS_FIELDS)}

    def action_names(self, cell: Cell) -> list[str]:
        return list(ACTION_NAMES)

    def make_env(self, cell: Cell, horizon: int) -> World:
        if cell.key not in self._batches:
            self._batches[cell.key] = LiftBatch(cell.robot)
        batch = self._batches[cell.key]
        check_worlds(sum(not w.closed for w in batch.worlds) + 1, cell.robot)
        return batch.add(horizon)

    def check_worlds(self, cells: list[Cell], vector: int, workers: int) -> None:
        """Before the run: refuse (one line, with the estimate) `vector` worlds in each of `workers` workers when
        their estimated memory exceeds what this machine has free."""
        for robot in dict.fromkeys(c.robot for c in cells):
            check_worlds(vector * max(1, workers), robot, per=f"vector={vector} x workers={max(1, workers)}")

    def make_expert(self, cell: Cell, env: Any) -> Policy:
        from baselines.mjx_lift_expert import BatchLiftExpert  # the expert's module: only when it is asked for

        return BatchLiftExpert(OBS_FIELDS, len(ACTION_NAMES))

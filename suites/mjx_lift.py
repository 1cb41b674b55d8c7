"""mjx_lift: held_out_robots' Lift on MJX, N worlds of one cell stepped in one compiled call.

Task:
    pick the cube up, as robosuite's `Lift` (held_out_robots, suites/lift.py): robosuite's Panda (its robot.xml
    dynamics, `bench.sims.panda_dynamics`) with a two-finger hand built here, a table and a 4 cm cube placed
    uniformly in [-3, 3] cm (x, y) with a random yaw from the episode seed. MJX steps it (`bench.sims.mjx_lift`,
    docs/mjx.md), on whatever device JAX finds.
Split:
    seen = Panda (this slice has one arm; the held-out arms of held_out_robots are not built yet).
Observation:
    the 18 numbers of suites/lift.py's OBS_FIELDS (eef pose, gripper opening, cube pose, gripper-to-cube).
Action:
    OSC_POSE-style deltas (3 position x 5 cm, 3 rotation x 0.5 rad) + gripper (+1 close), executed by a JAX
    controller: a damped-least-squares IK step and joint impedance (`bench.sims.mjx_lift`).
Conditions:
    nominal; `perturb.mass` and `perturb.friction` scale the cube's per world; other axes are refused before the
    run (MJX worlds here carry those two fields only).
Success:
    the cube's centre above table + 4 cm (robosuite Lift's `_check_success`); horizon 250 steps at 20 Hz.
    Reward: 1 while lifted (robosuite's sparse reward is 2.25).
Vectorised:
    `bench run suite=mjx_lift vector=N` makes the N envs of a cell N worlds of one batch, stepped in one call per
    control step (`bench.execution.vector.step_batches`); each world is one episode with its own record.
Policies:
    `scripted` is baselines/mjx_lift_expert.py's batched, stateless expert.
"""

from __future__ import annotations

from typing import Any

from bench.api.mjx_lift import ACTION_NAMES, OBS_FIELDS, LiftBatch, World, check_worlds
from bench.protocols import STATE, Feature, ObsSpec, Policy
from bench.protocols.suite import Cell, SuiteBase


class MjxLift(SuiteBase):
    """Lift on MJX; each env a world of one batch per cell."""

    name = "mjx_lift"
    version = "1"
    reference_policy = "scripted"
    default_horizon = 250
    capabilities = frozenset({"expert"})
    manifest = {"robots": {"seen": ["Panda"], "unseen": []}}

    def __init__(self, options: Any = None) -> None:
        super().__init__(options)
        self._batches: dict[str, LiftBatch] = {}

    def all_cells(self) -> list[Cell]:
        return [Cell(self.name, "Lift", "Panda", "default", "seen")]

    def obs_spec(self, cell: Cell) -> ObsSpec:
        return {STATE: Feature.state(OBS_FIELDS)}

    def action_names(self, cell: Cell) -> list[str]:
        return list(ACTION_NAMES)

    def make_env(self, cell: Cell, horizon: int) -> World:
        if cell.key not in self._batches:
            self._batches[cell.key] = LiftBatch()
        batch = self._batches[cell.key]
        check_worlds(len(batch.worlds) + 1)
        return batch.add(horizon)

    def make_expert(self, cell: Cell, env: Any) -> Policy:
        from baselines.mjx_lift_expert import BatchLiftExpert  # the expert's module: only when it is asked for

        return BatchLiftExpert(OBS_FIELDS, len(ACTION_NAMES))

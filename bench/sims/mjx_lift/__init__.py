"""Lift on MJX: robosuite's arms (their robot.xml dynamics), a two-finger hand, a table and a cube, N worlds per call.

`scene` builds the model of one arm (`ARMS`: Panda, Sawyer, IIWA, UR5e, Kinova3, Jaco, XArm7), `control` compiles
its batched control step (a JAX DLS-IK + joint impedance controller around `mjx.step`, the observation computed in
the same call), `batch` holds N worlds of one arm in numpy (`LiftBatch`) and exposes each as a bench env adapter
(`World`), with per-world model axes and calibration draws. docs/mjx.md has the figures.
"""

from bench.sims.mjx_lift.batch import (
    ACTION_NAMES,
    AXES,
    OBS_FIELDS,
    LiftBatch,
    World,
    check_worlds,
    memory_estimate,
)
from bench.sims.mjx_lift.scene import ARMS, LIFT_HEIGHT, SUBSTEPS, TABLE_Z, TIMESTEP

__all__ = [
    "ACTION_NAMES",
    "ARMS",
    "AXES",
    "LIFT_HEIGHT",
    "OBS_FIELDS",
    "SUBSTEPS",
    "TABLE_Z",
    "TIMESTEP",
    "LiftBatch",
    "World",
    "check_worlds",
    "memory_estimate",
]

"""The arm's own dynamics for its servos' calibration: the suite's MJCF of the robot, and the servo law written
into it.

The law of `bench.calibrate.servo.law` with Coulomb and viscous friction is exactly what a MuJoCo position
actuator and the joint's passive terms compute, so the arm's servos are realised in the model's own fields and
every simulator of the harness (MuJoCo CPU, `mujoco.rollout`, MJX) runs them unchanged:

    duty = clip(error_gain * kp * (goal - q), +-max_duty); tau = kt_over_r * (vin * duty - kt * dq) - friction
    stiffness  K = kt_over_r * vin * error_gain * kp  -> actuator_gainprm[0] = K, actuator_biasprm[1] = -K
    max torque F = kt_over_r * vin * max_duty         -> actuator_forcerange = +-F (the duty's clip)
    damping    D = kt_over_r * kt + viscous           -> dof_damping (back-EMF and viscous friction: one term
                                                         from positions alone)
    Coulomb    C                                      -> dof_frictionloss (sticks and slides as BAM's budget)
    armature   A                                      -> dof_armature (the rotor's inertia through the gears)

The firmware's kp is reported as K / torque_per_kp (the spec's `firmware.torque_per_kp`). Stribeck,
load-dependent friction and backlash have no model field: the arm's calibration leaves them out; a transport delay
is found by the loop (`bench.calibrate.servo.arm.loop`) and carried by `apply.delay_steps`, not written here.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from typing import Any

import mujoco
import numpy as np

from bench.calibrate.apply import CalibrationEdit, robot_hash
from bench.core.errors import DataError
from bench.protocols import registry

KINDS = ("stiffness", "damping", "coulomb", "armature")  # the fitted parameters of each servo, in this order
UNITS = {"stiffness": "N·m/rad", "damping": "N·m·s/rad", "coulomb": "N·m", "armature": "kg·m²"}


@dataclass(frozen=True)
class ArmServos:
    """Every servo of an arm: one value per joint (model order) of each parameter."""

    stiffness: np.ndarray  # K, N·m/rad
    damping: np.ndarray  # D, N·m·s/rad
    coulomb: np.ndarray  # C, N·m
    armature: np.ndarray  # A, kg·m²
    max_torque: np.ndarray  # F, N·m (declared: the duty's clip)

    def vector(self) -> np.ndarray:
        """The fitted parameters as one vector: kind-major (all stiffnesses, then dampings, ...)."""
        return np.concatenate([getattr(self, k) for k in KINDS])

    def with_vector(self, x: np.ndarray) -> ArmServos:
        parts = np.split(np.asarray(x, np.float64), len(KINDS))
        return replace(self, **{k: p.copy() for k, p in zip(KINDS, parts)})


@dataclass
class Arm:
    """A suite's robot as the calibration simulates it: its model (contacts off), joints and declared servos."""

    suite: str
    robot: str
    model: mujoco.MjModel  # the suite's scene with contacts disabled: the arm moves in free space
    nominal: mujoco.MjModel  # the suite's model as built (what a run's env holds; `robot_hash` of it)
    joints: tuple[str, ...]  # model order: the actuated joints
    qadr: np.ndarray
    dadr: np.ndarray
    actuators: np.ndarray
    limits: np.ndarray  # (J, 2) rad
    substeps: int  # physics steps per frame of the suite's control rate
    fps: float
    robot_hash: str

    def declared(self) -> ArmServos:
        m = self.nominal
        return ArmServos(
            stiffness=m.actuator_gainprm[self.actuators, 0].copy(),
            damping=m.dof_damping[self.dadr].copy(),
            coulomb=m.dof_frictionloss[self.dadr].copy(),
            armature=m.dof_armature[self.dadr].copy(),
            max_torque=m.actuator_forcerange[self.actuators, 1].copy(),
        )

    def realise(self, model: mujoco.MjModel, servos: ArmServos) -> None:
        """Write `servos` into `model` (a copy of this arm's model), as the module docstring maps them."""
        model.actuator_gainprm[self.actuators, 0] = servos.stiffness
        model.actuator_biasprm[self.actuators, 1] = -servos.stiffness
        model.actuator_forcerange[self.actuators, 0] = -servos.max_torque
        model.actuator_forcerange[self.actuators, 1] = servos.max_torque
        model.dof_damping[self.dadr] = servos.damping
        model.dof_frictionloss[self.dadr] = servos.coulomb
        model.dof_armature[self.dadr] = servos.armature

    def with_servos(self, servos: ArmServos) -> mujoco.MjModel:
        model = copy.copy(self.model)
        self.realise(model, servos)
        return model


def load_arm(suite_name: str) -> Arm:
    """The arm of `suite_name`'s robot, from the suite's first cell's env (its model as a run builds it)."""
    suite = registry.make_suite(suite_name)
    cell = suite.all_cells()[0]
    env = suite.make_env(cell, suite.default_horizon)
    try:
        if env.mujoco is None:
            raise DataError(f"suite {suite_name!r}: its env has no MuJoCo model to calibrate servos in")
        nominal = copy.copy(env.mujoco.model)
        fps = float(getattr(env, "fps", 0.0) or 0.0)
    finally:
        env.close()
    joints = tuple(suite.action_names(cell) or ())
    ids = [mujoco.mj_name2id(nominal, mujoco.mjtObj.mjOBJ_JOINT, j) for j in joints]
    acts = [mujoco.mj_name2id(nominal, mujoco.mjtObj.mjOBJ_ACTUATOR, j) for j in joints]
    if min(ids) < 0 or min(acts) < 0:
        raise DataError(f"suite {suite_name!r}: its actions ({', '.join(joints)}) are not joints with actuators")
    if fps <= 0:
        raise DataError(f"suite {suite_name!r}: its env declares no control rate (fps)")
    model = copy.copy(nominal)
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    substeps = round(1.0 / fps / model.opt.timestep)
    return Arm(
        suite=suite_name,
        robot=cell.robot,
        model=model,
        nominal=nominal,
        joints=joints,
        qadr=nominal.jnt_qposadr[ids].copy(),
        dadr=nominal.jnt_dofadr[ids].copy(),
        actuators=np.array(acts),
        limits=nominal.jnt_range[ids].copy(),
        substeps=substeps,
        fps=fps,
        robot_hash=robot_hash(nominal, list(joints)),
    )


def servo_edits(arm: Arm, servos: ArmServos) -> list[CalibrationEdit]:
    """The `apply` section's model edits that run `servos` on the arm (every joint's, nominal values beside)."""
    m = arm.nominal
    out: list[CalibrationEdit] = []
    for j, name in enumerate(arm.joints):
        a, d = int(arm.actuators[j]), int(arm.dadr[j])
        k = float(servos.stiffness[j])
        out.append(
            {
                "field": "actuator_gainprm",
                "element": name,
                "column": 0,
                "nominal": float(m.actuator_gainprm[a, 0]),
                "value": k,
            }
        )
        out.append(
            {
                "field": "actuator_biasprm",
                "element": name,
                "column": 1,
                "nominal": float(m.actuator_biasprm[a, 1]),
                "value": -k,
            }
        )
        for field, kind in (("dof_damping", "damping"), ("dof_frictionloss", "coulomb"), ("dof_armature", "armature")):
            out.append(
                {
                    "field": field,
                    "element": name,
                    "nominal": float(getattr(m, field)[d]),
                    "value": float(getattr(servos, kind)[j]),
                }
            )
    return out


FIELDS = {
    "stiffness": "actuator_gainprm",
    "damping": "dof_damping",
    "coulomb": "dof_frictionloss",
    "armature": "dof_armature",
}


def draw_keys(arm: Arm, kinds: tuple[str, ...] = KINDS) -> list[str]:
    """The `draws` section's keys (`perturb.AXIS=from(...)`) of the fitted `kinds`: field:joint[:column]."""
    keys = []
    for kind in kinds:
        keys += [f"{FIELDS[kind]}:{j}:0" if kind == "stiffness" else f"{FIELDS[kind]}:{j}" for j in arm.joints]
    if "stiffness" in kinds:
        keys += [f"actuator_biasprm:{j}:1" for j in arm.joints]  # a position servo's bias follows its gain
    return keys


def draw_row(servos: ArmServos, kinds: tuple[str, ...] = KINDS) -> list[float]:
    """One draw in `draw_keys` order."""
    row = [float(v) for kind in kinds for v in getattr(servos, kind)]
    return row + ([float(-k) for k in servos.stiffness] if "stiffness" in kinds else [])


def describe(arm: Arm, servos: ArmServos, torque_per_kp: float) -> dict[str, dict[str, Any]]:
    """Per joint: the firmware's kp and every parameter in its unit."""
    return {
        j: {
            "kp": float(servos.stiffness[i] / torque_per_kp),
            **{k: float(getattr(servos, k)[i]) for k in KINDS},
            "max_torque": float(servos.max_torque[i]),
        }
        for i, j in enumerate(arm.joints)
    }

"""The servo in MuJoCo CPU: a force computed every physics step, not a custom actuator.

Before each `mj_step` the law (`bench.calibrate.servo.law`) is evaluated from `data.qpos`/`data.qvel`: the motor
torque goes into `data.qfrc_applied[dof]` and the gearbox's friction budget into `model.dof_frictionloss[dof]`
(MuJoCo's friction-loss constraint then sticks and slides as BAM's budget does; BAM's own MuJoCo binding does the
same). Why not a custom actuator: MuJoCo's user actuator callbacks (`mjcb_act_gain`/`mjcb_act_bias`) are process
globals that every model shares and that `mujoco.rollout` threads would call from C; and the budget is a friction
loss, which no actuator can set. The load's inertia and gravity are the model's own.

Backlash is not realised here (the fit's simulator has it; an arm's play goes through `bench.calibrate.play`).
"""

from __future__ import annotations

import mujoco
import numpy as np

from bench.calibrate.servo.law import GRAVITY, ServoParams, duty, friction_budget, gravity_torque, motor_torque
from bench.core.errors import SpecError


class ServoActuator:
    """The law on one dof of a MuJoCo model, applied by `before_step` ahead of every `mj_step`."""

    def __init__(self, params: ServoParams, dof: int) -> None:
        if params.play > 0:
            raise SpecError(f"servo play {params.play:g} rad: backlash is not realised in MuJoCo CPU; fit without it")
        self.p = params
        self.dof = dof

    def before_step(self, model: mujoco.MjModel, data: mujoco.MjData, goal: float, enable: float, vin: float) -> float:
        """Write the motor torque and the friction budget for the coming step; returns the motor torque."""
        q, dq = float(data.qpos[self.dof]), float(data.qvel[self.dof])
        tm = float(motor_torque(self.p, duty(self.p, goal, q), vin, dq, enable))
        te = float(gravity_torque(self.p, q))
        data.qfrc_applied[self.dof] = tm
        model.dof_frictionloss[self.dof] = float(friction_budget(self.p, dq, tm, te))
        return tm


def pendulum(p: ServoParams, dt: float) -> mujoco.MjModel:
    """The bench as the fit sees it: a hinge about y (q = 0 hanging down) carrying a point mass whose m·g·l and
    m·l² are the fitted gravity torque and inertia (its encoder offset as the mass's angle)."""
    length = p.inertia * GRAVITY / max(p.gravity, 1e-9)
    mass = p.gravity / (GRAVITY * length)
    x, z = -length * np.sin(p.offset), -length * np.cos(p.offset)
    xml = f"""<mujoco><option timestep="{dt}" integrator="Euler"/><worldbody><body name="arm">
      <joint name="servo" type="hinge" axis="0 1 0" damping="0"/>
      <geom type="sphere" size="0.001" pos="{x} 0 {z}" mass="{mass}" contype="0" conaffinity="0"/>
    </body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    model.body_inertia[1] = 1e-12  # a point mass: m·l² is the whole inertia about the hinge
    return model


def simulate_run(
    p: ServoParams,
    goal: np.ndarray,
    enable: np.ndarray,
    vin: np.ndarray,
    q0: float,
    dq0: float,
    fps: float,
    substeps: int,
) -> np.ndarray:
    """A whole run in MuJoCo CPU from a logged state under the logged goal (frame rate `fps`): positions per frame."""
    dt = 1.0 / (fps * substeps)
    model = pendulum(p, dt)
    data = mujoco.MjData(model)
    data.qpos[0], data.qvel[0] = q0, dq0
    servo = ServoActuator(p, 0)
    t = np.arange(goal.size) / fps
    out = np.empty(goal.size - 1)
    for k in range(goal.size - 1):
        for s in range(substeps):
            tt = (k + s / substeps) / fps
            g = float(np.interp(max(tt - p.delay, 0.0), t, goal))
            servo.before_step(model, data, g, float(enable[k]), float(vin[k]))
            mujoco.mj_step(model, data)
        out[k] = data.qpos[0]
    return out

"""The servo in MuJoCo CPU: a force computed every physics step, not a custom actuator.

Before each `mj_step` the law (`bench.calibrate.servo.law`) is evaluated from `data.qpos`/`data.qvel`: the motor
torque goes into `data.qfrc_applied[dof]` and the gearbox's friction budget into `model.dof_frictionloss[dof]`
(MuJoCo's friction-loss constraint then sticks and slides as BAM's budget does; BAM's own MuJoCo binding does the
same). Why not a custom actuator: MuJoCo's user actuator callbacks (`mjcb_act_gain`/`mjcb_act_bias`) are process
globals that every model shares and that `mujoco.rollout` threads would call from C; and the budget is a friction
loss, which no actuator can set. The load's inertia and gravity are the model's own.

Backlash: the motor side of the play is a state of the actuator (position and velocity of the rotor, its share of
the inertia), integrated with the same contact torque as `bench.calibrate.servo.sim` at either end of the gap; that
torque, not the motor's, is what reaches the output joint through `qfrc_applied` (the model's link then carries the
rest of the inertia). The firmware's goal velocity limit is a state too (its internal target), reset to the measured
position while the torque is off.
"""

from __future__ import annotations

import mujoco
import numpy as np

from bench.calibrate.servo.law import (
    GRAVITY,
    ServoParams,
    coupling,
    duty,
    friction_budget,
    goal_step,
    gravity_torque,
    motor_torque,
    play_side,
    play_torque,
)


class ServoActuator:
    """The law on one dof of a MuJoCo model, applied by `before_step` ahead of every `mj_step` of length `dt`."""

    def __init__(self, params: ServoParams, dof: int, dt: float) -> None:
        self.p = params
        self.dof = dof
        self.dt = dt
        self.target: float | None = None  # the firmware's internal target (goal velocity limit)
        self.qm: float | None = None  # rotor position and velocity (play only)
        self.dqm = 0.0

    def _goal(self, goal: float, q: float, enable: float) -> float:
        if self.p.goal_slowness <= 0:
            return goal
        if self.target is None or enable < 0.5:
            self.target = goal if enable >= 0.5 else q
        else:
            self.target = float(goal_step(self.p, self.target, goal, self.dt))
        return self.target

    def before_step(self, model: mujoco.MjModel, data: mujoco.MjData, goal: float, enable: float, vin: float) -> float:
        """Write the torque reaching the output and the friction budget for the coming step; returns it."""
        p = self.p
        q, dq = float(data.qpos[self.dof]), float(data.qvel[self.dof])
        d = duty(p, self._goal(goal, q, enable), q)
        te = float(gravity_torque(p, q))
        if p.play > 0:
            half = 0.5 * p.play
            if self.qm is None:  # against the end the motor pushes on (or gravity, at rest), as in sim.py
                side = float(play_side(d, te))
                self.qm, self.dqm = q + side * half, dq
            c = coupling(p, self.dt)
            tm = float(motor_torque(p, d, vin, self.dqm, enable))
            tau = float(play_torque(c, self.qm, q, self.dqm, dq, half))
            self.dqm += (tm - tau) / (p.rotor_share * p.inertia) * self.dt
            self.qm += self.dqm * self.dt
        else:
            tau = float(motor_torque(p, d, vin, dq, enable))
        data.qfrc_applied[self.dof] = tau
        model.dof_frictionloss[self.dof] = float(friction_budget(p, dq, tau, te))
        return tau


def pendulum_xml(p: ServoParams, dt: float, frictionloss: float = 0.0) -> str:
    """The bench as the fit sees it: a hinge about y (q = 0 hanging down) carrying a point mass whose m·g·l and
    m·l² are the fitted gravity torque and the output's inertia (all of it; without the rotor's share with play),
    its encoder offset as the mass's angle. `frictionloss` > 0 makes MJX allocate the friction-loss row."""
    inertia = p.inertia * (1.0 - p.rotor_share) if p.play > 0 else p.inertia
    length = inertia * GRAVITY / max(p.gravity, 1e-9)
    mass = p.gravity / (GRAVITY * length)
    x, z = -length * np.sin(p.offset), -length * np.cos(p.offset)
    return f"""<mujoco><option timestep="{dt}" integrator="Euler"/><worldbody><body name="arm">
      <joint name="servo" type="hinge" axis="0 1 0" damping="0" frictionloss="{frictionloss}"/>
      <geom type="sphere" size="0.001" pos="{x} 0 {z}" mass="{mass}" contype="0" conaffinity="0"/>
    </body></worldbody></mujoco>"""


def pendulum(p: ServoParams, dt: float) -> mujoco.MjModel:
    """The pendulum of `pendulum_xml` as a MuJoCo model."""
    model = mujoco.MjModel.from_xml_string(pendulum_xml(p, dt))
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
    servo = ServoActuator(p, 0, dt)
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

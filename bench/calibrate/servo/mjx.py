"""The servo in MJX (MuJoCo's JAX backend): the same law as MuJoCo CPU (`bench.calibrate.servo.mujoco`), a force
computed inside every traced physics step, not a custom actuator.

Each substep of a `jax.lax.scan` evaluates `law.py` with `xp=jax.numpy` from the traced `qpos`/`qvel`: the torque
that reaches the output goes into `qfrc_applied`, the gearbox's friction budget into the model's `dof_frictionloss`
(MJX allocates the friction-loss row only for a dof whose friction loss is positive when the model is put on the
device, so the pendulum is built with a negligible one, 1e-9 N·m). The firmware's internal target (goal velocity
limit) and the rotor across the play are carried states of the scan, integrated as in `mujoco.py`. Why not a custom
actuator: MJX has no user-actuator callbacks at all, and no actuator sets a friction loss.

Float32 (JAX's default): trajectories agree with MuJoCo CPU to about 1e-4 rad over a few seconds on the bench
pendulum (`tests/test_servo_sims.py`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from bench.calibrate.servo.law import (
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
from bench.calibrate.servo.mujoco import pendulum_xml

MJX_FRICTIONLOSS = 1e-9  # N·m: the friction-loss row exists in MJX only when this is > 0 at put_model


def simulate_run_mjx(
    p: ServoParams,
    goal: np.ndarray,
    enable: np.ndarray,
    vin: np.ndarray,
    q0: float,
    dq0: float,
    fps: float,
    substeps: int,
) -> np.ndarray:
    """A whole run in MJX, as `mujoco.simulate_run` does it on the CPU: positions per frame (frames 1..N-1)."""
    dt = 1.0 / (fps * substeps)
    model = mujoco.MjModel.from_xml_string(pendulum_xml(p, dt, MJX_FRICTIONLOSS))
    model.body_inertia[1] = 1e-12  # a point mass, as in mujoco.pendulum
    mx = mjx.put_model(model)
    d0 = mjx.make_data(mx).replace(qpos=jnp.array([q0]), qvel=jnp.array([dq0]))
    frames = goal.size - 1
    tt = np.arange(frames * substeps) / (fps * substeps)
    t = np.arange(goal.size) / fps
    g = np.interp(np.maximum(tt - p.delay, 0.0), t, goal)
    k = np.arange(frames * substeps) // substeps
    inputs = (jnp.asarray(g), jnp.asarray(enable[k]), jnp.asarray(vin[k]))
    target0 = float(g[0]) if enable[0] >= 0.5 else q0
    half = 0.5 * p.play
    d_first = float(duty(p, target0 if p.goal_slowness > 0 else g[0], q0))
    side = float(play_side(d_first, float(gravity_torque(p, q0))))
    c = coupling(p, dt) if p.play > 0 else None
    j_m = p.rotor_share * p.inertia

    def substep(
        carry: tuple[mjx.Data, jax.Array, jax.Array, jax.Array], u: tuple[jax.Array, jax.Array, jax.Array]
    ) -> tuple[tuple[mjx.Data, jax.Array, jax.Array, jax.Array], jax.Array]:
        d, target, qm, dqm = carry
        gs, en, v = u
        q, dq = d.qpos[0], d.qvel[0]
        if p.goal_slowness > 0:
            target = jnp.where(en >= 0.5, goal_step(p, target, gs, dt, xp=jnp), q)
            gs = target
        du = duty(p, gs, q, xp=jnp)
        te = gravity_torque(p, q, xp=jnp)
        if c is not None:
            tm = motor_torque(p, du, v, dqm, en)
            tau = play_torque(c, qm, q, dqm, dq, half, xp=jnp)
            dqm = dqm + (tm - tau) / j_m * dt
            qm = qm + dqm * dt
        else:
            tau = motor_torque(p, du, v, dq, en)
        budget = friction_budget(p, dq, tau, te, xp=jnp)
        m = mx.replace(dof_frictionloss=jnp.maximum(budget, MJX_FRICTIONLOSS)[None])
        d = mjx.step(m, d.replace(qfrc_applied=d.qfrc_applied.at[0].set(tau)))
        return (d, target, qm, dqm), d.qpos[0]

    carry0 = (d0, jnp.asarray(target0), jnp.asarray(q0 + side * half), jnp.asarray(dq0))
    _, qs = jax.jit(lambda c0, us: jax.lax.scan(substep, c0, us))(carry0, inputs)
    return np.asarray(qs)[substeps - 1 :: substeps]

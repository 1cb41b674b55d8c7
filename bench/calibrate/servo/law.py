"""The servo's torque law: a position servo's firmware P controller, its DC motor with back-EMF, and the friction
budget of its gearbox (BAM's family, Duclusaud et al. 2025), written once for every simulator.

The law is a function of the state, so a simulator applies it as a generalised force computed every physics step
(never a precomputed command): `bench.calibrate.servo.sim` (the fit's batched windows), `bench.calibrate.servo.
mujoco` (MuJoCo CPU, `qfrc_applied` and the friction budget written into `dof_frictionloss` before each step) and
any array library with numpy's names (`xp`: numpy, or `jax.numpy` inside a traced MJX step).

Units: positions rad, velocities rad/s, torques N·m, volts V; the duty cycle is a share of the supply in [-1, 1].
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from types import ModuleType
from typing import Any

import numpy as np

GRAVITY = 9.80665  # m/s², the gravity the pendulum's torque m·g·l is divided by


@dataclass(frozen=True)
class ServoParams:
    """Every parameter of one servo driving one load (a pendulum on the bench, a link of an arm).

    The declared servo is the first block (its firmware and motor, the load's inertia and gravity); the
    effects of the library (`bench.calibrate.servo.effects`) are the second block: each is absent at zero.
    """

    # the firmware's P controller: duty = clip(error_gain * kp * (goal - q), -max_duty, max_duty)
    kp: Any = 1.0  # firmware gain in the servo's own units (one per run: an array over windows)
    error_gain: float = 1.0  # duty per rad per unit of kp (the firmware's scaling: encoder counts, divisor, PWM range)
    max_duty: float = 1.0  # the PWM limit, a share of the supply
    # the DC motor: torque = kt_over_r * (vin * duty - kt * dq), only while the torque is enabled
    kt_over_r: float = 0.1  # N·m/V: stall torque per volt (the torque scale; declared, not identifiable from positions)
    kt: float = 0.4  # V·s/rad: back-EMF constant (torque constant, N·m/A)
    # the load: inertia at the output (rotor armature included) and gravity torque amplitude m·g·l
    inertia: float = 0.005  # kg·m²
    gravity: float = 0.5  # N·m; gravity torque = -gravity * sin(q + offset), q = 0 hanging down
    offset: float = 0.0  # rad, the encoder's zero against the vertical
    # effects (zero: absent)
    coulomb: float = 0.0  # N·m, friction at every velocity
    viscous: float = 0.0  # N·m·s/rad, mechanical viscous friction (also while the torque is off)
    stribeck: float = 0.0  # N·m, extra friction at rest, gone above the Stribeck velocity
    stribeck_velocity: float = 0.2  # rad/s
    stribeck_alpha: float = 2.0  # shape exponent of the Stribeck curve
    load_friction: float = 0.0  # friction per N·m of torque through the gears, |tau_ext - tau_motor| (BAM m3)
    play: float = 0.0  # rad, backlash (total width) between motor and output
    rotor_share: float = 0.3  # share of the inertia on the motor side of the play (only with play)
    delay: float = 0.0  # s, transport delay of the goal position
    # the firmware's goal velocity limit (Feetech: the internal target moves at most max velocity toward the goal;
    # BAM's STS3215 model, `q_target_smooth`); as its inverse so that zero is absent
    goal_slowness: float = 0.0  # s/rad, 1 / the largest velocity of the firmware's internal target

    def with_(self, **changes: Any) -> ServoParams:
        """A copy with some parameters changed."""
        return replace(self, **changes)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = np.asarray(v).tolist() if np.ndim(v) else float(v)
        return out


def duty(p: ServoParams, goal: Any, q: Any, xp: ModuleType = np) -> Any:
    """The firmware's P controller: PWM duty from the position error, clipped at the PWM limit."""
    return xp.clip(p.error_gain * p.kp * (goal - q), -p.max_duty, p.max_duty)


def goal_step(p: ServoParams, target: Any, goal: Any, dt: float, xp: ModuleType = np) -> Any:
    """The firmware's internal target after a step `dt`: toward the goal at most 1/goal_slowness rad/s (the goal
    itself when the limit is absent). While the torque is off the caller resets it to the measured position."""
    reach = dt / xp.maximum(p.goal_slowness, 1e-12)
    return xp.clip(goal, target - reach, target + reach)


def motor_torque(p: ServoParams, d: Any, vin: Any, dq_motor: Any, enable: Any) -> Any:
    """Torque of the DC motor at the output: kt/R (V - kt dq); zero when the torque is disabled (H-bridge off)."""
    return enable * p.kt_over_r * (vin * d - p.kt * dq_motor)


def gravity_torque(p: ServoParams, q: Any, xp: ModuleType = np) -> Any:
    """The pendulum's gravity torque (q = 0 hanging down, BAM's convention)."""
    return -p.gravity * xp.sin(q + p.offset)


def friction_budget(p: ServoParams, dq: Any, tau_motor: Any, tau_ext: Any, xp: ModuleType = np) -> Any:
    """Largest friction torque the gearbox can oppose now: Coulomb + viscous + Stribeck + load-dependent.

    BAM's formulation: friction holds any torque up to this budget (sticking) and opposes sliding with it.
    """
    budget = p.coulomb + p.viscous * xp.abs(dq)
    budget = budget + p.stribeck * xp.exp(-(xp.abs(dq / p.stribeck_velocity) ** p.stribeck_alpha))
    return budget + p.load_friction * xp.abs(tau_ext - tau_motor)


def friction(budget: Any, tau_stop: Any, xp: ModuleType = np) -> Any:
    """Friction torque: the torque that would stop the output within the step, clipped to the budget."""
    return -xp.sign(tau_stop) * xp.minimum(xp.abs(tau_stop), budget)


@dataclass(frozen=True)
class Coupling:
    """The play between motor and output as a stiff contact at either end of the gap (only with play > 0)."""

    stiffness: Any  # N·m/rad (an array for a batch of parameter sets)
    damping: Any  # N·m·s/rad


def coupling(p: ServoParams, dt: float) -> Coupling:
    """Contact stiffness and damping of the play's ends for a step `dt`: stiff (period 25 steps) and well damped."""
    j_m = p.rotor_share * p.inertia
    j_l = (1.0 - p.rotor_share) * p.inertia
    mu = j_m * j_l / np.maximum(j_m + j_l, 1e-12)
    w = 0.25 / dt
    return Coupling(mu * w * w, 2.0 * 0.7 * mu * w)


def dead_zone(x: Any, half: float, xp: ModuleType = np) -> Any:
    """x beyond +-half (the compression of the play's contact)."""
    return xp.sign(x) * xp.maximum(xp.abs(x) - half, 0.0)


def play_side(d: Any, te: Any, xp: ModuleType = np) -> Any:
    """The end of the play the motor starts against: the one its duty pushes on, or gravity's when it does not push."""
    return xp.where(xp.abs(d) > 1e-6, xp.sign(d), -xp.sign(te))


def play_torque(c: Coupling, qm: Any, q: Any, dqm: Any, dq: Any, half: Any, xp: ModuleType = np) -> Any:
    """Torque through the play: none inside the gap, the stiff damped contact of `c` at either end."""
    comp = dead_zone(qm - q, half, xp)
    return c.stiffness * comp + c.damping * (dqm - dq) * (comp != 0)

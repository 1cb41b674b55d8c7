"""The servo's effect library: each family one row (`ServoEffect`), nested like the arm library's
(`bench.calibrate.effects`): with its amplitude parameters at zero the servo is exactly the declared one.

The declared servo (`DECLARED`) is BAM's electrical model without friction: the firmware's P gain per gain
setting, the back-EMF constant, the load's inertia, its gravity torque and the encoder's zero. The families add
what a log may need: Coulomb, viscous, Stribeck and load-dependent friction (BAM's M1-M3 terms), backlash, the
firmware's goal velocity limit (BAM's Feetech model) and a transport delay. Bounds scale with the servo:
`Scale.torque` is its stall torque at the logged supply.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Scale:
    """The servo's magnitudes that bound its parameters."""

    torque: float  # N·m, stall torque at the logged supply (kt/R x vin x max duty)
    velocity: float  # rad/s, spread of the logged velocity
    inertia: float  # kg·m², the declared fit's inertia
    dt: float  # s, log frame period


@dataclass(frozen=True)
class Param:
    """One fitted parameter: the `ServoParams` field it sets, its unit, bounds and start."""

    field: str
    unit: str
    bounds: Callable[[Scale], tuple[float, float]]
    start: Callable[[Scale], float] = lambda s: 0.0
    bam: str = ""  # the name of the same quantity in BAM's parameter files, when it has one


@dataclass(frozen=True)
class ServoEffect:
    """One family: parameters (the first `nested` are amplitudes: zero = absent), what it models."""

    name: str
    params: tuple[Param, ...]
    doc: str
    nested: int = 1

    @property
    def gated(self) -> tuple[str, ...]:
        """Amplitude parameters whose interval must exclude zero for the family to be added."""
        return tuple(p.field for p in self.params[: self.nested])


def _torque(share: float) -> Callable[[Scale], tuple[float, float]]:
    return lambda s: (0.0, share * s.torque)


SERVO_EFFECTS: dict[str, ServoEffect] = {
    e.name: e
    for e in [
        ServoEffect(
            "coulomb_friction",
            (Param("coulomb", "N·m", _torque(0.3), bam="friction_base"),),
            "dry friction of constant magnitude in the gearbox (sticking at rest; BAM M1)",
        ),
        ServoEffect(
            "viscous_friction",
            (
                Param(
                    "viscous",
                    "N·m·s/rad",
                    lambda s: (0.0, 0.3 * s.torque / max(s.velocity, 1e-6)),
                    bam="friction_viscous",
                ),
            ),
            "mechanical friction proportional to velocity, also while the torque is off (BAM M1)",
        ),
        ServoEffect(
            "stribeck_friction",
            (
                Param("stribeck", "N·m", _torque(0.3), bam="friction_stribeck"),
                Param("stribeck_velocity", "rad/s", lambda s: (0.02, 5.0), lambda s: 0.5, bam="dtheta_stribeck"),
                Param("stribeck_alpha", "1", lambda s: (0.5, 10.0), lambda s: 2.0, bam="alpha"),
            ),
            "friction higher at rest, falling to its sliding level above the Stribeck velocity (BAM M2)",
        ),
        ServoEffect(
            "load_friction",
            (Param("load_friction", "1", lambda s: (0.0, 0.5), bam="load_friction_base"),),
            "friction growing with the torque through the gears, |tau_ext - tau_motor| (BAM M3)",
        ),
        ServoEffect(
            "backlash",
            (
                Param("play", "rad", lambda s: (0.0, 0.1)),
                Param("rotor_share", "1", lambda s: (0.05, 0.9), lambda s: 0.3),
            ),
            "play between motor and output (total width); the encoder reads the output, the rotor crosses the gap",
        ),
        ServoEffect(
            "goal_velocity_limit",
            (Param("goal_slowness", "s/rad", lambda s: (0.0, 2.0), bam="1/max_velocity"),),
            "the firmware moves its internal target toward the goal at a limited velocity (Feetech STS: BAM's "
            "max_velocity, 3400 steps/s = 5.2 rad/s by default); as its inverse, zero absent",
        ),
        ServoEffect(
            "delay",
            (Param("delay", "s", lambda s: (0.0, max(0.1, 10 * s.dt))),),
            "transport delay between the goal written and the goal the firmware acts on",
        ),
    ]
}

# the declared servo's parameters (besides one gain per gain setting, `kp`)
DECLARED: tuple[Param, ...] = (
    Param("inertia", "kg·m²", lambda s: (1e-6, 10.0), bam="armature"),
    Param("gravity", "N·m", lambda s: (0.0, 5.0 * s.torque)),
    Param("offset", "rad", lambda s: (-0.5, 0.5), bam="q_offset"),
    Param("kt", "V·s/rad", lambda s: (0.0, 20.0), bam="kt"),
)
KP_UNIT = "firmware units"


def scale_of(torque: float, velocity: np.ndarray, inertia: float, dt: float) -> Scale:
    return Scale(float(torque), float(np.std(velocity)), float(inertia), float(dt))

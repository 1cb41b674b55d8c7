"""The library of physical effects a declared model may be missing.

Every effect is *nested*: with its amplitude parameters at zero the model is exactly the declared
one, so switching an effect on from zero is a small, well-defined change (its signature). Each effect
attaches to one target (a joint, an actuator or a body) and is realised in the simulation itself:

- through `MjModel` fields where MuJoCo has one (friction loss, damping, stiffness, armature,
  body mass, actuator gain), so `mujoco.rollout` runs them at full speed;
- through the model's structure for backlash as position play: a rotor behind a dead zone in
  position, built into the MJCF (`bench.calibrate.play`);
- through the applied command where the effect acts on the drive (delay, deadband, saturation),
  transformed before the rollout at the simulator's substep resolution;
- through `qfrc_applied` for generalised forces (bias, a known extra input, the offset part of
  asymmetric friction), constant or precomputed;
- only the Stribeck excess depends on the simulated velocity: it is added to `qfrc_applied` at
  every substep in a stepped rollout (see `bench.replay.simulate`).

Bounds are scaled to the system from the logs (`Scales`), so one library serves a 1 kg arm and a
95 kg carriage; a spec can override them per effect.

The package: `row` (one family as one row, and what it attaches to), `transforms` (the command and friction
transforms the rollouts and the generator share), `library` (the families themselves: `EFFECTS`, `MERGES`);
this face re-exports the names their callers use.
"""

from bench.calibrate.effects.library import EFFECTS, MERGES, saturation_limit
from bench.calibrate.effects.row import SIGNATURE_LEVELS, Bounds, Builder, Effect, Scales, Target, signature_steps
from bench.calibrate.effects.transforms import deadband, saturate, stribeck_force

__all__ = [
    "EFFECTS",
    "MERGES",
    "SIGNATURE_LEVELS",
    "Bounds",
    "Builder",
    "Effect",
    "Scales",
    "Target",
    "deadband",
    "saturate",
    "saturation_limit",
    "signature_steps",
    "stribeck_force",
]

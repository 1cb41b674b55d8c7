"""robosuite's Panda arm as a dynamics-only MJCF, built at run time from the installed robosuite.

Built with `mujoco.MjSpec` from `robosuite/models/assets/robots/panda/robot.xml`: every geom, site,
camera, light, mesh, texture and material removed; bodies with their inertials, the 7 hinge joints
and the 7 torque motors kept; contacts off and, for the forward simulation of a torque log, the
motors' command limits and the joint limits lifted (the log's torques are what the joints received,
and the logged positions stay inside the ranges). Without limit rows the model has no constraint at
all, so MJX's solver has nothing to do: one iteration (reverse-mode gradients) is exact, and MJX on a
CPU is not slowed by the solver's loop (with the 7 limit rows: 47 ms per step for one world here). Nothing of it is
stored in the project: robosuite ships the XML, this builds from it. robosuite's Panda inertials are
round placeholders (link masses 4/3/3/2/2/2/1.5/0.5 kg), not identified values, which is what makes
it a calibration case.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import mujoco

from bench.core.errors import ConfigError

JOINTS = tuple(f"joint{i}" for i in range(1, 8))


def robot_xml() -> Path:
    """Path of robosuite's Panda robot.xml (without importing robosuite)."""
    spec = importlib.util.find_spec("robosuite")
    if spec is None or spec.origin is None:
        raise ConfigError("the Panda dynamics model is built from robosuite's robot.xml; robosuite is not installed")
    path = Path(spec.origin).parent / "models" / "assets" / "robots" / "panda" / "robot.xml"
    if not path.exists():
        raise ConfigError(f"robosuite's Panda model is not at {path}")
    return path


def build(timestep: float = 0.002, damping: float = 0.0, armature: float = 0.0) -> mujoco.MjSpec:
    """The dynamics-only Panda as an `MjSpec` (compile it, or `.to_xml()` it for a calibration spec)."""
    spec = mujoco.MjSpec.from_file(str(robot_xml()))
    for g in list(spec.geoms):
        g.delete()
    for kind in (spec.sites, spec.cameras, spec.lights, spec.meshes, spec.materials, spec.textures):
        for item in list(kind):
            item.delete()
    for j in spec.joints:
        j.limited = mujoco.mjtLimited.mjLIMITED_FALSE  # no limit rows: see the module docstring
        j.damping = damping
        j.armature = armature
        j.frictionloss = 0.0
    for a in spec.actuators:
        a.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
    spec.option.timestep = timestep
    spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.modelname = "panda_dynamics"
    return spec


def model(**kw: float) -> mujoco.MjModel:
    """The compiled dynamics-only Panda (`build`'s keywords)."""
    return build(**kw).compile()


def write(folder: str | Path, **kw: float) -> Path:
    """Write `panda_dynamics.xml` into `folder` (e.g. beside a calibration spec made at run time)."""
    path = Path(folder) / "panda_dynamics.xml"
    spec = build(**kw)
    spec.compile()  # MjSpec writes XML only once compiled
    path.write_text(spec.to_xml())
    return path

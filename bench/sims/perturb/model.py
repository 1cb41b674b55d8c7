"""The model axes, one row each: which elements of the MuJoCo model a level scales, and how (PhysX too).

A level is a scale of the nominal value (1 = unperturbed). Each row names the `MjModel` fields it
edits, selects the elements (its default targets, or those named with `perturb.AXIS.bodies=[...]` and
the like) and writes `nominal x level` into them; `bench.sims.perturb.reset` saves and restores the
nominal values and calls these at each episode. The `physx` hook is the same axis on ManiSkill/SAPIEN,
through `bench.sims.perturb.physx.PhysxAxes`' scene handles (`axis.PhysxScene`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

from bench.core.errors import ConfigError, did_you_mean
from bench.protocols import MujocoHandle
from bench.sims.perturb.axis import MAX_SCALE, Axis, Named, PhysxScene

if TYPE_CHECKING:
    import mujoco


# -- names in the model --------------------------------------------------------------------
def names(model: mujoco.MjModel, objtype: str, count: int) -> list[str]:
    """Names of the first `count` objects of a MuJoCo type ("body", "geom", "joint", "actuator")."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    kind = getattr(mujoco.mjtObj, f"mjOBJ_{objtype.upper()}")
    return [mujoco.mj_id2name(model, kind, i) or "" for i in range(count)]


def resolve(given: Sequence[str], valid: list[str], what: str, field: str, where: str) -> list[int]:
    """Indices of `given` names in `valid`; ConfigError naming the first unknown one and the valid ones."""
    out = []
    for n in given:
        if n not in valid:
            shown = [v for v in valid if v]
            listing = ", ".join(shown[:15]) + (f", ... ({len(shown)} in all)" if len(shown) > 15 else "")
            article = "an" if what[0] in "aeiou" else "a"
            raise ConfigError(
                f"{field}: {n!r} is not {article} {what} of {where}; valid: {listing}.{did_you_mean(n, shown)}"
            )
        out.append(valid.index(n))
    return out


def object_body_ids(mj: MujocoHandle) -> list[int]:
    """Bodies of the manipulated object(s) the env declares."""
    all_names = names(mj.model, "body", mj.model.nbody)
    return [all_names.index(n) for n in mj.object_bodies if n in all_names]


def robot_body_ids(mj: MujocoHandle) -> list[int]:
    """Moving bodies with mass that are not object bodies: the robot's links."""
    model = mj.model
    objects = set(object_body_ids(mj))
    moving = [b for b in range(1, model.nbody) if model.body_weldid[b] != 0]
    return [b for b in moving if b not in objects and model.body_mass[b] > 0]


def _named_bodies(mj: MujocoHandle, named: Named, field: str, where: str) -> list[int]:
    model = mj.model
    return resolve(named["bodies"], names(model, "body", model.nbody), "body", f"{field}.bodies", where)


# -- selections: (handle, named targets, field, where) -> indices ---------------------------
def named_geoms(model: mujoco.MjModel, named: Named, field: str, where: str) -> list[int]:
    """Geom ids named by `.geoms=[...]`, and the geoms of the bodies named by `.bodies=[...]`, sorted."""
    ids: list[int] = []
    if "geoms" in named:
        ids += resolve(named["geoms"], names(model, "geom", model.ngeom), "geom", f"{field}.geoms", where)
    if "bodies" in named:
        valid = names(model, "body", model.nbody)
        bodies = set(resolve(named["bodies"], valid, "body", f"{field}.bodies", where))
        ids += [g for g in range(model.ngeom) if model.geom_bodyid[g] in bodies]
    return sorted(set(ids))


def _geoms(mj: MujocoHandle, named: Named, field: str, where: str) -> np.ndarray:
    if not named:
        return np.arange(mj.model.ngeom)
    return np.array(named_geoms(mj.model, named, field, where), dtype=int)


def _object_bodies(mj: MujocoHandle, named: Named, field: str, where: str) -> np.ndarray:
    if "bodies" in named:
        return np.array(_named_bodies(mj, named, field, where), dtype=int)
    ids = object_body_ids(mj)
    if not ids:
        raise ConfigError(
            f"{field}: {where} declares no manipulated object (object bodies); name the bodies with {field}.bodies=[...]"
        )
    return np.array(ids, dtype=int)


def _robot_bodies(mj: MujocoHandle, named: Named, field: str, where: str) -> np.ndarray:
    ids = _named_bodies(mj, named, field, where) if "bodies" in named else robot_body_ids(mj)
    return np.array(ids, dtype=int)


def _robot_dofs(mj: MujocoHandle, named: Named, field: str, where: str) -> np.ndarray:
    model = mj.model
    if "joints" in named:
        jids = resolve(named["joints"], names(model, "joint", model.njnt), "joint", f"{field}.joints", where)
    else:
        robot = set(robot_body_ids(mj))
        jids = [j for j in range(model.njnt) if model.jnt_bodyid[j] in robot]
    return np.array([d for d in range(model.nv) if model.dof_jntid[d] in set(jids)], dtype=int)


def _actuators(mj: MujocoHandle, named: Named, field: str, where: str) -> np.ndarray:
    model = mj.model
    if "actuators" not in named:
        return np.arange(model.nu)
    valid = names(model, "actuator", model.nu)
    return np.array(resolve(named["actuators"], valid, "actuator", f"{field}.actuators", where), dtype=int)


def _everything(mj: MujocoHandle, named: Named, field: str, where: str) -> np.ndarray:
    return np.arange(3)  # the three components of the gravity vector


# -- edits: (model, nominal values, indices, scale) ------------------------------------------
Nominal = Mapping[str, np.ndarray]
Edit = Callable[["mujoco.MjModel", Nominal, np.ndarray, float], None]
PhysxEdit = Callable[[PhysxScene, float, dict[str, list[str]], str], None]


def _scaled(field: str) -> Edit:
    """The edit of an axis that scales one per-element field."""

    def edit(m: mujoco.MjModel, nom: Nominal, idx: np.ndarray, s: float) -> None:
        getattr(m, field)[idx] = nom[field][idx] * s

    return edit


def _friction(m: mujoco.MjModel, nom: Nominal, idx: np.ndarray, s: float) -> None:
    m.geom_friction[idx] = nom["geom_friction"][idx] * s
    if m.npair and len(idx) == m.ngeom:  # explicit contact pairs override geom friction
        m.pair_friction[:] = nom["pair_friction"] * s


def _mass(m: mujoco.MjModel, nom: Nominal, idx: np.ndarray, s: float) -> None:
    m.body_mass[idx] = nom["body_mass"][idx] * s
    m.body_inertia[idx] = nom["body_inertia"][idx] * s  # same shape, scaled density


def _gain(m: mujoco.MjModel, nom: Nominal, idx: np.ndarray, s: float) -> None:
    g0 = nom["actuator_gainprm"][idx, 0]
    m.actuator_gainprm[idx, 0] = g0 * s
    for k in (1, 2):  # position servo: biasprm[1] = -kp; velocity servo: biasprm[2] = -kv
        mirror = np.isclose(nom["actuator_biasprm"][idx, k], -g0) & (g0 != 0)
        m.actuator_biasprm[idx[mirror], k] = nom["actuator_biasprm"][idx[mirror], k] * s


def _gravity(m: mujoco.MjModel, nom: Nominal, idx: np.ndarray, s: float) -> None:
    m.opt.gravity[:] = nom["opt.gravity"] * s


# -- the same axes on PhysX: (PhysxScene, scale, named targets, field) ---------------------------
def _physx_friction(px: PhysxScene, s: float, named: dict[str, list[str]], field: str) -> None:
    px.scale_friction(s, named.get("bodies"), field)


def _physx_bodies(default: str) -> PhysxEdit:
    """Mass and inertia of the named bodies, else of the env's objects ("objects") or robot links ("robot")."""

    def edit(px: PhysxScene, s: float, named: dict[str, list[str]], field: str) -> None:
        if "bodies" in named:
            bodies = px.resolve(named["bodies"], px.body_names(), "body", f"{field}.bodies")
        elif default == "objects":
            bodies = px.object_names()
            if not bodies:
                raise ConfigError(
                    f"{field}: {px.where()} declares no manipulated object; name the bodies with {field}.bodies=[...]"
                )
        else:
            bodies = px.robot_links()
        px.scale_mass(bodies, s, field)

    return edit


def _physx_drive(column: int) -> PhysxEdit:
    """Drive stiffness (column 0: the servo gain) or damping (column 1) of the robot's or the named joints."""

    def edit(px: PhysxScene, s: float, named: dict[str, list[str]], field: str) -> None:
        key = "actuators" if "actuators" in named else "joints"
        joints = (
            px.resolve(named[key], px.joint_names(), "joint", f"{field}.{key}") if key in named else px.joint_names()
        )
        px.scale_drive(joints, column, s, field)

    return edit


def _physx_gravity(px: PhysxScene, s: float, named: dict[str, list[str]], field: str) -> None:
    px.scale_gravity(s)


# a model axis whose level scales nominal values; one that scales the mass and inertia of bodies
_model_axis = partial(Axis, kind="model", unit="scale of nominal", maximum=MAX_SCALE)
_body_mass_axis = partial(
    Axis,
    kind="model",
    unit="scale of nominal",
    maximum=MAX_SCALE,
    strict=True,
    targets=("bodies",),
    fields=("body_mass", "body_inertia"),
    scale=_mass,
    setconst=True,
    physx_targets=("bodies",),
)


def _joint_row(
    name: str,
    short: str,
    doc: str,
    field: str,
    *,
    physx: PhysxEdit | None = None,
    physx_targets: tuple[str, ...] = (),
    setconst: bool = False,
) -> Axis:
    """A model axis that scales one per-dof field of the robot's (or the named) joints."""
    return _model_axis(
        name,
        short=short,
        doc=doc,
        targets=("joints",),
        select=_robot_dofs,
        fields=(field,),
        scale=_scaled(field),
        from_fields=(field,),
        physx=physx,
        physx_targets=physx_targets,
        setconst=setconst,
    )


ROWS: tuple[Axis, ...] = (
    _model_axis(
        "friction",
        short="friction of every geom",
        doc="sliding, torsional and rolling friction of every geom (and of explicit contact pairs); "
        "MuJoCo uses the max of the two geoms' friction, so all geoms are scaled unless geoms/bodies name some",
        targets=("geoms", "bodies"),
        fields=("geom_friction", "pair_friction"),
        select=_geoms,
        scale=_friction,
        physx=_physx_friction,
        physx_targets=("bodies",),
    ),
    _body_mass_axis(
        "mass",
        short="mass + inertia of the manipulated object",
        doc="mass and inertia of the manipulated object's bodies (the env's object bodies) or of the named bodies",
        select=_object_bodies,
        physx=_physx_bodies("objects"),
    ),
    _body_mass_axis(
        "link_mass",
        short="mass + inertia of the robot's links",
        doc="mass and inertia of the robot's moving bodies (every moving body that is not an object body) "
        "or of the named bodies",
        select=_robot_bodies,
        physx=_physx_bodies("robot"),
        from_fields=("body_mass", "body_ipos", "body_inertia", "body_iquat"),
    ),
    _joint_row(
        "damping",
        "joint damping",
        "joint damping of the robot's joints or of the named joints",
        "dof_damping",
        physx=_physx_drive(1),
        physx_targets=("joints",),
    ),
    _joint_row(
        "armature",
        "joint armature",
        "joint armature (rotor inertia) of the robot's joints or the named ones",
        "dof_armature",
        setconst=True,
    ),
    _joint_row(
        "frictionloss",
        "joint dry friction",
        "joint dry friction (frictionloss) of the robot's joints or the named ones",
        "dof_frictionloss",
    ),
    _model_axis(
        "gain",
        short="actuator gain (servo stiffness)",
        doc="actuator gain of every (or the named) actuator: gainprm[0], and for position/velocity servos the "
        "matching biasprm term, so a servo's setpoint is unchanged and only its stiffness scales",
        targets=("actuators",),
        fields=("actuator_gainprm", "actuator_biasprm"),
        select=_actuators,
        scale=_gain,
        from_fields=("actuator_gainprm", "actuator_biasprm"),  # a position servo's bias follows its gain
        physx=_physx_drive(0),
        physx_targets=("actuators", "joints"),
    ),
    _model_axis(
        "gravity",
        short="gravity vector",
        doc="the gravity vector (1 = nominal, 0 = weightless)",
        fields=("opt.gravity",),
        select=_everything,
        scale=_gravity,
        physx=_physx_gravity,
    ),
)

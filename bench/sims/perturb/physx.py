"""Model perturbation axes on SAPIEN/PhysX: the `ModelAxes` capability of `bench.sims.maniskill`.

Same axes and meaning of a level as the MuJoCo backends (a scale of the nominal value, restored
before every episode, so a reused env never drifts); what each edits in PhysX:

    friction   static and dynamic friction of the collision shapes' materials (all shapes, or those
               of the named bodies). PhysX averages the two materials of a contact, so scaling every
               shape scales every contact's friction by the level. A targeted shape that shares its
               material with others gets its own copy (same values) first.
    mass       mass and inertia of the manipulated object(s) (`env.object_names`) or named bodies.
    link_mass  mass and inertia of the robot's links (or the named bodies).
    damping    drive damping of the robot's joints (or the named joints): PhysX joints have no passive
               damping, and a position drive's damping acts on the joint velocity (target 0), i.e. as
               viscous joint damping.
    gain       drive stiffness of the robot's joints (or the named ones; `actuators` = joint names):
               the servo stiffness, damping unchanged (as MuJoCo's gain axis).
    gravity    the scene's gravity vector. PhysX fixes it when the scene is created, so the env is
               reconfigured (new PhysX scene, same seed -> same initial state) when it changes.
               ManiSkill disables gravity on robot links (their controllers do not compensate it), so
               this acts on the objects.

Named targets use ManiSkill's names: actors ("cube") and links ("panda_link3") for bodies, joints
("panda_joint1") for joints. A name that does not exist, or a target whose nominal value is 0, is a
ConfigError listing what is valid.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from bench.core.errors import ConfigError, did_you_mean
from bench.sims.perturb.axes import AXES
from bench.sims.perturb.axis import Axis

if TYPE_CHECKING:
    from mani_skill.envs.sapien_env import BaseEnv
    from mani_skill.envs.scene import ManiSkillScene
    from sapien.physx import PhysxArticulationJoint, PhysxMaterial, PhysxRigidBaseComponent, PhysxRigidBodyComponent

ROWS: dict[str, Axis] = {a.name: a for a in AXES.values() if a.physx is not None}  # the axes PhysX applies


class PhysxHost(Protocol):
    """What the PhysX handles need of their env (`bench.sims.maniskill.ManiSkillEnv`): ManiSkill's env and names."""

    base: BaseEnv
    env_id: str
    robot: str
    object_names: tuple[str, ...]


@dataclass
class _Nominal:
    """Handles and unperturbed values of one PhysX scene (collected once per scene)."""

    scene: ManiSkillScene
    bodies: dict[str, list[PhysxRigidBaseComponent]] = field(default_factory=dict)  # name -> physx body components
    robot_links: list[str] = field(default_factory=list)
    joints: dict[str, PhysxArticulationJoint] = field(default_factory=dict)  # robot joint name -> physx joint
    # id -> (material, static, dynamic friction)
    materials: dict[int, tuple[PhysxMaterial, float, float]] = field(default_factory=dict)
    # id -> (body, mass, inertia)
    mass: dict[int, tuple[PhysxRigidBodyComponent, float, np.ndarray]] = field(default_factory=dict)
    drives: dict[str, tuple[float, float]] = field(default_factory=dict)  # joint -> (stiffness, damping)


class PhysxAxes:
    """Scales PhysX model parameters of one `ManiSkillEnv` relative to their nominal values."""

    axes: frozenset[str] = frozenset(ROWS)

    def __init__(self, env: PhysxHost):
        self.env = env
        self._nom: _Nominal | None = None
        self._active: list[tuple[str, float, dict[str, list[str]]]] = []
        self._gravity0 = np.array(env.base.sim_config.scene_config.gravity, dtype=np.float64)
        self._gravity = self._gravity0.copy()

    # -- nominal values ----------------------------------------------------------------------
    def _nominal(self) -> _Nominal:
        scene = self.env.base.scene
        if self._nom is None or self._nom.scene is not scene:
            self._nom = self._collect(scene)
        return self._nom

    def _collect(self, scene: ManiSkillScene) -> _Nominal:
        nom = _Nominal(scene)
        for name, actor in scene.actors.items():
            nom.bodies[name] = list(actor._bodies)
        robot = self.env.base.agent.robot
        for art in scene.articulations.values():
            for link in art.links:
                nom.bodies[link.name] = list(link._bodies)
                if art is robot:
                    nom.robot_links.append(link.name)
        for joint in robot.active_joints:
            nom.joints[joint.name] = joint._objs[0]
        for comps in nom.bodies.values():
            for comp in comps:
                for shape in comp.collision_shapes:
                    mat = shape.physical_material
                    nom.materials.setdefault(id(mat), (mat, mat.static_friction, mat.dynamic_friction))
                if hasattr(comp, "mass") and not getattr(comp, "kinematic", False):
                    nom.mass[id(comp)] = (comp, float(comp.mass), np.array(comp.inertia, dtype=np.float64))
        for name, j in nom.joints.items():
            nom.drives[name] = (float(j.stiffness), float(j.damping))
        return nom

    # -- ModelAxes ---------------------------------------------------------------------------
    def restore(self) -> None:
        """Put every nominal value back (gravity on the next reset)."""
        self._active.clear()
        self._gravity = self._gravity0.copy()
        if self._nom is not None and self._nom.scene is self.env.base.scene:
            self._write_nominal(self._nom)

    def apply(self, axis: str, scale: float, targets: Mapping[str, Sequence[str]]) -> None:
        """Scale `axis` by `scale` on `targets` (empty: the axis' default targets); call before reset."""
        row = ROWS.get(axis)
        if row is None or row.physx is None:
            raise ConfigError(
                f"perturb.{axis}: not available on ManiSkill/PhysX; model axes there: "
                f"{', '.join(sorted(ROWS))} (interface axes work on every env)"
            )
        named = {k: [str(n) for n in v] for k, v in (targets or {}).items() if v}
        for key in named:
            if key not in row.physx_targets:
                valid = ", ".join(row.physx_targets) or "none"
                raise ConfigError(f"perturb.{axis}.{key}: {axis} takes no {key} on ManiSkill/PhysX; targets: {valid}")
        row.physx(self, float(scale), named, f"perturb.{axis}")
        self._active.append((axis, float(scale), named))

    # -- hooks for the adapter's reset -------------------------------------------------------
    def needs_reconfigure(self) -> bool:
        """Whether the next reset must rebuild the PhysX scene (its gravity differs from the wanted one)."""
        current = np.asarray(self.env.base.sim_config.scene_config.gravity, dtype=np.float64)
        if np.array_equal(current, self._gravity):
            return False
        self.env.base.sim_config.scene_config.gravity = self._gravity.tolist()
        return True

    def after_reconfigure(self) -> None:
        """Re-apply the episode's edits to the rebuilt scene (it was created with nominal values)."""
        for axis, scale, named in self._active:
            if axis != "gravity":
                physx = ROWS[axis].physx
                assert physx is not None  # only rows with a PhysX edit are applied (apply)
                physx(self, scale, named, f"perturb.{axis}")

    # -- edits -------------------------------------------------------------------------------
    def _write_nominal(self, nom: _Nominal) -> None:
        for mat, static, dynamic in nom.materials.values():
            mat.set_static_friction(static)
            mat.set_dynamic_friction(dynamic)
        for comp, mass, inertia in nom.mass.values():
            comp.set_mass(mass)
            comp.set_inertia(inertia)
        for name, (stiffness, damping) in nom.drives.items():
            self._set_drive(nom.joints[name], stiffness, damping)

    @staticmethod
    def _set_drive(joint: PhysxArticulationJoint, stiffness: float, damping: float) -> None:
        joint.set_drive_properties(stiffness, damping, joint.force_limit, joint.drive_mode)

    # -- what the rows' PhysX edits use (`bench.sims.perturb.model`) ---------------------------
    def where(self) -> str:
        return f"{self.env.env_id} with {self.env.robot}"

    def body_names(self) -> list[str]:
        return list(self._nominal().bodies)

    def joint_names(self) -> list[str]:
        return list(self._nominal().joints)

    def robot_links(self) -> list[str]:
        return list(self._nominal().robot_links)

    def object_names(self) -> list[str]:
        return list(self.env.object_names)

    def resolve(self, names: Sequence[str], valid: Sequence[str], what: str, field: str) -> list[str]:
        """`names`, each checked against `valid` (ConfigError naming the first unknown one and the valid ones)."""
        for n in names:
            if n not in valid:
                listing = ", ".join(list(valid)[:15]) + (f", ... ({len(valid)} in all)" if len(valid) > 15 else "")
                raise ConfigError(
                    f"{field}: {n!r} is not a {what} of {self.where()}; valid: {listing}.{did_you_mean(n, valid)}"
                )
        return list(names)

    def scale_gravity(self, s: float) -> None:
        """The scene's gravity for the next reset (PhysX fixes it when the scene is created)."""
        self._gravity = self._gravity0 * s

    def scale_mass(self, bodies: Sequence[str], s: float, field: str) -> None:
        """Mass and inertia of the bodies' dynamic components times `s`."""
        nom = self._nominal()
        comps = [c for b in bodies for c in nom.bodies[b] if id(c) in nom.mass]
        self._check_nonzero(field, [nom.mass[id(c)][1] for c in comps])
        for c in comps:
            _, mass, inertia = nom.mass[id(c)]
            c.set_mass(mass * s)
            c.set_inertia(inertia * s)

    def scale_drive(self, joints: Sequence[str], column: int, s: float, field: str) -> None:
        """Drive stiffness (column 0) or damping (1) of the joints times `s`; the other keeps its current value."""
        nom = self._nominal()
        self._check_nonzero(field, [nom.drives[j][column] for j in joints])
        for j in joints:  # axes compose
            joint, (stiffness, damping) = nom.joints[j], nom.drives[j]
            if column == 0:
                self._set_drive(joint, stiffness * s, float(joint.damping))
            else:
                self._set_drive(joint, float(joint.stiffness), damping * s)

    def scale_friction(self, s: float, bodies: list[str] | None, field: str) -> None:
        """Static and dynamic friction of every shape's material (or of the named bodies' shapes) times `s`."""
        import sapien.physx as physx  # the maniskill extra: loaded only for ManiSkill suites

        nom = self._nominal()
        if bodies is None:
            mats = list(nom.materials.values())
        else:
            self.resolve(bodies, list(nom.bodies), "body", f"{field}.bodies")
            targets = {id(sh) for b in bodies for c in nom.bodies[b] for sh in c.collision_shapes}
            users: dict[int, set[int]] = {}
            for comps in nom.bodies.values():
                for c in comps:
                    for sh in c.collision_shapes:
                        users.setdefault(id(sh.physical_material), set()).add(id(sh))
            mats = []
            for b in bodies:
                for c in nom.bodies[b]:
                    for sh in c.collision_shapes:
                        mat = sh.physical_material
                        if users[id(mat)] - targets:  # shared with a shape we must not change: own copy
                            _, st, dy = nom.materials[id(mat)]
                            mat = physx.PhysxMaterial(st, dy, mat.restitution)
                            sh.set_physical_material(mat)
                            nom.materials[id(mat)] = (mat, st, dy)
                            users.setdefault(id(mat), set()).add(id(sh))
                        mats.append(nom.materials[id(mat)])
        self._check_nonzero(field, [st for _, st, _ in mats])
        for mat, static, dynamic in mats:
            mat.set_static_friction(static * s)
            mat.set_dynamic_friction(dynamic * s)

    def _check_nonzero(self, field: str, values: list[float]) -> None:
        if not values or not any(v != 0 for v in values):
            raise ConfigError(
                f"{field}: the nominal value of every targeted element of {self.where()} is 0 ({len(values)} targeted), so scaling it changes nothing; "
                "target others or drop the axis"
            )

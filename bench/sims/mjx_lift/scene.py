"""The Lift scene on one of robosuite's arms: its robot.xml dynamics, a two-finger hand, a table and a cube.

Each arm is built from robosuite's `models/assets/robots/<arm>/robot.xml` with `mujoco.MjSpec` (nothing is stored
in the project): every geom, site, camera, light, mesh, material and texture removed, the bodies' inertials and
the arm's joints kept (joints robosuite's robot model does not list, e.g. Sawyer's head pan, removed: the head
is welded), motors removed (the JAX controller applies joint torques through `qfrc_applied`), joint limits and
friction loss lifted (no constraint rows but the contacts), every robot body gravity compensated. The base sits
where robosuite's table arena mounts every single arm (x -0.56 m, z 0.912 m on its mount). A parallel hand built
here (two slide fingers with capsule pads on position servos, 4 cm stroke each) hangs at robosuite's `right_hand`
at the grip offset of that arm's default gripper (`ARMS[..].grip`), so each arm reaches as far as robosuite's
does; the hand is the same on every arm (robosuite's arms carry different grippers: the arms differ here in
kinematics and inertia, not in the hand). The table top is a plane at 0.8 m; the cube is 4 cm on a free joint.
Contacts: cube-table and cube-pads only (box-plane and capsule-box, MJX's cheap pairs).
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bench.core.errors import ConfigError

if TYPE_CHECKING:
    import mujoco

TIMESTEP = 0.005  # s per physics step (robosuite: 2 ms; 5 ms keeps 10 MJX steps per control step)
SUBSTEPS = 10  # physics steps per control step: 20 Hz control, as robosuite's Lift
ITERATIONS, LS_ITERATIONS = 4, 8  # MJX solver iterations (Newton) and line-search iterations per physics step
TABLE_Z = 0.8  # table top height (robosuite's Lift table: offset 0.8 m)
CUBE_HALF = 0.02  # cube half-size (robosuite Lift: 0.020-0.022 m)
CUBE_RANGE = 0.03  # initial cube x, y uniform in [-0.03, 0.03] (robosuite Lift's sampler), yaw uniform
LIFT_HEIGHT = 0.04  # success: cube centre this far above its resting height (robosuite: table + 0.04)
BASE = (-0.56, 0.0, 0.912)  # arm base where robosuite's table arena mounts it (the same for every single arm)
STROKE = 0.04  # finger travel (m), open
FINGER_KP = 300.0  # finger servo stiffness (N/m)
JOINT_DAMPING, JOINT_ARMATURE = 0.1, 0.05  # every arm joint (N m s / rad, kg m^2): as the Panda of this suite had
OMEGA = 12.0  # joint impedance bandwidth (rad/s): kp = OMEGA^2 * (the joint's inertia at home), `gains`
ZETA = 0.9  # joint impedance damping ratio
KP_RANGE = (60.0, 400.0)  # kp clipped to this (N m / rad): a light wrist joint keeps some stiffness


@dataclass(frozen=True)
class Arm:
    """One of robosuite's single arms as this suite builds it.

    Attributes:
        folder: robosuite's `models/assets/robots/<folder>`.
        joints: the arm's joints (robosuite's robot model `joints`), base to hand.
        home: robosuite's `init_qpos` for the arm.
        grip: the grip site below `right_hand` (m, along its z axis) of robosuite's default gripper on that arm.
    """

    folder: str
    joints: tuple[str, ...]
    home: tuple[float, ...]
    grip: float


_PI = float(np.pi)
ARMS: dict[str, Arm] = {  # robosuite 1.5's robot models (init_qpos) and default grippers' grip sites
    "Panda": Arm(
        "panda",
        tuple(f"joint{i}" for i in range(1, 8)),
        (0.0, _PI / 16, 0.0, -_PI / 2 - _PI / 3, 0.0, _PI - 0.2, _PI / 4),
        0.1034,
    ),
    "Sawyer": Arm("sawyer", tuple(f"right_j{i}" for i in range(7)), (0.0, -1.18, 0.0, 2.18, 0.0, 0.57, -1.57), 0.109),
    "IIWA": Arm("iiwa", tuple(f"joint_{i}" for i in range(1, 8)), (0.0, 0.65, 0.0, -1.89, 0.0, 0.6, 0.0), 0.2075),
    "UR5e": Arm(
        "ur5e",
        (
            "shoulder_pan_joint",
            "shoulder_lift_joint",
            "elbow_joint",
            "wrist_1_joint",
            "wrist_2_joint",
            "wrist_3_joint",
        ),
        (-0.47, -1.735, 2.48, -2.275, -1.59, -1.991),
        0.145,
    ),
    "Kinova3": Arm(
        "kinova3", tuple(f"Actuator{i}" for i in range(1, 8)), (0.0, 0.65, 0.0, 1.89, 0.0, 0.6, -_PI / 2), 0.145
    ),
    "Jaco": Arm(
        "jaco",
        tuple(f"j2s7s300_joint_{i}" for i in range(1, 8)),
        (3.192, 3.680, 0.0, 1.170, 0.050, 3.760, 3.142),
        0.1775,
    ),
    "XArm7": Arm("xarm7", tuple(f"joint{i}" for i in range(1, 8)), (0.0, 0.0, 0.0, 1.2252, 0.0, 1.2252, 0.0), 0.147),
}


def robot_xml(arm: str) -> Path:
    """Path of robosuite's robot.xml for `arm` (without importing robosuite)."""
    if arm not in ARMS:
        raise ConfigError(f"robot={arm!r}: the MJX Lift scene builds {', '.join(ARMS)}")
    spec = importlib.util.find_spec("robosuite")
    if spec is None or spec.origin is None:
        raise ConfigError("the MJX Lift arms are built from robosuite's robot.xml files; robosuite is not installed")
    path = Path(spec.origin).parent / "models" / "assets" / "robots" / ARMS[arm].folder / "robot.xml"
    if not path.exists():
        raise ConfigError(f"robosuite's {arm} model is not at {path}")
    return path


def build(arm: str = "Panda") -> mujoco.MjModel:
    """The Lift scene on `arm` (module docstring)."""
    import mujoco  # MuJoCo's native library: loaded only when the scene is built (`bench list` imports the suite)

    a = ARMS[arm] if arm in ARMS else None
    path = robot_xml(arm)
    assert a is not None
    spec = mujoco.MjSpec.from_file(str(path))
    for g in list(spec.geoms):
        g.delete()
    for kind in (spec.sites, spec.cameras, spec.lights, spec.meshes, spec.materials, spec.textures, spec.actuators):
        for item in list(kind):
            item.delete()
    for j in list(spec.joints):
        if j.name not in a.joints:
            j.delete()  # not an arm joint (Sawyer's head pan): welded
            continue
        j.limited = mujoco.mjtLimited.mjLIMITED_FALSE  # no limit rows: the contacts are the only constraints
        j.damping, j.armature, j.frictionloss = JOINT_DAMPING, JOINT_ARMATURE, 0.0
    spec.option.timestep = TIMESTEP
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.iterations, spec.option.ls_iterations = ITERATIONS, LS_ITERATIONS
    spec.modelname = f"mjx_lift_{arm.lower()}"
    for b in spec.bodies:
        if b.name != "world":
            b.gravcomp = 1.0
    spec.body("base").pos = BASE
    hand = spec.body("right_hand")
    hand.add_site(name="grip", pos=[0, 0, a.grip])
    for side, sign in (("left", 1.0), ("right", -1.0)):
        finger = hand.add_body(name=f"finger_{side}", pos=[0, 0, 0], gravcomp=1.0)
        finger.add_joint(
            name=f"finger_{side}", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0, sign, 0], damping=5.0, armature=0.01
        )
        finger.add_geom(
            type=mujoco.mjtGeom.mjGEOM_CAPSULE,
            size=[0.008, 0.012, 0],
            pos=[0, sign * 0.008, a.grip],
            quat=[0.7071068, 0, 0.7071068, 0],
            mass=0.1,
            contype=0,
            conaffinity=2,
            friction=[1.5, 0.005, 1e-4],
            condim=3,
        )
        act = spec.add_actuator(name=f"finger_{side}", target=f"finger_{side}", trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.gaintype, act.biastype = mujoco.mjtGain.mjGAIN_FIXED, mujoco.mjtBias.mjBIAS_AFFINE
        act.gainprm[0], act.biasprm[1] = FINGER_KP, -FINGER_KP  # a position servo
        act.ctrlrange = [0.0, STROKE]
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-30.0, 30.0]
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    world = spec.worldbody
    world.add_geom(
        name="table",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[0.4, 0.4, 0.01],
        pos=[0, 0, TABLE_Z],
        contype=1,
        conaffinity=0,
        friction=[1.0, 0.005, 1e-4],
    )
    cube = world.add_body(name="cube", pos=[0, 0, TABLE_Z + CUBE_HALF])
    cube.add_freejoint(name="cube")
    cube.add_geom(
        name="cube",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[CUBE_HALF] * 3,
        density=1000.0,
        contype=2,
        conaffinity=1,
        friction=[1.0, 0.005, 1e-4],
        condim=3,
    )
    return spec.compile()


def gains(model: mujoco.MjModel, arm: str, dofs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(kp, kd) of the joint impedance on `arm`: each joint's inertia at home (the mass matrix's diagonal, the
    fingers open) sets its stiffness for one bandwidth `OMEGA` on every arm (clipped to `KP_RANGE`), and a damping
    ratio `ZETA` sets kd; so one controller fits arms whose links weigh 0.5 to 4 kg."""
    import mujoco  # MuJoCo's native library: loaded only when the scene is built

    data = mujoco.MjData(model)
    data.qpos[dofs] = ARMS[arm].home  # arm hinge qpos and dof addresses coincide (the arm comes first)
    mujoco.mj_forward(model, data)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, full, data.qM)
    inertia = np.diag(full)[dofs]
    kp = np.clip(OMEGA**2 * inertia, *KP_RANGE)
    kd = 2.0 * ZETA * np.sqrt(kp * inertia)
    return kp, kd

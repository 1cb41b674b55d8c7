"""Lift on MJX: robosuite's Panda (dynamics), a two-finger hand, a table and a cube, N worlds stepped in one call.

The model: `bench.sims.panda_dynamics`' Panda (robosuite's robot.xml, inertials and joints; no meshes) with gravity
compensation on its links, mounted where robosuite's table arena puts it; a parallel hand built here (two slide
fingers with capsule pads on position servos, 4 cm stroke each) at robosuite's `right_hand`; the table top as a plane
at 0.8 m; a 4 cm cube on a free joint. Contacts only cube-table and cube-pads (capsule-box and box-plane: MJX's cheap
pairs); no joint limits on the arm (no constraint rows but the contacts).

The controller (JAX, per world, inside the compiled step): joint impedance towards a damped-least-squares IK step.
At each control step the OSC_POSE-style action (3 position deltas x 5 cm, 3 rotation deltas x 0.5 rad, gripper)
moves a Cartesian goal (the grip site's position plus the delta; an orientation goal kept per world, rotated by
the delta), one DLS step `dq = J^T (J J^T + lambda^2 I)^-1 e` on the 6x7 Jacobian gives joint targets, and every
physics step applies `tau = kp (q* - q) - kd qdot` (gravity is compensated by the model). Why this and not
operational-space control: one 6x6 solve per control step instead of the mass matrix and its inverse every
physics step; it stays stable at the 5 ms step used here; it is robosuite's own alternative (IK + joint control).

`LiftBatch` holds N worlds' state in numpy between calls (qpos, qvel, orientation goal, per-world mass and friction
scales) and steps all of them with one compiled call per control step; `World` is one world as a bench env
adapter (`bench.protocols.EnvAdapter`), so each world is one episode with its own record.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from bench.core.errors import ConfigError
from bench.protocols import STATE, ActionSpec, Feature, NumArray, Obs
from bench.protocols.env import CachedStateAdapter
from bench.sims import mjx as mjx_sim

if TYPE_CHECKING:
    import mujoco
    from jax import Array

TIMESTEP = 0.005  # s per physics step (robosuite: 2 ms; 5 ms keeps 10 MJX steps per control step)
SUBSTEPS = 10  # physics steps per control step: 20 Hz control, as robosuite's Lift
TABLE_Z = 0.8  # table top height (robosuite's Lift table: offset 0.8 m)
CUBE_HALF = 0.02  # cube half-size (robosuite Lift: 0.020-0.022 m)
CUBE_RANGE = 0.03  # initial cube x, y uniform in [-0.03, 0.03] (robosuite Lift's sampler), yaw uniform
LIFT_HEIGHT = 0.04  # success: cube centre this far above its resting height (robosuite: table + 0.04)
BASE = (-0.56, 0.0, 0.912)  # Panda base where robosuite's table arena mounts it
HOME = np.array([0.0, np.pi / 16, 0.0, -np.pi / 2 - np.pi / 3, 0.0, np.pi - 0.2, np.pi / 4])  # robosuite init_qpos
STROKE = 0.04  # finger travel (m), open
FINGER_KP = 300.0  # finger servo stiffness (N/m)
GRIP_Z = 0.1034  # grip site below robosuite's right_hand frame (robosuite Panda gripper's grip_site)
KP = np.array([300.0, 300.0, 300.0, 300.0, 150.0, 150.0, 80.0])  # joint stiffness (N m / rad)
KD = 2.0 * np.sqrt(KP) * 0.6  # joint damping (N m s / rad): about 0.6 of critical for ~1 kg m^2
DLS_LAMBDA = 0.05  # damping of the IK step
POS_SCALE, ROT_SCALE = 0.05, 0.5  # action 1.0 = 5 cm / 0.5 rad (robosuite OSC_POSE output_max)
AXES = frozenset({"mass", "friction"})  # per-world model axes on the cube
ACTION_NAMES = ("dx", "dy", "dz", "droll", "dpitch", "dyaw", "gripper")  # robosuite OSC_POSE deltas + gripper
OBS_FIELDS = (  # the 18-number agnostic Lift observation of suites/lift.py (OBS_FIELDS there)
    ("eef_pos", 3),
    ("eef_quat_rel", 4),
    ("gripper_opening", 1),
    ("object_pos", 3),
    ("object_quat", 4),
    ("gripper_to_object", 3),
)
BYTES_PER_WORLD = 200_000  # measured order of MJX's per-world data + scan buffers at float32 (see `memory_estimate`)


def build() -> mujoco.MjModel:
    """The Lift scene on the dynamics-only Panda (module docstring)."""
    import mujoco  # MuJoCo's native library: loaded only when the scene is built (`bench list` imports the suite)

    from bench.sims import panda_dynamics  # imports MuJoCo: loaded only when the scene is built

    spec = panda_dynamics.build(timestep=TIMESTEP, damping=0.1, armature=0.05)
    spec.option.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    spec.option.iterations, spec.option.ls_iterations = 4, 8
    spec.modelname = "mjx_lift_panda"
    for a in list(spec.actuators):
        a.delete()  # the arm is torque-driven through qfrc_applied by the JAX controller
    for b in spec.bodies:
        if b.name.startswith("link") or b.name == "right_hand":
            b.gravcomp = 1.0
    spec.body("base").pos = BASE
    hand = spec.body("right_hand")
    hand.add_site(name="grip", pos=[0, 0, GRIP_Z])
    for side, sign in (("left", 1.0), ("right", -1.0)):
        finger = hand.add_body(name=f"finger_{side}", pos=[0, 0, 0], gravcomp=1.0)
        finger.add_joint(
            name=f"finger_{side}", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0, sign, 0], damping=5.0, armature=0.01
        )
        finger.add_geom(
            type=mujoco.mjtGeom.mjGEOM_CAPSULE,
            size=[0.008, 0.012, 0],
            pos=[0, sign * 0.008, GRIP_Z],
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


def memory_estimate(worlds: int) -> int:
    """Bytes N worlds need (an order of magnitude: MJX data, contacts, scan buffers at float32)."""
    return int(worlds) * BYTES_PER_WORLD


def check_worlds(worlds: int, available: int | None = None) -> None:
    """Refuse, in one line, a world count whose estimated memory exceeds what the machine has."""
    if available is None:
        import os  # the page count: only when a world count is checked

        available = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")
    need = memory_estimate(worlds)
    if need > available:
        raise ConfigError(
            f"worlds={worlds}: the MJX Lift suite needs about {need / 2**30:.1f} GiB ({BYTES_PER_WORLD / 1e3:.0f} kB "
            f"per world), and {available / 2**30:.1f} GiB is free; ask for at most {available // BYTES_PER_WORLD} worlds"
        )


class Compiled:
    """The compiled batched control step of the Lift model (one per process: JAX caches it per world count)."""

    def __init__(self) -> None:
        jax, jnp, mjx = mjx_sim.require(x64=False)
        self.jax, self.jnp, self.mjx = jax, jnp, mjx
        self.model = build()
        mjx_sim.check_model(self.model)
        self.mx = mjx.put_model(self.model)
        m = self.model
        self.cube_body = m.body("cube").id
        self.cube_geom = m.geom("cube").id
        self.hand = m.body("right_hand").id
        self.grip = m.site("grip").id
        self.cube_q = int(m.jnt_qposadr[m.joint("cube").id])
        self.finger_q = [int(m.jnt_qposadr[m.joint(f"finger_{s}").id]) for s in ("left", "right")]
        self.step = jax.jit(jax.vmap(self._one))

    def _one(self, qpos: Array, qvel: Array, rgoal: Array, action: Array, scale: Array) -> tuple[Array, ...]:
        """One world, one control step: (qpos, qvel, orientation goal, grip position, hand quaternion)."""
        jax, jnp, mjx = self.jax, self.jnp, self.mjx
        mx = self.mx
        m = mx.tree_replace(
            {
                "body_mass": mx.body_mass.at[self.cube_body].multiply(scale[0]),
                "geom_friction": mx.geom_friction.at[self.cube_geom, 0].multiply(scale[1]),
            }
        )
        d = mjx.make_data(m).replace(qpos=qpos, qvel=qvel)
        d = mjx.com_pos(m, mjx.kinematics(m, d))
        pos, rot = d.site_xpos[self.grip], d.site_xmat[self.grip]
        a = jnp.clip(action, -1.0, 1.0)
        rgoal = _rodrigues(jnp, ROT_SCALE * a[3:6]) @ rgoal
        err_rot = 0.5 * jnp.sum(jnp.cross(rot.T, rgoal.T), axis=0)  # columns: orientation error (world frame)
        jacp, jacr = mjx.jac(m, d, pos, self.hand)
        jac = jnp.concatenate([jacp[:7].T, jacr[:7].T])  # (6, 7): the arm's dofs come first
        err = jnp.concatenate([POS_SCALE * a[:3], err_rot])
        dq = jac.T @ jnp.linalg.solve(jac @ jac.T + DLS_LAMBDA**2 * jnp.eye(6), err)
        qstar = qpos[:7] + dq
        fingers = 0.5 * STROKE * (1.0 - a[6])  # +1 closes (0 m), -1 opens (4 cm)
        d = d.replace(ctrl=jnp.stack([fingers, fingers]))
        kp, kd = jnp.asarray(KP), jnp.asarray(KD)

        def physics(d: Any, _: None) -> tuple[Any, None]:
            tau = kp * (qstar - d.qpos[:7]) - kd * d.qvel[:7]
            d = d.replace(qfrc_applied=jnp.zeros(mx.nv).at[:7].set(tau))
            return mjx.step(m, d), None

        d, _ = jax.lax.scan(physics, d, None, length=SUBSTEPS)
        d = mjx.kinematics(m, d)
        return d.qpos, d.qvel, rgoal, d.site_xpos[self.grip], d.xquat[self.hand]


def _rodrigues(jnp: Any, v: Array) -> Array:
    """The rotation matrix of axis-angle `v` (differentiable at 0)."""
    theta = jnp.sqrt(jnp.sum(v * v) + 1e-12)
    k = jnp.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]]) / theta
    return jnp.eye(3) + jnp.sin(theta) * k + (1.0 - jnp.cos(theta)) * (k @ k)


_COMPILED: list[Compiled] = []


def compiled() -> Compiled:
    """The process's `Compiled` (built on first use: JAX and the model)."""
    if not _COMPILED:
        _COMPILED.append(Compiled())
    return _COMPILED[0]


class LiftBatch:
    """N worlds of the Lift scene: their state in numpy, stepped together by `step_all` (one compiled call)."""

    def __init__(self) -> None:
        import mujoco  # MuJoCo's native library: loaded only when a batch is made (`bench list` imports the suite)

        self.c = compiled()
        m = self.c.model
        data = mujoco.MjData(m)
        data.qpos[:7] = HOME
        data.qpos[self.c.finger_q] = STROKE
        mujoco.mj_forward(m, data)
        self.home_qpos = data.qpos.copy()
        self.home_grip = data.site_xpos[self.c.grip].copy()
        self.home_rot = data.site_xmat[self.c.grip].reshape(3, 3).copy()
        self.home_quat = data.xquat[self.c.hand].copy()
        self.nv = m.nv
        self.worlds: list[World] = []
        self._alloc(0)

    def _alloc(self, n: int) -> None:
        self.qpos = np.tile(self.home_qpos, (n, 1)).astype(np.float32)
        self.qvel = np.zeros((n, self.nv), np.float32)
        self.rgoal = np.tile(self.home_rot, (n, 1, 1)).astype(np.float32)
        self.scale = np.ones((n, 2), np.float32)
        self.grip = np.tile(self.home_grip, (n, 1)).astype(np.float32)
        self.quat = np.tile(self.home_quat, (n, 1)).astype(np.float32)

    def add(self, horizon: int) -> World:
        """A new world (one more row in every array)."""
        n = len(self.worlds) + 1
        old = (self.qpos, self.qvel, self.rgoal, self.scale, self.grip, self.quat)
        self._alloc(n)
        for new, prev in zip((self.qpos, self.qvel, self.rgoal, self.scale, self.grip, self.quat), old):
            new[: n - 1] = prev
        world = World(self, n - 1, horizon)
        self.worlds.append(world)
        return world

    def reset_world(self, i: int, seed: int) -> None:
        """World i at the home pose with its cube drawn from `seed` (robosuite Lift's placement ranges)."""
        rng = np.random.default_rng(seed)
        x, y = rng.uniform(-CUBE_RANGE, CUBE_RANGE, size=2)
        yaw = rng.uniform(0.0, 2.0 * np.pi)
        q = self.home_qpos.copy()
        k = self.c.cube_q
        q[k : k + 3] = (x, y, TABLE_Z + CUBE_HALF)
        q[k + 3 : k + 7] = (np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2))
        self.qpos[i], self.qvel[i] = q, 0.0
        self.rgoal[i], self.grip[i], self.quat[i] = self.home_rot, self.home_grip, self.home_quat

    def step_all(self, actions: Mapping[int, npt.ArrayLike]) -> None:
        """One control step of the worlds in `actions` (world index -> action), in one compiled call; the other
        worlds keep their state. All worlds, or one alone, are the two shapes compiled; any other subset steps
        every world and keeps the rows asked for."""
        n = len(self.worlds)
        rows = np.fromiter(actions, dtype=np.int64)
        act = np.asarray([np.asarray(a, np.float32) for a in actions.values()], np.float32).reshape(len(rows), 7)
        if len(rows) == 1 and n > 1:
            take = rows
        else:
            take = np.arange(n)
            full = np.zeros((n, 7), np.float32)
            full[rows] = act
            act = full
        state = (self.qpos, self.qvel, self.rgoal)
        out = self.c.step(*(x[take] for x in state), act, self.scale[take])
        out = [np.asarray(x) for x in out]
        if len(take) != len(rows):
            keep = np.isin(take, rows)
            out = [x[keep] for x in out]
        for arr, new in zip((self.qpos, self.qvel, self.rgoal, self.grip, self.quat), out):
            arr[rows] = new
        for i in rows:
            self.worlds[int(i)].fresh = True


class World(CachedStateAdapter):
    """One world of a `LiftBatch` as a bench env adapter: one episode at a time, its own seed and axis draws.

    `step(action)` returns the world's row of the batch's last `step_all` when the vectorised runner stepped the
    batch for it (`fresh`), else steps this world alone. Model axes (`mass`, `friction` of the cube) are per world:
    `model_axes` is the world itself (`apply` before `reset`, as `bench.sims.perturb` calls it)."""

    obs_spec = {STATE: Feature.state(OBS_FIELDS)}
    action_spec = ActionSpec.box(ACTION_NAMES, -1.0, 1.0)
    fps = 1.0 / (TIMESTEP * SUBSTEPS)
    axes = AXES

    def __init__(self, batch: LiftBatch, index: int, horizon: int) -> None:
        self.batch, self.index, self.horizon = batch, index, int(horizon)
        import mujoco  # MuJoCo's native library: loaded by the batch already (`bench list` imports the suite)

        jax = batch.c.jax
        self.backend = f"mjx-{mujoco.__version__}/jax-{jax.__version__}"
        self.model_axes = self
        self.fresh = False
        self._quat0_conj = np.array([0.0, 0.0, 0.0, 1.0])

    # ModelAxes: the cube's mass and friction, scaled per world
    def restore(self) -> None:
        self.batch.scale[self.index] = 1.0

    def apply(self, axis: str, scale: float, targets: Mapping[str, Sequence[str]]) -> None:
        if axis not in AXES:
            raise ConfigError(f"perturb.{axis}: the MJX Lift suite varies only {sorted(AXES)} per world")
        named = [t for names in targets.values() for t in names]
        if any(t != "cube" for t in named):
            raise ConfigError(f"perturb.{axis}: the MJX Lift suite perturbs the cube only (targets {named})")
        if not np.isfinite(scale) or scale <= 0:
            raise ConfigError(f"perturb.{axis}: scale {scale} must be positive")
        self.batch.scale[self.index, 0 if axis == "mass" else 1] = scale

    def reset(self, seed: int) -> Obs:
        b, i = self.batch, self.index
        b.reset_world(i, seed)
        self.fresh = False
        self._success = False
        self._init_state = np.concatenate([b.qpos[i], b.qvel[i]]).astype(np.float64)
        self._quat0_conj = _xyzw(b.home_quat) * np.array([-1.0, -1.0, -1.0, 1.0])
        return self._observe()

    def step(self, action: NumArray) -> tuple[Obs, float, bool, bool, dict[str, object]]:
        if not self.fresh:
            self.batch.step_all({self.index: action})
        self.fresh = False
        self._success = bool(self.batch.qpos[self.index, self.batch.c.cube_q + 2] > TABLE_Z + LIFT_HEIGHT)
        return self._observe(), float(self._success), False, False, {}

    def _observe(self) -> Obs:
        b, i = self.batch, self.index
        k = b.c.cube_q
        out = np.empty(18, np.float32)
        eef, cube = b.grip[i].astype(np.float64), b.qpos[i, k : k + 3].astype(np.float64)
        rel = _quat_mul_xyzw(self._quat0_conj, _xyzw(b.quat[i]))
        out[0:3] = eef
        out[3:7] = rel if rel[3] >= 0 else -rel
        out[7] = min(1.0, max(0.0, float(b.qpos[i, b.c.finger_q].mean()) / STROKE))
        out[8:11] = cube
        out[11:15] = _xyzw(b.qpos[i, k + 3 : k + 7])
        out[15:18] = cube - eef
        return {STATE: out}


def _xyzw(wxyz: npt.ArrayLike) -> NumArray:
    q = np.asarray(wxyz, np.float64)
    return np.array([q[1], q[2], q[3], q[0]])


def _quat_mul_xyzw(a: NumArray, b: NumArray) -> NumArray:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ]
    )

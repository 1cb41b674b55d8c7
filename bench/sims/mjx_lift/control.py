"""The compiled, batched control step of the MJX Lift scene on one arm: a JAX controller and MJX physics.

The controller (per world, inside the compiled step): joint impedance towards a damped-least-squares IK step
over the arm's own joints (7 on most arms, 6 on the UR5e). At each control step the OSC_POSE-style action
(3 position deltas x 5 cm, 3 rotation deltas x 0.5 rad, gripper) moves a Cartesian goal (the grip site's position
plus the delta; an orientation goal kept per world, rotated by the delta), one DLS step
`dq = J^T (J J^T + lambda^2 I)^-1 e` on the 6 x n Jacobian gives joint targets, and every physics step applies
`tau = kp (q* - q) - kd qdot` (gravity is compensated by the model; kp, kd per arm from its inertia,
`scene.gains`). The stiffness is applied as a force (`qfrc_applied`); the damping `kd` is added to the joints'
`dof_damping` in the step's model, so the implicitfast integrator integrates it implicitly: applied explicitly it
is unstable wherever `dt * max eig(M^-1 Kd) > 2`, which the IIWA reaches when it lifts towards an upright
shoulder (joints 1 and 3 aligned at q2 -> 0: 2.26 at q2 = 0.14, where its worlds went non-finite; docs/mjx.md).
Why this and not operational-space control: one 6x6 solve per control step instead of the mass matrix and its
inverse every physics step; it stays stable at the 5 ms step used here; it is robosuite's own alternative (IK +
joint control).

Per world the step also takes that world's model fields (`WORLD_FIELDS`: a perturbed cube mass or friction, a
calibration's link masses or joint damping drawn for it) and returns its observation, computed in the same call
(the 18 numbers of suites/lift.py), so the host does no per-world arithmetic.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from bench.protocols import NumArray
from bench.sims import mjx as mjx_sim
from bench.sims.mjx_lift import scene

if TYPE_CHECKING:
    from jax import Array

DLS_LAMBDA = 0.05  # damping of the IK step
POS_SCALE, ROT_SCALE = 0.05, 0.5  # action 1.0 = 5 cm / 0.5 rad (robosuite OSC_POSE output_max)
WORLD_FIELDS = ("body_mass", "body_ipos", "body_iquat", "body_inertia", "dof_damping", "geom_friction")
OBS_SIZE = 18


class Compiled:
    """The compiled batched control step of the Lift scene on one arm (one per arm and process: JAX caches it per
    world count). `substeps`, `iterations`, `ls_iterations` default to the scene's; `euler` swaps the scene's
    implicitfast integrator for Euler, `cg` its Newton solver for conjugate gradients, `warmstart=False` turns the
    solver's warm start off and `tolerance` replaces MuJoCo's; other values are for profiling
    (benchmarks/bench_mjx_suite.py), not for the suite."""

    def __init__(
        self,
        arm: str = "Panda",
        substeps: int = scene.SUBSTEPS,
        iterations: int = scene.ITERATIONS,
        ls_iterations: int = scene.LS_ITERATIONS,
        euler: bool = False,
        cg: bool = False,
        warmstart: bool = True,
        tolerance: float | None = None,
    ) -> None:
        jax, jnp, mjx = mjx_sim.require(x64=False)
        self.jax, self.jnp, self.mjx = jax, jnp, mjx
        self.arm, self.substeps = arm, int(substeps)
        m = scene.build(arm)
        m.opt.iterations, m.opt.ls_iterations = int(iterations), int(ls_iterations)
        import mujoco  # MuJoCo's native library: already loaded by `scene.build`

        if euler:
            m.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
        if cg:
            m.opt.solver = mujoco.mjtSolver.mjSOL_CG
        if not warmstart:
            m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_WARMSTART
        if tolerance is not None:
            m.opt.tolerance = float(tolerance)
        self.model = m
        mjx_sim.check_model(m)
        self.mx = mjx.put_model(m)
        self.cube_body = m.body("cube").id
        self.cube_geom = m.geom("cube").id
        self.hand = m.body("right_hand").id
        self.grip = m.site("grip").id
        self.cube_q = int(m.jnt_qposadr[m.joint("cube").id])
        self.finger_q = np.array([int(m.jnt_qposadr[m.joint(f"finger_{s}").id]) for s in ("left", "right")])
        arm_joints = [m.joint(j).id for j in scene.ARMS[arm].joints]
        self.dofs = np.array([int(m.jnt_dofadr[j]) for j in arm_joints])
        if not np.array_equal(self.dofs, np.arange(len(self.dofs))) or not np.array_equal(
            self.dofs, [int(m.jnt_qposadr[j]) for j in arm_joints]
        ):
            raise AssertionError(f"{arm}: the arm's joints must come first in qpos and qvel")
        self.n = len(self.dofs)
        self.kp, self.kd = scene.gains(m, arm, self.dofs)
        self.nominal = {f: np.array(getattr(m, f), np.float32) for f in WORLD_FIELDS}
        self._batched = jax.jit(jax.vmap(self._one))
        cpus = jax.devices("cpu") if jax.default_backend() == "cpu" else []
        self.devices = cpus if len(cpus) > 1 else []  # XLA's host devices (`mjx_sim.xla_cpu_flags`), one per core
        self._sharded = jax.pmap(jax.vmap(self._one), devices=self.devices) if self.devices else None

    def step(
        self,
        world: Mapping[str, NumArray],
        qpos: NumArray,
        qvel: NumArray,
        rgoal: NumArray,
        quat0: NumArray,
        action: NumArray,
    ) -> list[NumArray]:
        """One control step of N worlds: (qpos, qvel, orientation goal, observation), each with N rows.

        On a CPU with several host devices the worlds are split evenly across them (one per core; the last
        share padded with copies of world 0, dropped from the output), so the cores step their shares at once:
        one compiled call stepping every world ran on one core, measured 1.65x slower at 1,024 worlds on this
        2-core machine (benchmarks/bench_mjx_suite.py). A GPU, or fewer worlds than devices, takes one call."""
        n = len(qpos)
        k = len(self.devices)
        args = (world, qpos, qvel, rgoal, quat0, action)
        if self._sharded is None or n < k:
            return [np.asarray(x) for x in self._batched(*args)]
        per = -(-n // k)

        def split(x: NumArray) -> NumArray:
            x = np.asarray(x)
            if per * k > n:
                x = np.concatenate([x, np.repeat(x[:1], per * k - n, axis=0)])
            return x.reshape((k, per) + x.shape[1:])

        out = self._sharded(*self.jax.tree_util.tree_map(split, args))
        return [np.asarray(x).reshape((k * per,) + x.shape[2:])[:n] for x in out]

    def _one(
        self, world: dict[str, Array], qpos: Array, qvel: Array, rgoal: Array, quat0: Array, action: Array
    ) -> tuple[Array, ...]:
        """One world, one control step: (qpos, qvel, orientation goal, observation)."""
        jax, jnp, mjx = self.jax, self.jnp, self.mjx
        n = self.n
        kp, kd = jnp.asarray(self.kp, jnp.float32), jnp.asarray(self.kd, jnp.float32)
        m = self.mx.tree_replace({**world, "dof_damping": world["dof_damping"].at[:n].add(kd)})  # implicit kd
        d = mjx.make_data(m).replace(qpos=qpos, qvel=qvel)
        d = mjx.com_pos(m, mjx.kinematics(m, d))
        pos, rot = d.site_xpos[self.grip], d.site_xmat[self.grip]
        a = jnp.clip(action, -1.0, 1.0)
        rgoal = _rodrigues(jnp, ROT_SCALE * a[3:6]) @ rgoal
        err_rot = 0.5 * jnp.sum(jnp.cross(rot.T, rgoal.T), axis=0)  # columns: orientation error (world frame)
        jacp, jacr = mjx.jac(m, d, pos, self.hand)
        jac = jnp.concatenate([jacp[:n].T, jacr[:n].T])  # (6, n): the arm's dofs come first
        err = jnp.concatenate([POS_SCALE * a[:3], err_rot])
        dq = jac.T @ jnp.linalg.solve(jac @ jac.T + DLS_LAMBDA**2 * jnp.eye(6), err)
        qstar = qpos[:n] + dq
        fingers = 0.5 * scene.STROKE * (1.0 - a[6])  # +1 closes (0 m), -1 opens (4 cm)
        d = d.replace(ctrl=jnp.stack([fingers, fingers]))
        zeros = jnp.zeros(self.mx.nv)

        def physics(d: Any, _: None) -> tuple[Any, None]:
            tau = kp * (qstar - d.qpos[:n])  # - kd qdot: the model's dof_damping (implicit)
            return mjx.step(m, d.replace(qfrc_applied=zeros.at[:n].set(tau))), None

        d, _ = jax.lax.scan(physics, d, None, length=self.substeps)
        d = mjx.kinematics(m, d)
        return d.qpos, d.qvel, rgoal, self._observe(d, quat0)

    def _observe(self, d: Any, quat0: Array) -> Array:
        """suites/lift.py's 18 numbers of one world (quaternions x, y, z, w; eef_quat_rel relative to `quat0`)."""
        jnp = self.jnp
        k = self.cube_q
        eef, cube = d.site_xpos[self.grip], d.qpos[k : k + 3]
        rel = _quat_mul(jnp, quat0 * jnp.array([1.0, -1.0, -1.0, -1.0]), d.xquat[self.hand])  # w, x, y, z
        rel = jnp.where(rel[0] >= 0, rel, -rel)
        opening = jnp.clip(jnp.mean(d.qpos[self.finger_q]) / scene.STROKE, 0.0, 1.0)
        cq = d.qpos[k + 3 : k + 7]
        return jnp.concatenate([eef, rel[1:], rel[:1], opening[None], cube, cq[1:], cq[:1], cube - eef])


def _rodrigues(jnp: Any, v: Array) -> Array:
    """The rotation matrix of axis-angle `v` (differentiable at 0)."""
    theta = jnp.sqrt(jnp.sum(v * v) + 1e-12)
    k = jnp.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]]) / theta
    return jnp.eye(3) + jnp.sin(theta) * k + (1.0 - jnp.cos(theta)) * (k @ k)


def _quat_mul(jnp: Any, a: Array, b: Array) -> Array:
    """Hamilton product of quaternions w, x, y, z."""
    aw, ax, ay, az = a[0], a[1], a[2], a[3]
    bw, bx, by, bz = b[0], b[1], b[2], b[3]
    return jnp.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


_COMPILED: dict[str, Compiled] = {}


def compiled(arm: str = "Panda") -> Compiled:
    """The process's `Compiled` for `arm` (built on first use: JAX and the model)."""
    if arm not in _COMPILED:
        _COMPILED[arm] = Compiled(arm)
    return _COMPILED[arm]

"""Inverse dynamics of some joints of a MuJoCo model: their rigid-body torque, and its regressor.

The joint torque of a rigid arm is linear in each link's ten standard inertial parameters (mass, first
moment m c, inertia about the link frame's origin): tau = Y(q, dq, ddq) theta. `Dynamics` gives the
torque of the model as it is (`mj_inverse`) and, per body, the columns of Y computed from MuJoCo's own
kinematics, so any model a user brings, with its own frames and fixed bodies, gives its own regressor.
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np


class Dynamics:
    """Inverse dynamics of some joints of a MuJoCo model, with every other coordinate held still.

    The model is copied and stripped of what is not rigid-body dynamics (contacts, passive forces,
    friction loss; the joints' rotor inertia is zeroed): friction and rotor inertia are columns of
    their own. `qpos0` places the coordinates that are not identified (a gripper, an object).
    """

    def __init__(self, model: mujoco.MjModel, qadr: np.ndarray, dadr: np.ndarray, qpos0: np.ndarray) -> None:
        m = copy.copy(model)
        m.opt.disableflags |= int(
            mujoco.mjtDisableBit.mjDSBL_CONTACT
            | mujoco.mjtDisableBit.mjDSBL_PASSIVE
            | mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS
            | mujoco.mjtDisableBit.mjDSBL_LIMIT
            | mujoco.mjtDisableBit.mjDSBL_EQUALITY
        )
        m.dof_armature[dadr] = 0.0
        self.m, self.d = m, mujoco.MjData(m)
        self.qadr, self.dadr = np.asarray(qadr), np.asarray(dadr)
        self.qpos0 = np.asarray(qpos0, dtype=np.float64).copy()
        self.evaluations = 0

    def torques(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """(N, n) joint torques of the current model at N samples."""
        m, d = self.m, self.d
        mujoco.mj_setConst(m, d)  # body edits reach the mass matrix (simple bodies cache it)
        out = np.empty_like(q)
        d.qvel[:] = 0.0
        d.qacc[:] = 0.0
        for i in range(len(q)):
            d.qpos[:] = self.qpos0
            d.qpos[self.qadr] = q[i]
            d.qvel[self.dadr] = dq[i]
            d.qacc[self.dadr] = ddq[i]
            mujoco.mj_inverse(m, d)
            out[i] = d.qfrc_inverse[self.dadr]
        self.evaluations += len(q)
        return out

    def body_columns(self, bodies: list[int], q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> dict[int, np.ndarray]:
        """Per body, (N, n, 10): the torque per unit of each of its standard parameters (in its own frame).

        The classical regressor (Atkeson et al. 1986), computed from MuJoCo's own kinematics: for each
        sample one pass of `mj_kinematics`, `mj_comPos`, `mj_comVel` and `mj_rnePostConstraint` gives every
        body's spatial velocity and acceleration (gravity as an upward acceleration of the world) and the
        joints' motion axes; the rest is vectorised. The body's wrench about its frame origin is linear in
        [m, m c, I_origin]: f = m a + w' x h + w x (w x h), n = I w' + w x (I w) + h x a (body frame), and
        the joint torques are J' [f; n]. Exact (it matches differences of `mj_inverse` to 1e-12).
        """
        m, d = self.m, self.d
        bodies = [int(b) for b in bodies]
        nb, nd, n_rows = len(bodies), len(self.dadr), len(q)
        anc = np.zeros((nb, nd), bool)  # dof j moves body b
        for k, b in enumerate(bodies):
            chain, x = set(), b
            while x > 0:
                chain.add(x)
                x = int(m.body_parentid[x])
            anc[k] = [int(m.dof_bodyid[dof]) in chain for dof in self.dadr]
        roots = m.body_rootid[bodies]
        xpos, xmat = np.empty((n_rows, nb, 3)), np.empty((n_rows, nb, 9))
        cvel, cacc = np.empty((n_rows, nb, 6)), np.empty((n_rows, nb, 6))
        cdof, com = np.empty((n_rows, nd, 6)), np.empty((n_rows, nb, 3))
        for i in range(n_rows):
            d.qpos[:] = self.qpos0
            d.qpos[self.qadr] = q[i]
            d.qvel[:] = 0.0
            d.qvel[self.dadr] = dq[i]
            d.qacc[:] = 0.0
            d.qacc[self.dadr] = ddq[i]
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_comVel(m, d)
            mujoco.mj_rnePostConstraint(m, d)
            xpos[i], xmat[i], cvel[i], cacc[i] = d.xpos[bodies], d.xmat[bodies], d.cvel[bodies], d.cacc[bodies]
            cdof[i], com[i] = d.cdof[self.dadr], d.subtree_com[roots]
        self.evaluations += n_rows
        rt = np.swapaxes(xmat.reshape(n_rows, nb, 3, 3), -1, -2)  # world -> body
        r = xpos - com  # body origin from the point MuJoCo's spatial vectors refer to
        w, al = cvel[..., :3], cacc[..., :3]
        v_o = cvel[..., 3:] + np.cross(w, r)
        a_o = cacc[..., 3:] + np.cross(al, r) + np.cross(w, v_o)  # classical, gravity included
        wb, alb, ab = (np.einsum("nkij,nkj->nki", rt, v) for v in (w, al, a_o))
        ang = np.broadcast_to(cdof[:, None, :, :3], (n_rows, nb, nd, 3))
        lin = cdof[:, None, :, 3:] + np.cross(ang, r[:, :, None, :])
        jac = (
            np.concatenate([np.einsum("nkij,nkdj->nkdi", rt, lin), np.einsum("nkij,nkdj->nkdi", rt, ang)], axis=-1)
            * anc[None, :, :, None]
        )  # (N, nb, n, 6): [linear; angular] per dof, body frame
        cols = np.einsum("nkdi,nkip->nkdp", jac, _wrench_regressor(wb, alb, ab))
        return {b: np.ascontiguousarray(cols[:, k]) for k, b in enumerate(bodies)}


_SYM = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]  # the six inertia entries, in STD_NAMES order


def _wrench_regressor(w: np.ndarray, wd: np.ndarray, a: np.ndarray) -> np.ndarray:
    """(..., 6, 10): a body's wrench [f; n] about its origin per unit of each standard parameter."""
    out = np.zeros(w.shape[:-1] + (6, 10))
    out[..., :3, 0] = a
    eye = np.eye(3)
    for k in range(3):
        e = np.broadcast_to(eye[k], w.shape)
        out[..., :3, 1 + k] = np.cross(wd, e) + np.cross(w, np.cross(w, e))
        out[..., 3:, 1 + k] = np.cross(e, a)
    for j, (r, c) in enumerate(_SYM):
        basis = np.zeros((3, 3))
        basis[r, c] = basis[c, r] = 1.0
        out[..., 3:, 4 + j] = wd @ basis + np.cross(w, w @ basis)
    return out

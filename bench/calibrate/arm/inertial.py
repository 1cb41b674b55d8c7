"""A link's ten standard inertial parameters: to and from a MuJoCo body, and what makes them a physical body.

Standard parameters p = [m, m·c (3), I about the link frame's origin (xx, xy, xz, yy, yz, zz)] are what
inverse dynamics is linear in (`bench.calibrate.arm.idim`). A body is physical exactly when its 4x4
pseudo-inertia is positive definite (Wensing et al. 2017); fits move in log-Cholesky coordinates of it
(`factor_of`, `std_of_factor`), so every value they reach is a body, and `physical` lifts one that is not.
"""

from __future__ import annotations

import mujoco
import numpy as np

STD_NAMES = ("mass", "mx", "my", "mz", "ixx", "ixy", "ixz", "iyy", "iyz", "izz")


def std_params(m: mujoco.MjModel, body: int) -> np.ndarray:
    """A body's standard inertial parameters in its own frame: [m, m·c (3), I about the origin (6)]."""
    mass = float(m.body_mass[body])
    c = np.array(m.body_ipos[body], dtype=np.float64)
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, m.body_iquat[body])
    rot = rot.reshape(3, 3)
    ic = rot @ np.diag(m.body_inertia[body]) @ rot.T
    io = ic + mass * (c @ c * np.eye(3) - np.outer(c, c))
    return np.array([mass, *(mass * c), io[0, 0], io[0, 1], io[0, 2], io[1, 1], io[1, 2], io[2, 2]])


def inertia_at_com(p: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(mass, centre of mass, 3x3 inertia about it) of standard parameters `p`."""
    mass = float(p[0])
    c = p[1:4] / mass if mass > 0 else np.zeros(3)
    io = np.array([[p[4], p[5], p[6]], [p[5], p[7], p[8]], [p[6], p[8], p[9]]])
    return mass, c, io - mass * (c @ c * np.eye(3) - np.outer(c, c))


def set_std(m: mujoco.MjModel, body: int, p: np.ndarray) -> None:
    """Write standard parameters into a body's mass, centre of mass and principal inertia (+ orientation)."""
    mass, c, ic = inertia_at_com(p)
    w, v = np.linalg.eigh(ic)
    if np.linalg.det(v) < 0:
        v[:, 0] *= -1.0
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, v.ravel())
    m.body_mass[body] = mass
    m.body_ipos[body] = c
    m.body_inertia[body] = w
    m.body_iquat[body] = quat
    # the compiler marks bodies whose inertial frame sits on (or turns with) the body frame, and MuJoCo
    # then skips body_ipos / body_iquat: a moved or turned inertial frame must clear the mark
    m.body_sameframe[body] = int(mujoco.mjtSameFrame.mjSAMEFRAME_NONE)


def point_mass(mass: float, com: np.ndarray) -> np.ndarray:
    """Standard parameters of a point mass at `com` (frame coordinates)."""
    c = np.asarray(com, dtype=np.float64)
    io = mass * (c @ c * np.eye(3) - np.outer(c, c))
    return np.array([mass, *(mass * c), io[0, 0], io[0, 1], io[0, 2], io[1, 1], io[1, 2], io[2, 2]])


def feasible(p: np.ndarray) -> str | None:
    """Why standard parameters are not a physical body (positive mass, inertia positive definite and
    obeying the triangle inequality), or None."""
    mass, _, ic = inertia_at_com(p)
    if mass <= 0:
        return f"mass {mass:.3g} kg is not positive"
    w = np.linalg.eigvalsh(ic)
    if w[0] <= 0:
        return f"inertia about the centre of mass is not positive definite (eigenvalues {np.round(w, 6).tolist()})"
    if w[2] > w[0] + w[1] + 1e-12:
        return f"principal inertias {np.round(w, 6).tolist()} break the triangle inequality"
    return None


# --- physically consistent links: the pseudo-inertia J = [[S, h], [h', m]], S = tr(I)/2 - I, J = U U' ---------
_TRIU = np.triu_indices(4)


def pseudo_inertia(p: np.ndarray) -> np.ndarray:
    """The 4x4 pseudo-inertia of standard parameters: positive definite exactly for a physical body
    (positive mass, inertia positive definite and obeying the triangle inequality; Wensing et al. 2017)."""
    io = np.array([[p[4], p[5], p[6]], [p[5], p[7], p[8]], [p[6], p[8], p[9]]])
    j = np.zeros((4, 4))
    j[:3, :3] = 0.5 * np.trace(io) * np.eye(3) - io
    j[:3, 3] = j[3, :3] = p[1:4]
    j[3, 3] = p[0]
    return j


def _std_of_j(j: np.ndarray) -> np.ndarray:
    """Standard parameters of pseudo-inertias (..., 4, 4) -> (..., 10)."""
    sig = j[..., :3, :3]
    tr = np.trace(sig, axis1=-2, axis2=-1)[..., None, None]
    io = tr * np.eye(3) - sig
    return np.stack(
        [
            j[..., 3, 3],
            j[..., 0, 3],
            j[..., 1, 3],
            j[..., 2, 3],
            io[..., 0, 0],
            io[..., 0, 1],
            io[..., 0, 2],
            io[..., 1, 1],
            io[..., 1, 2],
            io[..., 2, 2],
        ],
        axis=-1,
    )


LOG_DIAG = np.array([0, 4, 7, 9])  # positions of U's diagonal among its upper-triangular entries


def factor_of(p: np.ndarray) -> np.ndarray:
    """Log-Cholesky coordinates z (10,) of a body's parameters: J = U U', U upper triangular with diagonal
    exp(z); parameters that are not a physical body are first nudged just inside."""
    j = pseudo_inertia(p)
    w, v = np.linalg.eigh(j)
    j = (v * np.maximum(w, 1e-9 * max(float(w.max()), 1e-12))) @ v.T
    perm = np.eye(4)[::-1]
    low = np.linalg.cholesky(perm @ j @ perm)  # J = P L L' P, so U = P L P is upper triangular
    u = perm @ low @ perm
    z = u[_TRIU].copy()
    z[LOG_DIAG] = np.log(np.diag(u))
    return z


def std_of_factor(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Standard parameters (L, 10) of log-Cholesky coordinates (L, 10), and their Jacobians (L, 10, 10)."""
    z = np.atleast_2d(z)
    u = np.zeros((len(z), 4, 4))
    u[:, _TRIU[0], _TRIU[1]] = z
    idx = np.arange(4)
    u[:, idx, idx] = np.exp(z[:, LOG_DIAG])
    std = _std_of_j(u @ np.swapaxes(u, 1, 2))
    jac = np.empty((len(z), 10, 10))
    for k, (r, c) in enumerate(zip(*_TRIU)):
        col = u[:, :, c] * (
            u[:, r, c][:, None] if k in LOG_DIAG else 1.0
        )  # d(U)/dz_k = e_r e_c' (x U_rc on the diagonal)
        dj = np.zeros((len(z), 4, 4))
        dj[:, r, :] += col
        dj[:, :, r] += col
        jac[:, :, k] = _std_of_j(dj)
    return std, jac


def physical(p: np.ndarray) -> np.ndarray:
    """The nearest physical body's parameters (the pseudo-inertia's negative eigenvalues lifted to zero+)."""
    if feasible(p) is None:
        return p
    j = pseudo_inertia(p)
    w, v = np.linalg.eigh(j)
    j = (v * np.maximum(w, 1e-9 * max(float(w.max()), 1e-12))) @ v.T
    return _std_of_j(j)

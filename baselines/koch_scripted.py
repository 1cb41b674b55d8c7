"""The Koch reach expert (suite koch): closed-loop damped least-squares inverse kinematics, sent as joint goals.

Each control step it reads the joint positions and the target (`env_state`) from the observation, computes the
tool point and its Jacobian on a scratch copy of the env's own MuJoCo model, and moves the arm's five joints by a
damped least-squares step toward the target (at most `MAX_STEP` rad per joint per step; a joint at its limit that
the step would push further is held and the step re-solved with the others). The goal sent is that pose
plus the declared servos' gravity droop there (gravity torque / the actuator's stiffness), so a P servo settles on
the pose rather than below it; the gripper holds its start. Its goals are plain joint positions: it runs under any
perturbation (a weaker servo droops more; the closed loop corrects what it can).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from baselines.servo_excitation import ServoExcitation

ARM = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll")
DAMPING = 0.02  # m: the least-squares damping (lambda)
MAX_STEP = 0.12  # rad per joint per control step
GAIN = 0.8  # share of the remaining error asked for per step

# the excitation pose (rad; the arm raised, clear of the floor for every goal within the amplitudes: 0 of 500
# random goals touch it) and each joint's amplitude
EXCITE_POSE = np.array([0.0, 0.85, 0.75, -0.4, 0.0, 0.6])
EXCITE_AMPLITUDE = np.array([0.6, 0.25, 0.3, 0.5, 1.0, 0.35])


class KochExpert:
    """Closed-loop reach for `suites.koch.KochEnv` (the unwrapped env: its model and tool body)."""

    def __init__(self, env: Any):
        import mujoco  # MuJoCo's native library: loaded only when the expert plans

        self._mj = mujoco
        m = env.mujoco.model
        self.model = m
        self._scratch = mujoco.MjData(m)
        joints = [m.joint(j) for j in ARM]
        self._qadr = np.array([j.qposadr[0] for j in joints])
        self._dofs = np.array([j.dofadr[0] for j in joints])
        self._lo, self._hi = m.jnt_range[[j.id for j in joints]].T
        acts = np.array([m.actuator(j).id for j in ARM])
        self._stiffness = m.actuator_gainprm[acts, 0].copy()
        self._tool = m.body("gripper_tcp").id
        self._gripper: float | None = None

    def reset(self, seed: int) -> None:
        self._gripper = None

    def act(self, obs: dict) -> np.ndarray:
        if "state" not in obs:
            raise ValueError(
                "the Koch expert reads the joints and the target from obs['state'] (obs=state or state+rgb)"
            )
        state = np.asarray(obs["state"], np.float64)
        q, target = state[:6], state[6:9]
        if self._gripper is None:
            self._gripper = float(q[5])
        mj, m, d = self._mj, self.model, self._scratch
        d.qpos[:] = 0.0
        d.qpos[self._qadr] = q[:5]
        mj.mj_kinematics(m, d)
        mj.mj_comPos(m, d)
        jacp = np.zeros((3, m.nv))
        mj.mj_jacBody(m, d, jacp, None, self._tool)
        J = jacp[:, self._dofs]
        err = GAIN * (target - d.xpos[self._tool])
        free = np.ones(5, bool)
        for _ in range(5):  # a joint at its limit that the step pushes further is held, the others re-solved
            Jf = J[:, free]
            dq = np.zeros(5)
            dq[free] = Jf.T @ np.linalg.solve(Jf @ Jf.T + DAMPING**2 * np.eye(3), err)
            blocked = free & (((q[:5] >= self._hi - 1e-3) & (dq > 0)) | ((q[:5] <= self._lo + 1e-3) & (dq < 0)))
            if not blocked.any():
                break
            free &= ~blocked
        want = np.clip(q[:5] + np.clip(dq, -MAX_STEP, MAX_STEP), self._lo, self._hi)
        d.qpos[self._qadr] = want
        d.qvel[:] = 0.0
        mj.mj_forward(m, d)
        droop = d.qfrc_bias[self._dofs] / self._stiffness  # gravity torque at the wanted pose over the stiffness
        return np.append(want + droop, self._gripper).astype(np.float32)


def excitation(cell: Any, env: Any, ctx: Any) -> ServoExcitation:
    """`policy=baselines.koch_scripted:excitation`: the servo excitation for suite koch."""
    return ServoExcitation(EXCITE_POSE, EXCITE_AMPLITUDE, float(getattr(env, "fps", 30.0) or 30.0))

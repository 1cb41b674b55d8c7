"""The SO-101 pick-cube expert (suite so101): a top-down grasp planned with inverse kinematics, sent as joint goals.

At reset it reads the cube's position from the first observation (`env_state`), solves three arm poses on a
copy of the env's own MuJoCo model (hover 5 cm above the cube, grasp, lift 10 cm) with damped least squares —
the point between the jaw pads on the target, the approach axis pointing down and the jaws across world y,
several seeds, the best kept — and plays them as linearly interpolated joint goals: hover, descend, close the
jaw, lift, hold. Its goals are plain joint positions, so it runs under any perturbation; the plan is open loop.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from baselines.servo_excitation import ServoExcitation

ARM = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll")
DOWN = np.array([0.0, 0.0, -1.0])
OPEN, CLOSED = 1.2, -0.17  # gripper goals, rad (closed is the joint's lower limit: the servo squeezes)
HOVER, GRASP, LIFT = 0.05, 0.003, 0.10  # m above the cube's centre
# (segment, control steps, gripper): the plan, 30 fps
SCHEDULE: tuple[tuple[str, int, float], ...] = (
    ("hover", 30, OPEN),
    ("hover", 5, OPEN),
    ("grasp", 20, OPEN),
    ("grasp", 5, OPEN),
    ("grasp", 15, CLOSED),
    ("lift", 30, CLOSED),
    ("lift", 15, CLOSED),
)


class SO101Expert:
    """Scripted pick for `suites.so101.SO101Env` (the unwrapped env: its model and grasp-point offset)."""

    def __init__(self, env: Any):
        import mujoco  # MuJoCo's native library: loaded only when the expert plans

        self._mj = mujoco
        self.model = env.mujoco.model
        self.offset = np.asarray(env.grasp_offset)
        self._scratch = mujoco.MjData(self.model)
        self._qadr = np.array([self.model.joint(j).qposadr[0] for j in ARM])
        self._dofs = np.array([self.model.joint(j).dofadr[0] for j in ARM])
        self._lo, self._hi = self.model.jnt_range[[self.model.joint(j).id for j in ARM]].T
        self._site = self.model.site("gripperframe").id
        self._base_x = float(self.model.body("shoulder").pos[0])
        self._plan: list[np.ndarray] = []
        self._t = 0

    def reset(self, seed: int) -> None:
        self._plan, self._t = [], 0

    def _point(self, d: Any) -> np.ndarray:
        return d.site_xpos[self._site] + d.site_xmat[self._site].reshape(3, 3) @ self.offset

    def solve(
        self, seed: np.ndarray, target: np.ndarray, weight: float = 0.3, iters: int = 100
    ) -> tuple[np.ndarray, float]:
        """Arm joints placing the grasp point at `target`, approach down, jaws across y; and the position error."""
        m, d = self.model, self._scratch
        jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        q = seed.copy()
        err = np.inf
        for _ in range(iters):
            d.qpos[self._qadr] = q
            self._mj.mj_kinematics(m, d)
            self._mj.mj_comPos(m, d)
            rot = d.site_xmat[self._site].reshape(3, 3)
            p = self._point(d)
            self._mj.mj_jac(m, d, jp, jr, p, m.site_bodyid[self._site])
            approach, jaw = rot[:, 0], rot[:, 2]
            err = float(np.linalg.norm(target - p))
            e = np.concatenate([target - p, weight * np.cross(approach, DOWN), [-weight * jaw[0]]])
            d_approach = -np.array([np.cross(jr[:, k], approach) for k in self._dofs]).T
            j_approach = np.array([np.cross(c, DOWN) for c in d_approach.T]).T
            j_jaw = np.array([np.cross(jr[:, k], jaw) for k in self._dofs]).T
            jac = np.vstack([jp[:, self._dofs], weight * j_approach, weight * j_jaw[0:1]])
            dq = jac.T @ np.linalg.solve(jac @ jac.T + 1e-4 * np.eye(len(e)), e)
            q = np.clip(q + dq, self._lo, self._hi)
        return q, err

    def best(self, start: np.ndarray, target: np.ndarray) -> np.ndarray:
        """`solve` from the start pose and from canonical reaching poses; the smallest error wins."""
        pan = np.arctan2(target[1], target[0] - self._base_x)
        poses = ((0.5, -0.3, 1.3), (0.0, 0.0, 1.5), (0.8, -0.8, 1.2))
        seeds = [start] + [np.array([s * pan, a, b, c, 1.57]) for s in (1, -1) for a, b, c in poses]
        return min((self.solve(s, target) for s in seeds), key=lambda r: r[1])[0]

    def plan(self, obs: dict) -> list[np.ndarray]:
        state = np.asarray(obs["state"], np.float64)
        q0, cube = state[:5], state[6:9]
        hover = self.best(q0, cube + [0, 0, HOVER])
        grasp = self.best(hover, cube + [0, 0, GRASP])
        lift = self.solve(grasp, cube + [0, 0, LIFT], weight=0.03)[0]  # a loose wrist: lifting is what counts
        poses = {"hover": hover, "grasp": grasp, "lift": lift}
        out, prev = [], q0
        for name, steps, grip in SCHEDULE:
            for t in np.linspace(0.0, 1.0, steps + 1)[1:]:
                out.append(np.append(prev + (poses[name] - prev) * t, grip))
            prev = poses[name]
        return out

    def act(self, obs: dict) -> np.ndarray:
        if not self._plan:
            if "state" not in obs:
                raise ValueError(
                    "the SO-101 expert reads the cube's position from obs['state'] (obs=state or state+rgb)"
                )
            self._plan = self.plan(obs)
        step = self._plan[min(self._t, len(self._plan) - 1)]
        self._t += 1
        return step.astype(np.float32)


# -- excitation for servo calibration -----------------------------------------------------------------------------
# the arm's excitation pose (rad; the gripper 15 cm above the floor, clear of the cube's spawn region) and the
# amplitude of each joint's goal about it
EXCITE_POSE = np.array([0.0, -0.3, 0.2, 0.3, 0.0, 0.4])
EXCITE_AMPLITUDE = np.array([0.6, 0.35, 0.35, 0.5, 1.0, 0.35])


def excitation(cell: Any, env: Any, ctx: Any) -> ServoExcitation:
    """`policy=baselines.so101_scripted:excitation`: the servo excitation for suite so101 (the scripted pick
    moves each joint once, slowly, and squeezes the cube, a contact the arm's model has not: too little to
    identify a servo)."""
    return ServoExcitation(EXCITE_POSE, EXCITE_AMPLITUDE, float(getattr(env, "fps", 30.0) or 30.0))

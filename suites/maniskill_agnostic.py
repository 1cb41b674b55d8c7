"""Embodiment-agnostic observation and action for ManiSkill robots (the `ManiSkillInterface` of
maniskill_held_out_robots).

Observation (the same 24 numbers on every robot, `STATE_FIELDS`): tool-centre-point position
(world; the point between the fingertips when the gripper is closed), its orientation relative to
the orientation at reset (a robot's TCP frame is its own, so only relative orientation compares),
gripper opening (1 = fully open, 0 = fully closed, from the
gripper's joint range), object position and orientation, TCP-to-object vector, goal position and
object-to-goal vector.

Action (`ACTION_NAMES`): a world-frame TCP displacement, 1.0 = 0.1 m per control step (ManiSkill's
`pd_ee_delta_pos` scale), and a gripper command, +1 closes and -1 opens (as in held_out_robots).
Panda and Panda with wrist camera run ManiSkill's own `pd_ee_delta_pos` controller (the delta is
rotated into the controller's root frame). The SO-100 has no Cartesian controller in ManiSkill, and
Fetch's does not move from its reset pose on the CPU backend (its IK step stalls: measured, the TCP
moves 2 cm and stops): both are driven through `pd_joint_pos` by one damped-least-squares step per
control step on a numerical Jacobian of the TCP (position first; orientation held near its reset
value with a low weight, since the SO-100's 5 joints cannot hold both). ManiSkill places the
objects beyond the reach of Fetch's arm from where its base starts, so Fetch's step also uses the
base's forward motion (a weighted joint of the least-squares step, sent as the base's forward
velocity); its head and torso are held still.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bench.api.sims import quat_conj, quat_mul
from bench.protocols import ActionSpec
from suites.lift import OBS_FIELDS

# held_out_robots' agnostic observation (suites.lift) and the goal
STATE_FIELDS: tuple[tuple[str, int], ...] = (*OBS_FIELDS, ("goal_pos", 3), ("object_to_goal", 3))
ACTION_NAMES = ("dx", "dy", "dz", "gripper")
STEP_M = 0.1  # metres of TCP displacement per unit of action
CARTESIAN = ("panda", "panda_wristcam")  # robots run by ManiSkill's pd_ee_delta_pos
# robots run by our DLS step on pd_joint_pos: TCP = mean of these links' origins, orientation = last link's
JOINT_DLS = {"so100": ("Fixed_Jaw_tip", "Moving_Jaw_tip", "Fixed_Jaw"), "fetch": ("gripper_link", "gripper_link")}
BASE_JOINT = {"fetch": "root_x_axis_joint"}  # a mobile base's forward joint the DLS step may use
BASE_COST = 4.0  # how much more a metre of base motion costs than a radian/metre of arm motion
ROBOTS = CARTESIAN + tuple(JOINT_DLS)


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    return quat_mul(quat_mul(q, np.append(0.0, v)), quat_conj(q))[1:]


def _np(x: Any) -> np.ndarray:
    return x[0].cpu().numpy().astype(np.float64)


class AgnosticInterface:
    """The agnostic observation/action of one (task, robot) cell; `object_attr`/`goal_attr` name the task's actors."""

    uses_ms_state = False
    state_fields = STATE_FIELDS
    action_spec = ActionSpec.box(ACTION_NAMES, -1.0, 1.0)

    def __init__(self, robot: str, object_attr: str, goal_attr: str):
        if robot not in ROBOTS:
            raise ValueError(f"robot {robot!r}: the agnostic interface knows {', '.join(ROBOTS)}")
        self.robot, self.object_attr, self.goal_attr = robot, object_attr, goal_attr
        self.control_mode: str | None = "pd_ee_delta_pos" if robot in CARTESIAN else "pd_joint_pos"
        self._quat0_conj = np.array([1.0, 0.0, 0.0, 0.0])

    # -- ManiSkillInterface ----------------------------------------------------------------
    def bind(self, env: Any) -> None:
        base = env.base
        self.base, self.agent = base, base.agent
        self.obj, self.goal = getattr(base, self.object_attr), getattr(base, self.goal_attr)
        ctrl = self.agent.controller
        self._parts = getattr(ctrl, "controllers", None) or {"joints": ctrl}
        self._widths = {k: int(c.single_action_space.shape[0]) for k, c in self._parts.items()}
        limits = self.agent.robot.get_qlimits()[0].cpu().numpy()
        if "gripper" in self._parts:  # a mimic two-finger gripper: normalised command, +1 = config.upper
            grip = self._parts["gripper"]
            self._grip_idx = int(grip.active_joint_indices[0])
            self._open = float(grip.config.upper)
            self._closed = max(float(grip.config.lower), float(limits[self._grip_idx, 0]))
        else:  # SO-100: one joint controller over arm + jaw; jaw at 0 is 8 cm open, its lower limit shut
            self._grip_idx = len(limits) - 1
            self._open, self._closed = 0.0, float(limits[-1, 0])
        if self.robot in JOINT_DLS:
            self._bind_dls(limits)

    def on_reset(self) -> None:
        self._quat0_conj = quat_conj(self._tcp_quat())
        if self.robot in JOINT_DLS:
            self._R0 = self._fk(self._qpos())[1]

    def state(self, ms_state: np.ndarray | None) -> np.ndarray:
        eef = self._tcp_pos()
        rel = quat_mul(self._quat0_conj, self._tcp_quat())
        obj_pose = _np(self.obj.pose.raw_pose)
        goal = _np(self.goal.pose.p)
        q = self._qpos()[self._grip_idx]
        opening = min(1.0, max(0.0, (q - self._closed) / (self._open - self._closed)))
        out = np.concatenate(
            [
                eef,
                rel if rel[0] >= 0 else -rel,
                [opening],
                obj_pose[:3],
                obj_pose[3:],
                obj_pose[:3] - eef,
                goal,
                goal - obj_pose[:3],
            ]
        )
        return out.astype(np.float32)

    def command(self, action: np.ndarray) -> np.ndarray:
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        delta, grip = a[:3] * STEP_M, float(a[3])
        out: list[Any] = []
        for name, ctrl in self._parts.items():
            if name == "arm" and self.robot in CARTESIAN:  # root-frame translation, normalised to +-0.1 m
                root_q = _np(ctrl.root_link.pose.q)
                out.append(_rotate(quat_conj(root_q), delta) / STEP_M)
            elif name == "arm":
                arm, base_v = self._dls_targets(delta)
                out.append(arm)
            elif name == "joints":  # SO-100: arm targets + absolute jaw target
                jaw = self._open + (grip + 1.0) / 2.0 * (self._closed - self._open)
                out.append(np.append(self._dls_targets(delta)[0], jaw))
            elif name == "base":  # Fetch: forward velocity from the DLS step (normalised: 1 = 1 m/s), no turning
                out.append([np.clip(base_v, -1.0, 1.0), 0.0])
            elif name == "gripper":  # ManiSkill: +1 opens
                out.append([-grip])
            else:  # Fetch's body (joint deltas) and base (velocities): hold still
                out.append(np.zeros(self._widths[name]))
        return np.concatenate(out).astype(np.float32)

    # -- robot state ---------------------------------------------------------------------------
    def _qpos(self) -> np.ndarray:
        return _np(self.agent.robot.get_qpos())

    def _tcp_pos(self) -> np.ndarray:
        if self.robot in JOINT_DLS:
            return self._fk(self._qpos())[0]
        return _np(self.agent.tcp_pose.p)

    def _tcp_quat(self) -> np.ndarray:
        return _np(self.agent.tcp_pose.q)

    # -- SO-100, Fetch: damped least squares on pd_joint_pos ----------------------------------
    _ROT_WEIGHT = 0.3  # metres of position error one radian of orientation error is worth
    _DAMPING = 0.05

    def _bind_dls(self, limits: np.ndarray) -> None:
        robot = self.agent.robot
        self._pin = robot._objs[0].create_pinocchio_model()
        names = [link.name for link in robot.links]  # same order as the PhysX articulation's links
        self._tcp_links = [names.index(n) for n in JOINT_DLS[self.robot]]
        ctrl: Any = self._parts.get("arm", self._parts.get("joints"))
        arm = [int(i) for i in ctrl.active_joint_indices]
        self._arm = np.array(arm if "arm" in self._parts else arm[:-1])  # SO-100: all but the jaw
        self._arm_limits = limits[self._arm]
        joints = [j.name for j in robot.active_joints]
        self._base = joints.index(BASE_JOINT[self.robot]) if self.robot in BASE_JOINT else None
        self._dof = np.append(self._arm, [] if self._base is None else [self._base]).astype(int)
        self._cost = np.append(np.ones(len(self._arm)), [] if self._base is None else [BASE_COST])
        self._dt = 1.0 / float(self.base.control_freq)

    def _fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """TCP position and orientation (world) at joint positions `q`, from the root's current pose.

        The TCP is taken with the gripper closed: the point the fingers close on, fixed in the hand
        (an SO-100's tip midpoint moves 2 cm up and sideways as its jaw opens).
        """
        q = q.copy()
        q[self._grip_idx] = self._closed
        self._pin.compute_forward_kinematics(q)
        root = self.agent.robot.pose.sp
        poses = [root * self._pin.get_link_pose(i) for i in self._tcp_links]
        pos_links = poses[:-1] if len(poses) > 2 else poses[:1]
        return np.mean([p.p for p in pos_links], axis=0), poses[-1].to_transformation_matrix()[:3, :3]

    @staticmethod
    def _rot_err(R: np.ndarray, R_target: np.ndarray) -> np.ndarray:
        return 0.5 * sum(np.cross(R[:, i], R_target[:, i]) for i in range(3))

    def _dls_targets(self, delta: np.ndarray) -> tuple[np.ndarray, float]:
        """Arm joint targets (and base forward velocity) moving the TCP by `delta` (world frame)."""
        q = self._qpos()
        p0, R0 = self._fk(q)
        err = np.concatenate([delta, self._ROT_WEIGHT * self._rot_err(R0, self._R0)])
        jac = np.empty((6, len(self._dof)))
        eps = 1e-4
        for k, j in enumerate(self._dof):
            dq = q.copy()
            dq[j] += eps
            p, R = self._fk(dq)
            jac[:, k] = np.concatenate([(p - p0) / eps, -self._ROT_WEIGHT * self._rot_err(R, R0) / eps])
        winv = 1.0 / self._cost  # weighted damped least squares: costly joints move less
        step = winv * (jac.T @ np.linalg.solve((jac * winv) @ jac.T + self._DAMPING**2 * np.eye(6), err))
        arm = np.clip(q[self._arm] + step[: len(self._arm)], self._arm_limits[:, 0], self._arm_limits[:, 1])
        base_v = float(step[-1]) / self._dt if self._base is not None else 0.0
        return arm, base_v

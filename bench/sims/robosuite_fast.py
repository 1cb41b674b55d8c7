"""The robosuite fast path: the same controller and the same physics, without the per-step work nobody reads.

robosuite's `env.step` runs its physics at 500 Hz under a 20 Hz policy: 25 substeps, each
`mj_step1`, the robot's composite controller (operational-space control of the arm, the gripper's
joint-velocity command), `mj_step2`, then every observable. On a single arm about 80% of that
is Python outside MuJoCo (profile in docs/performance.md): the controller's state is re-read twice
per substep (origin pose, reference site, three Jacobian computations per site), action limits are
rebuilt three times per substep just to check the action's length, the gripper command — constant
over a policy step — is recomputed 25 times, all 13 observables are polled at every substep, and the
robot's proprioceptive history buffers (never read by a bench observation, reward or success) are
pushed after every policy step.

`FastStep.step` computes the same torques with the same numpy and numba calls in the same order on
arrays of the same layout (robosuite's own `orientation_error`, `opspace_matrices` and
`nullspace_torques`; robosuite's own `set_goal`, `reward` and success check), so every control,
state, reward and observation it produces equals robosuite's bit for bit
(tests/test_robosuite_fast.py compares them on every arm and scene the suites use). What it leaves
out: the repeated look-ups, the duplicated Jacobians, the observables the observer does not read
(those it reads still go through robosuite's own `Observable.update`, so their sampling times
are unchanged) and the history buffers.

It applies only to the configuration it was checked against (`FastStep.reason_not`): one
fixed-base arm, robosuite's BASIC composite controller with the default OSC_POSE arm controller
(delta input in the base frame, fixed impedance, uncoupled, no interpolator) and a SimpleGrip
gripper, lite physics, no viewer, and the stock `step`/`_pre_action`/`control` methods. Anything
else steps through robosuite's own `env.step`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from robosuite.environments.robot_env import RobotEnv
    from robosuite.utils.observables import Observable

# the ufunc np.clip calls, without np.clip's argument handling (the same values)
_CLIP: np.ufunc = np.core.umath.clip  # type: ignore[attr-defined]  # numpy's stubs omit umath's ufuncs


def reason_not(raw: RobotEnv) -> str | None:
    """Why the fast path does not apply to robosuite env `raw` (None when it does)."""
    from robosuite.controllers.composite.composite_controller import (  # robosuite: loaded only when its env is made
        CompositeController,
    )
    from robosuite.controllers.parts.arm.osc import (  # robosuite: loaded only when its env is made
        OperationalSpaceController,
    )
    from robosuite.controllers.parts.gripper.simple_grip import (  # robosuite: loaded only when its env is made
        SimpleGripController,
    )
    from robosuite.environments.base import MujocoEnv  # robosuite: loaded only when its env is made
    from robosuite.environments.robot_env import RobotEnv  # robosuite: loaded only when its env is made
    from robosuite.robots.fixed_base_robot import FixedBaseRobot  # robosuite: loaded only when its env is made

    cls = type(raw)
    if cls.step is not MujocoEnv.step or cls._pre_action is not RobotEnv._pre_action:
        return f"{cls.__name__} overrides step or _pre_action"
    if not getattr(raw, "lite_physics", False):
        return "lite_physics is off"
    if raw.has_renderer or raw.viewer is not None or raw.viewer_get_obs:
        return "an on-screen viewer is open"
    if len(raw.robots) != 1 or type(raw.robots[0]) is not FixedBaseRobot:
        return "not one fixed-base arm"
    robot = raw.robots[0]
    if type(robot).control is not FixedBaseRobot.control:
        return "the robot overrides control"
    cc = robot.composite_controller
    if type(cc) is not CompositeController:
        return f"composite controller {type(cc).__name__} (fast path: BASIC)"
    if list(cc.part_controllers) != ["right", "right_gripper"]:
        return f"controller parts {list(cc.part_controllers)} (fast path: right, right_gripper)"
    osc, grip = cc.part_controllers["right"], cc.part_controllers["right_gripper"]
    if type(osc) is not OperationalSpaceController or type(grip) is not SimpleGripController:
        return f"controllers {type(osc).__name__}, {type(grip).__name__} (fast path: OSC, SimpleGrip)"
    checks = {
        "input_type": "delta",
        "input_ref_frame": "base",
        "impedance_mode": "fixed",
        "uncoupling": True,
        "interpolator_pos": None,
        "interpolator_ori": None,
        "use_ori": True,
        "_goal_update_mode": "achieved",
        "num_ref_sites": 1,
        "position_limits": None,
    }
    for key, want in checks.items():
        if getattr(osc, key, None) != want:
            return f"OSC {key}={getattr(osc, key, None)!r} (fast path: {want!r})"
    if np.array(osc.orientation_limits).any():
        return "OSC orientation limits are set"
    if grip.interpolator is not None:
        return "the gripper controller interpolates"
    if not all(robot._enabled_parts.get(p, False) for p in ("right", "right_gripper")):
        return "a controller part is disabled"
    return None


class FastStep:
    """`robosuite env.step` for the configuration `reason_not` accepts, computing only what is read.

    `keys`: the raw observation entries the caller reads (None: all of them, as robosuite returns).
    `ctrl_log`: a list-like noting `data.ctrl` before every physics step while not None
    (`bench.protocols.InputLog.rows`), read through `log_rows()` at every step.
    """

    def __init__(
        self, raw: RobotEnv, keys: tuple[str, ...] | None, log_rows: Callable[[], list[np.ndarray] | None]
    ) -> None:
        import mujoco  # MuJoCo's native library: loaded only when a model is simulated
        from robosuite.controllers.parts.arm import osc as osc_mod  # robosuite: loaded only when its env is made

        self.raw = raw
        self._mj = mujoco
        self._orientation_error = osc_mod.orientation_error
        self._opspace_matrices = osc_mod.opspace_matrices
        self._nullspace_torques = osc_mod.nullspace_torques
        self._log_rows = log_rows
        self.keys = keys
        model, data = raw.sim.model._model, raw.sim.data._data
        self._model, self._data = model, data
        nv = model.nv
        self._jacp = np.zeros((3, nv))
        self._jacr = np.zeros((3, nv))
        self._jacp_c = np.zeros((3, nv))
        self._jacr_c = np.zeros((3, nv))
        self._full_m: np.ndarray = np.ndarray(shape=(nv, nv), dtype=np.float64, order="C")

    def _observables(self) -> list[Observable]:
        obs = self.raw._observables
        if self.keys is None:
            return list(obs.values())
        return [obs[k] for k in self.keys]

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, dict]:
        """One policy step: robosuite's `(observations, reward, done, info)`."""
        env, mj, m, d = self.raw, self._mj, self._model, self._data
        if env.done:
            raise ValueError("executing action in terminated episode")
        robot = env.robots[0]
        if len(action) != env.action_dim:
            raise AssertionError(
                f"environment got invalid action dimension -- expected {env.action_dim}, got {len(action)}"
            )
        env.timestep += 1
        # per policy step (robosuite rebuilds the controllers at every reset: look them up again)
        cc = robot.composite_controller
        osc, grip = cc.part_controllers["right"], cc.part_controllers["right_gripper"]
        arm_act = robot._ref_actuators_indexes_dict["right"]
        grip_act = robot._ref_actuators_indexes_dict[robot.get_gripper_name("right")]
        arm_low, arm_high = m.actuator_ctrlrange[arm_act, 0], m.actuator_ctrlrange[arm_act, 1]
        grip_low, grip_high = m.actuator_ctrlrange[grip_act, 0], m.actuator_ctrlrange[grip_act, 1]
        center = m.site(f"{osc.naming_prefix}{osc.part_name}_center").id
        ref = m.site(osc.ref_name).id
        # index arrays once per step (robosuite passes lists, which numpy converts at every use: same elements)
        qpos_i, qvel_i = np.asarray(osc.qpos_index, dtype=np.intp), np.asarray(osc.qvel_index, dtype=np.intp)
        arm_act = np.asarray(arm_act, dtype=np.intp)
        grip_act = np.asarray(grip_act, dtype=np.intp)
        kp_pos, kp_ori = np.array(osc.kp[0:3]), np.array(osc.kp[3:6])
        kd_pos, kd_ori = osc.kd[0:3], osc.kd[3:6]
        initial_joint = osc.initial_joint
        observables = self._observables()
        timestep, cache = env.model_timestep, env._obs_cache
        jacp, jacr, jacp_c, jacr_c, full_m = self._jacp, self._jacr, self._jacp_c, self._jacr_c, self._full_m
        qvel, qpos, qfrc_bias, site_xpos, site_xmat, ctrl = (
            d.qvel,
            d.qpos,
            d.qfrc_bias,
            d.site_xpos,
            d.site_xmat,
            d.ctrl,
        )
        orientation_error, opspace, nullspace = self._orientation_error, self._opspace_matrices, self._nullspace_torques
        dot, array, multiply, concatenate, clip = np.dot, np.array, np.multiply, np.concatenate, _CLIP
        step1, step2, jac_site, full_mass = mj.mj_step1, mj.mj_step2, mj.mj_jacSite, mj.mj_fullM
        rows = self._log_rows()
        n = len(qvel_i)
        c_pos, c_ori, c_full = np.zeros((3, n)), np.zeros((3, n)), np.zeros((6, n))
        # the controller's origin site welded to the world: its pose and (zero) Jacobian are the same bits at
        # every substep, so the origin, the goal in the world frame and the site Jacobian are read once per step
        fixed_origin = bool(m.body_weldid[m.site_bodyid[center]] == 0)
        for i in range(int(env.control_timestep / env.model_timestep)):
            step1(m, d)
            if i == 0 or not fixed_origin:
                # robosuite's update_state(): the controller's origin
                origin_pos = array(site_xpos[center])
                origin_ori = array(site_xmat[center].reshape([3, 3]))
                jac_site(m, d, jacp_c, jacr_c, center)
            if i == 0:
                # robosuite's control() at a policy step: update_state, set_goal (whose update() reads the
                # reference data, unless the controller still holds fresh data from its reset), run_controller
                osc.update_origin(origin_pos, origin_ori)
                cc.set_goal(action)  # robosuite's own: the gripper's format_action and the OSC goal
                # the gripper's command is constant over the policy step (goal_qvel does not change)
                grip_ctrl = clip(grip.run_controller(), grip_low, grip_high)
                goal_pos, goal_ori = osc.goal_pos, osc.goal_ori
                ref_pos, ref_ori_mat = osc.ref_pos, osc.ref_ori_mat
                ref_pos_vel, ref_ori_vel = osc.ref_pos_vel, osc.ref_ori_vel
                j_pos, j_ori, j_full = osc.J_pos, osc.J_ori, osc.J_full
                joint_pos, joint_vel, mass_matrix = osc.joint_pos, osc.joint_vel, osc.mass_matrix
            else:
                # the OSC's update(): reference site pose, velocities, Jacobians, joint state, mass matrix
                ref_pos = array(site_xpos[ref])
                ref_ori_mat = array(site_xmat[ref].reshape([3, 3]))
                jac_site(m, d, jacp, jacr, ref)
                ref_pos_vel = dot(jacp, qvel)
                ref_ori_vel = dot(jacr, qvel)
                # into C-ordered arrays as robosuite does (a fancy-indexed copy is F-ordered, and BLAS
                # sums a transposed product in another order for each: the last bits would differ)
                j_pos, j_ori, j_full = c_pos, c_ori, c_full
                j_pos[:, :] = jacp[:, qvel_i]
                j_ori[:, :] = jacr[:, qvel_i]
                j_full[:3] = j_pos  # robosuite: np.vstack([J_pos, J_ori]), the same numbers
                j_full[3:] = j_ori
                joint_pos = qpos[qpos_i]
                joint_vel = qvel[qvel_i]
                full_mass(m, full_m, d.qM)
                mass_matrix = full_m[qvel_i, :][:, qvel_i]
            if i == 0 or not fixed_origin:
                desired_world_pos = origin_pos + dot(origin_ori, goal_pos)
                desired_world_ori = dot(origin_ori, goal_ori)
            # the OSC's run_controller()
            ori_error = orientation_error(desired_world_ori, ref_ori_mat)
            position_error = desired_world_pos - ref_pos
            vel_pos_error = -(ref_pos_vel - dot(jacp_c, qvel))
            desired_force = multiply(position_error, kp_pos) + multiply(vel_pos_error, kd_pos)
            vel_ori_error = -(ref_ori_vel - dot(jacr_c, qvel))
            desired_torque = multiply(ori_error, kp_ori) + multiply(vel_ori_error, kd_ori)
            _, lambda_pos, lambda_ori, nullspace_matrix = opspace(mass_matrix, j_full, j_pos, j_ori)
            decoupled_wrench = concatenate([dot(lambda_pos, desired_force), dot(lambda_ori, desired_torque)])
            torques = dot(j_full.T, decoupled_wrench) + qfrc_bias[qvel_i]
            torques += nullspace(mass_matrix, nullspace_matrix, initial_joint, joint_pos, joint_vel)
            # robot.control(): clip to the actuators' ranges and command them
            ctrl[arm_act] = clip(torques, arm_low, arm_high)
            ctrl[grip_act] = grip_ctrl
            if rows is not None:
                rows.append(ctrl.copy())
            step2(m, d)
            for observable in observables:
                observable.update(timestep=timestep, obs_cache=cache, force=False)
        osc.torques = torques
        osc.new_update = True
        env.cur_time += env.control_timestep
        reward, done, info = env._post_action(action)
        if self.keys is None:
            return env._get_observations(), reward, done, info
        obs = env._observables
        return {k: obs[k].obs for k in self.keys}, reward, done, info

"""Scripted ALOHA experts (suite=aloha, policy=scripted): ACT's end-effector trajectories as joint targets.

This is how the ALOHA sim datasets lerobot trains on were made (Zhao et al. 2023, ACT's
`scripted_policy.py` and `record_sim_episodes.py`): a scripted trajectory of both grippers is
written as waypoints in end-effector space from the objects' start poses, executed in gym-aloha's
end-effector model (the grippers welded to mocap bodies), and the arms' joint angles it produces,
with the commanded gripper openings, are replayed as the joint-space env's 14-D absolute targets.

The planner model is gym-aloha's end-effector MJCF with the arms' joint dry friction removed
(MuJoCo 3's soft mocap welds cannot overcome it, and the grippers stall short of their targets).
The expert reads only its observation: the objects' start poses (`state.env_state`) at the first
step. It answers that step with the whole trajectory as an action chunk (400 rows, executed open
loop); later calls (a horizon past 400) hold the last targets. The end-effector model runs here,
in the policy, never in the env being evaluated; it is nominal (scenes and perturbations change
the evaluated env only), so under held-out physics the expert replays the nominal plan.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bench.api.sims import quat_mul

STEPS = 400  # ACT's episode length for both tasks
EE_XML = {
    "transfer_cube": "bimanual_viperx_end_effector_transfer_cube.xml",
    "insertion": "bimanual_viperx_end_effector_insertion.xml",
}


def axis_angle(axis: tuple[float, float, float], degrees: float) -> np.ndarray:
    """The unit quaternion (w, x, y, z) of a rotation by `degrees` about `axis`."""
    half = np.radians(degrees) / 2.0
    return np.concatenate([[np.cos(half)], np.sin(half) * np.asarray(axis, float) / np.linalg.norm(axis)])


def waypoints(kind: str, left0: np.ndarray, right0: np.ndarray, env_state: np.ndarray) -> tuple[list, list]:
    """ACT's waypoints {t, xyz, quat, gripper (0 closed .. 1 open)} of the left and right grippers.

    `left0` / `right0`: the mocap poses at reset (xyz + quat); `env_state`: the objects' poses.
    """
    w = lambda t, xyz, quat, g: {"t": t, "xyz": np.asarray(xyz, float), "quat": np.asarray(quat, float), "gripper": g}
    if kind == "transfer_cube":
        box = env_state[:3]
        pick = quat_mul(right0[3:], axis_angle((0, 1, 0), -60))
        meet_left = axis_angle((1, 0, 0), 90)
        meet = np.array([0.0, 0.5, 0.25])
        left = [
            w(0, left0[:3], left0[3:], 0),  # sleep
            w(100, meet + [-0.1, 0, -0.02], meet_left, 1),  # approach the meeting point
            w(260, meet + [0.02, 0, -0.02], meet_left, 1),  # move to it
            w(310, meet + [0.02, 0, -0.02], meet_left, 0),  # close the gripper
            w(360, meet + [-0.1, 0, -0.02], [1, 0, 0, 0], 0),  # move left
            w(400, meet + [-0.1, 0, -0.02], [1, 0, 0, 0], 0),  # stay
        ]
        right = [
            w(0, right0[:3], right0[3:], 0),  # sleep
            w(90, box + [0, 0, 0.08], pick, 1),  # approach the cube
            w(130, box + [0, 0, -0.015], pick, 1),  # go down
            w(170, box + [0, 0, -0.015], pick, 0),  # close the gripper
            w(200, meet + [0.05, 0, 0], pick, 0),  # approach the meeting point
            w(220, meet, pick, 0),  # move to it
            w(310, meet, pick, 1),  # open the gripper
            w(360, meet + [0.1, 0, 0], pick, 1),  # move right
            w(400, meet + [0.1, 0, 0], pick, 1),  # stay
        ]
        return left, right
    peg, socket = env_state[:3], env_state[7:10]
    pick_right = quat_mul(right0[3:], axis_angle((0, 1, 0), -60))
    pick_left = quat_mul(right0[3:], axis_angle((0, 1, 0), 60))
    meet = np.array([0.0, 0.5, 0.15])
    lift_right = 0.00715
    left = [
        w(0, left0[:3], left0[3:], 0),  # sleep
        w(120, socket + [0, 0, 0.08], pick_left, 1),  # approach the socket
        w(170, socket + [0, 0, -0.03], pick_left, 1),  # go down
        w(220, socket + [0, 0, -0.03], pick_left, 0),  # close the gripper
        w(285, meet + [-0.1, 0, 0], pick_left, 0),  # approach the meeting point
        w(340, meet + [-0.05, 0, 0], pick_left, 0),  # insertion
        w(400, meet + [-0.05, 0, 0], pick_left, 0),  # stay
    ]
    right = [
        w(0, right0[:3], right0[3:], 0),  # sleep
        w(120, peg + [0, 0, 0.08], pick_right, 1),  # approach the peg
        w(170, peg + [0, 0, -0.03], pick_right, 1),  # go down
        w(220, peg + [0, 0, -0.03], pick_right, 0),  # close the gripper
        w(285, meet + [0.1, 0, lift_right], pick_right, 0),  # approach the meeting point
        w(340, meet + [0.05, 0, lift_right], pick_right, 0),  # insertion
        w(400, meet + [0.05, 0, lift_right], pick_right, 0),  # stay
    ]
    return left, right


def interpolate(trajectory: list[dict], t: int) -> np.ndarray:
    """xyz + quat + gripper at step `t`, linear between the waypoints around it (as ACT's BasePolicy)."""
    nxt = next(i for i, p in enumerate(trajectory) if p["t"] > t or i == len(trajectory) - 1)
    a, b = trajectory[max(nxt - 1, 0)], trajectory[nxt]
    frac = 0.0 if b["t"] == a["t"] else (t - a["t"]) / (b["t"] - a["t"])
    return np.concatenate(
        [
            a["xyz"] + (b["xyz"] - a["xyz"]) * frac,
            a["quat"] + (b["quat"] - a["quat"]) * frac,
            [a["gripper"] + (b["gripper"] - a["gripper"]) * frac],
        ]
    )


class EndEffectorSim:
    """gym-aloha's end-effector model of one task (mocap grippers), stepped by dm_control without images."""

    def __init__(self, kind: str):
        from dm_control import mujoco as dm_mujoco  # dm_control: loaded only when the expert plans
        from dm_control.rl import control  # dm_control: loaded only when the expert plans
        from dm_control.suite import base  # dm_control: loaded only when the expert plans
        from gym_aloha import constants  # gym-aloha: loaded only when the expert plans
        from gym_aloha.tasks import sim_end_effector as ee  # gym-aloha: loaded only when the expert plans

        parent = ee.TransferCubeEndEffectorTask if kind == "transfer_cube" else ee.InsertionEndEffectorTask

        class Task(parent):  # type: ignore[misc, valid-type]
            start: np.ndarray = np.zeros(0)

            def initialize_episode(self, physics: Any) -> None:
                self.initialize_robots(physics)
                physics.data.qpos[16 : 16 + len(self.start)] = self.start  # the objects where the env has them
                base.Task.initialize_episode(self, physics)

            def get_observation(self, physics: Any) -> dict:
                data = physics.data
                return {
                    "qpos": self.get_qpos(physics),
                    "mocap_pose_left": np.concatenate([data.mocap_pos[0], data.mocap_quat[0]]).copy(),
                    "mocap_pose_right": np.concatenate([data.mocap_pos[1], data.mocap_quat[1]]).copy(),
                    "gripper_ctrl": data.ctrl.copy(),
                }

        self.kind, self.task = kind, Task()
        self.physics = dm_mujoco.Physics.from_xml_path(str(constants.ASSETS_DIR / EE_XML[kind]))
        # The arms' joints have dry friction (30-60 N m) that the soft mocap welds cannot overcome near their
        # targets: the grippers stall centimetres short and push the objects. The planner's arms are frictionless
        # (only the plan comes from this model; the evaluated env keeps gym-aloha's friction).
        self.physics.model.ptr.dof_frictionloss[:16] = 0.0
        self.env = control.Environment(
            self.physics, self.task, time_limit=float("inf"), control_timestep=constants.DT, flat_observation=False
        )
        self.normalize = constants.normalize_puppet_gripper_position

    def joint_targets(self, env_state: np.ndarray, steps: int = STEPS) -> np.ndarray:
        """(steps, 14) joint targets: the arms' joints along the scripted trajectory, the commanded grippers."""
        self.task.start = np.asarray(env_state, float)
        ts = self.env.reset()
        obs = [ts.observation]
        left, right = waypoints(self.kind, obs[0]["mocap_pose_left"], obs[0]["mocap_pose_right"], self.task.start)
        for t in range(steps - 1):
            ts = self.env.step(np.concatenate([interpolate(left, t), interpolate(right, t)]))
            obs.append(ts.observation)
        out = np.array([o["qpos"] for o in obs], dtype=np.float64)
        ctrl = np.array([o["gripper_ctrl"] for o in obs])
        out[:, 6] = self.normalize(ctrl[:, 0])  # the commanded opening, not the measured one (as ACT records)
        out[:, 13] = self.normalize(ctrl[:, 2])
        return out.astype(np.float32)

    def close(self) -> None:
        self.physics.free()


class AlohaExpert:
    """suite=aloha's scripted expert: plans from the first observation, answers with the whole plan."""

    def __init__(self, env: Any):
        self.kind = env.kind
        fields = list(env.obs_spec["state"].fields)
        names = [n for n, _ in fields]
        self._offset = sum(w for _, w in fields[: names.index("env_state")])  # the objects' poses in the state
        self._width = dict(fields)["env_state"]
        self._sim: EndEffectorSim | None = None
        self._plan: np.ndarray | None = None

    def reset(self, seed: int) -> None:
        self._plan = None

    def act(self, obs: dict) -> np.ndarray:
        if self._plan is not None:
            return self._plan[-1]
        if self._sim is None:
            self._sim = EndEffectorSim(self.kind)
        state = np.asarray(obs["state"], float)
        self._plan = self._sim.joint_targets(state[self._offset : self._offset + self._width])
        return self._plan

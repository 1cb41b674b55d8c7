"""Scripted motion-planning solutions for ManiSkill tasks that ship none (PokeCube, RollBall).

Written like ManiSkill's own solutions (`mani_skill.examples.motionplanning.panda.solutions`):
`solve(env, seed=None, debug=False, vis=False)` plans screw motions with ManiSkill's Panda planner
from the true scene state and steps the env; `baselines.maniskill_mp.MotionPlanExpert` turns them
into policies. `SOLUTIONS` maps every ManiSkill task id the suites use to its solution.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np


def _planner(env: Any, **kwargs: Any) -> Any:
    from mani_skill.examples.motionplanning.panda.motionplanner import PandaArmMotionPlanningSolver

    return PandaArmMotionPlanningSolver(
        env,
        debug=False,
        vis=False,
        base_pose=env.unwrapped.agent.robot.pose,
        visualize_target_grasp_pose=False,
        print_env_info=False,
        **kwargs,
    )


def _p(x: Any) -> np.ndarray:
    return x.pose.p[0].cpu().numpy().astype(np.float64)


def solve_poke_cube(env: Any, seed: int | None = None, debug: bool = False, vis: bool = False) -> Any:
    """PokeCube: grasp the peg behind its middle, line its head up behind the cube, push the cube into the goal.

    The peg lies along +x with the cube 0.1 m beyond its head (at its own y) and the goal 0.1 m beyond
    the cube; the peg is carried 1 cm above the table, moved sideways first and forwards second so its
    head never sweeps through the cube.
    """
    import sapien
    from mani_skill.examples.motionplanning.base_motionplanner.utils import compute_grasp_info_by_obb, get_actor_obb

    env.reset(seed=seed)
    planner = _planner(env)
    u = env.unwrapped
    back = 0.05  # grasp this far behind the peg's centre: the head sticks out half_length + back ahead of the tcp
    obb = get_actor_obb(u.peg)
    approaching = np.array([0.0, 0.0, -1.0])
    closing_hint = u.agent.tcp.pose.to_transformation_matrix()[0, :3, 1].cpu().numpy()
    info = compute_grasp_info_by_obb(obb, approaching=approaching, target_closing=closing_hint, depth=0.025)
    grasp = u.agent.build_grasp_pose(approaching, info["closing"], info["center"] - np.array([back, 0.0, 0.0]))
    res = planner.move_to_pose_with_screw(grasp * sapien.Pose([0, 0, -0.05]))
    if res == -1:
        return res
    res = planner.move_to_pose_with_screw(grasp)
    if res == -1:
        return res
    planner.close_gripper()
    carry = sapien.Pose([0, 0, 0.01]) * grasp
    planner.move_to_pose_with_screw(carry)
    cube, goal = _p(u.cube), _p(u.goal_region)
    head_ahead = float(u.peg_half_length) + back  # tcp -> peg head along +x
    gap = float(u.cube_half_size) + 0.02  # head stops this far behind the cube's centre
    line_up = np.array([cube[0] - gap - head_ahead, cube[1], carry.p[2]])
    sideways = sapien.Pose([carry.p[0], cube[1], carry.p[2]], carry.q)
    planner.move_to_pose_with_screw(sideways)
    res = planner.move_to_pose_with_screw(sapien.Pose(line_up, carry.q))
    if res == -1:
        return res
    push = goal[0] - cube[0] + gap - float(u.cube_half_size)  # cube centre onto the goal's centre
    res = planner.move_to_pose_with_screw(sapien.Pose(line_up + [push, 0.0, 0.0], carry.q))
    planner.close()
    return res


def _joint_move(planner: Any, pose: Any, restarts: int = 64) -> Any:
    """Move to `pose` along a straight line in joint space (time-parameterised like the planner's paths).

    The IK starts from the current configuration, then from `restarts` configurations drawn from a
    fixed generator (mplib's own restarts use an unseeded one); of the solutions, the one nearest
    the current configuration wins. Deterministic, unlike RRT.
    """
    pl = planner.planner
    q0 = planner.robot.get_qpos().cpu().numpy()[0]
    goal = pl.transform_goal_to_wrt_base(np.concatenate([pose.p, pose.q]))
    limits = np.asarray(pl.joint_limits, dtype=np.float64)
    rng = np.random.default_rng(0)
    starts = [q0] + [
        np.where(np.isfinite(limits).all(1), rng.uniform(limits[:, 0], limits[:, 1]), q0) for _ in range(restarts)
    ]
    idx = pl.move_group_joint_indices
    best = None
    for start in starts:
        status, sols = pl.IK(goal, start, n_init_qpos=1)
        for q in sols if status == "Success" else []:
            if best is None or np.linalg.norm(q[idx] - q0[idx]) < np.linalg.norm(best[idx] - q0[idx]):
                best = q
        if best is not None and start is q0:
            break  # the nearest kind of solution: no need to look further
    if best is None:
        return -1
    path = np.linspace(q0[idx], best[idx], 10)
    _, qs, qds, _, _ = pl.TOPP(path, step=planner.base_env.control_timestep)
    return planner.follow_path({"position": qs, "velocity": qds})


def solve_roll_ball(env: Any, seed: int | None = None, debug: bool = False, vis: bool = False) -> Any:
    """RollBall: stand behind the ball on the line to the goal, then strike through it towards the goal.

    The closed fingers' flat side faces the goal. The approach is a joint-space move (a straight
    screw from the start pose is infeasible when the ball lies near the robot's base); the strike is
    a screw motion at twice the planner's default joint speed, so the ball rolls the ~1.4 m to the
    goal within the horizon.
    """
    import sapien

    env.reset(seed=seed)
    planner = _planner(env, joint_vel_limits=2.0, joint_acc_limits=2.0)
    u = env.unwrapped
    ball, goal = _p(u.ball), _p(u.goal_region)
    radius = float(u.ball_radius)
    direction = goal[:2] - ball[:2]
    direction /= np.linalg.norm(direction)
    closing = np.array([-direction[1], direction[0], 0.0])
    if closing @ u.agent.tcp.pose.to_transformation_matrix()[0, :3, 1].cpu().numpy() < 0:
        closing = -closing  # the smaller turn of the hand
    q = u.agent.build_grasp_pose(np.array([0.0, 0.0, -1.0]), closing, np.zeros(3)).q
    behind = np.append(ball[:2] - direction * (radius + 0.1), radius)
    planner.close_gripper()
    res = _joint_move(planner, sapien.Pose(behind + [0.0, 0.0, 0.08], q))
    if res == -1:
        return res
    res = planner.move_to_pose_with_screw(sapien.Pose(behind, q))
    if res == -1:
        return res
    res = planner.move_to_pose_with_screw(sapien.Pose(np.append(ball[:2] + direction * 0.1, radius), q))
    planner.close()
    return res


def solutions() -> dict[str, Callable[..., Any]]:
    """ManiSkill task id -> motion-planning solution (ManiSkill's own where it has one)."""
    from mani_skill.examples.motionplanning.panda import solutions as ms

    return {
        "PickCube-v1": ms.solvePickCube,
        "PushCube-v1": ms.solvePushCube,
        "PullCube-v1": ms.solvePullCube,
        "StackCube-v1": ms.solveStackCube,
        "LiftPegUpright-v1": ms.solveLiftPegUpright,
        "PlaceSphere-v1": ms.solvePlaceSphere,
        "PegInsertionSide-v1": ms.solvePegInsertionSide,
        "StackPyramid-v1": ms.solveStackPyramid,
        "PlugCharger-v1": ms.solvePlugCharger,
        "PokeCube-v1": solve_poke_cube,
        "RollBall-v1": solve_roll_ball,
    }

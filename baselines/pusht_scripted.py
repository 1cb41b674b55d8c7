"""Scripted PushT expert (suite=pusht, policy=scripted): a pushing controller on the T's keypoints.

Each step it recovers the block's pose from the 8 keypoints of its observation (a rigid fit to
the T's keypoints in its own frame) and compares it with the goal pose, then:

    translate   while the block's centre of gravity is more than `tol_pos` px from the goal's, the
                agent goes behind the block (on the far side from where it must move), walking
                around it on a circle so as not to knock it on the way, then pushes through it;
    rotate      otherwise, while the angle is off by more than `tol_angle`, it pushes one end of
                the T's bar sideways, the side that turns it the right way.

A deliberately simple controller: it makes the suite testable without a trained policy and gives
demonstrations of the right kind; its success rate (coverage > 95%) is measured, not assumed.
It reads the scene's goal, block keypoints and centre of gravity from the env (not from the
observation, which does not hold the goal).
"""

from __future__ import annotations

from typing import Any

import numpy as np

ARENA = (22.0, 490.0)  # where the agent (radius 15) can stand: inside gym-pusht's walls at 5 and 506 px


def fit_pose(local: np.ndarray, world: np.ndarray) -> tuple[np.ndarray, float]:
    """The rigid transform (translation, angle) taking `local` points (N, 2) onto `world` points (least squares)."""
    lc, wc = local.mean(axis=0), world.mean(axis=0)
    h = (local - lc).T @ (world - wc)
    angle = float(np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1]))
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    return wc - rot @ lc, angle


def wrap(a: float) -> float:
    return float((a + np.pi) % (2 * np.pi) - np.pi)


class PushExpert:
    """The controller above, for one PushT env (its goal, block keypoints and centre of gravity)."""

    def __init__(self, env: Any, tol_pos: float = 8.0, tol_angle: float = 0.12):
        self.env, self.tol_pos, self.tol_angle = env, tol_pos, tol_angle

    def reset(self, seed: int) -> None:
        self.local = self.env.local_keypoints
        self.cog_local = self.env.cog
        self.goal = self.env.goal
        self.radius = float(np.max(np.linalg.norm(self.local - self.cog_local, axis=1))) + 25.0
        self._pushing = False

    def _world(self, pos: np.ndarray, angle: float, local: np.ndarray) -> np.ndarray:
        c, s = np.cos(angle), np.sin(angle)
        return pos + np.array([[c, -s], [s, c]]) @ local

    def act(self, obs: dict) -> np.ndarray:
        state = np.asarray(obs["state"], dtype=np.float64)
        agent, keypoints = state[:2], state[2:18].reshape(8, 2)
        pos, angle = fit_pose(self.local, keypoints)
        cog = self._world(pos, angle, self.cog_local)
        goal_cog = self._world(self.goal[:2], float(self.goal[2]), self.cog_local)
        error = goal_cog - cog
        turn = wrap(float(self.goal[2]) - angle)
        if np.linalg.norm(error) > self.tol_pos:
            direction = self._feasible(cog, error / np.linalg.norm(error))
            behind = cog - direction * self.radius
            return self._around(agent, cog, behind, push=cog + direction * min(40.0, np.linalg.norm(error)))
        if abs(turn) > self.tol_angle:
            # push the bar's end sideways: the bar runs along the block's local x axis
            end = self._world(pos, angle, np.array([self.local[:, 0].max() * 0.8, self.local[:4, 1].mean()]))
            lever = end - cog
            tangent = np.sign(turn) * np.array([-lever[1], lever[0]]) / (np.linalg.norm(lever) + 1e-9)
            start = end - tangent * 35.0
            return self._around(agent, cog, start, push=end + tangent * 15.0)
        return agent.astype(np.float32)  # in place: hold

    def _feasible(self, cog: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """`direction`, or the nearest one (turned by up to 120 degrees) whose push point is inside the arena
        (a block against a wall cannot be pushed away from it: it is slid along it first)."""
        for turn in (0.0, 0.5, -0.5, 1.0, -1.0, 1.5, -1.5, 2.1, -2.1):
            c, s = np.cos(turn), np.sin(turn)
            d = np.array([[c, -s], [s, c]]) @ direction
            behind = cog - d * self.radius
            if np.all((behind > ARENA[0]) & (behind < ARENA[1])):
                return d
        return direction

    def _around(self, agent: np.ndarray, cog: np.ndarray, target: np.ndarray, push: np.ndarray) -> np.ndarray:
        """Go to `target` walking around the block (never through it), then push towards `push` for as long as
        the agent stays on the line from `target` through `push` (hysteresis: no chattering at the start point)."""
        line = push - target
        along = float(np.dot(agent - target, line) / (np.dot(line, line) + 1e-9))
        off = np.linalg.norm(agent - (target + along * line))
        if np.linalg.norm(agent - target) < 12.0 or (self._pushing and -0.2 < along < 1.0 and off < 25.0):
            self._pushing = True
            return np.clip(push, 0, 512).astype(np.float32)
        self._pushing = False
        a_ang = np.arctan2(*(agent - cog)[::-1])
        t_ang = np.arctan2(*(target - cog)[::-1])
        gap = wrap(float(t_ang - a_ang))
        if abs(gap) < 0.5 or np.linalg.norm(agent - cog) > self.radius * 1.6:
            return np.clip(target, 0, 512).astype(np.float32)
        step = a_ang + np.sign(gap) * 0.6
        waypoint = cog + self.radius * 1.15 * np.array([np.cos(step), np.sin(step)])
        if np.any((waypoint < ARENA[0]) | (waypoint > ARENA[1])):  # the circle leaves the arena: go the other way
            step = a_ang - np.sign(gap) * 0.6
            waypoint = cog + self.radius * 1.15 * np.array([np.cos(step), np.sin(step)])
        return np.clip(waypoint, *ARENA).astype(np.float32)

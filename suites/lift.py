"""robosuite Lift as an embodiment-agnostic task: its observation, its scripted expert and a suite base.

Shared by `held_out_robots` and `held_out_scenes` (both are `LiftSuite`s). The observation is the same 18 numbers
on every arm (`OBS_FIELDS`): end-effector position (world), end-effector orientation
relative to its own orientation at reset (robosuite's eef frames differ per arm, so only
relative orientation compares), gripper opening normalised to 1 = fully open, 0 = fully
closed in free air (both measured once when the env is built), object pose, and the
gripper-to-object vector.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from bench.api.sims import (
    LIFT_OBS_FIELDS,
    ROBOSUITE_ACTION_NAMES,
    RobosuiteOptions,
    camera_spec,
    check_options,
    import_robosuite,
    quat_conj,
    quat_mul,
    remembered,
    unwrap,
)
from bench.protocols import STATE, Feature, Obs, ObsSpec, Policy
from bench.protocols.suite import Cell, SuiteBase

if TYPE_CHECKING:
    from bench.api.sims import RobosuiteEnv

OBS_FIELDS: list[tuple[str, int]] = list(LIFT_OBS_FIELDS)  # bench.sims.lift_obs: shared with mjx_lift
OBJECT = {"Lift": "cube", "Stack": "cubeA"}
# robosuite's cameras on every single-arm table task (the same six on all 7 arms)
CAMERAS = ("frontview", "birdview", "agentview", "sideview", "robot0_robotview", "robot0_eye_in_hand")
DEFAULT_CAMERAS = ("agentview", "robot0_eye_in_hand")  # a front view of the table and the wrist camera


class LiftObserver:
    """The 18-number agnostic observation (a `bench.sims.robosuite.Observer`)."""

    obs_spec = {STATE: Feature.state(OBS_FIELDS)}

    def __init__(self, task: str = "Lift"):
        if task not in OBJECT:
            raise ValueError(f"task {task!r} not supported; valid: {sorted(OBJECT)}")
        self._object = OBJECT[task]
        # what observe() reads after a step (the fast path polls only these observables)
        self.raw_keys = ("robot0_eef_pos", "robot0_eef_quat", f"{self._object}_pos", f"{self._object}_quat")
        self._quat0_conj = np.array([0.0, 0.0, 0.0, 1.0])

    def bind(self, env: RobosuiteEnv) -> tuple[str, ...]:
        self._env = env
        self._data = env.raw.sim.data._data
        self._grip_idx = np.asarray(env.raw.robots[0]._ref_gripper_joint_pos_indexes["right"])
        self._calibrate_gripper()
        return (getattr(env.raw, self._object).root_body,)

    def _calibrate_gripper(self) -> None:
        """The finger joints fully open and fully closed in free air, measured once per build (or taken from
        another worker's build of the same cell in this run: `remembered`)."""
        ends = remembered("lift-gripper", self._measure_gripper)
        grip_open, grip_closed = ends["open"], ends["closed"]
        mask = np.abs(grip_open - grip_closed) > 1e-3  # joints that move
        # per-step opening = mean((q - closed) / (open - closed)) over the moving joints
        self._grip_qidx = self._grip_idx[mask]
        self._grip_c = grip_closed[mask]
        self._grip_inv_span = 1.0 / (grip_open - grip_closed)[mask]

    def _measure_gripper(self) -> dict[str, np.ndarray]:
        """Drive the fingers open, then shut, until they stop: their joint positions at both ends.

        Reset poses are not fully open on every hand (Jaco starts half-closed), so both
        ends are driven to; Jaco's three fingers need ~105 steps each way.
        """
        env, data = self._env, self._data
        env.raw_reset(0)
        command = np.zeros(env.action_spec.dim)
        ends = []
        for grip in (-1.0, 1.0):
            command[-1] = grip
            last = data.qpos[self._grip_idx].copy()
            still = 0
            for _ in range(300):  # Jaco needs ~200 steps from open to closed
                env.raw_step(command)
                q = data.qpos[self._grip_idx].copy()
                still = still + 1 if np.max(np.abs(q - last)) < 1e-4 else 0
                last = q
                if still >= 10:  # the fingers reached their end
                    break
            ends.append(last)
        return {"open": ends[0], "closed": ends[1]}

    def _opening(self) -> float:
        frac = float(((self._data.qpos[self._grip_qidx] - self._grip_c) * self._grip_inv_span).mean())
        return min(1.0, max(0.0, frac))

    def reset(self, raw: dict) -> None:
        self._quat0_conj = quat_conj(np.asarray(raw["robot0_eef_quat"], dtype=np.float64), w_first=False)

    def observe(self, raw: dict) -> Obs:
        obj = self._object
        out = np.empty(18, dtype=np.float32)  # layout: OBS_FIELDS
        eef, pos = raw["robot0_eef_pos"], raw[f"{obj}_pos"]
        quat_rel = quat_mul(self._quat0_conj, raw["robot0_eef_quat"], w_first=False)  # robosuite: (x, y, z, w)
        out[0:3] = eef
        out[3:7] = quat_rel if quat_rel[3] >= 0 else -quat_rel  # one hemisphere: same rotation, same numbers
        out[7] = self._opening()
        out[8:11] = pos
        out[11:15] = raw[f"{obj}_quat"]
        out[15:18] = pos - eef
        return {STATE: out}


def make_env(
    task: str, robot: str, horizon: int, env_kwargs: dict | None = None, options: Any = None, where: str = ""
) -> Any:
    """A robosuite env of `task` on `robot` with the agnostic observation (and cameras per `options`)."""
    from bench.api.sims import RobosuiteEnv, with_cameras

    fast = bool(getattr(options, "fast_path", True))
    env = RobosuiteEnv(task, robot, horizon, LiftObserver(task), env_kwargs=env_kwargs, fast=fast)
    if options is None:
        return env
    return with_cameras(env, options, DEFAULT_CAMERAS, where or f"{task}/{robot}")


def make_expert(env: Any) -> Policy:
    """The scripted pick-and-lift expert reading the agnostic observation."""
    from baselines.scripted_lift import LiftExpert

    return LiftExpert(list(env.obs_spec[STATE].fields), env.action_spec.dim)


class LiftSuite(SuiteBase):
    """What the Lift suites share: robosuite's options (cameras among `CAMERAS`), the agnostic observation
    (with the cameras the options ask for), OSC_POSE deltas + gripper on every arm, robosuite preloaded in
    workers started ahead of the plan, and the scripted expert. A subclass names its cells and builds them."""

    Options = RobosuiteOptions
    reference_policy = "scripted"
    default_horizon = 250
    capabilities = frozenset({"expert"})

    def __init__(self, options: Any = None) -> None:
        super().__init__(options)
        check_options(self.options, CAMERAS, "robosuite Lift")

    def obs_spec(self, cell: Cell) -> ObsSpec:
        return camera_spec(LiftObserver.obs_spec, self.options, DEFAULT_CAMERAS)

    def action_names(self, cell: Cell) -> list[str]:
        return list(ROBOSUITE_ACTION_NAMES)  # OSC_POSE deltas + gripper on every arm (RobosuiteEnv checks the size)

    @classmethod
    def preload(cls) -> None:
        import_robosuite()

    def make_expert(self, cell: Cell, env: Any) -> Policy:
        return make_expert(unwrap(env))

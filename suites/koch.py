"""koch: reach a point with the Koch v1.1 (the Dynamixel arm of lerobot's community), in MuJoCo.

Model:
    the Koch v1.1 follower URDF that ManiSkill 3.0.1 ships (`mani_skill/assets/robots/koch`, Apache-2.0, from
    jess-moss/koch-v1-1 with ManiSkill's fixed joint limits and axes), read from the installed package
    (`pip install -e '.[koch]'`, the ManiSkill extra), not copied here. MuJoCo 3.3 reads URDF but not the
    package's binary glTF meshes: each `.glb` is converted once to STL with trimesh into a cache
    (`$BENCH_KOCH_CACHE`, default `~/.cache/bench/koch-v1.1`), and the URDF is compiled with `mujoco.MjSpec`
    (visual meshes kept, not colliding; collision meshes collide). Added: lerobot's joint names (shoulder_pan,
    shoulder_lift, elbow_flex, wrist_flex, wrist_roll, gripper for the URDF's joint_1..joint_6), the base turned
    so the arm reaches along +x (ManiSkill's 90 degrees), a floor, a light, a `front` camera, a `target` marker
    (no contact), timestep 1/480 s (16 substeps per 30 fps control step, lerobot's recording rate), and the
    servos as MuJoCo `<position>` actuators with declared Dynamixel constants (`SERVO`): XL330-M288 at 5 V on
    every joint (stall 0.52 N·m; kt/R 0.104 N·m/V x 5 V x BAM's error gain 0.0028775 per P-gain unit = 1.50e-3
    N·m/rad per unit; P gain 800, 1500 on the elbow as lerobot's koch_follower writes it; BAM's XL330 armature,
    back-EMF + viscous damping and Coulomb friction). A real follower's two shoulder servos are XL430-W250s: the
    constants are declared, not measured, which is what `bench calibrate` (`method: servo_arm`, `arm: koch`) is
    for. The URDF's link masses (0.29 kg in all) are ManiSkill's, not weighed.
Task:
    `Reach`: a target point drawn per episode from the scene's region; bring the gripper's tool point
    (`gripper_tcp`) within 2 cm of it. Start: the arm folded at ManiSkill's `rest` keyframe.
Split (scenes; cell.options = the scene's region):
    seen region: x 0.17..0.25 m, |y| <= 0.08 m, z 0.06..0.16 m (in front of the base, where the arm reaches
             within its joint limits)
    seen   = nominal (x 0.18..0.24, |y| <= 0.06, z 0.08..0.14); near (x 0.17..0.19); high (z 0.13..0.16);
             left (y 0.04..0.08)
    unseen = far (x 0.26..0.29); right_wide (y -0.13..-0.10); low (z 0.03..0.05); above (x 0.17..0.20,
             z 0.18..0.21)
Observation:
    state   agent_pos (6 joint positions, rad, gripper last), env_state (the target's xyz, 3), float32.
    rgb.*   with `obs=rgb|state+rgb`: `front`; `image_size=`.
Action:
    6 absolute joint position goals (rad), lerobot's Koch joint order.
Conditions:
    nominal; `perturb.*` model axes (friction, damping, frictionloss, armature, gain [the servos' P gains],
    link_mass, gravity), interface axes, visual axes; `calibration=` from a servo_arm calibration of the Koch
    (the measured stiffness, damping, friction, armature written into the actuators and joints).
Success:
    success_once: the tool point within 2 cm of the target; horizon 90 steps (3 s at 30 fps).
Policies:
    `scripted` (baselines/koch_scripted.py): closed-loop damped least-squares IK on the env's own model, the
    goal ahead of the wanted pose by the declared servo's gravity droop. `baselines.koch_scripted:excitation`:
    goals that excite every servo, for recording a calibration dataset.
"""

from __future__ import annotations

import importlib.util
import os
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench.api.sims import CameraOptions, camera_spec, check_options, installed_version, unwrap, with_cameras
from bench.protocols import STATE, ActionSpec, Feature, MujocoHandle, Obs, ObsSpec
from bench.protocols.env import AdapterBase
from bench.protocols.suite import Cell, SuiteBase, declared_scene, scene_cells

ROBOT = "koch"
TASK_NAME = "Reach"
EXTRA = "koch"
FPS = 30.0
TIMESTEP = 1.0 / 480.0  # 16 substeps per control step
HORIZON = 90
REACH = 0.02  # m: success radius around the target
URDF_JOINTS = ("joint_1", "joint_2", "joint_3", "joint_4", "joint_5", "joint_6")
ACTION_NAMES = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")
ARM_JOINTS = ACTION_NAMES[:5]
REST = (0.0, 2.2, 3.017, -0.25, 0.0, 0.6044)  # ManiSkill's `rest` keyframe (folded)
TOOL = "gripper_tcp"
CAMERAS = ("front",)

# declared Dynamixel constants (module docstring): XL330-M288-T at 5 V, BAM's identification for the rest
KT_OVER_R, VIN, ERROR_GAIN = 0.104, 5.0, 0.0028775  # N·m/V, V, duty per rad per P-gain unit
TORQUE_PER_KP = KT_OVER_R * VIN * ERROR_GAIN  # N·m/rad per P-gain unit
P_GAIN = {"elbow_flex": 1500.0}  # lerobot's koch_follower; the others at P_GAIN_DEFAULT
P_GAIN_DEFAULT = 800.0
STALL = KT_OVER_R * VIN  # N·m at full duty
SERVO = {"armature": 0.0018, "damping": 0.041, "frictionloss": 0.0128}  # BAM xl330 m1: kt²/R + viscous, Coulomb

NOMINAL: dict[str, Any] = {"x": [0.18, 0.24], "y": [-0.06, 0.06], "z": [0.08, 0.14]}
SEEN_REGION: dict[str, tuple[float, float]] = {"x": (0.17, 0.25), "y": (-0.08, 0.08), "z": (0.06, 0.16)}
SEEN_SCENES: dict[str, dict[str, Any]] = {
    "nominal": {},
    "near": {"x": [0.17, 0.19]},
    "high": {"z": [0.13, 0.16]},
    "left": {"y": [0.04, 0.08]},
}
UNSEEN_SCENES: dict[str, dict[str, Any]] = {
    "far": {"x": [0.26, 0.29]},
    "right_wide": {"y": [-0.13, -0.10]},
    "low": {"z": [0.03, 0.05]},
    "above": {"x": [0.17, 0.20], "z": [0.18, 0.21]},
}


def scene_params(name: str) -> dict[str, Any]:
    """Full parameters of a declared scene (nominal values where the scene does not change them)."""
    return declared_scene(name, NOMINAL, SEEN_SCENES, UNSEEN_SCENES)


def in_seen_region(params: dict[str, Any]) -> bool:
    """Whether a scene's target region lies wholly inside `SEEN_REGION` (the split's declared rule)."""
    return all(SEEN_REGION[k][0] - 1e-9 <= v <= SEEN_REGION[k][1] + 1e-9 for k in ("x", "y", "z") for v in params[k])


def assets_dir() -> Path | None:
    """ManiSkill's Koch v1.1 folder (found without importing ManiSkill), or None."""
    spec = importlib.util.find_spec("mani_skill")
    if spec is None or not spec.submodule_search_locations:
        return None
    folder = Path(next(iter(spec.submodule_search_locations))) / "assets" / "robots" / "koch"
    return folder if (folder / "follower_arm_v1.1.urdf").is_file() else None


def cache_dir() -> Path:
    return Path(os.environ.get("BENCH_KOCH_CACHE", str(Path.home() / ".cache" / "bench" / "koch-v1.1")))


def _stl(src: Path) -> Path:
    """`src` as a mesh MuJoCo reads: STL as it is, glTF converted once into the cache (written whole, then
    renamed, so a reader never sees half a file)."""
    if src.suffix.lower() != ".glb":
        return src
    dst = cache_dir() / f"{src.stem}-{src.stat().st_size}.stl"
    if not dst.is_file():
        import trimesh  # a ManiSkill dependency: needed only the first time a mesh is converted

        tmp = dst.with_suffix(f".{os.getpid()}.tmp")
        try:
            dst.parent.mkdir(parents=True, exist_ok=True)
            tmp.write_bytes(trimesh.load(src, force="mesh").export(file_type="stl"))
            tmp.replace(dst)
        except OSError as exc:
            raise RuntimeError(
                f"suite koch: cannot write its converted meshes to {dst.parent} ({exc.strerror}); "
                "set BENCH_KOCH_CACHE to a writable folder"
            ) from None
    return dst


def urdf_text(folder: Path) -> str:
    """ManiSkill's URDF with every mesh a file MuJoCo reads, geoms named per link (the URDF repeats names) and
    MuJoCo's compiler told to keep visual geoms and the tool frames."""
    root = ET.parse(folder / "follower_arm_v1.1.urdf").getroot()
    for link in root.iter("link"):
        for kind in ("visual", "collision"):
            for i, el in enumerate(link.iter(kind)):
                el.set("name", f"{link.get('name')}_{kind}_{i}")
    for mesh in root.iter("mesh"):
        mesh.set("filename", str(_stl(folder / "meshes" / Path(mesh.get("filename", "")).name)))
    extra = ET.SubElement(root, "mujoco")
    ET.SubElement(extra, "compiler", discardvisual="false", fusestatic="false", strippath="false")
    return ET.tostring(root, encoding="unicode")


def build_model() -> Any:
    """The Koch scene, as the module docstring says."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    folder = assets_dir()
    if folder is None:
        raise RuntimeError(f"ManiSkill's Koch v1.1 assets are not installed: pip install -e '.[{EXTRA}]'")
    arm = mujoco.MjSpec.from_string(urdf_text(folder))
    spec = mujoco.MjSpec()
    spec.compiler.degree = False  # the URDF's limits are radians (the attached arm compiles with this spec's)
    spec.option.timestep = TIMESTEP
    spec.visual.global_.offwidth, spec.visual.global_.offheight = 640, 480
    world = spec.worldbody
    world.add_light(pos=[0, 0, 1.5], dir=[0, 0, -1])
    world.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1, 1, 0.05], rgba=[0.8, 0.8, 0.8, 1])
    world.add_camera(name="front", pos=[0.55, 0.0, 0.35], xyaxes=[0, 1, 0, -0.5, 0, 0.866], fovy=55)
    world.add_site(name="target", size=[0.012, 0, 0], rgba=[1, 0.2, 0.2, 0.6], group=2)
    mount = world.add_frame(quat=[np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])  # -y (the URDF's reach) -> +x
    mount.attach_body(arm.body("base_link"), "", "")
    spec.add_exclude(bodyname1="link_1", bodyname2="link_2")  # the base servo's horn sits inside the next link
    for urdf, name in zip(URDF_JOINTS, ACTION_NAMES):
        joint = spec.joint(urdf)
        joint.name = name
        joint.armature, joint.damping, joint.frictionloss = SERVO["armature"], SERVO["damping"], SERVO["frictionloss"]
        k = TORQUE_PER_KP * P_GAIN.get(name, P_GAIN_DEFAULT)
        act = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.gaintype, act.biastype = mujoco.mjtGain.mjGAIN_FIXED, mujoco.mjtBias.mjBIAS_AFFINE
        act.gainprm[0], act.biasprm[1] = k, -k  # a position servo: k (goal - q)
        act.ctrlrange = list(joint.range)
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-STALL, STALL]
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    return spec.compile()


@dataclass(frozen=True)
class KochOptions(CameraOptions):
    """Keys of suite=koch (the camera keys of `bench.sims.camera_env.CameraOptions`)."""


def state_feature() -> Feature:
    return Feature.state([("agent_pos", len(ACTION_NAMES)), ("env_state", 3)])


class KochEnv(AdapterBase):
    """The Koch reach scene behind the EnvAdapter contract: joint goals in, joint and target state out."""

    def __init__(self, params: dict[str, Any], horizon: int):
        import mujoco  # MuJoCo's native library: loaded only when a model is simulated

        self._mj = mujoco
        self.params = params
        self.horizon, self.fps = int(horizon), FPS
        model = build_model()
        data = mujoco.MjData(model)
        self.model, self.data = model, data
        self.substeps = round(1.0 / FPS / model.opt.timestep)
        self._qadr = np.array([model.joint(j).qposadr[0] for j in ACTION_NAMES])
        self._act = np.array([model.actuator(j).id for j in ACTION_NAMES])
        self._tool = model.body(TOOL).id
        self._target = model.site("target").id
        lo, hi = model.actuator_ctrlrange[self._act].T
        self.action_spec = ActionSpec.box(ACTION_NAMES, lo, hi)
        self.obs_spec: ObsSpec = {STATE: state_feature()}
        self.mujoco: MujocoHandle | None = MujocoHandle(model, data, object_bodies=(), arm_joints=ARM_JOINTS)
        self.backend = f"mani-skill-{installed_version('mani-skill')}-koch-v1.1/mujoco-{mujoco.__version__}"
        self._init = np.zeros(0)

    @property
    def target(self) -> np.ndarray:
        return np.asarray(self.model.site_pos[self._target])

    def tool_point(self) -> np.ndarray:
        return np.asarray(self.data.xpos[self._tool])

    def _obs(self) -> Obs:
        state = np.concatenate([self.data.qpos[self._qadr], self.target])
        return {STATE: state.astype(np.float32)}

    def reset(self, seed: int) -> Obs:
        m, d = self.model, self.data
        rng = np.random.default_rng(int(seed))
        self._mj.mj_resetData(m, d)
        m.site_pos[self._target] = [rng.uniform(*self.params[k]) for k in ("x", "y", "z")]
        d.qpos[self._qadr] = REST
        return self._started()

    def _started(self) -> Obs:
        m, d = self.model, self.data
        d.ctrl[self._act] = d.qpos[self._qadr]
        self._mj.mj_forward(m, d)
        physics = [m.body_mass, m.actuator_gainprm[:, 0], m.dof_damping, m.dof_frictionloss, m.dof_armature]
        self._init = np.concatenate([d.qpos, d.qvel, self.target, *physics]).copy()
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
        return bool(np.linalg.norm(self.tool_point() - self.target) < REACH)

    def init_state(self) -> np.ndarray:
        return self._init

    def hold_action(self) -> np.ndarray:
        """The goals the servos hold at the start (its joint positions): a delayed command's first frames."""
        return np.asarray(self.data.ctrl[self._act], np.float64).copy()


class Koch(SuiteBase):
    """Koch v1.1 reach in MuJoCo (ManiSkill's URDF); 4 seen, 4 held-out target regions."""

    name = "koch"
    version = "1"
    Options = KochOptions
    reference_policy = "scripted"
    default_horizon = HORIZON
    manifest = {"envs": {"seen": list(SEEN_SCENES), "unseen": list(UNSEEN_SCENES)}}
    capabilities = frozenset({"expert"})

    @classmethod
    def unavailable(cls) -> str | None:
        """Why the Koch model cannot be loaded here (one line), or None."""
        if assets_dir() is None:
            return f"suite koch needs ManiSkill's Koch v1.1 URDF and meshes: pip install -e '.[{EXTRA}]'"
        return None

    def __init__(self, options: Any = None) -> None:
        super().__init__(options)  # refused here while `unavailable()`
        check_options(self.options, CAMERAS, "the Koch scene")

    def all_cells(self) -> list[Cell]:
        return scene_cells(self.name, TASK_NAME, ROBOT, SEEN_SCENES, UNSEEN_SCENES, scene_params)

    def obs_spec(self, cell: Cell) -> ObsSpec:
        return camera_spec({STATE: state_feature()}, self.options, list(CAMERAS))

    def action_names(self, cell: Cell) -> list[str]:
        return list(ACTION_NAMES)

    def make_env(self, cell: Cell, horizon: int):
        env = KochEnv(cell.options or scene_params(cell.env), horizon)
        return with_cameras(env, self.options, list(CAMERAS), cell.key)

    def make_expert(self, cell: Cell, env):
        from baselines.koch_scripted import KochExpert  # baselines sit above suites: imported when asked for

        return KochExpert(unwrap(env))

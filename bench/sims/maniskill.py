"""ManiSkill3 adapter: one task, one robot, on SAPIEN/PhysX, behind the `EnvAdapter` contract.

CPU by default (`sim_backend="physx_cpu"`, one env per worker, no renderer): on a machine without
a Vulkan device `bench.sims.sapien_novulkan` installs inert visual materials so scenes build, and the
observation is state only. With a Vulkan device (a GPU, or lavapipe from
`scripts/fetch_lavapipe.sh`) camera images come as `rgb.<camera>` uint8 (H, W, 3).

What the policy sees and commands is the suite's `ManiSkillInterface` (task code lives in suites/):
`NativeInterface` hands over ManiSkill's own flattened state (fields named after its state dict)
and the control mode's own action. Episodes run the full horizon: `terminated` is never set (a
ManiSkill task that succeeds keeps simulating, as robosuite's `ignore_done`), `truncated` is set at
the horizon; success is `info["success"]` of the last step, a plain bool.

Resets: ManiSkill's ordinary reset (`reset="soft"`) restores the seed's initial state exactly, but
PhysX solves contacts in an order that depends on the scene's history, so after a hard contact
(the hand hitting the table) the same seed and actions can continue differently depending on the
episodes the worker ran before (measured: PickCube, random joint targets, the same initial state
twice, diverging at step 9). The default, `reset="rebuild"`, rebuilds the PhysX scene at every
reset (ManiSkill's `reconfigure`): the same seed and actions then give the same trajectory
whatever ran before, for ~20 ms per episode. ManiSkill frees the old scene with a full
`gc.collect()`, ~200 ms in a process that has imported torch; the adapter calls `gc.freeze()`
once after its first build so those collections skip the long-lived objects of the imports.

Assets are never downloaded: a robot or task whose assets are not on disk is refused with one
line naming them (and `MS_SKIP_ASSET_DOWNLOAD_PROMPT=1` is set so ManiSkill never prompts).

Perturbations: model axes through PhysX (`physx`, `bench.sims.perturb.physx`), visual axes through
SAPIEN's render scene (`sapien_scene`, `bench.sims.perturb.sapien_scene`: made after each reset, which
then renders its observation again), image-noise and interface axes as wrappers like everywhere.
"""

from __future__ import annotations

import gc
import logging
import os
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from bench.core.errors import ConfigError, did_you_mean
from bench.protocols import RGB, STATE, TASK, ActionSpec, Feature, InputLog, ModelAxes, MujocoHandle, Obs, ObsSpec
from bench.protocols.env import CachedStateAdapter
from bench.sims.perturb.physx import PhysxAxes
from bench.sims.perturb.sapien_scene import SapienScene
from bench.sims.sapien_novulkan import CHECKED, check_cameras, prepare

if TYPE_CHECKING:
    import torch
    from mani_skill.agents.controllers.base_controller import BaseController
    from mani_skill.envs.sapien_env import BaseEnv
    from mani_skill.utils.assets.data import DataSource

# ManiSkill's batched observation (a leading env axis): a torch tensor for obs_mode "state", else dicts of them
MsObs = Any

SIM_BACKENDS = ("physx_cpu", "physx_cuda")
RESETS = ("rebuild", "soft")
OBS_MODES = ("state", "rgb", "state+rgb")
EXTRA_HINT = "pip install -e '.[maniskill]'"
# cameras every table-top task mounts, and the ones a robot brings (ManiSkill 3.0.1)
TASK_CAMERAS = ("base_camera",)
ROBOT_CAMERAS = {"panda_wristcam": ("hand_camera",), "fetch": ("fetch_head", "fetch_hand")}
CAMERA_SIZE = 128


def missing_extra() -> str | None:
    """Why ManiSkill suites cannot run in this environment (one line), or None when they can."""
    absent = []
    for pkg in CHECKED:
        try:
            version(pkg)
        except PackageNotFoundError:
            absent.append(pkg)
    return f"needs {' and '.join(absent)}: {EXTRA_HINT}" if absent else None


def _require() -> None:
    why = missing_extra()
    if why:
        raise ConfigError(f"ManiSkill suites {why}")
    os.environ["MS_SKIP_ASSET_DOWNLOAD_PROMPT"] = "1"  # never an interactive prompt

    from mani_skill import logger  # named "mani_skill " (sic): take the object, not the name

    # ManiSkill warns on every scene build ("No initial pose set for actor builder ..."): not the user's concern
    logger.setLevel(logging.ERROR)


def check_backend(sim_backend: str, cameras: bool = False) -> None:
    """Refuse, in one line saying what is missing and how to get it, what ManiSkill cannot run here.

    physx_cuda needs a CUDA device and SAPIEN's PhysX GPU library, which SAPIEN downloads from GitHub
    at first use (machines without internet access never get it); `cameras` (obs=rgb) needs a Vulkan
    device (`sapien_novulkan.check_cameras`). Checked when the suite is built, i.e. when a run is
    planned: before any episode.
    """
    if sim_backend not in SIM_BACKENDS:
        raise ConfigError(f"sim_backend={sim_backend!r}: valid: {', '.join(SIM_BACKENDS)}")
    if sim_backend == "physx_cuda":
        import torch  # torch: loaded only when a network is built or run

        if not torch.cuda.is_available():
            raise ConfigError(
                "sim_backend=physx_cuda: this machine has no CUDA device (torch.cuda.is_available() "
                "is False); use sim_backend=physx_cpu"
            )
        missing = physx_gpu_library()
        if missing is not None:
            raise ConfigError(
                f"sim_backend=physx_cuda: SAPIEN's PhysX GPU library {missing} is missing; SAPIEN downloads it "
                'from GitHub at first use, which bench never does: run `python -c "import sapien; '
                "sapien.physx.enable_gpu()\"` where the network allows (or unzip SAPIEN's linux-so.zip of "
                "github.com/sapien-sim/physx-precompiled there), or use sim_backend=physx_cpu"
            )
    if cameras:
        _require()
        check_cameras()


def physx_gpu_library() -> str | None:
    """The path of SAPIEN's PhysX GPU library when it is not on disk (None when it is), without downloading it."""
    _require()
    import sapien.physx  # the maniskill extra: loaded only for ManiSkill suites

    if sapien.physx.is_gpu_enabled():
        return None
    name = "PhysXGpu_64.dll" if os.name == "nt" else "libPhysXGpu_64.so"
    path = Path.home() / ".sapien" / "physx" / str(sapien.physx.version()) / name
    return None if path.is_file() else str(path)


def cameras_of(robot: str) -> tuple[str, ...]:
    """Camera names a table-top task with `robot` has (declared without building the env)."""
    return TASK_CAMERAS + ROBOT_CAMERAS.get(robot, ())


def missing_assets(env_id: str, robot: str | None) -> list[str]:
    """Asset ids (as ManiSkill declares them) not on disk for this task and robot; empty when all are."""
    from mani_skill.agents.registration import (
        REGISTERED_AGENTS,  # the maniskill extra: loaded only for ManiSkill suites
    )
    from mani_skill.utils import assets  # the maniskill extra: loaded only for ManiSkill suites
    from mani_skill.utils.registration import REGISTERED_ENVS  # the maniskill extra: loaded only for ManiSkill suites

    wanted = list(REGISTERED_ENVS[env_id].asset_download_ids or [])
    if robot is not None and robot in REGISTERED_AGENTS:
        wanted += list(REGISTERED_AGENTS[robot].asset_download_ids or [])
    missing = []
    for asset in dict.fromkeys(wanted):
        sources = (
            assets.expand_data_group_into_individual_data_source_ids(asset) if asset in assets.DATA_GROUPS else [asset]
        )
        absent = [s for s in sources if not _on_disk(assets.DATA_SOURCES[s])]
        if absent:
            missing.append(asset if len(sources) == 1 else f"{asset} ({len(absent)} of {len(sources)} parts)")
    return missing


def _on_disk(source: DataSource) -> bool:
    """ManiSkill's own check (the folder exists) passes on the empty folder a failed download leaves."""
    path = source.output_dir / source.target_path
    return path.is_file() or (path.is_dir() and any(path.iterdir()))


def check_buildable(env_id: str, robot: str | None) -> None:
    """Refuse (one line, no download, no prompt) a task or robot that is unknown or needs assets."""
    _require()
    import mani_skill.envs  # noqa: F401  (registers the tasks)
    from mani_skill.agents.registration import (
        REGISTERED_AGENTS,  # the maniskill extra: loaded only for ManiSkill suites
    )
    from mani_skill.utils.registration import REGISTERED_ENVS  # the maniskill extra: loaded only for ManiSkill suites

    if env_id not in REGISTERED_ENVS:
        raise ConfigError(f"task {env_id!r} is not a ManiSkill task.{did_you_mean(env_id, REGISTERED_ENVS)}")
    if robot is not None and robot not in REGISTERED_AGENTS:
        raise ConfigError(f"robot {robot!r} is not a ManiSkill robot.{did_you_mean(robot, REGISTERED_AGENTS)}")
    missing = missing_assets(env_id, robot)
    if missing:
        raise ConfigError(
            f"{env_id} with robot {robot}: needs an asset download ({', '.join(missing)}), which bench "
            f"never does; fetch it where the network allows (python -m mani_skill.utils.download_asset "
            f"{missing[0].split()[0]}) or choose another robot/task"
        )


def reward_mode(env_id: str) -> str:
    """The task's reward: normalized dense (return comparable across tasks) when it has one."""
    from mani_skill.utils.registration import REGISTERED_ENVS  # the maniskill extra: loaded only for ManiSkill suites

    supported = REGISTERED_ENVS[env_id].cls.SUPPORTED_REWARD_MODES
    return next(m for m in ("normalized_dense", "dense", "sparse", "none") if m in supported)


class Built(Protocol):
    """What an interface binds to after every (re)build: an adapter holding the unwrapped ManiSkill env."""

    base: BaseEnv


class ManiSkillInterface(Protocol):
    """What a suite's policy sees and commands, computed from the built ManiSkill env.

    `uses_ms_state`: whether `state()` reads ManiSkill's own flattened state observation (then
    ManiSkill computes it every step) or computes the state itself from the scene (ManiSkill's
    observation is then skipped). `bind` is called after every (re)build, `on_reset` after every
    reset, `state(ms_state)` every step, `command(action)` maps the policy's action to ManiSkill's.
    """

    control_mode: str | None
    uses_ms_state: bool
    state_fields: tuple[tuple[str, int], ...]
    action_spec: ActionSpec

    def bind(self, env: Built) -> None: ...
    def on_reset(self) -> None: ...
    def state(self, ms_state: np.ndarray | None) -> np.ndarray: ...
    def command(self, action: np.ndarray) -> np.ndarray: ...


def state_fields(state_dict: dict, prefix: str = "") -> list[tuple[str, int]]:
    """(name, width) of ManiSkill's flattened state, in `flatten_state_dict` order (batch dim dropped).

    Leaves are named by their key ("qpos", "tcp_pose"); a nested key keeps its parent ("sensor.x").
    """
    out: list[tuple[str, int]] = []
    for key, value in state_dict.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out += state_fields(value, f"{name}.")
            continue
        shape = tuple(getattr(value, "shape", ()))
        width = int(np.prod(shape[1:])) if len(shape) >= 2 else 1
        if width:
            out.append((name, width))
    return out


class NativeInterface:
    """ManiSkill's own state observation (obs_mode "state") and the control mode's own action."""

    uses_ms_state = True

    def __init__(self, control_mode: str | None = None):
        self.control_mode = control_mode
        self.state_fields: tuple[tuple[str, int], ...] = ()
        self.action_spec = ActionSpec.box([], [], [])

    def bind(self, env: Built) -> None:
        base = env.base
        raw = base.get_obs(unflattened=True)  # {"agent": ..., "extra": ...}, flattened in that order
        self.state_fields = tuple(state_fields(raw.get("agent", {})) + state_fields(raw.get("extra", {})))
        self.control_mode = base.control_mode
        space = base.single_action_space
        self.action_spec = ActionSpec.box(_action_names(base.agent.controller, space.shape[0]), space.low, space.high)

    def on_reset(self) -> None:
        pass

    def state(self, ms_state: np.ndarray | None) -> np.ndarray:
        return np.asarray(ms_state, dtype=np.float32)

    def command(self, action: np.ndarray) -> np.ndarray:
        return np.asarray(action, dtype=np.float32)


def _action_names(controller: BaseController, width: int) -> list[str]:
    """Names of a controller's action entries: joint names where one entry drives one joint."""
    parts = getattr(controller, "controllers", None) or {"": controller}
    names: list[str] = []
    for uid, ctrl in parts.items():
        n = int(ctrl.single_action_space.shape[0])
        joints = [j.name.split("_", 1)[-1] if j.name.startswith("scene-") else j.name for j in ctrl.joints]
        if len(joints) == n:
            names += joints
        else:
            names += [uid or "a"] if n == 1 else [f"{uid or 'a'}.{i}" for i in range(n)]
    if len(names) != width:
        names = [f"a{i}" for i in range(width)]
    return names


_FROZEN = {"done": False}


def _freeze_imports() -> None:
    """Move every object alive now out of the cyclic GC's reach, once per process (see the module doc)."""
    if not _FROZEN["done"]:
        gc.collect()
        gc.freeze()
        _FROZEN["done"] = True


class ManiSkillEnv(CachedStateAdapter):
    """One ManiSkill3 env behind the `EnvAdapter` contract (built once per worker and cell)."""

    mujoco: MujocoHandle | None = None
    inputs: InputLog | None = None
    model_axes: ModelAxes | None
    physx: PhysxAxes | None  # the same object, with the adapter's reset hooks
    sapien_scene: SapienScene  # visual axes: lights, cameras and colours of SAPIEN's render scene
    obs_spec: ObsSpec
    base: BaseEnv  # the unwrapped ManiSkill env

    def __init__(
        self,
        env_id: str,
        robot: str,
        horizon: int,
        *,
        interface: ManiSkillInterface | None = None,
        obs: str = "state",
        cameras: Sequence[str] | None = None,
        image_size: int | None = None,
        object_names: Sequence[str] = (),
        instruction: str | None = None,
        sim_backend: str = "physx_cpu",
        reset: str = "rebuild",
        env_kwargs: dict | None = None,
    ):
        if obs not in OBS_MODES:
            raise ConfigError(f"obs={obs!r}: valid: {', '.join(OBS_MODES)}")
        if reset not in RESETS:
            raise ConfigError(f"reset={reset!r}: valid: {', '.join(RESETS)}")
        self.reset_mode = reset
        check_backend(sim_backend)
        check_buildable(env_id, robot)
        self.env_id, self.robot, self.horizon = env_id, robot, int(horizon)
        self.interface: ManiSkillInterface = interface or NativeInterface()
        self.obs_mode, self.object_names, self.instruction = obs, tuple(object_names), instruction
        self.want_state, want_rgb = "state" in obs, "rgb" in obs
        self.all_cameras = valid_cams = cameras_of(robot)
        self.cameras = tuple(cameras) if cameras else (valid_cams if want_rgb else ())
        for cam in self.cameras:
            if cam not in valid_cams:
                raise ConfigError(
                    f"cameras: {cam!r} is not a camera of {env_id} with {robot}; valid: "
                    f"{', '.join(valid_cams)}.{did_you_mean(cam, valid_cams)}"
                )
        if want_rgb and not self.cameras:
            raise ConfigError(f"obs={obs}: name at least one camera; valid: {', '.join(valid_cams)}")
        self.image_size = int(image_size or CAMERA_SIZE)

        self.render = prepare(cameras=want_rgb)  # "vulkan" or "stand-ins"
        ms_state = "state" if self.want_state and self.interface.uses_ms_state else None
        self._ms_obs_mode = "+".join(m for m in (ms_state, "rgb" if want_rgb else None) if m) or "none"
        self._kwargs: dict[str, Any] = dict(
            robot_uids=robot,
            obs_mode=self._ms_obs_mode,
            sim_backend=sim_backend,
            num_envs=1,
            render_backend="cpu" if want_rgb else "none",
            reward_mode=reward_mode(env_id),
            **(env_kwargs or {}),
        )
        if want_rgb:
            self._kwargs["sensor_configs"] = dict(width=self.image_size, height=self.image_size)
        self._build()
        import mani_skill  # the maniskill extra: loaded only for ManiSkill suites
        import sapien  # the maniskill extra: loaded only for ManiSkill suites

        self.backend = f"mani_skill-{mani_skill.__version__}/sapien-{sapien.__version__}/{sim_backend}"
        self.fps = float(self.base.control_freq)

        # PhysX parameters can be edited between steps on the CPU backend only (GPU buffers are fixed at start)
        self.physx = PhysxAxes(self) if sim_backend == "physx_cpu" else None
        self.model_axes = self.physx
        spec: dict[str, Feature] = {}
        if self.want_state:
            spec[STATE] = Feature.state(self.interface.state_fields)
        for cam in self.cameras:
            spec[RGB + cam] = Feature.rgb(self.image_size, self.image_size)
        if instruction is not None:
            spec[TASK] = Feature.text()
        self.obs_spec = spec
        self.sapien_scene = SapienScene(self)  # refuses every visual axis without a camera image (obs=state)
        self.action_spec = self.interface.action_spec
        self._success = False
        self._t = 0
        self._init_state = np.zeros(0)

    # -- building ----------------------------------------------------------------------------
    def _build(self) -> None:
        import gymnasium as gym  # gymnasium: loaded only when a Gymnasium env is made
        import mani_skill.envs  # noqa: F401

        mode = self.interface.control_mode
        try:
            self._gym = gym.make(self.env_id, control_mode=mode, **self._kwargs)
        except AssertionError:
            valid = self._control_modes()
            if mode not in valid:
                raise ConfigError(
                    f"control_mode={mode!r}: {self.robot} supports {', '.join(valid)}.{did_you_mean(str(mode), valid)}"
                ) from None
            raise
        self.base = self._gym.unwrapped
        self.interface.bind(self)
        _freeze_imports()

    def _control_modes(self) -> list[str]:
        import gymnasium as gym  # gymnasium: loaded only when a Gymnasium env is made

        probe = gym.make(self.env_id, **{**self._kwargs, "obs_mode": "none", "render_backend": "none"})
        try:
            base: BaseEnv = probe.unwrapped
            return list(base.agent.supported_control_modes)
        finally:
            probe.close()

    def reconfigure(self, seed: int) -> tuple[MsObs, dict[str, torch.Tensor]]:
        """Rebuild the scene (new PhysX system, e.g. after a gravity change) and reset it with `seed`."""
        return self.base.reset(seed=int(seed), options={"reconfigure": True})

    # -- contract ----------------------------------------------------------------------------
    def reset(self, seed: int) -> Obs:
        seed = int(seed)
        axes = self.physx
        gravity_changed = axes is not None and axes.needs_reconfigure()
        rebuild = self.reset_mode == "rebuild" or gravity_changed
        raw, info = self.reconfigure(seed) if rebuild else self.base.reset(seed=seed)
        if rebuild:
            self.interface.bind(self)  # new scene, new actors
            if axes is not None:
                axes.after_reconfigure()
        if self.sapien_scene.after_reset():  # the episode's visual edits, made on the scene the reset left
            raw = self.base.get_obs(info)  # the reset rendered the images before them
        self.interface.on_reset()
        self._t = 0
        self._success = bool(info["success"][0])
        self._init_state = self.base.get_state()[0].cpu().numpy().astype(np.float64)
        return self._obs(raw)

    def step(self, action: np.ndarray) -> tuple[Obs, float, bool, bool, dict[str, object]]:
        raw, reward, _, _, info = self.base.step(self.interface.command(action))  # batched tensors (1, ...)
        self._t += 1
        self._success = bool(info["success"][0])
        return self._obs(raw), float(reward[0]), False, self._t >= self.horizon, {"success": self._success}

    def close(self) -> None:
        self._gym.close()

    def _obs(self, raw: MsObs) -> Obs:
        out: Obs = {}
        if self.want_state:
            ms_state = None
            if self.interface.uses_ms_state:  # obs_mode "state": a (1, D) tensor; "state+rgb": a dict
                ms_state = (raw["state"] if isinstance(raw, dict) else raw)[0].cpu().numpy()
            out[STATE] = self.interface.state(ms_state)
        for cam in self.cameras:
            out[RGB + cam] = raw["sensor_data"][cam]["rgb"][0].cpu().numpy()
        if self.instruction is not None:
            out[TASK] = self.instruction
        return out

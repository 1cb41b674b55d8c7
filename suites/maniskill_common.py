"""What the two ManiSkill suites share: their camera/backend keys, declared specs and task table.

Everything here is declared without importing ManiSkill (so `bench list` and `bench check` work
without the `maniskill` extra); tests/test_maniskill_suites.py checks each table against the
built envs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from bench.api import ConfigError, did_you_mean
from bench.api.sims import OBS_MODES, RESETS, cameras_of, check_backend
from bench.api.sims import maniskill as sim_maniskill
from bench.protocols import RGB, STATE, TASK, Feature, ObsSpec
from bench.protocols.suite import SuiteBase

IMAGE_SIZES = (16, 1024)
COMMON_KEYS = ("obs", "cameras", "image_size", "sim_backend", "reset")  # every ManiSkill suite's camera/backend keys


@dataclass(frozen=True)
class Task:
    """One ManiSkill task as the suites use it."""

    env_id: str  # ManiSkill's id
    robot: str  # the robot its motion-planning solution is written for
    instruction: str  # obs["task"]
    objects: tuple[str, ...]  # scene actors that are the manipulated objects (perturb.mass)


TASKS: dict[str, Task] = {
    t.env_id.split("-")[0]: t
    for t in (
        Task("PickCube-v1", "panda", "pick up the red cube and move it to the green goal", ("cube",)),
        Task("PushCube-v1", "panda", "push the cube onto the red and white target", ("cube",)),
        Task("PullCube-v1", "panda", "pull the cube onto the red and white target", ("cube",)),
        Task("StackCube-v1", "panda", "stack the red cube on top of the green cube", ("cubeA", "cubeB")),
        Task("LiftPegUpright-v1", "panda", "lift the peg lying on the table and stand it upright", ("peg",)),
        Task("PlaceSphere-v1", "panda", "place the blue ball into the bin", ("sphere",)),
        Task("PegInsertionSide-v1", "panda_wristcam", "insert the peg sideways into the hole of the box", ("peg_0",)),
        Task("StackPyramid-v1", "panda", "stack the three cubes into a pyramid", ("cubeA", "cubeB", "cubeC")),
        Task("PlugCharger-v1", "panda", "plug the charger into the receptacle", ("charger",)),
        Task("PokeCube-v1", "panda", "use the peg to push the cube onto the target", ("cube", "peg")),
        Task("RollBall-v1", "panda", "roll the ball into the red and white target", ("ball",)),
    )
}

# ManiSkill 3.0.1's control modes per robot, in its order (checked against the agents by the tests):
# the arms and fetch share the joint/end-effector delta modes and the target/velocity modes
_DELTA_MODES = ("pd_joint_delta_pos", "pd_joint_pos", "pd_ee_delta_pos", "pd_ee_delta_pose")
_TARGET_VEL_MODES = (
    "pd_joint_target_delta_pos",
    "pd_ee_target_delta_pos",
    "pd_ee_target_delta_pose",
    "pd_joint_vel",
    "pd_joint_pos_vel",
    "pd_joint_delta_pos_vel",
)
_ARM_MODES = (*_DELTA_MODES, "pd_ee_pose", *_TARGET_VEL_MODES)
CONTROL_MODES: dict[str, tuple[str, ...]] = {
    "panda": _ARM_MODES,
    "panda_wristcam": _ARM_MODES,
    "fetch": (*_DELTA_MODES, "pd_ee_delta_pose_align", *_TARGET_VEL_MODES, "pd_joint_delta_pos_stiff_body"),
    "so100": ("pd_joint_delta_pos", "pd_joint_pos", "pd_joint_target_delta_pos"),
}


def require_extra() -> None:
    """ConfigError (one line, what to install) when mani-skill / sapien are absent."""
    why = sim_maniskill.missing_extra()
    if why:
        raise ConfigError(f"ManiSkill suites {why}")


def check_common(obs: str, cameras: Optional[Sequence[str]], image_size: int, sim_backend: str, reset: str) -> None:
    """The camera and backend keys both suites take, checked before anything is built."""
    if obs not in OBS_MODES:
        raise ConfigError(f"obs={obs!r}: valid: {', '.join(OBS_MODES)}.{did_you_mean(obs, OBS_MODES)}")
    if not IMAGE_SIZES[0] <= image_size <= IMAGE_SIZES[1]:
        raise ConfigError(f"image_size={image_size}: must be in [{IMAGE_SIZES[0]}, {IMAGE_SIZES[1]}] pixels")
    if cameras is not None and "rgb" not in obs:
        raise ConfigError(f"cameras={list(cameras)}: cameras need obs=rgb or obs=state+rgb (obs={obs})")
    if cameras is not None and not cameras:
        raise ConfigError("cameras=[] names no camera; leave it out for every camera of the cell")
    check_backend(sim_backend, cameras="rgb" in obs)  # a GPU backend, a Vulkan device: before any episode
    if reset not in RESETS:
        raise ConfigError(
            f"reset={reset!r}: valid: {', '.join(RESETS)} (rebuild: the same seed and actions give the "
            "same trajectory whatever ran before; soft: ManiSkill's own reset, faster)"
        )


def check_control_mode(mode: str, robot: str) -> None:
    valid = CONTROL_MODES[robot]
    if mode not in valid:
        raise ConfigError(f"control_mode={mode!r}: {robot} supports {', '.join(valid)}.{did_you_mean(mode, valid)}")


def cell_cameras(robot: str, obs: str, cameras: Optional[Sequence[str]]) -> tuple[str, ...]:
    """The cameras a cell renders: the named ones (each must exist on the cell) or all of them."""
    if "rgb" not in obs:
        return ()
    valid = cameras_of(robot)
    for cam in cameras or ():
        if cam not in valid:
            raise ConfigError(
                f"cameras: {cam!r} is not a camera of a table-top task with {robot}; valid: "
                f"{', '.join(valid)}.{did_you_mean(cam, valid)}"
            )
    return tuple(cameras) if cameras else valid


def obs_spec(
    state: Sequence[tuple[str, int]], robot: str, obs: str, cameras: Optional[Sequence[str]], image_size: int
) -> ObsSpec:
    """state (when asked for) + one rgb.<camera> per camera + the task instruction."""
    spec: dict[str, Feature] = {}
    if "state" in obs:
        spec[STATE] = Feature.state(state)
    for cam in cell_cameras(robot, obs, cameras):
        spec[RGB + cam] = Feature.rgb(image_size, image_size)
    spec[TASK] = Feature.text()
    return spec


class ManiSkillSuite(SuiteBase):
    """What every ManiSkill suite shares: unavailable without the extra, its common keys checked on construction,
    and an expert (`make_expert`) that is its reference policy."""

    reference_policy = "scripted"
    capabilities = frozenset({"expert"})
    instructions = str(Path(__file__).with_name("instructions") / "maniskill.json")  # `perturb.instruction`

    @classmethod
    def unavailable(cls) -> str | None:
        return sim_maniskill.missing_extra()

    def __init__(self, options: Any = None) -> None:
        require_extra()  # before SuiteBase's own refusal: this one says "ManiSkill suites needs ..."
        super().__init__(options)
        check_common(**self._common())

    def _common(self) -> dict[str, Any]:
        """This suite's values of the COMMON_KEYS, by name."""
        return {key: getattr(self.options, key) for key in COMMON_KEYS}

    def _env(self, cell: Any, horizon: int, interface: Any) -> Any:
        """The cell's ManiSkillEnv with this suite's common keys (obs, cameras, image size, backend, reset)."""
        task = TASKS[cell.task]
        return sim_maniskill.ManiSkillEnv(
            task.env_id,
            cell.robot,
            horizon,
            interface=interface,
            object_names=task.objects,
            instruction=task.instruction,
            **self._common(),
        )

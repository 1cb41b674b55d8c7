"""Building blocks for suites: simulator adapters, the camera wrapper and the perturbation axes.

A suite (those in `suites/`, or one of yours) builds its env adapters from these and never reaches
into `bench.sims` itself; the contract the adapters meet is `bench.protocols.EnvAdapter`. Each adapter
imports its simulator only when an env is made, so importing this module stays cheap.
"""

from __future__ import annotations

from bench.core.provenance import installed_version
from bench.protocols.env import unwrap
from bench.sims import maniskill  # the module: suites call `maniskill.missing_extra()` (tests replace it)
from bench.sims.build_memo import remembered
from bench.sims.camera import RENDERER_DEFAULTS, camera_names
from bench.sims.camera_env import CameraOptions, camera_spec, check_options, with_cameras
from bench.sims.gym import GymEnv
from bench.sims.lift_obs import LIFT_OBS_FIELDS
from bench.sims.maniskill import OBS_MODES, RESETS, ManiSkillEnv, NativeInterface, cameras_of, check_backend
from bench.sims.metaworld import OBS_NAMES, TOO_HIGH, MetaWorldEnv
from bench.sims.perturb.axes import AXES, conditions_from_config
from bench.sims.perturb.reset import set_nominal
from bench.sims.quaternion import quat_conj, quat_mul
from bench.sims.robosuite import ACTION_NAMES as ROBOSUITE_ACTION_NAMES
from bench.sims.robosuite import RobosuiteEnv, RobosuiteOptions, import_robosuite

__all__ = [
    "LIFT_OBS_FIELDS",
    "AXES",
    "OBS_MODES",
    "OBS_NAMES",
    "RENDERER_DEFAULTS",
    "RESETS",
    "ROBOSUITE_ACTION_NAMES",
    "TOO_HIGH",
    "CameraOptions",
    "GymEnv",
    "ManiSkillEnv",
    "MetaWorldEnv",
    "NativeInterface",
    "RobosuiteEnv",
    "RobosuiteOptions",
    "camera_names",
    "camera_spec",
    "cameras_of",
    "check_backend",
    "import_robosuite",
    "installed_version",
    "check_options",
    "conditions_from_config",
    "maniskill",
    "quat_conj",
    "quat_mul",
    "remembered",
    "set_nominal",
    "unwrap",
    "with_cameras",
]

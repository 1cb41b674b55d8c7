"""Image observations for any MuJoCo env adapter: the `obs=`, `cameras=`, `image_size=` keys and a wrapper.

A suite whose envs are MuJoCo-backed extends its `Options` with `CameraOptions`, declares its
spec with `camera_spec` and builds its env with `with_cameras`. The wrapper (`CameraEnv`) gives
the env a `bench.sims.camera.CameraRig` (as `env.mujoco.cameras`: episode videos and visual
perturbations use it too) and, with `obs=rgb` or `obs=state+rgb`, adds one `rgb.<camera>` entry
per camera to every observation (`obs=rgb` drops `state`). The rig is made with the env (once per
worker) and closed with it; it renders nothing until asked, so `obs=state` costs nothing.

Suites name their default cameras (a front view and, where the robot has one, a wrist view);
`cameras=[...]` picks others among the model's cameras.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Optional, Protocol

import numpy as np

from bench.core.errors import ConfigError, did_you_mean
from bench.protocols import RGB, STATE, EnvAdapter, Feature, Obs, ObsSpec
from bench.protocols.env import AdapterWrapper
from bench.sims.camera import CameraRig, camera_names, check_renderer, parse_image_size

OBS_MODES = ("state", "rgb", "state+rgb")


@dataclass(frozen=True)
class CameraOptions:
    """Image-observation keys shared by the MuJoCo suites (a suite's Options extends it)."""

    obs: str = "state"  # state | rgb | state+rgb: the state vector, camera images (rgb.<camera>), or both
    cameras: Optional[list[str]] = (
        None  # cameras rendered as rgb.<camera>; default: the suite's (front view, wrist view)
    )
    image_size: int = 128  # image height and width in pixels, in [16, 1024]


class CameraKeys(Protocol):
    """The camera keys of a suite's Options: `CameraOptions`' fields, inherited or declared alike."""

    @property
    def obs(self) -> str: ...

    @property
    def cameras(self) -> Sequence[str] | None: ...

    @property
    def image_size(self) -> object: ...  # one size, or [height, width] (`parse_image_size`)


def check_options(options: CameraKeys, known: Sequence[str] | None = None, where: str = "the suite") -> None:
    """Validate the camera keys without building an env (`known`: the suite's camera names, when fixed)."""
    if options.obs not in OBS_MODES:
        raise ConfigError(
            f"obs: {options.obs!r} is not an observation mode; valid: {', '.join(OBS_MODES)}."
            f"{did_you_mean(str(options.obs), OBS_MODES)}"
        )
    parse_image_size(options.image_size)
    if wants_images(options):
        check_renderer()
    if options.cameras is not None and known is not None:
        for name in options.cameras:
            if name not in known:
                raise ConfigError(
                    f"cameras: {name!r} is not a camera of {where}; valid: {', '.join(known)}."
                    f"{did_you_mean(str(name), known)}"
                )
        if not options.cameras:
            raise ConfigError(f"cameras: empty list; valid cameras of {where}: {', '.join(known)}")


def wants_images(options: CameraKeys) -> bool:
    return options.obs in ("rgb", "state+rgb")


def chosen_cameras(options: CameraKeys, defaults: Sequence[str]) -> list[str]:
    return list(options.cameras) if options.cameras is not None else list(defaults)


def camera_spec(base: ObsSpec, options: CameraKeys, defaults: Sequence[str]) -> ObsSpec:
    """`base` (the state spec) with the entries `obs=` asks for: state, rgb.<camera> images, or both."""
    size = parse_image_size(options.image_size)
    out: dict[str, Feature] = {}
    if options.obs != "rgb":
        out.update(base)
    else:
        out.update({k: v for k, v in base.items() if k != STATE})
    if wants_images(options):
        out.update({f"{RGB}{c}": Feature.rgb(*size) for c in chosen_cameras(options, defaults)})
    return out


def with_cameras(
    env: EnvAdapter,
    options: CameraKeys,
    defaults: Sequence[str],
    where: str,
    scene_flags: dict[str, bool] | None = None,
) -> EnvAdapter:
    """`env` with a camera rig (and image observations when `obs=` asks for them).

    Without image observations the rig is still attached when the model has the cameras (for
    episode videos and visual perturbations); an env without cameras is returned as it is.
    `scene_flags`: the rig's renderer settings (`bench.sims.camera.CameraRig`; default all off).
    """
    if env.mujoco is None:
        if wants_images(options):
            env.close()
            raise ConfigError(
                f"obs={options.obs}: {where} ({env.backend}) is not MuJoCo-backed; it has no cameras "
                f"to render (use obs=state)"
            )
        return env
    cams = chosen_cameras(options, defaults)
    present = camera_names(env.mujoco.model)
    if not wants_images(options):
        cams = [c for c in cams if c in present] or present[:1]
        if not cams:
            return env
    try:
        return CameraEnv(env, options.obs, cams, parse_image_size(options.image_size), where, scene_flags)
    except BaseException:
        env.close()
        raise


class CameraEnv(AdapterWrapper):
    """An env adapter plus offscreen cameras; the `EnvAdapter` contract forwarded to `inner`
    (`AdapterWrapper`), the observation and its spec extended with the camera images.

    Attributes:
        inner: the wrapped adapter (suites hand it to code that needs the concrete env, e.g. experts).
        rig: the `CameraRig`, also `mujoco.cameras`.
        mode: the `obs=` mode.
    """

    def __init__(
        self,
        inner: EnvAdapter,
        mode: str,
        cameras: Sequence[str],
        size: tuple[int, int],
        where: str,
        scene_flags: dict[str, bool] | None = None,
    ):
        super().__init__(inner)
        self.mode = mode
        assert self.mujoco is not None  # checked by the suite before wrapping: cameras need a MuJoCo model
        self.rig = CameraRig(self.mujoco.model, self.mujoco.data, cameras, size, where=where, scene_flags=scene_flags)
        self.mujoco.cameras = self.rig
        spec = dict(inner.obs_spec)
        if mode == "rgb":
            spec.pop(STATE, None)
        if mode != "state":
            spec.update(self.rig.spec())
        self.obs_spec: ObsSpec = spec

    def _obs(self, obs: Obs) -> Obs:
        if self.mode == "state":
            return obs
        out = {k: v for k, v in obs.items() if not (self.mode == "rgb" and k == STATE)}
        out.update(self.rig.render())
        return out

    def reset(self, seed: int) -> Obs:
        return self._obs(self.inner.reset(seed))

    def step(self, action: np.ndarray) -> tuple[Obs, float, bool, bool, dict[str, object]]:
        obs, reward, terminated, truncated, info = self.inner.step(action)
        return self._obs(obs), reward, terminated, truncated, info

    def edit_start(self, edit: Callable[[], None]) -> Obs:
        return self._obs(super().edit_start(edit))  # images rendered from the edited state

    def close(self) -> None:
        try:
            self.rig.close()
            if self.mujoco is not None:
                self.mujoco.cameras = None
        finally:
            self.inner.close()

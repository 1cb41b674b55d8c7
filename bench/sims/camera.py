"""Offscreen cameras of a MuJoCo env: `rgb.<camera>` images from the model's named cameras.

One `CameraRig` per env instance, made when the env is built (once per worker) and closed with
it: it owns an OpenGL context, a MuJoCo render context and one scene (made at the first render,
so an env that never renders costs nothing), and renders every requested camera of the current
`MjData` into (H, W, 3) uint8 arrays. `hook` (a `bench.sims.perturb.scene.VisualScene`, set per
episode) edits the scene before each render. Every MuJoCo backend
(robosuite, Meta-World, Gymnasium MuJoCo, raw MJCF) goes through it, so the images, the
scene settings and the visual perturbations (`bench.sims.perturb.scene`, applied through
`render(hook=...)`) are the same everywhere.

OpenGL backend: the one `MUJOCO_GL` names (egl, osmesa, glfw); EGL when it is unset or
"disable" (robosuite's adapter sets "disable" to keep robosuite's own renderer off; the rig does
not use robosuite's). On CPU machines EGL renders in software (Mesa llvmpipe). When no context
can be made, `RendererError` says why in one line and how to enable one.

Scene settings (they change what a policy sees, so `describe()` records them): shadows,
reflections and the skybox are off by default: on these CPU machines that halves the cost of a
frame (robosuite Lift, one 128x128 camera: ~69 -> ~38 ms, NOTES-simulators.md). A suite whose
policies were trained on another renderer's images passes that renderer's settings (`scene_flags`;
`RENDERER_DEFAULTS` are MuJoCo's and dm_control's, which gym-aloha renders with). Same state and
seed give bit-identical images.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Protocol

import numpy as np

from bench.core.errors import BenchError, ConfigError, valid_choices
from bench.protocols import RGB, Feature

if TYPE_CHECKING:
    import mujoco

IMAGE_SIZE_RANGE = (16, 1024)
SCENE_FLAGS = {"shadows": False, "reflections": False, "skybox": False}
RENDERER_DEFAULTS = {"shadows": True, "reflections": True, "skybox": True}  # MuJoCo's own (dm_control renders so)
_GL_BACKENDS = ("egl", "osmesa", "glfw")

SceneHook = Callable[["mujoco.MjvScene", str], None]  # (scene, camera name) -> None, called before each render


class GLContext(Protocol):
    """An offscreen OpenGL context: `mujoco.egl`, `mujoco.osmesa` or `mujoco.glfw`'s `GLContext`."""

    def make_current(self) -> None: ...

    def free(self) -> None: ...


class RendererError(BenchError):
    """No offscreen OpenGL context can be made in this process (no GPU driver, no software renderer)."""


def camera_names(model: mujoco.MjModel) -> list[str]:
    """The model's named cameras, in id order."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    return [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, i) or f"camera{i}" for i in range(model.ncam)]


def check_cameras(requested: Sequence[str], model: mujoco.MjModel, where: str, field: str = "cameras") -> list[str]:
    """`requested` as a list of the model's camera names; an unknown one is a ConfigError listing the valid ones."""
    valid = camera_names(model)
    if not valid:
        raise ConfigError(f"{field}: {where} has no cameras, so it cannot give image observations (use obs=state)")
    names = [str(c) for c in requested]
    if not names:
        raise ConfigError(f"{field}: empty list; valid cameras of {where}: {', '.join(valid)}")
    for name in names:
        if name not in valid:
            raise ConfigError(f"{field}: {name!r} is not a camera of {where}; {valid_choices(name, valid)}")
    if len(set(names)) != len(names):
        raise ConfigError(f"{field}: {names} names a camera twice")
    return names


def parse_image_size(value: object, field: str = "image_size") -> tuple[int, int]:
    """`image_size=128` (square) or `[height, width]`, each within IMAGE_SIZE_RANGE."""
    parts = list(value) if isinstance(value, (list, tuple)) else [value, value]
    if len(parts) != 2:
        raise ConfigError(f"{field}: {value!r}; expected one size (128) or [height, width]")
    out = []
    for p in parts:
        try:
            n = int(str(p).strip()) if not isinstance(p, bool) else None
        except ValueError:
            n = None
        lo, hi = IMAGE_SIZE_RANGE
        if n is None or str(p).strip() not in (str(n), f"{n}.0") or not lo <= n <= hi:
            raise ConfigError(f"{field}: {value!r} is invalid; image sizes are whole numbers of pixels in [{lo}, {hi}]")
        out.append(n)
    return out[0], out[1]


def _backend() -> str:
    wanted = os.environ.get("MUJOCO_GL", "").strip().lower()
    return wanted if wanted in _GL_BACKENDS else "egl"


def _no_renderer(reason: BaseException | str) -> RendererError:
    text = str(reason).strip().splitlines()
    why = text[0] if text else type(reason).__name__
    return RendererError(
        f"obs=rgb: no offscreen OpenGL renderer could start with MUJOCO_GL={_backend()} ({why}); "
        f"set MUJOCO_GL=egl (software rendering works without a GPU: Mesa's llvmpipe, Debian "
        f"packages libegl1 and libgl1-mesa-dri) or MUJOCO_GL=osmesa"
    )


def _gl_context(width: int, height: int) -> GLContext:
    """An OpenGL context for offscreen rendering, from the backend MUJOCO_GL names (EGL by default)."""
    backend = _backend()
    with warnings.catch_warnings(record=True) as caught:  # GLFW reports "no display" as warnings: one line instead
        warnings.simplefilter("always")
        try:
            if backend == "egl":
                from mujoco.egl import GLContext  # MuJoCo's native library: loaded only when a model is simulated
            elif backend == "osmesa":
                from mujoco.osmesa import GLContext  # MuJoCo's native library: loaded only when a model is simulated
            else:
                from mujoco.glfw import GLContext  # MuJoCo's native library: loaded only when a model is simulated
            ctx = GLContext(width, height)
            ctx.make_current()
        except Exception as exc:  # ImportError, RuntimeError, OpenGL errors: all mean "no context"
            raise _no_renderer(exc) from None
    if caught and backend == "glfw":
        ctx.free()
        raise _no_renderer(str(caught[0].message))
    return ctx


_RENDERER_OK: bool = False


def check_renderer() -> None:
    """Raise RendererError (one line, how to enable one) unless an offscreen OpenGL context can start here.

    Makes and frees a tiny context once per process; called before a run that needs images.
    """
    global _RENDERER_OK
    if _RENDERER_OK:
        return
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><camera name='c'/></worldbody></mujoco>")
    rig = CameraRig(model, mujoco.MjData(model), ["c"], (16, 16))
    try:
        rig.start()  # an OpenGL context, and MuJoCo's render context on it (GLFW without a display fails here)
    finally:
        rig.close()
    _RENDERER_OK = True


class CameraRig:
    """Renders the named cameras of one MuJoCo model into `rgb.<camera>` images.

    Args:
        model, data: the env's `MjModel` and `MjData` (read at every `render`).
        cameras: names of cameras in the model (checked: an unknown name lists the valid ones).
        size: (height, width) in pixels, each in IMAGE_SIZE_RANGE.
        where: the env's name for error messages.
        scene_flags: shadows / reflections / skybox on or off (default `SCENE_FLAGS`: all off).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        cameras: Sequence[str],
        size: tuple[int, int],
        where: str = "the env",
        scene_flags: dict[str, bool] | None = None,
    ):
        import mujoco  # MuJoCo's native library: loaded only when a model is simulated

        self.model, self.data = model, data
        self.cameras = check_cameras(cameras, model, where)
        self.height, self.width = parse_image_size(list(size))
        self._ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, c) for c in self.cameras]
        # The offscreen framebuffer is allocated from these model fields when the render context is made.
        model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), self.width)
        model.vis.global_.offheight = max(int(model.vis.global_.offheight), self.height)
        self._gl: GLContext | None = None
        self._ctx: mujoco.MjrContext | None = None
        self._closed = False
        self.hook: SceneHook | None = None
        self.scene = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom + 100))
        self.scene_flags = {**SCENE_FLAGS, **(scene_flags or {})}
        if set(self.scene_flags) != set(SCENE_FLAGS):
            raise ValueError(f"scene_flags: {sorted(self.scene_flags)}; valid keys: {', '.join(SCENE_FLAGS)}")
        self.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = self.scene_flags["shadows"]
        self.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = self.scene_flags["reflections"]
        self.scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = self.scene_flags["skybox"]
        self._option = mujoco.MjvOption()
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        self._rgb = np.empty((self.height, self.width, 3), dtype=np.uint8)

    def start(self) -> None:
        """Make the OpenGL and MuJoCo render contexts now (else at the first render); RendererError if none can start."""
        import mujoco  # MuJoCo's native library: loaded only when a model is simulated

        if self._ctx is not None:
            return
        if self._closed:
            raise RuntimeError("CameraRig used after close")
        self._gl = _gl_context(self.width, self.height)
        try:
            self._ctx = mujoco.MjrContext(self.model, mujoco.mjtFontScale.mjFONTSCALE_150)
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._ctx)
        except Exception as exc:  # e.g. a backend that "started" without a display: MuJoCo finds no GL
            self.close()
            raise _no_renderer(exc) from None

    @property
    def context(self) -> mujoco.MjrContext:
        """The `mujoco.MjrContext` (textures are uploaded to it after the model's are edited)."""
        self.start()
        return self._ctx

    def make_current(self) -> None:
        """Make this rig's OpenGL context current (before uploading textures or rendering)."""
        self.start()
        assert self._gl is not None  # made by start()
        self._gl.make_current()

    def spec(self) -> dict[str, Feature]:
        """The observation entries the rig adds: `rgb.<camera>` (H, W, 3) uint8."""
        return {f"{RGB}{c}": Feature.rgb(self.height, self.width) for c in self.cameras}

    def describe(self) -> dict[str, object]:
        """What shapes the images: cameras, size, scene settings and the OpenGL backend."""
        return {
            "cameras": list(self.cameras),
            "height": self.height,
            "width": self.width,
            "scene": dict(self.scene_flags),
            "gl": _backend(),
        }

    def render_one(self, camera: str, hook: SceneHook | None = None) -> np.ndarray:
        """One camera's image of the current state, as a new (H, W, 3) uint8 array (`hook` default: `self.hook`)."""
        import mujoco  # MuJoCo's native library: loaded only when a model is simulated

        self.start()
        hook = hook if hook is not None else self.hook
        self._camera.fixedcamid = self._ids[self.cameras.index(camera)]
        mujoco.mjv_updateScene(
            self.model, self.data, self._option, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL, self.scene
        )
        if hook is not None:
            hook(self.scene, camera)
        assert self._gl is not None  # made by start()
        self._gl.make_current()
        mujoco.mjr_render(self._rect, self.scene, self._ctx)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, self._ctx)
        return np.flipud(self._rgb).copy()  # OpenGL's first row is the bottom one

    def render(self, hook: SceneHook | None = None) -> dict[str, np.ndarray]:
        """Every camera's image of the current state: {"rgb.<camera>": (H, W, 3) uint8}."""
        return {f"{RGB}{c}": self.render_one(c, hook) for c in self.cameras}

    def close(self) -> None:
        """Free the render and OpenGL contexts (idempotent)."""
        self._closed = True
        if self._ctx is not None:
            self._ctx.free()
            self._ctx = None
        if self._gl is not None:
            self._gl.free()
            self._gl = None

    def __enter__(self) -> CameraRig:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()

"""The visual axes applied: a camera rig's render hook edits the scene MuJoCo builds for each camera.

`VisualScene` holds one episode's perturbation of one rig (lights, camera poses, colours,
textures, distractors) with draws from the episode's generator; `clear()` puts the nominal scene
back. `clear`, `apply` and `validate` are the per-episode flow `bench.sims.perturb.reset` calls. What the
axes are, and the checks of a model against them, are `bench.sims.perturb.visual`'s.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.core.errors import ConfigError
from bench.protocols import EnvAdapter, option_keys, registry
from bench.sims.camera_env import CameraEnv
from bench.sims.perturb.visual import AXES, TEXTURES, check, model_names, surface, target_geoms, textures_of


def _rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    """Rotation matrix about a unit axis (Rodrigues)."""
    k = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    a = math.radians(degrees)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(a) * kx + (1 - math.cos(a)) * kx @ kx


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _pattern(kind: int, height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """A procedural (H, W, 3) uint8 texture: 1 checker, 2 stripes, 3 smooth noise, 4 rings."""
    c0, c1 = rng.uniform(0, 255, size=3), rng.uniform(0, 255, size=3)
    y, x = np.mgrid[0:height, 0:width] / max(height, width)
    if kind == 1:
        mix = (np.floor(x * 8) + np.floor(y * 8)) % 2
    elif kind == 2:
        mix = np.floor((x + y) * 12) % 2
    elif kind == 3:
        coarse = rng.uniform(0, 1, size=(9, 9))
        yi, xi = np.clip((y * 8).astype(int), 0, 7), np.clip((x * 8).astype(int), 0, 7)
        fy, fx = y * 8 - yi, x * 8 - xi
        mix = (
            coarse[yi, xi] * (1 - fy) * (1 - fx)
            + coarse[yi + 1, xi] * fy * (1 - fx)
            + coarse[yi, xi + 1] * (1 - fy) * fx
            + coarse[yi + 1, xi + 1] * fy * fx
        )
    else:
        mix = 0.5 + 0.5 * np.sin(np.hypot(x - 0.5, y - 0.5) * 40)
    return np.rint(c0 * (1 - mix[..., None]) + c1 * mix[..., None]).astype(np.uint8)


@dataclass
class VisualScene:
    """One episode's visual perturbation of a camera rig; the rig calls it on every render (`hook`).

    Args:
        rig: the env's `bench.sims.camera.CameraRig`.
        object_bodies: bodies of the manipulated object(s) (from the env's `MujocoHandle`).
        where: the env's name for error messages.
    """

    rig: Any
    object_bodies: Sequence[str] = ()
    where: str = "the env"
    light_scale: float = 1.0
    light_rot: np.ndarray | None = None
    cam_cameras: tuple[str, ...] = ()
    cam_offset: np.ndarray | None = None
    cam_rot: np.ndarray | None = None
    colors: dict[int, tuple[float, np.ndarray]] = field(default_factory=dict)  # geom -> (blend, rgb in 0..1)
    n_distractors: int = 0
    _distractor_seed: int = 0
    _distractors: list[tuple] | None = None
    _nominal_tex: dict[int, np.ndarray] = field(default_factory=dict)
    _dirty_tex: set[int] = field(default_factory=set)

    def clear(self) -> None:
        """Back to the nominal scene (restores edited textures in the model and on the GPU)."""
        self.light_scale, self.light_rot = 1.0, None
        self.cam_cameras, self.cam_offset, self.cam_rot = (), None, None
        self.colors, self.n_distractors, self._distractors = {}, 0, None
        if self._dirty_tex:
            model = self.rig.model
            for t in sorted(self._dirty_tex):
                adr = int(model.tex_adr[t])
                model.tex_data[adr : adr + self._nominal_tex[t].size] = self._nominal_tex[t]
                self._upload(t)
            self._dirty_tex.clear()

    @property
    def active(self) -> bool:
        return bool(
            self.light_scale != 1.0
            or self.light_rot is not None
            or self.cam_offset is not None
            or self.cam_rot is not None
            or self.colors
            or self.n_distractors
            or self._dirty_tex
        )

    def _upload(self, texid: int) -> None:
        import mujoco  # MuJoCo's native library: loaded only when a model is simulated

        self.rig.make_current()
        mujoco.mjr_uploadTexture(self.rig.model, self.rig.context, texid)

    def apply(self, axis: str, value: float, named: dict[str, list[str]], rng: np.random.Generator) -> dict[str, Any]:
        """Perturb the scene along `axis` at level `value` (drawn already); returns the params to record."""
        model = self.rig.model
        field = f"perturb.{axis}"
        params: dict[str, Any] = {axis: value}
        if axis == "light":
            self.light_scale = float(value)
        elif axis == "light_dir":
            azimuth = float(rng.uniform(0.0, 360.0))
            a = math.radians(azimuth)
            self.light_rot = _rotation(np.array([math.cos(a), math.sin(a), 0.0]), float(value))
            params[f"{axis}.azimuth_deg"] = round(azimuth, 3)
        elif axis in ("camera_pos", "camera_rot"):
            direction = _unit(rng)
            self.cam_cameras = tuple(named.get("cameras") or self.rig.cameras)
            if axis == "camera_pos":
                self.cam_offset = float(value) * direction
            else:
                self.cam_rot = _rotation(direction, float(value))
            params[f"{axis}.{'direction' if axis == 'camera_pos' else 'axis'}"] = [
                round(float(v), 6) for v in direction
            ]
        elif axis in ("object_color", "table_color", "background"):
            rgb = rng.uniform(0.0, 1.0, size=3)
            for g in target_geoms(model, axis, self.object_bodies, named, self.where):
                self.colors[g] = (float(value), rgb)
            params[f"{axis}.rgb"] = [round(float(v), 4) for v in rgb]
        elif axis == "texture":
            kind = int(value)
            for t in textures_of(
                model, target_geoms(model, axis, self.object_bodies, named, self.where), field, self.where
            ):
                h, w, nc = int(model.tex_height[t]), int(model.tex_width[t]), int(model.tex_nchannel[t])
                adr = int(model.tex_adr[t])
                if t not in self._nominal_tex:
                    self._nominal_tex[t] = np.array(model.tex_data[adr : adr + h * w * nc], copy=True)
                img = _pattern(kind, h, w, rng)
                if nc == 4:
                    img = np.concatenate([img, np.full((h, w, 1), 255, np.uint8)], axis=-1)
                model.tex_data[adr : adr + h * w * nc] = img[..., :nc].reshape(-1)
                self._dirty_tex.add(t)
                self._upload(t)
            params[f"{axis}.name"] = TEXTURES[kind - 1]
        elif axis == "distractors":
            self.n_distractors = int(value)
            self._distractor_seed = int(rng.integers(0, 2**31 - 1))
            self._distractors = None
        else:
            raise ConfigError(f"{field}: not a visual axis; valid: {', '.join(AXES)}")
        return params

    def _place_distractors(self) -> list[tuple]:
        """Distractors for this episode, placed at the first render (the object has its initial position then)."""
        import mujoco  # MuJoCo's native library: loaded only when a model is simulated

        model, data = self.rig.model, self.rig.data
        rng = np.random.default_rng(self._distractor_seed)
        lo, hi, z = surface(model, data, self.object_bodies, self.where)
        bodies = model_names(model, "body", model.nbody)
        avoid = [np.asarray(data.xpos[bodies.index(b)][:2]) for b in self.object_bodies if b in bodies]
        kinds = (
            mujoco.mjtGeom.mjGEOM_BOX,
            mujoco.mjtGeom.mjGEOM_SPHERE,
            mujoco.mjtGeom.mjGEOM_CYLINDER,
            mujoco.mjtGeom.mjGEOM_CAPSULE,
        )
        out: list[tuple] = []
        for _ in range(self.n_distractors):
            kind = kinds[int(rng.integers(len(kinds)))]
            r, h = float(rng.uniform(0.012, 0.03)), float(rng.uniform(0.012, 0.035))
            for _attempt in range(50):
                xy = rng.uniform(lo, hi)
                if all(np.linalg.norm(xy - a) > 0.07 for a in avoid + [np.asarray(o[2][:2]) for o in out]):
                    break
            size = np.array([r, r, h]) if kind == mujoco.mjtGeom.mjGEOM_BOX else np.array([r, h, 0.0])
            lift = (
                r if kind == mujoco.mjtGeom.mjGEOM_SPHERE else h + (r if kind == mujoco.mjtGeom.mjGEOM_CAPSULE else 0.0)
            )
            yaw = float(rng.uniform(0, 2 * math.pi))
            mat = _rotation(np.array([0.0, 0.0, 1.0]), math.degrees(yaw)).reshape(-1)
            rgba = np.append(rng.uniform(0.05, 0.95, size=3), 1.0).astype(np.float32)
            out.append((kind, size, np.array([xy[0], xy[1], z + lift]), mat, rgba))
        return out

    def __call__(self, scene: Any, camera: str) -> None:
        """Render hook: edit the scene MuJoCo built for `camera` (lights, camera pose, colours, extra geoms)."""
        import mujoco  # MuJoCo's native library: loaded only when a model is simulated

        if self.light_scale != 1.0 or self.light_rot is not None:
            center = np.asarray(self.rig.model.stat.center)
            for i in range(scene.nlight):
                light = scene.lights[i]
                if self.light_scale != 1.0:
                    for attr in ("ambient", "diffuse", "specular"):
                        value = getattr(light, attr)
                        value[:] = np.clip(value * self.light_scale, 0.0, 1.0)
                if self.light_rot is not None and not light.headlight:
                    light.dir[:] = self.light_rot @ light.dir
                    light.pos[:] = center + self.light_rot @ (light.pos - center)
        if camera in self.cam_cameras:
            for cam in scene.camera:
                if self.cam_offset is not None:
                    cam.pos[:] = cam.pos + self.cam_offset
                if self.cam_rot is not None:
                    cam.forward[:] = self.cam_rot @ cam.forward
                    cam.up[:] = self.cam_rot @ cam.up
        if self.colors:
            geom_type = int(mujoco.mjtObj.mjOBJ_GEOM)
            for i in range(scene.ngeom):
                g = scene.geoms[i]
                hit = self.colors.get(int(g.objid)) if int(g.objtype) == geom_type else None
                if hit is not None:
                    blend, rgb = hit
                    g.rgba[:3] = (1.0 - blend) * g.rgba[:3] + blend * rgb
        if self.n_distractors:
            if self._distractors is None:
                self._distractors = self._place_distractors()
            for kind, size, pos, mat, rgba in self._distractors:
                if scene.ngeom >= scene.maxgeom:
                    break
                mujoco.mjv_initGeom(scene.geoms[scene.ngeom], kind, size, pos, mat, rgba)
                scene.ngeom += 1


def _rig(env: Any) -> Any:
    mj = env.mujoco
    return None if mj is None else mj.cameras


def clear(env: EnvAdapter) -> None:
    """Put the env's rendered scene back to nominal (every episode, whatever its condition)."""
    rig = _rig(env)
    if rig is not None and isinstance(rig.hook, VisualScene):
        rig.hook.clear()


def apply(
    env: EnvAdapter, axis: str, value: float, named: dict[str, list[str]], rng: np.random.Generator
) -> dict[str, Any]:
    """Apply one visual axis at `value` for this episode; returns the params to record."""
    rig = _rig(env)
    if rig is None:
        raise ConfigError(f"perturb.{axis}: env {env.backend} has no cameras to perturb")
    if not isinstance(rig.hook, VisualScene):
        assert env.mujoco is not None  # a rig exists only on a MuJoCo handle (_rig)
        rig.hook = VisualScene(rig, tuple(env.mujoco.object_bodies), where=env.backend)
    return rig.hook.apply(axis, value, named, rng)


def suites_with_cameras() -> list[str]:
    """Registered suites that take the camera keys (`obs`, `cameras`, `image_size`: `bench.sims.camera_env.CameraOptions`)."""
    out = []
    for name in registry.names(registry.SUITES):
        try:
            cls: Any = registry.suite_class(name)
            if {"obs", "cameras", "image_size"} <= set(option_keys(cls.Options)):
                out.append(name)
        except Exception:  # a broken plugin is reported by `bench list`, not here
            continue
    return out


def validate(env: EnvAdapter, axis: str, named: dict[str, list[str]], where: str) -> None:
    """ConfigError naming the axis (and the suites that can apply it) unless `env` can apply it this run."""
    rig = _rig(env)
    if rig is None:
        raise ConfigError(
            f"perturb.{axis}: {where} ({env.backend}) has no camera rig, so a visual axis changes "
            f"nothing; suites that render cameras: {', '.join(suites_with_cameras()) or 'none'}"
        )
    if isinstance(env, CameraEnv) and env.mode == "state":
        raise ConfigError(
            f"perturb.{axis} changes only what the cameras see, and obs=state gives the policy no "
            f"image; use obs=rgb or obs=state+rgb"
        )
    assert env.mujoco is not None  # a rig exists only on a MuJoCo handle (_rig)
    check(env.mujoco.model, tuple(env.mujoco.object_bodies), axis, named, list(rig.cameras), where)

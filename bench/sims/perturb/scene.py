"""The visual axes, one row each, applied by a camera rig's render hook to the scene MuJoCo builds per camera.

What the cameras see changes, the physics does not: every axis acts on the rendered scene of a
`bench.sims.camera.CameraRig`, relative to the nominal scene, with draws from the episode's own
generator (textures are the one model field edited: `tex_data`, which only the renderer reads, restored
and re-uploaded before the next episode). A row's `paint` sets one episode's perturbation on the
rig's `VisualScene`, whose `__call__` edits each camera's scene before it is drawn; its `check` refuses
a model the axis cannot act on (the targets, textures and surfaces are `bench.sims.perturb.visual`'s).
`clear`, `apply` and `validate` are the per-episode flow `bench.sims.perturb.reset` calls. Visual axes
need the env's camera rig (`env.mujoco.cameras`, suites built on `bench.sims.camera_env`) and a
policy that sees images (`obs=rgb` or `obs=state+rgb`).

On ManiSkill the same rows act through SAPIEN's render scene: a row's `sapien` hook sets the episode's
perturbation on the env's `bench.sims.perturb.sapien_scene.SapienScene` (`env.sapien_scene`), which
edits lights, cameras and materials after the reset; a row without one (texture, distractors) is refused
there. The hooks whose edit reads the same on both (light, light_dir, camera_pos, camera_rot, the colours)
are one function: it sets the same fields of either scene.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

from bench.core.errors import ConfigError
from bench.protocols import EnvAdapter, option_keys, registry
from bench.sims.camera import CameraRig
from bench.sims.camera_env import CameraEnv
from bench.sims.perturb.axis import MAX_SCALE, RGB_IMAGES, Axis, Named, Params
from bench.sims.perturb.sapien_scene import SapienScene
from bench.sims.perturb.visual import (
    TEXTURES,
    check_cameras,
    model_names,
    pattern,
    place_distractors,
    rotation,
    surface,
    target_geoms,
    textures_of,
)

if TYPE_CHECKING:
    import mujoco

# a row's hooks (`bench.sims.perturb.axis.Axis.paint` and `.check`)
Paint = Callable[["VisualScene", float, Named, np.random.Generator], Params]
Check = Callable[["mujoco.MjModel", Sequence[str], Named, Sequence[str], str], None]


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


@dataclass
class VisualScene:
    """One episode's visual perturbation of a camera rig; the rig calls it on every render (`hook`).

    Args:
        rig: the env's `bench.sims.camera.CameraRig`.
        object_bodies: bodies of the manipulated object(s) (from the env's `MujocoHandle`).
        where: the env's name for error messages.
    """

    rig: CameraRig
    object_bodies: Sequence[str] = ()
    where: str = "the env"
    light_scale: float = 1.0
    light_rot: np.ndarray | None = None
    cam_cameras: tuple[str, ...] = ()
    cam_offset: np.ndarray | None = None
    cam_rot: np.ndarray | None = None
    fov_cameras: tuple[str, ...] = ()
    fov_scale: float = 1.0  # tan(half field of view) of the perturbed camera over the nominal one's
    colors: dict[int, tuple[float, np.ndarray]] = field(default_factory=dict)  # geom -> (blend, rgb in 0..1)
    n_distractors: int = 0
    distractor_seed: int = 0
    distractors: list[tuple] | None = None
    nominal_tex: dict[int, np.ndarray] = field(default_factory=dict)
    dirty_tex: set[int] = field(default_factory=set)

    @property
    def cameras(self) -> tuple[str, ...]:
        """The cameras the rig renders."""
        return tuple(self.rig.cameras)

    def blend_toward(self, axis: str, named: Named, blend: float, rgb: np.ndarray) -> None:
        """Blend a colour axis' geoms (the named ones, else its default; ConfigError when none) toward `rgb`."""
        for g in target_geoms(self.rig.model, axis, self.object_bodies, named, self.where):
            self.colors[g] = (blend, rgb)

    def clear(self) -> None:
        """Back to the nominal scene (restores edited textures in the model and on the GPU)."""
        self.light_scale, self.light_rot = 1.0, None
        self.cam_cameras, self.cam_offset, self.cam_rot = (), None, None
        self.fov_cameras, self.fov_scale = (), 1.0
        self.colors, self.n_distractors, self.distractors = {}, 0, None
        if self.dirty_tex:
            model = self.rig.model
            for t in sorted(self.dirty_tex):
                adr = int(model.tex_adr[t])
                model.tex_data[adr : adr + self.nominal_tex[t].size] = self.nominal_tex[t]
                self.upload(t)
            self.dirty_tex.clear()

    @property
    def active(self) -> bool:
        return bool(
            self.light_scale != 1.0
            or self.light_rot is not None
            or self.cam_offset is not None
            or self.cam_rot is not None
            or self.fov_scale != 1.0
            or self.colors
            or self.n_distractors
            or self.dirty_tex
        )

    def upload(self, texid: int) -> None:
        import mujoco  # MuJoCo's native library: loaded only when a model is simulated

        self.rig.make_current()
        mujoco.mjr_uploadTexture(self.rig.model, self.rig.context, texid)

    def apply(self, axis: str, value: float, named: Named, rng: np.random.Generator) -> Params:
        """Perturb the scene along `axis` at level `value` (drawn already); returns the params to record."""
        row = ROWS.get(axis)
        if row is None or row.paint is None:
            raise ConfigError(f"perturb.{axis}: not a visual axis; valid: {', '.join(ROWS)}")
        return {axis: value, **row.paint(self, value, named, rng)}

    def __call__(self, scene: mujoco.MjvScene, camera: str) -> None:
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
        if camera in self.fov_cameras and self.fov_scale != 1.0:
            for cam in scene.camera:  # a perspective frustum: its half-extents at the near plane
                cam.frustum_bottom *= self.fov_scale
                cam.frustum_top *= self.fov_scale
                cam.frustum_center *= self.fov_scale
                cam.frustum_width *= self.fov_scale
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
            if self.distractors is None:
                self.distractors = place_distractors(
                    self.rig.model,
                    self.rig.data,
                    self.object_bodies,
                    self.n_distractors,
                    self.distractor_seed,
                    self.where,
                )
            for kind, size, pos, mat, rgba in self.distractors:
                if scene.ngeom >= scene.maxgeom:
                    break
                mujoco.mjv_initGeom(scene.geoms[scene.ngeom], kind, size, pos, mat, rgba)
                scene.ngeom += 1


def _rig(env: EnvAdapter) -> CameraRig | None:
    mj = env.mujoco
    return None if mj is None else mj.cameras


def _sapien(env: EnvAdapter) -> SapienScene | None:
    """The SAPIEN render scene a ManiSkill adapter exposes (`sapien_scene`), else None."""
    scene = getattr(env, "sapien_scene", None)  # a capability of ManiSkill adapters only, outside the contract
    return scene if isinstance(scene, SapienScene) else None


def clear(env: EnvAdapter) -> None:
    """Put the env's rendered scene back to nominal (every episode, whatever its condition)."""
    rig, sapien = _rig(env), _sapien(env)
    if rig is not None and isinstance(rig.hook, VisualScene):
        rig.hook.clear()
    if sapien is not None:
        sapien.clear()


def apply(env: EnvAdapter, axis: str, value: float, named: Named, rng: np.random.Generator) -> Params:
    """Apply one visual axis at `value` for this episode; returns the params to record."""
    sapien = _sapien(env)
    if sapien is not None:
        hook = ROWS[axis].sapien
        if hook is None:
            raise ConfigError(f"perturb.{axis}: not available on ManiSkill/SAPIEN; valid: {', '.join(_on_sapien())}")
        return {axis: value, **hook(sapien, value, named, rng)}
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
            cls = registry.suite_class(name)
            if {"obs", "cameras", "image_size"} <= set(option_keys(cls.Options)):
                out.append(name)
        except Exception:  # a broken plugin is reported by `bench list`, not here
            continue
    return out


def _on_sapien() -> list[str]:
    return [n for n, a in ROWS.items() if a.sapien is not None]


def validate(env: EnvAdapter, axis: str, named: Named, where: str) -> None:
    """ConfigError naming the axis (and the suites that can apply it) unless `env` can apply it this run."""
    sapien = _sapien(env)
    if sapien is not None:
        sapien.validate(axis, ROWS[axis].sapien, named, _on_sapien())
        return
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
    row = ROWS[axis]
    if row.check is not None:
        row.check(env.mujoco.model, tuple(env.mujoco.object_bodies), named, list(rig.cameras), where)


# -- the rows: (scene, level, named targets, generator) -> params to record beside the level ----
def _light(vs: VisualScene | SapienScene, value: float, named: Named, rng: np.random.Generator) -> Params:
    vs.light_scale = float(value)
    return {}


def _light_dir(vs: VisualScene | SapienScene, value: float, named: Named, rng: np.random.Generator) -> Params:
    azimuth = float(rng.uniform(0.0, 360.0))
    a = math.radians(azimuth)
    vs.light_rot = rotation(np.array([math.cos(a), math.sin(a), 0.0]), float(value))
    return {"light_dir.azimuth_deg": round(azimuth, 3)}


def _camera_pos(vs: VisualScene | SapienScene, value: float, named: Named, rng: np.random.Generator) -> Params:
    direction = _unit(rng)
    vs.cam_cameras = tuple(named.get("cameras") or vs.cameras)
    vs.cam_offset = float(value) * direction
    return {"camera_pos.direction": [round(float(v), 6) for v in direction]}


def _camera_rot(vs: VisualScene | SapienScene, value: float, named: Named, rng: np.random.Generator) -> Params:
    direction = _unit(rng)
    vs.cam_cameras = tuple(named.get("cameras") or vs.cameras)
    vs.cam_rot = rotation(direction, float(value))
    return {"camera_rot.axis": [round(float(v), 6) for v in direction]}


MAX_FOV_DEG = 170.0  # a wider perspective frustum is degenerate


def _camera_fov(vs: VisualScene, value: float, named: Named, rng: np.random.Generator) -> Params:
    """The vertical field of view of every (or the named) camera times the level (capped at 170 degrees)."""
    model = vs.rig.model
    vs.fov_cameras = tuple(named.get("cameras") or vs.rig.cameras)
    cams = model_names(model, "camera", model.ncam)
    fovy = {c: float(model.cam_fovy[cams.index(c)]) for c in vs.fov_cameras if c in cams}
    base = next(iter(fovy.values()), 45.0)
    wanted = min(base * float(value), MAX_FOV_DEG)
    # every camera's frustum scales by the same ratio of tangents (cameras of one rig share a fovy in our suites)
    vs.fov_scale = math.tan(math.radians(wanted) / 2) / math.tan(math.radians(base) / 2)
    return {"camera_fov.deg": round(wanted, 4)}


def _camera_fov_sapien(ss: SapienScene, value: float, named: Named, rng: np.random.Generator) -> Params:
    """The same on SAPIEN: each camera's own vertical field of view times the level (capped at 170 degrees)."""
    ss.fov_deg = {c: min(ss.fovy_deg(c) * float(value), MAX_FOV_DEG) for c in named.get("cameras") or ss.cameras}
    return {"camera_fov.deg": round(next(iter(ss.fov_deg.values()), 0.0), 4)}


def _color(axis: str) -> Paint:
    def paint(vs: VisualScene | SapienScene, value: float, named: Named, rng: np.random.Generator) -> Params:
        rgb = rng.uniform(0.0, 1.0, size=3)
        vs.blend_toward(axis, named, float(value), rgb)
        return {f"{axis}.rgb": [round(float(v), 4) for v in rgb]}

    return paint


def _texture(vs: VisualScene, value: float, named: Named, rng: np.random.Generator) -> Params:
    model, kind = vs.rig.model, int(value)
    geoms = target_geoms(model, "texture", vs.object_bodies, named, vs.where)
    for t in textures_of(model, geoms, "perturb.texture", vs.where):
        h, w, nc = int(model.tex_height[t]), int(model.tex_width[t]), int(model.tex_nchannel[t])
        adr = int(model.tex_adr[t])
        if t not in vs.nominal_tex:
            vs.nominal_tex[t] = np.array(model.tex_data[adr : adr + h * w * nc], copy=True)
        img = pattern(kind, h, w, rng)
        if nc == 4:
            img = np.concatenate([img, np.full((h, w, 1), 255, np.uint8)], axis=-1)
        model.tex_data[adr : adr + h * w * nc] = img[..., :nc].reshape(-1)
        vs.dirty_tex.add(t)
        vs.upload(t)
    return {"texture.name": TEXTURES[kind - 1]}


def _distractors(vs: VisualScene, value: float, named: Named, rng: np.random.Generator) -> Params:
    vs.n_distractors = int(value)
    vs.distractor_seed = int(rng.integers(0, 2**31 - 1))
    vs.distractors = None
    return {}


def _check_cameras(axis: str) -> Check:
    def check(model: mujoco.MjModel, objects: Sequence[str], named: Named, cameras: Sequence[str], where: str) -> None:
        check_cameras(axis, named, cameras, where)

    return check


def _check_geoms(axis: str) -> Check:
    def check(model: mujoco.MjModel, objects: Sequence[str], named: Named, cameras: Sequence[str], where: str) -> None:
        target_geoms(model, axis, objects, named, where)

    return check


def _check_texture(
    model: mujoco.MjModel, objects: Sequence[str], named: Named, cameras: Sequence[str], where: str
) -> None:
    textures_of(model, target_geoms(model, "texture", objects, named, where), "perturb.texture", where)


def _check_surface(
    model: mujoco.MjModel, objects: Sequence[str], named: Named, cameras: Sequence[str], where: str
) -> None:
    surface(model, None, objects, where)


# a visual axis; one that moves every (or the named) camera by an offset
_visual_axis = partial(Axis, kind="visual", sees=RGB_IMAGES, maximum=MAX_SCALE)
_camera_axis = partial(Axis, kind="visual", sees=RGB_IMAGES, maximum=MAX_SCALE, targets=("cameras",), nominal=0.0)


def _blend_row(name: str, short: str, what: str) -> Axis:
    """A colour axis: the default (or the named) geoms' colour blended toward a colour drawn per episode."""
    doc = f"{what} blended toward a colour drawn per episode"
    color = _color(name)
    return _visual_axis(
        name,
        unit="blend 0..1",
        short=short,
        doc=doc,
        targets=("geoms", "bodies"),
        nominal=0.0,
        maximum=1.0,
        paint=color,
        sapien=color,
        check=_check_geoms(name),
    )


ROWS: dict[str, Axis] = {
    a.name: a
    for a in (
        _visual_axis(
            "light",
            unit="scale of nominal",
            short="light intensity",
            doc="ambient, diffuse and specular intensity of every light, headlight included",
            paint=_light,
            sapien=_light,
        ),
        _visual_axis(
            "light_dir",
            unit="degrees",
            short="light direction tilt",
            doc="every light tilted about a horizontal axis through the scene centre (azimuth drawn per episode)",
            nominal=0.0,
            paint=_light_dir,
            sapien=_light_dir,
            maximum=90.0,
        ),
        _camera_axis(
            "camera_pos",
            unit="metres",
            short="camera position offset",
            doc="every (or the named) camera moved this far in a direction drawn per episode",
            paint=_camera_pos,
            sapien=_camera_pos,
            check=_check_cameras("camera_pos"),
            maximum=1.0,
        ),
        _camera_axis(
            "camera_rot",
            unit="degrees",
            short="camera orientation offset",
            doc="every (or the named) camera rotated this much about an axis drawn per episode",
            paint=_camera_rot,
            sapien=_camera_rot,
            check=_check_cameras("camera_rot"),
            maximum=90.0,
        ),
        _camera_axis(
            "camera_fov",
            unit="scale of nominal field of view",
            short="camera field of view",
            doc="the vertical field of view of every (or the named) camera times the level (0.5 zooms in, "
            f"2 widens; at most {MAX_FOV_DEG:g} degrees), the image size unchanged",
            strict=True,
            paint=_camera_fov,
            sapien=_camera_fov_sapien,
            check=_check_cameras("camera_fov"),
            nominal=1.0,
            maximum=4.0,
        ),
        _blend_row("object_color", "object colour", "the manipulated object's colour"),
        _blend_row("table_color", "table colour", "the table's colour (geoms/bodies named like 'table')"),
        _blend_row("background", "floor and wall colour", "floor and walls (world-body geoms other than the table)"),
        _visual_axis(
            "texture",
            unit=f"texture 1..{len(TEXTURES)} ({', '.join(TEXTURES)})",
            short="unseen table texture",
            doc="the table's texture replaced by a procedural one in colours drawn per episode",
            minimum=1.0,
            integer=True,
            targets=("geoms", "bodies"),
            nominal=0.0,
            paint=_texture,
            check=_check_texture,
            maximum=float(len(TEXTURES)),
        ),
        _visual_axis(
            "distractors",
            unit="objects",
            short="distractor objects on the table",
            doc="boxes, spheres, cylinders and capsules of random size and colour on the table (visual only)",
            integer=True,
            nominal=0.0,
            paint=_distractors,
            check=_check_surface,
            maximum=20.0,
        ),
    )
}

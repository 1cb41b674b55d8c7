"""Visual axes on ManiSkill: one episode's edit of the scene SAPIEN renders the cameras from.

The rows are `bench.sims.perturb.scene`'s (same names, units and draws as on MuJoCo); a row's `sapien`
hook sets the episode's perturbation on the env's `SapienScene` (`ManiSkillEnv.sapien_scene`) before
the reset, and the adapter calls `after_reset` once its reset has built (or kept) the scene: the edits
are made then, on the scene that renders the episode, the reset's observation is rendered again, and
`clear` undoes them before the next episode (a rebuilt scene starts nominal anyway). What each edits:

    light        the ambient light and every light's colour times the level (not clipped: SAPIEN's light
                 colours are intensities, so a level above 1 brightens without saturating the lights)
    light_dir    every light's pose rotated about a horizontal axis through the world origin (the table)
    camera_pos   the camera's local pose moved (a fixed camera: in the world frame; one mounted on a link,
                 e.g. `hand_camera`: in the link's frame; the direction is uniform either way)
    camera_rot   the camera rotated about its own position (the same frames)
    camera_fov   the camera's vertical field of view times the level (at most 170 degrees), the image size
                 and principal point unchanged
    object_color, table_color, background
                 the targeted actors' materials blended toward a colour: a material's base colour, or its
                 colour texture (blended in linear light, as the shader reads an sRGB texture)

Targets are ManiSkill's names: actors ("cube", "table-workspace", "ground") and links ("panda_hand") for
`bodies`, the rendered cameras for `cameras`. Defaults: the task's objects (`object_color`), the actors
named like "table" (`table_color`), the static actors other than the table (`background`: the ground).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from bench.core.errors import ConfigError, did_you_mean
from bench.protocols import RGB, ObsSpec
from bench.sims.perturb.axis import Named, Params

if TYPE_CHECKING:
    import sapien
    from mani_skill.envs.sapien_env import BaseEnv

Hook = Callable[["SapienScene", float, Named, np.random.Generator], Params]  # a row's `sapien` hook


class SapienHost(Protocol):
    """What the scene edits need of their env (`bench.sims.maniskill.ManiSkillEnv`)."""

    base: BaseEnv
    env_id: str
    robot: str
    cameras: tuple[str, ...]  # the cameras named for rendering
    all_cameras: tuple[str, ...]  # every camera the task and robot mount
    object_names: tuple[str, ...]
    obs_spec: ObsSpec


def _srgb_to_linear(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def _linear_to_srgb(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def _rotated(pose: sapien.Pose, rot: np.ndarray | None, offset: np.ndarray | None, about_origin: bool) -> Any:
    """`pose` rotated by `rot` (about the origin, or about its own position) and moved by `offset`."""
    import sapien  # the maniskill extra: loaded only for ManiSkill suites

    m = np.asarray(pose.to_transformation_matrix(), dtype=np.float64)
    if rot is not None:
        m[:3, :3] = rot @ m[:3, :3]
        if about_origin:
            m[:3, 3] = rot @ m[:3, 3]
    if offset is not None:
        m[:3, 3] += offset
    return sapien.Pose(m.astype(np.float32))


@dataclass
class SapienScene:
    """One episode's visual perturbation of a ManiSkill env: set by the rows' hooks, made by `after_reset`."""

    env: SapienHost
    light_scale: float = 1.0
    light_rot: np.ndarray | None = None
    cam_cameras: tuple[str, ...] = ()
    cam_offset: np.ndarray | None = None
    cam_rot: np.ndarray | None = None
    fov_deg: dict[str, float] = field(default_factory=dict)  # camera -> vertical field of view (degrees)
    colors: dict[str, tuple[float, np.ndarray]] = field(default_factory=dict)  # actor/link -> (blend, rgb 0..1)
    undo: list[Callable[[], None]] = field(default_factory=list)  # restores every edit made, in order

    @property
    def where(self) -> str:
        return f"{self.env.env_id} with {self.env.robot}"

    @property
    def renders(self) -> bool:
        """Whether the policy gets a camera image (obs=rgb or obs=state+rgb)."""
        return any(str(k).startswith(RGB) for k in self.env.obs_spec)

    @property
    def cameras(self) -> tuple[str, ...]:
        """The cameras the env renders (none with obs=state)."""
        return tuple(self.env.cameras) if self.renders else ()

    @property
    def active(self) -> bool:
        return bool(
            self.light_scale != 1.0
            or self.light_rot is not None
            or self.cam_offset is not None
            or self.cam_rot is not None
            or self.fov_deg
            or self.colors
        )

    # -- the episode flow (`bench.sims.perturb.scene`, and the adapter's reset) -----------------
    def clear(self) -> None:
        """Back to the nominal scene: undo the edits and forget the episode's perturbation."""
        self.restore()
        self.light_scale, self.light_rot = 1.0, None
        self.cam_cameras, self.cam_offset, self.cam_rot = (), None, None
        self.fov_deg, self.colors = {}, {}

    def restore(self) -> None:
        for undo in reversed(self.undo):
            undo()
        self.undo.clear()

    def after_reset(self) -> bool:
        """Make the episode's edits on the scene the reset left; whether the cameras see anything changed."""
        self.restore()  # a reset that kept the scene (reset=soft) keeps what was edited before it
        if not self.active or not self.renders:  # nothing renders (obs=state): `validate` refused the axis
            return False
        system = self.env.base.scene.sub_scenes[0].render_system  # one env per adapter
        if self.light_scale != 1.0 or self.light_rot is not None:
            self._lights(system)
        for name in dict.fromkeys(self.cam_cameras + tuple(self.fov_deg)):
            self._camera(name)
        if self.colors:
            self._colors()
        return True

    def validate(self, axis: str, hook: Hook | None, named: Named, available: Sequence[str]) -> None:
        """ConfigError (one line) unless `axis` can act on this env's images with these targets.

        `hook` is the row's `sapien` edit (None: the axis has none) and `available` the visual axes that
        have one. The hook is run once (with a throwaway generator) to check its default targets."""
        field_ = f"perturb.{axis}"
        if hook is None:
            raise ConfigError(
                f"{field_}: not available on ManiSkill/SAPIEN ({self.where}); visual axes there: "
                f"{', '.join(available)} (and the image-noise axes)"
            )
        for key, names in named.items():
            if key == "cameras":
                valid = self.cameras if self.renders else tuple(self.env.all_cameras)
                what = "rendered cameras" if self.renders else "cameras"
                self._check_names(f"{field_}.cameras", names, valid, what)
            elif key == "bodies":
                self._check_names(f"{field_}.bodies", names, list(self._entities()), "actors and links")
            else:
                raise ConfigError(
                    f"{field_}.{key}: ManiSkill/SAPIEN names actors and links, not {key}; use {field_}.bodies=[...]"
                )
        if not self.renders:
            raise ConfigError(
                f"{field_} changes only what the cameras see, and obs=state gives the policy no image; use "
                "obs=rgb or obs=state+rgb (on CPU: scripts/fetch_lavapipe.sh, docs/maniskill.md)"
            )
        try:
            hook(self, 1.0, named, np.random.default_rng(0))
        finally:
            self.clear()

    def _check_names(self, field_: str, names: Sequence[str], valid: Sequence[str], what: str) -> None:
        for n in names:
            if n not in valid:
                listing = ", ".join(list(valid)[:15]) + (f", ... ({len(valid)} in all)" if len(valid) > 15 else "")
                raise ConfigError(
                    f"{field_}: {n!r} is not among the {what} of {self.where}; valid: {listing or 'none'}."
                    f"{did_you_mean(n, valid)}"
                )

    # -- what the rows' hooks read ----------------------------------------------------------
    def fovy_deg(self, camera: str) -> float:
        """The camera's vertical field of view in degrees (nominal: read after `clear`)."""
        return math.degrees(float(self._camera_component(camera).fovy))

    def blend_toward(self, axis: str, named: Named, blend: float, rgb: np.ndarray) -> None:
        """Blend a colour axis' actors and links (the named ones, else its default) toward `rgb` this episode."""
        for name in self.color_targets(axis, named):
            self.colors[name] = (blend, rgb)

    def color_targets(self, axis: str, named: Named) -> list[str]:
        """Actors or links a colour axis blends: the named `bodies`, else the axis' default (ConfigError when none)."""
        field_ = f"perturb.{axis}"
        entities = self._entities()
        if named.get("bodies"):
            self._check_names(f"{field_}.bodies", named["bodies"], list(entities), "actors and links")
            return list(named["bodies"])
        actors = list(self.env.base.scene.actors)
        table = [a for a in actors if "table" in a.lower()]
        if axis == "object_color":
            out = [a for a in self.env.object_names if a in entities]
            if not out:
                raise ConfigError(
                    f"{field_}: {self.where} declares no manipulated object; name it with {field_}.bodies=[...]"
                )
        elif axis == "table_color":
            out = table
            if not out:
                raise ConfigError(
                    f"{field_}: found no actor named like 'table' in {self.where}; name it with {field_}.bodies=[...]"
                )
        else:
            import sapien.physx  # the maniskill extra: loaded only for ManiSkill suites

            hidden = {o.name for o in self.env.base._hidden_objects}  # hidden from the cameras (goal markers)
            out = [
                a
                for a in actors
                if a not in table
                and a not in self.env.object_names
                and a not in hidden
                and entities[a][0].find_component_by_type(sapien.physx.PhysxRigidStaticComponent) is not None
            ]
            if not out:
                raise ConfigError(
                    f"{field_}: {self.where} has no static actor besides the table; name them with {field_}.bodies=[...]"
                )
        return out

    # -- the edits ---------------------------------------------------------------------------
    def _entities(self) -> dict[str, list[sapien.Entity]]:
        """Actors and links of the current scene by ManiSkill name."""
        scene = self.env.base.scene
        out: dict[str, list[sapien.Entity]] = {name: list(a._objs) for name, a in scene.actors.items()}
        for art in scene.articulations.values():
            for link in art.links:
                out[link.name] = [obj.entity for obj in link._objs]
        return out

    def _camera_component(self, name: str) -> Any:
        return self.env.base.scene.sensors[name].camera._render_cameras[0]  # one sub-scene: one component

    def _edit(self, obj: Any, attr: str, value: Any) -> None:
        old = getattr(obj, attr)
        setattr(obj, attr, value)
        self.undo.append(lambda: setattr(obj, attr, old))

    def _lights(self, system: Any) -> None:
        s = self.light_scale
        if s != 1.0:
            self._edit(system, "ambient_light", np.asarray(system.ambient_light, dtype=np.float32) * s)
        for light in system.lights:
            if s != 1.0:
                self._edit(light, "color", np.asarray(light.color, dtype=np.float32) * s)
            if self.light_rot is not None:
                self._edit(light, "local_pose", _rotated(light.local_pose, self.light_rot, None, about_origin=True))

    def _camera(self, name: str) -> None:
        cam = self._camera_component(name)
        if name in self.cam_cameras:
            self._edit(cam, "local_pose", _rotated(cam.local_pose, self.cam_rot, self.cam_offset, about_origin=False))
        if name in self.fov_deg:
            fx, fy = float(cam.fx), float(cam.fy)  # restored exactly (set_fovy back would round)
            cam.set_fovy(math.radians(self.fov_deg[name]), compute_x=True)
            self.undo.append(lambda: cam.set_focal_lengths(fx, fy))

    def _colors(self) -> None:
        entities = self._entities()
        edits: list[tuple[Any, float, np.ndarray]] = []
        for name, (blend, rgb) in self.colors.items():
            for entity in entities[name]:
                for comp in entity.components:
                    for shape in getattr(comp, "render_shapes", ()):  # a RenderBodyComponent's shapes
                        edits += [(p.material, blend, rgb) for p in shape.parts]
        # every new value from the nominal ones read first, so a material shared by two targets is not blended twice
        nominal = [(m, np.asarray(m.base_color, dtype=np.float32), m.base_color_texture) for m, _, _ in edits]
        for (mat, blend, rgb), (_, color, texture) in zip(edits, nominal):
            if texture is not None:
                self._edit(mat, "base_color_texture", _blend_texture(texture, blend, rgb))
            else:
                new = color.copy()
                new[:3] = (1.0 - blend) * color[:3] + blend * rgb
                self._edit(mat, "base_color", new)


def _blend_texture(texture: Any, blend: float, rgb: np.ndarray) -> Any:
    """A copy of an 8-bit colour texture blended toward `rgb` (linear 0..1), in linear light when it is sRGB.

    Each channel's blend is a function of its 8-bit value alone: one 256-entry table per channel."""
    import sapien  # the maniskill extra: loaded only for ManiSkill suites

    img = np.asarray(texture.download())
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[-1] not in (3, 4):
        raise ConfigError(f"a colour axis met a {texture.format} texture it cannot blend; target other bodies")
    srgb = bool(texture.is_srgb)
    levels = np.arange(256, dtype=np.float64) / 255.0
    linear = _srgb_to_linear(levels) if srgb else levels
    out = img.copy()
    for c in range(3):
        mixed = (1.0 - blend) * linear + blend * float(rgb[c])
        table = np.rint(np.clip(_linear_to_srgb(mixed) if srgb else mixed, 0.0, 1.0) * 255.0).astype(np.uint8)
        out[..., c] = table[img[..., c]]
    return sapien.render.RenderTexture2D(
        out, texture.format, texture.mipmap_levels, texture.filter_mode, texture.address_mode, srgb
    )

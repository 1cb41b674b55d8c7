"""Inert SAPIEN visual materials, so ManiSkill builds its scenes on machines without a Vulkan device.

SAPIEN creates `sapien.render.RenderMaterial` / `RenderTexture2D` objects (and actor builders record
visual shapes) even with `render_backend="none"`; each of those asks the Vulkan renderer for a device
and fails with "failed to find a rendering device". With no renderer nothing ever draws them, so this
module replaces the two classes with inert stand-ins and makes `ActorBuilder.add_*visual*` record
nothing. What is replaced is render-side only: a visual record becomes a `RenderBodyComponent` when an
actor is built, never a PhysX shape, material, mass or joint, so physics is unchanged (the tests
compare trajectories with and without the stand-ins where a Vulkan device exists).

The stand-ins are installed only when no render device exists (`prepare(cameras=False)`), and only
for the exact mani-skill / sapien versions they were checked against (`CHECKED`); any other version
is refused with a one-line error rather than patched blindly. Installation is process-wide and
cannot be undone: a process that installed them cannot build camera observations afterwards.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterable
from importlib import import_module
from importlib.metadata import PackageNotFoundError, version
from typing import TypeVar

from bench.core.errors import ConfigError

CHECKED = {"mani-skill": "3.0.1", "sapien": "3.0.3"}
# modules that import the two classes by name (besides sapien.render itself)
_IMPORTERS = ("sapien.wrapper.urdf_loader", "sapien.wrapper.renderer", "mani_skill.utils.building._mjcf_loader")
_VISUAL_ADDERS = (
    "add_plane_visual",
    "add_box_visual",
    "add_capsule_visual",
    "add_cylinder_visual",
    "add_sphere_visual",
    "add_visual_from_file",
)
# SAPIEN warns at import when the system has no libvulkan.so.1 and falls back to the one it bundles, which works:
# on the machines this module is for, that line is noise before every one bench prints (an error included)
warnings.filterwarnings("ignore", message="Failed to find system libvulkan", category=UserWarning)
LAVAPIPE_HINT = "run scripts/fetch_lavapipe.sh and export the VK_ICD_FILENAMES it prints"

_state: dict[str, str | None] = {"mode": None}  # None (not decided yet) | "vulkan" | "stand-ins"


class InertRenderMaterial:
    """Holds the values a `sapien.render.RenderMaterial` would; draws nothing."""

    def __init__(
        self,
        emission: Iterable[float] = (0.0, 0.0, 0.0, 0.0),
        base_color: Iterable[float] = (1.0, 1.0, 1.0, 1.0),
        specular: float = 0.0,
        roughness: float = 1.0,
        metallic: float = 0.0,
        transmission: float = 0.0,
        ior: float = 1.45,
        transmission_roughness: float = 0.0,
    ):
        self.emission, self.base_color, self.specular = list(emission), list(base_color), specular
        self.roughness, self.metallic, self.transmission = roughness, metallic, transmission
        self.ior, self.transmission_roughness = ior, transmission_roughness
        self.base_color_texture = self.diffuse_texture = self.emission_texture = None
        self.metallic_texture = self.normal_texture = self.roughness_texture = self.transmission_texture = None


def _accessors(
    name: str,
) -> tuple[Callable[[InertRenderMaterial], object], Callable[[InertRenderMaterial, object], None]]:
    return (lambda self: getattr(self, name)), (lambda self, value: setattr(self, name, value))


for _name in (
    "emission",
    "base_color",
    "specular",
    "roughness",
    "metallic",
    "transmission",
    "ior",
    "transmission_roughness",
    "base_color_texture",
    "diffuse_texture",
    "emission_texture",
    "metallic_texture",
    "normal_texture",
    "roughness_texture",
    "transmission_texture",
):
    _get, _set = _accessors(_name)
    setattr(InertRenderMaterial, f"get_{_name}", _get)
    setattr(InertRenderMaterial, f"set_{_name}", _set)


class InertRenderTexture2D:
    """Remembers the file or array a `sapien.render.RenderTexture2D` would upload; uploads nothing."""

    def __init__(self, *args: object, **kwargs: object):
        self.filename = kwargs.get("filename", args[0] if args and isinstance(args[0], str) else None)


_Builder = TypeVar("_Builder")  # sapien.wrapper.actor_builder.ActorBuilder


def _record_nothing(self: _Builder, *args: object, **kwargs: object) -> _Builder:
    return self  # SAPIEN's add_*_visual return the builder


def installed_versions() -> dict[str, str | None]:
    """Installed versions of the packages in `CHECKED` (None when absent)."""
    out: dict[str, str | None] = {}
    for pkg in CHECKED:
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = None
    return out


def render_device_available() -> bool:
    """Whether SAPIEN finds a Vulkan device (creating one material is the cheapest thing that asks)."""
    import sapien.render  # the maniskill extra: loaded only for ManiSkill suites

    if _state["mode"] == "stand-ins":
        return False
    try:
        sapien.render.RenderMaterial()
    except RuntimeError:
        return False
    return True


def install() -> None:
    """Install the stand-ins (idempotent). Raises ConfigError for versions they were not checked against."""
    if _state["mode"] == "stand-ins":
        return
    found = installed_versions()
    if found != CHECKED:
        got = ", ".join(f"{k} {v or 'absent'}" for k, v in found.items())
        want = ", ".join(f"{k}=={v}" for k, v in CHECKED.items())
        raise ConfigError(
            f"ManiSkill without a Vulkan device: the inert SAPIEN materials were checked against {want}, "
            f"found {got}; install those versions (pip install -e '.[maniskill]') or {LAVAPIPE_HINT}"
        )
    import sapien.render  # the maniskill extra: loaded only for ManiSkill suites
    from sapien.wrapper.actor_builder import ActorBuilder  # the maniskill extra: loaded only for ManiSkill suites

    import_module("mani_skill.envs")  # mani_skill's own import order; its loaders import the classes by name
    sapien.render.RenderMaterial = InertRenderMaterial
    sapien.render.RenderTexture2D = InertRenderTexture2D
    for name in _IMPORTERS:
        module = import_module(name)
        for attr, stand_in in (("RenderMaterial", InertRenderMaterial), ("RenderTexture2D", InertRenderTexture2D)):
            if hasattr(module, attr):
                setattr(module, attr, stand_in)
    for adder in _VISUAL_ADDERS:
        setattr(ActorBuilder, adder, _record_nothing)
    _state["mode"] = "stand-ins"


def check_cameras() -> None:
    """ConfigError (what is missing and how to get it) unless ManiSkill can render cameras in this process.

    Called when a run with camera observations is planned, so a machine without a Vulkan device refuses
    the run in one line before any episode, instead of failing every one of them.
    """
    mode = _state["mode"]
    if mode is None:
        mode = _state["mode"] = "vulkan" if render_device_available() else None
    if mode != "vulkan":
        why = (
            "the inert SAPIEN materials are installed in this process"
            if mode == "stand-ins"
            else "SAPIEN finds no Vulkan device"
        )
        raise ConfigError(
            f"obs=rgb: ManiSkill cameras need a Vulkan device and {why}; {LAVAPIPE_HINT}, or use obs=state"
        )


def prepare(cameras: bool) -> str:
    """Make ManiSkill scenes buildable in this process; return "vulkan" or "stand-ins".

    With a Vulkan device nothing is changed. Without one, camera observations are impossible
    (ConfigError naming the fix, `check_cameras`) and state-only envs get the inert stand-ins.
    """
    if cameras:
        check_cameras()
    mode = _state["mode"]
    if mode is None:
        mode = _state["mode"] = "vulkan" if render_device_available() else None
    if mode is None:
        install()
        mode = "stand-ins"
    return mode

"""Visual perturbation axes: what the cameras see changes, the physics does not.

Every axis acts on the rendered scene of a `bench.sims.camera.CameraRig`, relative to the nominal
scene, with draws from the episode's own generator; nothing in the physics model changes
(textures are the one model field edited: `tex_data`, which only the renderer reads, restored
and re-uploaded before the next episode). Levels follow the physics axes' grammar
(`perturb.light=[0.3,0.6]`, `perturb.light=uniform(0.5,1.5)`, dict forms with targets).

    light         scale of every light's ambient, diffuse and specular intensity (1 = nominal)
    light_dir     degrees: every light (not the headlight) tilted about a horizontal axis through the
                  scene centre, at an azimuth drawn per episode
    camera_pos    metres: every (or the named) camera moved this far in a direction drawn per episode
    camera_rot    degrees: every (or the named) camera rotated this much about an axis drawn per episode
    object_color  0..1: the manipulated object's colour blended this far toward a colour drawn per episode
    table_color   0..1: the same for the table (geoms or bodies named like "table", or the named ones)
    background    0..1: the same for the floor and walls (world-body geoms that are not the table)
    texture       1..4: the table's texture replaced by a procedural one never in any training set
                  (1 checker, 2 stripes, 3 smooth noise, 4 rings), colours drawn per episode
    distractors   count: objects (boxes, spheres, cylinders, capsules of random size and colour) placed
                  on the table top away from the manipulated object; visual only (no collisions)

This module is the catalogue (`AXIS_TABLE`, kind "visual", which `bench.sims.perturb.axes` includes) and
the checks of a model against it (`check`: targets, textures, a surface for distractors); it
renders nothing. `bench.sims.perturb.scene` applies the axes: its `VisualScene` holds one episode's
perturbation of one rig and is the rig's render hook, and `bench.sims.perturb.reset`, which owns the grammar
and the per-episode flow, calls its `clear`, `apply` and `validate`. Visual axes need the env's
camera rig (`env.mujoco.cameras`, suites built on `bench.sims.camera_env`) and a policy that sees
images (`obs=rgb` or `obs=state+rgb`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from bench.core.errors import ConfigError, did_you_mean

TEXTURES = ("checker", "stripes", "noise", "rings")
_GEOMS = ("geoms", "bodies")
_CAMERA: dict[str, Any] = dict(targets=("cameras",), nominal=0.0)  # offsets of every (or the named) camera
_BLEND: dict[str, Any] = dict(unit="blend 0..1", maximum=1.0, targets=_GEOMS, nominal=0.0)  # colour blends
# Keyword arguments of `bench.sims.perturb.axes.Axis` (kind "visual"); `nominal` is the level that changes nothing.
AXIS_TABLE: tuple[dict[str, Any], ...] = (
    dict(
        name="light",
        unit="scale of nominal",
        short="light intensity",
        doc="ambient, diffuse and specular intensity of every light, headlight included",
        nominal=1.0,
    ),
    dict(
        name="light_dir",
        unit="degrees",
        short="light direction tilt",
        maximum=90.0,
        nominal=0.0,
        doc="every light tilted about a horizontal axis through the scene centre (azimuth drawn per episode)",
    ),
    dict(
        name="camera_pos",
        unit="metres",
        short="camera position offset",
        maximum=1.0,
        doc="every (or the named) camera moved this far in a direction drawn per episode",
        **_CAMERA,
    ),
    dict(
        name="camera_rot",
        unit="degrees",
        short="camera orientation offset",
        maximum=90.0,
        doc="every (or the named) camera rotated this much about an axis drawn per episode",
        **_CAMERA,
    ),
    dict(
        name="object_color",
        short="object colour",
        doc="the manipulated object's colour blended toward a colour drawn per episode",
        **_BLEND,
    ),
    dict(
        name="table_color",
        short="table colour",
        doc="the table's colour (geoms/bodies named like 'table') blended toward a colour drawn per episode",
        **_BLEND,
    ),
    dict(
        name="background",
        short="floor and wall colour",
        doc="floor and walls (world-body geoms other than the table) blended toward a drawn colour",
        **_BLEND,
    ),
    dict(
        name="texture",
        unit=f"texture 1..{len(TEXTURES)} ({', '.join(TEXTURES)})",
        short="unseen table texture",
        minimum=1.0,
        maximum=float(len(TEXTURES)),
        integer=True,
        targets=_GEOMS,
        nominal=0.0,
        doc="the table's texture replaced by a procedural one in colours drawn per episode",
    ),
    dict(
        name="distractors",
        unit="objects",
        short="distractor objects on the table",
        maximum=20.0,
        integer=True,
        nominal=0.0,
        doc="boxes, spheres, cylinders and capsules of random size and colour on the table (visual only)",
    ),
)
AXES = tuple(a["name"] for a in AXIS_TABLE)


def model_names(model: Any, kind: str, count: int) -> list[str]:
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    obj = getattr(mujoco.mjtObj, f"mjOBJ_{kind.upper()}")
    return [mujoco.mj_id2name(model, obj, i) or "" for i in range(count)]


def _named(model: Any, named: dict[str, list[str]], field: str, where: str) -> list[int] | None:
    """Geom ids named by `.geoms=[...]` / `.bodies=[...]` targets, or None when none are named."""
    if not named:
        return None
    ids: set[int] = set()
    for key, kind, count in (("geoms", "geom", model.ngeom), ("bodies", "body", model.nbody)):
        valid = model_names(model, kind, count)
        for n in named.get(key, []):
            if n not in valid:
                shown = [v for v in valid if v]
                raise ConfigError(
                    f"{field}.{key}: {n!r} is not a {kind} of {where}; valid: "
                    f"{', '.join(shown[:15])}{' ...' if len(shown) > 15 else ''}.{did_you_mean(n, shown)}"
                )
            i = valid.index(n)
            ids |= {i} if kind == "geom" else {g for g in range(model.ngeom) if model.geom_bodyid[g] == i}
    return sorted(ids)


def target_geoms(
    model: Any, axis: str, object_bodies: Sequence[str], named: dict[str, list[str]], where: str = "the env"
) -> list[int]:
    """Geom ids an appearance axis recolours or retextures (ConfigError when there are none)."""
    field = f"perturb.{axis}"
    ids = _named(model, named, field, where)
    if ids is not None:
        return ids
    bodies = model_names(model, "body", model.nbody)
    geoms = model_names(model, "geom", model.ngeom)
    if axis == "object_color":
        wanted = {bodies.index(b) for b in object_bodies if b in bodies}
        ids = [g for g in range(model.ngeom) if model.geom_bodyid[g] in wanted]
        if not ids:
            raise ConfigError(f"{field}: {where} declares no manipulated object; name it with {field}.bodies=[...]")
        return ids
    table = [
        g for g in range(model.ngeom) if "table" in geoms[g].lower() or "table" in bodies[model.geom_bodyid[g]].lower()
    ]
    if axis in ("table_color", "texture"):
        if not table:
            raise ConfigError(
                f"{field}: found no table in {where} (no geom or body named like 'table'); "
                f"name its geoms with {field}.geoms=[...]"
            )
        return table
    ids = [g for g in range(model.ngeom) if model.geom_bodyid[g] == 0 and g not in set(table)]
    if not ids:
        raise ConfigError(
            f"{field}: {where} has no floor or wall geoms (world-body geoms); name them with {field}.geoms=[...]"
        )
    return ids


def textures_of(model: Any, geoms: Sequence[int], field: str, where: str) -> list[int]:
    """The 2-D or cube RGB textures the geoms' materials use (ConfigError when the geoms have none)."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    out: set[int] = set()
    for g in geoms:
        mat = int(model.geom_matid[g])
        if mat < 0:
            continue
        for role in (mujoco.mjtTextureRole.mjTEXROLE_RGB, mujoco.mjtTextureRole.mjTEXROLE_RGBA):
            t = int(model.mat_texid[mat, int(role)])
            kinds = (int(mujoco.mjtTexture.mjTEXTURE_2D), int(mujoco.mjtTexture.mjTEXTURE_CUBE))
            if t >= 0 and int(model.tex_type[t]) in kinds:  # not the skybox
                out.add(t)
    if not out:
        raise ConfigError(
            f"{field}: the targeted geoms of {where} have no texture to replace (a material with "
            f"a 2-D or cube texture); use table_color, or target textured geoms with {field}.geoms=[...]"
        )
    return sorted(out)


def check(
    model: Any,
    object_bodies: Sequence[str],
    axis: str,
    named: dict[str, list[str]],
    cameras: Sequence[str],
    where: str = "the env",
) -> None:
    """Raise ConfigError if `axis` (with its named targets) cannot be applied to this model and rig."""
    field = f"perturb.{axis}"
    if axis in ("camera_pos", "camera_rot"):
        for c in named.get("cameras", []):
            if c not in cameras:
                raise ConfigError(
                    f"{field}.cameras: {c!r} is not a rendered camera of {where}; valid: "
                    f"{', '.join(cameras)}.{did_you_mean(c, cameras)}"
                )
    elif axis in ("object_color", "table_color", "background"):
        target_geoms(model, axis, object_bodies, named, where)
    elif axis == "texture":
        textures_of(model, target_geoms(model, axis, object_bodies, named, where), field, where)
    elif axis == "distractors":
        surface(model, None, object_bodies, where)


def surface(model: Any, data: Any, object_bodies: Sequence[str], where: str) -> tuple[np.ndarray, np.ndarray, float]:
    """Where distractors stand: (xy low, xy high, z) of the table top, else of a floor plane near the scene centre."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    xpos = data.geom_xpos if data is not None else model.geom_pos
    xmat = data.geom_xmat if data is not None else None
    geoms, bodies = model_names(model, "geom", model.ngeom), model_names(model, "body", model.nbody)
    best = None
    for g in range(model.ngeom):
        if int(model.geom_type[g]) != int(mujoco.mjtGeom.mjGEOM_BOX):
            continue
        if "table" not in geoms[g].lower() and "table" not in bodies[model.geom_bodyid[g]].lower():
            continue
        rot = np.abs(xmat[g].reshape(3, 3)) if xmat is not None else np.eye(3)
        half = rot @ model.geom_size[g]
        top = float(xpos[g][2] + half[2])
        if best is None or top > best[2]:
            best = (xpos[g][:2] - half[:2] + 0.05, xpos[g][:2] + half[:2] - 0.05, top)
    if best is not None:
        return best
    for g in range(model.ngeom):
        if int(model.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_PLANE):
            c, r = np.asarray(model.stat.center[:2]), 0.5 * float(model.stat.extent)
            return c - r, c + r, float(xpos[g][2])
    raise ConfigError(
        f"perturb.distractors: {where} has no table (box geom named like 'table') or floor plane to "
        f"place distractors on"
    )

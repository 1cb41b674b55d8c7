"""What the visual axes act on in a MuJoCo model: the geoms they recolour, the textures they replace,
the surface distractors stand on, the cameras they move; each a check that raises ConfigError naming
the axis when a model has none. `pattern` draws the procedural textures that replace a table's, `place_distractors` the distractors.

The visual axes themselves (one row each: what a level means and how it is painted into the rendered
scene) are `bench.sims.perturb.scene`'s; this module renders nothing.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from bench.core.errors import ConfigError, did_you_mean
from bench.sims.perturb.model import named_geoms
from bench.sims.perturb.model import names as model_names

if TYPE_CHECKING:
    import mujoco

TEXTURES = ("checker", "stripes", "noise", "rings")


def _named(model: mujoco.MjModel, named: Mapping[str, Sequence[str]], field: str, where: str) -> list[int] | None:
    """Geom ids named by `.geoms=[...]` / `.bodies=[...]` targets, or None when none are named."""
    return named_geoms(model, named, field, where) if named else None


def target_geoms(
    model: mujoco.MjModel,
    axis: str,
    object_bodies: Sequence[str],
    named: Mapping[str, Sequence[str]],
    where: str = "the env",
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


def textures_of(model: mujoco.MjModel, geoms: Sequence[int], field: str, where: str) -> list[int]:
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


def check_cameras(
    axis: str, named: Mapping[str, Sequence[str]], cameras: Sequence[str], where: str = "the env"
) -> None:
    """ConfigError unless every camera named by `.cameras=[...]` is one the rig renders."""
    for c in named.get("cameras", []):
        if c not in cameras:
            raise ConfigError(
                f"perturb.{axis}.cameras: {c!r} is not a rendered camera of {where}; valid: "
                f"{', '.join(cameras)}.{did_you_mean(c, cameras)}"
            )


def surface(
    model: mujoco.MjModel, data: mujoco.MjData | None, object_bodies: Sequence[str], where: str
) -> tuple[np.ndarray, np.ndarray, float]:
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


def pattern(kind: int, height: int, width: int, rng: np.random.Generator) -> np.ndarray:
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


def rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    """Rotation matrix about a unit axis (Rodrigues)."""
    k = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    a = math.radians(degrees)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(a) * kx + (1 - math.cos(a)) * kx @ kx


def place_distractors(
    model: mujoco.MjModel, data: mujoco.MjData, object_bodies: Sequence[str], n: int, seed: int, where: str
) -> list[tuple]:
    """`n` distractors (geom type, size, position, rotation, rgba) on the table or floor, away from the objects,
    placed from `seed` (at an episode's first render: the object has its initial position then)."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    rng = np.random.default_rng(seed)
    lo, hi, z = surface(model, data, object_bodies, where)
    bodies = model_names(model, "body", model.nbody)
    avoid = [np.asarray(data.xpos[bodies.index(b)][:2]) for b in object_bodies if b in bodies]
    kinds = (
        mujoco.mjtGeom.mjGEOM_BOX,
        mujoco.mjtGeom.mjGEOM_SPHERE,
        mujoco.mjtGeom.mjGEOM_CYLINDER,
        mujoco.mjtGeom.mjGEOM_CAPSULE,
    )
    out: list[tuple] = []
    for _ in range(n):
        kind = kinds[int(rng.integers(len(kinds)))]
        r, h = float(rng.uniform(0.012, 0.03)), float(rng.uniform(0.012, 0.035))
        for _attempt in range(50):
            xy = rng.uniform(lo, hi)
            if all(np.linalg.norm(xy - a) > 0.07 for a in avoid + [np.asarray(o[2][:2]) for o in out]):
                break
        size = np.array([r, r, h]) if kind == mujoco.mjtGeom.mjGEOM_BOX else np.array([r, h, 0.0])
        lift = r if kind == mujoco.mjtGeom.mjGEOM_SPHERE else h + (r if kind == mujoco.mjtGeom.mjGEOM_CAPSULE else 0.0)
        yaw = float(rng.uniform(0, 2 * math.pi))
        mat = rotation(np.array([0.0, 0.0, 1.0]), math.degrees(yaw)).reshape(-1)
        rgba = np.append(rng.uniform(0.05, 0.95, size=3), 1.0).astype(np.float32)
        out.append((kind, size, np.array([xy[0], xy[1], z + lift]), mat, rgba))
    return out

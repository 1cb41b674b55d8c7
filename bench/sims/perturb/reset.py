"""Perturbed simulators: conditions applied to an env at each episode reset.

Contract used by `bench.execution.rollout`: `apply(env, condition, rng) -> (stepper, params)`
restores the env's nominal values, applies the condition with draws from `rng`
(the episode's own generator) and returns the object to reset/step (the env, or
a wrapper for interface axes) plus the sampled values to record. It is called
before the env's reset, so the initial state is the one the episode seed gives.

Model axes edit the `mujoco.MjModel` of the env's `mujoco` capability, so one
implementation serves every MuJoCo backend (robosuite, Meta-World, Gymnasium MuJoCo, raw
MJCF); other backends apply them through their `model_axes` capability (PhysX). Their
levels are scales of the nominal values, which are cached once per env the first
time `apply` sees it and restored before every episode: a reused env never
drifts. Interface axes wrap the env (`bench.sims.perturb.interface.Interface`): action latency, action noise,
observation noise and a slower control rate (action hold). Visual axes (kind "visual":
light, camera pose, colours, textures, background, distractors) change only what the
env's cameras render; `bench.sims.perturb.scene` applies them, called from here (the catalogue
and its checks are `bench.sims.perturb.visual`'s).
The axes and the `perturb.*` grammar that makes conditions are `bench.sims.perturb.axes`'.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from typing import Any

import numpy as np

from bench.core.errors import ConfigError, did_you_mean
from bench.protocols import Cell, EnvAdapter, MujocoHandle, Suite
from bench.protocols.suite import Condition
from bench.sims.perturb import scene
from bench.sims.perturb.axes import AXES, FROM_FIELDS, INTERFACE_AXES, MODEL_AXES, VISUAL_AXES, axis_named
from bench.sims.perturb.interface import Interface


# -- names in the model --------------------------------------------------------------------
def _names(model, objtype: str, count: int) -> list[str]:
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    kind = getattr(mujoco.mjtObj, f"mjOBJ_{objtype.upper()}")
    return [mujoco.mj_id2name(model, kind, i) or "" for i in range(count)]


def _moving_bodies(model) -> list[int]:
    return [b for b in range(1, model.nbody) if model.body_weldid[b] != 0]


def _object_body_ids(mj: MujocoHandle, model) -> list[int]:
    names = list(mj.object_bodies)
    all_names = _names(model, "body", model.nbody)
    return [all_names.index(n) for n in names if n in all_names]


def _robot_body_ids(mj: MujocoHandle, model) -> list[int]:
    objects = set(_object_body_ids(mj, model))
    return [b for b in _moving_bodies(model) if b not in objects and model.body_mass[b] > 0]


def _resolve(names: Sequence[str], valid: list[str], what: str, field: str, where: str) -> list[int]:
    out = []
    for n in names:
        if n not in valid:
            shown = [v for v in valid if v]
            listing = ", ".join(shown[:15]) + (f", ... ({len(shown)} in all)" if len(shown) > 15 else "")
            article = "an" if what[0] in "aeiou" else "a"
            raise ConfigError(
                f"{field}: {n!r} is not {article} {what} of {where}; valid: {listing}.{did_you_mean(n, shown)}"
            )
        out.append(valid.index(n))
    return out


def targets(mj: MujocoHandle, condition: Condition, where: str = "the env") -> np.ndarray:
    """Indices (geoms, bodies, dofs or actuators) a model-axis condition edits in the MuJoCo model.

    Raises ConfigError when a named target does not exist or the default target set is empty.
    """
    model, axis = mj.model, condition.axis
    named = (condition.spec or {}).get("targets") or {}
    field = f"perturb.{axis}"
    if axis == "friction":
        if not named:
            return np.arange(model.ngeom)
        ids: list[int] = []
        if "geoms" in named:
            ids += _resolve(named["geoms"], _names(model, "geom", model.ngeom), "geom", f"{field}.geoms", where)
        if "bodies" in named:
            bodies = set(
                _resolve(named["bodies"], _names(model, "body", model.nbody), "body", f"{field}.bodies", where)
            )
            ids += [g for g in range(model.ngeom) if model.geom_bodyid[g] in bodies]
        return np.array(sorted(set(ids)), dtype=int)
    if axis in ("mass", "link_mass"):
        if "bodies" in named:
            ids = _resolve(named["bodies"], _names(model, "body", model.nbody), "body", f"{field}.bodies", where)
        elif axis == "mass":
            ids = _object_body_ids(mj, model)
            if not ids:
                raise ConfigError(
                    f"{field}: {where} declares no manipulated object (object bodies); "
                    f"name the bodies with {field}.bodies=[...]"
                )
        else:
            ids = _robot_body_ids(mj, model)
        return np.array(ids, dtype=int)
    if axis in ("damping", "armature", "frictionloss"):
        if "joints" in named:
            jids = _resolve(named["joints"], _names(model, "joint", model.njnt), "joint", f"{field}.joints", where)
        else:
            robot = set(_robot_body_ids(mj, model))
            jids = [j for j in range(model.njnt) if model.jnt_bodyid[j] in robot]
        dofs = [d for d in range(model.nv) if model.dof_jntid[d] in set(jids)]
        return np.array(dofs, dtype=int)
    if axis == "gain":
        if "actuators" in named:
            return np.array(
                _resolve(
                    named["actuators"], _names(model, "actuator", model.nu), "actuator", f"{field}.actuators", where
                ),
                dtype=int,
            )
        return np.arange(model.nu)
    return np.arange(0)


def _check_from(mj: MujocoHandle, cond: Condition, where: str) -> None:
    """Every element a calibration's draws name exists in the env's model (else one line naming it)."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    kinds = {"body_": mujoco.mjtObj.mjOBJ_BODY, "actuator_": mujoco.mjtObj.mjOBJ_ACTUATOR}
    for key in (cond.spec or {}).get("keys", []):
        field, element = key.split(":")[:2]
        obj = next((v for p, v in kinds.items() if field.startswith(p)), mujoco.mjtObj.mjOBJ_JOINT)
        if mujoco.mj_name2id(mj.model, obj, element) < 0:
            raise ConfigError(
                f"perturb.{cond.axis}: from({(cond.spec or {}).get('source')}) draws {field} of {element!r}, "
                f"which {where} does not have (a calibration of another robot?)"
            )


def validate(env: EnvAdapter, conditions: Sequence[Condition], where: str = "the env") -> None:
    """Check `conditions` against a built env: a model for model axes, names that exist, and
    targets whose nominal value is not zero (a scale of zero changes nothing).

    Raises ConfigError (exit 2) with the field, the bad value and what is valid.
    """
    for cond in conditions:
        if cond.axis in VISUAL_AXES:
            scene.validate(env, cond.axis, (cond.spec or {}).get("targets") or {}, where)
            continue
        if cond.axis not in MODEL_AXES:
            continue
        mj = env.mujoco
        if mj is None:
            other = env.model_axes
            if other is not None and cond.axis in other.axes:
                # the backend checks the named targets (and refuses zero-valued ones) by applying once
                level = cond.level[0] if isinstance(cond.level, (list, tuple)) else cond.level
                try:
                    other.apply(
                        str(cond.axis),
                        float(level if level is not None else 1.0),
                        (cond.spec or {}).get("targets") or {},
                    )
                finally:
                    other.restore()
                continue
            can = sorted(other.axes) if other is not None else []
            raise ConfigError(
                f"perturb.{cond.axis}: {where} ({env.backend}) cannot apply it; model axes there: "
                f"{', '.join(can) or 'none'}; interface axes work everywhere: {', '.join(INTERFACE_AXES)}"
            )
        if (cond.spec or {}).get("kind") == "from":
            _check_from(mj, cond, where)
            continue
        idx = targets(mj, cond, where)
        nominal = nominal_of(mj)
        values = nominal.gravity if cond.axis == "gravity" else getattr(nominal, str(AXES[cond.axis].field))[idx]
        if cond.axis == "gain":
            values = values[:, 0]
        if values.size == 0 or not np.any(values != 0):
            raise ConfigError(
                f"perturb.{cond.axis}: the nominal {cond.axis} of every targeted element of {where} is 0 "
                f"({values.size} targeted), so scaling it changes nothing; target others or drop the axis"
            )


def validate_run(suite: Suite, cells: Sequence[Cell], conditions: Sequence[Condition], horizon: int) -> None:
    """Check model-axis conditions against real envs before a run writes anything.

    Builds (then closes) the first cell's env, or every cell's when names are targeted
    (names differ between robots). Nothing is built when only interface axes are used.
    An env that cannot be built here is left to the workers, which record the error.
    """
    model_conds = [c for c in conditions if c.axis in MODEL_AXES or c.axis in VISUAL_AXES]
    if not model_conds or not cells:
        return
    named = any((c.spec or {}).get("targets") for c in model_conds)
    for cell in cells if named else cells[:1]:
        try:
            env = suite.make_env(cell, horizon)
        except Exception:
            continue
        try:
            validate(env, model_conds, where=cell.key)
        finally:
            try:
                env.close()
            except Exception:
                pass


# -- nominal cache and model edits ---------------------------------------------------------
class _Nominal:
    """Copies of every model field a model axis edits, taken from an unperturbed model."""

    FIELDS = (
        "geom_friction",
        "pair_friction",
        "body_mass",
        "body_inertia",
        "body_ipos",
        "body_iquat",
        "dof_damping",
        "dof_armature",
        "dof_frictionloss",
        "actuator_gainprm",
        "actuator_biasprm",
    )
    # one copy per name in FIELDS, set in __init__
    geom_friction: np.ndarray
    pair_friction: np.ndarray
    body_mass: np.ndarray
    body_inertia: np.ndarray
    body_ipos: np.ndarray
    body_iquat: np.ndarray
    dof_damping: np.ndarray
    dof_armature: np.ndarray
    dof_frictionloss: np.ndarray
    actuator_gainprm: np.ndarray
    actuator_biasprm: np.ndarray

    def __init__(self, model):
        self.model = model
        for f in self.FIELDS:
            setattr(self, f, np.array(getattr(model, f), copy=True))
        self.gravity = np.array(model.opt.gravity, copy=True)
        self.const_dirty = False  # derived constants computed from perturbed masses/armature

    def restore(self) -> None:
        m = self.model
        for f in self.FIELDS:
            getattr(m, f)[...] = getattr(self, f)
        m.opt.gravity[:] = self.gravity


_CACHE: weakref.WeakKeyDictionary[MujocoHandle, _Nominal] = weakref.WeakKeyDictionary()


def nominal_of(mj: MujocoHandle) -> _Nominal:
    """The model's nominal values, cached the first time they are asked for (and again if the
    handle's model object was replaced, e.g. by a hard reset that rebuilt it from XML)."""
    entry = _CACHE.get(mj)
    if entry is None or entry.model is not mj.model:
        entry = _CACHE[mj] = _Nominal(mj.model)
    return entry


def _set_const(mj: MujocoHandle) -> None:
    """Recompute derived constants (body/dof inverse weights, subtree masses, ...) after mass or
    armature edits, keeping the current state (mj_setConst overwrites it with qpos0)."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    m, d = mj.model, mj.data
    qpos, qvel, act = d.qpos.copy(), d.qvel.copy(), d.act.copy()
    mujoco.mj_setConst(m, d)
    d.qpos[:], d.qvel[:], d.act[:] = qpos, qvel, act


def write_fields(mj: MujocoHandle, edits: Sequence[dict[str, Any]]) -> None:
    """Set model values by name ({field, element, value[, column]}: dof_* by joint, body_*, actuator_*;
    a 2-D field's column 0 unless `column` says), e.g. a suite calibration's (`bench.calibrate.apply`).
    Call before the first episode, so the nominal values `apply` restores are these."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    m = mj.model
    objs = {
        "dof_": mujoco.mjtObj.mjOBJ_JOINT,
        "jnt_": mujoco.mjtObj.mjOBJ_JOINT,
        "body_": mujoco.mjtObj.mjOBJ_BODY,
        "actuator_": mujoco.mjtObj.mjOBJ_ACTUATOR,
    }
    setconst = False
    for e in edits:
        prefix = next(p for p in objs if e["field"].startswith(p))
        idx = mujoco.mj_name2id(m, objs[prefix], e["element"])
        if idx < 0:
            raise ConfigError(f"model edit of {e['field']}: {e['element']!r} is not in the model")
        row = int(m.jnt_dofadr[idx]) if prefix == "dof_" else idx
        arr = getattr(m, e["field"])
        if arr.ndim == 2:
            arr[row, int(e.get("column", 0))] = e["value"]
        else:
            arr[row] = e["value"]
        if e["field"] in ("body_ipos", "body_iquat"):  # MuJoCo skips these for bodies marked "same frame"
            m.body_sameframe[row] = int(mujoco.mjtSameFrame.mjSAMEFRAME_NONE)
        setconst |= e["field"] in ("body_mass", "body_inertia", "body_ipos", "body_iquat", "dof_armature")
    if setconst:
        _set_const(mj)
    mj.forward()


def _scale_model(mj: MujocoHandle, nom: _Nominal, axis: str, idx: np.ndarray, s: float) -> None:
    m = mj.model
    if axis == "friction":
        m.geom_friction[idx] = nom.geom_friction[idx] * s
        if m.npair and len(idx) == m.ngeom:  # explicit contact pairs override geom friction
            m.pair_friction[:] = nom.pair_friction * s
    elif axis in ("mass", "link_mass"):
        m.body_mass[idx] = nom.body_mass[idx] * s
        m.body_inertia[idx] = nom.body_inertia[idx] * s  # same shape, scaled density
    elif axis == "damping":
        m.dof_damping[idx] = nom.dof_damping[idx] * s
    elif axis == "armature":
        m.dof_armature[idx] = nom.dof_armature[idx] * s
    elif axis == "frictionloss":
        m.dof_frictionloss[idx] = nom.dof_frictionloss[idx] * s
    elif axis == "gain":
        g0 = nom.actuator_gainprm[idx, 0]
        m.actuator_gainprm[idx, 0] = g0 * s
        for k in (1, 2):  # position servo: biasprm[1] = -kp; velocity servo: biasprm[2] = -kv
            mirror = np.isclose(nom.actuator_biasprm[idx, k], -g0) & (g0 != 0)
            m.actuator_biasprm[idx[mirror], k] = nom.actuator_biasprm[idx[mirror], k] * s
    elif axis == "gravity":
        m.opt.gravity[:] = nom.gravity * s


def _from_draw(mj: MujocoHandle, nom: _Nominal, axis: str, condition: Condition, rng: np.random.Generator) -> dict:
    """One bootstrap draw of a calibration written into the model; the record gets the draw and the
    mean ratio of the drawn values to the nominal ones of the axis' first field."""
    spec = condition.spec or {}
    k = int(rng.integers(len(spec["values"])))
    edits = []
    ratios = []
    for key, value in zip(spec["keys"], spec["values"][k]):
        field, element, *col = key.split(":")
        edits.append({"field": field, "element": element, "value": value, **({"column": int(col[0])} if col else {})})
        if field == FROM_FIELDS[axis][0]:
            current = _value(mj, field, element, int(col[0]) if col else 0)
            if current:
                ratios.append(value / current)
    write_fields(mj, edits)
    nom.const_dirty = True
    return {axis: round(float(np.mean(ratios)), 9) if ratios else 1.0, f"{axis}.draw": k}


def _value(mj: MujocoHandle, field: str, element: str, column: int) -> float:
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    m = mj.model
    obj = (
        mujoco.mjtObj.mjOBJ_BODY
        if field.startswith("body_")
        else (mujoco.mjtObj.mjOBJ_ACTUATOR if field.startswith("actuator_") else mujoco.mjtObj.mjOBJ_JOINT)
    )
    idx = mujoco.mj_name2id(m, obj, element)
    row = int(m.jnt_dofadr[idx]) if field.startswith("dof_") else idx
    arr = getattr(m, field)
    return float(arr[row, column] if arr.ndim == 2 else arr[row])


def set_nominal(mj: MujocoHandle, levels: dict[str, float], where: str = "the env") -> None:
    """Edit a freshly built model as the model axes would at `levels` ({axis: scale of the current value}),
    once, before its first episode: the edited values are then the env's nominal ones, which `apply`
    restores and perturbations scale. A suite's held-out scenes are built this way from the same axes
    (e.g. {"mass": 3.0}: the object three times heavier in every episode of the cell).

    Raises ConfigError for an axis that is not a model axis (or a level out of its range), and
    RuntimeError when episodes already ran on the handle (their nominal values are cached).
    """
    if mj in _CACHE:
        raise RuntimeError(f"set_nominal on {where}: call it when the env is built, before its first episode")
    for name, level in levels.items():
        axis = axis_named(name)
        if axis.kind != "model":
            raise ConfigError(
                f"scene of {where}: {name!r} is a {axis.kind} axis; a scene scales model axes: {', '.join(MODEL_AXES)}"
            )
        condition = Condition(name=f"{name}={level:g}", axis=name, level=float(level))
        _scale_model(mj, _Nominal(mj.model), name, targets(mj, condition, where), float(level))
        if axis.setconst:
            _set_const(mj)
    mj.forward()


def _draw(condition: Condition, rng: np.random.Generator) -> float:
    kind = (condition.spec or {}).get("kind", "grid")
    if kind == "grid":
        return condition.level
    lo, hi = condition.level
    assert condition.axis is not None, "only a perturbation condition draws a value"
    axis = AXES[condition.axis]
    if axis.integer:
        return int(rng.integers(int(lo), int(hi) + 1))
    if kind == "loguniform":
        return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    return float(rng.uniform(lo, hi))


def apply(env: EnvAdapter, condition: Condition, rng: np.random.Generator) -> tuple[Any, dict[str, Any]]:
    """Apply `condition` to `env` for one episode; call before the env's reset.

    Restores the nominal model first (the env may have run another condition), draws
    the episode's value from `rng` for a range, and returns `(stepper, params)`:
    the env itself for model axes and nominal, an `Interface` wrapper for interface
    axes; `params` = {axis: value applied} for the episode record.
    """
    mj = env.mujoco
    nom = nominal_of(mj) if mj is not None else None
    if nom is not None:
        nom.restore()
    if env.model_axes is not None:
        env.model_axes.restore()
    scene.clear(env)
    axis = axis_named(condition.axis) if condition.axis is not None else None
    if axis is not None and axis.kind == "visual":
        if mj is not None and nom is not None and nom.const_dirty:
            _set_const(mj)
            nom.const_dirty = False
            mj.forward()
        value = _draw(condition, rng)
        return env, scene.apply(env, axis.name, value, (condition.spec or {}).get("targets") or {}, rng)
    if axis is None or axis.kind == "interface":
        if mj is not None and nom is not None and nom.const_dirty:
            _set_const(mj)
            nom.const_dirty = False
            mj.forward()
        if axis is None:
            return env, {}
        value = _draw(condition, rng)
        kw: dict[str, Any] = {"latency": 0, "action_noise": 0.0, "obs_noise": 0.0, "action_hold": 1}
        kw[axis.name] = value
        return Interface(env, rng, **kw), {axis.name: value}
    if (condition.spec or {}).get("kind") == "from":
        if mj is None or nom is None:
            raise ConfigError(f"perturb.{axis.name}: from(...) edits a MuJoCo model; env {env.backend} has none")
        return env, _from_draw(mj, nom, axis.name, condition, rng)
    value = _draw(condition, rng)
    if mj is None or nom is None:
        if env.model_axes is None or axis.name not in env.model_axes.axes:
            raise ConfigError(f"perturb.{axis.name}: env {env.backend} cannot apply this model axis")
        env.model_axes.apply(axis.name, float(value), (condition.spec or {}).get("targets") or {})
        return env, {axis.name: value}
    idx = targets(mj, condition)
    _scale_model(mj, nom, axis.name, idx, float(value))
    if axis.setconst or nom.const_dirty:
        _set_const(mj)
    nom.const_dirty = axis.setconst
    mj.forward()
    return env, {axis.name: value}

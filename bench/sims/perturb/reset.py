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
drifts. Interface and frame axes wrap the env (a row's `wrap`: action latency, action noise,
observation noise, a slower control rate; noise on camera images). Visual axes (kind "visual":
light, camera pose and field of view, colours, textures, background, distractors) change only
what the env's cameras render; `bench.sims.perturb.scene` applies them, called from here.
This module dispatches on the hooks a row carries (`bench.sims.perturb.axis`), never on an axis' name;
the axes and the `perturb.*` grammar that makes conditions are `bench.sims.perturb.axes`'.
"""

from __future__ import annotations

import weakref
from collections.abc import Iterator, Mapping, Sequence
from typing import TYPE_CHECKING, TypedDict

import numpy as np

from bench.core.errors import ConfigError
from bench.protocols import RGB, Cell, EnvAdapter, MujocoHandle, Suite, WritesDraws
from bench.protocols.suite import Condition, condition_rng
from bench.sims.perturb.axes import AXES, INTERFACE_AXES, MODEL_AXES, axis_named
from bench.sims.perturb.axis import RGB_IMAGES, Params
from bench.sims.perturb.combine import Combination
from bench.sims.perturb.scene import apply as paint_scene
from bench.sims.perturb.scene import clear as clear_scene
from bench.sims.perturb.scene import validate as validate_scene

if TYPE_CHECKING:
    import mujoco


def targets(mj: MujocoHandle, condition: Condition, where: str = "the env") -> np.ndarray:
    """Indices (geoms, bodies, dofs or actuators) a model-axis condition edits in the MuJoCo model.

    Raises ConfigError when a named target does not exist or the default target set is empty.
    """
    axis = AXES.get(condition.axis or "")
    if axis is None or axis.select is None:
        return np.arange(0)
    named = condition.targets
    return axis.select(mj, named, f"perturb.{axis.name}", where)


def _check_from(mj: MujocoHandle, cond: Condition, where: str) -> None:
    """Every element a calibration's draws name exists in the env's model (else one line naming it)."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    kinds = {"body_": mujoco.mjtObj.mjOBJ_BODY, "actuator_": mujoco.mjtObj.mjOBJ_ACTUATOR}
    for key in cond.spec.get("keys", []):
        field, element = key.split(":")[:2]
        obj = next((v for p, v in kinds.items() if field.startswith(p)), mujoco.mjtObj.mjOBJ_JOINT)
        if mujoco.mj_name2id(mj.model, obj, element) < 0:
            raise ConfigError(
                f"perturb.{cond.axis}: from({cond.spec.get('source')}) draws {field} of {element!r}, "
                f"which {where} does not have (a calibration of another robot?)"
            )


def validate(env: EnvAdapter, conditions: Sequence[Condition], where: str = "the env") -> None:
    """Check `conditions` against a built env: a model for model axes, names that exist, and
    targets whose nominal value is not zero (a scale of zero changes nothing).

    Raises ConfigError (exit 2) with the field, the bad value and what is valid.
    """
    for cond in conditions:
        axis = AXES.get(cond.axis or "")
        if axis is not None and axis.paint is not None:
            validate_scene(env, axis.name, cond.targets, where)
            continue
        if axis is not None and axis.sees == RGB_IMAGES and not any(str(k).startswith(RGB) for k in env.obs_spec):
            raise ConfigError(
                f"perturb.{axis.name} changes only camera images, and {where} ({env.backend}) gives the policy "
                f"none (it observes {', '.join(map(str, env.obs_spec))}); use obs=rgb or obs=state+rgb where the "
                "suite takes it, or leave the image axes out"
            )
        if axis is not None and axis.check_start is not None:  # a pose axis, at its largest level
            levels = cond.level if isinstance(cond.level, (list, tuple)) else [cond.level]
            axis.check_start(env, max(float(v) for v in levels), cond.targets, where)
            continue
        if axis is None or axis.kind != "model":
            continue
        mj = env.mujoco
        if mj is None:
            other = env.model_axes
            # a backend that writes a calibration's draws (MJX worlds)
            if cond.kind == "from" and isinstance(other, WritesDraws) and cond.axis in other.axes:
                try:  # the backend checks the draw's names by writing one
                    other.write_draw(str(cond.axis), cond.spec["keys"], cond.spec["values"][0])
                finally:
                    other.restore()
                continue
            if other is not None and cond.axis in other.axes:
                # the backend checks the named targets (and refuses zero-valued ones) by applying once
                level = cond.level[0] if isinstance(cond.level, (list, tuple)) else cond.level
                try:
                    other.apply(
                        str(cond.axis),
                        float(level if level is not None else 1.0),
                        cond.targets,
                    )
                finally:
                    other.restore()
                continue
            can = sorted(other.axes) if other is not None else []
            raise ConfigError(
                f"perturb.{cond.axis}: {where} ({env.backend}) cannot apply it; model axes there: "
                f"{', '.join(can) or 'none'}; interface axes work everywhere: {', '.join(INTERFACE_AXES)}"
            )
        if cond.kind == "from":
            _check_from(mj, cond, where)
            continue
        idx = targets(mj, cond, where)
        values = nominal_of(mj)[axis.fields[0]][idx]
        if values.ndim == 2:  # of a per-element row (friction, gain), its first entry
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
    model_conds = [c for c in conditions if c.axis in AXES and AXES[c.axis].kind in ("model", "visual", "pose")]
    if not model_conds or not cells:
        return
    # every cell when names are targeted (they differ between robots), or a pose axis asked (so do joint ranges)
    named = any(c.targets or AXES[str(c.axis)].kind == "pose" for c in model_conds)
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
class _Named(TypedDict):
    field: str  # a model field: dof_* (by joint), jnt_*, body_*, actuator_*
    element: str  # the joint, body or actuator's name
    value: float


class ModelEdit(_Named, total=False):
    """One model value set by name (`write_fields`); `column` of a 2-D field (0 when absent)."""

    column: int


def _fields() -> tuple[str, ...]:
    """Every model field a model axis edits or a calibration's draws write (a dotted name: `opt.gravity`)."""
    out: dict[str, None] = {}
    for axis in AXES.values():
        out.update(dict.fromkeys(axis.fields + axis.from_fields))
    return tuple(out)


def _field(model: mujoco.MjModel, name: str) -> np.ndarray:
    obj = model
    for part in name.split("."):
        obj = getattr(obj, part)
    return obj


class Nominal(dict[str, np.ndarray]):
    """Copies of every model field an axis edits, taken from an unperturbed model: {field: values}."""

    def __init__(self, model: mujoco.MjModel):
        super().__init__({f: np.array(_field(model, f), copy=True) for f in _fields()})
        self.model = model
        self.const_dirty = False  # derived constants computed from perturbed masses/armature

    def __missing__(self, name: str) -> np.ndarray:
        # a field no row declared when this env was first seen (a row added since): still nominal, as
        # nothing edits a field before reading its nominal values here
        self[name] = values = np.array(_field(self.model, name), copy=True)
        return values

    def restore(self) -> None:
        for f, values in self.items():
            _field(self.model, f)[...] = values


_CACHE: weakref.WeakKeyDictionary[MujocoHandle, Nominal] = weakref.WeakKeyDictionary()


def nominal_of(mj: MujocoHandle) -> Nominal:
    """The model's nominal values, cached the first time they are asked for (and again if the
    handle's model object was replaced, e.g. by a hard reset that rebuilt it from XML)."""
    entry = _CACHE.get(mj)
    if entry is None or entry.model is not mj.model:
        entry = _CACHE[mj] = Nominal(mj.model)
    return entry


def _set_const(mj: MujocoHandle) -> None:
    """Recompute derived constants (body/dof inverse weights, subtree masses, ...) after mass or
    armature edits, keeping the current state (mj_setConst overwrites it with qpos0)."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    m, d = mj.model, mj.data
    qpos, qvel, act = d.qpos.copy(), d.qvel.copy(), d.act.copy()
    mujoco.mj_setConst(m, d)
    d.qpos[:], d.qvel[:], d.act[:] = qpos, qvel, act


def write_fields(mj: MujocoHandle, edits: Sequence[ModelEdit]) -> None:
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


def _scale_model(mj: MujocoHandle, nom: Nominal, axis: str, idx: np.ndarray, s: float) -> None:
    scale = AXES[axis].scale
    assert scale is not None, f"{axis} is a model axis with an edit"
    scale(mj.model, nom, idx, s)


def _from_draw(mj: MujocoHandle, nom: Nominal, axis: str, condition: Condition, rng: np.random.Generator) -> Params:
    """One bootstrap draw of a calibration written into the model; the record gets the draw and the
    mean ratio of the drawn values to the nominal ones of the axis' first field."""
    spec = condition.spec
    k = int(rng.integers(len(spec["values"])))
    edits: list[ModelEdit] = []
    ratios = []
    for key, value in zip(spec["keys"], spec["values"][k]):
        field, element, *col = key.split(":")
        edit: ModelEdit = {"field": field, "element": element, "value": value}
        if col:
            edit["column"] = int(col[0])
        edits.append(edit)
        if field == AXES[axis].from_fields[0]:
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
        _scale_model(mj, Nominal(mj.model), name, targets(mj, condition, where), float(level))
        if axis.setconst:
            _set_const(mj)
    mj.forward()


def _draw(condition: Condition, rng: np.random.Generator) -> float:
    kind = condition.kind
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


def apply(
    env: EnvAdapter, condition: Condition, rng: np.random.Generator, seed: int | None = None
) -> tuple[EnvAdapter, Params]:
    """Apply `condition` to `env` for one episode; call before the env's reset.

    Restores the nominal model first (the env may have run another condition), draws
    the episode's value from `rng` for a range, and returns `(stepper, params)`:
    the env itself for model and visual axes and nominal, the row's wrapper for interface
    and frame axes; `params` = {axis: value applied} for the episode record.

    A combined condition (`bench.sims.perturb.combine.Combination`) applies each of its parts as it is
    applied alone, in order, drawing from the part's own `condition_rng(seed, part)`: it needs the episode's
    `seed` (ValueError without it). Model scales compose (each part scales the
    values the parts before it left), wrappers nest (the first part innermost), visual edits accumulate.
    """
    mj = env.mujoco
    nom = nominal_of(mj) if mj is not None else None
    if nom is not None:
        nom.restore()
    if env.model_axes is not None:
        env.model_axes.restore()
    clear_scene(env)
    if isinstance(condition, Combination):
        if seed is None:
            raise ValueError(f"{condition.name}: a combined condition needs the episode seed (apply(..., seed=))")
        return _apply_parts(env, nom, condition, int(seed))
    axis = axis_named(condition.axis) if condition.axis is not None else None
    if axis is None or axis.scale is None:  # the model stays nominal this episode
        if mj is not None and nom is not None and nom.const_dirty:
            _set_const(mj)
            nom.const_dirty = False
            mj.forward()
        if axis is None:
            return env, {}
        value = _draw(condition, rng)
        named = condition.targets
        if axis.paint is not None:
            return env, paint_scene(env, axis.name, value, named, rng)
        if axis.start is not None:  # a pose axis: the env whose reset starts from an edited state
            stepper, extra = axis.start(env, rng, value, named)
            return stepper, {axis.name: value, **extra}
        assert axis.wrap is not None, f"axis {axis.name} has no hook (axis.py: select+scale, wrap or paint)"
        stepper, extra = axis.wrap(env, rng, value)
        return stepper, {axis.name: value, **extra}
    if condition.kind == "from":
        draws = env.model_axes  # a backend that writes a calibration's draws (MJX)
        if mj is None and isinstance(draws, WritesDraws) and axis.name in draws.axes:
            k = int(rng.integers(len(condition.spec["values"])))
            ratio = draws.write_draw(axis.name, condition.spec["keys"], condition.spec["values"][k])
            return env, {axis.name: round(float(ratio), 9), f"{axis.name}.draw": k}
        if mj is None or nom is None:
            raise ConfigError(f"perturb.{axis.name}: from(...) edits a MuJoCo model; env {env.backend} has none")
        return env, _from_draw(mj, nom, axis.name, condition, rng)
    value = _draw(condition, rng)
    if mj is None or nom is None:
        if env.model_axes is None or axis.name not in env.model_axes.axes:
            raise ConfigError(f"perturb.{axis.name}: env {env.backend} cannot apply this model axis")
        env.model_axes.apply(axis.name, float(value), condition.targets)
        return env, {axis.name: value}
    idx = targets(mj, condition)
    _scale_model(mj, nom, axis.name, idx, float(value))
    if axis.setconst or nom.const_dirty:
        _set_const(mj)
    nom.const_dirty = axis.setconst
    mj.forward()
    return env, {axis.name: value}


# -- combined conditions (`perturb.combine`) ------------------------------------------------
class _Current(Mapping[str, np.ndarray]):
    """A model's current values by field, read as a model axis' edit reads the nominal ones: a part of a
    combination scales what the parts before it left, so two scales of one field multiply."""

    def __init__(self, model: mujoco.MjModel):
        self.model = model

    def __getitem__(self, name: str) -> np.ndarray:
        return np.array(_field(self.model, name), copy=True)

    def __iter__(self) -> Iterator[str]:
        return iter(_fields())

    def __len__(self) -> int:
        return len(_fields())


def _apply_parts(env: EnvAdapter, nom: Nominal | None, combo: Combination, seed: int) -> tuple[EnvAdapter, Params]:
    """Apply every part of `combo` to the restored `env`, each with its own generator; (stepper, every part's params)."""
    mj = env.mujoco
    stepper: EnvAdapter = env
    params: Params = {}
    stale = False  # derived constants (mj_setConst) behind an edited mass or armature
    for part in combo.parts:
        rng = condition_rng(seed, part)
        axis = axis_named(str(part.axis))
        if part.kind == "from":
            if mj is None or nom is None:
                raise ConfigError(f"perturb.{axis.name}: from(...) edits a MuJoCo model; env {env.backend} has none")
            params.update(_from_draw(mj, nom, axis.name, part, rng))
            stale = True
            continue
        value = _draw(part, rng)
        if axis.paint is not None:
            params.update(paint_scene(env, axis.name, value, part.targets, rng))
        elif axis.scale is not None and mj is not None:
            axis.scale(mj.model, _Current(mj.model), targets(mj, part), float(value))
            stale |= axis.setconst
            params[axis.name] = value
        elif axis.start is not None:  # a pose axis: its wrapper edits the state the reset leaves
            stepper, extra = axis.start(stepper, rng, value, part.targets)
            params.update({axis.name: value, **extra})
        elif axis.kind == "model":
            if env.model_axes is None or axis.name not in env.model_axes.axes:
                raise ConfigError(f"perturb.{axis.name}: env {env.backend} cannot apply this model axis")
            env.model_axes.apply(axis.name, float(value), part.targets)
            params[axis.name] = value
        else:
            assert axis.wrap is not None, f"axis {axis.name} has no hook (axis.py: select+scale, wrap or paint)"
            stepper, extra = axis.wrap(stepper, rng, value)
            params.update({axis.name: value, **extra})
    if mj is not None and nom is not None:
        if stale or nom.const_dirty:
            _set_const(mj)
        nom.const_dirty = stale
        mj.forward()
    return stepper, params

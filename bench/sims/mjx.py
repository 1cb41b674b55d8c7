"""MJX, MuJoCo's JAX backend: many worlds of one MJCF model stepped at once, differentiably.

The same `mujoco.MjModel` the CPU paths use is put on JAX's default device (the CPU here and in CI,
a GPU where JAX finds one: nothing in this module names a device) and stepped with `mjx.step`,
`jax.vmap`-ed over worlds and `lax.scan`-ed over time. A world is one initial state, one command
sequence (actuator commands plus a generalised force per physics step) and, optionally, its own values
of some model fields (a perturbed mass, a fitted damping), so N perturbed worlds, N replayed
segments or N calibration horizons are one compiled call.

Derivatives: MJX's constraint solver is a `while_loop`, which JAX cannot differentiate in reverse
mode except with `opt.iterations = 1` (then it is one unrolled step). A model with no constraint rows
(no contact, joint limit or friction loss) is unchanged by that setting and gets reverse-mode
gradients; one with constraint rows keeps its solver and gets forward-mode derivatives (see
`Rollouts`).

Needs the `mjx` extra (`pip install -e ".[mjx]"`: mujoco-mjx at the pinned MuJoCo's version and JAX);
`require()` names it when it is missing. Compiled functions are cached on disk across processes in
`$BENCH_JAX_CACHE` (default `~/.cache/bench/jax`; `0` turns the cache off). `unsupported(model)` names the first geom pair, option or
element MJX cannot simulate, so a model is refused before any work.
"""

from __future__ import annotations

import copy
import os
import time
from collections.abc import Callable, Mapping
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, TypedDict, TypeVar

import numpy as np

from bench.core.errors import ConfigError, SpecError

if TYPE_CHECKING:
    import mujoco
    from jax import Array
    from mujoco.mjx import Data as MjxData

EXTRA = 'pip install -e ".[mjx]"'
ITERATIONS_FOR_GRADIENTS = 1  # reverse-mode differentiation of mjx.step needs the solver unrolled to one step
FRICTIONLOSS_FLOOR = 1e-9  # friction loss added to every dof that gets a row (N or N*m): rows exist, force ~ 0

_state: dict[str, ModuleType] = {}

# An array leaf of the trees below: numpy outside the compiled functions, a `jax.Array` (a tracer, while JAX
# traces) inside them. The same trees cross that line (`jnp.asarray` in, `np.asarray` out), so one name for both.
Leaf = Any
Batch = Mapping[str, Leaf]  # qpos0, qvel0, ctrl (B, T, nu + nv), [inputs (B, T, m)], target, weight, mask, channels
_T = TypeVar("_T")


class _Shared(TypedDict):
    model: Mapping[str, Leaf]  # mjx.Model field -> value
    qfrc: Leaf  # (nv,) constant generalised force


class Params(_Shared, total=False):
    """The parameters a calibration differentiates (`Rollouts.value_and_grad`), or tangents of the same structure."""

    input_gain: Leaf  # (m, nv) gain on the logged extra inputs


# jaxlib 0.7's XLA:CPU "fusion emitters" (on by default from 0.7) run MJX's many small fusions 100-300x
# slower than the emitters before them (google-deepmind/mujoco#2957, jax-ml/jax#33761); measured here on
# the Panda dynamics model, one world, float32: kinematics 9.1 ms -> 0.05 ms, an mjx.step inside a scan
# 13 ms -> 0.04 ms. GPU backends ignore xla_cpu_* flags.
CPU_FLAG = "--xla_cpu_use_fusion_emitters=false"
CPU_FLAG_JAXLIB = ((0, 7), (0, 8))  # jaxlib versions [from, to) that have the flag and the slow default
# One XLA host device per usable core: a compiled call runs on one device, and one device's call keeps one core
# busy (a 1,024-world MJX Lift step used 1.1 of 2 cores); batched paths split their worlds across the devices
# (`bench.sims.mjx_lift.control.Compiled.step`). A call on one device is as fast as before (measured).
DEVICES_FLAG = "--xla_force_host_platform_device_count"


def xla_cpu_flags() -> str | None:
    """Add `CPU_FLAG` to `XLA_FLAGS` for this process (before JAX creates its CPU backend) where the installed
    jaxlib needs it and `XLA_FLAGS` does not already choose, and `DEVICES_FLAG` (one host device per usable core)
    where `XLA_FLAGS` does not set it; returns the fusion flag added, or None."""
    flags = os.environ.get("XLA_FLAGS", "")
    if DEVICES_FLAG not in flags:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        if cores > 1:
            flags = f"{flags} {DEVICES_FLAG}={cores}".strip()
            os.environ["XLA_FLAGS"] = flags
    if "xla_cpu_use_fusion_emitters" in flags:
        return None  # the user chose
    try:
        jaxlib = tuple(int(p) for p in version("jaxlib").split(".")[:2])
    except (PackageNotFoundError, ValueError):
        return None
    if not CPU_FLAG_JAXLIB[0] <= jaxlib < CPU_FLAG_JAXLIB[1]:
        return None  # an unknown flag in XLA_FLAGS aborts the process: only versions known to have it
    os.environ["XLA_FLAGS"] = f"{flags} {CPU_FLAG}".strip()
    return CPU_FLAG


def require(x64: bool | None = None) -> tuple[ModuleType, ModuleType, ModuleType]:
    """(jax, jax.numpy, mujoco.mjx), imported once; a one-line ConfigError naming the extra when missing.

    `x64`: run in float64 (the default the first time: calibration and the CPU comparisons need it);
    False for float32, which is what a GPU runs fast. It is JAX's process-wide setting.
    """
    if "jax" not in _state:
        xla_cpu_flags()  # read by JAX when it creates its CPU backend (first use), so before anything runs
        try:
            import jax  # JAX: an optional extra, loaded only when backend=mjx or method=gradient is asked for
            import jax.numpy as jnp  # JAX: an optional extra, loaded only when MJX is used
            from mujoco import mjx  # mujoco-mjx: an optional extra, loaded only when MJX is used
        except ImportError as e:
            raise ConfigError(
                f"the MJX backend needs JAX and mujoco-mjx, which are not installed ({e.name or e}); "
                f"install the extra: {EXTRA}"
            ) from None
        _state.update(jax=jax, jnp=jnp, mjx=mjx)
        if x64 is None:
            x64 = True
        cache = os.environ.get("BENCH_JAX_CACHE", str(Path.home() / ".cache" / "bench" / "jax"))
        if cache and cache != "0":  # compiled rollouts kept across processes (first compiles take 10-100 s on a CPU)
            jax.config.update("jax_compilation_cache_dir", cache)
            jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
    if x64 is not None:
        _state["jax"].config.update("jax_enable_x64", bool(x64))
    return _state["jax"], _state["jnp"], _state["mjx"]


def device() -> str:
    """The device JAX runs on, in words (e.g. 'cpu', 'gpu: NVIDIA H100 80GB HBM3')."""
    jax, _, _ = require()
    d = jax.devices()[0]
    kind = getattr(d, "device_kind", "")
    return f"{d.platform}: {kind}" if kind and kind.lower() != d.platform else d.platform


# --- what MJX cannot simulate -------------------------------------------------------------------------------
def _name(model: mujoco.MjModel, obj: mujoco.mjtObj, i: int) -> str:
    import mujoco  # MuJoCo's native library: loaded only when a model is checked

    return mujoco.mj_id2name(model, obj, i) or f"#{i}"


def unsupported(model: mujoco.MjModel) -> str | None:
    """The first feature of `model` that MJX (the installed version) cannot simulate, named; None if none.

    Checks what `mjx.put_model` would refuse, naming the geoms and options involved: the integrator,
    cone, Jacobian, solver, enabled flags, fluid drag with implicitfast, colliding geom pairs without an
    MJX collision function, margins on meshes, and actuator / equality / sensor / tendon-wrap types.
    """
    import mujoco  # MuJoCo's native library: loaded only when a model is checked

    _, _, mjx = require()
    from mujoco.mjx._src import collision_driver, types  # mujoco-mjx: collision table + enums, loaded only with MJX

    o = model.opt
    for field, enum, supported in (
        ("integrator", mujoco.mjtIntegrator, types.IntegratorType),
        ("cone", mujoco.mjtCone, types.ConeType),
        ("jacobian", mujoco.mjtJacobian, types.JacobianType),
        ("solver", mujoco.mjtSolver, types.SolverType),
    ):
        value = int(getattr(o, field))
        if value not in {int(s) for s in supported}:
            valid = ", ".join(enum(int(s)).name.split("_", 1)[1].lower() for s in supported)
            return f"option {field}={enum(value).name.split('_', 1)[1].lower()} (MJX supports {valid})"
    for i in range(mujoco.mjtEnableBit.mjNENABLE):
        if o.enableflags & 2**i:
            return f"option flag {mujoco.mjtEnableBit(2**i).name.removeprefix('mjENBL_').lower()}=enable"
    fluid = o.density > 0 or o.viscosity > 0 or bool(np.any(o.wind))
    if fluid and o.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST:
        return "option density/viscosity/wind (fluid drag) with integrator=implicitfast"
    geom = mujoco.mjtObj.mjOBJ_GEOM
    for g1, g2, ip in collision_driver.geom_pairs(model):
        t1, t2 = (int(t) for t in model.geom_type[[g1, g2]])
        what = (
            f"geom {_name(model, geom, g1)!r} ({mujoco.mjtGeom(t1).name.removeprefix('mjGEOM_').lower()}) "
            f"against geom {_name(model, geom, g2)!r} ({mujoco.mjtGeom(t2).name.removeprefix('mjGEOM_').lower()})"
        )
        if not collision_driver.has_collision_fn(t1, t2):
            return f"{what}: MJX has no collision function for this pair (set contype/conaffinity to 0 to drop it)"
        no_margin = {int(mujoco.mjtGeom.mjGEOM_MESH), int(mujoco.mjtGeom.mjGEOM_HFIELD)}
        margin = model.pair_margin[ip] if ip != -1 else model.geom_margin[g1] + model.geom_margin[g2]
        if no_margin & {t1, t2} and np.any(margin):
            return f"{what}: a margin/gap on a mesh or height field"
    for objtype, field_name, enum_field, enum_type, mj_type in (
        (mujoco.mjtObj.mjOBJ_ACTUATOR, "dyntype", model.actuator_dyntype, types.DynType, mujoco.mjtDyn),
        (mujoco.mjtObj.mjOBJ_ACTUATOR, "gaintype", model.actuator_gaintype, types.GainType, mujoco.mjtGain),
        (mujoco.mjtObj.mjOBJ_ACTUATOR, "biastype", model.actuator_biastype, types.BiasType, mujoco.mjtBias),
        (mujoco.mjtObj.mjOBJ_ACTUATOR, "trntype", model.actuator_trntype, types.TrnType, mujoco.mjtTrn),
        (mujoco.mjtObj.mjOBJ_EQUALITY, "type", model.eq_type, types.EqType, mujoco.mjtEq),
        (mujoco.mjtObj.mjOBJ_SENSOR, "type", model.sensor_type, types.SensorType, mujoco.mjtSensor),
    ):
        ok = {int(t) for t in enum_type}
        for i, t in enumerate(enum_field):
            if int(t) not in ok:
                kind = objtype.name.removeprefix("mjOBJ_").lower()
                return f"{kind} {_name(model, objtype, i)!r} has {field_name} {mj_type(int(t)).name}, which MJX lacks"
    ok_wrap = {int(t) for t in types.WrapType}
    for i, t in enumerate(model.wrap_type):
        if int(t) not in ok_wrap:
            return f"tendon wrap #{i} of type {mujoco.mjtWrap(int(t)).name}, which MJX lacks"
    try:
        mjx.put_model(model)
    except NotImplementedError as e:  # anything this list missed: MJX's own words
        return str(e)
    return None


def check_model(model: mujoco.MjModel, field: str = "model", where: str = "the model") -> None:
    """Refuse, in one line before any work, a model MJX cannot simulate (SpecError naming the feature)."""
    problem = unsupported(model)
    if problem is not None:
        raise SpecError(
            f"spec field {field!r}: MJX cannot simulate {where}: {problem}; use the CPU backend (backend=mujoco, "
            "method=least_squares) for this model"
        )


# --- batched rollouts ---------------------------------------------------------------------------------------
class Rollouts:
    """Compiled batched rollouts (and their derivatives) of one model structure.

    `world` fields are `mjx.Model` field names whose values are inputs rather than constants: given
    per world (`simulate(..., per_world=True)`, leading axis = worlds) or shared by all worlds (the
    parameters a calibration differentiates). Commands: `ctrl` (B, T, nu + nv) per physics step, the
    actuator commands then the applied generalised force (the layout `bench.replay.simulate` uses);
    frames are read every `substeps` steps. Compiled functions are cached by JAX per shape.

    Derivatives: with no constraint rows (nefc = 0) the solver has nothing to do, `opt.iterations` is
    set to 1 (`ITERATIONS_FOR_GRADIENTS`; the dynamics are unchanged) and gradients come from one
    reverse-mode pass (`mode == "reverse"`, cost independent of the number of parameters). With
    constraint rows, one solver iteration is not the converged solution MuJoCo computes (measured on
    the 3-joint arm with friction loss 0.3: 0.037 rad apart after 20 frames), so the model keeps its
    solver and derivatives are forward-mode (`mode == "forward"`, one tangent per parameter, which
    passes the solver's `while_loop`). `frictionloss_rows` gives every dof a friction-loss row (MJX
    creates rows only where the friction loss is non-zero when the model is put on the device, and a
    row of exactly zero is not "no friction" in MJX 3.3): the friction loss simulated is the given one
    plus FRICTIONLOSS_FLOOR.
    """

    def __init__(self, model: mujoco.MjModel, substeps: int, *, frictionloss_rows: bool = False) -> None:
        check_model(model)
        jax, jnp, mjx = require()
        self.jax, self.jnp, self.mjx = jax, jnp, mjx
        m = copy.copy(model)
        self.floor = FRICTIONLOSS_FLOOR if frictionloss_rows else 0.0
        if frictionloss_rows:
            m.dof_frictionloss[:] += self.floor
        self.nefc = int(mjx.make_data(mjx.put_model(m)).efc_J.shape[0])
        self.mode = "reverse" if self.nefc == 0 else "forward"
        if self.mode == "reverse":
            m.opt.iterations = ITERATIONS_FOR_GRADIENTS
        self.model = m
        self.mx = mjx.put_model(m)
        self.nq, self.nv, self.nu = m.nq, m.nv, m.nu
        self.substeps = int(substeps)
        self.compile_s = 0.0  # seconds spent in the first call of each new shape (tracing + XLA compile)
        self._seen: set[tuple[object, ...]] = set()
        self._sim = jax.jit(self._batched, static_argnames=("per_world",))
        self._vg = jax.jit(jax.value_and_grad(self._loss))
        self._vd = jax.jit(self._loss_dirs)

    # the pure functions that get compiled
    def _one(self, world: Mapping[str, Array], qpos0: Array, qvel0: Array, ctrl: Array) -> Array:
        """One world: (T, nu + nv) commands -> (T // substeps, nq + nv) states after each frame."""
        jax, jnp, mjx = self.jax, self.jnp, self.mjx
        if self.floor and "dof_frictionloss" in world:
            world = {**world, "dof_frictionloss": world["dof_frictionloss"] + self.floor}
        m = self.mx.tree_replace(dict(world)) if world else self.mx
        d = mjx.make_data(m).replace(qpos=qpos0, qvel=qvel0)
        nu, s = self.nu, self.substeps

        def substep(d: MjxData, u: Array) -> tuple[MjxData, None]:
            d = d.replace(ctrl=u[:nu], qfrc_applied=u[nu:])
            return mjx.step(m, d), None

        @jax.checkpoint  # reverse mode keeps one state per frame, not one per physics step
        def frame(d: MjxData, u: Array) -> tuple[MjxData, Array]:
            d, _ = jax.lax.scan(substep, d, u)
            return d, jnp.concatenate([d.qpos, d.qvel])

        _, out = jax.lax.scan(frame, d, ctrl.reshape(ctrl.shape[0] // s, s, ctrl.shape[-1]))
        return out

    def _batched(self, world: Mapping[str, Array], qpos0: Array, qvel0: Array, ctrl: Array, per_world: bool) -> Array:
        axes = (0 if per_world else None, 0, 0, 0)
        return self.jax.vmap(self._one, in_axes=axes)(world, qpos0, qvel0, ctrl)

    def _window_losses(self, params: Params, batch: Batch) -> Array:
        """Per window: sum of squared weighted, masked residuals under shared `params`.

        params: {"model": {field: value}, "qfrc": (nv,), "input_gain": (m, nv) or absent};
        batch: qpos0, qvel0, ctrl (B, T, nu + nv), inputs (B, T, m) or absent, target (B, L, C),
        weight (C,), mask (B, L, C), channels (C,) indices into [qpos, qvel].
        """
        jnp = self.jnp
        ctrl = batch["ctrl"]
        push = jnp.broadcast_to(params["qfrc"], ctrl.shape[:-1] + (self.nv,))
        if "input_gain" in params:
            push = push + batch["inputs"] @ params["input_gain"]
        u = ctrl + jnp.concatenate([jnp.zeros(ctrl.shape[:-1] + (self.nu,)), push], axis=-1)
        sim = self._batched(params["model"], batch["qpos0"], batch["qvel0"], u, False)
        r = (sim[..., batch["channels"]] - batch["target"]) * batch["weight"]
        return jnp.sum(jnp.where(batch["mask"], r * r, 0.0), axis=(1, 2))

    def _loss(self, params: Params, batch: Batch) -> Array:
        return self.jnp.sum(self._window_losses(params, batch))

    def _loss_dirs(self, params: Params, tangents: Params, batch: Batch) -> tuple[Array, Array]:
        """Loss and its directional derivatives along each tangent (leading axis), in forward mode."""
        f = lambda th: self._loss(th, batch)  # noqa: E731
        value = f(params)
        dirs = self.jax.vmap(lambda t: self.jax.jvp(f, (params,), (t,))[1])(tangents)
        return value, dirs

    def _timed(self, key: tuple[object, ...], fn: Callable[[], _T]) -> _T:
        first = key not in self._seen
        t0 = time.perf_counter()
        out = self.jax.block_until_ready(fn())
        if first:
            self._seen.add(key)
            self.compile_s += time.perf_counter() - t0
        return out

    def _key(self, name: str, *trees: object) -> tuple[object, ...]:
        tu = self.jax.tree_util
        return (name, tu.tree_structure(trees), *(np.shape(v) for v in tu.tree_leaves(trees)))

    # the calls
    def simulate(
        self,
        qpos0: np.ndarray,
        qvel0: np.ndarray,
        ctrl: np.ndarray,
        world: Mapping[str, np.ndarray] | None = None,
        per_world: bool = True,
    ) -> np.ndarray:
        """States [qpos, qvel] after each frame of each world: (B, T // substeps, nq + nv)."""
        jnp = self.jnp
        w = {k: jnp.asarray(v) for k, v in (world or {}).items()}
        args = (jnp.asarray(qpos0), jnp.asarray(qvel0), jnp.asarray(ctrl))
        key = self._key(f"sim{per_world}", w, args)
        return np.asarray(self._timed(key, lambda: self._sim(w, *args, per_world=per_world)))

    def value_and_grad(self, params: Params, batch: Batch) -> tuple[float, Params]:
        """Loss and its gradient with respect to every array of `params` (same structure, numpy): reverse mode,
        for models without constraint rows (`mode == "reverse"`)."""
        if self.mode != "reverse":
            raise ValueError("reverse-mode gradients need a model without constraint rows; use value_and_dirs")
        jax, jnp = self.jax, self.jnp
        p = jax.tree_util.tree_map(jnp.asarray, dict(params))
        b = {k: jnp.asarray(v) for k, v in batch.items()}
        value, grad = self._timed(self._key("vg", p, b), lambda: self._vg(p, b))
        return float(value), jax.tree_util.tree_map(np.asarray, grad)

    def value_and_dirs(self, params: Params, tangents: Params, batch: Batch) -> tuple[float, np.ndarray]:
        """Loss and its derivatives along tangents (`params`' structure, each leaf with a leading axis of K):
        (value, (K,)). Reverse mode (one gradient, then K dot products) or forward mode (K tangents)."""
        jax, jnp = self.jax, self.jnp
        tu = jax.tree_util
        if self.mode == "reverse":
            value, g = self.value_and_grad(params, batch)
            gl, tl = tu.tree_leaves(g), tu.tree_leaves(tangents)
            dirs = sum(np.asarray(t).reshape(len(t), -1) @ np.ravel(x) for x, t in zip(gl, tl))
            return value, np.asarray(dirs, dtype=float)
        p = tu.tree_map(jnp.asarray, dict(params))
        t = tu.tree_map(jnp.asarray, dict(tangents))
        b = {k: jnp.asarray(v) for k, v in batch.items()}
        value, dirs = self._timed(self._key("vd", p, t, b), lambda: self._vd(p, t, b))
        return float(value), np.asarray(dirs, dtype=float)

    def window_losses(self, params: Params, batch: Batch) -> np.ndarray:
        """Each window's loss (B,), to find where a loss or gradient turned non-finite."""
        jax, jnp = self.jax, self.jnp
        p = jax.tree_util.tree_map(jnp.asarray, dict(params))
        b = {k: jnp.asarray(v) for k, v in batch.items()}
        fn = jax.jit(self._window_losses)
        return np.asarray(self._timed(self._key("wl", p, b), lambda: fn(p, b)))

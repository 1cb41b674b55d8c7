"""Gradient calibration: a fit's parameters by gradient descent through batched MJX rollouts.

`fit_gradient` is a drop-in for `bench.calibrate.fit.fit` (the Real2Sim loop takes either, see
`bench.calibrate.trace.calibrate(fitter=...)`, and `bench calibrate ... method=gradient` picks this
one). It minimises the same objective, the weighted squared error of simulated positions (and logged
velocities) on the same truncated horizons re-initialised from logged states: multiple shooting
windows, so the gradient of a long log stays well conditioned. What differs is how:

- every window of the objective runs in one compiled MJX call (`bench.sims.mjx.Rollouts`), on the
  CPU here and on a GPU unchanged, and the gradient of the whole loss comes from one reverse-mode
  pass through it (the cost does not grow with the number of parameters);
- the solver is L-BFGS-B on bound-normalised parameters (z in [0, 1]): quasi-Newton steps built from
  those gradients, with the bounds kept exactly.

Solver settings it needs: reverse-mode gradients pass MJX's constraint solver only at one iteration
(`opt.iterations = 1`), which changes nothing for a model without constraint rows (no contact, limit
or friction loss): such fits are reverse mode. A layout that can move a friction loss keeps the
model's solver and gets forward-mode derivatives, one tangent per parameter (`bench.sims.mjx.Rollouts`;
one iteration is not MuJoCo's converged friction). JAX runs in float64.

A parameter vector reaches MJX as model fields (`realise` on the CPU side, the same code the
least-squares path uses, so both fit the same model): the MjModel float fields it changes, a constant
generalised force and a gain on logged extra inputs. Their derivatives with respect to the
parameters are taken by a finite difference of `realise` (exact for the affine edits of the library:
damping, friction loss, armature, masses, gains, springs, biases). Effects that reach the simulation
otherwise (delay, dead band and saturation transform the command; Stribeck adds a state-dependent
force; backlash rebuilds the model; a suite's scene maps coordinates) are not differentiable here:
`NotDifferentiable` says which, and the loop fits that layout by least squares (noted in the fit's
warnings).

A gradient that turns non-finite stops the fit (`DataError`) naming the window and the parameter
and suggesting method=least_squares.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from bench.calibrate.fit import FitResult, Objective, fd_jacobian, fit, optimum
from bench.calibrate.model import Layout, Plant
from bench.core.errors import DataError
from bench.replay.simulate import Variant, hold
from bench.sims import mjx as mjx_backend
from bench.sims.mjx import Params

if TYPE_CHECKING:
    import mujoco

METHODS = ("least_squares", "gradient")
DIFF_STEP = 1e-6  # finite-difference step of `realise` (normalised units; its edits are affine or smooth)
MAX_ITER = 200  # L-BFGS-B iterations per fit at most
MIN_BATCH = 8  # windows are padded to a power of two (at least this), so few shapes are compiled
# model fields that the library's effects and the constants mj_setConst derives from masses edit: always
# inputs of the compiled rollout, so adding an effect to a layout does not compile a new one
STANDARD_FIELDS = (
    "dof_damping",
    "dof_frictionloss",
    "dof_armature",
    "jnt_stiffness",
    "body_mass",
    "body_inertia",
    "body_ipos",
    "body_subtreemass",
    "body_invweight0",
    "dof_invweight0",
    "actuator_gainprm",
    "actuator_biasprm",
)


def _scaled(vg: tuple[float, np.ndarray], scale: float) -> tuple[float, np.ndarray]:
    """Loss and gradient divided by the starting loss (L-BFGS-B's tolerances are absolute)."""
    return vg[0] * scale, vg[1] * scale


def _friction_rows(layout: Layout) -> bool:
    """Whether the layout's parameters can move a friction loss (then MJX needs a row on every dof)."""
    fields = {s.field for s in layout.plant.slots} | {f for c in layout.active for f in c.effect.fields}
    return "dof_frictionloss" in fields or bool(np.any(layout.plant.model.dof_frictionloss > 0))


class NotDifferentiable(Exception):
    """A layout whose parameters reach the simulation other than through model fields and forces."""


@dataclass
class Stats:
    """What the gradient fits of one calibration cost (for the report and the benchmark)."""

    fits: int = 0
    fallbacks: int = 0
    evaluations: int = 0
    wall_s: float = 0.0
    compile_s: float = 0.0
    window_steps: int = 0  # physics steps simulated for losses and gradients (windows x steps)

    def to_json(self) -> dict[str, object]:
        return {k: getattr(self, k) for k in ("fits", "fallbacks", "evaluations", "wall_s", "compile_s")} | {
            "window_steps": self.window_steps
        }


def _float_fields(model: mujoco.MjModel, names: tuple[str, ...]) -> list[str]:
    return [n for n in names if isinstance(getattr(model, n, None), np.ndarray)]


def _declared_fields(plant: Plant) -> set[str]:
    """Model fields the declared slots change (their own, and constants derived from them), found by
    realising a changed value of each slot."""
    x0 = plant.declared_nominal()
    v0 = plant.realise(x0, [])
    prefixes = ("dof_", "jnt_", "body_", "actuator_", "geom_", "tendon_")
    arrays = [
        n
        for n in dir(v0.model)
        if n.startswith(prefixes)
        and isinstance(getattr(v0.model, n), np.ndarray)
        and getattr(v0.model, n).dtype.kind == "f"
    ]
    out: set[str] = set()
    for i, slot in enumerate(plant.slots):
        lo, hi = slot.bounds
        xi = x0.copy()
        xi[i] += 0.01 * (hi - lo) if xi[i] + 0.01 * (hi - lo) <= hi else -0.01 * (hi - lo)
        vi = plant.realise(xi, [])
        out |= {n for n in arrays if not np.array_equal(getattr(vi.model, n), getattr(v0.model, n))}
    return out


class GradientFitter:
    """`fit`'s signature, by gradient through MJX; one per calibration (it keeps compiled rollouts)."""

    def __init__(self, log: Callable[[str], None] | None = None) -> None:
        self.stats = Stats()
        self.log = log or (lambda msg: None)
        self._rollouts: dict[tuple[int, bool], mjx_backend.Rollouts] = {}
        self._fields: dict[int, list[str]] = {}

    def __call__(
        self, obj: Objective, x0: np.ndarray, *, max_nfev: int = 40, tol: float = 1e-6, broyden: bool = False
    ) -> FitResult:
        try:
            return self.fit(obj, x0, tol=tol)
        except NotDifferentiable as e:
            self.stats.fallbacks += 1
            self.log(f"gradient: {e}; this fit runs by least squares")
            res = fit(obj, x0, max_nfev=max_nfev, tol=tol, broyden=broyden)
            res.warnings.append(f"fitted by least squares, not by gradient: {e}")
            return res

    # --- the parameter vector as MJX inputs ---------------------------------------------------------------
    def _check(self, layout: Layout, v: Variant, base: Variant) -> None:
        plant = layout.plant
        if plant.scene is not None:
            raise NotDifferentiable("a suite's scene (logged coordinates inside a larger model)")
        bad = [c.key for c in layout.active if c.effect.play_side]
        if bad or v.coords is not None:
            raise NotDifferentiable(f"{', '.join(bad) or 'a model with play'} rebuilds the model (backlash)")
        if v.force is not None:
            names = [c.key for c in layout.active if c.effect.name == "stribeck_friction"]
            raise NotDifferentiable(f"{', '.join(names) or 'an effect'} adds a state-dependent force (Stribeck)")
        if v.ctrl is not base.ctrl and not np.array_equal(v.ctrl, base.ctrl):
            ops = [c.key for c in layout.active if c.effect.kind == "actuator" and not c.effect.fields]
            raise NotDifferentiable(
                f"{', '.join(ops) or 'an effect'} transforms the command (delay, dead band, saturation)"
            )

    def _theta(self, v: Variant, fields: list[str], with_inputs: bool) -> Params:
        p: Params = {
            "model": {f: np.array(getattr(v.model, f), dtype=float) for f in fields},
            "qfrc": np.array(v.qfrc_const, dtype=float),
        }
        if with_inputs:
            gain = v.input_gain if v.input_gain is not None else np.zeros((self._n_inputs, v.model.nv))
            p["input_gain"] = np.array(gain, dtype=float)
        return p

    @staticmethod
    def _unflat(rows: np.ndarray, like: Params) -> Params:
        """Rows of flat vectors (K, size) as `like`'s structure with a leading axis of K (tangents)."""
        k, i = len(rows), 0

        def take(a: np.ndarray) -> np.ndarray:
            nonlocal i
            out = rows[:, i : i + a.size].reshape((k, *a.shape))
            i += a.size
            return out

        model = {f: take(like["model"][f]) for f in sorted(like["model"])}
        out: Params = {"model": model, "qfrc": take(like["qfrc"])}
        if "input_gain" in like:
            out["input_gain"] = take(like["input_gain"])
        return out

    @staticmethod
    def _flat(p: Params) -> np.ndarray:
        parts = [p["model"][f].ravel() for f in sorted(p["model"])] + [p["qfrc"].ravel()]
        if "input_gain" in p:
            parts.append(p["input_gain"].ravel())
        return np.concatenate(parts)

    def _realise(self, layout: Layout, x: np.ndarray, fields: list[str], base: Variant, inputs: bool) -> Params:
        v = layout.realise(x)
        self._check(layout, v, base)
        return self._theta(v, fields, inputs)

    # --- the fit ----------------------------------------------------------------------------------------
    def fit(self, obj: Objective, x0: np.ndarray, *, tol: float = 1e-6) -> FitResult:
        t0 = time.perf_counter()
        layout, segs = obj.layout, obj.segs
        plant = layout.plant
        lo, hi = layout.bounds
        span = hi - lo
        p = len(lo)
        x0 = np.clip(np.asarray(x0, float), lo, hi)
        base = plant.realise(plant.declared_nominal(), [])
        inputs = plant.rec.inputs is not None and any(c.effect.reads_input for c in layout.active)
        self._n_inputs = 0 if plant.rec.inputs is None else plant.rec.inputs.shape[1]
        rows = _friction_rows(layout)
        key = (id(plant), rows)
        if key not in self._rollouts:
            mjx_backend.check_model(plant.model, where=plant.spec.model.name)
            self._rollouts[key] = mjx_backend.Rollouts(plant.model, plant.substeps, frictionloss_rows=rows)
        if id(plant) not in self._fields:
            mx_fields = {f.name for f in type(self._rollouts[key].mx).fields()}
            names = set(_float_fields(plant.model, STANDARD_FIELDS)) | _declared_fields(plant)
            self._fields[id(plant)] = sorted(f for f in names if f in mx_fields)
        rollouts, fields = self._rollouts[key], self._fields[id(plant)]
        rec = plant.rec
        s = plant.substeps
        n, length = len(segs), segs.length
        size = max(MIN_BATCH, 1 << int(np.ceil(np.log2(max(n, 1)))))
        rows = np.concatenate([np.arange(n), np.zeros(size - n, dtype=np.int64)])
        start = segs.start[rows]
        idx = np.minimum(start[:, None] * s + np.arange(length * s)[None, :], len(base.ctrl) - 1)
        ctrl = np.zeros((size, length * s, plant.model.nu + plant.model.nv))
        ctrl[..., : plant.model.nu] = base.ctrl[idx]
        mask = np.array(obj.mask)[rows].copy()
        mask[n:] = False
        batch = {
            "qpos0": rec.qpos[start],
            "qvel0": rec.qvel[start],
            "ctrl": ctrl,
            "target": obj.target[rows],
            "weight": obj.weight,
            "mask": mask,
            "channels": np.asarray(obj.channels),
        }
        if inputs and rec.inputs is not None:
            batch["inputs"] = hold(rec.inputs, s)[idx]
        labels = layout.labels
        compile0 = rollouts.compile_s
        evals = [0]

        n_tan = max(4, 1 << int(np.ceil(np.log2(max(p, 1)))))  # tangents padded: few shapes to compile

        def value_grad(z: np.ndarray) -> tuple[float, np.ndarray]:
            x = lo + np.clip(z, 0.0, 1.0) * span
            th = self._realise(layout, x, fields, base, inputs)
            flat0 = self._flat(th)
            jac = np.zeros((n_tan, len(flat0)))
            for i in range(p):  # d theta / dz_i by a one-sided difference of `realise`, kept inside the bounds
                h = DIFF_STEP if z[i] + DIFF_STEP <= 1.0 else -DIFF_STEP
                xi = x.copy()
                xi[i] = lo[i] + (z[i] + h) * span[i]
                jac[i] = (self._flat(self._realise(layout, xi, fields, base, inputs)) - flat0) / h
            value, dirs = rollouts.value_and_dirs(th, self._unflat(jac, th), batch)
            evals[0] += 1
            gz = dirs[:p]
            if not (np.isfinite(value) and np.all(np.isfinite(gz))):
                self._non_finite(rollouts, th, self._unflat(jac, th), batch, x, gz, labels, obj, n)
            return value, gz

        from scipy.optimize import minimize  # scipy: loaded only when a gradient fit runs

        z0 = (x0 - lo) / np.where(span > 0, span, 1.0)
        f0, _ = value_grad(z0)
        scale = 1.0 / max(f0, 1e-300)
        if p:
            res = minimize(
                lambda z: _scaled(value_grad(z), scale),
                z0,
                jac=True,
                method="L-BFGS-B",
                bounds=[(0.0, 1.0)] * p,
                options={"maxiter": MAX_ITER, "ftol": min(tol, 1e-6) * 1e-3, "gtol": 1e-9, "maxcor": 20},
            )
            z, success = np.clip(res.x, 0.0, 1.0), bool(res.success)
        else:
            z, success = z0, True
        x = lo + z * span
        self.stats.fits += 1
        self.stats.evaluations += evals[0]
        self.stats.window_steps += evals[0] * n * length * s
        self.stats.compile_s += rollouts.compile_s - compile0
        self.stats.wall_s += time.perf_counter() - t0
        return self._result(obj, x, lo, hi, labels, evals[0], success)

    def _non_finite(self, rollouts, th, tangents, batch, x, gz, labels, obj: Objective, n: int) -> None:
        """Stop the fit: name the window and the parameter whose gradient is not finite."""
        bad = [i for i in range(len(gz)) if not np.isfinite(gz[i])]
        param = labels[bad[0]] if bad else (labels[0] if labels else "(none)")
        value = float(x[bad[0]]) if bad else float("nan")
        losses = rollouts.window_losses(th, batch)[:n]
        window = int(np.flatnonzero(~np.isfinite(losses))[0]) if not np.all(np.isfinite(losses)) else None
        if window is None:  # finite losses, a non-finite derivative: find its window one at a time
            for w in range(n):
                one = {k: (v[w : w + 1] if k not in ("weight", "channels") else v) for k, v in batch.items()}
                _, d = rollouts.value_and_dirs(th, tangents, one)
                if not np.all(np.isfinite(d[: len(gz)])):
                    window = w
                    break
        rec = obj.layout.plant.rec
        where = "no single window (only their sum)"
        if window is not None:
            start = int(obj.segs.start[window])
            ep = int(np.searchsorted(rec.offsets, start, side="right") - 1)
            first = start - int(rec.offsets[ep])
            where = f"window {window} (episode {ep}, frames {first}..{first + obj.segs.length})"
        raise DataError(
            f"method=gradient: the gradient turned non-finite in {where} for parameter {param} = {value:.6g}; "
            "the simulation diverges or the loss is not differentiable there: tighten that parameter's bounds, "
            "or use method=least_squares (finite differences on the CPU simulator)"
        )

    @staticmethod
    def _result(obj: Objective, x: np.ndarray, lo, hi, labels, nfev: int, success: bool) -> FitResult:
        """The optimum with intervals and warnings from the CPU objective, as the least-squares path reports them."""
        grid = obj.residual_grid(x[None])[0]
        return optimum(obj, x, grid, lambda r: fd_jacobian(obj, x, r, lo, hi), hi - lo, labels, nfev, success)

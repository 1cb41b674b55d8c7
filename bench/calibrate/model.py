"""The simulated plant: an `MjModel` plus the recipe that turns a parameter vector into a simulation variant.

A variant (`bench.replay.simulate.Variant`) is what one rollout needs; here it is built from a
parameter vector: a model copy with the declared parameters and model-field effects written in, the
command actually applied at every substep (after delay / deadband / saturation), the applied
generalised forces, and the Stribeck force (the only state-dependent part) as the variant's force hook.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import mujoco
import numpy as np

from bench.calibrate.effects import EFFECTS, Bounds, Effect, Scales, Target, deadband, saturate, stribeck_force
from bench.calibrate.play import Play, PlayModel, build, coordinates, set_play
from bench.calibrate.spec import CalibrationSpec, EffectRequest, ParamSpec
from bench.core.errors import SpecError, did_you_mean, valid_choices
from bench.replay.data import Recording
from bench.replay.simulate import Coordinates, Simulator, StateForce, Variant, hold, prepare_model

# field prefix -> (MuJoCo object type, words for messages, model count attribute)
_PREFIX = {
    "dof_": (mujoco.mjtObj.mjOBJ_JOINT, "joint", "nv"),
    "jnt_": (mujoco.mjtObj.mjOBJ_JOINT, "joint", "njnt"),
    "body_": (mujoco.mjtObj.mjOBJ_BODY, "body", "nbody"),
    "actuator_": (mujoco.mjtObj.mjOBJ_ACTUATOR, "actuator", "nu"),
    "geom_": (mujoco.mjtObj.mjOBJ_GEOM, "geom", "ngeom"),
    "tendon_": (mujoco.mjtObj.mjOBJ_TENDON, "tendon", "ntendon"),
}
# edits of these need mj_setConst, or MuJoCo keeps using the constants derived at compile time
_SETCONST_FIELDS = ("body_mass", "body_inertia", "body_ipos", "body_iquat", "dof_armature")
PLAY_WARMUP = 0.1  # seconds simulated before each segment to find the unlogged side of a play


def _names(model: mujoco.MjModel, obj: mujoco.mjtObj, count: int) -> list[str]:
    return [mujoco.mj_id2name(model, obj, i) or f"#{i}" for i in range(count)]


@dataclass(frozen=True)
class Slot:
    """One declared free value: `model.<field>[row, col]`, or with `scaled` a factor on the nominal
    value of each (row, nominal) it lists."""

    label: str
    field: str
    row: int
    col: int | None
    bounds: tuple[float, float]
    nominal: float
    init: float
    scaled: tuple[tuple[int, float], ...] = ()

    @property
    def rows(self) -> list[int]:
        return [r for r, _ in self.scaled] if self.scaled else [self.row]


def resolve_params(params: tuple[ParamSpec, ...], model: mujoco.MjModel, model_name: str) -> list[Slot]:
    """Resolve each declared parameter's field and element names in the model."""
    array_fields = sorted(
        n
        for n in dir(model)
        if any(n.startswith(p) for p in _PREFIX)
        and isinstance(getattr(model, n, None), np.ndarray)
        and np.issubdtype(getattr(model, n).dtype, np.floating)
    )  # ids, addresses, types: not physics
    slots = []
    for i, p in enumerate(params):
        where = f"params[{i}]"
        prefix = next((pre for pre in _PREFIX if p.field.startswith(pre)), None)
        if prefix is None or p.field not in array_fields:
            kind = getattr(getattr(model, p.field, None), "dtype", None)
            what = (
                f"an integer MjModel field ({kind}: ids, addresses or types), not a physical parameter"
                if kind is not None and not np.issubdtype(kind, np.floating)
                else "not an MjModel field of joints, dofs, bodies, actuators, geoms or tendons"
            )
            raise SpecError(
                f"spec field '{where}.field': {p.field!r} is {what}; calibration parameters are "
                f"floating-point model arrays.{did_you_mean(p.field, array_fields)}"
            )
        obj, word, count_attr = _PREFIX[prefix]
        arr = getattr(model, p.field)
        if arr.ndim == 2 and arr.shape[1] > 1 and p.column is None:
            raise SpecError(f"spec field '{where}.column' is required: {p.field} has {arr.shape[1]} columns")
        if p.column is not None and (arr.ndim == 1 or p.column >= arr.shape[1]):
            width = 1 if arr.ndim == 1 else arr.shape[1]
            raise SpecError(f"spec field '{where}.column': {p.column} is out of range for {p.field} (width {width})")
        col = p.column if arr.ndim == 2 else None
        valid = _names(
            model,
            obj,
            {
                "joint": model.njnt,
                "body": model.nbody,
                "actuator": model.nu,
                "geom": model.ngeom,
                "tendon": model.ntendon,
            }[word],
        )
        lo, hi = p.bounds
        scaled = []
        for name in p.elements:
            idx = mujoco.mj_name2id(model, obj, name)
            if idx < 0:
                raise SpecError(
                    f"spec field '{where}.elements': {name!r} is not a {word} of {model_name}; "
                    f"{valid_choices(name, valid)}"
                )
            row = int(model.jnt_dofadr[idx]) if prefix == "dof_" else idx
            nominal = float(arr[row] if col is None else arr[row, col])
            if p.scale:
                scaled.append((row, nominal))
                continue
            init = p.init if p.init is not None else min(max(nominal, lo), hi)
            if not lo <= init <= hi:
                raise SpecError(f"spec field '{where}.init': {init} is outside the bounds [{lo}, {hi}]")
            label = p.name if len(p.elements) == 1 and p.name != p.field else f"{p.name}[{name}]"
            slots.append(Slot(label, p.field, row, col, (lo, hi), nominal, float(init)))
        if p.scale:  # one factor, 1 = the model as given
            init = 1.0 if p.init is None else p.init
            if not lo <= init <= hi:
                raise SpecError(
                    f"spec field '{where}.init': {init} is outside the bounds [{lo}, {hi}] "
                    "(a scale: 1 is the model as given)"
                )
            slots.append(Slot(p.name, p.field, scaled[0][0], col, (lo, hi), 1.0, float(init), tuple(scaled)))
    return slots


@dataclass(frozen=True)
class Candidate:
    """An effect family attached to one target, with its bounds."""

    effect: Effect
    target: Target
    bounds: Bounds

    @property
    def key(self) -> str:
        return f"{self.effect.name}@{self.target.label}"

    def start(self) -> np.ndarray:
        return self.effect.start(self.bounds)


def _stribeck(fs: np.ndarray, vs: np.ndarray) -> StateForce:
    """The Stribeck excess of every dof as a force hook of the stepped rollout."""
    return lambda qpos, qvel, ctrl: stribeck_force(qvel, fs, vs)


class Edits:
    """What the effects of one parameter vector change (implements `effects.Builder`)."""

    def __init__(self, model: mujoco.MjModel, n_inputs: int, play: PlayModel | None = None) -> None:
        self.model = model
        self.play = play
        self.plays: list[tuple[Play, float]] = []
        self.qfrc = np.zeros(model.nv)
        self.input_gain = np.zeros((n_inputs, model.nv)) if n_inputs else None
        self.fs = np.zeros(model.nv)
        self.vs = np.ones(model.nv)
        self.ops: list[tuple[str, int, float]] = []
        self.setconst = False

    def add_qfrc(self, dof: int, value: float) -> None:
        self.qfrc[dof] += value

    def add_input(self, col: int, dof: int, gain: float) -> None:
        assert self.input_gain is not None, "input_channel needs logged inputs"
        self.input_gain[col, dof] += gain

    def add_stribeck(self, dof: int, fs: float, vs: float) -> None:
        self.fs[dof] += fs
        self.vs[dof] = vs

    def ctrl_op(self, kind: str, act: int, value: float) -> None:
        self.ops.append((kind, act, value))

    def mark_setconst(self) -> None:
        self.setconst = True

    def set_play(self, act: int, width: float, inertia: float) -> None:
        if width <= 0 or self.play is None:  # no play: the declared drive, exactly
            return
        p = self.play.play(act)
        set_play(self.model, p, width, inertia)
        self.plays.append((p, width))
        self.setconst = True

    def coordinates(self, nq: int, warmup: int) -> Coordinates | None:
        """Where the logged coordinates are in a model rebuilt with play (None: the model's own)."""
        return coordinates(self.model, self.plays, nq, warmup) if self.plays else None

    def finish_model(self) -> mujoco.MjModel:
        """The edited model, with derived constants recomputed where mass edits need it."""
        if self.setconst:
            mujoco.mj_setConst(self.model, mujoco.MjData(self.model))
        return self.model


@dataclass(frozen=True)
class Scene:
    """A model whose logged coordinates are some of its own: a suite's robot in its scene.

    The logged joints must be the model's leading dofs (robosuite puts the arm first); the rest of
    each segment's initial state (gripper, objects) comes from the full logged state (`coords.init`).
    """

    coords: Coordinates  # the logged coordinates in the model
    ctrl: np.ndarray  # (N * substeps, nu) logged command of every physics step
    substeps: int
    joints: tuple[int, ...]  # the calibrated joints: effects attach to them, their actuators and bodies


class Plant:
    """Nominal model, log-derived scales and the declared parameter slots for one calibration."""

    def __init__(
        self, spec: CalibrationSpec, model: mujoco.MjModel, rec: Recording, scene: Scene | None = None
    ) -> None:
        self.spec = spec
        self.rec = rec
        self.scene = scene
        if scene is None:
            self.model, self.substeps = prepare_model(model, rec.fps, spec.substeps)
        else:  # joints outside the logged ones may be free (objects): they start from the logged state
            self.model, self.substeps = copy.copy(model), scene.substeps
            self.model.opt.timestep = 1.0 / (rec.fps * self.substeps)
        self.slots = resolve_params(spec.params, self.model, spec.model.name)
        for slot, value in zip(self.slots, self.declared_nominal()):  # the nominal model, within bounds
            self._write(self.model, slot, value)
        mujoco.mj_setConst(self.model, mujoco.MjData(self.model))
        self.base_ctrl = hold(rec.ctrl, self.substeps) if scene is None else scene.ctrl
        self.joint_names = [
            self.model.joint(int(j)).name for j in (range(self.model.njnt) if scene is None else scene.joints)
        ]
        self.scales = self._scales()
        self._plays: dict[tuple[tuple[int, str], ...], PlayModel] = {}

    def play_model(self, plays: tuple[tuple[int, str], ...]) -> PlayModel:
        """The model rebuilt with play on these (actuator, measured side) pairs (built once each)."""
        if plays not in self._plays:
            self._plays[plays] = build(self.spec.model, plays, self.model)
        return self._plays[plays]

    def simulator(self, threads: int = 1) -> Simulator:
        """A batched simulator of this plant's variants over its recording."""
        return Simulator(self.model, self.rec, self.substeps, threads)

    # --- parameters ------------------------------------------------------------------------
    @staticmethod
    def _write(model: mujoco.MjModel, slot: Slot, value: float) -> None:
        arr = getattr(model, slot.field)
        for row, nominal in slot.scaled or ((slot.row, 1.0),):
            v = nominal * value if slot.scaled else value
            if slot.col is None:
                arr[row] = v
            else:
                arr[row, slot.col] = v

    def declared_nominal(self) -> np.ndarray:
        """Declared values of the model as given (clipped into the bounds)."""
        return np.array([min(max(s.nominal, s.bounds[0]), s.bounds[1]) for s in self.slots])

    def declared_init(self) -> np.ndarray:
        return np.array([s.init for s in self.slots])

    def realise(self, declared: np.ndarray, effects: list[tuple[Candidate, np.ndarray]]) -> Variant:
        """Model copy + applied signals for declared values and active effects with their parameters."""
        plays = tuple(
            sorted((c.target.index, str(c.effect.play_side)) for c, x in effects if c.effect.play_side and x[0] > 0)
        )
        pm = self.play_model(plays) if plays else None
        b = Edits(
            copy.copy(pm.model if pm else self.model), 0 if self.rec.inputs is None else self.rec.inputs.shape[1], pm
        )
        for slot, value in zip(self.slots, declared):
            self._write(b.model, slot, float(value))
            if slot.field in _SETCONST_FIELDS:
                b.setconst = True
        for cand, x in effects:
            cand.effect.apply(b, cand.target, np.asarray(x, dtype=float), self.scales)
        gain = b.input_gain if b.input_gain is not None and np.any(b.input_gain) else None
        coords = b.coordinates(self.model.nq, max(1, round(PLAY_WARMUP * self.rec.fps)))
        if self.scene is not None:
            if coords is not None:
                raise ValueError("backlash (a rebuilt model) is not supported in a suite's scene")
            coords = self.scene.coords
        return Variant(
            b.finish_model(),
            self.applied_ctrl(b.ops),
            b.qfrc,
            gain,
            _stribeck(b.fs, b.vs) if np.any(b.fs != 0) else None,
            coords,
        )

    # --- the applied command -----------------------------------------------------------------
    def applied_ctrl(self, ops: list[tuple[str, int, float]]) -> np.ndarray:
        """Logged command after the drive effects, in a fixed order: delay, dead band, saturation."""
        if not ops:
            return self.base_ctrl
        out = self.base_ctrl.copy()
        s = self.substeps
        for kind in ("delay", "deadband", "saturation"):
            for k, act, value in ops:
                if k != kind:
                    continue
                if kind == "delay":
                    out[:, act] = self._delayed(out[:, act], value * self.rec.fps * s)
                elif kind == "deadband":
                    out[:, act] = deadband(out[:, act], value)
                else:
                    out[:, act] = saturate(out[:, act], value)
        return out

    def _delayed(self, u: np.ndarray, shift: float) -> np.ndarray:
        """Shift a substep signal later by `shift` substeps (linear interpolation; held at episode start)."""
        if shift <= 0:
            return u
        out = np.empty_like(u)
        s = self.substeps
        for e in range(self.rec.n_episodes):
            a, b = self.rec.offsets[e] * s, self.rec.offsets[e + 1] * s
            x = np.arange(b - a) - shift
            i0 = np.floor(x).astype(np.int64)
            w = x - i0
            lo = np.clip(i0, 0, b - a - 1)
            hi = np.clip(i0 + 1, 0, b - a - 1)
            seg = u[a:b]
            out[a:b] = (1.0 - w) * seg[lo] + w * seg[hi]
        return out

    # --- scales and candidates -----------------------------------------------------------------
    def _scales(self) -> Scales:
        m, rec = self.model, self.rec
        train = rec.frames(rec.train)
        gain = np.array([m.actuator_gear[a, 0] * m.actuator_gainprm[a, 0] for a in range(m.nu)])
        force = np.zeros(m.nv)
        for a in range(m.nu):
            if m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT:
                dof = int(m.jnt_dofadr[m.actuator_trnid[a, 0]])
                force[dof] = max(force[dof], float(np.percentile(np.abs(rec.ctrl[train, a] * gain[a]), 95)))
        if np.any(force > 0):
            force[force <= 0] = force[force > 0].max()
        else:
            force[:] = 1.0
        d = mujoco.MjData(m)
        qadr = np.arange(m.nq) if self.scene is None else self.scene.coords.qpos_adr
        d.qpos[qadr] = rec.qpos[train].mean(axis=0)
        mujoco.mj_forward(m, d)
        mass_matrix = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, mass_matrix, d.qM)
        span = rec.qpos[train].max(axis=0) - rec.qpos[train].min(axis=0)
        return Scales(
            force=force,
            vel=np.maximum(rec.qvel[train].std(axis=0), 1e-6),
            half_range=np.maximum(0.5 * span, 1e-6),
            inertia=np.maximum(np.diag(mass_matrix).copy(), 1e-9),
            ctrl_gain=np.where(np.abs(gain) > 0, np.abs(gain), 1.0),
            ctrl_max=np.maximum(np.abs(rec.ctrl).max(axis=0), 1e-12),
            ctrl_sorted=tuple(np.sort(np.abs(rec.ctrl[:, a])) for a in range(m.nu)),
            input_max=np.abs(rec.inputs).max(axis=0) if rec.inputs is not None else np.zeros(0),
            mass=float(m.body_mass[1:].sum()),
            dt=1.0 / rec.fps,
            spring_ref=m.qpos_spring[m.jnt_qposadr[m.dof_jntid]].copy(),
        )

    def targets(self, kind: str) -> list[Target]:
        """Every place an effect of this kind can attach in the model."""
        m = self.model
        jname = _names(m, mujoco.mjtObj.mjOBJ_JOINT, m.njnt)
        scope = set(range(m.njnt)) if self.scene is None else set(self.scene.joints)
        if kind == "joint":
            return [Target("joint", jname[j], j, int(m.jnt_dofadr[j]), jname[j]) for j in range(m.njnt) if j in scope]
        if kind == "actuator":
            out = []
            for a, name in enumerate(_names(m, mujoco.mjtObj.mjOBJ_ACTUATOR, m.nu)):
                if m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT and int(m.actuator_trnid[a, 0]) in scope:
                    j = int(m.actuator_trnid[a, 0])
                    out.append(Target("actuator", name, a, int(m.jnt_dofadr[j]), jname[j]))
            return out
        if kind == "body":  # bodies that move (not welded to the world); in a scene, those of its joints
            names = _names(m, mujoco.mjtObj.mjOBJ_BODY, m.nbody)
            bodies = range(1, m.nbody) if self.scene is None else sorted({int(m.jnt_bodyid[j]) for j in scope})
            return [Target("body", names[b], b) for b in bodies if m.body_weldid[b] != 0]
        raise ValueError(kind)

    def candidates(self, requests: tuple[EffectRequest, ...] | None) -> tuple[list[Candidate], list[str]]:
        """All (effect, target) pairs to trace, and notes on families that cannot apply here."""
        reqs = requests if requests is not None else tuple(EffectRequest(n) for n in EFFECTS)
        declared = {(s.field, r) for s in self.slots for r in s.rows}
        out, notes = [], []
        for i, req in enumerate(reqs):
            eff = EFFECTS[req.name]
            targets = self.targets(eff.kind)
            if eff.reads_input:
                if self.rec.inputs is None:
                    notes.append(f"{eff.name}: no signals.inputs declared in the spec; skipped")
                    continue
                targets = [
                    Target("joint", t.name, t.index, t.dof, t.joint, c, self.rec.input_names[c])
                    for c in range(self.rec.inputs.shape[1])
                    for t in targets
                ]
            if req.targets is not None:
                valid = sorted({t.name for t in targets})
                for name in req.targets:
                    if name not in valid:
                        raise SpecError(
                            f"spec field 'effects[{i}].targets': {name!r} is not a {eff.kind} of "
                            f"{self.spec.model.name}; valid: {', '.join(valid)}."
                            f"{did_you_mean(name, valid)}"
                        )
                targets = [t for t in targets if t.name in req.targets]
            for t in targets:
                row = {"dof_": t.dof, "jnt_": t.index, "body_": t.index, "actuator_": t.index}
                if any((f, row[next(p for p in row if f.startswith(p))]) in declared for f in eff.fields):
                    notes.append(f"{eff.name}@{t.label}: already declared free; skipped")
                    continue
                bounds = list(req.bounds) if req.bounds else eff.bounds(self.scales, t)
                out.append(Candidate(eff, t, [(float(lo), float(hi)) for lo, hi in bounds]))
        return out, notes


@dataclass
class Layout:
    """A parameter vector: the declared slots, then each active effect's parameters."""

    plant: Plant
    active: list[Candidate] = field(default_factory=list)

    @property
    def labels(self) -> list[str]:
        return [s.label for s in self.plant.slots] + [f"{c.key}.{p}" for c in self.active for p in c.effect.params]

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        b = [s.bounds for s in self.plant.slots] + [bd for c in self.active for bd in c.bounds]
        arr = np.array(b, dtype=float).reshape(-1, 2)
        return arr[:, 0], arr[:, 1]

    @property
    def smooth(self) -> bool:
        """Whether the output moves smoothly and near-linearly with every parameter: no effect with shape
        parameters (Stribeck velocity) or with output jumps (contact events: a coarse difference step)."""
        return all(c.effect.fd_step is None and not c.effect.shape for c in self.active)

    def fd_steps(self, default: float) -> np.ndarray:
        """Finite-difference step of each parameter in normalised units: `default`, or the coarser one an
        effect whose output moves in jumps asks for (then for every parameter: the jumps move them all)."""
        coarse = [c.effect.fd_step for c in self.active if c.effect.fd_step is not None]
        return np.full(len(self.plant.slots) + sum(len(c.effect.params) for c in self.active), max([default, *coarse]))

    def split(self, x: np.ndarray) -> tuple[np.ndarray, list[tuple[Candidate, np.ndarray]]]:
        n = len(self.plant.slots)
        parts, i = [], n
        for c in self.active:
            k = len(c.effect.params)
            parts.append((c, x[i : i + k]))
            i += k
        return x[:n], parts

    def offset(self, cand: Candidate) -> int:
        """Index of a candidate's first parameter in the vector."""
        i = len(self.plant.slots)
        for c in self.active:
            if c is cand:
                return i
            i += len(c.effect.params)
        raise KeyError(cand.key)

    def realise(self, x: np.ndarray) -> Variant:
        declared, effects = self.split(np.asarray(x, dtype=float))
        return self.plant.realise(declared, effects)

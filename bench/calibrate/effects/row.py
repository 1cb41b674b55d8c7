"""One effect family as one row (`Effect`): its parameters, bounds, realisation, the families it extends, its
physical limits and the ground truth the synthetic-data generator plants; what it attaches to (`Target`), the
system's magnitudes that scale its bounds (`Scales`), what it may change while a model is realised (`Builder`),
and the signature steps taken when it is switched on from zero."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:
    import mujoco


@dataclass(frozen=True)
class Scales:
    """Typical magnitudes of the system, per dof / actuator, used to bound the effects."""

    force: np.ndarray  # (nv,) typical actuator force on each dof [N or N·m]
    vel: np.ndarray  # (nv,) velocity spread [m/s or rad/s]
    half_range: np.ndarray  # (nv,) half the position range
    inertia: np.ndarray  # (nv,) diagonal of the mass matrix at the logged mean pose
    ctrl_gain: np.ndarray  # (nu,) force per unit command (gear x gain)
    ctrl_max: np.ndarray  # (nu,) largest |command| in the logs
    ctrl_sorted: tuple[np.ndarray, ...]  # per actuator, |command| of every logged frame, sorted
    input_max: np.ndarray  # (m,) largest |extra input| in the logs
    mass: float  # total mass of the model [kg]
    dt: float  # log frame period [s]
    spring_ref: np.ndarray  # (nv,) the model's spring reference position of each dof (qpos_spring)


@dataclass(frozen=True)
class Target:
    """Where an effect attaches: a joint (its dof), an actuator (and the dof it drives) or a body."""

    kind: str  # "joint" | "actuator" | "body"
    name: str
    index: int  # joint / actuator / body id
    dof: int = -1  # dof driven (joints and actuators)
    joint: str = ""  # name of that dof's joint
    input: int = -1  # extra-input column (input_channel)
    input_name: str = ""

    @property
    def label(self) -> str:
        return f"{self.name}<-{self.input_name}" if self.input >= 0 else self.name


class Builder(Protocol):
    """What an effect may change while a parameter vector is realised (see `bench.calibrate.model`)."""

    model: mujoco.MjModel  # being edited

    def add_qfrc(self, dof: int, value: float) -> None: ...
    def add_input(self, col: int, dof: int, gain: float) -> None: ...
    def add_stribeck(self, dof: int, fs: float, vs: float) -> None: ...
    def ctrl_op(self, kind: str, act: int, value: float) -> None: ...
    def mark_setconst(self) -> None: ...
    def set_play(self, act: int, width: float, inertia: float) -> None: ...


Bounds = list[tuple[float, float]]


@dataclass(frozen=True)
class Effect:
    """One family of the library: its parameters, bounds, realisation and the families it extends."""

    name: str
    kind: str
    params: tuple[str, ...]
    units: tuple[str, ...]
    bounds: Callable[[Scales, Target], Bounds]
    apply: Callable[[Builder, Target, np.ndarray, Scales], None]
    doc: str
    fields: tuple[str, ...] = ()  # MjModel fields edited on the target (a declared free field excludes it)
    shape: tuple[float, ...] = ()  # start values of non-nested (shape) params, as a share of their upper bound
    # families this one generalises: lift their parameters to ours, and the contrast (weights on our
    # parameters) that must differ from zero for the generalisation to be worth it
    extends: dict[str, Callable[[np.ndarray, Bounds], np.ndarray]] = field(default_factory=dict)
    contrast: tuple[float, ...] = ()
    threshold: bool = False  # shows only beyond a threshold: its signature is also taken at a large step
    report: Callable[[np.ndarray, Scales, Target], dict[str, float]] | None = None
    # 95% intervals of the reported parameters from the estimate and its covariance (default: the
    # report of x -+ 1.96 sd, right for monotone maps of one parameter each)
    intervals: Callable[[np.ndarray, np.ndarray, Scales, Target], dict[str, list | None]] | None = None
    gate: tuple[int, ...] | None = None  # nested params whose interval must exclude zero (default: all)
    standalone: bool = False  # offered on its own too, not only as a replacement of a family it extends
    group: str = ""  # families of one group exclude each other on a target
    play_side: str | None = None  # backlash as position play: which side the log measures
    # finite-difference step (normalised units) where the output moves in small jumps (contact events)
    fd_step: float | None = None
    # amplitudes (shares of the bound) simulated as starting points for a landscape with several basins
    scan: tuple[float, ...] = ()
    # parameters that stop being physical outside [0, top] (top None: no upper limit), as a spec's bounds
    # are checked: {param: (what it is, top)}
    limits: dict[str, tuple[str, float | None]] = field(default_factory=dict)
    # the ground truth the synthetic-data generator (`bench.calibrate.generate`) hides in its arm
    # (models/arm3.xml): a target there and physical parameters
    example: tuple[str, dict[str, float]] = ("", {})
    # how the generator plants `example`'s parameters where they are not the effect's own (physical units,
    # another target): (builder, target, parameters, the true model); default: `apply` with them in order
    plant: Callable[[Builder, Target, dict[str, float], mujoco.MjModel], None] | None = None
    reads_input: bool = False  # acts through a logged extra input (`signals.inputs`): one target per input column

    @property
    def n_nested(self) -> int:
        """Amplitude parameters (zero = absent) come first; shape parameters follow."""
        return len(self.params) - len(self.shape)

    @property
    def gated(self) -> tuple[int, ...]:
        """The parameters whose interval must exclude zero for the effect to be accepted."""
        return tuple(range(self.n_nested)) if self.gate is None else self.gate

    def start(self, bounds: Bounds) -> np.ndarray:
        """Parameter vector with the effect switched off (nested params zero, shape params at their start)."""
        x = np.zeros(len(self.params))
        for i, share in enumerate(self.shape):
            lo, hi = bounds[self.n_nested + i]
            x[self.n_nested + i] = lo + share * (hi - lo)
        return x

    def physical(self, x: np.ndarray, scales: Scales, target: Target) -> dict[str, float]:
        """The parameters as reported (physical units), e.g. a saturation's force limit."""
        if self.report is not None:
            return self.report(x, scales, target)
        return {p: float(v) for p, v in zip(self.params, x)}


# signature steps, as shares of each amplitude parameter's largest magnitude: a small one for the
# slope at zero and a large one for effects that only show beyond a threshold (saturation, dead band)
SIGNATURE_LEVELS = (0.1, 0.4)


def signature_steps(effect: Effect, bounds: Bounds, level: float) -> np.ndarray:
    """Finite-difference steps for the nested parameters when an effect is switched on from zero."""
    return np.array([level * max(abs(lo), abs(hi)) for lo, hi in bounds[: effect.n_nested]])

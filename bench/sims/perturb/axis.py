"""One perturbation axis as one row: what it is (name, unit, valid levels, targets) and how a level is applied.

A row is declared once, in the module that implements it — `model` (MuJoCo model fields, and the same
axes on PhysX), `interface` (held, delayed and noisy commands and observations), `frames` (noise on the
images the policy sees), `scene` (what the cameras render) — and `bench.sims.perturb.axes` gathers the
rows into the one table the grammar, `--help` and the docs read. Adding an axis is one row in one of
those modules (plus its docs row and a test); nothing else dispatches on its name.

The hooks a row carries say how a level is applied; `bench.sims.perturb.reset` calls whichever the row has:
- `select` + `scale` (model axes): the indices of the model elements edited (default targets, or the
  named ones) and the edit itself, as a scale of the nominal values of `fields`, which are saved the
  first time an env is seen and restored before every episode;
- `physx` (model axes on ManiSkill/SAPIEN): the same edit through PhysX's scene API;
- `wrap` (interface and frame axes): the env seen through a wrapper for the episode;
- `paint` + `check` (visual axes): one episode's edit of the rendered scene, and the model checks;
- `sapien` (visual axes on ManiSkill/SAPIEN): the same episode's edit of SAPIEN's render scene (a visual
  row without it is refused there);
- `start` + `check_start` (pose axes, `pose`): the env whose reset starts from an edited initial state
  (robot joints, object layout), and the check of a built env before any episode.

A categorical axis (`words`: `instruction`, `bench.sims.perturb.language`) takes words for levels, not
numbers: its `wrap` hook receives the word.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from bench.protocols import EnvAdapter, MujocoHandle

if TYPE_CHECKING:
    import mujoco


class PhysxScene(Protocol):
    """What a model row's PhysX edit uses of the env's PhysX handles (`bench.sims.perturb.physx.PhysxAxes`)."""

    def where(self) -> str: ...
    def body_names(self) -> list[str]: ...
    def joint_names(self) -> list[str]: ...
    def robot_links(self) -> list[str]: ...
    def object_names(self) -> list[str]: ...
    def resolve(self, names: Sequence[str], valid: Sequence[str], what: str, field: str) -> list[str]: ...
    def scale_gravity(self, s: float) -> None: ...
    def scale_mass(self, bodies: Sequence[str], s: float, field: str) -> None: ...
    def scale_drive(self, joints: Sequence[str], column: int, s: float, field: str) -> None: ...
    def scale_friction(self, s: float, bodies: list[str] | None, field: str) -> None: ...


MAX_SCALE = 1000.0  # a model field scaled by more than this is not a perturbation but a typo (1e300)
MAX_STEPS = 100_000  # latency / hold in control steps (also at most the run's horizon, checked by plan)

RGB_IMAGES = "rgb"  # `Axis.sees` of an axis that changes only camera images
Named = Mapping[str, Sequence[str]]  # targets named on the command line: {"bodies": [...], "joints": [...]}
Params = dict[str, object]  # what an episode records beside a level (JSON-able: numbers, strings, lists of them)
# an interface or frame axis' hook (`Axis.wrap`): (env, episode generator, level) -> (the env to step, params);
# the level is a number, or one of a categorical axis' words
Wrap = Callable[[EnvAdapter, np.random.Generator, Any], tuple[EnvAdapter, Params]]


@dataclass(frozen=True)
class Axis:
    """One perturbation axis: what it changes, its unit, the levels it accepts and how a level is applied."""

    name: str
    kind: str  # "model" (edits the simulator's model), "interface" (wraps the env), "visual" (images), "pose" (start)
    unit: str  # what a level means
    short: str  # a few words for `bench run --help`
    doc: str
    minimum: float = 0.0  # smallest valid level
    strict: bool = False  # level must be > minimum (not >=)
    integer: bool = False  # levels are whole numbers
    targets: tuple[str, ...] = ()  # optional name lists: "bodies", "joints", "geoms", "actuators", "cameras"
    nominal: float = 1.0  # the level that means "unperturbed"
    maximum: float = math.inf  # largest valid level
    words: tuple[str, ...] = ()  # a categorical axis' levels (numbers, ranges and curves refused); empty: numeric
    # -- model axes (MuJoCo) ------------------------------------------------------------------
    # MjModel fields it edits (saved on first sight, restored before every episode); the first one's
    # nominal values at the selected indices must not all be zero (column 0 of a 2-D field)
    fields: tuple[str, ...] = ()
    # (handle, named targets, field name for errors, where) -> indices into `fields`' first dimension
    select: Callable[[MujocoHandle, Named, str, str], np.ndarray] | None = None
    # (model, nominal values by field, indices, scale) -> edits the model
    scale: Callable[[mujoco.MjModel, Mapping[str, np.ndarray], np.ndarray, float], None] | None = None
    setconst: bool = False  # derived constants depend on it: mj_setConst after editing
    from_fields: tuple[str, ...] = ()  # model fields a calibration's draws carry for `from(CALIBRATION)`
    # -- model axes (ManiSkill / PhysX): (PhysxAxes, scale, named targets, field) -> edits the scene
    physx: Callable[[PhysxScene, float, dict[str, list[str]], str], None] | None = None
    physx_targets: tuple[str, ...] = ()  # target keys the PhysX edit takes
    # -- interface and frame axes: (env, episode generator, level) -> (the env to reset and step,
    # params to record beside the level)
    wrap: Wrap | None = None
    # -- visual axes: (VisualScene, level, named targets, generator) -> params to record; and the check
    # of a model and rig against the axis: (model, object bodies, named, cameras, where)
    # (the first argument is the rig's `bench.sims.perturb.scene.VisualScene`, which the row's module defines)
    paint: Callable[[Any, float, Named, np.random.Generator], Params] | None = None
    check: Callable[[mujoco.MjModel, Sequence[str], Named, Sequence[str], str], None] | None = None
    # the same edit on ManiSkill: (`bench.sims.perturb.sapien_scene.SapienScene`, level, named, generator) -> params
    sapien: Callable[[Any, float, Named, np.random.Generator], Params] | None = None
    sees: str = ""  # "rgb": changes only camera images (a policy that reads none is refused)
    # -- pose axes (kind "pose"): (env, episode generator, level, named targets) -> (the env whose reset returns
    # the edited initial state, params to record); and the check of a built env before any episode:
    # (env, the largest level asked, named targets, where), which may reset the env
    start: Callable[[EnvAdapter, np.random.Generator, float, Named], tuple[EnvAdapter, Params]] | None = None
    check_start: Callable[[EnvAdapter, float, Named, str], None] | None = None

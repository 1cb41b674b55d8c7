"""Suites, cells and jobs: what a run is made of.

A suite (the `bench.protocols.Suite` contract) is a named set of cells (task x robot x
environment) with a declared split manifest: for each axis (robots, envs, tasks) which
values are `seen` (allowed in training data) and which are `unseen` (held out). A run
selects cells (`select_cells`) and expands them into jobs (cell, condition, episode index;
`expand_jobs`); the episode seed depends only on the run seed and the episode index, so
the same episode index starts from the same initial state in every condition (pairing by
seed). `SuiteBase` gives a suite the contract's defaults; subclassing it is optional.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import zlib
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypedDict

import numpy as np

from bench.core.errors import ConfigError, valid_choices
from bench.protocols import Cell, EnvAdapter, NoOptions, ObsSpec, Policy, Suite

__all__ = [
    "Cell",
    "Condition",
    "ConditionSpec",
    "Job",
    "NOMINAL",
    "SPLITS",
    "SEED_SCHEMES",
    "SPLIT_AXES",
    "METRICS",
    "SuiteBase",
    "episode_seed",
    "condition_rng",
    "select_cells",
    "expand_jobs",
    "summary_line",
    "cell_to_dict",
    "SuiteSpec",
    "SIM_PACKAGES",
]

SPLITS = ("seen", "unseen")
# how episode seeds follow from the run seed: bench's hashed draw, or run seed + episode index (the convention of
# lerobot-eval's --seed and of Gymnasium's vector envs, so an evaluation made there is re-run on the same starts)
SEED_SCHEMES = ("hashed", "consecutive")
MAX_ENV_SEED = 2**32 - 1  # Gymnasium and numpy's legacy RandomState take 32-bit seeds
# selection key (`robots=[...]`) -> the Cell attribute it selects on; also the manifest's axes
SPLIT_AXES: dict[str, str] = {"robots": "robot", "tasks": "task", "envs": "env"}
METRICS = ("success_once", "success_at_end", "return")


class ConditionSpec(TypedDict, total=False):
    """How a perturbation condition takes its value (`Condition.spec`, written by `bench.sims.perturb.axes`).

    kind: "grid" (the level itself), "uniform" / "loguniform" (a value drawn per episode from the [low, high]
        level) or "from" (one of a calibration's bootstrap draws per episode); absent: "grid".
    targets: the elements the axis acts on by kind ({"joints": ["hinge1"]}); absent or empty: its defaults.
    source, sha256: for "from", the calibration.json drawn from and the sha256 of its bytes.
    keys, values: for "from", the draws' columns (`field:element[:column]`) and one row of values per draw.
    curve: a range asked to be scored as a curve (`perturb.AXIS.curve=`): at least 10 draws are required.
    instructions: for `instruction`, the paraphrase data of the run's tasks (`bench.sims.perturb.language.prepare`).
    """

    kind: str
    targets: dict[str, list[str]]
    source: str
    sha256: str
    keys: list[str]
    curve: bool
    values: list[list[float]]
    instructions: dict[str, Any]


@dataclass(frozen=True)
class Condition:
    """A physics/interface condition: `nominal`, or one perturbation setting (see bench.sims.perturb.reset)."""

    name: str = "nominal"
    axis: str | None = None  # e.g. "friction"; None for nominal
    # a scale/value (float or int), or a [low, high] range for randomisation (`from`: [0, draws - 1]); untyped, as
    # the perturbation code reads it by `kind` rather than by narrowing a union
    level: Any = None
    spec: ConditionSpec = field(default_factory=ConditionSpec, hash=False, compare=False)

    @property
    def kind(self) -> str:
        """`grid`, `uniform`, `loguniform` or `from` (`ConditionSpec.kind`; `grid` when unset, as for nominal)."""
        return self.spec.get("kind", "grid")

    @property
    def targets(self) -> Mapping[str, Sequence[str]]:
        """The named targets by kind (`ConditionSpec.targets`); empty: the axis' default targets."""
        return self.spec.get("targets") or {}


NOMINAL = Condition()


@dataclass(frozen=True)
class Job:
    """One episode to run: a cell under a condition with its own seed."""

    cell: Cell
    condition: Condition
    episode: int
    seed: int

    @property
    def job_id(self) -> str:
        return f"{self.cell.key}|{self.condition.name}|{self.episode}"


def episode_seed(run_seed: int, episode: int, scheme: str = "hashed") -> int:
    """Seed of episode `episode` of a run: independent of cell and condition (paired by seed).

    `hashed` (bench's default): a 32-bit draw from SeedSequence([run_seed, episode]);
    `consecutive`: run_seed + episode, lerobot-eval's `--seed` convention.
    """
    if scheme == "consecutive":
        return int(run_seed) + int(episode)
    return int(np.random.SeedSequence([int(run_seed), int(episode)]).generate_state(1)[0])


def condition_rng(seed: int, condition: Condition) -> np.random.Generator:
    """Generator for a condition's random draws in one episode (stable across processes)."""
    return np.random.default_rng([int(seed), zlib.crc32(condition.name.encode())])


# the packages whose version changes what a suite simulates (a run's provenance lists every package)
SIM_PACKAGES = ("mujoco", "robosuite", "metaworld", "gymnasium", "mani-skill", "sapien", "gym-aloha", "gym-pusht")


@dataclass(frozen=True)
class SuiteSpec:
    """What a run's suite was, frozen and serialisable (as Gymnasium's EnvSpec is for an env): name,
    version, split manifest (tasks, robots, envs: seen and unseen), the suite's own options and the
    simulator versions. Two runs are comparable when their specs are equal; `digest` names one.

    Built from what every run already stores (the summary's `suite`, its provenance's packages), so
    summaries written before the spec existed read into one too.
    """

    name: str
    version: str
    manifest: tuple[tuple[str, tuple[tuple[str, tuple[str, ...]], ...]], ...]
    options: tuple[tuple[str, str], ...]
    simulators: tuple[tuple[str, str], ...]

    @classmethod
    def of(cls, suite: Mapping[str, Any], packages: Mapping[str, object] | None) -> SuiteSpec:  # JSON in
        """From a suite's `describe()` (a summary's or run.json's `suite`) and a provenance's packages."""
        manifest = suite.get("manifest") or {}
        options = {k: v for k, v in suite.items() if k not in ("name", "version", "manifest")}
        sims = {k: str(v) for k, v in (packages or {}).items() if k in SIM_PACKAGES and v is not None}
        return cls(
            name=str(suite.get("name")),
            version=str(suite.get("version")),
            manifest=tuple(
                (axis, tuple((sp, tuple(str(x) for x in vals)) for sp, vals in sorted(splits.items())))
                for axis, splits in sorted(manifest.items())
            ),
            options=tuple((k, json.dumps(v, sort_keys=True)) for k, v in sorted(options.items())),
            simulators=tuple(sorted(sims.items())),
        )

    def to_json(self) -> dict[str, object]:
        return {
            "name": self.name,
            "version": self.version,
            "manifest": {a: {s: list(v) for s, v in splits} for a, splits in self.manifest},
            "options": {k: json.loads(v) for k, v in self.options},
            "simulators": dict(self.simulators),
            "digest": self.digest,
        }

    @property
    def digest(self) -> str:
        """`name-vVERSION@` and 12 hex digits of a hash of everything else."""
        body = json.dumps([self.manifest, self.options, self.simulators], sort_keys=True)
        return f"{self.name}-v{self.version}@{hashlib.sha256(body.encode()).hexdigest()[:12]}"

    def differs(self, other: SuiteSpec) -> str | None:
        """The first difference from `other`, in words, or None when the two are the same suite."""
        if self.name != other.name:
            return f"suite {self.name!r} vs {other.name!r}"
        if self.version != other.version:
            return f"suite {self.name} version {self.version} vs {other.version}"
        if self.manifest != other.manifest:
            return f"suite {self.name}: another split manifest"
        # options and simulators that only one side records (an older run) cannot differ
        a, b = dict(self.options), dict(other.options)
        for k in sorted(set(a) & set(b)):
            if a[k] != b[k]:
                return f"suite {self.name}: option {k}={a[k]} vs {b[k]}"
        a, b = dict(self.simulators), dict(other.simulators)
        for k in sorted(set(a) & set(b)):
            if a[k] != b[k]:
                return f"suite {self.name}: simulator {k} {a[k]} vs {b[k]}"
        return None


class SuiteBase(ABC):
    """Defaults of the `Suite` contract; a suite sets the class attributes and implements
    `all_cells`, `obs_spec` and `make_env` (and `make_expert` with the "expert" capability)."""

    name: ClassVar[str] = ""
    version: ClassVar[str] = "1"
    Options: ClassVar[type] = NoOptions
    reference_policy: str = "scripted"
    default_policy: str = ""  # "" = the reference policy
    default_horizon: int = 200
    max_horizon: int | None = None
    default_metric: str = "success_once"
    manifest: Mapping[str, Mapping[str, Sequence[str]]] = {}
    capabilities: frozenset[str] = frozenset()
    instructions: str | None = None  # the paraphrase data file `perturb.instruction` reads; None: none shipped

    def __init__(self, options: Any = None) -> None:
        why = self.unavailable()
        if why:  # refused with the line `bench list` shows
            raise ConfigError(why)
        self.options = self.Options() if options is None else options
        if not self.default_policy:
            self.default_policy = self.reference_policy

    @classmethod
    def unavailable(cls) -> str | None:
        """Why the suite cannot run in this environment (one line, e.g. a missing optional extra), or None.

        `bench list` shows it and `bench check` (every suite) skips the suite; the suite itself
        refuses to be built with the same message.
        """
        return None

    @abstractmethod
    def all_cells(self) -> list[Cell]: ...

    @abstractmethod
    def obs_spec(self, cell: Cell) -> ObsSpec: ...

    @abstractmethod
    def make_env(self, cell: Cell, horizon: int) -> EnvAdapter: ...

    def action_names(self, cell: Cell) -> Sequence[str] | None:
        """The action names a cell's env will take, declared without building it; None (this default) when
        only a built env can tell (a policy's preflight then builds one to check a checkpoint against)."""
        return None

    def make_expert(self, cell: Cell, env: EnvAdapter) -> Policy:
        raise ConfigError(f"suite {self.name!r} declares no scripted expert")

    @classmethod
    def preload(cls) -> None:
        """Import what building the suite's envs needs, in a worker started while the parent plans (the
        simulator: robosuite takes ~0.5 s); nothing by default. Errors are the build's to report."""
        return None  # a hook

    def check_worlds(self, cells: list[Cell], vector: int, workers: int) -> None:
        """Refuse a world count that cannot fit before the run writes anything; any count fits by default (a
        batched simulator's suite overrides it: suites/mjx_lift.py)."""
        return None  # a hook

    def describe(self) -> dict[str, object]:
        """JSON-able identity of the suite: name, version, split manifest and its options.

        An option declared with `metadata={"spec": False}` changes how the same numbers are computed,
        not what is computed (robosuite's `fast_path`): it is left out, so runs with and without it
        compare as the same suite."""
        out: dict[str, object] = {
            "name": self.name,
            "version": self.version,
            "manifest": {a: {s: list(v) for s, v in split.items()} for a, split in self.manifest.items()},
        }
        if dataclasses.is_dataclass(self.options) and not isinstance(self.options, type):
            hidden = {f.name for f in dataclasses.fields(self.options) if f.metadata.get("spec") is False}
            out.update({k: v for k, v in dataclasses.asdict(self.options).items() if k not in hidden})
        return out


def declared_scene(name: str, nominal: Mapping[str, Any], *declared: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """A suite's declared scene `name` in full: `nominal`'s values (lists copied), then the overrides of the first
    of `declared` (e.g. SEEN_SCENES, UNSEEN_SCENES) that names it. KeyError when none does."""
    overrides = next((scenes[name] for scenes in declared if name in scenes), None)
    if overrides is None:
        raise KeyError(name)
    params = {k: (list(v) if isinstance(v, list) else v) for k, v in nominal.items()}
    params.update(overrides)
    return params


def scene_cells(
    suite: str,
    task: str,
    robot: str,
    seen: Mapping[str, object],
    unseen: Mapping[str, object],
    params: Callable[[str], dict[str, Any]],
) -> list[Cell]:
    """One cell per declared scene of a one-task, one-robot suite: the seen scenes, then the unseen ones, each with
    its full parameters (`params(name)`, e.g. `declared_scene` over the suite's nominal) as the cell's options."""
    return [
        Cell(suite, task, robot, scene, split, options=params(scene))
        for split, scenes in (("seen", seen), ("unseen", unseen))
        for scene in scenes
    ]


def policy_ref(suite: Suite | type[Suite], policy: str | None) -> str:
    """The policy a run of `suite` uses: `policy`, else the suite's `default_policy`, else its reference policy."""
    return policy or suite.default_policy or suite.reference_policy


def summary_line(suite: object) -> str:
    """The first line of a suite's (class or instance) docstring (what `bench list` prints); any object's."""
    doc = (suite.__doc__ or "").strip().splitlines()
    return doc[0] if doc else ""


def select_cells(suite: Suite, selection: object) -> list[Cell]:
    """The suite's cells selected by `robots=`, `tasks=`, `envs=` and `splits=` (all when unset): the attributes
    of that name of `selection` (a run's config), a list of values or None.

    An empty list selects nothing and is refused, as is a value the suite does not have.
    """
    cells = suite.all_cells()
    for key, attr in (*SPLIT_AXES.items(), ("splits", "split")):
        wanted = getattr(selection, key, None)
        if wanted is None:
            continue
        valid = sorted({getattr(c, attr) for c in cells})
        if not wanted:
            raise ConfigError(f"{key}=[] selects nothing; list some of: {', '.join(valid)} (or leave {key} out)")
        for w in wanted:
            if w not in valid:
                raise ConfigError(f"{key}: {w!r} is not in suite {suite.name!r}; {valid_choices(w, valid)}")
        cells = [c for c in cells if getattr(c, attr) in wanted]
    return cells


def expand_jobs(
    cells: Sequence[Cell], conditions: Sequence[Condition], episodes: int, seed: int, scheme: str = "hashed"
) -> list[Job]:
    """Jobs in cell-major order, so each worker reuses its env across consecutive episodes."""
    return [
        Job(cell, cond, ep, episode_seed(seed, ep, scheme))
        for cell in cells
        for cond in conditions
        for ep in range(episodes)
    ]


def cell_to_dict(cell: Cell) -> dict[str, object]:
    return dataclasses.asdict(cell)

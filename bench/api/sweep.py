"""`bench sweep` from Python: a suite run per training checkpoint on common seeds, success against training
step, and the best checkpoint selected with the multiplicity of looking at many accounted for
(`bench.scoring.sweep`; docs/predict.md, "Checkpoint sweeps").

OUT/runs/<name>/ is each checkpoint's run (run.json, episodes.jsonl, summary.json: a leaderboard entry),
OUT/leaderboard.json ranks them, OUT/sweep.json holds the verdict, OUT/sweep.png the curve. Rerunning the same
command resumes: recorded episodes are not played again.
"""

from __future__ import annotations

import json
import re
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from bench.api.planning import Plan, parse_run, plan
from bench.api.running import run
from bench.core import outputs
from bench.core.config import one_or_more, ranged, top_key
from bench.core.errors import ConfigError
from bench.core.io import write_atomic
from bench.scoring.sweep import Point, outcomes_of, select

__all__ = ["SweepConfig", "SweepResult", "sweep"]

WEIGHTS = (".safetensors", ".pt")
OWNED_KEYS = ("policy", "checkpoint", "out", "run_id")  # set by the sweep for each run
STEP_META = ("step", "global_step", "train_step", "iteration")
ARCH_FIELDS = ("architecture", "kwargs", "obs_names", "action_names", "chunk")


@dataclass(frozen=True)
class SweepConfig:
    """Keys of `bench sweep` (every other key=value is a `bench run` key, the same for every checkpoint)."""

    checkpoints: Optional[list[str]] = one_or_more()  # checkpoint files, or one folder holding *.safetensors / *.pt
    policy: str = "checkpoint"  # the policy plugin each checkpoint is loaded by (checkpoint=PATH)
    alpha: float = ranged(
        0.05, 0, 0.5, lo_open=True, hi_open=True
    )  # family-wise error of the selection and the intervals
    min_success: Optional[float] = ranged(
        None, 0, 1
    )  # exit 1 unless the selected checkpoint's lower bound reaches this
    out: str = "runs/sweep"  # the sweep folder: runs/, sweep.json, sweep.png, leaderboard.json
    overwrite: bool = False  # replace an existing out= folder that bench wrote


@dataclass(frozen=True)
class SweepResult:
    """What `sweep` did: the folder, the verdict document and the command's exit code."""

    out: Path
    doc: dict[str, Any]
    exit_code: int  # 0 selected; 1 below min_success; 3 a checkpoint measured nothing
    figures: list[str] = field(default_factory=list)


def checkpoint_files(given: Sequence[str]) -> list[Path]:
    """The checkpoint files: `given` itself, or the weight files in the one folder it names (sorted)."""
    if not given:
        raise ConfigError("checkpoints=[]: the checkpoint list is empty; give checkpoint files or a folder of them")
    if len(given) == 1 and Path(given[0]).is_dir():
        found = sorted(p for p in Path(given[0]).iterdir() if p.suffix in WEIGHTS and p.is_file())
        if not found:
            raise ConfigError(f"checkpoints={given[0]!r}: the folder holds no {' or '.join(WEIGHTS)} file")
        return found
    paths = [Path(g) for g in given]
    for p in paths:
        if not p.is_file():
            raise ConfigError(f"checkpoints: {str(p)!r} is not a file (give checkpoint files or one folder)")
    return paths


def read_spec(path: Path) -> dict[str, Any] | None:
    """A checkpoint's policy spec: the sidecar PATH.json, else the safetensors header's embedded copy."""
    side = path.with_suffix(".json")
    try:
        if side.is_file():
            doc = json.loads(side.read_text(encoding="utf-8"))
            return doc if isinstance(doc, dict) else None
        if path.suffix == ".safetensors":
            with path.open("rb") as f:
                (size,) = struct.unpack("<Q", f.read(8))
                header = json.loads(f.read(min(size, 100_000_000)))
            embedded = (header.get("__metadata__") or {}).get("bench.policy_spec")
            return json.loads(embedded) if embedded else None
    except (OSError, ValueError, struct.error, UnicodeDecodeError, AttributeError):
        return None
    return None


def _architecture(spec: dict[str, Any] | None) -> str | None:
    if spec is None:
        return None
    return json.dumps({k: spec.get(k) for k in ARCH_FIELDS}, sort_keys=True)


def check_architectures(paths: Sequence[Path], specs: Sequence[dict[str, Any] | None]) -> None:
    """One architecture (and observation/action layout) for every checkpoint, else ConfigError naming two."""
    first = next(((p, s) for p, s in zip(paths, specs) if s is not None), None)
    if first is None:
        return
    for p, s in zip(paths, specs):
        if s is not None and _architecture(s) != _architecture(first[1]):
            what = next(k for k in ARCH_FIELDS if s.get(k) != first[1].get(k))
            raise ConfigError(
                f"checkpoints of different architectures in one sweep: {p.name} has {what}={s.get(what)!r}, "
                f"{first[0].name} has {first[1].get(what)!r}; sweep the checkpoints of one training run"
            )


def training_step(path: Path, spec: dict[str, Any] | None) -> tuple[float | None, str]:
    """(step, where it came from): the spec's meta (step, global_step, train_step, iteration), else the file
    name (the number after 'step'/'iter'/'it', else its last number), else None."""
    meta = (spec or {}).get("meta") or {}
    for key in STEP_META:
        value = meta.get(key) if isinstance(meta, dict) else None
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value), f"meta.{key}"
    stem = path.stem
    named = re.findall(r"(?:step|iter|it)[_\-=]?(\d+)", stem, flags=re.IGNORECASE)
    numbers = named or re.findall(r"\d+", stem)
    return (float(numbers[-1]), "file name") if numbers else (None, "order")


def _names(paths: Sequence[Path]) -> list[str]:
    names = [p.stem for p in paths]
    if len(set(names)) < len(names):
        names = [f"{p.parent.name}-{p.stem}" for p in paths]
    if len(set(names)) < len(names):
        raise ConfigError("checkpoints: two checkpoints have the same folder and file name; give distinct files")
    return names


def _plans(
    cfg: SweepConfig, run_keys: Sequence[str], paths: Sequence[Path], names: Sequence[str], out: Path
) -> list[Plan]:
    for key in run_keys:
        if top_key(key) in OWNED_KEYS:
            raise ConfigError(f"{key!r}: bench sweep sets {top_key(key)}= for each run (use checkpoints= and out=)")
    plans = [
        plan(parse_run([*run_keys, f"policy={cfg.policy}", f"checkpoint={p}", f"out={out / 'runs'}", f"run_id={n}"]))
        for p, n in zip(paths, names)
    ]
    metric = plans[0].config.metric
    if metric not in ("success_once", "success_at_end"):
        raise ConfigError(f"metric={metric!r}: bench sweep selects by a success rate (success_once or success_at_end)")
    seeds = [sorted((j.job_id, j.seed) for j in pl.jobs) for pl in plans]
    if any(s != seeds[0] for s in seeds[1:]):
        raise ConfigError("the checkpoints' runs would play different episodes; give the same keys for all")
    return plans


def sweep(cfg: SweepConfig, run_keys: Sequence[str] = (), progress: Callable[[str], None] | None = None) -> SweepResult:
    """Run the suite for every checkpoint, score and select (see the module docstring).

    Raises:
        ConfigError: an empty checkpoint list, checkpoints of different architectures, a bad run key; raised
            before anything is written.
    """
    note = progress or (lambda _m: None)
    paths = checkpoint_files(list(cfg.checkpoints or []))
    specs = [read_spec(p) for p in paths]
    check_architectures(paths, specs)
    steps = [training_step(p, s) for p, s in zip(paths, specs)]
    sources = {src for _, src in steps}
    if "order" in sources:  # one checkpoint without a step: every checkpoint is placed by its order
        steps = [(float(i), "order") for i in range(len(paths))]
    order = sorted(range(len(paths)), key=lambda i: (steps[i][0], str(paths[i])))
    paths, steps = [paths[i] for i in order], [steps[i] for i in order]
    names = _names(paths)
    out = outputs.check(
        "out",
        cfg.out,
        {"checkpoints": [str(p) for p in paths]},
        kind="dir",
        overwrite=cfg.overwrite,
        resume=lambda d: (d / "runs").is_dir(),
    )
    plans = _plans(cfg, run_keys, paths, names, out)
    metric = str(plans[0].config.metric)
    points, run_dirs, empty = [], [], []
    for i, (pl, name, (step, _)) in enumerate(zip(plans, names, steps)):
        note(f"checkpoint {i + 1}/{len(plans)} {name} (step {step:g}): {len(pl.jobs)} episodes")
        result = run(pl)
        outcomes = outcomes_of(result.records, metric)
        if not outcomes:
            empty.append(name)
        points.append(Point(name, float(step or 0.0), outcomes))
        run_dirs.append(result.run_dir)
    verdict = select(points, cfg.alpha)
    for row, path, (_, src), rd in zip(verdict["checkpoints"], paths, steps, run_dirs):
        row.update(checkpoint=str(path), step_source=src, run_dir=str(rd))
    doc: dict[str, Any] = {
        "schema": "bench.sweep/1",
        "metric": metric,
        "step_source": ", ".join(sorted({src for _, src in steps})),
        "min_success": cfg.min_success,
        **verdict,
    }
    exit_code = 3 if empty else 0
    selected = next((r for r in verdict["checkpoints"] if r["name"] == verdict["selected"]), None)
    if cfg.min_success is not None and exit_code == 0:
        lower = (selected or {}).get("success", {}).get("ci") or [0.0]
        exit_code = 1 if lower[0] < cfg.min_success else 0
    doc["exit_code"] = exit_code
    write_atomic(out / "sweep.json", doc)
    from bench.api.board import MergeConfig, leaderboard_merge  # pulls the board's schema checks: only at the end

    if not empty:
        leaderboard_merge([str(d) for d in run_dirs], MergeConfig(out=str(out / "leaderboard.json"), overwrite=True))
    from bench.board.report.figures import fig_sweep  # matplotlib: loaded only when the figure is drawn

    figures = ["sweep.png"] if fig_sweep(doc, out / "sweep.png") else []
    outputs.mark(out)
    return SweepResult(out, doc, exit_code, figures)

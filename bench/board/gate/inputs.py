"""What the regression gate compares, checked before anything runs: candidate/baseline arguments,
recorded runs, whether two sides pair (same cells, same episode seeds), where outputs may go.

Every check raises a one-line `BenchError` (exit 2) naming the difference; nothing here
writes a byte or runs an episode.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, Optional

from bench.core.errors import ConfigError, DataError
from bench.protocols import registry
from bench.scoring.summary import load_run

BINARY_METRICS = ("success_once", "success_at_end")  # the metrics a gate (or a comparison) of success reads


def require_binary(metric: object) -> str:
    """The gate's check of its metric: one of the success metrics (ConfigError naming the valid ones)."""
    if metric not in BINARY_METRICS:
        raise ConfigError(f"metric={metric!r}: the gate compares success; valid: {', '.join(BINARY_METRICS)}")
    return str(metric)


CHECKPOINT_SUFFIXES = (".safetensors", ".pt")


def resolve(value: Optional[str], role: str) -> dict[str, Any]:
    """Classify a candidate/baseline argument: a recorded run dir, a checkpoint file, or a policy name."""
    if not value:
        raise ConfigError(f"{role}= is required: a checkpoint file, a registered policy name or a run directory")
    path = Path(value)
    if path.is_file() and path.name in ("run.json", "summary.json", "episodes.jsonl"):
        path = path.parent  # a file of a run directory: the run directory
    if path.is_dir():
        if not (path / "run.json").is_file():
            raise ConfigError(f"{role}={value!r}: directory has no run.json; give a run directory written by bench run")
        return {"kind": "run", "spec": value, "run_dir": path}
    if path.suffix in CHECKPOINT_SUFFIXES or path.is_file():
        if not path.is_file():
            raise ConfigError(f"{role}={value!r}: no such file")
        if path.suffix not in CHECKPOINT_SUFFIXES:
            raise DataError(
                f"{role}={value!r}: not a checkpoint ({', '.join(CHECKPOINT_SUFFIXES)}) nor a run "
                "directory's run.json/summary.json/episodes.jsonl"
            )
        return {"kind": "checkpoint", "spec": value, "policy": "checkpoint", "checkpoint": str(path)}
    if "/" in value or value.endswith(".json"):
        raise ConfigError(f"{role}={value!r}: no such file or directory")
    registry.load_policy(value)  # RegistryError with the valid names
    return {"kind": "policy", "spec": value, "policy": value, "checkpoint": None}


def load_recorded(run_dir: Path, role: str):
    """Records and run.json of a recorded run; foreign or corrupt files are a one-line DataError."""
    records, meta = load_run(run_dir)
    for key in ("run_id", "suite", "policy", "config"):
        if not isinstance(meta, dict) or key not in meta:
            raise DataError(f"{run_dir / 'run.json'}: not a bench run.json (missing field {key!r})")
    if not records:
        raise DataError(f"{role}={str(run_dir)!r}: episodes.jsonl has no records")
    return records, meta


def cells_of_records(records: list) -> set[tuple]:
    """(task, robot, env, condition, split) of every cell some record belongs to."""
    return {(r.task, r.robot, r.env, r.condition, r.split) for r in records}


def cells_of_jobs(jobs: list, wanted: set[str] | None = None) -> set[tuple]:
    """(task, robot, env, condition, split) of the cells of a plan's jobs (only job ids in `wanted`, if given)."""
    return {
        (j.cell.task, j.cell.robot, j.cell.env, j.condition.name, j.cell.split)
        for j in jobs
        if wanted is None or j.job_id in wanted
    }


def check_pairable(
    records: list, where: str, role: str, cells: set[tuple], seeds: Mapping[str, int], live: bool
) -> None:
    """Refuse a recorded run (`records`, described by `where`) that does not pair with the other side.

    Args:
        role: the other side ("candidate" or "baseline").
        cells, seeds: the other side's cells and episode seed per job id (planned, when `live`).

    Raises:
        ConfigError: naming the first cell one side lacks, or the first episode whose seeds differ.
    """
    mine = cells_of_records(records)
    if mine != cells:
        missing, extra = sorted(cells - mine), sorted(mine - cells)
        diff = f"lacks cell {'/'.join(missing[0][:4])}" if missing else f"has cell {'/'.join(extra[0][:4])}"
        raise ConfigError(
            f"{where} was made with other suite cells: it {diff} that the {role} "
            f"{'does not have' if not missing else 'plays'} ({len(missing)} missing, {len(extra)} "
            "extra); paired episodes need the same cells"
        )
    bad = next((r for r in records if r.job_id in seeds and seeds[r.job_id] != r.seed), None)
    if bad is not None:
        raise ConfigError(
            f"{where} was made with other episode seeds: {bad.job_id} has seed {bad.seed}, the {role} "
            f"{'would play' if live else 'has'} {seeds[bad.job_id]} (another seed= or bench "
            "version?); paired episodes need the same seeds (paired=false compares two recorded runs unpaired)"
        )


def check_outputs(paths: Mapping[str, Path], inputs: list[tuple[Path, str]]) -> None:
    """No output file may be, or lie inside, an input (a checkpoint, its spec, a recorded run directory).

    Args:
        paths: the outputs by kind; `paths["verdict"]` is the out= the user gave.
        inputs: (resolved path, label) of everything read.
    """
    for what, path in paths.items():
        r = path.resolve()
        for inp, label in inputs:
            if r == inp or inp in r.parents:
                raise ConfigError(
                    f"out={str(paths['verdict'])!r}: the {what} file {r} would be written "
                    f"{'over' if r == inp else 'inside'} {label} ({inp}); choose another out="
                )

"""`bench logs` from Python: LeRobot v3.0 datasets inspected and verified, CSV / MAT / RLDS logs imported into one,
a log's data card, and its episodes ranked by sim-real surprise (`bench.logs`; pyarrow, so kept apart)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
from numpy.typing import NDArray

from bench.api import load_suite
from bench.core import outputs
from bench.core.config import MAX_SEED, one_or_more, ranged
from bench.core.errors import ConfigError, DataError, did_you_mean
from bench.core.io import write_atomic
from bench.logs import (
    LogDataset,
    check_files,
    import_csv,
    import_mat,
    import_rlds,
    info,
    read_dataset,
    verify,
    write_dataset,
)
from bench.logs.card import card, format_card
from bench.logs.lerobot.validate import MAX_FPS
from bench.protocols import STATE
from bench.protocols.suite import episode_seed

__all__ = [
    "FORMATS",
    "CardConfig",
    "CsvKeys",
    "ImportConfig",
    "Imported",
    "MatKeys",
    "RankConfig",
    "RldsKeys",
    "Written",
    "format_card",
    "format_for",
    "import_log",
    "log_card",
    "log_info",
    "rank_log",
    "verify_log",
]

MAX_CARD_EPISODES = 10_000  # evaluation initial states per cell a card compares the log with


@dataclass(frozen=True)
class ImportConfig:
    """Keys of `bench logs import` for every format (SRC is positional)."""

    out: Optional[str] = None  # target folder (required; must be new or empty unless overwrite=true)
    format: Optional[str] = None  # csv | mat | rlds (default: from SRC: .csv, .mat, a folder or .tfrecord file)
    fps: Optional[float] = ranged(
        None, 0, MAX_FPS, lo_open=True
    )  # frame rate in Hz (csv/mat: default 1/median time step; rlds: required)
    task: Optional[str] = None  # task string of the episodes (rlds: where an episode has no instruction)
    robot_type: Optional[str] = None  # robot type written to info.json
    overwrite: bool = False  # replace a non-empty out folder


@dataclass(frozen=True)
class CsvKeys:
    """Keys of `bench logs import` for a CSV file."""

    state: Optional[list[str]] = one_or_more()  # columns of observation.state (default: every numeric column not used)
    action: Optional[list[str]] = one_or_more()  # columns of action (default: none)
    time: Optional[str] = None  # time column in seconds (without it, fps is required)
    episode: Optional[str] = None  # column whose values split the rows into episodes
    delimiter: str = ","  # field separator, one character
    velocity: Optional[list[str]] = one_or_more()  # columns of observation.velocity (joint velocities as logged)
    effort: Optional[list[str]] = one_or_more()  # columns of observation.effort (measured joint torques or currents)
    resample: Optional[float] = ranged(
        None, 0, MAX_FPS, lo_open=True
    )  # put an irregular clock on a uniform grid at this rate (Hz; linear interpolation, needs time=)


@dataclass(frozen=True)
class MatKeys:
    """Keys of `bench logs import` for a MATLAB .mat file (one episode)."""

    state: Optional[list[str]] = one_or_more()  # variables of observation.state (default: every vector but time)
    action: Optional[list[str]] = one_or_more()  # variables of action
    time: Optional[str] = None  # time variable in seconds (default: t or time)
    velocity: bool = False  # append d/dt of each state variable as <var>_dot


@dataclass(frozen=True)
class RldsKeys:
    """Keys of `bench logs import` for RLDS tfrecord shards."""

    split: str = "train"  # shards to read
    state: str = "observation/state"  # step field of observation.state
    action: str = "action"  # step field of action
    instruction: str = "language_instruction"  # step field with the task text


FORMATS: dict[str, type[CsvKeys] | type[MatKeys] | type[RldsKeys]] = {"csv": CsvKeys, "mat": MatKeys, "rlds": RldsKeys}


@dataclass(frozen=True)
class CardConfig:
    """Keys of `bench logs card` (DIR is positional)."""

    suite: Optional[str] = None  # suite whose evaluation the log must not overlap (builds its envs once per cell)
    episodes: int = ranged(10, 0, MAX_CARD_EPISODES)  # evaluation episodes per cell (at least 1 with suite=)
    seed: int = ranged(0, 0, MAX_SEED)  # evaluation run seed
    dup_tol: float = ranged(0.05, 0)  # near-duplicate threshold, RMS in standardised units
    overlap_tol: float = ranged(0.01, 0)  # overlap threshold, RMS in standardised units
    out: Optional[str] = None  # also write the card as JSON (bench.logs_card/1) to this new file


@dataclass(frozen=True)
class RankConfig:
    """Keys of `bench logs rank` (DIR is positional)."""

    calibration: Optional[str] = None  # calibration.json of `bench calibrate`, or its folder (required)
    horizon: str = "free_run"  # free_run | k_step (see below)
    top: int = ranged(10, 0)  # rows printed (out= holds all)
    out: Optional[str] = None  # also write the ranking as JSON (bench.logs_rank/1) to this new file


@dataclass(frozen=True)
class Imported:
    """What `import_log` wrote: the dataset folder, the dataset, the format it came from and the folder's summary."""

    path: Path
    dataset: LogDataset
    format: str
    info: dict[str, Any]  # `log_info` of the written folder


@dataclass(frozen=True)
class Written:
    """A document computed from a log (a card, a ranking) and the file it was also written to (None: no out=)."""

    doc: dict[str, Any]
    path: Path | None


def format_for(src: Path, given: Optional[str]) -> str:
    """The import format of `src`: `given` (csv | mat | rlds), else from its name (.csv, .mat, a folder or .tfrecord)."""
    if given is not None:
        fmt = given.lower()
        if fmt not in FORMATS:
            raise ConfigError(f"format is {given!r}; valid: {', '.join(FORMATS)}.{did_you_mean(fmt, FORMATS)}")
        return fmt
    if src.suffix.lower() == ".csv":
        return "csv"
    if src.suffix.lower() == ".mat":
        return "mat"
    if src.is_dir() or ".tfrecord" in src.name:
        return "rlds"
    raise ConfigError(f"cannot tell the format of {str(src)!r}; pass format=csv|mat|rlds")


def import_log(src: str | Path, cfg: ImportConfig, keys: CsvKeys | MatKeys | RldsKeys | None = None) -> Imported:
    """Convert the log `src` to a LeRobot v3.0 dataset folder `cfg.out` (`bench logs import`).

    `keys`: the format's own keys, a `CsvKeys`, `MatKeys` or `RldsKeys` (None: that format's defaults); the format
    is `cfg.format`, else told from `src`'s name.
    """
    src = Path(src).expanduser()
    fmt = format_for(src, cfg.format)
    keys = keys if keys is not None else FORMATS[fmt]()
    if not isinstance(keys, FORMATS[fmt]):
        raise ConfigError(f"format={fmt} takes {FORMATS[fmt].__name__} keys, not {type(keys).__name__}")
    if not cfg.out:
        raise ConfigError("missing key 'out': bench logs import SRC out=DIR")
    task = cfg.task or "default"
    meta: dict[str, Any] = {"task": task, "fps": cfg.fps, "robot_type": cfg.robot_type}  # what every format takes
    if isinstance(keys, CsvKeys):
        if len(keys.delimiter) != 1:
            raise ConfigError(f"delimiter is {keys.delimiter!r}; expected one character (e.g. , or ; or a tab)")
        ds = import_csv(
            src,
            state=keys.state,
            action=keys.action,
            time=keys.time,
            episode=keys.episode,
            delimiter=keys.delimiter,
            velocity=keys.velocity,
            effort=keys.effort,
            resample=keys.resample,
            **meta,
        )
    elif isinstance(keys, MatKeys):
        pairs = (("observation.state", keys.state), ("action", keys.action))
        mapping: dict[str, str | Sequence[str]] = {feature: names for feature, names in pairs if names}
        ds = import_mat(src, mapping or None, time=keys.time, velocity=keys.velocity, **meta)
    else:
        ds = import_rlds(
            src, split=keys.split, state=keys.state, action=keys.action, instruction=keys.instruction, **meta
        )
    out = write_dataset(Path(cfg.out).expanduser(), ds, overwrite=cfg.overwrite, inputs={"SRC": src})
    return Imported(out, ds, fmt, log_info(out))


def log_info(root: Path | str) -> dict[str, Any]:
    """A dataset folder's metadata summary, after every data file's footer is read (`check_files`: no frames)."""
    summary: dict[str, Any] = info(root)
    summary["files"] = check_files(root)
    return summary


def verify_log(root: Path | str) -> dict[str, Any]:
    """Every frame of every file of a dataset folder read and checked; the counts (DataError on the first bad one)."""
    got: dict[str, Any] = verify(Path(root).expanduser())
    return got


def _eval_starts(suite_name: str, ds: LogDataset, episodes: int, seed: int) -> dict[str, NDArray[np.float64]]:
    """Initial observations of a suite's evaluation for the cells the log's episodes name (task strings)."""
    suite = load_suite(suite_name)
    cells = {c.key: c for c in suite.all_cells()}
    named = sorted({ep.tasks[0] for ep in ds.episodes if ep.tasks} & set(cells))
    if not named:
        raise DataError(
            f"no episode of the log names a cell of suite {suite_name!r} in its task string (cells: "
            f"{', '.join(sorted(cells)[:5])}...); was it recorded with `bench run suite={suite_name} "
            "record=`?"
        )
    out = {}
    for key in named:
        env = suite.make_env(cells[key], suite.default_horizon)
        try:
            out[key] = np.stack(
                [np.asarray(env.reset(episode_seed(seed, e))[STATE], dtype=np.float64).ravel() for e in range(episodes)]
            )
        finally:
            env.close()
    return out


def _new_file(value: Any, key: str, inputs: dict[str, Any]) -> Path | None:
    """A new output file (`bench.core.outputs`' rule: never an input or inside one; never over an existing file)."""
    if value is None:
        return None
    return outputs.check(key, str(value), inputs, kind="file", can_overwrite=False)


def log_card(root: str | Path, cfg: CardConfig) -> Written:
    """The data card of the log in `root` (`bench logs card`; `format_card` prints it), also written to `cfg.out`."""
    root = Path(root).expanduser()
    out = _new_file(cfg.out, "out", {"DIR": root})
    if not root.exists():
        raise ConfigError(f"logs folder {str(root)!r} does not exist")
    ds = read_dataset(root)
    starts, where = None, ""
    if cfg.suite is not None:
        if cfg.episodes < 1:
            raise ConfigError("key 'episodes' must be at least 1 with suite=")
        starts = _eval_starts(cfg.suite, ds, cfg.episodes, cfg.seed)
        where = (
            f"suite {cfg.suite}: {cfg.episodes} evaluation episode(s) of run seed {cfg.seed} in {len(starts)} cell(s)"
        )
    doc: dict[str, Any] = card(ds, starts=starts, where=where, dup_tol=cfg.dup_tol, overlap_tol=cfg.overlap_tol)
    if out is not None:
        write_atomic(out, doc)
    return Written(doc, out)


def rank_log(root: str | Path, cfg: RankConfig) -> Written:
    """The episodes of the log in `root` ordered by sim-real surprise under `cfg.calibration` (`bench logs rank`),
    also written to `cfg.out`."""
    from bench.calibrate.rank import rank  # mujoco and scipy: only `bench logs rank` needs them

    root = Path(root).expanduser()
    if cfg.calibration is None:
        raise ConfigError("missing key 'calibration' (a `bench calibrate` output folder or its calibration.json)")
    out = _new_file(cfg.out, "out", {"DIR": root, "calibration": cfg.calibration})
    doc: dict[str, Any] = rank(cfg.calibration, root, cfg.horizon)
    if out is not None:
        write_atomic(out, doc)
    return Written(doc, out)

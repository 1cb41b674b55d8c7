"""`bench logs`: inspect LeRobot v3.0 datasets and import CSV / MAT / RLDS logs into one (the command lines and
printed text over `bench.api.logs`)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from bench.api.logs import (
    FORMATS,
    CardConfig,
    ImportConfig,
    RankConfig,
    format_card,
    format_for,
    import_log,
    log_card,
    log_info,
    rank_log,
    verify_log,
)
from bench.core import config
from bench.core.errors import ConfigError, did_you_mean

T = TypeVar("T")


INFO_USAGE = "usage: bench logs info DIR"
VERIFY_USAGE = "usage: bench logs verify DIR"
IMPORT_USAGE = "usage: bench logs import SRC out=DIR [format=csv|mat|rlds] [key=value ...]"
CARD_USAGE = (
    "usage: bench logs card DIR [suite=NAME] [episodes=10] [seed=0] [dup_tol=0.05] [overlap_tol=0.01]\n"
    "                      [out=FILE]"
)
RANK_USAGE = "usage: bench logs rank DIR calibration=FILE [horizon=free_run|k_step] [top=10] [out=FILE]"


def help_text() -> str:
    """`bench logs --help`: the subcommands (each has its own --help with its keys)."""
    usages = [INFO_USAGE, VERIFY_USAGE, IMPORT_USAGE, CARD_USAGE.split("\n")[0], RANK_USAGE]
    return config.command_help(
        "\n".join([usages[0]] + ["      " + u.removeprefix("usage:") for u in usages[1:]]),
        "Real-robot logs as LeRobot v3.0 datasets (parquet, read and written without pandas).",
        notes="subcommands:\n"
        "  info    episodes, frames, fps, features with shapes and tasks of a dataset folder; every data\n"
        "          file's footer is read (a truncated or garbage file is named)\n"
        "  verify  read every frame of every file of a dataset folder (exit 2 naming the first bad one)\n"
        "  import  convert a CSV file, a MATLAB .mat file or RLDS tfrecord shards to a dataset\n"
        "  card    how many episodes are worth having: N_eff = N (1 - d) (1 - n) (1 - c)\n"
        "  rank    episodes ordered by sim-real surprise under a calibrated model\n\n"
        "`bench logs SUBCOMMAND --help` describes each and lists its keys.",
    )


def info_help() -> str:
    """`bench logs info --help`."""
    return config.command_help(
        INFO_USAGE,
        "Print a LeRobot v3.0 dataset's summary from its metadata: episodes, frames, episode lengths,\n"
        "fps, robot type, every feature with dtype and shape, the tasks. Camera features are dtype\n"
        "`image` (PNG inside the parquet) or `video` (MP4 files; shown with codec, pixel format, fps and\n"
        "number of files). No frame is read, but every data file's parquet footer is: a missing,\n"
        "truncated or garbage file, other columns than declared or other row counts than the episodes\n"
        "table's are named (exit 2). `bench logs verify DIR` reads every frame. It takes no keys.",
        examples=["bench logs info logs/pendulum"],
    )


def verify_help() -> str:
    """`bench logs verify --help`."""
    return config.command_help(
        VERIFY_USAGE,
        "Read a LeRobot v3.0 dataset completely: every data file's footer and every row group decoded\n"
        "and checked as the readers check it (columns and shapes as declared, episode and task indices,\n"
        "no NaN or inf, increasing timestamps, row counts as the episodes table says), and every video\n"
        "frame decoded. Prints the counts, or one line naming the first bad file and field (exit 2).\n"
        "It takes no keys.",
        examples=["bench logs verify logs/pendulum"],
    )


def import_help() -> str:
    """`bench logs import --help`: the keys of every format, then each format's own."""
    sections = {
        "csv": "csv keys",
        "mat": "mat keys (one episode; scalar variables go to the episode metadata)",
        "rlds": "rlds keys (TFDS shards; features.json gives shapes and dtypes; no TensorFlow needed)",
    }
    return config.command_help(
        IMPORT_USAGE,
        "Convert a log to a LeRobot v3.0 dataset folder. observation.state and action become\n"
        "float32 vectors; a time column gives `timestamp` (s from the episode start) and `time_ns`\n"
        "(absolute, int64 ns). The keys below the first list belong to one format each.",
        ImportConfig,
        examples=[
            "bench logs import data_measured.csv out=logs/pendulum time=time state=[position,velocity] action=[torque]",
            "bench logs import DATA_EMPS.mat out=logs/emps state=[qm] action=[vir] velocity=true",
            "bench logs import ~/tensorflow_datasets/bridge/1.0.0 out=logs/bridge format=rlds fps=5",
        ],
        notes="\n\n".join(f"{title}:\n{config.key_help(FORMATS[fmt])}" for fmt, title in sections.items()),
    )


def card_help() -> str:
    """`bench logs card --help`."""
    return config.command_help(
        CARD_USAGE,
        "A data card of a log: N episodes, and how many of them count, N_eff = N (1 - d) (1 - n) (1 - c):\n"
        "  d  near-duplicate share: episodes whose observation.state trajectory (resampled to 32 instants,\n"
        "     standardised by the log's spread) is within dup_tol RMS of an earlier episode's\n"
        "  n  noise share: white-noise variance (var of second differences / 6) over variance, mean of channels\n"
        "  c  overlap with an evaluation: episodes whose first observation is within overlap_tol (RMS,\n"
        "     standardised) of an initial observation of `bench run suite=NAME episodes=K seed=S` (the\n"
        "     cells the episodes' task strings name; measured only with suite=)",
        CardConfig,
        examples=["bench logs card logs/pendulum", "bench logs card runs/rec suite=held_out_robots out=card.json"],
    )


def rank_help() -> str:
    """`bench logs rank --help`."""
    return config.command_help(
        RANK_USAGE,
        "Episodes of DIR ordered by sim-real surprise: the position NRMSE of each episode replayed in the\n"
        "calibrated model (a `bench calibrate` output: spec calibrations rebuild the spec's model, suite\n"
        "calibrations the suite's robot in its scene), highest first — what to replay, inspect or collect next.",
        RankConfig,
        notes="horizon:\n"
        "  free_run  open loop from the episode's first state to its end (default)\n"
        "  k_step    re-initialised from the log every k frames (the calibration's k)",
        examples=["bench logs rank logs/emps calibration=runs/emps top=5"],
    )


def _names(schema: type) -> list[str]:
    return [f.name for f in dataclasses.fields(schema)]


def cmd_import(argv: list[str]) -> int:
    """`bench logs import SRC out=DIR [format=...] [key=value ...]`."""
    positional, overrides = config.split_args(argv)
    if len(positional) != 1:
        raise ConfigError(f"expected one source path, got {len(positional)}: bench logs import SRC out=DIR")
    src = Path(positional[0]).expanduser()
    common = _names(ImportConfig)
    cfg: ImportConfig = config.build(ImportConfig, [o for o in overrides if config.top_key(o) in common])
    fmt = format_for(src, cfg.format)
    parts = config.partition(overrides, {"all formats": common, fmt: _names(FORMATS[fmt])}, f"for format={fmt}")
    done = import_log(src, cfg, config.build(FORMATS[fmt], parts[fmt]))
    ds = done.dataset
    print(f"wrote {done.path}: {len(ds.episodes)} episodes, {ds.num_frames} frames at {ds.fps:g} fps from {fmt} {src}")
    print(format_info(done.info))
    return 0


def format_info(summary: dict[str, Any]) -> str:
    """Plain aligned text for `bench logs info`."""
    lengths = summary["lengths"]
    lines = [
        f"dataset   {summary['root']}",
        f"format    LeRobot {summary['codebase_version']}, robot_type {summary['robot_type']}",
        f"episodes  {summary['episodes']}  (frames {summary['frames']}; length {lengths['min']}..{lengths['max']}, "
        f"mean {lengths['mean']:.1f})",
        f"fps       {summary['fps']}",
        "features",
    ]
    width = max(len(n) for n in summary["features"])
    for name, feat in summary["features"].items():
        names = feat.get("names")
        shown = ""
        if isinstance(names, list) and names:
            shown = ", ".join(map(str, names[:8])) + (", ..." if len(names) > 8 else "")
        elif isinstance(names, dict):
            shown = ", ".join(f"{k}: {v}" for k, v in names.items())
        video = feat.get("video")
        if video:  # frames in MP4 files beside the parquet data
            files = video["files"]
            shown = (
                f"{video.get('codec') or '?'} {video.get('pix_fmt') or '?'}, {video.get('fps') or '?'} fps, "
                f"{files} mp4 file{'s' if files != 1 else ''}"
            )
        lines.append(f"  {name.ljust(width)}  {feat['dtype']:<8} {str(feat['shape']):<14} {shown}".rstrip())
    files = summary.get("files")
    if files:
        lines.append(
            f"files     {files['data_files']} data file(s) ({files['rows']} rows), {files['video_files']} video "
            "file(s): footers read, as the metadata says (`bench logs verify` reads every frame)"
        )
    lines.append(f"tasks     {len(summary['tasks'])}")
    for i, task in enumerate(summary["tasks"][:20]):
        lines.append(f"  {i:>3}  {task}")
    if len(summary["tasks"]) > 20:
        lines.append(f"  ... {len(summary['tasks']) - 20} more")
    return "\n".join(lines)


def cmd_info(argv: list[str]) -> int:
    """`bench logs info DIR` (no keys)."""
    if len(argv) != 1 or "=" in argv[0]:
        raise ConfigError(f"expected one dataset folder: {INFO_USAGE.removeprefix('usage: ')}")
    print(format_info(log_info(Path(argv[0]).expanduser())))
    return 0


def cmd_verify(argv: list[str]) -> int:
    """`bench logs verify DIR` (no keys): every frame of every file read and checked."""
    if len(argv) != 1 or "=" in argv[0]:
        raise ConfigError(f"expected one dataset folder: {VERIFY_USAGE.removeprefix('usage: ')}")
    t0 = time.perf_counter()
    got = verify_log(argv[0])
    print(
        f"{argv[0]}: ok: {got['episodes']} episodes, {got['frames']} frames; {got['data_files']} data file(s) and "
        f"{got['video_files']} video file(s) read in full ({time.perf_counter() - t0:.1f} s)"
    )
    return 0


def _dir_and_config(argv: list[str], schema: type[T], usage: str) -> tuple[Path, T]:
    """`DIR key=value ...` -> the dataset folder and the subcommand's frozen config."""
    positional, overrides = config.split_args(argv)
    if len(positional) != 1:
        raise ConfigError(f"expected one dataset folder; {usage.splitlines()[0]}")
    return Path(positional[0]).expanduser(), config.build(schema, overrides)


def cmd_card(argv: list[str]) -> int:
    """`bench logs card DIR ...`."""
    root, cfg = _dir_and_config(argv, CardConfig, CARD_USAGE)
    done = log_card(root, cfg)
    print(format_card(done.doc))
    if done.path is not None:
        print(f"wrote {done.path}")
    return 0


def cmd_rank(argv: list[str]) -> int:
    """`bench logs rank DIR calibration=FILE ...`."""
    root, cfg = _dir_and_config(argv, RankConfig, RANK_USAGE)
    done = rank_log(root, cfg)
    doc = done.doc
    print(f"surprise = {doc['statistic']}; {len(doc['episodes'])} episodes, most first")
    print(f"{'rank':>4}  {'episode':>7}  {'frames':>6}  {'surprise':>9}  worst joint")
    for i, row in enumerate(doc["episodes"][: cfg.top]):
        joint, value = max(row["per_joint"].items(), key=lambda kv_: kv_[1])
        print(f"{i + 1:>4}  {row['episode']:>7}  {row['frames']:>6}  {row['surprise']:>9.4g}  {joint} ({value:.3g})")
    if done.path is not None:
        print(f"wrote {done.path}")
    return 0


# subcommand -> (handler, its --help)
SUBCOMMANDS: dict[str, tuple[Callable[[list[str]], int], Callable[[], str]]] = {
    "info": (cmd_info, info_help),
    "verify": (cmd_verify, verify_help),
    "import": (cmd_import, import_help),
    "card": (cmd_card, card_help),
    "rank": (cmd_rank, rank_help),
}


def main(argv: list[str]) -> int:
    """Dispatch `bench logs info|verify|import|card|rank`."""
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(help_text(), end="")
        return 0
    sub, rest = argv[0], argv[1:]
    if sub not in SUBCOMMANDS:
        raise ConfigError(
            f"unknown logs subcommand {sub!r}; valid: {', '.join(SUBCOMMANDS)}.{did_you_mean(sub, SUBCOMMANDS)}"
        )
    handler, help_of = SUBCOMMANDS[sub]
    if not rest or any(a in ("-h", "--help") for a in rest):
        print(help_of(), end="")
        return 0
    return handler(rest)

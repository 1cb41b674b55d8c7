"""`bench logs`: inspect LeRobot v3.0 datasets and import CSV / MAT / RLDS logs into one."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.errors import ConfigError, did_you_mean

USAGE = """usage: bench logs info DIR
       bench logs import SRC out=DIR [format=csv|mat|rlds] [key=value ...]
       bench logs card DIR [suite=NAME] [episodes=10] [seed=0] [out=FILE]
       bench logs rank DIR calibration=FILE [top=10] [out=FILE]

Real-robot logs as LeRobot v3.0 datasets (parquet, read and written without pandas).

subcommands:
  info    episodes, frames, fps, features with shapes and tasks of a dataset folder
  import  convert a CSV file, a MATLAB .mat file or RLDS tfrecord shards to a dataset
  card    how many episodes are worth having: N_eff = N (1 - d) (1 - n) (1 - c)
  rank    episodes ordered by sim-real surprise under a calibrated model

`bench logs SUBCOMMAND --help` describes each.
"""

CARD_USAGE = """usage: bench logs card DIR [suite=NAME] [episodes=10] [seed=0] [dup_tol=0.05] [overlap_tol=0.01]
                      [out=FILE]

A data card of a log: N episodes, and how many of them count, N_eff = N (1 - d) (1 - n) (1 - c):
  d  near-duplicate share: episodes whose observation.state trajectory (resampled to 32 instants,
     standardised by the log's spread) is within dup_tol RMS of an earlier episode's
  n  noise share: white-noise variance (var of second differences / 6) over variance, mean of channels
  c  overlap with an evaluation: episodes whose first observation is within overlap_tol (RMS,
     standardised) of an initial observation of `bench run suite=NAME episodes=K seed=S` (the
     cells the episodes' task strings name; measured only with suite=)

keys:
  suite        suite whose evaluation the log must not overlap (builds its envs once per cell)
  episodes     evaluation episodes per cell (default 10)
  seed         evaluation run seed (default 0)
  dup_tol      near-duplicate threshold, RMS in standardised units (default 0.05)
  overlap_tol  overlap threshold, RMS in standardised units (default 0.01)
  out          also write the card as JSON (bench.logs_card/1) to this new file
"""

RANK_USAGE = """usage: bench logs rank DIR calibration=FILE [horizon=free_run|k_step] [top=10] [out=FILE]

Episodes of DIR ordered by sim-real surprise: the position NRMSE of each episode replayed in the
calibrated model (a `bench calibrate` output: spec calibrations rebuild the spec's model, suite
calibrations the suite's robot in its scene), highest first — what to replay, inspect or collect next.

keys:
  calibration  calibration.json (or its folder)
  horizon      free_run (default): open loop from the episode's first state to its end;
               k_step: re-initialised from the log every k frames (the calibration's k)
  top          rows printed (default 10; out= holds all)
  out          also write the ranking as JSON (bench.logs_rank/1) to this new file
"""

INFO_USAGE = """usage: bench logs info DIR

Print a LeRobot v3.0 dataset's summary from its metadata (no frames are read): episodes,
frames, episode lengths, fps, robot type, every feature with dtype and shape, the tasks.
Camera features are dtype `image` (PNG inside the parquet) or `video` (MP4 files; shown with
codec, pixel format, fps and number of files).
"""

IMPORT_USAGE = """usage: bench logs import SRC out=DIR [format=csv|mat|rlds] [key=value ...]

Convert a log to a LeRobot v3.0 dataset folder. observation.state and action become
float32 vectors; a time column gives `timestamp` (s from the episode start) and `time_ns`
(absolute, int64 ns).

keys (all formats):
  out         target folder (required; must be new or empty unless overwrite=true)
  format      csv | mat | rlds (default: from SRC: .csv, .mat, a folder or .tfrecord file)
  fps         frame rate in Hz (csv/mat: default 1/median time step; rlds: required)
  task        task string of the episodes (rlds: where an episode has no instruction)
  robot_type  robot type written to info.json
  overwrite   replace a non-empty out folder (default false)

csv:
  state=[c1,c2]   columns of observation.state (default: every numeric column not used)
  action=[c1]     columns of action (default: none)
  time=COL        time column in seconds (without it, fps is required)
  episode=COL     column whose values split the rows into episodes
  delimiter=,     field separator
  example: bench logs import data_measured.csv out=logs/pendulum time=time state=[position,velocity] action=[torque]

mat (one episode; scalar variables go to the episode metadata):
  state=[v1,v2]   variables of observation.state (default: every vector but time)
  action=[v1]     variables of action
  time=VAR        time variable in seconds (default: t or time)
  velocity=true   append d/dt of each state variable as <var>_dot
  example: bench logs import DATA_EMPS.mat out=logs/emps state=[qm] action=[vir] velocity=true

rlds (TFDS shards; features.json gives shapes and dtypes; no TensorFlow needed):
  split=train               shards to read
  state=observation/state   step field of observation.state
  action=action             step field of action
  instruction=language_instruction   step field with the task text
  example: bench logs import ~/tensorflow_datasets/bridge/1.0.0 out=logs/bridge format=rlds fps=5
"""

_COMMON = ("out", "format", "fps", "task", "robot_type", "overwrite")
_KEYS = {
    "csv": _COMMON + ("state", "action", "time", "episode", "delimiter"),
    "mat": _COMMON + ("state", "action", "time", "velocity"),
    "rlds": _COMMON + ("split", "state", "action", "instruction"),
}


def _format_for(src: Path, given: Any) -> str:
    if given is not None:
        fmt = str(given).lower()
        if fmt not in _KEYS:
            raise ConfigError(f"format is {given!r}; valid: {', '.join(_KEYS)}.{did_you_mean(fmt, _KEYS)}")
        return fmt
    if src.suffix.lower() == ".csv":
        return "csv"
    if src.suffix.lower() == ".mat":
        return "mat"
    if src.is_dir() or ".tfrecord" in src.name:
        return "rlds"
    raise ConfigError(f"cannot tell the format of {str(src)!r}; pass format=csv|mat|rlds")


def _bool(value: Any, key: str) -> bool:
    if isinstance(value, bool):
        return value
    if str(value).lower() in ("true", "1", "yes"):
        return True
    if str(value).lower() in ("false", "0", "no"):
        return False
    raise ConfigError(f"{key} is {value!r}; expected true or false")


def _names(value: Any, key: str) -> list[str] | None:
    if value is None:
        return None
    if isinstance(value, (list, tuple)):
        return [str(v) for v in value]
    if isinstance(value, (str, int, float)):
        return [str(value)]
    raise ConfigError(f"{key} is {value!r}; expected a name or a list [a,b]")


def _fps(value: Any) -> float | None:
    from bench.logs.lerobot_info import MAX_FPS

    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise ConfigError(f"fps is {value!r}; expected a number in (0, {MAX_FPS}]")
    try:
        fps = float(value)
    except (TypeError, ValueError, OverflowError):
        raise ConfigError(f"fps is {value!r}; expected a number in (0, {MAX_FPS}]") from None
    if not 0 < fps <= MAX_FPS:
        raise ConfigError(f"fps is {value!r}; expected a number in (0, {MAX_FPS}]")
    return fps


def _text(value: Any, key: str, default: str | None) -> str | None:
    """A string key (task, robot_type, column names): a list or a map is refused, not stringified."""
    if value is None:
        return default
    if isinstance(value, (list, dict, tuple)) or isinstance(value, bool):
        raise ConfigError(f"{key} is {value!r}; expected a text value")
    return str(value)


def cmd_import(argv: list[str]) -> int:
    """`bench logs import SRC out=DIR [format=...] [key=value ...]`."""
    from bench.config import parse_kv
    from bench.logs import import_csv, import_mat, import_rlds, write_dataset

    positional, kv = parse_kv(argv)
    if len(positional) != 1:
        raise ConfigError(f"expected one source path, got {len(positional)}: bench logs import SRC out=DIR")
    src = Path(positional[0]).expanduser()
    fmt = _format_for(src, kv.get("format"))
    for key in kv:
        if key not in _KEYS[fmt]:
            raise ConfigError(
                f"unknown key {key!r} for format={fmt}; valid keys: {', '.join(_KEYS[fmt])}."
                f"{did_you_mean(key, _KEYS[fmt])}"
            )
    if not kv.get("out"):
        raise ConfigError("missing key 'out': bench logs import SRC out=DIR")
    fps, robot_type = _fps(kv.get("fps")), _text(kv.get("robot_type"), "robot_type", None)
    delimiter = _text(kv.get("delimiter"), "delimiter", ",")
    if delimiter is None or len(delimiter) != 1:
        raise ConfigError(f"delimiter is {delimiter!r}; expected one character (e.g. , or ; or a tab)")
    task = _text(kv.get("task"), "task", "default") or "default"
    if fmt == "csv":
        ds = import_csv(
            src,
            state=_names(kv.get("state"), "state"),
            action=_names(kv.get("action"), "action"),
            time=_text(kv.get("time"), "time", None),
            episode=_text(kv.get("episode"), "episode", None),
            task=task,
            delimiter=delimiter,
            fps=fps,
            robot_type=robot_type,
        )
    elif fmt == "mat":
        pairs = (("observation.state", "state"), ("action", "action"))
        mapping: dict[str, str | Sequence[str]] = {
            feature: names for feature, key in pairs if kv.get(key) and (names := _names(kv.get(key), key))
        }
        ds = import_mat(
            src,
            mapping or None,
            fps,
            time=_text(kv.get("time"), "time", None),
            velocity=_bool(kv.get("velocity", False), "velocity"),
            task=task,
            robot_type=robot_type,
        )
    else:
        ds = import_rlds(
            src,
            split=str(kv.get("split", "train")),
            state=str(kv.get("state", "observation/state")),
            action=str(kv.get("action", "action")),
            instruction=str(kv.get("instruction", "language_instruction")),
            task=task,
            fps=fps,
            robot_type=robot_type,
        )
    out = write_dataset(
        Path(str(kv["out"])).expanduser(),
        ds,
        overwrite=_bool(kv.get("overwrite", False), "overwrite"),
        inputs={"SRC": src},
    )
    print(f"wrote {out}: {len(ds.episodes)} episodes, {ds.num_frames} frames at {ds.fps:g} fps from {fmt} {src}")
    print(format_info(_info(out)))
    return 0


def _info(root: Path | str) -> dict:
    from bench.logs import info

    return info(root)


def format_info(summary: dict) -> str:
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
    lines.append(f"tasks     {len(summary['tasks'])}")
    for i, task in enumerate(summary["tasks"][:20]):
        lines.append(f"  {i:>3}  {task}")
    if len(summary["tasks"]) > 20:
        lines.append(f"  ... {len(summary['tasks']) - 20} more")
    return "\n".join(lines)


def cmd_info(argv: list[str]) -> int:
    """`bench logs info DIR`."""
    if len(argv) != 1 or "=" in argv[0]:
        raise ConfigError("expected one dataset folder: bench logs info DIR")
    print(format_info(_info(Path(argv[0]).expanduser())))
    return 0


def _eval_starts(suite_name: str, ds: Any, episodes: int, seed: int) -> dict:
    """Initial observations of a suite's evaluation for the cells the log's episodes name (task strings)."""
    import numpy as np

    from bench import api
    from bench.errors import DataError
    from bench.protocols import STATE
    from bench.suite import episode_seed

    suite = api.load_suite(suite_name)
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
    """A new output file (`bench.outputs`' rule: never an input or inside one; never over an existing file)."""
    from bench import outputs

    if value is None:
        return None
    return outputs.check(key, str(value), inputs, kind="file", can_overwrite=False)


def _dir_and_keys(argv: list[str], valid: tuple[str, ...], usage: str) -> tuple[Path, dict]:
    from bench.config import parse_kv

    positional, kv = parse_kv(argv)
    if len(positional) != 1:
        raise ConfigError(f"expected one dataset folder; {usage.splitlines()[0]}")
    for key in kv:
        if key not in valid:
            raise ConfigError(f"unknown key {key!r}; valid keys: {', '.join(valid)}.{did_you_mean(key, valid)}")
    return Path(positional[0]).expanduser(), kv


def _pos_number(kv: dict, key: str, default: float, integer: bool = False) -> Any:
    value = kv.get(key, default)
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0
    if not ok or (integer and not float(value).is_integer()):
        kind = "a non-negative integer" if integer else "a non-negative number"
        raise ConfigError(f"key {key!r} must be {kind}; got {value!r}")
    return int(value) if integer else float(value)


def cmd_card(argv: list[str]) -> int:
    """`bench logs card DIR ...`."""
    from bench.io import write_atomic
    from bench.logs import read_dataset
    from bench.logs.card import card, format_card

    root, kv = _dir_and_keys(argv, ("suite", "episodes", "seed", "dup_tol", "overlap_tol", "out"), CARD_USAGE)
    out = _new_file(kv.get("out"), "out", {"DIR": root})
    episodes, seed = _pos_number(kv, "episodes", 10, integer=True), _pos_number(kv, "seed", 0, integer=True)
    if episodes > 10_000:
        raise ConfigError(f"key 'episodes' is {episodes}; at most 10000 evaluation initial states per cell")
    tols = {k: _pos_number(kv, k, d) for k, d in (("dup_tol", 0.05), ("overlap_tol", 0.01))}
    if not root.exists():
        raise ConfigError(f"logs folder {str(root)!r} does not exist")
    ds = read_dataset(root)
    starts, where = None, ""
    if kv.get("suite") is not None:
        if episodes < 1:
            raise ConfigError("key 'episodes' must be at least 1 with suite=")
        starts = _eval_starts(str(kv["suite"]), ds, episodes, seed)
        where = f"suite {kv['suite']}: {episodes} evaluation episode(s) of run seed {seed} in {len(starts)} cell(s)"
    doc = card(ds, starts=starts, where=where, **tols)
    print(format_card(doc))
    if out is not None:
        write_atomic(out, doc)
        print(f"wrote {out}")
    return 0


def cmd_rank(argv: list[str]) -> int:
    """`bench logs rank DIR calibration=FILE ...`."""
    from bench.calibrate.rank import rank
    from bench.io import write_atomic

    root, kv = _dir_and_keys(argv, ("calibration", "horizon", "top", "out"), RANK_USAGE)
    if kv.get("calibration") in (None, ""):
        raise ConfigError("missing key 'calibration' (a `bench calibrate` output folder or its calibration.json)")
    out = _new_file(kv.get("out"), "out", {"DIR": root, "calibration": kv.get("calibration")})
    top = _pos_number(kv, "top", 10, integer=True)
    doc = rank(str(kv["calibration"]), root, str(kv.get("horizon", "free_run")))
    print(f"surprise = {doc['statistic']}; {len(doc['episodes'])} episodes, most first")
    print(f"{'rank':>4}  {'episode':>7}  {'frames':>6}  {'surprise':>9}  worst joint")
    for i, row in enumerate(doc["episodes"][:top]):
        joint, value = max(row["per_joint"].items(), key=lambda kv_: kv_[1])
        print(f"{i + 1:>4}  {row['episode']:>7}  {row['frames']:>6}  {row['surprise']:>9.4g}  {joint} ({value:.3g})")
    if out is not None:
        write_atomic(out, doc)
        print(f"wrote {out}")
    return 0


def main(argv: list[str]) -> int:
    """Dispatch `bench logs info|import|card|rank`."""
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(USAGE)
        return 0
    sub, rest = argv[0], argv[1:]
    commands = {
        "info": (cmd_info, INFO_USAGE),
        "import": (cmd_import, IMPORT_USAGE),
        "card": (cmd_card, CARD_USAGE),
        "rank": (cmd_rank, RANK_USAGE),
    }
    if sub not in commands:
        raise ConfigError(
            f"unknown logs subcommand {sub!r}; valid: {', '.join(commands)}.{did_you_mean(sub, commands)}"
        )
    handler, usage = commands[sub]
    if not rest or any(a in ("-h", "--help") for a in rest):
        print(usage)
        return 0
    return handler(rest)

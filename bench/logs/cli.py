"""`bench logs`: inspect LeRobot v3.0 datasets and import CSV / MAT / RLDS logs into one."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from bench.errors import ConfigError, did_you_mean

USAGE = """usage: bench logs info DIR
       bench logs import SRC out=DIR [format=csv|mat|rlds] [key=value ...]

Real-robot logs as LeRobot v3.0 datasets (parquet, read and written without pandas).

subcommands:
  info    episodes, frames, fps, features with shapes and tasks of a dataset folder
  import  convert a CSV file, a MATLAB .mat file or RLDS tfrecord shards to a dataset

`bench logs info --help` and `bench logs import --help` describe each.
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
    if value is None:
        return None
    try:
        fps = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"fps is {value!r}; expected a positive number") from None
    if not fps > 0:
        raise ConfigError(f"fps is {value!r}; expected a positive number")
    return fps


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
    common = {"fps": _fps(kv.get("fps")), "robot_type": kv.get("robot_type")}
    if fmt == "csv":
        ds = import_csv(
            src, state=_names(kv.get("state"), "state"), action=_names(kv.get("action"), "action"),
            time=kv.get("time"), episode=kv.get("episode"), task=str(kv.get("task", "default")),
            delimiter=str(kv.get("delimiter", ",")), **common,
        )
    elif fmt == "mat":
        pairs = (("observation.state", "state"), ("action", "action"))
        mapping = {feature: _names(kv.get(key), key) for feature, key in pairs if kv.get(key)}
        ds = import_mat(
            src, mapping or None, common["fps"], time=kv.get("time"),
            velocity=_bool(kv.get("velocity", False), "velocity"), task=str(kv.get("task", "default")),
            robot_type=common["robot_type"],
        )
    else:
        ds = import_rlds(
            src, split=str(kv.get("split", "train")), state=str(kv.get("state", "observation/state")),
            action=str(kv.get("action", "action")), instruction=str(kv.get("instruction", "language_instruction")),
            task=str(kv.get("task", "default")), **common,
        )
    out = write_dataset(Path(str(kv["out"])).expanduser(), ds, overwrite=_bool(kv.get("overwrite", False), "overwrite"))
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
            shown = (f"{video.get('codec') or '?'} {video.get('pix_fmt') or '?'}, {video.get('fps') or '?'} fps, "
                     f"{files} mp4 file{'s' if files != 1 else ''}")
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


def main(argv: list[str]) -> int:
    """Dispatch `bench logs info|import`."""
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(USAGE)
        return 0
    sub, rest = argv[0], argv[1:]
    commands = {"info": (cmd_info, INFO_USAGE), "import": (cmd_import, IMPORT_USAGE)}
    if sub not in commands:
        raise ConfigError(f"unknown logs subcommand {sub!r}; valid: info, import.{did_you_mean(sub, commands)}")
    handler, usage = commands[sub]
    if not rest or any(a in ("-h", "--help") for a in rest):
        print(usage)
        return 0
    return handler(rest)

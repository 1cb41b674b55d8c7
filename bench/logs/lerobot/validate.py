"""Validation of a LeRobot v3 `meta/info.json`: the reading side's first gate.

Split out of `bench.logs.lerobot` (reading/validation vs writing): every field the
readers use is checked here once, with one line naming the file, the field, what was
found and what is valid. The writer calls `check_fps` too, so a dataset bench writes
can always be read back.
"""

from __future__ import annotations

import math
import string
from pathlib import Path
from typing import TypeGuard

from bench.core.errors import DataError

MAX_FPS = 10_000.0  # frames per second; beyond this a value is a unit mistake, not a camera
MAX_DIM = 1 << 16  # one axis of a feature's shape
MAX_ELEMENTS = 1 << 28  # values per frame of one feature (an 8K RGB frame is ~1e8)
MAX_TOTAL = 10**12  # total_episodes / total_frames
DTYPES = (
    "bool",
    "int8",
    "int16",
    "int32",
    "int64",
    "uint8",
    "uint16",
    "uint32",
    "uint64",
    "float16",
    "float32",
    "float64",
    "string",
    "image",
    "video",
)
PATH_KEYS = {"data_path": {"chunk_index", "file_index"}, "video_path": {"video_key", "chunk_index", "file_index"}}


def _is_number(v: object) -> TypeGuard[int | float]:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def check_fps(fps: object, where: str) -> float:
    """A frame rate: a finite number in (0, MAX_FPS]; booleans and strings are not numbers."""
    if not _is_number(fps) or not math.isfinite(fps) or not 0 < fps <= MAX_FPS:
        raise DataError(f"{where}: field 'fps' is {fps!r:.40}; valid: a number in (0, {MAX_FPS:g}]")
    return float(fps)


def _check_path_template(info: dict, key: str, path: Path) -> None:
    tpl = info.get(key)
    if tpl is None and key == "video_path":
        return
    if not isinstance(tpl, str):
        raise DataError(f"{path}: field {key!r} is {tpl!r:.60}; valid: a path template string")
    try:
        names = {f[1].split(".")[0].split("[")[0] for f in string.Formatter().parse(tpl) if f[1] is not None}
    except ValueError as exc:
        raise DataError(f"{path}: field {key!r} is {tpl!r:.80}: {exc}") from None
    if names - PATH_KEYS[key]:
        raise DataError(
            f"{path}: field {key!r} uses {', '.join(sorted(names - PATH_KEYS[key]))}; valid "
            f"placeholders: {', '.join(sorted(PATH_KEYS[key]))}"
        )
    parts = Path(tpl).parts
    if tpl.startswith("/") or ".." in parts or "\\" in tpl:
        raise DataError(f"{path}: field {key!r} is {tpl!r:.80}; valid: a relative path inside the dataset")
    try:
        tpl.format(chunk_index=0, file_index=0, video_key="k")
    except (ValueError, IndexError, KeyError, TypeError) as exc:
        raise DataError(f"{path}: field {key!r} is {tpl!r:.80}: {exc}") from None


def _check_feature(name: str, feat: object, path: Path) -> None:
    where = f"{path}: field 'features.{name}"
    if not isinstance(feat, dict):
        raise DataError(f"{where}' is {feat!r:.60}; valid: an object with dtype and shape")
    dtype = feat.get("dtype")
    if dtype not in DTYPES:
        raise DataError(f"{where}.dtype' is {dtype!r:.40}; valid: {', '.join(DTYPES)}")
    shape = feat.get("shape")
    if (
        not isinstance(shape, list)
        or not shape
        or not all(isinstance(s, int) and not isinstance(s, bool) and 0 < s <= MAX_DIM for s in shape)
    ):
        raise DataError(f"{where}.shape' is {shape!r:.60}; valid: a non-empty list of integers in [1, {MAX_DIM}]")
    if math.prod(shape) > MAX_ELEMENTS:
        raise DataError(f"{where}.shape' is {shape}: {math.prod(shape)} values per frame; at most {MAX_ELEMENTS}")
    names = feat.get("names")
    if names is not None and not isinstance(names, (list, dict)):
        raise DataError(f"{where}.names' is {names!r:.40}; valid: a list, an object or null")


def check_info(info: object, path: Path, required: tuple[str, ...]) -> dict:
    """Validate a decoded info.json; returns it unchanged.

    Raises:
        DataError: one line naming `path`, the field, what was found and what is valid.
    """
    if not isinstance(info, dict):
        raise DataError(f"{path}: top level is a JSON {type(info).__name__}; valid: an object")
    for key in required:
        if key not in info:
            raise DataError(f"{path}: field {key!r} is missing")
    version = info["codebase_version"]
    if not isinstance(version, str) or not version.startswith("v3."):
        raise DataError(
            f"{path}: field 'codebase_version' is {version!r:.40}; only LeRobot v3.x datasets are supported"
        )
    check_fps(info["fps"], str(path))
    for key in ("total_episodes", "total_frames", "total_tasks"):
        v = info.get(key, 0)
        if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v <= MAX_TOTAL:
            raise DataError(f"{path}: field {key!r} is {v!r:.40}; valid: an integer in [0, {MAX_TOTAL}]")
    robot = info.get("robot_type")
    if robot is not None and not isinstance(robot, str):
        raise DataError(f"{path}: field 'robot_type' is {robot!r:.40}; valid: a string or null")
    _check_path_template(info, "data_path", path)
    _check_path_template(info, "video_path", path)
    feats = info["features"]
    if not isinstance(feats, dict):
        raise DataError(f"{path}: field 'features' is a JSON {type(feats).__name__}; valid: an object")
    for name, feat in feats.items():
        _check_feature(name, feat, path)
    return info

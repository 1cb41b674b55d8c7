"""The metadata side of a LeRobot v3.0 dataset: layout constants, info.json, tasks and the episodes table.

`load_index` reads everything a reader needs before touching frames (one `Index`, cached while
the metadata files are unchanged); `info` summarises a dataset from it. The parquet helpers here
(`open_parquet`, `read_arrow`, `location`) turn pyarrow's errors into one-line `DataError`s
naming the file, for the frame reader (`bench.logs.lerobot.read`) as well.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import ParamSpec, TypeVar

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from bench.core.errors import DataError
from bench.logs.dataset import DEFAULT_FEATURES, first_bad_row
from bench.logs.lerobot.validate import check_info

P = ParamSpec("P")
T = TypeVar("T")

CODEBASE_VERSION = "v3.0"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
EPISODES_DIR = "meta/episodes"
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
VIDEO_COLUMNS = ("chunk_index", "file_index", "from_timestamp", "to_timestamp")  # videos/<key>/<column>
CHUNKS_SIZE = 1000
DATA_FILES_SIZE_IN_MB = 100
VIDEO_FILES_SIZE_IN_MB = 200
META_COLUMN = "bench/meta"
# info.json keys, in lerobot's order; the reader needs the first group, lerobot needs all of them.
REQUIRED_INFO_KEYS = ("codebase_version", "fps", "features", "total_episodes", "total_frames", "data_path")
INFO_KEYS = (
    "codebase_version",
    "robot_type",
    "total_episodes",
    "total_frames",
    "total_tasks",
    "chunks_size",
    "data_files_size_in_mb",
    "video_files_size_in_mb",
    "fps",
    "splits",
    "data_path",
    "video_path",
    "features",
)
EPISODE_COLUMNS = (
    "episode_index",
    "tasks",
    "length",
    "data/chunk_index",
    "data/file_index",
    "dataset_from_index",
    "dataset_to_index",
)


@dataclass
class Index:
    """What a reader needs before touching frames: info, tasks and the episode table."""

    root: Path
    info: dict
    features: dict[str, dict]  # non-video features (the parquet columns), in info.json order
    videos: dict[str, dict]  # video features, in info.json order
    video_index: dict[str, dict[str, np.ndarray]]  # per video feature: VIDEO_COLUMNS, by episode
    tasks: list[str]
    episodes_file: str  # relative path of the first episodes file (for messages)
    episode_index: np.ndarray
    length: np.ndarray
    chunk: np.ndarray
    file: np.ndarray
    start: np.ndarray  # dataset_from_index
    stop: np.ndarray  # dataset_to_index
    base: np.ndarray  # dataset_from_index of the first row of the episode's data file
    order: np.ndarray  # episode e's row in the episodes file(s) (rows may be in any order)
    raw_tasks: pa.ChunkedArray  # per row: the episode's task strings
    raw_meta: pa.ChunkedArray | None  # per row: bench's JSON metadata, if the column exists

    def data_file(self, e: int) -> str:
        return self.info["data_path"].format(chunk_index=int(self.chunk[e]), file_index=int(self.file[e]))

    def video_file(self, key: str, e: int) -> str:
        cols = self.video_index[key]
        return str(self.info["video_path"]).format(
            video_key=key, chunk_index=int(cols["chunk_index"][e]), file_index=int(cols["file_index"][e])
        )

    def episode_tasks(self, e: int) -> list[str]:
        """Task strings of episode e (parsed on demand: opening a dataset stays cheap)."""
        return list(self.raw_tasks[int(self.order[e])].as_py() or [])

    def episode_meta(self, e: int) -> dict:
        """bench's per-episode metadata of episode e ({} for datasets written by other tools)."""
        raw = None if self.raw_meta is None else self.raw_meta[int(self.order[e])].as_py()
        try:
            meta = json.loads(raw) if raw else {}
        except json.JSONDecodeError:
            meta = None
        if not isinstance(meta, dict):
            where = location(self.root, self.episodes_file)
            raise DataError(f"{where}: column {META_COLUMN!r} is not a JSON object for episode {e}")
        return meta


_INDEX_CACHE: dict[Path, tuple[tuple, Index]] = {}


def stamp(paths: list[Path]) -> tuple:
    """Identity of a set of files for caching: (mtime_ns, size) of each."""
    out = []
    for p in paths:
        st = p.stat()
        out.append((str(p), st.st_mtime_ns, st.st_size))
    return tuple(out)


def _rel(root: Path, path: Path) -> str:
    try:
        return str(path.relative_to(root))
    except ValueError:
        return str(path)


def location(root: Path, rel: str) -> str:
    """A file of the dataset as messages name it."""
    return str(root / rel)


def open_parquet(root: Path, rel: str) -> pq.ParquetFile:
    """Open a parquet file; a missing or unreadable (e.g. truncated) file is a one-line DataError."""
    path = root / rel
    if not path.is_file():
        raise DataError(f"{location(root, rel)}: file is missing")
    try:
        return pq.ParquetFile(path)
    except (pa.ArrowException, OSError) as exc:
        raise DataError(f"{location(root, rel)}: not a readable parquet file (truncated?): {first_line(exc)}") from None


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message (its type name if it has none)."""
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def read_arrow(root: Path, rel: str, fn: Callable[P, T], *args: P.args, **kwargs: P.kwargs) -> T:
    """Run a pyarrow read, turning its errors into a DataError naming the file."""
    try:
        return fn(*args, **kwargs)
    except (pa.ArrowException, OSError) as exc:
        reason = first_line(exc)
        raise DataError(f"{location(root, rel)}: cannot read parquet data (truncated or corrupt?): {reason}") from None


def _load_info(root: Path) -> dict:
    path = root / INFO_PATH
    if not root.is_dir():
        raise DataError(f"{root}: dataset folder does not exist")
    if not path.is_file():
        raise DataError(f"{path}: file is missing (not a LeRobot v3.0 dataset?)")
    try:
        info = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError) as exc:  # ValueError: bad JSON, non-UTF-8
        raise DataError(f"{path}: not valid JSON: {first_line(exc)}") from None
    check_info(info, path, REQUIRED_INFO_KEYS)
    feats = info["features"]
    for name in DEFAULT_FEATURES:
        if name not in feats:
            raise DataError(f"{path}: field 'features' lacks the default feature {name!r}")
    return info


def _load_tasks(root: Path) -> list[str]:
    pf = open_parquet(root, TASKS_PATH)
    table = read_arrow(root, TASKS_PATH, pf.read)
    names = table.column_names
    if "task_index" not in names:
        raise DataError(f"{location(root, TASKS_PATH)}: column 'task_index' is missing")
    text_col: str | None
    if "task" in names:
        text_col = "task"
    else:
        meta = (table.schema.metadata or {}).get(b"pandas")
        index_cols = json.loads(meta).get("index_columns", []) if meta else []
        text_col = next((c for c in index_cols if isinstance(c, str) and c in names), None)
        if text_col is None:
            raise DataError(f"{location(root, TASKS_PATH)}: no task string column ('task' or a pandas index column)")
    idx = table.column("task_index").to_numpy()
    text = table.column(text_col).to_pylist()
    if sorted(idx.tolist()) != list(range(len(idx))):
        found = sorted(idx.tolist())
        raise DataError(f"{location(root, TASKS_PATH)}: column 'task_index' is not 0..{len(idx) - 1}: {found}")
    tasks = [""] * len(idx)
    for i, t in zip(idx.tolist(), text):
        tasks[i] = t
    return tasks


def _episode_files(root: Path) -> list[str]:
    folder = root / EPISODES_DIR
    files = sorted(folder.glob("chunk-*/file-*.parquet")) if folder.is_dir() else []
    if not files:
        raise DataError(f"{root / EPISODES_PATH.format(chunk_index=0, file_index=0)}: file is missing")
    return [_rel(root, f) for f in files]


def _load_episodes(root: Path, rels: list[str], videos: list[str]) -> dict[str, pa.ChunkedArray | None]:
    """The episode table's columns over all episodes files, as arrow columns (no per-row Python objects)."""
    required = list(EPISODE_COLUMNS) + [f"videos/{k}/{c}" for k in videos for c in VIDEO_COLUMNS]
    parts: dict[str, list] = {c: [] for c in (*required, META_COLUMN)}
    for rel in rels:
        pf = open_parquet(root, rel)
        present = pf.schema_arrow.names
        for c in required:
            if c not in present:
                raise DataError(f"{location(root, rel)}: column {c!r} is missing")
        wanted = required + ([META_COLUMN] if META_COLUMN in present else [])
        table = read_arrow(root, rel, pf.read, columns=wanted, use_threads=False)
        for c in wanted:
            parts[c].append(table.column(c))
        if META_COLUMN not in present:
            parts[META_COLUMN].append(pa.chunked_array([pa.nulls(len(table), pa.string())]))
    cols: dict[str, pa.ChunkedArray | None] = {}
    for c, columns in parts.items():
        try:
            cols[c] = pa.chunked_array([chunk for col in columns for chunk in col.chunks], type=columns[0].type)
        except (pa.ArrowException, TypeError):  # files disagree on a column's type: fall back to Python values
            cols[c] = pa.chunked_array([pa.array([v for col in columns for v in col.to_pylist()])])
    return cols


def _build_index(root: Path) -> Index:
    info = _load_info(root)
    tasks = _load_tasks(root)
    rels = _episode_files(root)
    videos = {k: v for k, v in info["features"].items() if v["dtype"] == "video"}
    if videos and not isinstance(info.get("video_path"), str):
        raise DataError(
            f"{root / INFO_PATH}: field 'video_path' is {info.get('video_path')!r} but features "
            f"{', '.join(videos)} are videos; expected a template like {VIDEO_PATH!r}"
        )
    for key, feat in videos.items():
        if len(feat["shape"]) != 3 or feat["shape"][2] != 3:
            raise DataError(
                f"{root / INFO_PATH}: field 'features.{key}' is a video of shape {feat['shape']}; "
                f"expected [height, width, 3]"
            )
    cols = _load_episodes(root, rels, list(videos))
    where = location(root, rels[0])

    def ints(name: str) -> np.ndarray:
        column = cols[name]
        try:
            if column is None or column.null_count or not pa.types.is_integer(column.type):
                raise ValueError
            return np.asarray(column.to_numpy(), dtype=np.int64)
        except (TypeError, ValueError, pa.ArrowException):
            raise DataError(f"{where}: column {name!r} has missing or non-integer values") from None

    ep = ints("episode_index")
    order = np.argsort(ep, kind="stable")
    ep = ep[order]
    n = len(ep)
    expected = np.arange(n)
    if n == 0:
        raise DataError(f"{where}: no episodes")
    if not np.array_equal(ep, expected):
        bad = first_bad_row(ep != expected)
        raise DataError(
            f"{where}: column 'episode_index' has a gap or repeat: expected episode {bad}, found {int(ep[bad])} "
            f"(episode indices must be 0..N-1)"
        )
    if int(info["total_episodes"]) != n:
        raise DataError(f"{root / INFO_PATH}: field 'total_episodes' is {info['total_episodes']} but {where} lists {n}")

    def col(name: str) -> np.ndarray:
        return ints(name)[order]

    length, start, stop = col("length"), col("dataset_from_index"), col("dataset_to_index")
    bad = first_bad_row((stop - start != length) | (length <= 0))
    if bad >= 0:
        raise DataError(
            f"{where}: column 'length' is {int(length[bad])} for episode {bad} but dataset_to_index - "
            f"dataset_from_index is {int(stop[bad] - start[bad])}"
        )
    if int(length.sum()) != int(info["total_frames"]):
        total = int(length.sum())
        declared = info["total_frames"]
        raise DataError(f"{root / INFO_PATH}: field 'total_frames' is {declared} but the episodes sum to {total}")
    features = {k: v for k, v in info["features"].items() if v["dtype"] != "video"}
    video_index: dict[str, dict[str, np.ndarray]] = {}
    for key in videos:
        video_index[key] = {c: col(f"videos/{key}/{c}") for c in VIDEO_COLUMNS[:2]}
        for c in VIDEO_COLUMNS[2:]:
            column = cols[f"videos/{key}/{c}"]
            if (
                column is None
                or column.null_count
                or not (pa.types.is_floating(column.type) or pa.types.is_integer(column.type))
            ):
                raise DataError(f"{where}: column 'videos/{key}/{c}' has missing or non-numeric values")
            video_index[key][c] = np.asarray(column.to_numpy(), dtype=np.float64)[order]
    chunk, file = col("data/chunk_index"), col("data/file_index")
    for name, values in [
        ("data/chunk_index", chunk),
        ("data/file_index", file),
        *[(f"videos/{k}/{c}", v) for k, vi in video_index.items() for c, v in vi.items()],
    ]:
        bad = first_bad_row(values < 0)
        if bad >= 0:
            raise DataError(f"{where}: column {name!r} is {values[bad]} for episode {bad}; valid: an index >= 0")
    ttype = cols["tasks"].type if cols["tasks"] is not None else None
    if ttype is not None and not (
        (pa.types.is_list(ttype) or pa.types.is_large_list(ttype))
        and (pa.types.is_string(ttype.value_type) or pa.types.is_large_string(ttype.value_type))
    ):
        raise DataError(f"{where}: column 'tasks' has type {ttype}; valid: a list of task strings")
    base = start.copy()
    for key in set(zip(chunk.tolist(), file.tolist())):
        members = (chunk == key[0]) & (file == key[1])
        base[members] = start[members].min()
    return Index(
        root=root,
        info=info,
        features=features,
        videos=videos,
        video_index=video_index,
        tasks=tasks,
        episodes_file=rels[0],
        episode_index=ep,
        length=length,
        chunk=chunk,
        file=file,
        start=start,
        stop=stop,
        base=base,
        order=order,
        raw_tasks=cols["tasks"],
        raw_meta=cols[META_COLUMN],
    )


def load_index(root: str | os.PathLike) -> Index:
    """The dataset's metadata, cached while info.json, tasks and the episodes files are unchanged."""
    root = Path(root).resolve()
    meta_files = [root / INFO_PATH, root / TASKS_PATH]
    folder = root / EPISODES_DIR
    if folder.is_dir():
        meta_files += sorted(folder.glob("chunk-*/file-*.parquet"))
    try:
        key = stamp(meta_files)
    except OSError:
        return _build_index(root)  # something is missing: let the builder name it
    hit = _INDEX_CACHE.get(root)
    if hit is not None and hit[0] == key:
        return hit[1]
    idx = _build_index(root)
    if len(_INDEX_CACHE) > 16:
        _INDEX_CACHE.clear()
    _INDEX_CACHE[root] = (key, idx)
    return idx


def info(root: str | os.PathLike) -> dict:
    """Summary of a dataset from its metadata only (no frames are read).

    Returns:
        {"root", "codebase_version", "robot_type", "fps", "episodes", "frames", "features":
        {name: {"dtype", "shape", "names"}}, "tasks": [...], "lengths": {"min", "max", "mean"}}.
        Video features also carry "video": {"codec", "pix_fmt", "fps", "files"} (from info.json's
        `info` entry and the episodes table).
    """
    idx = load_index(root)
    return {
        "root": str(idx.root),
        "codebase_version": idx.info["codebase_version"],
        "robot_type": idx.info.get("robot_type"),
        "fps": idx.info["fps"],
        "episodes": len(idx.episode_index),
        "frames": int(idx.length.sum()),
        "features": {k: _feature_summary(idx, k, v) for k, v in idx.info["features"].items()},
        "tasks": list(idx.tasks),
        "lengths": {"min": int(idx.length.min()), "max": int(idx.length.max()), "mean": float(idx.length.mean())},
    }


def _feature_summary(idx: Index, name: str, feat: dict) -> dict:
    out = {"dtype": feat["dtype"], "shape": list(feat["shape"]), "names": feat.get("names")}
    if feat["dtype"] == "video":
        raw = feat.get("info")
        vinfo: dict = raw if isinstance(raw, dict) else {}
        cols = idx.video_index[name]
        files = len(set(zip(cols["chunk_index"].tolist(), cols["file_index"].tolist())))
        out["video"] = {
            "codec": vinfo.get("video.codec"),
            "pix_fmt": vinfo.get("video.pix_fmt"),
            "fps": vinfo.get("video.fps"),
            "files": files,
        }
    return out


def forget_index(root: Path) -> None:
    """Drop the cached index of `root` (a writer has just replaced the folder)."""
    _INDEX_CACHE.pop(root, None)

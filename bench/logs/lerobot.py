"""LeRobot v3.0 datasets read and written with pyarrow alone (no pandas, no lerobot).

On-disk layout (as written by lerobot 0.4.x):

    meta/info.json                                  fps, features, totals, path templates
    meta/stats.json                                 per-feature min/max/mean/std/count/q01..q99
    meta/tasks.parquet                              task_index + the task string as a pandas index
    meta/episodes/chunk-000/file-000.parquet        one row per episode: length, data file, row range
    data/chunk-000/file-000.parquet                 the frames, one row group per episode
    videos/<key>/chunk-000/file-000.mp4             video features: episodes one after another

Camera streams are either images, PNG bytes inside the parquet (`struct<bytes, path>`), or
videos: one MP4 stream per feature and file, episodes concatenated, frame k of an episode shown
at `from_timestamp + timestamp[k]` (the episodes table holds `videos/<key>/chunk_index`,
`file_index`, `from_timestamp`, `to_timestamp`; info.json the codec in the feature's `info`).
Video features have no parquet column. Both are decoded to (T, H, W, C) uint8 with PyAV
(`bench.video`): no torchvision, no torchcodec. The writer encodes H.264 by default (AV1 on
request, lerobot's own default). Per-episode metadata of ours (`Episode.meta`) travels as a JSON
string column `bench/meta` in the episodes file, which lerobot ignores.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import tempfile
import uuid
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from bench.errors import DataError
from bench.logs.dataset import (
    DEFAULT_FEATURES,
    FRAME_COLUMNS,
    Episode,
    LogDataset,
    first_bad_row,
    is_image,
    validate,
)
from bench.logs.lerobot_info import MAX_FPS, check_fps, check_info  # noqa: F401  (MAX_FPS: the bound importers share)

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
STAT_NAMES = ("min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99")
QUANTILES = {"q01": 0.01, "q10": 0.10, "q50": 0.50, "q90": 0.90, "q99": 0.99}
# pandas reads `__index_level_0__` back as the index only with this schema metadata; lerobot
# looks tasks up by that index (the task string), so without it tasks come back as integers.
_PANDAS_TASKS_META = {
    "index_columns": ["__index_level_0__"],
    "column_indexes": [
        {
            "name": None,
            "field_name": None,
            "pandas_type": "unicode",
            "numpy_type": "str",
            "metadata": {"encoding": "UTF-8"},
        }
    ],
    "columns": [
        {
            "name": "task_index",
            "field_name": "task_index",
            "pandas_type": "int64",
            "numpy_type": "int64",
            "metadata": None,
        },
        {
            "name": None,
            "field_name": "__index_level_0__",
            "pandas_type": "object",
            "numpy_type": "str",
            "metadata": None,
        },
    ],
    "attributes": {},
    "creator": {"library": "pyarrow", "version": pa.__version__},
    "pandas_version": "2.2.3",
}


# ----------------------------------------------------------------------------- reading: metadata


@dataclass
class _Index:
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
            where = _where(self.root, self.episodes_file)
            raise DataError(f"{where}: column {META_COLUMN!r} is not a JSON object for episode {e}")
        return meta


_INDEX_CACHE: dict[Path, tuple[tuple, _Index]] = {}
_FOOTER_CACHE: dict[Path, tuple[tuple, pq.FileMetaData, np.ndarray]] = {}


def _stamp(paths: list[Path]) -> tuple:
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


def _where(root: Path, rel: str) -> str:
    return str(root / rel)


def _parquet_file(root: Path, rel: str) -> pq.ParquetFile:
    """Open a parquet file; a missing or unreadable (e.g. truncated) file is a one-line DataError."""
    path = root / rel
    if not path.is_file():
        raise DataError(f"{_where(root, rel)}: file is missing")
    try:
        return pq.ParquetFile(path)
    except (pa.ArrowException, OSError) as exc:
        raise DataError(f"{_where(root, rel)}: not a readable parquet file (truncated?): {_first_line(exc)}") from None


def _footer(root: Path, rel: str) -> tuple[pq.ParquetFile, np.ndarray]:
    """A data file opened with its cached footer, and the first row of each row group (plus the total)."""
    path = root / rel
    if not path.is_file():
        raise DataError(f"{_where(root, rel)}: file is missing")
    key = _stamp([path])
    hit = _FOOTER_CACHE.get(path)
    if hit is None or hit[0] != key:
        try:
            md = pq.read_metadata(path)
        except (pa.ArrowException, OSError) as exc:
            reason = _first_line(exc)
            raise DataError(f"{_where(root, rel)}: not a readable parquet file (truncated?): {reason}") from None
        sizes = [md.row_group(g).num_rows for g in range(md.num_row_groups)]
        hit = (key, md, np.concatenate([[0], np.cumsum(sizes, dtype=np.int64)]))
        if len(_FOOTER_CACHE) > 256:
            _FOOTER_CACHE.clear()
        _FOOTER_CACHE[path] = hit
    return pq.ParquetFile(path, metadata=hit[1]), hit[2]


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def _read(root: Path, rel: str, fn, *args, **kwargs):
    """Run a pyarrow read, turning its errors into a DataError naming the file."""
    try:
        return fn(*args, **kwargs)
    except (pa.ArrowException, OSError) as exc:
        reason = _first_line(exc)
        raise DataError(f"{_where(root, rel)}: cannot read parquet data (truncated or corrupt?): {reason}") from None


def _load_info(root: Path) -> dict:
    path = root / INFO_PATH
    if not root.is_dir():
        raise DataError(f"{root}: dataset folder does not exist")
    if not path.is_file():
        raise DataError(f"{path}: file is missing (not a LeRobot v3.0 dataset?)")
    try:
        info = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError) as exc:  # ValueError: bad JSON, non-UTF-8
        raise DataError(f"{path}: not valid JSON: {_first_line(exc)}") from None
    check_info(info, path, REQUIRED_INFO_KEYS)
    feats = info["features"]
    for name in DEFAULT_FEATURES:
        if name not in feats:
            raise DataError(f"{path}: field 'features' lacks the default feature {name!r}")
    return info


def _load_tasks(root: Path) -> list[str]:
    pf = _parquet_file(root, TASKS_PATH)
    table = _read(root, TASKS_PATH, pf.read)
    names = table.column_names
    if "task_index" not in names:
        raise DataError(f"{_where(root, TASKS_PATH)}: column 'task_index' is missing")
    text_col: str | None
    if "task" in names:
        text_col = "task"
    else:
        meta = (table.schema.metadata or {}).get(b"pandas")
        index_cols = json.loads(meta).get("index_columns", []) if meta else []
        text_col = next((c for c in index_cols if isinstance(c, str) and c in names), None)
        if text_col is None:
            raise DataError(f"{_where(root, TASKS_PATH)}: no task string column ('task' or a pandas index column)")
    idx = table.column("task_index").to_numpy()
    text = table.column(text_col).to_pylist()
    if sorted(idx.tolist()) != list(range(len(idx))):
        found = sorted(idx.tolist())
        raise DataError(f"{_where(root, TASKS_PATH)}: column 'task_index' is not 0..{len(idx) - 1}: {found}")
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
        pf = _parquet_file(root, rel)
        present = pf.schema_arrow.names
        for c in required:
            if c not in present:
                raise DataError(f"{_where(root, rel)}: column {c!r} is missing")
        wanted = required + ([META_COLUMN] if META_COLUMN in present else [])
        table = _read(root, rel, pf.read, columns=wanted, use_threads=False)
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


def _build_index(root: Path) -> _Index:
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
    where = _where(root, rels[0])

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
    return _Index(
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


def _index(root: str | os.PathLike) -> _Index:
    """The dataset's metadata, cached while info.json, tasks and the episodes files are unchanged."""
    root = Path(root).resolve()
    meta_files = [root / INFO_PATH, root / TASKS_PATH]
    folder = root / EPISODES_DIR
    if folder.is_dir():
        meta_files += sorted(folder.glob("chunk-*/file-*.parquet"))
    try:
        key = _stamp(meta_files)
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
    idx = _index(root)
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


def _feature_summary(idx: _Index, name: str, feat: dict) -> dict:
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


# ----------------------------------------------------------------------------- reading: frames


def _column_to_numpy(arr: pa.Array, name: str, feature: dict, root: Path, rel: str) -> np.ndarray:
    """A parquet column as a (rows, *shape) array ((rows,) for the default columns)."""
    where = _where(root, rel)
    if arr.null_count:
        raise DataError(f"{where}: column {name!r} has {arr.null_count} missing values")
    if feature["dtype"] == "image":
        return _decode_images(arr, name, feature, root, rel)
    shape = tuple(feature["shape"])
    rows = len(arr)
    values = arr
    depth = 0
    while isinstance(values, (pa.ListArray, pa.LargeListArray, pa.FixedSizeListArray)):
        if depth >= len(shape):
            raise DataError(f"{where}: column {name!r} is nested deeper than its declared shape {list(shape)}")
        if not pa.types.is_fixed_size_list(values.type):
            lengths = values.value_lengths().to_numpy(zero_copy_only=False)
            if lengths.size and (lengths.min() != shape[depth] or lengths.max() != shape[depth]):
                got = int(lengths[lengths != shape[depth]][0])
                raise DataError(
                    f"{where}: column {name!r} has {got} values per frame but {INFO_PATH} declares shape {list(shape)}"
                )
        elif values.type.list_size != shape[depth]:
            raise DataError(
                f"{where}: column {name!r} has {values.type.list_size} values per frame but {INFO_PATH} "
                f"declares shape {list(shape)}"
            )
        values = values.flatten()
        depth += 1
    if depth == 0 and shape != (1,):
        raise DataError(f"{where}: column {name!r} holds scalars but {INFO_PATH} declares shape {list(shape)}")
    if depth not in (0, len(shape)):
        raise DataError(f"{where}: column {name!r} is nested {depth} deep but {INFO_PATH} declares shape {list(shape)}")
    if not (pa.types.is_integer(values.type) or pa.types.is_floating(values.type) or pa.types.is_boolean(values.type)):
        raise DataError(f"{where}: column {name!r} has type {values.type}, expected {feature['dtype']}")
    if values.null_count:
        raise DataError(f"{where}: column {name!r} has missing values inside its lists")
    out = values.to_numpy(zero_copy_only=False)
    want = np.dtype(feature["dtype"]) if name not in FRAME_COLUMNS else np.dtype(DEFAULT_FEATURES[name]["dtype"])
    if out.dtype != want:
        if out.dtype.kind == "f" and want.kind in "iub":
            raise DataError(f"{where}: column {name!r} has type {values.type}, expected {feature['dtype']}")
        out = out.astype(want)
    if name in FRAME_COLUMNS or name == "episode_index":
        return out.reshape(rows)
    return out.reshape((rows,) + shape)


def _decode_images(arr: pa.Array, name: str, feature: dict, root: Path, rel: str) -> np.ndarray:
    from PIL import Image

    where = _where(root, rel)
    if not pa.types.is_struct(arr.type) or arr.type.get_field_index("bytes") < 0:
        raise DataError(f"{where}: image column {name!r} has type {arr.type}, expected struct<bytes, path>")
    shape = tuple(feature["shape"])
    blobs = arr.field("bytes").to_pylist()
    paths = arr.field("path").to_pylist() if arr.type.get_field_index("path") >= 0 else [None] * len(blobs)
    out = np.empty((len(blobs),) + shape, dtype=np.uint8)
    for i, (blob, path) in enumerate(zip(blobs, paths)):
        try:
            img: Image.Image = Image.open(io.BytesIO(blob) if blob is not None else root / str(path))
            if shape[-1] == 3 and img.mode != "RGB":
                img = img.convert("RGB")
            pix = np.asarray(img)
        except Exception as exc:  # Pillow raises many kinds
            raise DataError(f"{where}: image column {name!r} row {i} cannot be decoded: {_first_line(exc)}") from None
        if pix.ndim == 2:
            pix = pix[:, :, None]
        if pix.shape != shape:
            raise DataError(
                f"{where}: image column {name!r} row {i} has shape {pix.shape} but {INFO_PATH} declares {list(shape)}"
            )
        out[i] = pix
    return out


def _check_schema(idx: _Index, rel: str, pf: pq.ParquetFile) -> list[str]:
    """The columns to read from a data file; every declared column must be there and no other."""
    names = pf.schema_arrow.names
    for name in names:
        if name not in idx.info["features"]:
            raise DataError(f"{_where(idx.root, rel)}: column {name!r} is not declared in {INFO_PATH} features")
    for name in idx.features:
        if name not in names:
            raise DataError(f"{_where(idx.root, rel)}: column {name!r} declared in {INFO_PATH} is missing")
    return list(idx.features)


def _table_columns(idx: _Index, rel: str, table: pa.Table) -> dict[str, np.ndarray]:
    out = {}
    for name, feat in idx.features.items():
        col = table.column(name)
        arr = col.chunk(0) if col.num_chunks == 1 else col.combine_chunks()
        out[name] = _column_to_numpy(arr, name, feat, idx.root, rel)
    return out


def _check_rows(idx: _Index, rel: str, cols: dict[str, np.ndarray], eps: np.ndarray, offsets: np.ndarray) -> None:
    """Validate rows of one file holding episodes `eps`, episode k at rows offsets[k]:offsets[k+1]."""
    where = _where(idx.root, rel)
    lengths = np.diff(offsets)
    expected = np.repeat(eps, lengths)
    got = cols["episode_index"]
    row = first_bad_row(got != expected)
    if row >= 0:
        k = int(np.searchsorted(offsets, row, side="right") - 1)
        raise DataError(
            f"{where}: column 'episode_index' is {int(got[row])} at frame {row - int(offsets[k])} of episode "
            f"{int(eps[k])} ({idx.episodes_file} places that episode there)"
        )
    task = cols["task_index"]
    row = first_bad_row((task < 0) | (task >= len(idx.tasks)))
    if row >= 0:
        k = int(np.searchsorted(offsets, row, side="right") - 1)
        raise DataError(
            f"{where}: column 'task_index' is {int(task[row])} in episode {int(eps[k])} at frame "
            f"{row - int(offsets[k])} but {TASKS_PATH} has {len(idx.tasks)} tasks"
        )
    starts = offsets[:-1]
    for name, arr in cols.items():
        if arr.dtype.kind == "f":
            row = first_bad_row(~np.isfinite(arr))
            if row >= 0:
                k = int(np.searchsorted(offsets, row, side="right") - 1)
                raise DataError(
                    f"{where}: column {name!r} has NaN or inf in episode {int(eps[k])} at frame {row - int(offsets[k])}"
                )
        if name == "timestamp" and len(arr) > 1:
            bad = np.diff(arr) <= 0
            bad[starts[1:] - 1] = False  # the step into the next episode is not a step in time
            row = first_bad_row(bad)
            if row >= 0:
                k = int(np.searchsorted(offsets, row + 1, side="right") - 1)
                raise DataError(
                    f"{where}: column 'timestamp' is not increasing in episode {int(eps[k])} at frame "
                    f"{row + 1 - int(offsets[k])}"
                )


def _read_videos(idx: _Index, eps: np.ndarray, offsets: np.ndarray, timestamps: np.ndarray) -> dict[str, np.ndarray]:
    """Frames of every video feature for episodes `eps` (rows offsets[k]:offsets[k+1] of `timestamps`).

    Frame j of episode e is the one shown at `from_timestamp[e] + timestamp[j]` in its MP4 file
    (within `bench.video.TOLERANCE_S`, lerobot's default tolerance). Each file is decoded once,
    forward from the keyframe before the first frame wanted.
    """
    from bench.video import VideoError, decode_frames

    out: dict[str, np.ndarray] = {}
    for key, feat in idx.videos.items():
        shape = tuple(feat["shape"])
        frames = np.empty((int(offsets[-1]),) + shape, dtype=np.uint8)
        by_file: dict[str, list[int]] = {}
        for k, e in enumerate(eps.tolist()):
            by_file.setdefault(idx.video_file(key, e), []).append(k)
        for rel, ks in by_file.items():
            path = idx.root / rel
            if not path.is_file():
                raise DataError(f"{path}: file is missing (video of feature {key!r}, episode {int(eps[ks[0]])})")
            rows = np.concatenate([np.arange(offsets[k], offsets[k + 1]) for k in ks])
            start = idx.video_index[key]["from_timestamp"]
            times = np.concatenate(
                [start[eps[k]] + timestamps[offsets[k] : offsets[k + 1]].astype(np.float64) for k in ks]
            )
            try:
                frames[rows] = decode_frames(path, times, shape)
            except VideoError as exc:
                which = ", ".join(str(int(eps[k])) for k in ks[:5]) + (" ..." if len(ks) > 5 else "")
                raise DataError(f"video feature {key!r} of episode(s) {which}: {exc}") from None
        out[key] = frames
    return out


def _episode(idx: _Index, e: int, cols: dict[str, np.ndarray], lo: int, hi: int) -> Episode:
    data = {n: a[lo:hi] for n, a in cols.items() if n != "episode_index"}
    return Episode(index=e, data=data, tasks=idx.episode_tasks(e), meta=idx.episode_meta(e))


def _dataset(idx: _Index, episodes: list[Episode], videos: bool) -> LogDataset:
    fps = idx.info["fps"]
    names = [k for k in idx.info["features"] if k in idx.features or (videos and k in idx.videos)]
    # A video's `info` (codec, pixel format) describes files this dataset has; a writer makes its own.
    features = {
        k: {f: v for f, v in idx.info["features"][k].items() if not (f == "info" and k in idx.videos)} for k in names
    }
    return LogDataset(
        fps=float(fps),
        features=features,
        episodes=episodes,
        tasks=list(idx.tasks),
        robot_type=idx.info.get("robot_type"),
    )


def _check_file_rows(idx: _Index, rel: str, eps: np.ndarray, num_rows: int) -> np.ndarray:
    """Row offsets of `eps` inside their data file; the file must hold exactly those rows."""
    base = int(idx.start[eps].min())
    first = idx.start[eps] - base
    if not np.array_equal(first, np.concatenate([[0], np.cumsum(idx.length[eps])[:-1]])):
        where = _where(idx.root, idx.episodes_file)
        raise DataError(f"{where}: column 'dataset_from_index' is not contiguous within {rel}")
    total = int(idx.length[eps].sum())
    if num_rows != total:
        raise DataError(
            f"{_where(idx.root, rel)}: file has {num_rows} rows but {idx.episodes_file} assigns it {total} frames"
        )
    return np.concatenate([first, [total]])


def read_dataset(root: str | os.PathLike, videos: bool = True) -> LogDataset:
    """Read a whole LeRobot v3.0 dataset into memory.

    Each data file is read once; episodes are views into its columns. Raises a one-line
    `DataError` naming the file and the field for missing files, shape mismatches, NaN/inf,
    non-increasing timestamps, gaps in episode indices and truncated parquet files.

    Args:
        root: the dataset folder.
        videos: decode video features into (T, H, W, 3) uint8 arrays; False leaves them out of
            the returned dataset (for consumers of the numeric features only: decoding costs time).
    """
    idx = _index(root)
    files: dict[str, list[int]] = {}
    for e in range(len(idx.episode_index)):
        files.setdefault(idx.data_file(e), []).append(e)
    episodes: list[Episode | None] = [None] * len(idx.episode_index)
    for rel, members in files.items():
        eps = np.asarray(sorted(members, key=lambda k: int(idx.start[k])), dtype=np.int64)
        pf = _parquet_file(idx.root, rel)
        offsets = _check_file_rows(idx, rel, eps, pf.metadata.num_rows)
        # Single-threaded decoding: as fast for episode-sized row groups and no thread pool
        # contention when several readers share a machine (measured in benchmarks/bench_logs.py).
        table = _read(idx.root, rel, pf.read, columns=_check_schema(idx, rel, pf), use_threads=False)
        cols = _table_columns(idx, rel, table)
        _check_rows(idx, rel, cols, eps, offsets)
        if videos:
            cols.update(_read_videos(idx, eps, offsets, cols["timestamp"]))
        for k, e in enumerate(eps.tolist()):
            episodes[e] = _episode(idx, e, cols, int(offsets[k]), int(offsets[k + 1]))
    return _dataset(idx, episodes, videos)  # type: ignore[arg-type]


def read_episode(root: str | os.PathLike, episode_index: int, videos: bool = True) -> Episode:
    """Read one episode without reading the rest of its data file.

    Uses the row offsets in meta/episodes and reads only the parquet row groups that overlap the
    episode (one, for files written by lerobot or by `write_dataset`). Metadata and parquet footers
    are cached while the files are unchanged, so a loop over episodes stays fast. With `videos`,
    its frames of every video feature are decoded (a seek to the episode's first keyframe).
    """
    idx = _index(root)
    n = len(idx.episode_index)
    if not isinstance(episode_index, (int, np.integer)) or not 0 <= int(episode_index) < n:
        where = _where(idx.root, idx.episodes_file)
        raise DataError(f"{where}: field 'episode_index' {episode_index!r} is not in 0..{n - 1}")
    e = int(episode_index)
    rel = idx.data_file(e)
    base = int(idx.base[e])
    lo, hi = int(idx.start[e]) - base, int(idx.stop[e]) - base
    pf, starts = _footer(idx.root, rel)
    if starts[-1] < hi:
        where = _where(idx.root, rel)
        raise DataError(f"{where}: file has {starts[-1]} rows but episode {e} needs rows {lo}..{hi - 1}")
    first, last = int(np.searchsorted(starts, lo, side="right")) - 1, int(np.searchsorted(starts, hi, side="left"))
    groups = list(range(first, last))  # the row groups overlapping rows lo..hi-1
    table = _read(idx.root, rel, pf.read_row_groups, groups, columns=_check_schema(idx, rel, pf), use_threads=False)
    table = table.slice(lo - int(starts[first]), hi - lo)
    cols = _table_columns(idx, rel, table)
    _check_rows(idx, rel, cols, np.asarray([e]), np.asarray([0, hi - lo]))
    if videos:
        cols.update(_read_videos(idx, np.asarray([e]), np.asarray([0, hi - lo]), cols["timestamp"]))
    return _episode(idx, e, cols, 0, hi - lo)


# ----------------------------------------------------------------------------- writing


def _arrow_type(feature: dict) -> pa.DataType:
    if feature["dtype"] == "image":
        return pa.struct([("bytes", pa.binary()), ("path", pa.string())])
    base = pa.from_numpy_dtype(np.dtype(feature["dtype"]))
    shape = feature["shape"]
    if shape == [1]:
        return base
    if len(shape) != 1:
        raise DataError(f"write_dataset: feature shape {shape} is not supported (vectors, scalars and images only)")
    return pa.list_(base, shape[0])


def _hf_feature(feature: dict) -> dict:
    """The `datasets` feature lerobot declares for a column (stored in the parquet schema metadata)."""
    if feature["dtype"] == "image":
        return {"_type": "Image"}
    value = {"dtype": feature["dtype"], "_type": "Value"}
    if feature["shape"] == [1]:
        return value
    return {"feature": value, "length": feature["shape"][0], "_type": "List"}


def _schema(features: dict[str, dict]) -> pa.Schema:
    hf = {name: _hf_feature(f) for name, f in features.items()}
    fields = [pa.field(name, _arrow_type(f)) for name, f in features.items()]
    return pa.schema(fields, metadata={"huggingface": json.dumps({"info": {"features": hf}})})


def _encode_png(frames: np.ndarray) -> list[bytes]:
    from PIL import Image

    out = []
    for frame in frames:
        buf = io.BytesIO()
        Image.fromarray(frame[:, :, 0] if frame.shape[-1] == 1 else frame).save(buf, format="PNG")
        out.append(buf.getvalue())
    return out


def _to_arrow(arr: np.ndarray, feature: dict, frame_index: np.ndarray) -> pa.Array:
    if feature["dtype"] == "image":
        paths = [f"frame-{int(i):06d}.png" for i in frame_index]
        return pa.StructArray.from_arrays(
            [pa.array(_encode_png(arr), pa.binary()), pa.array(paths, pa.string())], names=["bytes", "path"]
        )
    flat = np.ascontiguousarray(arr, dtype=np.dtype(feature["dtype"])).reshape(-1)
    values = pa.array(flat)
    if feature["shape"] == [1]:
        return values
    return pa.FixedSizeListArray.from_arrays(values, feature["shape"][0])


def _quantiles(x: np.ndarray) -> dict[str, np.ndarray]:
    """q01..q99 of each column, numpy's default (linear) method; a sort is 7x faster than
    np.quantile on episode-sized arrays, which dominates writing many episodes."""
    xs = np.sort(x, axis=0)
    out = {}
    for name, q in QUANTILES.items():
        pos = q * (len(xs) - 1)
        lo = int(np.floor(pos))
        hi = min(lo + 1, len(xs) - 1)
        out[name] = xs[lo] + (xs[hi] - xs[lo]) * (pos - lo)
    return out


def _image_stats(arr: np.ndarray) -> dict[str, np.ndarray]:
    """Per-channel statistics of (T, H, W, C) uint8 frames scaled to [0, 1], shaped (C, 1, 1) as lerobot's."""
    x = arr.reshape(-1, arr.shape[-1]).astype(np.float64) / 255.0
    shape = (arr.shape[-1], 1, 1)
    out = {"min": x.min(axis=0), "max": x.max(axis=0), "mean": x.mean(axis=0), "std": x.std(axis=0)}
    out.update(_quantiles(x))
    out = {k: v.reshape(shape) for k, v in out.items()}
    out["count"] = np.asarray([len(arr)], dtype=np.int64)
    return out


def _feature_stats(cols: dict[str, np.ndarray], features: dict[str, dict]) -> dict[str, dict[str, np.ndarray]]:
    """lerobot's statistics of every feature: per element for vectors, per channel for images.

    The numeric features are stacked into one float64 matrix so each statistic is one numpy call.
    """
    out: dict[str, dict[str, np.ndarray]] = {}
    numeric = [n for n, f in features.items() if not is_image(f)]
    if numeric:
        t = len(cols[numeric[0]])
        blocks = [cols[n].reshape(t, -1) for n in numeric]
        x = np.concatenate([b.astype(np.float64) for b in blocks], axis=1)
        whole = {"min": x.min(axis=0), "max": x.max(axis=0), "mean": x.mean(axis=0), "std": x.std(axis=0)}
        whole.update(_quantiles(x))
        edges = np.cumsum([0] + [b.shape[1] for b in blocks])
        for k, name in enumerate(numeric):
            part = {stat: v[edges[k] : edges[k + 1]] for stat, v in whole.items()}
            if np.dtype(features[name]["dtype"]).kind in "iub":  # integer features keep integer bounds
                part["min"], part["max"] = part["min"].astype(np.int64), part["max"].astype(np.int64)
            part["count"] = np.asarray([t], dtype=np.int64)
            out[name] = part
    for name, feat in features.items():
        if is_image(feat):
            out[name] = _image_stats(cols[name])
    return {name: {stat: out[name][stat] for stat in STAT_NAMES} for name in features}


def _stats_arrow_type(feature: dict, stat: str) -> pa.DataType:
    is_int = not is_image(feature) and np.dtype(feature["dtype"]).kind in "iub"
    if stat == "count" or (is_int and stat in ("min", "max")):
        return pa.list_(pa.int64())
    if is_image(feature):
        return pa.list_(pa.list_(pa.list_(pa.float64())))
    return pa.list_(pa.float64())


def _tasks_table(tasks: list[str]) -> pa.Table:
    schema = pa.schema(
        [pa.field("task_index", pa.int64()), pa.field("__index_level_0__", pa.large_string())],
        metadata={"pandas": json.dumps(_PANDAS_TASKS_META)},
    )
    return pa.table([pa.array(range(len(tasks)), pa.int64()), pa.array(tasks, pa.large_string())], schema=schema)


def _frame_arrays(ds: LogDataset, ep: Episode, offset: int) -> dict[str, np.ndarray]:
    """Episode columns in feature order, with the derived default columns filled in."""
    t = len(ep)
    cols: dict[str, np.ndarray] = {}
    for name, feat in ds.features.items():
        if name == "episode_index":
            cols[name] = np.full(t, ep.index, dtype=np.int64)
        elif name == "frame_index":
            cols[name] = np.arange(t, dtype=np.int64)
        elif name == "index":
            cols[name] = np.arange(offset, offset + t, dtype=np.int64)
        elif name in FRAME_COLUMNS:
            cols[name] = np.asarray(ep.data[name], dtype=np.dtype(feat["dtype"])).reshape(t)
        else:
            cols[name] = np.asarray(ep.data[name]).reshape((t,) + tuple(feat["shape"]))
    return cols


class _VideoFiles:
    """The MP4 files of one video feature: episodes appended to the current file until it passes
    `video_files_size_in_mb`, then a new file (lerobot's layout)."""

    def __init__(self, tmp: Path, key: str, fps: float, codec: str, crf: int | None):
        self.tmp, self.key, self.fps, self.codec, self.crf = tmp, key, fps, codec, crf
        self.file_no = 0
        self.frames = 0  # frames in the current file
        self.writer: Any = None  # the current file's bench.video.Mp4Writer
        self.first: Path | None = None

    def add(self, frames: np.ndarray) -> tuple[int, int, float, float]:
        """Encode one episode's frames; returns (chunk_index, file_index, from_timestamp, to_timestamp)."""
        from bench.video import Mp4Writer

        if self.writer is not None and self.writer.bytes_written >= VIDEO_FILES_SIZE_IN_MB * 1024 * 1024:
            self.writer.close()
            self.writer, self.frames, self.file_no = None, 0, self.file_no + 1
        chunk, fidx = divmod(self.file_no, CHUNKS_SIZE)
        if self.writer is None:
            path = self.tmp / VIDEO_PATH.format(video_key=self.key, chunk_index=chunk, file_index=fidx)
            self.writer = Mp4Writer(path, self.fps, codec=self.codec, crf=self.crf)
            self.first = self.first or path
        start = self.frames
        self.writer.write_many(frames)
        self.frames += len(frames)
        return chunk, fidx, start / self.fps, self.frames / self.fps

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None

    def abort(self) -> None:
        if self.writer is not None:
            self.writer.abort()
            self.writer = None


def _check_video_timestamps(ds: LogDataset, where: str) -> None:
    """Video frames are shown at frame_index / fps: a dataset with video needs timestamps that say so."""
    from bench.video import TOLERANCE_S

    for ep in ds.episodes:
        ts = np.asarray(ep.data["timestamp"], dtype=np.float32).reshape(-1)
        want = (np.arange(len(ts), dtype=np.float64) / ds.fps).astype(np.float32)
        frame = first_bad_row(np.abs(ts.astype(np.float64) - want) > TOLERANCE_S)
        if frame >= 0:
            raise DataError(
                f"{where}: column 'timestamp' is {float(ts[frame]):.6f} at frame {frame} of episode {ep.index} but "
                f"video frames are shown at frame/fps = {float(want[frame]):.6f} s; video features need evenly spaced "
                f"timestamps (store the cameras as dtype 'image' otherwise)"
            )


def _write_into(tmp: Path, ds: LogDataset, video_codec: str, crf: int | None) -> None:
    videos = [n for n, f in ds.features.items() if f["dtype"] == "video"]
    columns = {n: f for n, f in ds.features.items() if f["dtype"] != "video"}
    schema = _schema(columns)
    limit = DATA_FILES_SIZE_IN_MB * 1024 * 1024
    file_no, written, writer = 0, 0, None
    offset = 0
    rows: dict[str, list] = {c: [] for c in EPISODE_COLUMNS}
    rows.update({f"videos/{k}/{c}": [] for k in videos for c in VIDEO_COLUMNS})
    stat_rows: dict[str, list] = {f"stats/{n}/{s}": [] for n in ds.features for s in STAT_NAMES}
    metas: list[str | None] = []
    sinks = {k: _VideoFiles(tmp, k, ds.fps, video_codec, crf) for k in videos}
    try:
        for ep in ds.episodes:
            if writer is not None and written >= limit:
                writer.close()
                writer, written, file_no = None, 0, file_no + 1
            chunk, fidx = divmod(file_no, CHUNKS_SIZE)
            if writer is None:
                path = tmp / DATA_PATH.format(chunk_index=chunk, file_index=fidx)
                path.parent.mkdir(parents=True, exist_ok=True)
                # Dictionary pages only where values repeat: float data would fall back to plain
                # encoding anyway after a wasted dictionary (3x slower reads, 40 % larger files).
                writer = pq.ParquetWriter(path, schema, use_dictionary=["episode_index", "task_index"])
            cols = _frame_arrays(ds, ep, offset)
            arrays = [_to_arrow(cols[n], columns[n], cols["frame_index"]) for n in columns]
            table = pa.Table.from_arrays(arrays, schema=schema)
            writer.write_table(table, row_group_size=max(len(ep), 1))  # one row group per episode
            written += table.nbytes
            t = len(ep)
            _, first = np.unique(cols["task_index"], return_index=True)
            used = [ds.tasks[int(i)] for i in cols["task_index"][np.sort(first)]]  # in order of appearance
            for key, value in zip(EPISODE_COLUMNS, (ep.index, used, t, chunk, fidx, offset, offset + t)):
                rows[key].append(value)
            for key, sink in sinks.items():
                for c, value in zip(VIDEO_COLUMNS, sink.add(cols[key])):
                    rows[f"videos/{key}/{c}"].append(value)
            for name, per in _feature_stats(cols, ds.features).items():
                for stat, value in per.items():
                    stat_rows[f"stats/{name}/{stat}"].append(value.tolist())
            metas.append(json.dumps(ep.meta, allow_nan=False) if ep.meta else None)
            offset += t
        for sink in sinks.values():
            sink.close()
    finally:
        if writer is not None:
            writer.close()
        for sink in sinks.values():
            sink.abort()

    fields = [
        pa.field("episode_index", pa.int64()),
        pa.field("tasks", pa.list_(pa.string())),
        pa.field("length", pa.int64()),
        pa.field("data/chunk_index", pa.int64()),
        pa.field("data/file_index", pa.int64()),
        pa.field("dataset_from_index", pa.int64()),
        pa.field("dataset_to_index", pa.int64()),
    ]
    for key in videos:
        fields += [
            pa.field(f"videos/{key}/chunk_index", pa.int64()),
            pa.field(f"videos/{key}/file_index", pa.int64()),
            pa.field(f"videos/{key}/from_timestamp", pa.float64()),
            pa.field(f"videos/{key}/to_timestamp", pa.float64()),
        ]
    arrays = [pa.array(rows[f.name], f.type) for f in fields]
    for name, feat in ds.features.items():
        for stat in STAT_NAMES:
            typ = _stats_arrow_type(feat, stat)
            fields.append(pa.field(f"stats/{name}/{stat}", typ))
            arrays.append(pa.array(stat_rows[f"stats/{name}/{stat}"], typ))
    n = len(ds.episodes)
    for key in ("meta/episodes/chunk_index", "meta/episodes/file_index"):
        fields.append(pa.field(key, pa.int64()))
        arrays.append(pa.array(np.zeros(n, dtype=np.int64)))
    if any(m is not None for m in metas):
        fields.append(pa.field(META_COLUMN, pa.string()))
        arrays.append(pa.array(metas, pa.string()))
    ep_path = tmp / EPISODES_PATH.format(chunk_index=0, file_index=0)
    ep_path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_arrays(arrays, schema=pa.schema(fields)), ep_path)

    pq.write_table(_tasks_table(ds.tasks), tmp / TASKS_PATH)

    stats = {name: _aggregate_stats(stat_rows, name, feat) for name, feat in ds.features.items()}
    (tmp / STATS_PATH).write_text(json.dumps(stats, indent=4, allow_nan=False))

    from bench.video import probe

    fps = int(ds.fps) if float(ds.fps).is_integer() else float(ds.fps)
    features = {
        k: {"dtype": v["dtype"], "shape": list(v["shape"]), "names": v.get("names")} for k, v in ds.features.items()
    }
    for key, sink in sinks.items():  # as lerobot: the codec etc. of the feature's first file
        assert sink.first is not None
        features[key]["info"] = probe(sink.first)
    info_doc = {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": ds.robot_type,
        "total_episodes": n,
        "total_frames": offset,
        "total_tasks": len(ds.tasks),
        "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": DATA_FILES_SIZE_IN_MB,
        "video_files_size_in_mb": VIDEO_FILES_SIZE_IN_MB,
        "fps": fps,
        "splits": {"train": f"0:{n}"},
        "data_path": DATA_PATH,
        "video_path": VIDEO_PATH if videos else None,
        "features": features,
    }
    (tmp / INFO_PATH).write_text(json.dumps(info_doc, indent=4))


def _aggregate_stats(stat_rows: dict[str, list], name: str, feature: dict) -> dict:
    """Dataset statistics from the per-episode ones, as lerobot aggregates them: exact min, max,
    mean and (pooled) std; quantiles as the frame-weighted mean of the episodes' quantiles."""
    counts = np.asarray([c[0] for c in stat_rows[f"stats/{name}/count"]], dtype=np.float64)
    w = counts / counts.sum()
    get = lambda s: np.asarray(stat_rows[f"stats/{name}/{s}"], dtype=np.float64)  # noqa: E731
    mean = np.tensordot(w, get("mean"), axes=1)
    var = np.tensordot(w, get("std") ** 2 + (get("mean") - mean) ** 2, axes=1)
    out = {
        "min": get("min").min(axis=0),
        "max": get("max").max(axis=0),
        "mean": mean,
        "std": np.sqrt(var),
        "count": np.asarray([int(counts.sum())]),
    }
    if not is_image(feature) and np.dtype(feature["dtype"]).kind in "iub":
        out["min"], out["max"] = out["min"].astype(np.int64), out["max"].astype(np.int64)
    for q in QUANTILES:
        out[q] = np.tensordot(w, get(q), axes=1)
    return {k: out[k].tolist() for k in STAT_NAMES}


def _replace(tmp: Path, root: Path) -> None:
    """Move the finished `tmp` folder to `root`; the old `root` is removed only once `tmp` is in place."""
    if not root.exists():
        os.replace(tmp, root)
        return
    backup = root.parent / f".{root.name}.old-{uuid.uuid4().hex[:8]}"
    os.replace(root, backup)
    try:
        os.replace(tmp, root)
    except OSError:
        os.replace(backup, root)
        raise
    shutil.rmtree(backup, ignore_errors=True)


def write_dataset(
    root: str | os.PathLike,
    ds: LogDataset,
    overwrite: bool = False,
    video_codec: str = "h264",
    crf: int | None = None,
    *,
    key: str = "out",
    inputs: Mapping[str, Any] | None = None,
) -> Path:
    """Write `ds` as a LeRobot v3.0 folder that lerobot itself can load.

    `frame_index` and `index` are derived on write (position in episode / in dataset). The files
    are written to a temporary sibling folder and moved into place at the end, so a failure leaves
    nothing half-written and an existing dataset is replaced only by a complete one. Video
    features are encoded to MP4 (see `bench.video`): lossy, so frames read back differ from the
    written ones by a few levels (H.264 at the default quality: mean absolute error about 1-3 of
    255 on rendered scenes); their timestamps must be frame_index / fps.

    Args:
        root: target folder; must not exist or be empty unless `overwrite`.
        ds: the dataset; checked with `validate` first.
        overwrite: replace an existing folder bench wrote (never one holding anything else).
        key: the output's key, for messages (`out`, `record`).
        inputs: what the command read (key -> path): the output may not equal, contain or lie inside them
            (`bench.outputs`).
        video_codec: "h264" (default) or "av1" for video features.
        crf: video quality (lower is better; default 20 for H.264, 30 for AV1).

    Returns:
        The resolved path of the written folder.
    """
    from bench.video import CODECS, VideoError, check_codec, check_size

    root = Path(root).resolve()
    where = f"write_dataset({root})"
    check_fps(ds.fps, where)  # the same bound the reader applies: never write what cannot be read back
    validate(ds, where=where)
    if any(v["dtype"] == "video" for v in ds.features.values()):
        if video_codec not in CODECS:
            raise DataError(f"{where}: video_codec is {video_codec!r}; valid: {', '.join(CODECS)}")
        try:
            check_codec(video_codec)
        except VideoError as exc:
            raise DataError(f"{where}: {exc}") from None
        for name, feat in ds.features.items():
            try:
                if feat["dtype"] == "video":
                    check_size(video_codec, feat["shape"][0], feat["shape"][1])
            except VideoError as exc:
                raise DataError(f"{where}: feature {name!r}: {exc}") from None
        if not float(ds.fps).is_integer():
            raise DataError(
                f"{where}: field 'fps' is {ds.fps!r}; video features need a whole number of frames per second"
            )
        _check_video_timestamps(ds, where)
    from bench import outputs

    root = outputs.check(key, root, inputs or {}, overwrite=overwrite)
    root.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{root.name}.tmp-", dir=root.parent))
    try:
        (tmp / "meta").mkdir()
        _write_into(tmp, ds, video_codec, crf)
        outputs.mark(tmp)
        _replace(tmp, root)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    _INDEX_CACHE.pop(root, None)
    return root


def iter_episodes(root: str | os.PathLike, videos: bool = True) -> Iterator[Episode]:
    """Episodes one at a time, in index order, reading one row range each (low memory)."""
    for e in range(len(_index(root).episode_index)):
        yield read_episode(root, e, videos=videos)

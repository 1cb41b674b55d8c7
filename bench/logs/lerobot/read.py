"""Frames of a LeRobot v3.0 dataset: parquet columns to numpy, PNG images, MP4 video features.

Every row read is checked against the index (`bench.logs.lerobot.index`): declared columns and
shapes, episode and task indices, finite values, increasing timestamps. Video features are
decoded with PyAV (`bench.core.video`).
"""

from __future__ import annotations

import io
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from bench.core.errors import DataError
from bench.core.video import VideoError, decode_frames
from bench.logs.dataset import DEFAULT_FEATURES, FRAME_COLUMNS, Episode, LogDataset, first_bad_row
from bench.logs.lerobot.index import (
    INFO_PATH,
    TASKS_PATH,
    Index,
    first_line,
    load_index,
    location,
    open_parquet,
    read_arrow,
    stamp,
)

_FOOTER_CACHE: dict[Path, tuple[tuple, pq.FileMetaData, np.ndarray]] = {}


def _footer(root: Path, rel: str) -> tuple[pq.ParquetFile, np.ndarray]:
    """A data file opened with its cached footer, and the first row of each row group (plus the total)."""
    path = root / rel
    if not path.is_file():
        raise DataError(f"{location(root, rel)}: file is missing")
    key = stamp([path])
    hit = _FOOTER_CACHE.get(path)
    if hit is None or hit[0] != key:
        try:
            md = pq.read_metadata(path)
        except (pa.ArrowException, OSError) as exc:
            reason = first_line(exc)
            raise DataError(f"{location(root, rel)}: not a readable parquet file (truncated?): {reason}") from None
        sizes = [md.row_group(g).num_rows for g in range(md.num_row_groups)]
        hit = (key, md, np.concatenate([[0], np.cumsum(sizes, dtype=np.int64)]))
        if len(_FOOTER_CACHE) > 256:
            _FOOTER_CACHE.clear()
        _FOOTER_CACHE[path] = hit
    return pq.ParquetFile(path, metadata=hit[1]), hit[2]


def _column_to_numpy(arr: pa.Array, name: str, feature: dict, root: Path, rel: str) -> np.ndarray:
    """A parquet column as a (rows, *shape) array ((rows,) for the default columns)."""
    where = location(root, rel)
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
    from PIL import Image  # Pillow: loaded only when PNG images are read or written

    where = location(root, rel)
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
            raise DataError(f"{where}: image column {name!r} row {i} cannot be decoded: {first_line(exc)}") from None
        if pix.ndim == 2:
            pix = pix[:, :, None]
        if pix.shape != shape:
            raise DataError(
                f"{where}: image column {name!r} row {i} has shape {pix.shape} but {INFO_PATH} declares {list(shape)}"
            )
        out[i] = pix
    return out


def _check_schema(idx: Index, rel: str, pf: pq.ParquetFile) -> list[str]:
    """The columns to read from a data file; every declared column must be there and no other."""
    names = pf.schema_arrow.names
    for name in names:
        if name not in idx.info["features"]:
            raise DataError(f"{location(idx.root, rel)}: column {name!r} is not declared in {INFO_PATH} features")
    for name in idx.features:
        if name not in names:
            raise DataError(f"{location(idx.root, rel)}: column {name!r} declared in {INFO_PATH} is missing")
    return list(idx.features)


def _table_columns(idx: Index, rel: str, table: pa.Table) -> dict[str, np.ndarray]:
    out = {}
    for name, feat in idx.features.items():
        col = table.column(name)
        arr = col.chunk(0) if col.num_chunks == 1 else col.combine_chunks()
        out[name] = _column_to_numpy(arr, name, feat, idx.root, rel)
    return out


def _check_rows(idx: Index, rel: str, cols: dict[str, np.ndarray], eps: np.ndarray, offsets: np.ndarray) -> None:
    """Validate rows of one file holding episodes `eps`, episode k at rows offsets[k]:offsets[k+1]."""
    where = location(idx.root, rel)
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


def _read_videos(idx: Index, eps: np.ndarray, offsets: np.ndarray, timestamps: np.ndarray) -> dict[str, np.ndarray]:
    """Frames of every video feature for episodes `eps` (rows offsets[k]:offsets[k+1] of `timestamps`).

    Frame j of episode e is the one shown at `from_timestamp[e] + timestamp[j]` in its MP4 file
    (within `bench.core.video.TOLERANCE_S`, lerobot's default tolerance). Each file is decoded once,
    forward from the keyframe before the first frame wanted.
    """
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


def _episode(idx: Index, e: int, cols: dict[str, np.ndarray], lo: int, hi: int) -> Episode:
    data = {n: a[lo:hi] for n, a in cols.items() if n != "episode_index"}
    return Episode(index=e, data=data, tasks=idx.episode_tasks(e), meta=idx.episode_meta(e))


def _dataset(idx: Index, episodes: list[Episode], videos: bool) -> LogDataset:
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


def _check_file_rows(idx: Index, rel: str, eps: np.ndarray, num_rows: int) -> np.ndarray:
    """Row offsets of `eps` inside their data file; the file must hold exactly those rows."""
    base = int(idx.start[eps].min())
    first = idx.start[eps] - base
    if not np.array_equal(first, np.concatenate([[0], np.cumsum(idx.length[eps])[:-1]])):
        where = location(idx.root, idx.episodes_file)
        raise DataError(f"{where}: column 'dataset_from_index' is not contiguous within {rel}")
    total = int(idx.length[eps].sum())
    if num_rows != total:
        raise DataError(
            f"{location(idx.root, rel)}: file has {num_rows} rows but {idx.episodes_file} assigns it {total} frames"
        )
    return np.concatenate([first, [total]])


def _files(idx: Index) -> dict[str, np.ndarray]:
    """Data file -> the episodes it holds, in row order."""
    files: dict[str, list[int]] = {}
    for e in range(len(idx.episode_index)):
        files.setdefault(idx.data_file(e), []).append(e)
    return {rel: np.asarray(sorted(m, key=lambda k: int(idx.start[k])), dtype=np.int64) for rel, m in files.items()}


def check_files(root: str | os.PathLike) -> dict[str, int]:
    """Every file the metadata points to, checked without reading frames (what `bench logs info` runs).

    Each data file's parquet footer is read: the file is there and is parquet (a truncated or garbage
    file has no footer), its columns are the declared features, and its row count is what the
    episodes table assigns it. Each video file is there and not empty. Raises a one-line DataError
    naming the file; returns {"data_files", "video_files", "rows"}.
    """
    idx = load_index(root)
    rows = 0
    files = _files(idx)
    for rel, eps in files.items():
        pf, starts = _footer(idx.root, rel)
        _check_schema(idx, rel, pf)
        _check_file_rows(idx, rel, eps, int(starts[-1]))
        rows += int(starts[-1])
    videos = {idx.video_file(key, e) for key in idx.videos for e in range(len(idx.episode_index))}
    for rel in sorted(videos):
        path = idx.root / rel
        if not path.is_file() or path.stat().st_size == 0:
            raise DataError(f"{location(idx.root, rel)}: video file is {'empty' if path.is_file() else 'missing'}")
    return {"data_files": len(files), "video_files": len(videos), "rows": rows}


def verify(root: str | os.PathLike) -> dict[str, int]:
    """Read every frame of every file (`bench logs verify`): the footers (`check_files`), then every row
    group decoded and checked as `read_dataset` checks it (episode and task indices, NaN/inf, timestamps),
    and every video frame decoded. Raises a one-line DataError naming the file; returns the counts."""
    counts = check_files(root)
    ds = read_dataset(root, videos=True)
    return {**counts, "episodes": len(ds.episodes), "frames": sum(len(ep.data["timestamp"]) for ep in ds.episodes)}


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
    idx = load_index(root)
    episodes: list[Episode | None] = [None] * len(idx.episode_index)
    for rel, eps in _files(idx).items():
        pf = open_parquet(idx.root, rel)
        offsets = _check_file_rows(idx, rel, eps, pf.metadata.num_rows)
        # Single-threaded decoding: as fast for episode-sized row groups and no thread pool
        # contention when several readers share a machine (measured in benchmarks/bench_logs.py).
        table = read_arrow(idx.root, rel, pf.read, columns=_check_schema(idx, rel, pf), use_threads=False)
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
    idx = load_index(root)
    n = len(idx.episode_index)
    if not isinstance(episode_index, (int, np.integer)) or not 0 <= int(episode_index) < n:
        where = location(idx.root, idx.episodes_file)
        raise DataError(f"{where}: field 'episode_index' {episode_index!r} is not in 0..{n - 1}")
    e = int(episode_index)
    rel = idx.data_file(e)
    base = int(idx.base[e])
    lo, hi = int(idx.start[e]) - base, int(idx.stop[e]) - base
    pf, starts = _footer(idx.root, rel)
    if starts[-1] < hi:
        where = location(idx.root, rel)
        raise DataError(f"{where}: file has {starts[-1]} rows but episode {e} needs rows {lo}..{hi - 1}")
    first, last = int(np.searchsorted(starts, lo, side="right")) - 1, int(np.searchsorted(starts, hi, side="left"))
    groups = list(range(first, last))  # the row groups overlapping rows lo..hi-1
    table = read_arrow(
        idx.root, rel, pf.read_row_groups, groups, columns=_check_schema(idx, rel, pf), use_threads=False
    )
    table = table.slice(lo - int(starts[first]), hi - lo)
    cols = _table_columns(idx, rel, table)
    _check_rows(idx, rel, cols, np.asarray([e]), np.asarray([0, hi - lo]))
    if videos:
        cols.update(_read_videos(idx, np.asarray([e]), np.asarray([0, hi - lo]), cols["timestamp"]))
    return _episode(idx, e, cols, 0, hi - lo)


def iter_episodes(root: str | os.PathLike, videos: bool = True) -> Iterator[Episode]:
    """Episodes one at a time, in index order, reading one row range each (low memory)."""
    for e in range(len(load_index(root).episode_index)):
        yield read_episode(root, e, videos=videos)

"""Writing a LeRobot v3.0 dataset that lerobot itself can load: data files, videos, episodes, stats, info.

Files go to a temporary sibling folder that replaces the target only once complete.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import tempfile
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from bench.core import outputs
from bench.core.errors import DataError
from bench.core.video import CODECS, TOLERANCE_S, Mp4Writer, VideoError, check_codec, check_size, probe
from bench.logs.dataset import FRAME_COLUMNS, Episode, LogDataset, first_bad_row, validate
from bench.logs.lerobot.index import (
    CHUNKS_SIZE,
    CODEBASE_VERSION,
    DATA_FILES_SIZE_IN_MB,
    DATA_PATH,
    EPISODE_COLUMNS,
    EPISODES_PATH,
    INFO_PATH,
    META_COLUMN,
    STATS_PATH,
    TASKS_PATH,
    VIDEO_COLUMNS,
    VIDEO_FILES_SIZE_IN_MB,
    VIDEO_PATH,
    forget_index,
)
from bench.logs.lerobot.stats import STAT_NAMES, aggregate_stats, feature_stats, stats_arrow_type
from bench.logs.lerobot.validate import check_fps

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
    from PIL import Image  # Pillow: loaded only when PNG images are read or written

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
        self.writer: Mp4Writer | None = None  # the current file's
        self.first: Path | None = None

    def add(self, frames: np.ndarray) -> tuple[int, int, float, float]:
        """Encode one episode's frames; returns (chunk_index, file_index, from_timestamp, to_timestamp)."""
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
            for name, per in feature_stats(cols, ds.features).items():
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
            typ = stats_arrow_type(feat, stat)
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

    stats = {name: aggregate_stats(stat_rows, name, feat) for name, feat in ds.features.items()}
    (tmp / STATS_PATH).write_text(json.dumps(stats, indent=4, allow_nan=False))

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
    inputs: Mapping[str, outputs.InputPath | Sequence[outputs.InputPath]] | None = None,
) -> Path:
    """Write `ds` as a LeRobot v3.0 folder that lerobot itself can load.

    `frame_index` and `index` are derived on write (position in episode / in dataset). The files
    are written to a temporary sibling folder and moved into place at the end, so a failure leaves
    nothing half-written and an existing dataset is replaced only by a complete one. Video
    features are encoded to MP4 (see `bench.core.video`): lossy, so frames read back differ from the
    written ones by a few levels (H.264 at the default quality: mean absolute error about 1-3 of
    255 on rendered scenes); their timestamps must be frame_index / fps.

    Args:
        root: target folder; must not exist or be empty unless `overwrite`.
        ds: the dataset; checked with `validate` first.
        overwrite: replace an existing folder bench wrote (never one holding anything else).
        key: the output's key, for messages (`out`, `record`).
        inputs: what the command read (key -> path): the output may not equal, contain or lie inside them
            (`bench.core.outputs`).
        video_codec: "h264" (default) or "av1" for video features.
        crf: video quality (lower is better; default 20 for H.264, 30 for AV1).

    Returns:
        The resolved path of the written folder.
    """
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
    forget_index(root)
    return root

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
(`bench.core.video`): no torchvision, no torchcodec. The writer encodes H.264 by default (AV1 on
request, lerobot's own default). Per-episode metadata of ours (`Episode.meta`) travels as a JSON
string column `bench/meta` in the episodes file, which lerobot ignores.
"""

from bench.logs.lerobot.index import (
    CHUNKS_SIZE,
    CODEBASE_VERSION,
    DATA_FILES_SIZE_IN_MB,
    DATA_PATH,
    EPISODE_COLUMNS,
    EPISODES_DIR,
    EPISODES_PATH,
    INFO_KEYS,
    INFO_PATH,
    META_COLUMN,
    REQUIRED_INFO_KEYS,
    STATS_PATH,
    TASKS_PATH,
    VIDEO_COLUMNS,
    VIDEO_FILES_SIZE_IN_MB,
    VIDEO_PATH,
    info,
)
from bench.logs.lerobot.read import check_files, iter_episodes, read_dataset, read_episode, verify
from bench.logs.lerobot.stats import QUANTILES, STAT_NAMES
from bench.logs.lerobot.validate import MAX_FPS
from bench.logs.lerobot.write import write_dataset

__all__ = [
    "CHUNKS_SIZE",
    "CODEBASE_VERSION",
    "DATA_FILES_SIZE_IN_MB",
    "DATA_PATH",
    "EPISODE_COLUMNS",
    "EPISODES_DIR",
    "EPISODES_PATH",
    "INFO_KEYS",
    "INFO_PATH",
    "MAX_FPS",
    "META_COLUMN",
    "QUANTILES",
    "REQUIRED_INFO_KEYS",
    "STATS_PATH",
    "STAT_NAMES",
    "TASKS_PATH",
    "VIDEO_COLUMNS",
    "VIDEO_FILES_SIZE_IN_MB",
    "VIDEO_PATH",
    "check_files",
    "info",
    "iter_episodes",
    "read_dataset",
    "read_episode",
    "verify",
    "write_dataset",
]

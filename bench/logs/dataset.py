"""In-memory form of a real-robot log: a `LogDataset` of `Episode`s, LeRobot v3.0 style.

Conventions (shared by the reader, the writer, the importers and every consumer):

- `Episode.data` maps a feature name to an array whose first axis is time (T frames).
- The four per-frame default columns are 1-D: `timestamp` (T,) float32 seconds from the episode
  start, `frame_index`, `index` (global frame number) and `task_index` (T,) int64. The fifth
  default feature, `episode_index`, is `Episode.index` and is not repeated in `data`.
- Every other feature has shape (T, *features[name]["shape"]): a vector feature is (T, D), a
  scalar feature declared with shape [1] is (T, 1), an image is (T, H, W, C) uint8. A camera
  stream is either dtype "image" (PNG per frame inside the parquet) or dtype "video" (H.264 or AV1
  in MP4 files beside it, C = 3): in memory both are (T, H, W, C) uint8 arrays.
- Floats are float32 (LeRobot reads float64 back as float32); absolute times, when kept, are
  int64 nanoseconds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from bench.core.errors import DataError

# Columns every LeRobot v3.0 data file carries, in the order lerobot declares them.
DEFAULT_FEATURES: dict[str, dict] = {
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}
# Default features stored as 1-D arrays in `Episode.data` (episode_index is `Episode.index`).
FRAME_COLUMNS = ("timestamp", "frame_index", "index", "task_index")
IMAGE_NAMES = ["height", "width", "channels"]
NUMERIC_DTYPES = frozenset(
    {"bool", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64", "float16", "float32", "float64"}
)


@dataclass
class Episode:
    """One episode: per-frame arrays plus the tasks it uses and free JSON-able metadata."""

    index: int
    data: dict[str, np.ndarray]
    tasks: list[str] = field(default_factory=list)
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        """Number of frames."""
        if "timestamp" in self.data:
            return len(self.data["timestamp"])
        return len(next(iter(self.data.values()))) if self.data else 0


@dataclass
class LogDataset:
    """A set of episodes sharing a frame rate, a feature schema and a task list."""

    fps: float
    features: dict[str, dict]
    episodes: list[Episode]
    tasks: list[str]
    robot_type: str | None = None

    @property
    def num_frames(self) -> int:
        """Total number of frames over all episodes."""
        return sum(len(ep) for ep in self.episodes)

    def feature_shape(self, name: str) -> tuple[int, ...]:
        """Per-frame shape of `name` as stored in `Episode.data` (without the time axis)."""
        if name in FRAME_COLUMNS or name == "episode_index":
            return ()
        return tuple(int(s) for s in self.features[name]["shape"])


def is_image(feature: dict) -> bool:
    """Whether a feature entry is a camera stream (stored as PNG or video, decoded to uint8)."""
    return feature.get("dtype") in ("image", "video")


def _infer_feature(name: str, arr: np.ndarray, names: list[str] | None, video: bool = False) -> dict:
    """Feature entry for a (T, ...) array: images are (T, H, W, C) uint8, the rest numeric."""
    if arr.dtype == np.uint8 and arr.ndim == 4 and arr.shape[-1] in (1, 3, 4):
        if video and arr.shape[-1] != 3:
            raise DataError(
                f"from_arrays: feature {name!r} has {arr.shape[-1]} channels; a video feature needs 3 (RGB)"
            )
        return {"dtype": "video" if video else "image", "shape": list(arr.shape[1:]), "names": list(IMAGE_NAMES)}
    if video:
        raise DataError(
            f"from_arrays: feature {name!r} is {arr.dtype} {list(arr.shape[1:])}, not (T, H, W, 3) uint8 "
            f"frames; only camera streams can be stored as video"
        )
    shape = list(arr.shape[1:]) or [1]
    if names is not None and len(names) != int(np.prod(shape)):
        raise DataError(f"from_arrays: names[{name!r}] has {len(names)} entries but the feature has shape {shape}")
    return {"dtype": arr.dtype.name, "shape": shape, "names": list(names) if names is not None else None}


def _as_frame_array(name: str, value: npt.ArrayLike, where: str) -> np.ndarray:
    arr = np.asarray(value)
    if arr.ndim == 0:
        raise DataError(f"{where}: feature {name!r} is a scalar; expected an array with a leading time axis")
    if arr.dtype.kind == "f" and name != "timestamp":
        arr = arr.astype(np.float32, copy=False)
    elif arr.dtype.kind in "iu" and not (arr.dtype == np.uint8 and arr.ndim == 4):
        arr = arr.astype(np.int64, copy=False)
    elif arr.dtype.kind not in "bfiu":
        raise DataError(f"{where}: feature {name!r} has dtype {arr.dtype}; expected numbers, booleans or uint8 images")
    return arr


def from_arrays(
    episodes: list[dict[str, np.ndarray]],
    fps: float,
    task: str | Sequence[str] = "default",
    names: dict[str, list[str]] | None = None,
    robot_type: str | None = None,
    meta: list[dict] | None = None,
    video: bool | Sequence[str] = False,
) -> LogDataset:
    """Build a dataset from plain per-episode dicts such as {"observation.state": (T, D), "action": (T, A)}.

    Floats become float32 and integers int64; a 1-D array becomes a (T, 1) scalar feature; a
    (T, H, W, C) uint8 array becomes an image feature. The default columns are filled in:
    `timestamp` = frame / fps unless given (seconds from the episode start), `frame_index`,
    the global `index`, and `task_index`.

    Args:
        episodes: one dict per episode, feature name -> array with a leading time axis.
        fps: frame rate in Hz.
        task: one task string for every episode, or one per episode.
        names: optional per-feature element names, e.g. {"action": ["j0", "j1"]}.
        robot_type: stored in info.json.
        meta: optional per-episode JSON-able metadata, e.g. [{"success": True}, ...].
        video: store camera streams as video features (MP4 files) instead of PNG images: True for
            every (T, H, W, 3) uint8 feature, or a list of feature names.
    """
    if not np.isfinite(fps) or fps <= 0:
        raise DataError(f"from_arrays: fps must be a positive number, got {fps!r}")
    if not episodes:
        raise DataError("from_arrays: no episodes given")
    ep_tasks = [task] * len(episodes) if isinstance(task, str) else list(task)
    if len(ep_tasks) != len(episodes):
        raise DataError(f"from_arrays: {len(ep_tasks)} tasks given for {len(episodes)} episodes")
    if meta is not None and len(meta) != len(episodes):
        raise DataError(f"from_arrays: {len(meta)} meta entries given for {len(episodes)} episodes")
    tasks = list(dict.fromkeys(ep_tasks))
    names = names or {}
    as_video = set() if video is False else None if video is True else {str(v) for v in video}

    features: dict[str, dict] = {}
    out: list[Episode] = []
    offset = 0
    for e, raw in enumerate(episodes):
        where = f"from_arrays: episode {e}"
        data: dict[str, np.ndarray] = {}
        for name, value in raw.items():
            if name == "episode_index":
                continue
            data[name] = _as_frame_array(name, value, where)
        user = [n for n in data if n not in FRAME_COLUMNS]
        if not user:
            raise DataError(f"{where}: no features besides the default columns")
        t = len(data[user[0]])
        if t == 0:
            raise DataError(f"{where}: feature {user[0]!r} has no frames")
        for name, arr in data.items():
            if len(arr) != t:
                raise DataError(f"{where}: feature {name!r} has {len(arr)} frames but {user[0]!r} has {t}")
        for name in user:
            if data[name].ndim == 1:
                data[name] = data[name][:, None]
            is_frames = data[name].dtype == np.uint8 and data[name].ndim == 4 and data[name].shape[-1] == 3
            want_video = (as_video is None and is_frames) or (as_video is not None and name in as_video)
            feat = _infer_feature(name, data[name], names.get(name), want_video)
            if name not in features:
                features[name] = feat
            elif features[name]["shape"] != feat["shape"] or features[name]["dtype"] != feat["dtype"]:
                raise DataError(
                    f"{where}: feature {name!r} has dtype {feat['dtype']} shape {feat['shape']} but episode 0 "
                    f"has dtype {features[name]['dtype']} shape {features[name]['shape']}"
                )
        if "timestamp" in data:
            data["timestamp"] = np.asarray(data["timestamp"], dtype=np.float32).reshape(t)
        else:
            data["timestamp"] = (np.arange(t, dtype=np.float64) / fps).astype(np.float32)
        data["frame_index"] = np.arange(t, dtype=np.int64)
        data["index"] = np.arange(offset, offset + t, dtype=np.int64)
        data["task_index"] = np.full(t, tasks.index(ep_tasks[e]), dtype=np.int64)
        offset += t
        ordered = {n: data[n] for n in user}
        ordered.update({n: data[n] for n in FRAME_COLUMNS})
        out.append(Episode(index=e, data=ordered, tasks=[ep_tasks[e]], meta=dict(meta[e]) if meta else {}))
    for name in names:
        if name not in features:
            raise DataError(f"from_arrays: names given for unknown feature {name!r}; features: {', '.join(features)}")
    for name in sorted(as_video or ()):
        if name not in features:
            raise DataError(f"from_arrays: video given for unknown feature {name!r}; features: {', '.join(features)}")
    features.update({k: dict(v) for k, v in DEFAULT_FEATURES.items()})
    return LogDataset(fps=float(fps), features=features, episodes=out, tasks=tasks, robot_type=robot_type)


def first_bad_row(bad: np.ndarray) -> int:
    """Index of the first frame where a boolean (T, ...) mask is set, or -1."""
    rows = bad.reshape(len(bad), -1).any(axis=1) if bad.ndim > 1 else bad
    hit = np.flatnonzero(rows)
    return int(hit[0]) if hit.size else -1


def validate(ds: LogDataset, where: str = "LogDataset") -> None:
    """Check an in-memory dataset before writing it; raise a one-line `DataError` naming the field.

    Checks: positive fps, the default features declared, episode indices 0..N-1 in order, every
    declared feature present with shape (T, *shape), no undeclared feature, finite floats, strictly
    increasing timestamps, task indices within `tasks`.
    """
    if not np.isfinite(ds.fps) or ds.fps <= 0:
        raise DataError(f"{where}: field 'fps' must be a positive number, got {ds.fps!r}")
    for key, ref in DEFAULT_FEATURES.items():
        feat = ds.features.get(key)
        if feat is None or feat.get("dtype") != ref["dtype"]:
            raise DataError(f"{where}: field 'features' must declare default feature {key!r} as {ref['dtype']}")
    for name, feat in ds.features.items():
        dtype = feat.get("dtype")
        shape = feat.get("shape")
        if dtype not in NUMERIC_DTYPES and dtype not in ("image", "video"):
            raise DataError(f"{where}: feature {name!r} has unsupported dtype {dtype!r}")
        if not isinstance(shape, (list, tuple)) or not shape or not all(isinstance(s, int) and s > 0 for s in shape):
            raise DataError(f"{where}: feature {name!r} has bad shape {shape!r}; expected a list of positive ints")
        if dtype == "video" and (len(shape) != 3 or shape[2] != 3):
            raise DataError(f"{where}: video feature {name!r} has shape {list(shape)}; expected [height, width, 3]")
    if not ds.episodes:
        raise DataError(f"{where}: no episodes")
    declared = [n for n in ds.features if n != "episode_index"]
    for pos, ep in enumerate(ds.episodes):
        if ep.index != pos:
            raise DataError(f"{where}: episode at position {pos} has index {ep.index}; indices must be 0..N-1 in order")
        validate_episode(ds, ep, declared, where)


def validate_episode(ds: LogDataset, ep: Episode, declared: list[str], where: str) -> None:
    """Check one episode's arrays against the dataset's features (see `validate`)."""
    t = len(ep)
    if t == 0:
        raise DataError(f"{where}: episode {ep.index} has no frames")
    for name in ep.data:
        if name not in ds.features:
            raise DataError(f"{where}: episode {ep.index} has feature {name!r} that is not declared in 'features'")
    for name in declared:
        if name in ("frame_index", "index"):
            continue  # derived on write
        if name not in ep.data:
            raise DataError(f"{where}: episode {ep.index} lacks feature {name!r}")
        arr = ep.data[name]
        want = (t,) + ds.feature_shape(name)
        if arr.shape != want and not (arr.ndim == 1 and want == (t, 1)):
            raise DataError(f"{where}: feature {name!r} in episode {ep.index} has shape {arr.shape}, expected {want}")
        check_frames(name, arr, ds.features[name], ep.index, where)
    if ep.data["task_index"].size and (ep.data["task_index"].min() < 0 or ep.data["task_index"].max() >= len(ds.tasks)):
        raise DataError(
            f"{where}: feature 'task_index' in episode {ep.index} is outside 0..{len(ds.tasks) - 1} (field 'tasks')"
        )


def check_frames(name: str, arr: np.ndarray, feature: dict, episode: int, where: str) -> None:
    """Raise if a float column has NaN/inf, or if `timestamp` is not strictly increasing."""
    if arr.dtype.kind == "f":
        frame = first_bad_row(~np.isfinite(arr))
        if frame >= 0:
            raise DataError(f"{where}: column {name!r} has NaN or inf in episode {episode} at frame {frame}")
    if name == "timestamp" and len(arr) > 1:
        frame = first_bad_row(np.diff(arr) <= 0)
        if frame >= 0:
            raise DataError(f"{where}: column 'timestamp' is not increasing in episode {episode} at frame {frame + 1}")
    if is_image(feature) and arr.dtype != np.uint8:
        kind = feature["dtype"]
        raise DataError(f"{where}: {kind} feature {name!r} in episode {episode} has dtype {arr.dtype}, expected uint8")

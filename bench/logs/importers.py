"""Importers from other log formats to a `LogDataset`: CSV, MATLAB .mat and RLDS (TFDS) shards.

Every importer returns the same in-memory form as `read_dataset` (see `bench.logs.dataset`):
`observation.state` and `action` as float32 (T, D) with element names, `timestamp` in seconds
from the episode start, and, when the source has a time column, the source's absolute time as
an int64 nanosecond feature `time_ns` (T, 1) — float32 seconds lose precision on long logs.
"""

from __future__ import annotations

import io
import json
import os
import re
import zlib
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

import bench.logs.tfrecord as tfrecord
from bench.errors import DataError, did_you_mean
from bench.logs.dataset import LogDataset, first_bad_row, from_arrays

TIME_NAMES = ("t", "time", "Time", "timestamp")


def _as_list(value: str | Sequence[str] | None) -> list[str] | None:
    if value is None:
        return None
    return [value] if isinstance(value, str) else [str(v) for v in value]


def _fps_from_time(t: np.ndarray, where: str, column: str) -> float:
    dt = np.diff(t)
    if dt.size == 0:
        raise DataError(f"{where}: column {column!r} has one sample; pass fps= to set the frame rate")
    fps = 1.0 / float(np.median(dt))
    # A nominal rate: sample clocks jitter (EMPS: 1000.016 Hz by median step), the true times
    # stay in `timestamp` / `time_ns`. Snap to an integer within 0.1 %, as lerobot expects ints.
    return float(round(fps)) if abs(fps - round(fps)) <= 1e-3 * fps else round(fps, 6)


def _check_time(t: np.ndarray, where: str, column: str, offset: int = 0) -> None:
    row = first_bad_row(~np.isfinite(t))
    if row >= 0:
        raise DataError(f"{where}: column {column!r} is not finite at row {row + offset}")
    row = first_bad_row(np.diff(t) <= 0)
    if row >= 0:
        raise DataError(f"{where}: column {column!r} is not increasing at row {row + 1 + offset}")


def _time_features(t: np.ndarray) -> dict[str, np.ndarray]:
    """`timestamp` (seconds from the first sample, float32) and `time_ns` (absolute, int64 ns)."""
    t = np.asarray(t, dtype=np.float64)
    return {"timestamp": (t - t[0]).astype(np.float32), "time_ns": np.round(t * 1e9).astype(np.int64)[:, None]}


# ----------------------------------------------------------------------------- CSV


F32_MAX = float(np.finfo(np.float32).max)


def import_csv(
    path: str | os.PathLike,
    *,
    state: str | Sequence[str] | None = None,
    action: str | Sequence[str] | None = None,
    time: str | None = None,
    fps: float | None = None,
    task: str = "default",
    episode: str | None = None,
    robot_type: str | None = None,
    delimiter: str = ",",
) -> LogDataset:
    """Import a CSV file with a header row.

    Args:
        path: the CSV file.
        state: columns for `observation.state` (default: every numeric column not used otherwise).
        action: columns for `action` (default: none).
        time: column with the sample time in seconds; gives `timestamp`, `time_ns` and, without
            `fps`, the nominal frame rate (1 / median step, snapped to an integer within 0.1 %).
            Without it, `timestamp` = frame / fps.
        fps: frame rate in Hz (required when there is no time column).
        task: task string of every episode.
        episode: column whose value splits the rows into episodes (default: one episode).
        robot_type: stored in info.json.
        delimiter: field separator.
    """
    import pyarrow as pa
    import pyarrow.csv as pacsv

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: file is missing")
    try:
        table = pacsv.read_csv(
            path,
            parse_options=pacsv.ParseOptions(delimiter=delimiter),
            convert_options=pacsv.ConvertOptions(null_values=[""]),  # "nan" stays a NaN float, caught below
        )
    except (pa.ArrowException, OSError) as exc:
        raise DataError(f"{path}: cannot parse CSV: {str(exc).splitlines()[0]}") from None
    columns = table.column_names
    if table.num_rows == 0:
        raise DataError(f"{path}: no data rows")
    twice = next((c for i, c in enumerate(columns) if c in columns[:i]), None)
    if twice is not None:
        raise DataError(f"{path}: column {twice!r} appears twice in the header; give every column its own name")

    def column(name: str, numeric: bool = True) -> np.ndarray:
        if name not in columns:
            hint = did_you_mean(name, columns)
            raise DataError(f"{path}: column {name!r} not found; columns: {', '.join(columns)}.{hint}")
        col = table.column(name)
        if col.null_count:
            row = first_bad_row(np.asarray(col.is_null().to_numpy(zero_copy_only=False)))
            raise DataError(f"{path}: column {name!r} has an empty cell at row {row}")
        if numeric and not (pa.types.is_integer(col.type) or pa.types.is_floating(col.type)):
            raise DataError(f"{path}: column {name!r} is {col.type}, not numeric")
        return col.to_numpy() if numeric else np.asarray(col.to_pylist(), dtype=object)

    state_cols, action_cols = _as_list(state), _as_list(action) or []
    used = {c for c in (time, episode) if c}
    if state_cols is None:
        numeric = [
            c
            for c in columns
            if pa.types.is_integer(table.column(c).type) or pa.types.is_floating(table.column(c).type)
        ]
        state_cols = [c for c in numeric if c not in used and c not in action_cols]
        text = [c for c in columns if c not in numeric and c not in used]
        if text:
            raise DataError(
                f"{path}: column {text[0]!r} is {table.column(text[0]).type}, not numeric; pass "
                "state=[...] (and action=[...]) to choose the columns to import"
            )
    if not state_cols and not action_cols:
        raise DataError(f"{path}: no state or action columns; pass state=[...] and/or action=[...]")
    for c in state_cols + action_cols:
        column(c)
    t_all = column(time).astype(np.float64) if time else None
    if t_all is None and fps is None:
        raise DataError(f"{path}: field 'fps' is required when no time column is given (time=COLUMN)")

    if episode:
        ids = column(episode, numeric=False)
        keys = list(dict.fromkeys(ids.tolist()))
        groups = [np.flatnonzero(ids == k) for k in keys]
    else:
        keys, groups = [None], [np.arange(table.num_rows)]

    episodes: list[dict[str, np.ndarray]] = []
    meta: list[dict] = []
    rate = fps
    for key, rows in zip(keys, groups):
        data: dict[str, np.ndarray] = {}
        if state_cols:
            data["observation.state"] = np.stack([column(c)[rows] for c in state_cols], axis=1)
        if action_cols:
            data["action"] = np.stack([column(c)[rows] for c in action_cols], axis=1)
        for name, arr in data.items():
            bad = first_bad_row(~np.isfinite(arr.astype(np.float64)))
            if bad >= 0:
                cols = state_cols if name == "observation.state" else action_cols
                c = next(c for j, c in enumerate(cols) if not np.isfinite(float(arr[bad, j])))
                raise DataError(f"{path}: column {c!r} is NaN or inf at row {int(rows[bad])}")
            big = first_bad_row(np.abs(arr.astype(np.float64)) > F32_MAX)
            if big >= 0:
                cols = state_cols if name == "observation.state" else action_cols
                c = next(c for j, c in enumerate(cols) if abs(float(arr[big, j])) > F32_MAX)
                raise DataError(
                    f"{path}: column {c!r} is {float(arr[big, cols.index(c)]):g} at row {int(rows[big])}, "
                    "beyond what float32 holds (3.4e38)"
                )
        if t_all is not None:
            t = t_all[rows]
            _check_time(t, str(path), time, offset=int(rows[0]))  # type: ignore[arg-type]
            data.update(_time_features(t))
            if rate is None:
                rate = _fps_from_time(t, str(path), time)  # type: ignore[arg-type]
        episodes.append(data)
        meta.append({"source": path.name, **({"episode": key} if key is not None else {})})
    names = {k: v for k, v in (("observation.state", state_cols), ("action", action_cols)) if v}
    assert rate is not None  # fps given, or measured from the time column above
    return from_arrays(
        episodes,
        fps=float(rate),
        task=task,
        names=names,  # type: ignore[arg-type]
        robot_type=robot_type,
        meta=meta,
    )


# ----------------------------------------------------------------------------- MATLAB


def import_mat(
    path: str | os.PathLike,
    mapping: dict[str, str | Sequence[str]] | None = None,
    fps: float | None = None,
    *,
    time: str | None = None,
    velocity: bool = False,
    task: str = "default",
    robot_type: str | None = None,
) -> LogDataset:
    """Import a MATLAB v5/v7 .mat file (scipy.io.loadmat) as a one-episode dataset.

    Example (EMPS: position `qm`, drive command `vir`, time `t`):
        import_mat("DATA_EMPS.mat", {"observation.state": ["qm"], "action": ["vir"]}, velocity=True)
        # observation.state = [qm, qm_dot], action = [vir], fps 1000, meta["mat"] = {gtau, kp, kv}

    Args:
        path: the .mat file.
        mapping: feature name -> variable names, concatenated as columns (a (T, k) variable adds k
            columns). Default: every length-T variable except time becomes `observation.state`.
        fps: frame rate; default 1 / median time step (snapped to an integer within 0.1 %).
        time: the time variable in seconds (default: the first of t, time, Time present).
        velocity: append the time derivative (central differences) of each `observation.state`
            column, named `<var>_dot`, for logs that measure position only.
        task: the episode's task string.
        robot_type: stored in info.json.

    Scalar variables (e.g. gains) go to the episode's `meta["mat"]`.
    """
    import scipy.io

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: file is missing")
    try:
        raw = scipy.io.loadmat(str(path))
    except NotImplementedError:
        raise DataError(f"{path}: MATLAB v7.3 (HDF5) files are not supported; save with -v7") from None
    except Exception as exc:  # scipy raises ValueError/TypeError/MatReadError on bad files
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DataError(f"{path}: cannot read .mat file: {reason}") from None
    variables = {k: v for k, v in raw.items() if not k.startswith("__")}
    numeric = {k: np.asarray(v) for k, v in variables.items() if isinstance(v, np.ndarray) and v.dtype.kind in "biuf"}
    if time is None:
        time = next((n for n in TIME_NAMES if n in numeric and numeric[n].size > 1), None)
    elif time not in numeric:
        hint = did_you_mean(time, variables)
        raise DataError(f"{path}: time variable {time!r} not found; variables: {', '.join(variables)}.{hint}")
    t = numeric[time].astype(np.float64).reshape(-1) if time else None
    if t is None and fps is None:
        raise DataError(f"{path}: field 'fps' is required: no time variable ({', '.join(TIME_NAMES)}) found")
    if t is not None:
        _check_time(t, str(path), time)  # type: ignore[arg-type]
        length = len(t)
    else:
        sizes = [max(v.shape) for v in numeric.values() if v.size > 1 and v.ndim <= 2]
        if not sizes:
            raise DataError(f"{path}: no vector variables")
        length = max(sizes)

    def columns(name: str) -> tuple[np.ndarray, list[str]]:
        if name not in variables:
            hint = did_you_mean(name, variables)
            raise DataError(f"{path}: variable {name!r} not found; variables: {', '.join(variables)}.{hint}")
        if name not in numeric or numeric[name].ndim > 2:
            raise DataError(f"{path}: variable {name!r} is not a numeric vector or matrix")
        v = numeric[name].astype(np.float64)
        if v.ndim == 1:
            v = v[:, None]
        if v.shape[0] != length and v.shape[1] == length:
            v = v.T
        if v.shape[0] != length:
            like = time or "the longest vector"
            shape = numeric[name].shape
            raise DataError(f"{path}: variable {name!r} has shape {shape}; expected {length} samples like {like!r}")
        row = first_bad_row(~np.isfinite(v))
        if row >= 0:
            raise DataError(f"{path}: variable {name!r} is NaN or inf at sample {row}")
        names = [name] if v.shape[1] == 1 else [f"{name}[{j}]" for j in range(v.shape[1])]
        return v, names

    if mapping is None:
        vectors = [k for k, v in numeric.items() if k != time and v.size > 1 and length in v.shape and v.ndim <= 2]
        mapping = {"observation.state": vectors}
    data: dict[str, np.ndarray] = {}
    names: dict[str, list[str]] = {}
    for feature, var_names in mapping.items():
        blocks = [columns(v) for v in _as_list(var_names) or []]
        if not blocks:
            raise DataError(f"{path}: mapping for {feature!r} names no variables")
        data[feature] = np.concatenate([b[0] for b in blocks], axis=1)
        names[feature] = [n for b in blocks for n in b[1]]
    if velocity:
        if "observation.state" not in data:
            raise DataError(f"{path}: velocity=True needs an 'observation.state' mapping")
        x = data["observation.state"]
        spacing = t if t is not None else 1.0 / float(fps)  # type: ignore[arg-type]
        dx = np.gradient(x, spacing, axis=0)
        data["observation.state"] = np.concatenate([x, dx], axis=1)
        names["observation.state"] = names["observation.state"] + [f"{n}_dot" for n in names["observation.state"]]
    rate = fps
    if t is not None:
        data.update(_time_features(t))
        rate = rate or _fps_from_time(t, str(path), time)  # type: ignore[arg-type]
    big = next((k for k, v in numeric.items() if v.size and np.abs(v.astype(np.float64)).max() > F32_MAX), None)
    if big is not None:
        raise DataError(f"{path}: variable {big!r} holds values beyond what float32 holds (3.4e38)")
    scalars = {k: float(v.reshape(-1)[0]) for k, v in numeric.items() if v.size == 1}
    odd = next((k for k, v in scalars.items() if not np.isfinite(v)), None)
    if odd is not None:  # metadata is JSON: NaN / inf has no place there
        raise DataError(f"{path}: scalar variable {odd!r} is {scalars[odd]}; metadata must be finite (drop or fix it)")
    meta = {"source": path.name, **({"mat": scalars} if scalars else {})}
    assert rate is not None  # fps given, or measured from the time column above
    return from_arrays(
        [data],
        fps=float(rate),
        task=task,
        names=names,  # type: ignore[arg-type]
        robot_type=robot_type,
        meta=[meta],
    )


# ----------------------------------------------------------------------------- RLDS (TFDS)


def _version_key(name: str) -> tuple:
    return tuple(int(p) if p.isdigit() else p for p in re.split(r"[.]", name))


def _resolve_rlds(path: Path, split: str) -> tuple[Path, list[Path]]:
    """(folder with features.json, shard files of `split`) for a version folder, dataset folder or shard."""
    if path.is_file():
        spec_dir, shards = path.parent, [path]
    else:
        spec_dir = path
        if not (spec_dir / "features.json").is_file():
            versions = (
                sorted(
                    (d for d in path.iterdir() if d.is_dir() and (d / "features.json").is_file()),
                    key=lambda d: _version_key(d.name),
                )
                if path.is_dir()
                else []
            )
            if not versions:
                raise DataError(f"{path / 'features.json'}: file is missing (not a TFDS/RLDS dataset folder?)")
            spec_dir = versions[-1]
        shards = sorted(p for p in spec_dir.glob(f"*-{split}.tfrecord*") if p.is_file())
        if not shards:
            names = (re.search(r"-(\w+)\.tfrecord", p.name) for p in spec_dir.glob("*.tfrecord*"))
            found = ", ".join(sorted({m.group(1) for m in names if m})) or "none"
            raise DataError(f"{spec_dir}: no tfrecord shards for split {split!r}; splits found: {found}")
    if not (spec_dir / "features.json").is_file():
        raise DataError(f"{spec_dir / 'features.json'}: file is missing (needed for feature shapes and dtypes)")
    return spec_dir, shards


def _leaves(node: dict, prefix: str, stepwise: bool, out: dict[str, dict], where: str) -> None:
    """Flatten a TFDS features.json tree into {"steps/observation/state": spec, ...}."""
    if "featuresDict" in node:
        for key, child in node["featuresDict"]["features"].items():
            _leaves(child, f"{prefix}{key}/", stepwise, out, where)
    elif "sequence" in node:
        _leaves(node["sequence"]["feature"], prefix, True, out, where)
    elif "tensor" in node or "image" in node:
        kind = "tensor" if "tensor" in node else "image"
        body = node[kind]
        dims = [int(d) for d in body.get("shape", {}).get("dimensions", [])]
        out[prefix[:-1]] = {
            "kind": kind,
            "dtype": body.get("dtype", "uint8"),
            "shape": dims,
            "stepwise": stepwise,
            "encoding": body.get("encoding", "none"),
        }
    elif "text" in node:
        out[prefix[:-1]] = {"kind": "text", "stepwise": stepwise}
    elif "classLabel" in node:
        out[prefix[:-1]] = {"kind": "tensor", "dtype": "int64", "shape": [], "stepwise": stepwise, "encoding": "none"}
    else:
        kinds = ", ".join(k for k in node if k != "pythonClassName")
        what = kinds or node.get("pythonClassName")
        raise DataError(f"{where}: feature {prefix[:-1]!r} has unsupported kind {what!r}")


def _decode_tensor(value: Any, spec: dict, key: str, where: str) -> np.ndarray:
    dtype = np.dtype(spec["dtype"])
    if spec["encoding"] in ("bytes", "zlib"):
        blobs = value if isinstance(value, list) else []
        raw = b"".join(zlib.decompress(b) if spec["encoding"] == "zlib" else b for b in blobs)
        return np.frombuffer(raw, dtype=dtype.newbyteorder("<")).astype(dtype)
    if spec["encoding"] != "none":
        raise DataError(f"{where}: feature {key!r} has unsupported tensor encoding {spec['encoding']!r}")
    if isinstance(value, list):
        raise DataError(f"{where}: feature {key!r} is stored as bytes but features.json declares {spec['dtype']}")
    arr = np.asarray(value)
    if dtype == np.bool_:
        return arr != 0
    if dtype.kind in "iu" and arr.dtype.kind == "f":
        raise DataError(f"{where}: feature {key!r} is stored as floats but features.json declares {spec['dtype']}")
    return arr.astype(dtype)


def _decode_image(blob: bytes, spec: dict, key: str, where: str) -> np.ndarray:
    from PIL import Image

    try:
        img: Image.Image = Image.open(io.BytesIO(blob))
        if spec["shape"] and spec["shape"][-1] == 3 and img.mode != "RGB":
            img = img.convert("RGB")
        pix = np.asarray(img)
    except Exception as exc:  # Pillow raises many kinds
        raise DataError(f"{where}: feature {key!r} holds an undecodable image: {exc}") from None
    return pix[:, :, None] if pix.ndim == 2 else pix


def _record_values(features: dict, lists: dict, key: str, spec: dict) -> Any:
    """A leaf's value in an Example (flattened steps) or a SequenceExample (one Feature per step)."""
    if not spec["stepwise"] or not lists:
        return features.get(key)
    rel = key.split("/", 1)[1] if key.startswith("steps/") else key
    per_step = lists.get(key, lists.get(rel))
    if per_step is None:
        return None
    if spec["kind"] in ("image", "text") or spec.get("encoding", "none") != "none":
        return [b for step in per_step for b in step]
    return np.concatenate([np.asarray(s) for s in per_step]) if per_step else np.zeros(0)


def _decode_record(buf: memoryview, leaves: dict[str, dict], where: str) -> tuple[dict, dict, int]:
    """(step arrays by leaf, episode values by leaf, number of steps) of one RLDS episode."""
    try:
        features, lists = tfrecord.parse_example(buf)
    except tfrecord.ProtoError as exc:
        raise DataError(f"{where}: not a tf.train.Example: {exc}") from None
    steps: dict[str, Any] = {}
    episode: dict[str, Any] = {}
    length: int | None = None
    first = ""
    for key, spec in leaves.items():
        value = _record_values(features, lists, key, spec)
        if value is None:
            raise DataError(f"{where}: feature {key!r} declared in features.json is missing")
        if spec["kind"] == "text":
            items = value if isinstance(value, list) else []
            decoded: Any = [b.decode("utf-8") if isinstance(b, bytes) else str(b) for b in items]
            n = len(decoded)
        elif spec["kind"] == "image":
            if not isinstance(value, list):
                raise DataError(f"{where}: image feature {key!r} is not stored as bytes")
            decoded = [_decode_image(b, spec, key, where) for b in value]
            for img in decoded:
                if spec["shape"] and all(d > 0 for d in spec["shape"]) and list(img.shape) != spec["shape"]:
                    raise DataError(
                        f"{where}: image feature {key!r} has shape {list(img.shape)}, "
                        f"features.json declares {spec['shape']}"
                    )
            n = len(decoded)
            decoded = np.stack(decoded) if decoded else np.zeros([0] + spec["shape"], dtype=np.uint8)
        else:
            flat = _decode_tensor(value, spec, key, where)
            per = int(np.prod([d for d in spec["shape"] if d > 0])) if spec["shape"] else 1
            if any(d <= 0 for d in spec["shape"]):
                raise DataError(f"{where}: feature {key!r} has an unknown dimension in features.json; not supported")
            if flat.size % per:
                raise DataError(
                    f"{where}: feature {key!r} has {flat.size} values, not a multiple of its shape {spec['shape']}"
                )
            n = flat.size // per
            decoded = flat.reshape([n] + spec["shape"])
        if spec["stepwise"]:
            if length is None:
                length, first = n, key
            elif n != length:
                raise DataError(f"{where}: feature {key!r} has {n} steps but {first!r} has {length}")
            steps[key] = decoded
        else:
            if spec["kind"] == "text":
                episode[key] = decoded[0] if len(decoded) == 1 else decoded
            elif spec["kind"] == "tensor" and decoded.size == 1:
                episode[key] = decoded.reshape(-1)[0].item()
            else:
                episode[key] = np.asarray(decoded).tolist()
    return steps, episode, int(length or 0)


def _feature_name(rel: str, spec: dict, state: str, action: str) -> str:
    if rel == state:
        return "observation.state"
    if rel == action:
        return "action"
    if spec["kind"] == "image":
        return "observation.images." + rel.split("/")[-1] if rel.startswith("observation/") else rel.replace("/", ".")
    return rel.replace("/", ".")


def import_rlds(
    path: str | os.PathLike,
    *,
    fps: float | None = None,
    split: str = "train",
    state: str = "observation/state",
    action: str = "action",
    instruction: str = "language_instruction",
    task: str = "default",
    robot_type: str | None = None,
    verify: bool = True,
) -> LogDataset:
    """Import RLDS episodes (TFDS tfrecord shards, the Open X-Embodiment layout) without TensorFlow.

    Feature shapes and dtypes come from the dataset's features.json. Each record is one episode
    (a tf.train.Example whose `steps/...` features hold the steps back to back). Episodes are
    ordered by `episode_metadata/episode_id` when present (TFDS shuffles them on disk) and the
    episode-level fields go to `Episode.meta`.

    Mapping: `steps/<state>` -> observation.state, `steps/<action>` -> action, images ->
    observation.images.<name>, `steps/<instruction>` -> the per-frame task, every other step
    tensor -> its path with dots (e.g. reward, is_last) as a (T, 1) or (T, D) feature.

    Args:
        path: a version folder (with features.json), a dataset folder holding version folders,
            or one tfrecord shard.
        fps: frame rate in Hz; required, RLDS stores none (BridgeData V2: 5).
        split: which shards to read (file names `<name>-<split>.tfrecord-*`).
        state, action, instruction: step paths (below `steps/`) of those fields.
        task: task string where an episode has no instruction.
        robot_type: stored in info.json.
        verify: check the TFRecord CRCs.
    """
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: file or folder is missing")
    if fps is None:
        raise DataError(f"{path}: field 'fps' is required: RLDS stores no frame rate (BridgeData V2 is 5 Hz)")
    spec_dir, shards = _resolve_rlds(path, split)
    spec_path = spec_dir / "features.json"
    try:
        spec_doc = json.loads(spec_path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError, UnicodeDecodeError, RecursionError, ValueError) as exc:
        raise DataError(f"{spec_path}: not valid JSON: {str(exc).splitlines()[0][:160]}") from None
    if not isinstance(spec_doc, dict):
        raise DataError(f"{spec_path}: expected a JSON object (a TFDS feature tree), found {type(spec_doc).__name__}")
    leaves: dict[str, dict] = {}
    try:
        _leaves(spec_doc, "", False, leaves, str(spec_path))
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise DataError(f"{spec_path}: not a TFDS feature tree ({type(exc).__name__}: {str(exc)[:120]})") from None
    for key, leaf in leaves.items():
        if leaf.get("kind") in ("tensor", "image"):
            try:
                np.dtype(leaf["dtype"])
            except TypeError:
                raise DataError(
                    f"{spec_path}: feature {key!r} has dtype {leaf['dtype']!r}, which is not a numpy "
                    "dtype (e.g. float32, uint8)"
                ) from None
    step_leaves = {k: v for k, v in leaves.items() if v["stepwise"]}
    if not step_leaves:
        raise DataError(f"{spec_path}: no step features (expected an RLDS 'steps' sequence)")
    for rel, label in ((state, "state"), (action, "action")):
        if f"steps/{rel}" not in step_leaves:
            rels = [k[len("steps/") :] for k in step_leaves]
            raise DataError(
                f"{spec_path}: field {label!r} names step feature {rel!r}, which is not there; "
                f"step features: {', '.join(rels)}.{did_you_mean(rel, rels)}"
            )

    records: list[tuple[dict, dict, int, str]] = []
    for shard in shards:
        for k, buf in enumerate(tfrecord.iter_records(shard, verify=verify)):
            where = f"{shard}: record {k}"
            steps, episode, length = _decode_record(buf, leaves, where)
            if length == 0:
                raise DataError(f"{where}: episode has no steps")
            records.append((steps, episode, length, f"{shard.name}#{k}"))
    if not records:
        raise DataError(f"{shards[0]}: no records")
    ids = [r[1].get("episode_metadata/episode_id") for r in records]
    if all(isinstance(i, int) for i in ids):
        records = [r for _, r in sorted(zip(ids, records), key=lambda p: p[0] if p[0] is not None else -1)]

    arrays: list[dict[str, np.ndarray]] = []
    per_frame_tasks: list[list[str]] = []
    metas: list[dict] = []
    text_key = f"steps/{instruction}"
    for steps, episode, length, source in records:
        named = {
            _feature_name(key[len("steps/") :], leaves[key], state, action): value
            for key, value in steps.items()
            if leaves[key]["kind"] != "text"
        }
        first = ["observation.state", "action"] + sorted(n for n in named if n.startswith("observation.images."))
        data = {n: named[n] for n in first if n in named}
        data.update((n, v) for n, v in named.items() if n not in data)
        words = steps.get(text_key) or [task] * length
        per_frame_tasks.append([w if w else task for w in words])
        meta = {
            k.split("/")[-1] if k.startswith("episode_metadata/") else k.replace("/", "."): v
            for k, v in episode.items()
        }
        meta["source"] = source
        metas.append(meta)
        arrays.append(data)
    firsts = [words[0] for words in per_frame_tasks]
    ds = from_arrays(arrays, fps=float(fps), task=firsts, robot_type=robot_type, meta=metas)
    _set_frame_tasks(ds, per_frame_tasks)
    return ds


def _set_frame_tasks(ds: LogDataset, per_frame: Iterable[list[str]]) -> None:
    """Per-frame task strings -> `ds.tasks`, each episode's `task_index` and `tasks`."""
    tasks: dict[str, int] = {}
    for ep, words in zip(ds.episodes, per_frame):
        for w in words:
            tasks.setdefault(w, len(tasks))
        ep.data["task_index"] = np.asarray([tasks[w] for w in words], dtype=np.int64)
        ep.tasks = list(dict.fromkeys(words))
    ds.tasks = list(tasks)

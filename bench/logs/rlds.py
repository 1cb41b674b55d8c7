"""RLDS (TFDS) episodes imported to a `LogDataset` without TensorFlow: the Open X-Embodiment layout.

Feature shapes and dtypes come from the dataset's features.json; records are read by
`bench.logs.tfrecord`. The in-memory form is the one every importer returns (`bench.logs.importers`).
"""

from __future__ import annotations

import io
import json
import os
import re
import zlib
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

import bench.logs.tfrecord as tfrecord
from bench.core.errors import DataError, did_you_mean
from bench.logs.dataset import LogDataset, from_arrays


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


def _decode_tensor(value: object, spec: dict, key: str, where: str) -> np.ndarray:
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
    from PIL import Image  # Pillow: loaded only when PNG images are read or written

    try:
        img: Image.Image = Image.open(io.BytesIO(blob))
        if spec["shape"] and spec["shape"][-1] == 3 and img.mode != "RGB":
            img = img.convert("RGB")
        pix = np.asarray(img)
    except Exception as exc:  # Pillow raises many kinds
        raise DataError(f"{where}: feature {key!r} holds an undecodable image: {exc}") from None
    return pix[:, :, None] if pix.ndim == 2 else pix


def _record_values(features: dict, lists: dict, key: str, spec: dict) -> object:
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
    steps: dict[str, object] = {}
    episode: dict[str, object] = {}
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

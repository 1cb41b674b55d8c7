"""Where a result came from: package versions, git sha, machine."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from collections.abc import Mapping
from functools import lru_cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from bench.core.errors import DataError
from bench.core.io import sha256_file

PACKAGES = (
    "bench-harness",
    "numpy",
    "scipy",
    "mujoco",
    "robosuite",
    "metaworld",
    "gymnasium",
    "pyarrow",
    "torch",
    "omegaconf",
    "mani-skill",
    "sapien",
)


@lru_cache(maxsize=1)
def package_versions() -> dict[str, str]:
    """Installed versions of the packages that can change a result (absent ones omitted)."""
    out = {}
    for name in PACKAGES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            pass
    return out


def installed_version(dist: str, module: object = None) -> str:
    """The installed version of distribution `dist`; without its metadata, `module.__version__` ("?" when absent)."""
    try:
        return version(dist)
    except PackageNotFoundError:
        return str(getattr(module, "__version__", "?"))


ROOT = Path(__file__).resolve().parents[2]  # the checkout (or install root) holding bench/ and baselines/
PATH_KEYS = ("checkpoint", "calibration", "record", "out")  # run keys (config) that name files or folders


def portable(path: str | os.PathLike[str] | None) -> str | None:
    """`path` as a result file records it: relative to the checkout when it lies inside it (the packaged BC
    checkpoint, a committed run), so a committed result names no folder of the machine that made it; any
    other path as it was given. Reading it back (`local`) resolves such a path against the checkout."""
    if path is None:
        return None
    p = Path(path)
    if not p.is_absolute():
        return str(path)
    try:
        return p.resolve().relative_to(ROOT).as_posix()
    except (ValueError, OSError):
        return str(path)


def local(path: str | os.PathLike[str]) -> Path:
    """A recorded path on this machine: as given when it exists here, else relative to the checkout (`portable`)."""
    p = Path(path)
    if p.is_absolute() or p.exists():
        return p
    inside = ROOT / p
    return inside if inside.exists() else p


def portable_config(config: Mapping[str, object]) -> dict[str, object]:
    """A run's flat config with its path keys (`PATH_KEYS`) made `portable`."""
    return {k: portable(v) if k in PATH_KEYS and isinstance(v, str) else v for k, v in config.items()}


@lru_cache(maxsize=1)
def git_sha() -> str | None:
    """The harness checkout's commit (with `-dirty` when it has local changes), or None."""
    root = ROOT
    try:
        sha = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=5,
        ).stdout.strip()
        return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return None


def machine() -> dict[str, object]:
    """Python, platform and core count of this machine."""
    return {
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "cores": os.cpu_count(),
    }


POLICY_SPEC_KEY = "bench.policy_spec"  # where a bench checkpoint keeps its policy spec (its `meta` = training)
SAFETENSORS_MAX_HEADER = 100 * 1024 * 1024  # the safetensors format's own limit


def safetensors_metadata(path: str | Path) -> dict[str, str] | None:
    """The `__metadata__` map of a .safetensors file's JSON header (None when it has none).

    Reads only the header (8-byte little-endian length, then JSON), never the tensors, and
    imports nothing: any safetensors file works, whoever wrote it.

    Raises:
        DataError: the file is too short or its header is not a JSON object.
    """
    path = Path(path)
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(8)
        n = int.from_bytes(head, "little") if len(head) == 8 else -1
        if n < 2 or n > min(SAFETENSORS_MAX_HEADER, size - 8):
            raise DataError(f"{path}: not a safetensors file (header length {n} of a {size}-byte file)")
        try:
            header = json.loads(fh.read(n).decode("utf-8"), parse_constant=lambda c: None)
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise DataError(f"{path}: safetensors header is not valid JSON ({str(exc).splitlines()[0]})") from None
    if not isinstance(header, dict):
        raise DataError(f"{path}: safetensors header is not a JSON object")
    meta = header.get("__metadata__")
    return {str(k): str(v) for k, v in meta.items()} if isinstance(meta, dict) else None


def checkpoint_provenance(
    path: str | Path, recorded_sha256: str | None = None, hash_file: bool = True
) -> dict[str, object]:
    """What identifies a checkpoint file: sha256, size, and the training metadata stored in it.

    Training metadata: the `meta` of the bench policy spec, read from the safetensors header
    (`__metadata__["bench.policy_spec"]`) or else from the spec beside the weights (PATH with
    `.json`); other header metadata is kept as is. A file that is gone or changed since a run
    recorded `recorded_sha256` gets a `note` saying so. With `hash_file=False` the file is
    taken to be `recorded_sha256` (the caller has just hashed it; checkpoints can be large).
    """
    p = local(path)
    out: dict[str, object] = {
        "path": str(path),
        "format": p.suffix.lstrip(".") or None,
        "sha256": recorded_sha256,
        "size_bytes": None,
        "architecture": None,
        "training": None,
        "metadata": None,
        "note": None,
    }
    if not p.is_file():
        out["note"] = "checkpoint file not found here; sha256 as recorded by the run"
        return out
    out["size_bytes"] = p.stat().st_size
    out["sha256"] = sha256_file(p) if hash_file or not recorded_sha256 else recorded_sha256
    if recorded_sha256 and recorded_sha256 != out["sha256"]:
        out["note"] = (
            f"the file changed since the run was recorded (recorded sha256 {recorded_sha256}); "
            "sha256 and metadata are the file's now"
        )
    spec = None
    try:
        meta = safetensors_metadata(p) if p.suffix == ".safetensors" else None
    except DataError as exc:
        out["note"] = str(exc)
        meta = None
    if meta:
        rest = {k: v[:2000] for k, v in meta.items() if k != POLICY_SPEC_KEY}
        out["metadata"] = rest or None
        if POLICY_SPEC_KEY in meta:
            try:
                spec = json.loads(meta[POLICY_SPEC_KEY], parse_constant=lambda c: None)
            except json.JSONDecodeError:
                out["note"] = f"header key {POLICY_SPEC_KEY} is not valid JSON"
    sidecar = p.with_suffix(".json")
    if spec is None and sidecar.is_file():
        try:
            spec = json.loads(sidecar.read_text(), parse_constant=lambda c: None)
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            spec = None
    if isinstance(spec, dict):
        out["architecture"] = spec.get("architecture") if isinstance(spec.get("architecture"), str) else None
        out["training"] = spec.get("meta") if isinstance(spec.get("meta"), dict) else None
    return out

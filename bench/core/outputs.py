"""The one rule for outputs: checked before the first byte is written, for every command.

An output (`out=`, `record=`, a run directory ...) is resolved (`~`, `..`, symlinks, the current folder) and
refused, with one line naming its key, when it

- equals, contains or lies inside any input of the command (a report written into the run it reads, an
  import over its own source, a leaderboard merged over one of its inputs);
- contains the current folder (replacing it would pull the folder from under the user's shell);
- is an existing file and `overwrite=true` was not given, or is an existing folder that holds anything
  bench did not write there (bench lists what it wrote in `.bench-outputs.json`; `overwrite=true` never
  removes anything else);
- cannot be written: a parent that is a file, a name component over 255 bytes, a folder without write
  permission.

Folders are built in a hidden temporary sibling and swapped in at the end (`replace_dir`), so an error
leaves nothing new behind and the old output intact until the new one is complete.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Literal

from bench.core.errors import ConfigError

MARKER = ".bench-outputs.json"
MAX_NAME_BYTES = 255

Kind = Literal["dir", "file"]
InputPath = str | os.PathLike[str] | None  # an input a command reads (None: not given)


def resolved(path: str | os.PathLike[str]) -> Path:
    """The absolute path `path` names, symlinks and `..` resolved (the path need not exist)."""
    return Path(path).expanduser().resolve(strict=False)


def _inside(child: Path, parent: Path) -> bool:
    return child != parent and child.is_relative_to(parent)


def written_by_bench(folder: Path) -> bool:
    """True when every entry of `folder` is listed in its marker (bench wrote all of it)."""
    marker = folder / MARKER
    try:
        listed = set(json.loads(marker.read_text(encoding="utf-8")).get("files", []))
    except (OSError, ValueError, AttributeError, UnicodeDecodeError):
        return False
    present = {p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file() or p.is_symlink()}
    return present - {MARKER} <= listed


def mark(folder: Path, extra: tuple[str, ...] = ()) -> None:
    """Write the marker listing every file now in `folder` (and `extra` names bench will add later)."""
    files = sorted({p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()} | set(extra))
    (folder / MARKER).write_text(
        json.dumps({"written_by": "bench", "files": [f for f in files if f != MARKER]}), encoding="utf-8"
    )


def remember(*paths: Path) -> None:
    """Add files bench just wrote to their folder's marker (so overwrite=true may replace them later)."""
    for path in paths:
        marker = path.parent / MARKER
        try:
            doc = json.loads(marker.read_text(encoding="utf-8"))
            files = set(doc.get("files", [])) if isinstance(doc, dict) else set()
        except (OSError, ValueError, UnicodeDecodeError):
            files = set()
        files.add(path.name)
        marker.write_text(json.dumps({"written_by": "bench", "files": sorted(files)}), encoding="utf-8")


def names_fit(key: str, shown: str, path: Path) -> None:
    for part in path.parts:
        if len(part.encode("utf-8", "surrogateescape")) > MAX_NAME_BYTES:
            raise ConfigError(
                f"{key}={shown!r}: the name {part[:40]!r}... is longer than {MAX_NAME_BYTES} bytes "
                "(the file system's limit); give a shorter name"
            )


def _writable(key: str, shown: str, path: Path) -> None:
    probe = path.parent
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise ConfigError(f"{key}={shown!r}: {str(probe)!r} is a file, not a folder; give a path under a folder")
    if not os.access(probe, os.W_OK | os.X_OK) or not probe.stat().st_mode & 0o222:  # root ignores permissions
        raise ConfigError(
            f"{key}={shown!r}: cannot write under {str(probe)!r} (permission denied); give a writable folder"
        )


def check(
    key: str,
    path: str | os.PathLike[str],
    inputs: Mapping[str, InputPath | Sequence[InputPath]],
    *,
    kind: Kind = "dir",
    overwrite: bool = False,
    resume: Callable[[Path], bool] | None = None,
    can_overwrite: bool = True,
) -> Path:
    """Validate one output against the rule above; returns its resolved path. Writes nothing.

    Args:
        key: the output's key as the user typed it (`out`, `record` ...), for the message.
        path: the output.
        inputs: key -> path (or a list of paths, or None) of everything the command reads.
        kind: "dir" for an output folder, "file" for an output file.
        overwrite: the command's `overwrite=true`: an existing bench-written output may be replaced.
        resume: for folders a command continues (a run directory): True when the existing folder is one
            this command may continue (then it is accepted as it is).
        can_overwrite: False for outputs the command has no `overwrite=` for (messages then ask for a new path).
    """
    again = "pass overwrite=true to replace it" if can_overwrite else "give a new one (nothing is overwritten)"
    shown = str(path)
    names_fit(key, shown, Path(path).expanduser().absolute())
    out = resolved(path)
    for in_key, value in inputs.items():
        values = [value] if value is None or isinstance(value, (str, os.PathLike)) else value
        for v in values:
            if v is None or v == "":
                continue
            src = resolved(v)
            if out == src:
                raise ConfigError(
                    f"{key}={shown!r} is the input {in_key}={str(v)!r}; write the output somewhere "
                    "else (nothing is written over an input)"
                )
            if _inside(src, out):
                raise ConfigError(
                    f"{key}={shown!r} contains the input {in_key}={str(v)!r}; give an output that "
                    "does not hold the input"
                )
            if _inside(out, src):
                raise ConfigError(
                    f"{key}={shown!r} lies inside the input {in_key}={str(v)!r}; give an output outside it"
                )
    cwd = Path.cwd().resolve()
    if out == cwd or _inside(cwd, out):
        raise ConfigError(f"{key}={shown!r} contains the current folder; give a new folder for the output")
    if out.exists() or out.is_symlink():
        if kind == "file":
            if out.is_dir():
                raise ConfigError(f"{key}={shown!r} is a folder; give a file name")
            if not overwrite:
                raise ConfigError(f"{key}={shown!r} exists; {again}")
            if not _bench_file(out):
                raise ConfigError(
                    f"{key}={shown!r} was not written by bench; overwrite=true only replaces bench's "
                    "own outputs (give a new file)"
                )
        else:
            if not out.is_dir():
                raise ConfigError(f"{key}={shown!r} exists and is a file, not a folder")
            if resume is not None and resume(out):
                return out
            if any(out.iterdir()):
                if not overwrite:
                    raise ConfigError(f"{key}={shown!r} exists and is not empty; {again}")
                if not written_by_bench(out):
                    raise ConfigError(
                        f"{key}={shown!r} holds files bench did not write there; overwrite=true only "
                        "replaces bench's own outputs (give a new folder)"
                    )
    _writable(key, shown, out)
    return out


def _bench_file(path: Path) -> bool:
    """A file bench wrote: listed in its folder's marker, or a JSON document with a `bench.*` schema."""
    marker = path.parent / MARKER
    try:
        if path.name in json.loads(marker.read_text(encoding="utf-8")).get("files", []):
            return True
    except (OSError, ValueError, AttributeError, UnicodeDecodeError):
        pass
    try:
        with open(path, "rb") as fh:
            doc = json.loads(fh.read(64 * 2**20))
    except (OSError, ValueError, UnicodeDecodeError):
        return False
    return isinstance(doc, dict) and str(doc.get("schema", "")).startswith("bench.")


def replace_dir(out: Path, build: Callable[[Path], object]) -> Path:
    """Build a folder in a hidden temporary sibling of `out`, mark it, and swap it in for `out`.

    `out` must have passed `check` (an existing `out` is bench's own). On any error the temporary folder
    is removed and `out` is left as it was.
    """
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        build(tmp)
        mark(tmp)
        os.chmod(tmp, 0o755)
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.", dir=out.parent))
            os.replace(out, old / "x")
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out

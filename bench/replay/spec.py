"""Signal map: which MJCF model a log is replayed in and where its quantities live in the log.

A signal map is the part of a spec file that replay needs: `model` (an MJCF path, relative to
the spec file), `substeps` (simulator steps per log frame) and `signals` (log column and indices
of qpos, qvel, ctrl and extra inputs). The calibration spec (`bench.calibrate.spec`) extends it
with free parameters, effects and the held-out split; `bench replay spec=` reads such a file and
ignores what it adds. Every problem is a one-line `SpecError` that names the field.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, TypedDict, TypeGuard, overload

import yaml

from bench.core.errors import SpecError, did_you_mean, valid_choices
from bench.core.provenance import portable


class _Loader(yaml.SafeLoader):
    """YAML 1.1 reads `1e6` and `-1.0e6` as strings (it wants `1.0e+6`); spec files read them as the numbers
    everybody means (YAML 1.2's float rule)."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)

MAP_KEYS = ("model", "substeps", "signals")
MAX_SUBSTEPS = 10_000  # simulator steps per log frame: more is a typo, and multiplies every rollout
SIGNAL_NAMES = ("qpos", "qvel", "ctrl", "inputs")
SIGNAL_KEYS = ("column", "index")


@dataclass(frozen=True)
class SignalSpec:
    """Where one simulator quantity lives in the log: a column and the indices within it."""

    column: str
    index: tuple[int, ...]


@dataclass(frozen=True)
class SignalMap:
    """A parsed signal map (model path resolved against the spec file)."""

    model: Path
    signals: dict[str, SignalSpec]
    substeps: int | None = None
    source: Path | None = None

    def to_json(self) -> dict[str, object]:
        """JSON-able form, for embedding the signal map in a result file."""
        return {
            "model": str(self.model),
            "substeps": self.substeps,
            "signals": {k: {"column": s.column, "index": list(s.index)} for k, s in self.signals.items()},
            "source": portable(self.source),  # relative to the checkout when inside it
        }


def read_spec_file(path: str | Path) -> tuple[object, Path]:
    """The raw mapping of a YAML or JSON spec file, and its path."""
    path = Path(path)
    if not path.is_file():
        raise SpecError(f"spec file {str(path)!r} does not exist")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise SpecError(f"spec {str(path)!r} is not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    try:
        raw = json.loads(text) if path.suffix == ".json" else yaml.load(text, Loader=_Loader)  # noqa: S506 (a SafeLoader)
    except (yaml.YAMLError, ValueError, RecursionError) as exc:  # ValueError: bad JSON, integers of 4300+ digits
        first = str(exc).splitlines()[0][:160] if str(exc) else type(exc).__name__
        kind = "JSON" if path.suffix == ".json" else "YAML"
        raise SpecError(f"spec {str(path)!r} is not valid {kind}: {first}") from None
    return raw, path


def check_keys(obj: object, valid: tuple[str, ...], where: str) -> dict:
    """`obj` as a mapping whose keys are all in `valid` (else a SpecError naming the first stranger)."""
    if not isinstance(obj, dict):
        raise SpecError(f"spec field {where!r} must be a mapping with keys {', '.join(valid)}; got {obj!r}")
    for key in obj:
        if key not in valid:
            name = (where + "." if where else "") + str(key)
            raise SpecError(f"unknown spec field {name!r}; {valid_choices(str(key), valid)}")
    return obj


def _finite(value: object) -> TypeGuard[int | float]:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


@overload
def number(value: object, where: str, *, lo: float = ..., hi: float = ..., integer: Literal[False] = ...) -> float: ...


@overload
def number(value: object, where: str, *, lo: float = ..., hi: float = ..., integer: Literal[True]) -> int: ...


def number(value: object, where: str, *, lo: float = -math.inf, hi: float = math.inf, integer: bool = False) -> float:
    """A finite number (int when `integer`) within [lo, hi], else a SpecError naming the field."""
    if not _finite(value) or (integer and not float(value).is_integer()) or not lo <= value <= hi:
        kind = "an integer" if integer else "a number"
        rng = f" in [{lo}, {hi}]" if (math.isfinite(lo) or math.isfinite(hi)) else ""
        raise SpecError(f"spec field {where!r} must be {kind}{rng}; got {value!r}")
    return int(value) if integer else float(value)


def parse_signal(raw: object, where: str) -> SignalSpec:
    """One `{column, index}` signal entry of a spec."""
    raw = check_keys(raw, SIGNAL_KEYS, where)
    if not isinstance(raw.get("column"), str) or not raw["column"]:
        raise SpecError(f"spec field {where + '.column'!r} must be a log column name; got {raw.get('column')!r}")
    index = raw.get("index")
    if isinstance(index, int) and not isinstance(index, bool):
        index = [index]
    if not isinstance(index, (list, tuple)) or not index:
        raise SpecError(f"spec field {where + '.index'!r} must be a non-empty list of column indices; got {index!r}")
    idx = tuple(number(i, where + ".index", lo=0, integer=True) for i in index)
    return SignalSpec(column=raw["column"], index=idx)


class MapFields(TypedDict):
    """The signal-map fields of a spec (`map_fields`): a `SignalMap`'s keywords but its source."""

    model: Path
    signals: dict[str, SignalSpec]
    substeps: int | None


def map_fields(raw: dict, base_dir: str | Path) -> MapFields:
    """Validate the signal-map keys of a spec mapping: {'model', 'signals', 'substeps'} for a constructor."""
    if not isinstance(raw.get("model"), str) or not raw["model"]:
        raise SpecError(f"spec field 'model' must be the path of an MJCF file; got {raw.get('model')!r}")
    model = (Path(base_dir) / raw["model"]).resolve()
    if not model.is_file():
        raise SpecError(f"spec field 'model': MJCF file {str(model)!r} does not exist")
    signals_raw = check_keys(raw.get("signals"), SIGNAL_NAMES, "signals")
    for required in ("qpos", "ctrl"):
        if required not in signals_raw:
            raise SpecError(f"spec field 'signals.{required}' is required (column and index of the logged {required})")
    signals = {k: parse_signal(v, f"signals.{k}") for k, v in signals_raw.items()}
    given = raw.get("substeps")
    substeps = None if given is None else number(given, "substeps", lo=1, hi=MAX_SUBSTEPS, integer=True)
    return {"model": model, "signals": signals, "substeps": substeps}


def load_signal_map(path: str | Path) -> tuple[SignalMap, dict[str, object]]:
    """Read the signal map of a spec file; what it ignores (a calibration spec's own fields) is returned.

    An ignored key close to a signal-map key ('substep') is taken for a typo and refused.
    """
    raw, path = read_spec_file(path)
    if not isinstance(raw, dict):
        raise SpecError(f"spec {str(path)!r} must be a mapping with keys {', '.join(MAP_KEYS)}; got {raw!r}")
    ignored = {str(k): v for k, v in raw.items() if k not in MAP_KEYS}
    for key in ignored:
        hint = did_you_mean(key, MAP_KEYS)
        if hint:
            raise SpecError(
                f"unknown spec field {key!r}; valid: {', '.join(MAP_KEYS)} (and a calibration "
                f"spec's own fields, which replay ignores).{hint}"
            )
    return SignalMap(**map_fields(raw, path.parent), source=path), ignored


def load_model(path: Path):
    """Compile an MJCF file; compile errors become a one-line SpecError."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        raise SpecError(f"spec field 'model': cannot compile {str(path)!r}: {str(exc).splitlines()[0]}") from None

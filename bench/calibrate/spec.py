"""Calibration spec: the model, the log columns it is compared with, its free parameters, the effects to try.

A spec is YAML or JSON (see docs/calibration.md). Parsing checks the spec on its own; the names it
uses are checked against the model in `bench.calibrate.model` and against the data in
`bench.calibrate.data`. Every problem is a one-line `SpecError` that names the field.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.errors import SpecError, did_you_mean

SPEC_KEYS = ("model", "substeps", "signals", "params", "effects", "holdout", "horizon", "trace", "threads")
SIGNAL_NAMES = ("qpos", "qvel", "ctrl", "inputs")
SIGNAL_KEYS = ("column", "index")
PARAM_KEYS = ("name", "field", "elements", "bounds", "column", "init")
EFFECT_KEYS = ("name", "targets", "bounds")
TRACE_KEYS = ("margin", "max_effects", "max_tries", "min_score", "criterion", "max_segments")


@dataclass(frozen=True)
class SignalSpec:
    """Where one simulator quantity lives in the log: a column and the indices within it."""

    column: str
    index: tuple[int, ...]


@dataclass(frozen=True)
class ParamSpec:
    """A declared free parameter: one value per element of an `MjModel` field, within bounds."""

    name: str
    field: str
    elements: tuple[str, ...]
    bounds: tuple[float, float]
    column: int | None = None
    init: float | None = None


@dataclass(frozen=True)
class EffectRequest:
    """An effect family to try, optionally restricted to some targets or given explicit bounds."""

    name: str
    targets: tuple[str, ...] | None = None
    bounds: tuple[tuple[float, float], ...] | None = None


@dataclass(frozen=True)
class TraceSpec:
    """Knobs of the add / refit / accept loop."""

    margin: float = 0.05  # held-out error must drop by this share
    max_effects: int = 3
    max_tries: int = 3  # candidates refitted per round before giving up
    min_score: float = 0.02  # share of the held-out residual a candidate must explain to be tried
    criterion: str = "bic"  # "bic" or "aic"
    max_segments: int = 400  # training horizons used by the fit (a seeded subset beyond this)


@dataclass(frozen=True)
class CalibrationSpec:
    """A parsed, self-consistent calibration spec (model path resolved against the spec file)."""

    model: Path
    signals: dict[str, SignalSpec]
    params: tuple[ParamSpec, ...] = ()
    effects: tuple[EffectRequest, ...] | None = None  # None = all
    substeps: int | None = None
    holdout: float = 0.3
    horizon: float = 0.2  # seconds per truncated horizon (the k of k-step errors)
    trace: TraceSpec = field(default_factory=TraceSpec)
    threads: int = 1
    source: Path | None = None

    def to_json(self) -> dict[str, Any]:
        """JSON-able form, for embedding the exact spec in a result file."""
        return {
            "model": str(self.model),
            "substeps": self.substeps,
            "signals": {k: {"column": s.column, "index": list(s.index)} for k, s in self.signals.items()},
            "params": [
                {"name": p.name, "field": p.field, "elements": list(p.elements), "bounds": list(p.bounds),
                 **({"column": p.column} if p.column is not None else {}),
                 **({"init": p.init} if p.init is not None else {})}
                for p in self.params
            ],
            "effects": "all" if self.effects is None else [
                {"name": e.name, **({"targets": list(e.targets)} if e.targets else {}),
                 **({"bounds": [list(b) for b in e.bounds]} if e.bounds else {})} for e in self.effects
            ],
            "holdout": self.holdout,
            "horizon": self.horizon,
            "trace": dict(self.trace.__dict__),
            "source": str(self.source) if self.source else None,
        }


def load_spec(path: str | Path) -> CalibrationSpec:
    """Read a YAML or JSON spec file; the model path is taken relative to the spec's folder."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise SpecError(f"spec file {str(path)!r} does not exist")
    text = path.read_text()
    try:
        raw = json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
    except (yaml.YAMLError, json.JSONDecodeError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        kind = "JSON" if path.suffix == ".json" else "YAML"
        raise SpecError(f"spec {str(path)!r} is not valid {kind}: {first}") from None
    return parse_spec(raw, base_dir=path.parent, source=path)


def _check_keys(obj: Any, valid: tuple[str, ...], where: str) -> dict:
    if not isinstance(obj, dict):
        raise SpecError(f"spec field {where!r} must be a mapping with keys {', '.join(valid)}; got {obj!r}")
    for key in obj:
        if key not in valid:
            raise SpecError(f"unknown spec field {(where + '.' if where else '') + str(key)!r}; "
                            f"valid: {', '.join(valid)}.{did_you_mean(str(key), valid)}")
    return obj


def _number(value: Any, where: str, *, lo: float = -math.inf, hi: float = math.inf, integer: bool = False) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok and integer:
        ok = float(value).is_integer()
    if not ok or not lo <= value <= hi:
        kind = "an integer" if integer else "a number"
        rng = f" in [{lo}, {hi}]" if (math.isfinite(lo) or math.isfinite(hi)) else ""
        raise SpecError(f"spec field {where!r} must be {kind}{rng}; got {value!r}")
    return int(value) if integer else float(value)


def _bounds(value: Any, where: str) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise SpecError(f"spec field {where!r} must be [low, high]; got {value!r}")
    lo, hi = (_number(v, where) for v in value)
    if not lo < hi:
        raise SpecError(f"spec field {where!r} must have low < high; got {list(value)}")
    return lo, hi


def _names(value: Any, where: str) -> tuple[str, ...]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, (list, tuple)) or not value or not all(isinstance(v, str) for v in value):
        raise SpecError(f"spec field {where!r} must be a non-empty list of names; got {value!r}")
    return tuple(value)


def _signal(raw: Any, where: str) -> SignalSpec:
    raw = _check_keys(raw, SIGNAL_KEYS, where)
    if not isinstance(raw.get("column"), str) or not raw["column"]:
        raise SpecError(f"spec field {where + '.column'!r} must be a log column name; got {raw.get('column')!r}")
    index = raw.get("index")
    if isinstance(index, int) and not isinstance(index, bool):
        index = [index]
    if not isinstance(index, (list, tuple)) or not index:
        raise SpecError(f"spec field {where + '.index'!r} must be a non-empty list of column indices; got {index!r}")
    idx = tuple(_number(i, where + ".index", lo=0, integer=True) for i in index)
    return SignalSpec(column=raw["column"], index=idx)


def _effects(raw: Any) -> tuple[EffectRequest, ...] | None:
    from bench.calibrate.effects import EFFECTS

    if raw is None or raw == "all":
        return None
    if raw == "none":
        return ()
    if isinstance(raw, str):
        raw = [raw]
    if not isinstance(raw, (list, tuple)):
        raise SpecError(f"spec field 'effects' must be 'all', 'none' or a list of effect names; got {raw!r}")
    out = []
    for i, item in enumerate(raw):
        where = f"effects[{i}]"
        if isinstance(item, str):
            item = {"name": item}
        item = _check_keys(item, EFFECT_KEYS, where)
        name = item.get("name")
        if name not in EFFECTS:
            raise SpecError(f"spec field {where + '.name'!r}: unknown effect {name!r}; valid: "
                            f"{', '.join(EFFECTS)}.{did_you_mean(str(name), EFFECTS)}")
        targets = _names(item["targets"], where + ".targets") if "targets" in item else None
        bounds = None
        if "bounds" in item:
            b = item["bounds"]
            nparam = len(EFFECTS[name].params)
            if nparam == 1 and isinstance(b, (list, tuple)) and len(b) == 2 and not isinstance(b[0], (list, tuple)):
                b = [b]
            if not isinstance(b, (list, tuple)) or len(b) != nparam:
                raise SpecError(f"spec field {where + '.bounds'!r} needs {nparam} [low, high] pairs for "
                                f"{', '.join(EFFECTS[name].params)}; got {item['bounds']!r}")
            bounds = tuple(_bounds(x, where + ".bounds") for x in b)
        out.append(EffectRequest(name=name, targets=targets, bounds=bounds))
    return tuple(out)


def parse_spec(raw: Any, base_dir: str | Path = ".", source: Path | None = None) -> CalibrationSpec:
    """Validate a spec mapping (as loaded from YAML/JSON) and return a `CalibrationSpec`."""
    raw = _check_keys(raw, SPEC_KEYS, "")
    if not isinstance(raw.get("model"), str) or not raw["model"]:
        raise SpecError(f"spec field 'model' must be the path of an MJCF file; got {raw.get('model')!r}")
    model = (Path(base_dir) / raw["model"]).resolve()
    if not model.is_file():
        raise SpecError(f"spec field 'model': MJCF file {str(model)!r} does not exist")
    signals_raw = _check_keys(raw.get("signals"), SIGNAL_NAMES, "signals")
    for required in ("qpos", "ctrl"):
        if required not in signals_raw:
            raise SpecError(f"spec field 'signals.{required}' is required (column and index of the logged {required})")
    signals = {k: _signal(v, f"signals.{k}") for k, v in signals_raw.items()}
    params_raw = raw.get("params") or []
    if not isinstance(params_raw, list):
        raise SpecError(f"spec field 'params' must be a list of parameter mappings; got {params_raw!r}")
    params, seen = [], set()
    for i, p in enumerate(params_raw):
        where = f"params[{i}]"
        p = _check_keys(p, PARAM_KEYS, where)
        for key in ("field", "elements", "bounds"):
            if key not in p:
                raise SpecError(f"spec field {where + '.' + key!r} is required")
        if not isinstance(p["field"], str):
            raise SpecError(f"spec field {where + '.field'!r} must be an MjModel field name; got {p['field']!r}")
        name = str(p.get("name") or p["field"])
        if name in seen:
            raise SpecError(f"spec field {where + '.name'!r}: parameter name {name!r} is used twice")
        seen.add(name)
        column = _number(p["column"], where + ".column", lo=0, integer=True) if "column" in p else None
        init = _number(p["init"], where + ".init") if "init" in p else None
        params.append(ParamSpec(name=name, field=p["field"], elements=_names(p["elements"], where + ".elements"),
                                bounds=_bounds(p["bounds"], where + ".bounds"), column=column, init=init))
    substeps = raw.get("substeps")
    if substeps is not None:
        substeps = _number(substeps, "substeps", lo=1, integer=True)
    trace_raw = _check_keys(raw.get("trace") or {}, TRACE_KEYS, "trace")
    trace_kw: dict[str, Any] = {}
    for key, value in trace_raw.items():
        if key == "criterion":
            if value not in ("bic", "aic"):
                raise SpecError(f"spec field 'trace.criterion' must be 'bic' or 'aic'; got {value!r}")
            trace_kw[key] = value
        elif key in ("max_effects", "max_tries", "max_segments"):
            trace_kw[key] = _number(value, f"trace.{key}", lo=0 if key == "max_effects" else 1, integer=True)
        else:
            trace_kw[key] = _number(value, f"trace.{key}", lo=0, hi=1)
    return CalibrationSpec(
        model=model,
        signals=signals,
        params=tuple(params),
        effects=_effects(raw.get("effects", "all")),
        substeps=substeps,
        holdout=_number(raw.get("holdout", 0.3), "holdout", lo=0.05, hi=0.9),
        horizon=_number(raw.get("horizon", 0.2), "horizon", lo=1e-6),
        trace=TraceSpec(**trace_kw),
        threads=_number(raw.get("threads", 1), "threads", lo=1, hi=64, integer=True),
        source=source,
    )

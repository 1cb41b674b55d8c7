"""Calibration spec: a signal map (model, log columns) extended with free parameters and effects to try.

A spec is YAML or JSON (see docs/calibration.md). Its `model`, `substeps` and `signals` are the
signal map that replay reads (`bench.replay.spec`); this module adds `params`, `effects`,
`holdout` (a share, or a window [t0, t1] in seconds of a one-episode log), `holdout_at` (where the
share sits: least_repeated, end or episodes; `bench.calibrate.novelty`), `period` (the excitation's,
in seconds, when known), `horizon`, `trace` and `threads`. Parsing checks the spec on its own; the names it
uses are checked against the model in `bench.calibrate.model` and against the data in
`bench.replay.data.extract`. Every problem is a one-line `SpecError` that names the field.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.calibrate.effects import EFFECTS
from bench.calibrate.feedback import gains
from bench.core.errors import SpecError, did_you_mean, valid_choices
from bench.replay.spec import MAP_KEYS, SignalMap, check_keys, map_fields, number, read_spec_file

MAX_HORIZON_S = 3600.0  # seconds per truncated horizon: longer is a typo (a free run is the whole episode anyway)
SPEC_KEYS = (
    *MAP_KEYS,
    "params",
    "effects",
    "holdout",
    "holdout_at",
    "period",
    "horizon",
    "trace",
    "threads",
    "controller",
)
HOLDOUT_AT = ("least_repeated", "end", "episodes")  # where the held-out share sits (bench.calibrate.novelty)
PARAM_KEYS = ("name", "field", "elements", "bounds", "column", "init", "scale")
EFFECT_KEYS = ("name", "targets", "bounds")
TRACE_KEYS = ("margin", "max_effects", "max_tries", "min_score", "criterion", "max_segments")


# What a bound may not cross: MjModel fields that are physically non-negative, with the quantity's name
# for the message (an effect's parameters carry theirs: `Effect.limits`).
PHYSICAL_FIELDS = {
    "body_mass": "a mass",
    "body_inertia": "an inertia",
    "dof_damping": "a damping",
    "dof_armature": "an armature",
    "dof_frictionloss": "a friction loss",
    "jnt_stiffness": "a joint stiffness",
    "geom_friction": "a friction coefficient",
    "tendon_damping": "a tendon damping",
    "tendon_stiffness": "a tendon stiffness",
    "tendon_frictionloss": "a tendon friction loss",
}


def _physical(bounds: tuple[float, float], what: str, top: float | None, quantity: str, where: str) -> None:
    """SpecError when `bounds` reach below 0 (or above `top`), where `what` would stop being physical."""
    lo, hi = bounds
    if lo < 0 or (top is not None and hi > top):
        valid = f"[0, {top:g}]" if top is not None else "[0, inf)"
        raise SpecError(
            f"spec field {where!r}: {[lo, hi]} lets {quantity} go {'negative' if lo < 0 else f'above {top:g}'}, "
            f"which {what} cannot; valid: bounds within {valid}"
        )


@dataclass(frozen=True)
class ParamSpec:
    """A declared free parameter: one value per element of an `MjModel` field, within bounds."""

    name: str
    field: str
    elements: tuple[str, ...]
    bounds: tuple[float, float]
    column: int | None = None
    init: float | None = None
    scale: bool = False  # one factor on every element's nominal value instead of one value per element


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
class CalibrationSpec(SignalMap):
    """A parsed, self-consistent calibration spec: the signal map plus what the calibration fits and tries."""

    params: tuple[ParamSpec, ...] = ()
    effects: tuple[EffectRequest, ...] | None = None  # None = all
    holdout: float = 0.3  # share of the log held out
    horizon: float = 0.2  # seconds per truncated horizon (the k of k-step errors)
    trace: TraceSpec = field(default_factory=TraceSpec)
    threads: int = 1
    controller: tuple[tuple[float, ...], tuple[float, ...]] | None = None  # (kp, kd) per actuator: the log's loop
    holdout_window: tuple[float, float] | None = None  # or these seconds (from its first frame) of a one-episode log
    holdout_at: str = "least_repeated"  # where the share sits: least_repeated | end | episodes
    period: float | None = None  # seconds: the excitation's period, when known (else detected)

    def to_json(self) -> dict[str, object]:
        """JSON-able form, for embedding the exact spec in a result file."""
        head = super().to_json()
        source = head.pop("source")
        return {
            **head,
            "params": [
                {
                    "name": p.name,
                    "field": p.field,
                    "elements": list(p.elements),
                    "bounds": list(p.bounds),
                    **({"column": p.column} if p.column is not None else {}),
                    **({"init": p.init} if p.init is not None else {}),
                    **({"scale": True} if p.scale else {}),
                }
                for p in self.params
            ],
            "effects": "all"
            if self.effects is None
            else [
                {
                    "name": e.name,
                    **({"targets": list(e.targets)} if e.targets else {}),
                    **({"bounds": [list(b) for b in e.bounds]} if e.bounds else {}),
                }
                for e in self.effects
            ],
            "holdout": list(self.holdout_window) if self.holdout_window else self.holdout,
            "holdout_at": self.holdout_at,
            "period": self.period,
            "horizon": self.horizon,
            "trace": dict(self.trace.__dict__),
            **(
                {"controller": {"kp": list(self.controller[0]), "kd": list(self.controller[1])}}
                if self.controller
                else {}
            ),
            "source": source,
        }


def load_spec(path: str | Path) -> CalibrationSpec:
    """Read a YAML or JSON spec file; the model path is taken relative to the spec's folder."""
    raw, path = read_spec_file(path)
    if isinstance(raw, dict) and raw.get("method") == "idim":
        raise SpecError(
            f"spec {str(path)!r} asks for method: idim (a real arm's inverse dynamics); read it with "
            "bench.calibrate.arm.spec.load_arm_spec (bench calibrate does)"
        )
    return parse_spec(raw, base_dir=path.parent, source=path)


def _bounds(value: object, where: str) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise SpecError(f"spec field {where!r} must be [low, high]; got {value!r}")
    lo, hi = (number(v, where) for v in value)
    if not lo < hi:
        raise SpecError(f"spec field {where!r} must have low < high; got {list(value)}")
    return lo, hi


def _names(value: object, where: str) -> tuple[str, ...]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, (list, tuple)) or not value or not all(isinstance(v, str) for v in value):
        raise SpecError(f"spec field {where!r} must be a non-empty list of names; got {value!r}")
    return tuple(value)


def _effects(raw: object) -> tuple[EffectRequest, ...] | None:
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
        item = check_keys(item, EFFECT_KEYS, where)
        name = item.get("name")
        if name not in EFFECTS:
            raise SpecError(
                f"spec field {where + '.name'!r}: unknown effect {name!r}; valid: "
                f"{', '.join(EFFECTS)}.{did_you_mean(str(name), EFFECTS)}"
            )
        targets = _names(item["targets"], where + ".targets") if "targets" in item else None
        bounds = None
        if "bounds" in item:
            b = item["bounds"]
            nparam = len(EFFECTS[name].params)
            if nparam == 1 and isinstance(b, (list, tuple)) and len(b) == 2 and not isinstance(b[0], (list, tuple)):
                b = [b]
            if not isinstance(b, (list, tuple)) or len(b) != nparam:
                raise SpecError(
                    f"spec field {where + '.bounds'!r} needs {nparam} [low, high] pairs for "
                    f"{', '.join(EFFECTS[name].params)}; got {item['bounds']!r}"
                )
            bounds = tuple(_bounds(x, where + ".bounds") for x in b)
            for param, pair in zip(EFFECTS[name].params, bounds):
                if param in EFFECTS[name].limits:
                    what, top = EFFECTS[name].limits[param]
                    _physical(pair, what, top, f"{name}'s {param}", where + ".bounds")
        out.append(EffectRequest(name=name, targets=targets, bounds=bounds))
    return tuple(out)


def parse_holdout(raw: object) -> tuple[float, tuple[float, float] | None]:
    """The `holdout` of a spec: a share of the log, or a window [t0, t1] in seconds (share 0 then)."""
    if isinstance(raw, (list, tuple)):
        if len(raw) != 2:
            raise SpecError(
                f"spec field 'holdout' must be a share (0.05-0.9) or a window [t0, t1] in seconds; got {raw!r}"
            )
        t0, t1 = (number(v, "holdout", lo=0.0) for v in raw)
        if t1 <= t0:
            raise SpecError(f"spec field 'holdout': the window [{t0:g}, {t1:g}] s is empty (t1 must exceed t0)")
        return 0.0, (t0, t1)
    return number(raw, "holdout", lo=0.05, hi=0.9), None


def parse_trace(raw: object) -> TraceSpec:
    """The `trace` mapping of a spec (the loop's knobs; defaults for what it leaves out)."""
    trace_raw = check_keys(raw or {}, TRACE_KEYS, "trace")
    trace_kw: dict[str, Any] = {}  # TraceSpec keywords of several types
    for key, value in trace_raw.items():
        if key == "criterion":
            if value not in ("bic", "aic"):
                raise SpecError(f"spec field 'trace.criterion' must be 'bic' or 'aic'; got {value!r}")
            trace_kw[key] = value
        elif key in ("max_effects", "max_tries", "max_segments"):
            trace_kw[key] = number(value, f"trace.{key}", lo=0 if key == "max_effects" else 1, integer=True)
        else:
            trace_kw[key] = number(value, f"trace.{key}", lo=0, hi=1)
    return TraceSpec(**trace_kw)


def parse_spec(raw: object, base_dir: str | Path = ".", source: Path | None = None) -> CalibrationSpec:
    """Validate a spec mapping (as loaded from YAML/JSON) and return a `CalibrationSpec`."""
    raw = check_keys(raw, SPEC_KEYS, "")
    base = map_fields(raw, base_dir)
    params_raw = raw.get("params") or []
    if not isinstance(params_raw, list):
        raise SpecError(f"spec field 'params' must be a list of parameter mappings; got {params_raw!r}")
    params, seen = [], set()
    for i, p in enumerate(params_raw):
        where = f"params[{i}]"
        p = check_keys(p, PARAM_KEYS, where)
        for key in ("field", "elements", "bounds"):
            if key not in p:
                raise SpecError(f"spec field {where + '.' + key!r} is required")
        if not isinstance(p["field"], str):
            raise SpecError(f"spec field {where + '.field'!r} must be an MjModel field name; got {p['field']!r}")
        name = str(p.get("name") or p["field"])
        if name in seen:
            raise SpecError(f"spec field {where + '.name'!r}: parameter name {name!r} is used twice")
        seen.add(name)
        column = number(p["column"], where + ".column", lo=0, integer=True) if "column" in p else None
        init = number(p["init"], where + ".init") if "init" in p else None
        scale = p.get("scale", False)
        if not isinstance(scale, bool):
            raise SpecError(f"spec field {where + '.scale'!r} must be true or false; got {scale!r}")
        bounds = _bounds(p["bounds"], where + ".bounds")
        if p["field"] in PHYSICAL_FIELDS:  # a factor (scale: true) on a non-negative value must not be negative either
            what = PHYSICAL_FIELDS[p["field"]]
            quantity = f"the factor on {p['field']}" if scale else p["field"]
            _physical(bounds, what, None, quantity, where + ".bounds")
        params.append(
            ParamSpec(
                name=name,
                field=p["field"],
                elements=_names(p["elements"], where + ".elements"),
                bounds=bounds,
                column=column,
                init=init,
                scale=scale,
            )
        )
    share, window = parse_holdout(raw.get("holdout", 0.3))
    holdout_at = raw.get("holdout_at", "least_repeated")
    if holdout_at not in HOLDOUT_AT:
        raise SpecError(f"spec field 'holdout_at': {holdout_at!r}; {valid_choices(str(holdout_at), HOLDOUT_AT)}")
    return CalibrationSpec(
        **base,
        params=tuple(params),
        effects=_effects(raw.get("effects", "all")),
        holdout=share,
        holdout_window=window,
        holdout_at=holdout_at,
        period=None if raw.get("period") is None else number(raw["period"], "period", lo=1e-3, hi=1e6),
        horizon=number(raw.get("horizon", 0.2), "horizon", lo=1e-6, hi=MAX_HORIZON_S),
        trace=parse_trace(raw.get("trace")),
        threads=number(raw.get("threads", 1), "threads", lo=1, hi=64, integer=True),
        controller=gains(raw["controller"]) if raw.get("controller") is not None else None,
        source=source,
    )

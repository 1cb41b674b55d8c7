"""Perturbation axes and the `perturb.*` grammar: the one table of axes, and key=value -> conditions.

Command-line grammar (`perturb.AXIS=...`, see docs/perturbations.md):
    perturb.friction=[0.25,0.5,2]             level grid: one condition per level
    perturb.friction=uniform(0.8,1.2)         domain randomisation: one condition, a draw per episode
    perturb.mass=loguniform(0.5,2)            log-uniform draw
    perturb.mass.levels=[0.5,2] perturb.mass.bodies=[cube_main]   dict form, with targets
    perturb.mass.uniform=[0.8,1.2]            dict form of a range
    perturb.damping=from(runs/panda_cal)      a calibration's bootstrap draws: one condition, a draw per episode

The rows themselves (what each axis is and how a level is applied) live with their implementation
(`bench.sims.perturb.axis` says where); applying a condition to an env is `bench.sims.perturb.reset`'s.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from collections.abc import Mapping
from pathlib import Path

from bench.core.errors import ConfigError, DataError, did_you_mean
from bench.protocols import RGB, ObsSpec
from bench.protocols.suite import NOMINAL, Condition, ConditionSpec
from bench.sims.perturb.axis import MAX_SCALE, MAX_STEPS, RGB_IMAGES, Axis
from bench.sims.perturb.combine import KEY as COMBINE
from bench.sims.perturb.combine import combinations
from bench.sims.perturb.frames import ROWS as FRAME_ROWS
from bench.sims.perturb.interface import ROWS as INTERFACE_ROWS
from bench.sims.perturb.language import ROWS as LANGUAGE_ROWS
from bench.sims.perturb.model import ROWS as MODEL_ROWS
from bench.sims.perturb.pose import ROWS as POSE_ROWS
from bench.sims.perturb.scene import ROWS as SCENE_ROWS

__all__ = ["AXES", "MAX_SCALE", "MAX_STEPS", "Axis"]  # with the grammar's functions below


# the one table: every module that implements axes contributes its rows (`bench.sims.perturb.axis`)
AXES: dict[str, Axis] = {
    a.name: a
    for rows in (MODEL_ROWS, INTERFACE_ROWS, SCENE_ROWS.values(), FRAME_ROWS, LANGUAGE_ROWS, POSE_ROWS)
    for a in rows
}
MODEL_AXES = tuple(n for n, a in AXES.items() if a.kind == "model")
INTERFACE_AXES = tuple(n for n, a in AXES.items() if a.kind == "interface")
VISUAL_AXES = tuple(n for n, a in AXES.items() if a.kind == "visual")
# the model fields a calibration's draws (`bench calibrate`'s `draws` section) carry, per axis that samples them
FROM_FIELDS = {n: a.from_fields for n, a in AXES.items() if a.from_fields}
DISTRIBUTIONS = ("uniform", "loguniform")
_SHORT = {"uniform": "U", "loguniform": "logU"}
_FROM_RE = re.compile(r"^\s*from\s*\(\s*(.+?)\s*\)\s*$", re.IGNORECASE)
_DIST_RE = re.compile(r"^\s*(uniform|loguniform|u|logu)\s*\(\s*([^,()]+)\s*,\s*([^,()]+)\s*\)\s*$", re.IGNORECASE)


# -- command line -> conditions ------------------------------------------------------------
def _num(axis: Axis, field: str, value: object) -> float | int:
    """A level as a number, checked against the axis' minimum and integrality."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        try:
            value = float(str(value).strip())
        except ValueError:
            raise ConfigError(f"{field}: {value!r} is not a number; {axis.name} takes {axis.unit}") from None
    value = float(value)
    if not math.isfinite(value):
        raise ConfigError(f"{field}: {value!r} is not finite")
    bad = value <= axis.minimum if axis.strict else value < axis.minimum
    if bad:
        op = ">" if axis.strict else ">="
        raise ConfigError(
            f"{field}: {value:g} is invalid; {axis.name} levels ({axis.unit}) must be {op} {axis.minimum:g}"
        )
    if axis.integer and value != int(value):
        raise ConfigError(f"{field}: {value:g} is not a whole number; {axis.name} is in {axis.unit}")
    if value > axis.maximum:
        raise ConfigError(
            f"{field}: {value:g} is invalid; {axis.name} levels ({axis.unit}) must be <= {axis.maximum:g}"
        )
    return int(value) if axis.integer else value


def _range(axis: Axis, field: str, dist: str, bounds: object) -> tuple[float, float]:
    if not isinstance(bounds, (list, tuple)) or len(bounds) != 2:
        raise ConfigError(f"{field}: {dist} needs [low, high], got {bounds!r}")
    lo, hi = (_num(axis, field, b) for b in bounds)
    if lo > hi:
        raise ConfigError(f"{field}: {dist}({lo:g},{hi:g}) has low > high")
    if dist == "loguniform" and lo <= 0:
        raise ConfigError(f"{field}: loguniform needs low > 0, got {lo:g}")
    return lo, hi


def _parse_dist(text: str) -> tuple[str, list[str]] | None:
    m = _DIST_RE.match(text)
    if not m:
        return None
    name = {"u": "uniform", "logu": "loguniform"}.get(m.group(1).lower(), m.group(1).lower())
    return name, [m.group(2), m.group(3)]


def _fmt(x: float) -> str:
    return f"{x:g}"


def _from(axis: Axis, field: str, source: str) -> Condition:
    """`from(CALIBRATION)`: one condition whose episodes each take one bootstrap draw of what the
    calibration measured for this axis' fields (absolute values, written over the nominal ones)."""
    if axis.name not in FROM_FIELDS:
        raise ConfigError(
            f"{field}: from(...) samples what a calibration measured; axes that take it: {', '.join(FROM_FIELDS)}"
        )
    path = Path(source).expanduser()
    path = path / "calibration.json" if path.is_dir() else path
    if not path.is_file():
        raise ConfigError(
            f"{field}: from({source}): no calibration there (a `bench calibrate` output folder or its calibration.json)"
        )
    raw = path.read_bytes()
    try:
        doc = json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"{field}: from({source}): {path} is not JSON ({exc})") from None
    draws = doc.get("draws") if isinstance(doc, dict) else None
    if (
        not isinstance(draws, dict)
        or not isinstance(draws.get("keys"), list)
        or not isinstance(draws.get("values"), list)
    ):
        raise ConfigError(
            f"{field}: from({source}): {path} has no 'draws' section (a real-arm calibration, `method: idim`, writes one)"
        )
    keys, values = draws["keys"], draws["values"]
    keep = [i for i, k in enumerate(keys) if isinstance(k, str) and k.split(":")[0] in FROM_FIELDS[axis.name]]
    if not keep:
        have = sorted({str(k).split(":")[0] for k in keys})
        raise ConfigError(
            f"{field}: from({source}): the calibration measured no {', '.join(FROM_FIELDS[axis.name])} "
            f"(its draws carry {', '.join(have) or 'nothing'})"
        )
    rows = [[row[i] for i in keep] for row in values if isinstance(row, list) and len(row) == len(keys)]
    if len(rows) < 2 or len(rows) != len(values):
        raise ConfigError(f"{field}: from({source}): {path} holds {len(rows)} usable draws; at least 2 are needed")
    if not all(isinstance(v, (int, float)) and math.isfinite(v) for row in rows for v in row):
        raise DataError(f"{field}: from({source}): {path} has a draw that is not a finite number")
    sha = hashlib.sha256(raw).hexdigest()
    spec: ConditionSpec = {
        "kind": "from",
        "targets": {},
        "source": str(path),
        "sha256": sha,
        "keys": [keys[i] for i in keep],
        "values": rows,
    }
    label = f"{path.parent.name or path.name}@{sha[:8]}"
    return Condition(name=f"{axis.name}~from({label})", axis=axis.name, level=[0, len(rows) - 1], spec=spec)


def axis_named(name: str) -> Axis:
    """The axis called `name`; a one-line ConfigError listing the axes otherwise."""
    if name not in AXES:
        raise ConfigError(
            f"perturb.{name}: unknown perturbation axis; valid: {', '.join(AXES)}.{did_you_mean(name, AXES)}"
        )
    return AXES[name]


def _words(axis: Axis, field: str, value: object) -> list[Condition]:
    """A categorical axis' conditions: one per word (`perturb.instruction=[paraphrase,empty]`, or `.levels=[...]`);
    a number, a range, a curve or a target is refused with the words that are valid."""
    if isinstance(value, dict):
        bad = [k for k in value if k != "levels"]
        if bad:
            raise ConfigError(f"{field}.{bad[0]}: {axis.name} is categorical; its only key is levels=[...]")
        value = value.get("levels")
    words = list(value) if isinstance(value, (list, tuple)) else [value]
    if not words:
        raise ConfigError(f"{field}: empty list of levels; valid: {', '.join(axis.words)}")
    out: list[Condition] = []
    for w in words:
        if w not in axis.words:
            raise ConfigError(
                f"{field}: {w!r} is not a level of {axis.name}, a categorical axis (no numbers, ranges or curves); "
                f"valid: {', '.join(axis.words)}.{did_you_mean(str(w), list(axis.words))}"
            )
        if all(c.level != w for c in out):
            out.append(
                Condition(name=f"{axis.name}={w}", axis=axis.name, level=w, spec={"kind": "grid", "targets": {}})
            )
    return out


def _conditions_for(name: str, value: object) -> list[Condition]:
    axis = axis_named(name)
    field = f"perturb.{name}"
    if axis.words:
        return _words(axis, field, value)
    targets: dict[str, list[str]] = {}
    levels: list[object] = []
    dists: list[tuple[str, object, str]] = []
    curve = False
    if isinstance(value, dict):
        valid_keys = ["levels", *DISTRIBUTIONS, "curve", *axis.targets]
        for key, v in value.items():
            if key not in valid_keys:
                raise ConfigError(
                    f"{field}.{key}: unknown key; valid: {', '.join(valid_keys)}.{did_you_mean(key, valid_keys)}"
                )
            if key == "levels":
                levels.extend(v if isinstance(v, (list, tuple)) else [v])
            elif key in DISTRIBUTIONS:
                dists.append((key, v, f"{field}.{key}"))
            elif key == "curve":  # a range scored as a curve, asked for: refused with fewer than MIN_DRAWS draws
                parsed = _parse_dist(v) if isinstance(v, str) else None
                if parsed is None:
                    raise ConfigError(
                        f"{field}.curve: {v!r} is not a range; write uniform(low,high) or loguniform(low,high)"
                    )
                dists.append((parsed[0], parsed[1], f"{field}.curve"))
                curve = True
            else:
                names = [v] if isinstance(v, str) else list(v or [])
                if not names or not all(isinstance(n, str) and n for n in names):
                    raise ConfigError(f"{field}.{key}: expected a list of names, got {v!r}")
                targets[key] = names
        if not levels and not dists:
            raise ConfigError(
                f"{field}: give levels=[...], a range ({'/'.join(DISTRIBUTIONS)}=[low,high]) or curve=uniform(low,high)"
            )
    else:
        levels = list(value) if isinstance(value, (list, tuple)) else [value]
        if not levels:
            raise ConfigError(f"{field}: empty list of levels")
    grid: list[float | int] = []
    froms: list[Condition] = []
    for lv in levels:
        parsed = _parse_dist(lv) if isinstance(lv, str) else None
        sampled = _FROM_RE.match(lv) if isinstance(lv, str) else None
        if parsed:
            dists.append((parsed[0], parsed[1], field))
        elif sampled:
            froms.append(_from(axis, field, sampled.group(1)))
        elif isinstance(lv, str) and "(" in lv:
            raise ConfigError(
                f"{field}: cannot parse {lv!r}; write uniform(low,high), loguniform(low,high) or from(CALIBRATION)"
            )
        else:
            grid.append(_num(axis, field, lv))
    out: list[Condition] = []
    for lv in dict.fromkeys(grid):  # unique, in the given order
        spec: ConditionSpec = {"kind": "grid", "targets": targets}
        out.append(Condition(name=f"{name}={_fmt(lv)}", axis=name, level=lv, spec=spec))
    for dist, bounds, f in dists:
        lo, hi = _range(axis, f, dist, bounds)
        spec = {"kind": dist, "targets": targets, **({"curve": True} if curve else {})}
        out.append(
            Condition(name=f"{name}~{_SHORT[dist]}({_fmt(lo)},{_fmt(hi)})", axis=name, level=[lo, hi], spec=spec)
        )
    return out + froms


def conditions_from_config(perturb: Mapping[str, object], seed: int = 0) -> list[Condition]:
    """The run's conditions from `perturb.*` overrides: nominal first, then one per axis level, then the
    combinations `perturb.combine` asks for (`bench.sims.perturb.combine`; `seed`, the run's, draws a fraction).

    A grid gives one condition per level ("friction=0.5"); a range gives one condition
    whose value is drawn per episode ("friction~U(0.8,1.2)"). Raises ConfigError on an
    unknown axis, a level out of range or a malformed range.
    """
    out = [NOMINAL]
    seen: set[str] = set()
    for name, value in (perturb or {}).items():
        if name == COMBINE:
            continue
        for cond in _conditions_for(str(name), value):
            if cond.name not in seen:
                seen.add(cond.name)
                out.append(cond)
    if COMBINE in (perturb or {}):
        out += combinations(perturb[COMBINE], out[1:], AXES, seed)
    return out


def check_horizon(conditions: list[Condition], horizon: int) -> None:
    """Step-valued levels (latency, action_hold) longer than the episode are refused: the policy would
    never act (ConfigError naming the axis, the level and the horizon)."""
    for cond in conditions:
        axis = AXES.get(cond.axis or "")
        if axis is None or axis.unit != "control steps":
            continue
        levels = cond.level if isinstance(cond.level, (list, tuple)) else [cond.level]
        worst = max(float(v) for v in levels)
        if worst >= horizon:
            raise ConfigError(
                f"perturb.{axis.name}: {worst:g} control steps is not less than the horizon "
                f"({horizon} steps); valid: < {horizon} (or a longer horizon=)"
            )


def check_policy_sees(conditions: list[Condition], needs: tuple[str, ...], spec: ObsSpec, policy: str) -> None:
    """A visual axis changes only camera images: refused (ConfigError naming the axis) for a policy that reads none.

    `needs` are the observation keys the policy declares it reads (none: the whole observation, as a
    remote policy without `obs_map` gets it) and `spec` a cell's declared observation. Without this, a
    state-only policy would report a drop of +0 [0, 0] that reads as robustness.
    """
    visual = [c for c in conditions if c.axis in AXES and AXES[c.axis].sees == RGB_IMAGES]
    if not visual:
        return
    seen = [k for k in (needs or tuple(spec)) if str(k).startswith(RGB)]
    if not seen:
        reads = ", ".join(needs) if needs else ", ".join(spec)
        raise ConfigError(
            f"perturb.{visual[0].axis} changes only camera images, and policy {policy!r} reads none (it reads "
            f"{reads}): the drop would measure nothing; use a policy that observes images (e.g. bc_image, or "
            "remote with an rgb.* entry in obs_map) or leave the visual axes out"
        )


def axes_help() -> str:
    """One line per axis (name, unit, what it changes, optional targets) for `bench run --help`."""
    rows = []
    for a in AXES.values():
        tgt = f" [targets: {', '.join(a.targets)}]" if a.targets else ""
        rows.append(f"  {a.name:<13} {a.short} ({a.unit}){tgt}")
    return "\n".join(rows)

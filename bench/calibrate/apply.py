"""A suite calibration carried into runs: model edits for one robot, and the check that they fit.

`bench calibrate suite=NAME robot=NAME logs=DIR` writes, besides the report, an `apply` section:
the robot, a fingerprint of the nominal model it was fitted on (`model_hash`), and the model edits
(field, element, value) the calibrated physics makes. `bench run ... calibration=FILE` loads it
(`load`), and each worker writes the edits into the env of that robot's cells right after building
it (`apply`), so perturbations scale the calibrated values and every episode starts from them. A
file for another suite, robot or model version is refused with one line naming what differs.

`load` also reads the file's `trust` section (`trust_of`): whether the calibrated model simulates the
held-out data better than the declared one (the forward verdict) and how new that held-out data is
(its repeat share). A run records it in `provenance.calibration`, says it before its episodes
(`describe`) and warns (`warning`) or, with `strict=true`, refuses (`refuse`) a calibration whose
model simulates worse or was never checked (a file without `trust`: unchecked).
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypedDict

import mujoco
import numpy as np

from bench.core.errors import ConfigError, DataError
from bench.protocols import Cell, MujocoHandle, Suite
from bench.sims.perturb.reset import ModelEdit, write_fields

# What `load` returns and the checks below read: {path, sha256, robot, model_hash, [robot_hash], joints, edits
# (`CalibrationEdit`s), trust (`Trust` or None), [delay_steps]}. A plain dict: bench.api's `Calibration` builds it (`loaded()`).
Loaded = dict[str, Any]
MAX_DELAY_STEPS = 1000  # apply.delay_steps: a servo calibration's transport delay, in the suite's control steps


class CalibrationEdit(ModelEdit):
    """One edit of a calibration's `apply` section: a `ModelEdit` and the nominal value it replaces."""

    nominal: float


class Forward(TypedDict, total=False):
    """What a run records of a calibration's forward check (`Trust.forward`); `why` only when it says why."""

    criterion: str | None
    declared: float | None
    calibrated: float | None
    rose: list[str]
    why: str | None


class Heldout(TypedDict):
    placement: str | None
    repeat_share: float | None
    nothing_new: bool | None


class Trust(TypedDict):
    """The facts of a calibration's `trust` section a run records (`trust_of`)."""

    simulates_better: bool | None
    forward: Forward
    heldout: Heldout
    estimate: str | None
    torque_beats_repeat: bool | None


# the MjModel fields whose values fingerprint a robot's nominal model (`model_hash`): fixed, so a
# calibration written before more fields became editable still matches its model
HASH_FIELDS = {
    "dof_damping": mujoco.mjtObj.mjOBJ_JOINT,
    "dof_armature": mujoco.mjtObj.mjOBJ_JOINT,
    "dof_frictionloss": mujoco.mjtObj.mjOBJ_JOINT,
    "jnt_stiffness": mujoco.mjtObj.mjOBJ_JOINT,
    "body_mass": mujoco.mjtObj.mjOBJ_BODY,
    "actuator_gainprm": mujoco.mjtObj.mjOBJ_ACTUATOR,
}
# the MjModel fields a suite calibration may edit: every one is realised by MuJoCo itself, so an env
# carries it without any change to its controller or step loop; 2-D fields edit every column listed
FIELDS = {
    **HASH_FIELDS,
    "body_ipos": mujoco.mjtObj.mjOBJ_BODY,
    "body_iquat": mujoco.mjtObj.mjOBJ_BODY,
    "body_inertia": mujoco.mjtObj.mjOBJ_BODY,
}
COLUMNS = {"body_ipos": 3, "body_iquat": 4, "body_inertia": 3}  # other 2-D fields: column 0


def _row(model: mujoco.MjModel, field: str, name: str) -> int:
    idx = mujoco.mj_name2id(model, FIELDS[field], name)
    if idx < 0:
        raise DataError(f"calibration edit of {field}: {name!r} is not in the model")
    return int(model.jnt_dofadr[idx]) if field.startswith("dof_") else idx


def _get(model: mujoco.MjModel, field: str, row: int) -> float:
    arr = getattr(model, field)
    return float(arr[row, 0] if arr.ndim == 2 else arr[row])


def model_hash(model: mujoco.MjModel, joints: list[str]) -> str:
    """Fingerprint of a robot's nominal model: its structure and the values a calibration edits."""
    names = {
        k: [mujoco.mj_id2name(model, obj, i) for i in range(n)]
        for k, obj, n in (
            ("joint", mujoco.mjtObj.mjOBJ_JOINT, model.njnt),
            ("body", mujoco.mjtObj.mjOBJ_BODY, model.nbody),
            ("actuator", mujoco.mjtObj.mjOBJ_ACTUATOR, model.nu),
        )
    }
    values = {}
    for field, obj in HASH_FIELDS.items():
        kind = (
            "joint" if obj == mujoco.mjtObj.mjOBJ_JOINT else "body" if obj == mujoco.mjtObj.mjOBJ_BODY else "actuator"
        )
        values[field] = [round(_get(model, field, _row(model, field, n)), 9) for n in names[kind] if n]
    doc = {
        "nq": model.nq,
        "nv": model.nv,
        "nu": model.nu,
        "names": names,
        "values": values,
        "joints": joints,
        "timestep": model.opt.timestep,
    }
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def fixed_to(model: mujoco.MjModel, body: int, link: int) -> bool:
    """True when `body` is `link` or hangs from it through bodies without joints (they move as one)."""
    while body > 0:
        if body == link:
            return True
        if model.body_jntnum[body] > 0:
            return False
        body = int(model.body_parentid[body])
    return False


def robot_hash(model: mujoco.MjModel, joints: list[str]) -> str:
    """Fingerprint of a robot alone, whatever scene holds it: its joints (kind, axis, range and the
    calibrated fields), the bodies they move with what is fixed to them (names and inertial values)
    and the motors that drive them. Two suites that put the same arm in different scenes share it."""
    rows: list[list[object]] = []
    for name in joints:
        j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if j < 0:
            return f"missing joint {name}"
        d = int(model.jnt_dofadr[j])
        link = int(model.jnt_bodyid[j])
        group = [b for b in range(model.nbody) if fixed_to(model, b, link)]
        rows.append(
            [
                name,
                int(model.jnt_type[j]),
                np.round(model.jnt_axis[j], 9).tolist(),
                np.round(model.jnt_range[j], 9).tolist(),
                [round(float(getattr(model, f)[d]), 9) for f in ("dof_damping", "dof_armature", "dof_frictionloss")],
                round(float(model.jnt_stiffness[j]), 9),
                [
                    [
                        mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b),
                        round(float(model.body_mass[b]), 9),
                        np.round(model.body_ipos[b], 9).tolist(),
                        np.round(model.body_inertia[b], 9).tolist(),
                    ]
                    for b in group
                ],
                [
                    [
                        mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a),
                        round(float(model.actuator_gainprm[a, 0]), 9),
                    ]
                    for a in range(model.nu)
                    if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT and model.actuator_trnid[a, 0] == j
                ],
            ]
        )
    doc = {"robot": rows, "timestep": model.opt.timestep, "gravity": np.round(model.opt.gravity, 9).tolist()}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def edits(nominal: mujoco.MjModel, fitted: mujoco.MjModel) -> list[CalibrationEdit]:
    """What the calibrated model changes in the editable fields: [{field, element, nominal, value[, column]}]."""
    out: list[CalibrationEdit] = []
    for field, obj in FIELDS.items():
        full_a, full_b = getattr(nominal, field), getattr(fitted, field)
        for col in range(COLUMNS.get(field, 1)):
            a, b = (full_a[:, col], full_b[:, col]) if full_a.ndim == 2 else (full_a, full_b)
            changed = ~np.isclose(a, b, rtol=1e-12, atol=0.0)
            if field in COLUMNS:  # a body's frame moves as a whole: every column of a changed row
                changed = np.any(~np.isclose(full_a, full_b, rtol=1e-12, atol=0.0), axis=1)
            for row in np.flatnonzero(changed):
                idx = int(nominal.dof_jntid[row]) if field.startswith("dof_") else int(row)
                element, was, now = mujoco.mj_id2name(nominal, obj, idx), float(a[row]), float(b[row])
                if field in COLUMNS:
                    out.append({"field": field, "element": element, "column": col, "nominal": was, "value": now})
                else:
                    out.append({"field": field, "element": element, "nominal": was, "value": now})
    return out


def read_calibration(path: str | Path) -> tuple[Path, bytes, object]:
    """A `bench calibrate` output folder or its calibration.json -> (file, its bytes, the parsed JSON)."""
    p = Path(path).expanduser()
    if p.is_dir():
        p = p / "calibration.json"
    if not p.is_file():
        raise ConfigError(
            f"calibration={str(path)!r}: no such file (a `bench calibrate` output folder or its calibration.json)"
        )
    raw = p.read_bytes()
    try:
        return p, raw, json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"calibration={str(p)!r} is not JSON: {exc}") from None


def load(path: str | Path, suite: str, suite_version: str, robots: list[str]) -> Loaded:
    """A calibration to carry into a run of `suite` whose selected cells have `robots`; refused otherwise."""
    p, raw, doc = read_calibration(path)
    section = doc.get("apply") if isinstance(doc, dict) else None
    if not isinstance(doc, dict) or doc.get("schema") != "bench.calibration/1" or not isinstance(section, dict):
        raise DataError(
            f"calibration={str(p)!r} is not a suite calibration (schema bench.calibration/1 with an "
            "'apply' section, written by `bench calibrate suite=NAME robot=NAME logs=DIR`)"
        )
    where = doc.get("suite", {})
    portable = "robot_hash" in section  # a robot's calibration: any suite whose robot matches it
    if not portable and (where.get("name") != suite or str(where.get("version")) != str(suite_version)):
        raise ConfigError(
            f"calibration={str(p)!r} was fitted for suite {where.get('name')!r} version "
            f"{where.get('version')!r}; this run is suite {suite!r} version {suite_version!r}"
        )
    if section.get("robot") not in robots:
        raise ConfigError(
            f"calibration={str(p)!r} is for robot {section.get('robot')!r}, which no selected cell "
            f"has (robots: {', '.join(sorted(set(robots)))})"
        )
    _check_servos(section, p)
    delay = section.get("delay_steps", 0)
    if isinstance(delay, bool) or not isinstance(delay, int) or not 0 <= delay <= MAX_DELAY_STEPS:
        raise DataError(
            f"calibration={str(p)!r}: apply.delay_steps is {delay!r}; a whole number of control steps in "
            f"[0, {MAX_DELAY_STEPS}] (the transport delay `method: servo_arm` found)"
        )
    return {
        "path": str(p.resolve()),
        "sha256": hashlib.sha256(raw).hexdigest(),
        "robot": section["robot"],
        "model_hash": section["model_hash"],
        **({"robot_hash": section["robot_hash"]} if portable else {}),
        "joints": section["joints"],
        "edits": section["edits"],
        "trust": trust_of(doc, p),
        **({"delay_steps": delay} if delay else {}),
    }


def _check_servos(section: Mapping[str, object], p: Path) -> None:
    """An arm's servo calibration (`servos` beside its edits): every servo holds (kp and stiffness > 0) and its
    friction and armature are not negative; one line naming the joint and the value otherwise."""
    servos = section.get("servos")
    if servos is None:
        return
    if not isinstance(servos, dict):
        raise DataError(f"calibration={str(p)!r}: apply.servos must map each joint to its servo's parameters")
    for joint, row in servos.items():
        for key, v in row.items() if isinstance(row, dict) else [("servo", row)]:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise DataError(f"calibration={str(p)!r}: apply.servos.{joint}.{key} is {v!r}, not a number")
            if key in ("kp", "stiffness") and v <= 0:
                raise DataError(
                    f"calibration={str(p)!r}: apply.servos.{joint}.{key} is {v:g}; a servo's {key} must be > 0"
                )
            if v < 0:
                raise DataError(f"calibration={str(p)!r}: apply.servos.{joint}.{key} is {v:g}; must be >= 0")
    edits = section.get("edits")
    for e in edits if isinstance(edits, list) else []:
        if (
            isinstance(e, dict)
            and e.get("field") == "actuator_gainprm"
            and not (isinstance(e.get("value"), (int, float)) and e["value"] > 0)
        ):
            raise DataError(
                f"calibration={str(p)!r}: the servo of {e.get('element')!r} has gain {e.get('value')!r}; must be > 0"
            )


def _number(v: object) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) else None


def _text(v: object) -> str | None:
    """A string of the file on one line (a message quoting it stays one line), or None."""
    return " ".join(v.split()) if isinstance(v, str) else None


def trust_of(doc: Mapping[str, object], p: Path) -> Trust | None:
    """The facts of a calibration's `trust` section a run records (None: a file written before it existed).

    {simulates_better: true|false|null (null: no forward check), forward: {criterion, declared, calibrated,
    rose[, why]}, heldout: {placement, repeat_share, nothing_new}, estimate, torque_beats_repeat}; a
    value of the wrong type is recorded as null, so it reads as unchecked."""
    t = doc.get("trust")
    if t is None:
        return None
    if not isinstance(t, dict):
        raise DataError(f"calibration={str(p)!r}: 'trust' is not an object (as `bench calibrate` writes it)")
    fw: Mapping[str, object] = t["forward"] if isinstance(t.get("forward"), dict) else {}
    held: Mapping[str, object] = t["heldout"] if isinstance(t.get("heldout"), dict) else {}
    better = t.get("simulates_better", fw.get("simulates_better"))
    rose = fw.get("rose")
    forward: Forward = {
        "criterion": _text(fw.get("criterion")),
        "declared": _number(fw.get("declared")),
        "calibrated": _number(fw.get("calibrated")),
        "rose": [" ".join(str(r).split()) for r in rose] if isinstance(rose, list) else [],
    }
    if _text(fw.get("why")):
        forward["why"] = _text(fw["why"])
    nothing_new = held.get("nothing_new")
    return {
        "simulates_better": better if isinstance(better, bool) else None,
        "forward": forward,
        "heldout": {
            "placement": _text(held.get("placement")),
            "repeat_share": _number(held.get("repeat_share")),
            "nothing_new": nothing_new if isinstance(nothing_new, bool) else None,
        },
        "estimate": _text(t.get("estimate")),
        "torque_beats_repeat": t.get("torque_beats_repeat") if isinstance(t.get("torque_beats_repeat"), bool) else None,
    }


def _detail(fw: Forward, worse: bool) -> str:
    """' (closed-loop free run 0.06 -> 0.0076)', or for a worse model what rose (at most two horizons named)."""
    rose = fw["rose"] if worse else []
    loop = "closed-loop " if "closed-loop" in (fw.get("criterion") or "") else ""  # an arm's check closes a loop
    if rose:
        more = f"; and {len(rose) - 2} more" if len(rose) > 2 else ""
        return f" ({loop}{'; '.join(rose[:2])}{more})"
    a, b = fw.get("declared"), fw.get("calibrated")
    return "" if a is None or b is None else f" ({loop}free run {a:.3g} -> {b:.3g})"


WORSE = "simulates the held-out data worse than the declared model"
BETTER = "simulates the held-out data better than the declared model"


def verdict(cal: Loaded) -> str:
    """The trust verdict in a few words: `simulates ... better (...)`, `... worse (...)` or `unchecked (...)`."""
    t = cal.get("trust")
    if t is None:
        return "unchecked (the file has no trust section: written before `bench calibrate` checked its model)"
    fw = t["forward"]
    if t["simulates_better"] is None:
        return f"unchecked ({fw.get('why') or 'no forward check on held-out data'})"
    worse = not t["simulates_better"]
    return (WORSE if worse else BETTER) + _detail(fw, worse)


def describe(cal: Loaded) -> str:
    """One line a run prints before its episodes: robot, file, edits, delay, trust verdict, repeat share."""
    t = cal.get("trust")
    share = None if t is None else t["heldout"]["repeat_share"]
    n = len(cal["edits"])
    d = int(cal.get("delay_steps", 0))
    delay = f", commands {d} control step{'' if d == 1 else 's'} late" if d else ""
    return (
        f"calibration: the {cal['robot']} cells run the calibrated model of {cal['path']} ({n} model edit"
        f"{'' if n == 1 else 's'}{delay}); {verdict(cal)}; held-out repeat share "
        + ("unknown" if share is None else f"{share:.0%}")
    )


def _untrusted(cal: Loaded) -> str | None:
    """What is wrong with a calibration's trust, naming the file (None: it simulates better)."""
    t = cal.get("trust")
    if t is not None and t["simulates_better"]:
        return None
    head = f"calibration={cal['path']}: the calibrated {cal['robot']}"
    if t is not None and t["simulates_better"] is False:
        return f"{head} {WORSE}{_detail(t['forward'], True)}"
    return f"{head} was never checked against held-out data {verdict(cal).removeprefix('unchecked ')}"


def warning(cal: Loaded) -> str | None:
    """The warning line (without 'warning: ') for a calibration whose model simulates worse or was never
    checked; None when its forward check found it simulates better."""
    bad = _untrusted(cal)
    return None if bad is None else f"{bad}; strict=true refuses it"


def refuse(cal: Loaded) -> None:
    """`strict=true`: refuse a calibration whose model simulates worse or was never checked (one line)."""
    bad = _untrusted(cal)
    if bad is not None:
        raise ConfigError(
            f"{bad}; strict=true runs only a calibration whose model simulates the held-out data better than the "
            "declared one (leave strict out to run it with a warning)"
        )


def check(mj: MujocoHandle | None, cal: Loaded) -> None:
    """Refuse a calibration fitted on another model of its robot (one line naming both fingerprints)."""
    if mj is None:
        raise ConfigError(
            f"calibration {cal['path']!r} edits a MuJoCo model; the env of robot {cal['robot']!r} has none"
        )
    if "robot_hash" in cal:
        missing = [j for j in cal["joints"] if mujoco.mj_name2id(mj.model, mujoco.mjtObj.mjOBJ_JOINT, j) < 0]
        if missing:
            raise ConfigError(
                f"calibration {cal['path']!r} names joints this env's robot {cal['robot']!r} lacks: "
                f"{', '.join(missing)}"
            )
        have = robot_hash(mj.model, cal["joints"])
        if have != cal["robot_hash"]:
            raise ConfigError(
                f"calibration {cal['path']!r} was fitted on another model of robot {cal['robot']!r} "
                f"(robot fingerprint {cal['robot_hash'][:12]}, this env's {have[:12]}); recalibrate against it"
            )
        return
    have = model_hash(mj.model, cal["joints"])
    if have != cal["model_hash"]:
        raise ConfigError(
            f"calibration {cal['path']!r} was fitted on another model of robot {cal['robot']!r} "
            f"(model fingerprint {cal['model_hash'][:12]}, this env's {have[:12]}); recalibrate "
            "against this suite version"
        )


def verify(suite: Suite, cells: list[Cell], horizon: int, cal: Loaded) -> None:
    """Build the env of the calibration's robot once and check the calibration fits its model (before a run
    writes anything)."""
    cell = next(c for c in cells if c.robot == cal["robot"])
    env = suite.make_env(cell, horizon)
    try:
        check(env.mujoco, cal)
    finally:
        env.close()


def apply(mj: MujocoHandle | None, cal: Loaded) -> None:
    """Check a loaded calibration against an env's MuJoCo model and write its edits into it."""
    check(mj, cal)
    assert mj is not None  # refused by check
    write_fields(mj, cal["edits"])


def edited_model(nominal: mujoco.MjModel, model_edits: Sequence[ModelEdit]) -> mujoco.MjModel:
    """A copy of `nominal` with `model_edits` written in by the runner's own `write_fields`: the model a run with
    this calibration simulates (what the calibration's forward check steps)."""
    model = copy.copy(nominal)
    handle = MujocoHandle(model, mujoco.MjData(model))
    write_fields(handle, model_edits)
    return handle.model

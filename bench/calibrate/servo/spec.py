"""Spec of a servo's calibration (`method: servo`): how its logs are written and what the servo is.

method: servo
servo: xl330                          # a name for the report
units: rad                            # rad | deg: the logged positions (rad is checked: one turn at most)
rate: 200                             # Hz, the uniform grid the logs are resampled on
columns: {time: timestamp, position: position, goal: goal_position, enable: torque_enable,
          load: load, volts: input_volts}
load: {kind: pwm, full_scale: 885}    # the load reading: the PWM duty in counts (XL330), or none
firmware: {error_gain: 0.0028775, max_duty: 1.0}   # duty per rad per unit of kp; the PWM limit
motor: {kt_over_r: 0.104, kt_over_r_sd: 0.1, kt: 0.464, source: "..."}   # N·m/V (and its relative sd), V·s/rad
effects: all                          # all | none | [coulomb_friction, ...] (bench.calibrate.servo.effects)
holdout: {trajectory: lift_and_drop}  # whole runs held out: by trajectory, or {runs: [name, ...]}
horizon: 0.3                          # s, the fit's simulated windows
margin: 0.03                          # an effect is added when it cuts the validation error by this share
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeGuard

from bench.calibrate.servo.data import Columns
from bench.calibrate.servo.effects import SERVO_EFFECTS
from bench.core.errors import SpecError, did_you_mean

KEYS = (
    "method",
    "servo",
    "units",
    "rate",
    "columns",
    "load",
    "firmware",
    "motor",
    "effects",
    "holdout",
    "horizon",
    "margin",
)


@dataclass(frozen=True)
class ServoSpec:
    """A parsed servo spec (see the module's docstring)."""

    servo: str
    units: str
    rate: float
    columns: Columns
    load_scale: float | None  # counts of the load reading per unit duty; None: no load reading used
    error_gain: float
    max_duty: float
    kt_over_r: float
    kt_over_r_sd: float  # relative
    kt: float
    source: str
    effects: tuple[str, ...]
    holdout: dict[str, Any]
    horizon: float
    margin: float
    path: str = ""

    def to_json(self) -> dict[str, Any]:
        return {
            "method": "servo",
            "servo": self.servo,
            "units": self.units,
            "rate": self.rate,
            "load": {"kind": "pwm", "full_scale": self.load_scale} if self.load_scale else "none",
            "firmware": {"error_gain": self.error_gain, "max_duty": self.max_duty},
            "motor": {
                "kt_over_r": self.kt_over_r,
                "kt_over_r_sd": self.kt_over_r_sd,
                "kt": self.kt,
                "source": self.source,
            },
            "effects": list(self.effects),
            "holdout": self.holdout,
            "horizon": self.horizon,
            "margin": self.margin,
        }


def is_servo_spec(raw: Any) -> TypeGuard[dict[str, Any]]:
    return isinstance(raw, dict) and raw.get("method") == "servo"


def _number(raw: dict[str, Any], key: str, where: str, default: float | None = None, *, positive: bool = True) -> float:
    v = raw.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise SpecError(f"spec field '{where}{key}' must be a number; got {v!r}")
    if positive and not v > 0:
        raise SpecError(f"spec field '{where}{key}' must be > 0; got {v!r}")
    return float(v)


def _section(raw: dict[str, Any], key: str) -> dict[str, Any]:
    v = raw.get(key, {})
    if not isinstance(v, dict):
        raise SpecError(f"spec field {key!r} must be a mapping; got {v!r}")
    return v


def parse_servo_spec(raw: dict[str, Any], path: Path | None = None) -> ServoSpec:
    """The spec, checked: one line naming the field and what is valid on any error."""
    for k in raw:
        if k not in KEYS:
            raise SpecError(
                f"unknown spec field {k!r} for a servo spec; valid: {', '.join(KEYS)}.{did_you_mean(k, KEYS)}"
            )
    units = raw.get("units", "rad")
    if units not in ("rad", "deg"):
        raise SpecError(f"spec field 'units' must be rad or deg; got {units!r}")
    cols = _section(raw, "columns")
    bad = [k for k in cols if k not in Columns.__dataclass_fields__]
    if bad:
        raise SpecError(
            f"spec field 'columns.{bad[0]}' is not a servo log column; valid: {', '.join(Columns.__dataclass_fields__)}"
        )
    load = raw.get("load", "none")
    load_scale = None
    if load != "none":
        if not isinstance(load, dict) or load.get("kind") != "pwm":
            raise SpecError(f"spec field 'load' must be none or {{kind: pwm, full_scale: COUNTS}}; got {load!r}")
        load_scale = _number(load, "full_scale", "load.")
    fw, motor = _section(raw, "firmware"), _section(raw, "motor")
    eff = raw.get("effects", "all")
    if eff == "all":
        effects = tuple(SERVO_EFFECTS)
    elif eff == "none":
        effects = ()
    elif isinstance(eff, list):
        for e in eff:
            if e not in SERVO_EFFECTS:
                raise SpecError(
                    f"spec field 'effects': unknown servo effect {e!r}; valid: {', '.join(SERVO_EFFECTS)}."
                    f"{did_you_mean(str(e), SERVO_EFFECTS)}"
                )
        effects = tuple(eff)
    else:
        raise SpecError(f"spec field 'effects' must be all, none or a list; got {eff!r}")
    hold = _section(raw, "holdout") or {"trajectory": "lift_and_drop"}
    if set(hold) - {"trajectory", "runs"} or len(hold) != 1:
        raise SpecError(f"spec field 'holdout' must be {{trajectory: NAME}} or {{runs: [NAME, ...]}}; got {hold!r}")
    return ServoSpec(
        servo=str(raw.get("servo", "servo")),
        units=units,
        rate=_number(raw, "rate", "", 200.0),
        columns=Columns(**{k: str(v) for k, v in cols.items()}),
        load_scale=load_scale,
        error_gain=_number(fw, "error_gain", "firmware."),
        max_duty=_number(fw, "max_duty", "firmware.", 1.0),
        kt_over_r=_number(motor, "kt_over_r", "motor."),
        kt_over_r_sd=_number(motor, "kt_over_r_sd", "motor.", 0.1),
        kt=_number(motor, "kt", "motor."),
        source=str(motor.get("source", "")),
        effects=effects,
        holdout=hold,
        horizon=_number(raw, "horizon", "", 0.3),
        margin=_number(raw, "margin", "", 0.03),
        path=str(path or ""),
    )

"""Spec of an arm's servos calibrated from a LeRobot dataset (`method: servo_arm`).

method: servo_arm
arm: so101                      # so101 | koch: the suite whose robot's model is the arm (mass matrix, gravity, coupling)
units: rad                      # rad | deg | normalized: how the dataset writes positions and goals
ranges: so101_follower.json     # lerobot's calibration file (units: normalized only), relative to the spec
gripper: gripper                # the joint lerobot writes 0..100 (normalized); the others -100..100
servo: sts3215                  # a name for the report
firmware: {torque_per_kp: 1.1125}   # N·m/rad of stiffness per unit of the firmware's kp (reports kp; default per arm)
free: [stiffness, damping, coulomb] # the fitted kinds (armature may be added); the others stay the MJCF's
holdout: 0.3                    # share of whole episodes held out (at least one)
horizon: 0.5                    # s, the refinement's simulated windows
max_delay: 0.1                  # s, the longest transport delay searched (whole frames; 0: none)

Positions in degrees and lerobot's normalised units are both referenced to the middle of the calibrated
range (lerobot's `degrees` mode: (raw - (range_min + range_max) / 2) * 360 / 4095), which is the MJCF's
zero (so101_new_calib); normalised units are converted through the ranges to raw ticks first. The Koch's model
(ManiSkill's URDF) has its zero at a joint limit for several joints: its datasets are read in rad or deg from the
model's zero, and normalised units are refused.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeGuard

from bench.core.errors import SpecError, did_you_mean

METHOD = "servo_arm"
UNITS = ("rad", "deg", "normalized")
KEYS = ("method", "arm", "units", "ranges", "gripper", "servo", "firmware", "free", "holdout", "horizon", "max_delay")
KINDS = ("stiffness", "damping", "coulomb", "armature")  # bench.calibrate.servo.arm.model's, in its order
# positions identify a joint's stiffness, damping and friction relative to its whole inertia (link + rotor):
# where the rotor's armature dominates (the wrist roll, the gripper) their common scale is not identifiable,
# so the armature is held at the MJCF's (the rotor's, through the gears) unless the spec frees it
FREE = ("stiffness", "damping", "coulomb")
RANGE_KEYS = ("drive_mode", "homing_offset", "range_min", "range_max")


@dataclass(frozen=True)
class ArmModel:
    """An arm the calibration can simulate: the suite whose robot's model it is, and its declared servo scale."""

    suite: str
    torque_per_kp: float  # N·m/rad of stiffness per unit of the firmware's gain (the spec's default)
    mid_range_zero: bool  # the model's joint zero is the middle of lerobot's calibrated range


ARMS = {
    # the MJCF's 17.8 N·m/rad (Open Duck Mini's STS3215 constants) at lerobot's default P_Coefficient of 16
    "so101": ArmModel("so101", 17.8 / 16.0, mid_range_zero=True),
    # Dynamixel XL330 at 5 V: kt/R 0.104 N·m/V x 5 V x BAM's error gain 0.0028775 per Position P Gain unit
    # (suites/koch.py); ManiSkill's Koch URDF has its zero at a joint limit for several joints, not mid-range
    "koch": ArmModel("koch", 0.104 * 5.0 * 0.0028775, mid_range_zero=False),
}
TORQUE_PER_KP = ARMS["so101"].torque_per_kp


@dataclass(frozen=True)
class MotorRange:
    """One motor of lerobot's calibration file: raw ticks (0..4095) of its calibrated range."""

    drive_mode: int
    homing_offset: int
    range_min: float
    range_max: float


@dataclass(frozen=True)
class ArmServoSpec:
    """A parsed `method: servo_arm` spec (see the module's docstring)."""

    arm: str
    suite: str
    units: str
    ranges: dict[str, MotorRange] | None
    ranges_path: str | None
    gripper: str
    servo: str
    torque_per_kp: float
    free: tuple[str, ...]
    holdout: float
    horizon: float
    max_delay: float = 0.1
    path: str = ""

    def to_json(self) -> dict[str, Any]:
        return {
            "method": METHOD,
            "arm": self.arm,
            "units": self.units,
            "ranges": self.ranges_path,
            "gripper": self.gripper,
            "servo": self.servo,
            "firmware": {"torque_per_kp": self.torque_per_kp},
            "free": list(self.free),
            "holdout": self.holdout,
            "horizon": self.horizon,
            "max_delay": self.max_delay,
        }


def is_servo_arm_spec(raw: Any) -> TypeGuard[dict[str, Any]]:
    return isinstance(raw, dict) and raw.get("method") == METHOD


def _number(raw: dict[str, Any], key: str, default: float, lo: float, hi: float, where: str = "") -> float:
    v = raw.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo < v <= hi:
        raise SpecError(f"spec field '{where}{key}' must be a number in ({lo:g}, {hi:g}]; got {v!r}")
    return float(v)


def _max_delay(v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v <= 1.0:
        raise SpecError(f"spec field 'max_delay' must be seconds in [0, 1] (0: no delay searched); got {v!r}")
    return float(v)


def read_ranges(path: Path) -> dict[str, MotorRange]:
    """lerobot's calibration JSON: {motor: {id, drive_mode, homing_offset, range_min, range_max}} (raw ticks)."""
    if not path.is_file():
        raise SpecError(f"spec field 'ranges': {str(path)!r} is not a file (lerobot's calibration JSON)")
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SpecError(f"spec field 'ranges': {str(path)!r} is not JSON ({exc})") from None
    if not isinstance(doc, dict) or not doc:
        raise SpecError(f"spec field 'ranges': {str(path)!r} must map each motor to its calibration")
    out = {}
    for motor, row in doc.items():
        if not isinstance(row, dict) or any(k not in row for k in RANGE_KEYS):
            raise SpecError(
                f"spec field 'ranges': motor {motor!r} of {str(path)!r} needs {', '.join(RANGE_KEYS)} (raw ticks)"
            )
        lo, hi = row["range_min"], row["range_max"]
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (lo, hi)) or not 0 <= lo < hi:
            raise SpecError(
                f"spec field 'ranges': motor {motor!r} has range_min {lo!r}, range_max {hi!r}; "
                "need 0 <= range_min < range_max (raw ticks)"
            )
        out[str(motor)] = MotorRange(int(row["drive_mode"]), int(row["homing_offset"]), float(lo), float(hi))
    return out


def parse_servo_arm_spec(raw: dict[str, Any], path: Path | None = None) -> ArmServoSpec:
    """The spec, checked: one line naming the field and what is valid on any error."""
    for k in raw:
        if k not in KEYS:
            raise SpecError(
                f"unknown spec field {k!r} for a servo_arm spec; valid: {', '.join(KEYS)}.{did_you_mean(k, KEYS)}"
            )
    arm = raw.get("arm")
    if arm not in ARMS:
        raise SpecError(f"spec field 'arm' must name an arm with a model; valid: {', '.join(ARMS)}; got {arm!r}")
    model = ARMS[str(arm)]
    units = raw.get("units")
    if units not in UNITS:
        raise SpecError(
            f"spec field 'units' must be one of {', '.join(UNITS)} (how the dataset writes positions); got {units!r}"
        )
    if units == "normalized" and not model.mid_range_zero:
        raise SpecError(
            f"spec field 'units': normalized needs the model's joint zero at the middle of lerobot's calibrated range, "
            f"which arm {arm}'s model does not have; write positions in rad (or deg) from the model's zero"
        )
    ranges, ranges_path = None, raw.get("ranges")
    if units == "normalized":
        if ranges_path is None:
            raise SpecError(
                "spec field 'ranges' is required with units: normalized (lerobot's calibration JSON: per motor "
                "drive_mode, homing_offset, range_min, range_max in raw ticks); without it -100..100 has no angle"
            )
        p = Path(str(ranges_path)).expanduser()
        if not p.is_absolute() and path is not None:
            p = path.parent / p
        ranges, ranges_path = read_ranges(p), str(p)
    elif ranges_path is not None:
        raise SpecError(f"spec field 'ranges' applies to units: normalized only; units is {units}")
    fw = raw.get("firmware", {})
    if not isinstance(fw, dict):
        raise SpecError(f"spec field 'firmware' must be a mapping; got {fw!r}")
    free = raw.get("free", list(FREE))
    if not isinstance(free, list) or not free or any(k not in KINDS for k in free):
        raise SpecError(f"spec field 'free' must be a non-empty list of {', '.join(KINDS)}; got {free!r}")
    return ArmServoSpec(
        arm=str(arm),
        suite=model.suite,
        units=str(units),
        ranges=ranges,
        ranges_path=None if ranges_path is None else str(ranges_path),
        gripper=str(raw.get("gripper", "gripper")),
        servo=str(raw.get("servo", "servo")),
        torque_per_kp=_number(fw, "torque_per_kp", model.torque_per_kp, 0.0, 1e6, "firmware."),
        free=tuple(k for k in KINDS if k in free),
        holdout=_number(raw, "holdout", 0.3, 0.0, 0.9),
        horizon=_number(raw, "horizon", 0.5, 0.0, 10.0),
        max_delay=_max_delay(raw.get("max_delay", 0.1)),
        path=str(path or ""),
    )

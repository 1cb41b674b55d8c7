"""An arm's servo calibration written out: calibration.json (with `apply` for `bench run calibration=` and `draws`
for `perturb.AXIS=from(...)`) and report.md; and a calibration document from known servos (`servo_document`)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from bench.calibrate.apply import model_hash
from bench.calibrate.servo.arm.loop import ArmServoCalibration
from bench.calibrate.servo.arm.model import KINDS, UNITS, Arm, ArmServos, describe, draw_keys, draw_row, servo_edits
from bench.core.errors import ConfigError
from bench.core.io import json_safe, write_atomic

SCHEMA = "bench.calibration/1"
SERVO_KEYS = ("kp", "stiffness", "damping", "coulomb", "armature")


def apply_section(arm: Arm, servos: ArmServos, torque_per_kp: float, delay_steps: int = 0) -> dict[str, Any]:
    """What `bench run calibration=` reads: the robot, its fingerprints, the model edits and the servos they realise,
    and a transport delay found (`delay_steps`, only when there is one: the robot's commands act that late)."""
    return {
        "robot": arm.robot,
        "joints": list(arm.joints),
        "robot_hash": arm.robot_hash,  # portable: any suite whose robot is this arm
        "model_hash": model_hash(arm.nominal, list(arm.joints)),
        "edits": servo_edits(arm, servos),
        "servos": describe(arm, servos, torque_per_kp),
        **({"delay_steps": int(delay_steps)} if delay_steps else {}),
    }


def servos_from(arm: Arm, table: dict[str, dict[str, float]], torque_per_kp: float, where: str) -> ArmServos:
    """Servos from {joint: {kp | stiffness, damping, coulomb, armature}} (a joint left out keeps the declared
    servo, a key left out its declared value); one line naming a bad joint, key or value."""
    declared = arm.declared()
    x = declared.vector().reshape(len(KINDS), -1).copy()
    for joint, row in table.items():
        if joint not in arm.joints:
            raise ConfigError(f"{where}: {joint!r} is not a joint of the {arm.robot}; joints: {', '.join(arm.joints)}")
        if not isinstance(row, dict):
            raise ConfigError(f"{where}.{joint}: must map {', '.join(SERVO_KEYS)} to numbers; got {row!r}")
        j = arm.joints.index(joint)
        for key, v in row.items():
            if key not in SERVO_KEYS and key != "max_torque":
                raise ConfigError(f"{where}.{joint}.{key}: unknown servo parameter; valid: {', '.join(SERVO_KEYS)}")
            if key == "max_torque":
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"{where}.{joint}.{key}: {v!r} is not a number")
            if key in ("kp", "stiffness") and v <= 0:
                raise ConfigError(f"{where}.{joint}.{key}: {v:g}; a servo's {key} must be > 0 (0 holds nothing)")
            if v < 0:
                raise ConfigError(f"{where}.{joint}.{key}: {v:g}; must be >= 0")
            if key == "kp":
                x[0, j] = v * torque_per_kp
            else:
                x[KINDS.index(key), j] = v
    return declared.with_vector(x.ravel())


def servo_document(
    arm: Arm, servos: ArmServos, torque_per_kp: float, delay_steps: int = 0, **extra: Any
) -> dict[str, Any]:
    """A calibration document that runs `servos` on the arm (known servos: a test's hidden truth)."""
    return {
        "schema": SCHEMA,
        "method": "servo_arm",
        "suite": {"name": arm.suite, "robot": arm.robot},
        "apply": apply_section(arm, servos, torque_per_kp, delay_steps),
        **extra,
    }


def _num(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def document(cal: ArmServoCalibration) -> dict[str, Any]:
    arm, spec = cal.arm, cal.spec
    lo, hi = cal.interval()
    n = len(arm.joints)
    fitted = describe(arm, cal.servos, spec.torque_per_kp)
    for k, kind in enumerate(KINDS):
        for j, joint in enumerate(arm.joints):
            held = kind not in spec.free  # the declared value, not fitted: no interval
            fitted[joint].setdefault("interval95", {})[kind] = (
                None if held else [_num(lo[k * n + j]), _num(hi[k * n + j])]
            )
    fr = cal.errors["free_run"]
    better = fr["fitted"]["rmse"] < fr["declared"]["rmse"]
    ep = cal.log.episodes
    return servo_document(
        arm,
        cal.servos,
        spec.torque_per_kp,
        cal.delay,
        spec=spec.to_json(),
        logs={"path": cal.logs, "fps": cal.log.fps, "frames": cal.log.frames},
        episodes={"train": [ep[i] for i in cal.train], "heldout": [ep[i] for i in cal.heldout]},
        units={k: UNITS[k] for k in KINDS} | {"kp": "firmware units", "errors": "rad"},
        declared=describe(arm, cal.declared, spec.torque_per_kp),
        linear_start=describe(arm, cal.start, spec.torque_per_kp),
        fitted=fitted,
        errors=cal.errors,
        fit={"cost": cal.fit.cost, "rollouts": cal.fit.rollouts},
        delay={
            "frames": cal.delay,
            "seconds": cal.delay / cal.log.fps,
            "searched_to": len(cal.delay_search) - 1,
            "window_rmse_by_frames": cal.delay_search,
            "applied_by": "apply.delay_steps: bench run calibration= delays the commands of the robot's cells"
            if cal.delay
            else None,
        },
        held=[k for k in KINDS if k not in spec.free],
        draws={
            "keys": draw_keys(arm, spec.free),
            "values": [draw_row(cal.servos.with_vector(d), spec.free) for d in cal.draws],
        },
        trust={
            "simulates_better": better,
            "forward": {
                "criterion": "held-out free-run position RMSE (rad), whole episodes",
                "declared": fr["declared"]["rmse"],
                "calibrated": fr["fitted"]["rmse"],
                "rose": [] if better else [f"free run {fr['declared']['rmse']:.3g} -> {fr['fitted']['rmse']:.3g} rad"],
            },
            "heldout": {"placement": "seeded whole episodes", "repeat_share": None, "nothing_new": None},
        },
        wall_s=cal.wall,
        cpu_s=cal.cpu,
        warnings=cal.warnings,
    )


def summary(cal: ArmServoCalibration) -> list[str]:
    """The lines `bench calibrate` prints: per joint declared -> fitted [interval], the errors, the time."""
    lo, hi = cal.interval()
    n = len(cal.arm.joints)
    out = [f"{'joint':14s} " + "  ".join(f"{k} ({UNITS[k]})".ljust(30) for k in KINDS)]
    for j, joint in enumerate(cal.arm.joints):
        cells = []
        for k, kind in enumerate(KINDS):
            d, f = getattr(cal.declared, kind)[j], getattr(cal.servos, kind)[j]
            if kind not in cal.spec.free:
                cells.append(f"{d:.3g} (held)".ljust(30))
                continue
            cells.append(f"{d:.3g} -> {f:.4g} [{lo[k * n + j]:.3g}, {hi[k * n + j]:.3g}]".ljust(30))
        out.append(f"{joint:14s} " + "  ".join(cells))
    if len(cal.delay_search) > 1:
        out.append(
            f"transport delay: {cal.delay} frame(s) ({1e3 * cal.delay / cal.log.fps:.0f} ms), searched 0-"
            f"{len(cal.delay_search) - 1} (linear-start window RMSE "
            + ", ".join(f"{v:.3g}" for v in cal.delay_search)
            + " rad)"
            + ("; calibration= runs include it" if cal.delay else "")
        )
    fr, wi = cal.errors["free_run"], cal.errors["window"]
    out.append(
        f"held-out position RMSE ({len(cal.heldout)} episodes): free run {fr['declared']['rmse']:.4g} -> "
        f"{fr['fitted']['rmse']:.4g} rad; {cal.spec.horizon:g} s windows {wi['declared']['rmse']:.4g} -> "
        f"{wi['fitted']['rmse']:.4g} rad (declared servos -> fitted)"
    )
    out.append(f"time: {cal.wall['total']:.1f} s wall, {cal.cpu['total']:.1f} s CPU ({cal.fit.rollouts} rollouts)")
    return out


def write_arm_servo_report(cal: ArmServoCalibration, out: Path) -> None:
    """OUT/calibration.json and OUT/report.md."""
    doc = document(cal)
    write_atomic(out / "calibration.json", json_safe(doc))
    lines = [
        f"# Servos of the {cal.arm.robot} from {cal.logs}",
        "",
        f"Spec: {cal.spec.path or '(inline)'}; units {cal.spec.units}; {len(cal.log.q)} episodes at {cal.log.fps:g} fps, "
        f"{len(cal.heldout)} held out (whole episodes).",
        "",
        "Declared (the suite's MJCF) -> fitted [95% interval]:",
        "",
        "```",
        *summary(cal),
        "```",
        "",
        "Run with it: `bench run suite=" + cal.arm.suite + " calibration=OUT/calibration.json`; draw per episode: "
        "`perturb.gain=from(OUT)` (stiffness), `perturb.damping=from(OUT)`, `perturb.frictionloss=from(OUT)`, "
        "`perturb.armature=from(OUT)` (when the spec frees the armature)."
        + (
            f" The transport delay found ({cal.delay} frame(s)) is no MJCF field: `calibration=` runs the robot's "
            f"cells with their commands {cal.delay} control step(s) late (`apply.delay_steps`), and "
            "`perturb.latency` adds to it."
            if cal.delay
            else ""
        ),
        "",
    ]
    (out / "report.md").write_text("\n".join(lines))

"""Servo logs: one JSON object per run (BAM's format, Rhoban/bam), read, checked and put on a uniform grid.

A run holds `entries`, a list of samples with a time, the measured position, the goal position (the servo's input),
whether the torque is enabled and, when logged, the servo's load reading (on the Dynamixel XL330 its present PWM in
counts). Besides, the run's settings: `kp` (the firmware gain), `vin` (V), `motor`, `trajectory`, and for a bench the
load's `mass` and `length`; these are kept as `truth` to check a calibration against and never enter the fit (`kp`
only labels which runs share one gain setting).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.signal import savgol_filter

from bench.core.errors import DataError
from bench.logs.resample import check_times, resample

TWO_PI = 2.0 * np.pi
RAD_LIMIT = TWO_PI + 0.5  # a servo's position in rad stays within one turn (+ margin); degrees go far beyond


@dataclass(frozen=True)
class Columns:
    """Names of a run's entry fields (the spec's `columns`)."""

    time: str = "timestamp"
    position: str = "position"
    goal: str = "goal_position"
    enable: str = "torque_enable"
    load: str = "load"
    volts: str = "input_volts"


@dataclass(frozen=True)
class ServoRun:
    """One run on a uniform grid: time from 0, position, goal, torque enable, supply, duty (None: not logged)."""

    name: str
    fps: float
    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray  # from the positions (Savitzky-Golay derivative)
    ddq: np.ndarray
    goal: np.ndarray
    enable: np.ndarray  # 1.0 torque on, 0.0 off (free motion)
    vin: np.ndarray
    duty: np.ndarray | None
    label: str  # the gain setting (runs with one label share one fitted gain)
    trajectory: str
    truth: dict[str, Any] = field(default_factory=dict)  # mass, length, kp, vin as logged: checked, never fitted
    source: str = ""  # the run's file

    @property
    def frames(self) -> int:
        return int(self.t.size)


def _column(entries: list[dict[str, Any]], key: str, where: str, why: str) -> np.ndarray:
    for i, e in enumerate(entries):
        if key not in e:
            raise DataError(f"{where}: entry {i} has no {key!r} ({why}); its fields: {', '.join(sorted(e))}")
    try:
        return np.asarray([float(e[key]) for e in entries], dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise DataError(f"{where}: column {key!r} is not numeric ({err})") from None


def _check_radians(x: np.ndarray, where: str, column: str) -> None:
    top = float(np.max(np.abs(x))) if x.size else 0.0
    if top > RAD_LIMIT:
        raise DataError(
            f"{where}: column {column!r} reaches {top:.4g}, beyond one turn in rad (|x| <= {RAD_LIMIT:.2f}): it looks "
            "like degrees; declare `units: deg` in the spec or convert the log"
        )


UNIT_RATIO = 20.0  # spread of position over goal beyond which one of them is in degrees (the servo follows its goal)


def _check_same_units(q: np.ndarray, goal: np.ndarray, on: np.ndarray, where: str, cols: Columns) -> None:
    """Position and goal in one unit: while its torque is on (`on`) a servo follows its goal, so their spreads
    differ by far less than 180/pi."""
    if int(on.sum()) < 10:
        return
    sq, sg = float(np.std(q[on])), float(np.std(goal[on]))
    if sq > 0 and sg > 0 and not 1.0 / UNIT_RATIO < sq / sg < UNIT_RATIO:
        big = cols.position if sq > sg else cols.goal
        raise DataError(
            f"{where}: column {big!r} spreads {max(sq, sg) / min(sq, sg):.3g}x more than "
            f"{cols.goal if big == cols.position else cols.position!r} (180/pi = 57.3): it looks like degrees while "
            "the other is in rad; log both in the spec's `units`"
        )


def read_run(path: Path, cols: Columns, *, units: str, load_scale: float | None, fps: float) -> ServoRun:
    """One run file, checked (time increasing, goal present, positions in the declared units, kp > 0), resampled."""
    where = f"servo log {path.name}"
    try:
        raw = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise DataError(f"{where}: not a readable JSON object ({err})") from None
    if not isinstance(raw, dict) or not isinstance(raw.get("entries"), list) or len(raw["entries"]) < 10:
        raise DataError(f"{where}: expected a JSON object with a list 'entries' of at least 10 samples")
    kp = raw.get("kp")
    if not isinstance(kp, (int, float)) or not np.isfinite(kp) or kp <= 0:
        raise DataError(f"{where}: kp is {kp!r}; the firmware gain of a position servo must be a number > 0")
    entries = raw["entries"]
    t = _column(entries, cols.time, where, "the sample time")
    check_times(t, where, cols.time)
    q = _column(entries, cols.position, where, "the measured position")
    goal = _column(entries, cols.goal, where, "the goal position, the servo's input")
    scale = np.pi / 180.0 if units == "deg" else 1.0
    if units == "rad":
        _check_radians(q, where, cols.position)
        _check_radians(goal, where, cols.goal)
    enable = _column(entries, cols.enable, where, "torque on/off") if cols.enable in entries[0] else np.ones_like(t)
    _check_same_units(q, goal, enable > 0.5, where, cols)
    vin = _column(entries, cols.volts, where, "supply") if cols.volts in entries[0] else np.full_like(t, 0.0)
    if not np.any(vin > 0):
        vin = np.full_like(t, float(raw.get("vin", 0.0)))
    if not np.all(vin > 0):
        raise DataError(f"{where}: no supply voltage: neither column {cols.volts!r} nor the run's 'vin' is > 0")
    columns = {"q": q * scale, "goal": goal * scale, "enable": enable, "vin": vin}
    if load_scale is not None:
        raw_load = _column(entries, cols.load, where, "the load reading the spec declares")
        signed = np.where(raw_load > 32767, raw_load - 65536, raw_load)  # two's complement 16-bit register
        columns["duty"] = np.clip(signed / load_scale, -1.0, 1.0)
    grid, out, _ = resample(t - t[0], columns, fps, where=where, column=cols.time)
    win = max(5, int(round(0.03 * fps)) | 1)
    dt = 1.0 / fps
    truth = {k: raw[k] for k in ("mass", "length", "kp", "vin", "motor", "arm_mass") if k in raw}
    return ServoRun(
        name=path.stem,
        fps=fps,
        t=grid,
        q=out["q"],
        dq=savgol_filter(out["q"], win, 2, deriv=1, delta=dt),
        ddq=savgol_filter(out["q"], win, 2, deriv=2, delta=dt),
        goal=out["goal"],
        enable=(out["enable"] > 0.5).astype(np.float64),
        vin=out["vin"],
        duty=out.get("duty"),
        label=f"kp={kp:g}",
        trajectory=str(raw.get("trajectory", "")),
        truth=truth,
        source=str(path),
    )


def read_runs(folder: Path, cols: Columns, *, units: str, load_scale: float | None, fps: float) -> list[ServoRun]:
    """Every `*.json` run of a folder, in name order (a DataError names the first bad file and what is wrong)."""
    if not folder.is_dir():
        raise DataError(f"servo logs folder {str(folder)!r} does not exist")
    files = sorted(folder.glob("*.json"))
    if not files:
        raise DataError(f"servo logs folder {str(folder)!r} holds no *.json run")
    return [read_run(f, cols, units=units, load_scale=load_scale, fps=fps) for f in files]

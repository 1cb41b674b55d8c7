"""An arm's LeRobot v3 dataset as the servo calibration reads it: goals (`action`) and positions
(`observation.state`) per joint, in radians, per episode.

Joints are matched by name: the action's element names (lerobot writes `shoulder_pan.pos`; `.pos` is
dropped) must be the arm's joints. `observation.state`'s entries are taken by the same names when it carries
them, else its first entries in the action's order (bench's own recordings name them agent_pos_0..).
Units (`ArmServoSpec.units`) are converted to radians and checked by range: positions beyond a full turn
where radians are declared, normalised values beyond -100..100 (gripper 0..100), and any position outside
the arm's joint range (by more than `SLACK`) are refused with one line naming the unit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bench.calibrate.servo.arm.spec import ArmServoSpec, MotorRange
from bench.core.errors import DataError
from bench.logs import Episode, LogDataset, read_dataset

GOAL, STATE = "action", "observation.state"
TICKS = 4095.0  # lerobot's degrees mode: (raw - mid) * 360 / 4095
SLACK = 0.35  # rad a logged position may lie beyond the model's joint range (calibration offsets, overshoot)


@dataclass(frozen=True)
class ArmLog:
    """Goals and positions of an arm's episodes, radians, on the dataset's frame grid."""

    joints: tuple[str, ...]
    fps: float
    goal: list[np.ndarray]  # per episode (T, J): the goal commanded at each frame (held until the next)
    q: list[np.ndarray]  # per episode (T, J): the position observed at each frame (before its goal acts)
    episodes: list[int]  # dataset episode index of each

    @property
    def frames(self) -> int:
        return sum(len(q) for q in self.q)

    def delayed(self, frames: int) -> ArmLog:
        """The log with every goal acting `frames` frames late (a transport delay): frame k's goal is the one
        logged at k - frames, and before that the episode's first goal (held)."""
        if frames <= 0:
            return self
        goal = [np.concatenate([np.repeat(g[:1], frames, axis=0), g[:-frames]])[: len(g)] for g in self.goal]
        return replace(self, goal=goal)


def _base(name: str) -> str:
    return name.removesuffix(".pos")


def _names(ds_features: dict, key: str, width: int) -> list[str]:
    names = ds_features.get(key, {}).get("names")
    if isinstance(names, dict):  # lerobot v2 wrote {"motors": [...]}
        names = next(iter(names.values()), None)
    return [str(n) for n in names] if isinstance(names, list) and len(names) == width else []


def normalized_to_rad(values: np.ndarray, joint: str, r: MotorRange, gripper: bool) -> np.ndarray:
    """lerobot's normalised units (RANGE_M100_100, or RANGE_0_100 for the gripper) -> radians from mid-range."""
    v = np.asarray(values, np.float64)
    span = r.range_max - r.range_min
    if gripper:
        v = 100.0 - v if r.drive_mode else v
        raw = v / 100.0 * span + r.range_min
    else:
        v = -v if r.drive_mode else v
        raw = (v + 100.0) / 200.0 * span + r.range_min
    return (raw - (r.range_min + r.range_max) / 2.0) * (2.0 * math.pi / TICKS)


def rad_to_normalized(q: np.ndarray, r: MotorRange, gripper: bool) -> np.ndarray:
    """The inverse of `normalized_to_rad` (what a lerobot recording of these angles would hold)."""
    raw = np.asarray(q, np.float64) * (TICKS / (2.0 * math.pi)) + (r.range_min + r.range_max) / 2.0
    span = r.range_max - r.range_min
    if gripper:
        v = (raw - r.range_min) / span * 100.0
        return 100.0 - v if r.drive_mode else v
    v = (raw - r.range_min) / span * 200.0 - 100.0
    return -v if r.drive_mode else v


def _to_rad(x: np.ndarray, spec: ArmServoSpec, joints: tuple[str, ...], column: str, where: str) -> np.ndarray:
    if spec.units == "rad":
        big = float(np.max(np.abs(x))) if x.size else 0.0
        if big > 2.0 * math.pi:
            raise DataError(
                f"{where}: {column} reaches {big:.4g}, more than a turn in radians: degrees where radians are "
                "declared? (spec units: rad; use deg or normalized)"
            )
        return x
    if spec.units == "deg":
        return np.radians(x)
    assert spec.ranges is not None, "a normalized spec has its ranges (parse_servo_arm_spec)"
    out = np.empty_like(x)
    for j, name in enumerate(joints):
        if name not in spec.ranges:
            raise DataError(
                f"spec field 'ranges': {spec.ranges_path} has no motor {name!r}; it has {', '.join(spec.ranges)}"
            )
        grip = name == spec.gripper
        lo, hi = (0.0, 100.0) if grip else (-100.0, 100.0)
        col = x[:, j]
        if col.size and (col.min() < lo - 1.0 or col.max() > hi + 1.0):
            raise DataError(
                f"{where}: {column} of {name!r} spans {col.min():.4g}..{col.max():.4g}, outside lerobot's "
                f"normalised {lo:g}..{hi:g}: not normalised units (spec units: normalized; use rad or deg)"
            )
        out[:, j] = normalized_to_rad(col, name, spec.ranges[name], grip)
    return out


def read_arm_log(path: Path, spec: ArmServoSpec, joints: tuple[str, ...], limits: np.ndarray) -> ArmLog:
    """The dataset at `path` for an arm with `joints` (model order) and joint `limits` (J, 2), in radians."""
    if not path.exists():
        raise DataError(f"logs folder {str(path)!r} does not exist")
    ds = read_dataset(path)
    for col in (GOAL, STATE):
        if col not in ds.features:
            what = "goal positions" if col == GOAL else "positions"
            raise DataError(
                f"{path}: no {col!r} column ({what}); an arm's servo calibration reads the goal (action) and the "
                f"position (observation.state); columns: {', '.join(sorted(ds.features))}"
            )
    width = int(np.prod(ds.feature_shape(GOAL)))
    goal_names = [_base(n) for n in _names(ds.features, GOAL, width)]
    if sorted(goal_names) != sorted(joints):
        raise DataError(
            f"{path}: the action's joints ({', '.join(goal_names) or 'unnamed'}) are not the {spec.arm}'s "
            f"({', '.join(joints)}); a dataset of another arm?"
        )
    g_idx = [goal_names.index(j) for j in joints]
    s_width = int(np.prod(ds.feature_shape(STATE)))
    state_names = [_base(n) for n in _names(ds.features, STATE, s_width)]
    if all(j in state_names for j in joints):
        s_idx = [state_names.index(j) for j in joints]
    elif s_width >= width:
        s_idx = [goal_names.index(j) for j in joints]  # the state's first entries, in the action's order
    else:
        raise DataError(f"{path}: observation.state has {s_width} entries, fewer than the {width} joints")
    goal, q, idx = [], [], []
    for ep in ds.episodes:
        where = f"{path} episode {ep.index}"
        g = np.asarray(ep.data[GOAL], np.float64).reshape(len(ep), -1)[:, g_idx]
        s = np.asarray(ep.data[STATE], np.float64).reshape(len(ep), -1)[:, s_idx]
        if len(ep) < 3:
            continue
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(s))):
            raise DataError(f"{where}: a goal or position is not a finite number")
        g, s = _to_rad(g, spec, joints, GOAL, where), _to_rad(s, spec, joints, STATE, where)
        for j, name in enumerate(joints):
            lo, hi = limits[j]
            if s[:, j].min() < lo - SLACK or s[:, j].max() > hi + SLACK:
                raise DataError(
                    f"{where}: {name} spans {s[:, j].min():.3g}..{s[:, j].max():.3g} rad after conversion from "
                    f"{spec.units}, beyond its joint range {lo:.3g}..{hi:.3g}: are the units right (spec units)?"
                )
        goal.append(g)
        q.append(s)
        idx.append(int(ep.index))
    if len(q) < 2:
        raise DataError(f"{path}: {len(q)} episode(s) of 3 frames or more; the calibration holds out whole episodes")
    return ArmLog(joints, float(ds.fps), goal, q, idx)


def in_units(
    ds: LogDataset,
    joints: tuple[str, ...],
    units: str,
    ranges: dict[str, MotorRange] | None = None,
    gripper: str = "gripper",
) -> LogDataset:
    """A copy of `ds` (goals and positions in radians, the joints first in `action` and `observation.state`) with
    its joints written as lerobot would: `deg`, or `normalized` through `ranges`; the action named `<joint>.pos`."""

    def convert(x: np.ndarray) -> np.ndarray:
        y = np.array(x, np.float64)
        for j, name in enumerate(joints):
            if units == "deg":
                y[:, j] = np.degrees(y[:, j])
            elif units == "normalized":
                assert ranges is not None, "normalized units need the ranges"
                y[:, j] = rad_to_normalized(y[:, j], ranges[name], name == gripper)
        return y.astype(np.asarray(x).dtype)

    episodes = [
        Episode(ep.index, {**ep.data, GOAL: convert(ep.data[GOAL]), STATE: convert(ep.data[STATE])}, ep.tasks, ep.meta)
        for ep in ds.episodes
    ]
    features = dict(ds.features)
    features[GOAL] = {**features[GOAL], "names": [f"{j}.pos" for j in joints]}
    return LogDataset(ds.fps, features, episodes, ds.tasks, ds.robot_type)

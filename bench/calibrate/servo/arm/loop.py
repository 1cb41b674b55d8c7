"""An arm's servos calibrated from a LeRobot dataset: read, split, fit, check on held-out episodes.

Held out: a seeded share of whole episodes (`spec.holdout`, at least one). The check simulates each held-out
episode whole from its second frame under its goals (free run) and in the fit's windows, with the declared servos
(the suite's MJCF) and with the fitted ones: position RMSE per joint, before and after.

Transport delay (`spec.max_delay`): a goal that acts d frames after it is logged (the bus, the firmware's cycle, a
policy's latency) biases every servo's fit (a hidden 2-frame delay on the simulated SO-101: stiffnesses 18-78% low,
8 of 18 truths inside their intervals). The delay is searched in whole frames, 0 to `max_delay`: for each, the
linear start on the training episodes with the goals delayed, simulated over the training windows; one more frame
is kept only while it lowers that window error by at least `DELAY_GAIN` (as an effect is added only when it pays).
The fit, the draws and the fitted check use the chosen delay; the declared servos are checked without one (the
MJCF has none). calibration.json's `apply.delay_steps` carries it into `bench run ... calibration=`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench.calibrate.servo.arm.data import ArmLog, read_arm_log
from bench.calibrate.servo.arm.fit import Fit, Windows, linear_start, refine, simulate, windows
from bench.calibrate.servo.arm.model import Arm, ArmServos, load_arm
from bench.calibrate.servo.arm.spec import ArmServoSpec
from bench.core.errors import DataError

DRAWS = 64  # bootstrap-style draws of the fitted servos written for `perturb.AXIS=from(...)`
DELAY_GAIN = 0.1  # one more frame of delay is kept only if it lowers the training windows' error by this share
Z95 = 1.959964


@dataclass
class ArmServoCalibration:
    """What `calibrate_arm_servos` found (calibration.json and report.md are written from it)."""

    spec: ArmServoSpec
    arm: Arm
    log: ArmLog
    logs: str
    train: list[int]
    heldout: list[int]
    declared: ArmServos
    start: ArmServos
    fit: Fit
    errors: dict[str, Any]
    draws: np.ndarray  # (DRAWS, 4J) kind-major
    wall: dict[str, float]
    cpu: dict[str, float]
    warnings: list[str] = field(default_factory=list)
    delay: int = 0  # frames: the transport delay found (goals act this many frames after they are logged)
    delay_search: list[float] = field(default_factory=list)  # window RMSE (rad) of the linear start per delay

    @property
    def servos(self) -> ArmServos:
        return self.fit.servos

    def interval(self) -> tuple[np.ndarray, np.ndarray]:
        """95% intervals of every fitted parameter (kind-major vectors, natural units; clipped at zero)."""
        x = self.servos.vector().reshape(4, -1)
        sd = np.sqrt(np.maximum(np.einsum("jkk->kj", self.fit.covariance), 0.0))
        return np.maximum(x - Z95 * sd, 0.0).ravel(), (x + Z95 * sd).ravel()


def _rmse(pred: np.ndarray, target: np.ndarray) -> dict[str, Any]:
    err = pred - target
    per_joint = np.sqrt(np.mean(err.reshape(-1, err.shape[-1]) ** 2, axis=0))
    return {"rmse": float(np.sqrt(np.mean(err**2))), "per_joint": [float(v) for v in per_joint]}


def held_out_errors(
    arm: Arm, heldout: list[int], frames: int, models: dict[str, tuple[ArmServos, ArmLog]]
) -> dict[str, Any]:
    """Free-run and window position RMSE (rad) of the held-out episodes under each named (servos, log): the log
    gives the goals the servos act on (the dataset's, or the same delayed). Models sharing a log share its windows
    and one rollout."""
    out: dict[str, Any] = {"free_run": {}, "window": {}}
    n_j = len(arm.joints)
    groups: dict[int, list[str]] = {}
    for name, (_, log) in models.items():
        groups.setdefault(id(log), []).append(name)
    for names in groups.values():
        log, servos = models[names[0]][1], [models[n][0] for n in names]
        win = windows(arm, log, heldout, frames)
        if len(win.state):
            for n, s in zip(names, simulate(arm, servos, win)):
                out["window"][n] = _rmse(s, win.target)
        whole = [windows(arm, log, [e], 0) for e in heldout]
        runs = [simulate(arm, servos, w) for w in whole]
        target = np.concatenate([w.target.reshape(-1, n_j) for w in whole])
        for i, n in enumerate(names):
            out["free_run"][n] = _rmse(np.concatenate([r[i].reshape(-1, n_j) for r in runs]), target)
    if not out["window"]:  # held-out episodes shorter than a window: the free run is the whole check
        out["window"] = out["free_run"]
    return out


def split(n: int, share: float, seed: int) -> tuple[list[int], list[int]]:
    """(train, held out) episode positions: a seeded `share` of whole episodes held out, at least one each."""
    order = np.random.default_rng(seed).permutation(n)
    k = min(max(1, round(share * n)), n - 1)
    return sorted(int(i) for i in order[k:]), sorted(int(i) for i in order[:k])


def calibrate_arm_servos(
    spec: ArmServoSpec, logs: str | Path, *, seed: int = 0, log: Callable[[str], None] = lambda msg: None
) -> ArmServoCalibration:
    """The loop (module docstring): the arm's servos fitted to the dataset at `logs`."""
    wall0, cpu0 = time.perf_counter(), time.process_time()
    arm = load_arm(spec.suite)
    data = read_arm_log(Path(logs).expanduser(), spec, arm.joints, arm.limits)
    if abs(data.fps - arm.fps) > 1e-6:
        raise DataError(
            f"{logs}: recorded at {data.fps:g} fps; the {spec.arm}'s model steps its servos at {arm.fps:g} fps "
            "(lerobot records the SO-101 at 30): resample the dataset"
        )
    train, heldout = split(len(data.q), spec.holdout, seed)
    frames = max(2, round(spec.horizon * data.fps))
    log(
        f"{spec.arm}: {len(data.q)} episodes, {data.frames} frames at {data.fps:g} fps ({spec.units}); "
        f"{len(heldout)} held out; servos of {', '.join(arm.joints)}"
    )
    wall1, cpu1 = time.perf_counter(), time.process_time()
    declared = arm.declared()
    search: list[float] = []
    best: tuple[int, ArmServos, Windows, list[float]] | None = None
    for d in range(round(spec.max_delay * data.fps) + 1):
        delayed = data.delayed(d)
        start_d = linear_start(arm, delayed, train, declared, spec.free)
        win_d = windows(arm, delayed, train, frames)
        if len(win_d.state) < 2:
            raise DataError(
                f"{logs}: the training episodes hold {len(win_d.state)} window(s) of horizon {spec.horizon:g} s "
                f"({frames} frames); record longer episodes or lower the spec's horizon"
            )
        # the start that simulates the training windows better: the linear one, or the declared servos
        costs_d = [float(np.mean((s - win_d.target) ** 2)) for s in simulate(arm, [start_d, declared], win_d)]
        search.append(float(np.sqrt(min(costs_d))))
        if best is not None and search[-1] > (1.0 - DELAY_GAIN) * search[best[0]]:
            break  # one more frame does not pay: the delay is the one before
        best = (d, start_d, win_d, costs_d)
    assert best is not None
    delay, start, win, costs = best
    if len(search) > 1:
        log(
            f"  transport delay: {delay} frame(s) ({1e3 * delay / data.fps:.0f} ms); linear-start window RMSE by "
            "delay " + ", ".join(f"{i}: {v:.4g}" for i, v in enumerate(search)) + " rad"
        )
    wall2, cpu2 = time.perf_counter(), time.process_time()
    first = start if costs[0] <= costs[1] else declared
    log(f"  linear start: window RMSE {np.sqrt(costs[0]):.4g} rad (declared {np.sqrt(costs[1]):.4g})")
    fit = refine(arm, first, declared, win, spec.free, log)
    wall3, cpu3 = time.perf_counter(), time.process_time()
    # the declared servos act on the logged goals (the MJCF has no delay), the fitted ones on the delayed goals
    errors = held_out_errors(
        arm, heldout, frames, {"declared": (declared, data), "fitted": (fit.servos, data.delayed(delay))}
    )
    rng = np.random.default_rng(seed)
    x = fit.servos.vector().reshape(4, -1)
    draws = np.empty((DRAWS, x.size))
    for j in range(x.shape[1]):
        sample = rng.multivariate_normal(x[:, j], fit.covariance[j], size=DRAWS, method="eigh")
        draws[:, j :: x.shape[1]] = sample
    draws = np.maximum(draws, 0.0)
    draws[:, : x.shape[1]] = np.maximum(draws[:, : x.shape[1]], 1e-3 * x[0])  # a stiffness stays positive
    wall4, cpu4 = time.perf_counter(), time.process_time()
    warnings = []
    if errors["free_run"]["fitted"]["rmse"] >= errors["free_run"]["declared"]["rmse"]:
        warnings.append("the fitted servos simulate the held-out episodes no better than the declared ones")
    return ArmServoCalibration(
        spec=spec,
        arm=arm,
        log=data,
        logs=str(Path(logs).expanduser().resolve()),
        train=train,
        heldout=heldout,
        declared=declared,
        start=start,
        fit=fit,
        errors=errors,
        draws=draws,
        wall={
            "read": wall1 - wall0,
            "linear": wall2 - wall1,
            "refine": wall3 - wall2,
            "check": wall4 - wall3,
            "total": wall4 - wall0,
        },
        cpu={"total": cpu4 - cpu0, "fit": (cpu2 - cpu1) + (cpu3 - cpu2)},
        warnings=warnings,
        delay=delay,
        delay_search=search,
    )

"""Calibrate a suite's own robot from `bench run record=` logs, in the suite's own scene model.

    bench calibrate suite=held_out_robots robot=Panda logs=DIR out=DIR

The logs are what `bench run ... record=DIR` writes (or the same recorded on the real robot): the
MuJoCo state before every frame (`observation.sim_state`) and the command of every physics step
(`action.ctrl`). The model is the suite's nominal env for that robot, the whole scene (table,
object, gripper) included. Calibrated are the robot's torque-driven joints (joints driven by a
motor: joint transmission, no bias); they are the logged coordinates compared and fitted. Every
segment starts from the full logged state, and is driven by the logged commands of its physics
steps, so the controller's output is taken from the log (replay's `commands=ctrl`).

Declared free: a damping scale and an armature scale over the robot's joints (one factor each on
the model's own values); searched: the effects a run can carry in the model itself (Coulomb
friction per joint, a payload per link, a gain error per motor). Held out: the 30% of episodes that
repeat the others least (`bench.calibrate.data.choose_split`; the seeded share when all are equally
new), scored beside a repeat baseline (`calibration.json`'s `heldout` and `trust`). The result can be
applied to runs (`bench.calibrate.apply`).
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path
from typing import TypedDict

import mujoco
import numpy as np

from bench.calibrate.apply import edits, model_hash
from bench.calibrate.data import with_split
from bench.calibrate.model import Plant, Scene
from bench.calibrate.spec import CalibrationSpec, EffectRequest, ParamSpec, TraceSpec
from bench.calibrate.trace import Calibration, calibrate
from bench.core.errors import ConfigError, DataError, did_you_mean
from bench.logs import Episode, LogDataset, read_dataset
from bench.protocols import registry
from bench.replay.common import CTRL, ReplayConfig
from bench.replay.data import Recording, Window
from bench.replay.simulate import Coordinates
from bench.replay.spec import SignalSpec
from bench.replay.suite_env import load_suite_logs

# effects realised in MjModel fields (a run's env carries them without any change to its step loop)
EFFECTS = ("coulomb_friction", "payload_mass", "actuator_gain")
HOLDOUT, HORIZON = 0.3, 0.25  # share of episodes held out; seconds per truncated horizon
MAX_EFFECTS = 6  # a robot has several joints: room for an effect on each of a few


class SuiteLogs(TypedDict):
    """calibration.json's `suite` section: the suite, its robot and the logs fitted."""

    name: str
    version: str
    robot: str
    logs: str
    condition: str | None
    episodes: list[int]  # dataset index of each episode used


class PlantInfo(TypedDict):
    """What identifies a suite's plant (`suite_plant`)."""

    suite: SuiteLogs
    nominal: mujoco.MjModel  # the robot's model in its nominal scene
    joints: list[str]  # the motor-driven joints calibrated
    model_hash: str  # `bench.calibrate.apply.model_hash` of `nominal`


def torque_joints(model: mujoco.MjModel) -> list[int]:
    """Joints driven by a motor (joint transmission, no bias term): the robot's arm, not its servo gripper."""
    out = []
    for a in range(model.nu):
        if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT and model.actuator_biastype[a] == 0:
            j = int(model.actuator_trnid[a, 0])
            if model.jnt_type[j] in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
                out.append(j)
    return sorted(set(out))


def _episodes(ds: LogDataset, logs: Path, robot: str, condition: str | None) -> list[Episode]:
    meta = [ep.meta if isinstance(ep.meta, dict) else {} for ep in ds.episodes]
    robots = sorted({str(m.get("robot")) for m in meta})
    eps = [ep for ep, m in zip(ds.episodes, meta) if m.get("robot") == robot]
    if not eps:
        listing = ", ".join(robots) or "none (not a `bench run record=` dataset?)"
        raise ConfigError(
            f"robot={robot!r}: no episode of {logs} was recorded with it; robots in the log: "
            f"{listing}.{did_you_mean(robot, robots)}"
        )
    if condition is not None:
        conds = sorted({str(m.get("condition")) for ep, m in zip(ds.episodes, meta) if m.get("robot") == robot})
        eps = [ep for ep in eps if ep.meta.get("condition") == condition]
        if not eps:
            raise ConfigError(
                f"condition={condition!r}: no episode of robot {robot!r} in {logs} has it; conditions: "
                f"{', '.join(conds)}.{did_you_mean(condition, conds)}"
            )
    if len(eps) < 2:
        raise DataError(
            f"{logs}: {len(eps)} episode of robot {robot!r}; calibration holds out whole episodes and needs at least 2"
        )
    return eps


def suite_plant(
    suite: str, robot: str, logs: str | Path, seed: int = 0, threads: int = 1, condition: str | None = None
) -> tuple[Plant, PlantInfo]:
    """The plant of a suite's robot in its nominal scene, with the logs of that robot; and what identifies it."""
    path = Path(logs).expanduser()
    if not path.exists():
        raise DataError(f"logs folder {str(path)!r} does not exist")
    cls = registry.suite_class(suite)
    ds = read_dataset(path)
    eps = _episodes(ds, path, robot, condition)
    sl = load_suite_logs(ReplayConfig(logs=str(path), suite=suite, threads=threads), ds, eps, need_ctrl=True)
    try:
        scenes = len({id(e) for e in sl.envs})
        if scenes != 1:
            raise DataError(
                f"{path}: the episodes of robot {robot!r} come from {scenes} scenes; calibrate one scene at a time"
            )
        if sl.ctrl_spec != int(mujoco.mjtState.mjSTATE_CTRL):
            raise DataError(
                f"{path}: {CTRL!r} holds more than actuator commands (ctrl_spec {sl.ctrl_spec}); "
                "a suite calibration drives the model by its actuators only"
            )
        model = copy.copy(sl.envs[0].mujoco.model)
    finally:
        sl.close()
    joints = torque_joints(model)
    names = [model.joint(j).name for j in joints]
    qadr, dadr = model.jnt_qposadr[joints], model.jnt_dofadr[joints]
    if not joints or not (np.array_equal(qadr, np.arange(len(joints))) and np.array_equal(dadr, qadr)):
        raise DataError(
            f"suite {suite!r}: the motor-driven joints of {robot} ({', '.join(names) or 'none'}) are not "
            "the model's leading coordinates; this suite's scene cannot be calibrated"
        )
    full, nq = sl.full, model.nq
    assert sl.ctrl is not None  # need_ctrl
    lengths = [int(sl.offsets[i + 1] - sl.offsets[i]) for i in range(len(sl.eps))]
    ctrl = sl.ctrl.reshape(len(full) * sl.substeps, model.nu)
    rec = Recording(
        fps=float(ds.fps),
        qpos=full[:, qadr],
        qvel=full[:, nq + dadr],
        ctrl=ctrl[:: sl.substeps].copy(),
        inputs=None,
        offsets=sl.offsets,
        train=[Window(i, 0, n) for i, n in enumerate(lengths)],
        holdout=[],
        qvel_logged=True,
    )

    def init(frames: np.ndarray, qpos: np.ndarray, qvel: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return full[frames, :nq].copy(), full[frames, nq:].copy()  # the whole scene as logged

    scene = Scene(Coordinates(qadr, dadr, init), ctrl, sl.substeps, tuple(joints))
    spec = CalibrationSpec(
        model=Path(f"{suite}/{robot}"),
        signals={
            "qpos": SignalSpec("observation.sim_state", tuple(int(i) for i in qadr)),
            "qvel": SignalSpec("observation.sim_state", tuple(int(nq + i) for i in dadr)),
            "ctrl": SignalSpec(CTRL, tuple(range(model.nu))),
        },
        substeps=sl.substeps,
        params=(
            ParamSpec("damping_scale", "dof_damping", tuple(names), (0.1, 100.0), scale=True),
            ParamSpec("armature_scale", "dof_armature", tuple(names), (0.25, 4.0), scale=True),
        ),
        effects=tuple(EffectRequest(e) for e in EFFECTS),
        holdout=HOLDOUT,
        horizon=HORIZON,
        trace=TraceSpec(max_effects=MAX_EFFECTS),
        threads=threads,
        source=path,
    )
    info: PlantInfo = {
        "suite": {
            "name": cls.name,
            "version": cls.version,
            "robot": robot,
            "logs": str(path.resolve()),
            "condition": condition,
            "episodes": [int(ep.index) for ep in sl.eps],
        },
        "nominal": copy.copy(model),
        "joints": names,
        "model_hash": model_hash(model, names),
    }
    rec = with_split(rec, spec, seed)  # the least repeated episodes held out (bench.calibrate.novelty)
    return Plant(spec, model, rec, scene), info


def calibrate_suite(
    suite: str,
    robot: str,
    logs: str | Path,
    *,
    seed: int = 0,
    threads: int = 1,
    log: Callable[[str], None] = lambda msg: None,
    residual: bool = False,
    condition: str | None = None,
) -> tuple[Calibration, dict[str, object]]:
    """The loop on a suite's robot; the calibration and the `suite` and `apply` sections of its JSON.

    `condition` keeps only the episodes recorded under it (a log that mixes conditions)."""
    plant, info = suite_plant(suite, robot, logs, seed, threads, condition)
    log(
        f"{suite} {robot}: {plant.rec.n_episodes} episodes, {len(plant.rec.qpos)} frames at {plant.rec.fps:g} Hz, "
        f"{plant.substeps} physics steps per frame; calibrating {', '.join(info['joints'])}"
    )
    cal = calibrate(plant, seed=seed, threads=threads, log=log, residual=residual)
    fitted = cal.layout.realise(cal.final_fit.x).model
    extra: dict[str, object] = {
        "suite": info["suite"],
        "apply": {
            "robot": robot,
            "joints": info["joints"],
            "model_hash": info["model_hash"],
            "edits": edits(info["nominal"], fitted),
        },
    }
    return cal, extra

"""The forward check of an arm calibration: both models driven by the logged torque, from logged states.

Inverse dynamics fits torques; a suite steps the simulator forward. This check replays what the
robot did in both the declared and the calibrated model: each held-out horizon (`horizon` seconds)
starts from the logged position and velocity and is simulated under the logged torque (the
calibrated side with the signal's fitted offset removed and its gain error applied), all horizons
batched in `mujoco.rollout`, contacts off (the real arm's workspace is not the suite's scene) and the
simulator's air drag off (MuJoCo's fluid model acts on each body's equivalent inertia box, which
for placeholder or fitted inertias is not the arm's shape; inverse dynamics leaves it out too). The
per-joint position RMSE of the two models is compared. There is no free run: an arm replayed open
loop under torque drifts away within a second whatever its model, so a long horizon measures the
drift, not the model. A `measured` torque is the link-side torque of a joint torque sensor: the rotor
inertia (armature) is on the sensor's other side, so both models step their links without it.
"""

from __future__ import annotations

import copy
from typing import Any

import mujoco
import numpy as np

from bench.calibrate.arm.data import ArmLog
from bench.calibrate.arm.model import ArmModel, require_motors
from bench.calibrate.arm.spec import ArmSpec
from bench.replay.data import Recording, Window
from bench.replay.metrics import segment_errors
from bench.replay.simulate import Coordinates, Simulator, Variant, horizons

MIN_FRAMES = 2  # a horizon shorter than this is no forward check


def _prepare(model: mujoco.MjModel, fps: float) -> tuple[mujoco.MjModel, int]:
    """A copy stepping a whole number of times per frame, contacts off; coordinates not logged (a gripper,
    a free object) start where the model keeps them."""
    m = copy.copy(model)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    m.opt.density, m.opt.viscosity = 0.0, 0.0  # the fluid model drags inertia boxes, not the real arm's shape
    substeps = max(1, int(round(1.0 / (fps * m.opt.timestep))))
    m.opt.timestep = 1.0 / (fps * substeps)
    return m, substeps


def _init(am: ArmModel, nv: int):
    """Full initial rows from the logged arm rows: every other coordinate where the model keeps it."""

    def init(frames: np.ndarray, lq: np.ndarray, lv: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        fq = np.repeat(am.qpos0[None, :], len(frames), axis=0)
        fv = np.zeros((len(frames), nv))
        fq[:, am.qadr], fv[:, am.dadr] = lq, lv
        return fq, fv

    return init


def forward_errors(
    am: ArmModel,
    spec: ArmSpec,
    data: ArmLog,
    fitted: mujoco.MjModel,
    values: dict[str, Any],
    offsets: dict[str, float],
    threads: int = 1,
) -> dict[str, Any]:
    """Per-joint k-step position errors of the declared and the calibrated model on held-out data."""
    why = require_motors(am)
    if why:
        return {"skipped": f"no forward check: {why}"}
    src = data.source_fps
    step = max(1, int(round(src * am.model.opt.timestep)))  # log frames per model timestep (at least one)
    fps = src / step
    q, dq, tau = (data.dense[k][::step] for k in ("q", "dq", "tau"))
    if spec.gains:  # a current signal in torque units
        tau = tau * np.asarray(spec.gains)
    offs = np.concatenate(
        [
            [0],
            np.cumsum(
                [len(range(0, int(b - a), step)) for a, b in zip(data.dense_offsets[:-1], data.dense_offsets[1:])]
            ),
        ]
    )
    hold = [Window(e, a // step, min(int(offs[e + 1] - offs[e]), b // step)) for e, a, b in data.dense_hold]
    k = max(MIN_FRAMES, int(round(spec.horizon * fps)))
    gains = np.array([values["joints"].get(jn, {}).get("gain", 1.0) for jn in am.joints])
    off = np.array([offsets.get(jn, 0.0) for jn in am.joints])
    results: dict[str, Any] = {"horizon_s": k / fps, "frames": k, "fps": fps}
    # the declared model takes the signal as its torque; the calibrated one applies g * s - offset, where
    # its own actuator gain already carries g (force = gear * g * ctrl), so ctrl = (s - offset / g) / gear
    for label, model, ctrl_arm in (("nominal", am.model, tau), ("final", fitted, tau - off / gains)):
        m, substeps = _prepare(model, fps)
        if spec.torque == "measured":  # a link-side torque drives the link: the rotor is on the sensor's other side
            m.dof_armature[am.dadr] = 0.0
        ctrl = np.zeros((len(q), m.nu))
        ctrl[:, am.motors] = ctrl_arm / m.actuator_gear[am.motors, 0] / am.model.actuator_gainprm[am.motors, 0]
        if spec.controller is not None:  # the log's loop closed in the simulation (bench.calibrate.feedback)
            kp, kd = (np.asarray(g) for g in spec.controller)
            gear, gain = m.actuator_gear[am.motors, 0], m.actuator_gainprm[am.motors, 0]
            m.actuator_biastype[am.motors] = mujoco.mjtBias.mjBIAS_AFFINE
            m.actuator_biasprm[am.motors, 0] = 0.0
            m.actuator_biasprm[am.motors, 1] = -kp / gear**2
            m.actuator_biasprm[am.motors, 2] = -kd / gear**2
            m.actuator_ctrllimited[am.motors] = 0
            ctrl[:, am.motors] += (kp * q + kd * dq) / (gear * gain)
        rec = Recording(
            fps=fps, qpos=q, qvel=dq, ctrl=ctrl, inputs=None, offsets=offs, train=[], holdout=hold, qvel_logged=True
        )
        coords = Coordinates(am.qadr, am.dadr, _init(am, m.nv))
        sim = Simulator(m, rec, substeps, threads)
        try:
            segs = horizons(rec, hold, k)
            variant = Variant(m, np.repeat(ctrl, substeps, axis=0), np.zeros(m.nv), coords=coords)
            pred = sim.run([variant], segs)[0][..., : len(am.joints)]
        finally:
            sim.close()
        spread = np.maximum(q[rec.frames(hold)].std(axis=0), 1e-12)
        err = segment_errors(pred, rec, segs, spread)
        results.setdefault("k_step", {})[label] = {
            "rmse": err.rmse.tolist(),
            "nrmse": float(np.mean(err.nrmse)),
            "finite": bool(np.all(np.isfinite(pred))),
        }
    return results

"""Logs recorded under a feedback controller: the simulation closes the same loop around the log.

A robot that tracked a reference under a joint PD loop logged its command u = u_ff + kp (q_ref - q)
+ kd (dq_ref - dq). Replaying that command open loop in a model that differs slightly from the robot
drifts away (the robot's own loop would have corrected it), so free-run errors grow whatever the
model; a fit that lowers the k-step error can raise the free-run one. Declaring the loop's gains
(`controller: {kp: [...], kd: [...]}`, one per actuator, in joint torque per rad and per rad/s)
makes every simulated horizon run under the same feedback: the applied command is

    u_sim = u_log + kp (q_log - q_sim) + kd (dq_log - dq_sim)

(the logged command plus the loop's reaction to the simulated deviation from the log; the reference
and the feedforward cancel out). It is MuJoCo's own affine actuator bias, so it runs inside
`mujoco.rollout` at full speed: each motor gets biasprm = [0, -kp / G^2, -kd / G^2] (G its gear) and
the command ctrl = u_log + (kp q_log + kd dq_log) / (G g) (g its gain). Effects that act on the
command (delay, saturation, dead band) then act on that whole command.
"""

from __future__ import annotations

import copy
from dataclasses import replace

import mujoco

from bench.core.errors import SpecError
from bench.replay.data import Recording
from bench.replay.spec import check_keys, number


def close_loop(
    model: mujoco.MjModel, rec: Recording, kp: tuple[float, ...], kd: tuple[float, ...]
) -> tuple[mujoco.MjModel, Recording]:
    """The model with each motor closed by its PD gains, and the recording's commands re-expressed for it."""
    if len(kp) != model.nu or len(kd) != model.nu:
        raise SpecError(f"spec field 'controller': kp and kd need one gain per actuator ({model.nu})")
    m = copy.copy(model)
    ctrl = rec.ctrl.copy()
    for a in range(model.nu):
        if kp[a] == 0 and kd[a] == 0:
            continue
        if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT or model.actuator_biastype[a] != 0:
            raise SpecError(
                f"spec field 'controller': actuator {a} is not a plain motor on a joint; a declared loop closes "
                "around motors only"
            )
        j = int(model.actuator_trnid[a, 0])
        gear, gain = float(model.actuator_gear[a, 0]), float(model.actuator_gainprm[a, 0])
        if gear == 0 or gain == 0:
            raise SpecError(f"spec field 'controller': actuator {a} has gear or gain 0")
        m.actuator_biastype[a] = mujoco.mjtBias.mjBIAS_AFFINE
        m.actuator_biasprm[a, :3] = [0.0, -kp[a] / gear**2, -kd[a] / gear**2]
        q = rec.qpos[:, int(model.jnt_qposadr[j])]
        dq = rec.qvel[:, int(model.jnt_dofadr[j])]
        ctrl[:, a] = rec.ctrl[:, a] + (kp[a] * q + kd[a] * dq) / (gear * gain)
        m.actuator_ctrllimited[a] = 0  # the PD terms ride on the command: the motor's own limit no longer applies
    return m, replace(rec, ctrl=ctrl)


def gains(raw: object, where: str = "controller") -> tuple[tuple[float, ...], tuple[float, ...]]:
    """kp and kd lists of a spec's `controller` mapping (numbers >= 0)."""
    raw = check_keys(raw, ("kp", "kd"), where)
    out = []
    for key in ("kp", "kd"):
        v = raw.get(key)
        if not isinstance(v, (list, tuple)) or not v:
            raise SpecError(f"spec field '{where}.{key}' must list one gain per actuator; got {v!r}")
        out.append(tuple(number(x, f"{where}.{key}", lo=0.0) for x in v))
    if len(out[0]) != len(out[1]):
        raise SpecError(f"spec field '{where}': kp and kd name {len(out[0])} and {len(out[1])} gains")
    return out[0], out[1]

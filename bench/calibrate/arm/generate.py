"""Synthetic real-arm logs whose answer is known: a six-joint arm's torque log with one hidden effect.

The arm (`models/arm6.xml`) follows an excitation trajectory inside its range (`EXCITATIONS`):

- `fourier` (default): five harmonics per joint whose base period is the log's duration (one period:
  nothing repeats);
- `periodic`: the same with a 10 s period, so a 20 s log repeats itself (a time split holds out states
  the fit has seen: `bench.calibrate.novelty`);
- `one_path`: every joint follows one scalar path along one direction of joint space (q = q_mid + d s(t)),
  as a careless excitation does: a payload's mass and centre of mass then trade off and only some of
  their combinations are identified.

What is logged is what a real arm logs: joint positions, velocities (with
noise) and the joint torque (the truth model's inverse dynamics, plus Coulomb and viscous friction
and a constant sensor offset, with noise), on a jittery clock (periods of 1 ms +-30%, and a few of
3 ms). The hidden effect:

- `payload`: a 1.2 kg point mass 5 cm beyond the flange, off its axis ((0.05, 0.02, 0.03) m in the
  flange frame; `payload_com` moves it, e.g. a tool whose centre of mass sits 25 cm out);
- `actuator_gain`: the log holds the commanded torque (`torque: command`) and joint 2's drive delivers
  80% of it;
- `none`: nothing but the declared friction terms (a search that adds anything here is spurious).

Every case's spec trusts the arm's links (`inertia: none`), as a user with a manufacturer's model and an
unknown tool or drive would: a payload rigidly fixed to the last link, or one drive's gain, is
otherwise indistinguishable from corrections to the links' inertial parameters (no torque log can
tell them apart), and the report would say so.

All draws come from `numpy.random.default_rng(seed)`.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np
import yaml

from bench.calibrate.arm.inertial import point_mass, set_std, std_params
from bench.core.errors import ConfigError, valid_choices
from bench.core.io import write_atomic
from bench.logs import from_arrays, write_dataset

if TYPE_CHECKING:
    from bench.calibrate.arm.model import Payload

MODEL = Path(__file__).resolve().parents[1] / "models" / "arm6.xml"
JOINTS = tuple(f"joint{i}" for i in range(1, 7))
CASES = ("payload", "actuator_gain", "none")
EXCITATIONS = ("fourier", "periodic", "one_path")
COULOMB = np.array([0.3, 0.5, 0.3, 0.1, 0.1, 0.05])
VISCOUS = np.array([0.2, 0.3, 0.2, 0.05, 0.05, 0.02])
OFFSET = np.array([0.1, -0.2, 0.05, 0.0, 0.02, 0.0])
PAYLOAD: Payload = {"mass": 1.2, "com": [0.05, 0.02, 0.03]}  # kg, m in the flange frame
GAIN = {"joint": "joint2", "gain": 0.8}  # the drive delivers this share of the command
NOISE = {"qpos": 2e-4, "qvel": 5e-3, "torque": 0.05}  # rad, rad/s, N·m


def _trajectory(rng: np.random.Generator, t: np.ndarray, lo: np.ndarray, hi: np.ndarray, period: float, one_path: bool):
    """q, dq, ddq of a five-harmonic Fourier series per joint (base period `period`), inside 80% of each range;
    with `one_path`, one series s(t) drives every joint along one random direction of joint space."""
    n = len(lo)
    w0 = 2 * np.pi / period
    k = np.arange(1, 6)
    mid, half = (lo + hi) / 2, 0.8 * (hi - lo) / 2
    q, dq, ddq = (np.zeros((len(t), n)) for _ in range(3))
    if one_path:
        a, b = rng.normal(0, 1, 5) / k, rng.normal(0, 1, 5) / k
        s, c = np.sin(np.outer(t, k * w0)), np.cos(np.outer(t, k * w0))
        raw = s @ a + c @ b
        d = rng.normal(0, 1, n)
        d *= np.min(np.minimum(half, 1.2) / np.abs(d)) / max(np.abs(raw).max(), 1e-9)
        q[:] = mid + np.outer(raw, d)
        dq[:] = np.outer(c @ (a * k * w0) - s @ (b * k * w0), d)
        ddq[:] = np.outer(-(s @ (a * (k * w0) ** 2)) - c @ (b * (k * w0) ** 2), d)
        return q, dq, ddq
    for j in range(n):
        a = rng.normal(0, 1, 5) / k
        b = rng.normal(0, 1, 5) / k
        s = np.sin(np.outer(t, k * w0))
        c = np.cos(np.outer(t, k * w0))
        raw = s @ a + c @ b
        scale = min(half[j], 1.2) / max(np.abs(raw).max(), 1e-9)
        q[:, j] = mid[j] + scale * raw
        dq[:, j] = scale * (c @ (a * k * w0) - s @ (b * k * w0))
        ddq[:, j] = scale * (-(s @ (a * (k * w0) ** 2)) - c @ (b * (k * w0) ** 2))
    return q, dq, ddq


def truth_model(case: str, payload_com: tuple[float, float, float] | None = None) -> mujoco.MjModel:
    """The arm as the logs were made with it (the declared model plus the hidden payload, if any)."""
    m = mujoco.MjModel.from_xml_path(str(MODEL))
    if case == "payload":
        site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "flange")
        body = int(m.site_bodyid[site])
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, m.site_quat[site])
        com = m.site_pos[site] + rot.reshape(3, 3) @ np.array(payload_com or PAYLOAD["com"])
        set_std(m, body, std_params(m, body) + point_mass(PAYLOAD["mass"], com))
        mujoco.mj_setConst(m, mujoco.MjData(m))
    return m


def simulate(
    case: str,
    seed: int = 0,
    duration: float = 20.0,
    excitation: str = "fourier",
    payload_com: tuple[float, float, float] | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, object]]:
    """One episode of logged columns on an irregular clock, and the truth."""
    if case not in CASES:
        raise ConfigError(f"effect={case!r} for the arm6 cases; {valid_choices(case, CASES)}")
    if excitation not in EXCITATIONS:
        raise ConfigError(f"excitation={excitation!r}; {valid_choices(excitation, EXCITATIONS)}")
    rng = np.random.default_rng(seed)
    m = truth_model(case, payload_com)
    d = mujoco.MjData(m)
    dt = 1e-3 * rng.uniform(0.7, 1.3, int(duration * 1000) + 10)
    dt[rng.choice(len(dt), size=max(1, len(dt) // 500), replace=False)] = 3e-3  # the controller missed a beat
    t = np.concatenate([[0.0], np.cumsum(dt)])
    t = t[t <= duration]
    lo, hi = m.jnt_range[:, 0], m.jnt_range[:, 1]
    period = 10.0 if excitation == "periodic" else duration
    q, dq, ddq = _trajectory(rng, t, lo, hi, period, excitation == "one_path")
    tau = np.empty_like(q)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_PASSIVE)
    m.dof_armature[:] = 0.0
    for i in range(len(t)):
        d.qpos[:], d.qvel[:], d.qacc[:] = q[i], dq[i], ddq[i]
        mujoco.mj_inverse(m, d)
        tau[i] = d.qfrc_inverse
    armature = mujoco.MjModel.from_xml_path(str(MODEL)).dof_armature
    if case != "payload":  # a command drives the rotor too; a link-side torque sensor does not see it
        tau += armature * ddq
    tau += COULOMB * np.tanh(dq / 0.02) + VISCOUS * dq
    signal = tau + OFFSET
    truth: dict[str, object] = {
        "case": case,
        "coulomb": COULOMB.tolist(),
        "viscous": VISCOUS.tolist(),
        "offset": OFFSET.tolist(),
        "armature": armature.tolist(),
        "noise": NOISE,
        "excitation": excitation,
        "period_s": period,
    }
    if case == "payload":
        truth["payload"] = {**PAYLOAD, "com": list(payload_com or PAYLOAD["com"])}
    if case in ("actuator_gain", "none"):
        g = np.ones(len(JOINTS))
        if case == "actuator_gain":
            g[JOINTS.index(GAIN["joint"])] = GAIN["gain"]
            truth["actuator_gain"] = GAIN
        signal = tau / g + OFFSET  # the command that made the drives deliver tau
    cols = {
        "observation.state": q + rng.normal(0, NOISE["qpos"], q.shape),
        "observation.velocity": dq + rng.normal(0, NOISE["qvel"], dq.shape),
        "observation.effort": signal + rng.normal(0, NOISE["torque"], signal.shape),
        "timestamp": t.astype(np.float32),
        "time_ns": np.round(t * 1e9).astype(np.int64)[:, None],
    }
    return cols, truth


def spec_dict(case: str, model_file: str = "arm6.xml") -> dict[str, object]:
    """The arm spec of a case (the links are trusted: see the module docstring)."""
    idx = list(range(len(JOINTS)))
    return {
        "method": "idim",
        "model": model_file,
        "joints": list(JOINTS),
        "signals": {
            "qpos": {"column": "observation.state", "index": idx},
            "qvel": {"column": "observation.velocity", "index": idx},
            "torque": {"column": "observation.effort", "index": idx},
        },
        "torque": "measured" if case == "payload" else "command",
        "inertia": "none",
        "payload": "flange",
        "bootstrap": 100,
    }


def write_arm_case(
    out: str | Path,
    case: str,
    *,
    seed: int = 0,
    duration: float = 20.0,
    excitation: str = "fourier",
    payload_com: tuple[float, float, float] | None = None,
) -> Path:
    """OUT/logs (a LeRobot dataset), OUT/arm6.xml (the declared model), OUT/spec.yaml and OUT/truth.json."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cols, truth = simulate(case, seed, duration, excitation, payload_com)
    names = {
        "observation.state": [f"{j}.pos" for j in JOINTS],
        "observation.velocity": [f"{j}.vel" for j in JOINTS],
        "observation.effort": [f"{j}.torque" for j in JOINTS],
    }
    ds = from_arrays([cols], fps=1000.0, task="excitation trajectory", names=names, robot_type="arm6")
    write_dataset(out / "logs", ds)
    (out / "arm6.xml").write_text(MODEL.read_text())
    (out / "spec.yaml").write_text(yaml.safe_dump(spec_dict(case), sort_keys=False))
    write_atomic(out / "truth.json", truth)
    return out

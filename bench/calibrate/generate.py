"""Synthetic logs with one hidden effect, for testing the Real2Sim loop on data whose answer is known.

A three-joint arm (models/arm3.xml) tracks a multisine reference under a PD controller with gravity
compensation from the *declared* model, at the log rate, with noisy position and velocity
sensors: closed loop, so the controller partly hides the effect, as on a real robot. The plant
carries one effect from the library, realised by the library's own code (model fields, the applied
command, generalised forces). What is written: a LeRobot v3 dataset, the declared model (its joint
damping set off from the truth, and without the effect), a spec for it and `truth.json`.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, replace
from pathlib import Path

import mujoco
import numpy as np
import yaml

from bench.calibrate.effects import EFFECTS, Target, deadband, saturate, stribeck_force
from bench.calibrate.model import Edits
from bench.calibrate.play import build
from bench.core.errors import ConfigError, did_you_mean, valid_choices
from bench.logs import from_arrays, write_dataset

MODELS = Path(__file__).resolve().parent / "models"
ARM = MODELS / "arm3.xml"
JOINTS = ("j1", "j2", "j3")
DECLARED_DAMPING = 0.2  # the declared model's joint damping (the truth is 0.4 / 0.3 / 0.15)
KP = np.array([60.0, 40.0, 15.0])
KD = np.array([6.0, 4.0, 1.5])
INPUT_COLUMN = "observation.extra"

# a drive with play (an effect with a `play_side`) is a geared one: its reflected rotor inertia
# (armature, kg·m²) on the driven joint, in the plant and in the declared model (with arm3's 0.01 the PD
# loop, closed on the motor alone while it crosses the gap, would be unstable at 100 Hz)
GEARED_ARMATURE = 0.1
FREE_FIELD = "dof_damping"  # what the generated spec declares free (but where the hidden effect edits it)

# forces no family of the library describes (what the learned residual is for): name -> (joint, doc)
DISTURBANCES = {
    "cogging": ("j2", "cogging torque 0.8 sin(6 q) N·m of a motor with 6 pole pairs per radian on j2"),
}


def _disturbance(name: str | None, model: mujoco.MjModel) -> np.ndarray | None:
    """(dof, amplitude, spatial frequency) of a disturbance, or None."""
    if name is None:
        return None
    if name not in DISTURBANCES:
        raise ConfigError(f"unknown disturbance {name!r}; {valid_choices(name, DISTURBANCES)}")
    dof = int(model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, DISTURBANCES[name][0])])
    return np.array([dof, 0.8, 6.0])


def example(effect: str) -> tuple[str, dict[str, float]]:
    """The hidden effect's default target in arm3.xml and its true physical parameters (the effect's row)."""
    target, params = EFFECTS[effect].example
    if not target:
        raise ConfigError(f"effect {effect!r} declares no example (Effect.example) for the generator to plant")
    return target, params


def _target(model: mujoco.MjModel, kind: str, name: str) -> Target:
    obj = {
        "joint": mujoco.mjtObj.mjOBJ_JOINT,
        "actuator": mujoco.mjtObj.mjOBJ_ACTUATOR,
        "body": mujoco.mjtObj.mjOBJ_BODY,
    }[kind]
    idx = mujoco.mj_name2id(model, obj, name)
    if idx < 0:
        raise ConfigError(f"target {name!r} is not a {kind} of arm3.xml")
    if kind == "joint":
        return Target(kind, name, idx, int(model.jnt_dofadr[idx]), name)
    if kind == "actuator":
        j = int(model.actuator_trnid[idx, 0])
        return Target(kind, name, idx, int(model.jnt_dofadr[j]), model.joint(j).name)
    return Target(kind, name, idx)


def _multisine(rng: np.random.Generator, t: np.ndarray, amp: float, n: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Sum of n sines (0.1-1.2 Hz, random phases) scaled to peak `amp`, faded in over 1 s; and its derivative."""
    f = rng.uniform(0.1, 1.2, n)
    ph = rng.uniform(0, 2 * np.pi, n)
    a = rng.uniform(0.5, 1.0, n)
    w = 2 * np.pi * f
    s = (a[:, None] * np.sin(w[:, None] * t + ph[:, None])).sum(0)
    ds = (a[:, None] * w[:, None] * np.cos(w[:, None] * t + ph[:, None])).sum(0)
    s0 = s[0]
    fade = np.clip(t / 1.0, 0, 1)
    fade = 0.5 - 0.5 * np.cos(np.pi * fade)
    dfade = np.where(t < 1.0, 0.5 * np.pi * np.sin(np.pi * np.clip(t, 0, 1)), 0.0)
    scale = amp / max(np.abs(s - s0).max(), 1e-9)
    return scale * fade * (s - s0), scale * (fade * ds + dfade * (s - s0))


@dataclass(frozen=True)
class Truth:
    """The hidden effect of a generated data set."""

    effect: str | None
    target: str | None
    joint: str | None
    params: dict[str, float]
    disturbance: str | None = None  # a force outside the effect library (`DISTURBANCES`)

    def to_json(self) -> dict:
        return {
            "effect": self.effect,
            "target": self.target,
            "joint": self.joint,
            "params": self.params,
            **({"disturbance": self.disturbance} if self.disturbance else {}),
        }


def simulate_arm(
    effect: str | None,
    *,
    episodes: int = 8,
    duration: float = 6.0,
    fps: float = 100.0,
    substeps: int = 5,
    seed: int = 0,
    target: str | None = None,
    params: dict[str, float] | None = None,
    noise: tuple[float, float] = (5e-4, 1e-2),
    disturbance: str | None = None,
) -> tuple[list[dict[str, np.ndarray]], Truth]:
    """Closed-loop episodes of the arm with one hidden effect (None: the plain arm) as column arrays.

    `disturbance` adds a force outside the effect library (`DISTURBANCES`) on top.
    """
    if effect is not None and effect not in EFFECTS:
        raise ConfigError(
            f"unknown effect {effect!r}; valid: none, {', '.join(EFFECTS)}.{did_you_mean(effect, EFFECTS)}"
        )
    rng = np.random.default_rng(seed)
    xml = arm_xml(effect, target)
    true = mujoco.MjModel.from_xml_string(xml)
    true.opt.timestep = 1.0 / (fps * substeps)
    declared = mujoco.MjModel.from_xml_string(xml)  # the controller's model (gravity is what it needs)
    b = Edits(true, 1)
    truth = Truth(None, None, None, {})
    if effect is not None:
        eff = EFFECTS[effect]
        name, default = example(effect)
        name = target or name
        p = {**default, **(params or {})}
        tgt = _target(true, eff.kind, name)
        if eff.reads_input:  # the generator logs one extra input column
            tgt = Target(tgt.kind, tgt.name, tgt.index, tgt.dof, tgt.joint, 0, f"{INPUT_COLUMN}[0]")
        if eff.play_side is not None:  # the plant rebuilt with a rotor behind the play
            pm = build(xml, ((tgt.index, eff.play_side),), true)
            b = Edits(pm.model, 1, pm)
            b.set_play(tgt.index, p["play"], 0.0)
        elif eff.plant is not None:
            eff.plant(b, tgt, p, true)
        else:
            eff.apply(b, tgt, np.array([p[k] for k in eff.params], dtype=float), None)  # type: ignore[arg-type]
        truth = Truth(effect, tgt.label, tgt.joint or None, p)
    b.finish_model()
    dist = _disturbance(disturbance, true)
    truth = replace(truth, disturbance=disturbance)
    t = np.arange(int(round(duration * fps))) / fps
    out = []
    for _ in range(episodes):
        out.append(_episode(b.model, declared, b, t, fps, substeps, rng, noise, dist))
    return out, truth


def _episode(
    true: mujoco.MjModel,
    declared: mujoco.MjModel,
    b: Edits,
    t: np.ndarray,
    fps: float,
    substeps: int,
    rng: np.random.Generator,
    noise: tuple[float, float],
    dist: np.ndarray | None,
) -> dict[str, np.ndarray]:
    nT, nu, nv = len(t), declared.nu, declared.nv
    amps = (0.6, 0.8, 1.0)
    ref = np.empty((nT, nv))
    dref = np.empty((nT, nv))
    for j in range(nv):
        ref[:, j], dref[:, j] = _multisine(rng, t, amps[j])
    extra, _ = _multisine(rng, t, 1.0, n=3)  # a measured external load (cable, hose) in arbitrary units
    gain = np.zeros(true.nv) if b.input_gain is None else b.input_gain[0]  # the extra load's gain per dof
    coords = b.coordinates(nv, 0)  # the logged coordinates (a rebuilt plant with play has more)
    qadr = np.arange(nv) if coords is None else coords.qpos_adr
    vadr = np.arange(nv) if coords is None else coords.dof_adr
    d = mujoco.MjData(true)
    dc = mujoco.MjData(declared)
    delay = {a: v * fps * substeps for k, a, v in b.ops if k == "delay"}
    hist = np.zeros((nT * substeps, nu))
    obs = np.empty((nT, 2 * nv), dtype=np.float32)
    act = np.empty((nT, nu), dtype=np.float32)
    for k in range(nT):
        q = d.qpos[qadr] + rng.normal(0, noise[0], nv)
        v = d.qvel[vadr] + rng.normal(0, noise[1], nv)
        dc.qpos[:] = q
        dc.qvel[:] = 0.0
        mujoco.mj_forward(declared, dc)
        u = KP * (ref[k] - q) + KD * (dref[k] - v) + dc.qfrc_bias
        obs[k, :nv], obs[k, nv:] = q, v
        act[k] = u
        u = act[k].astype(np.float64)  # the plant gets exactly what is logged
        hist[k * substeps : (k + 1) * substeps] = u
        for s in range(substeps):
            n = k * substeps + s
            applied = hist[n].copy()
            for a, shift in delay.items():
                x = n - shift
                i0 = int(np.floor(x))
                w = x - i0
                lo, hi = min(max(i0, 0), n), min(max(i0 + 1, 0), n)
                applied[a] = (1 - w) * hist[lo, a] + w * hist[hi, a]
            for kind, a, value in b.ops:
                if kind == "deadband":
                    applied[a] = deadband(applied[a], value)
                elif kind == "saturation":
                    applied[a] = saturate(applied[a], value)
            d.ctrl[:] = applied
            d.qfrc_applied[:] = b.qfrc + gain * extra[k] + stribeck_force(d.qvel, b.fs, b.vs)
            if dist is not None:
                dof = int(dist[0])
                d.qfrc_applied[dof] += dist[1] * np.sin(dist[2] * d.qpos[dof])
            mujoco.mj_step(true, d)
    extra_meas = (extra + rng.normal(0, 0.01, nT)).astype(np.float32)[:, None]
    return {"observation.state": obs, "action": act, INPUT_COLUMN: extra_meas, "timestamp": t.astype(np.float32)}


def arm_xml(effect: str | None, target: str | None = None) -> str:
    """arm3.xml as the plant of a case is built (geared drive where the hidden effect is play)."""
    text = ARM.read_text()
    if effect is not None and EFFECTS[effect].play_side is not None:
        act = target or example(effect)[0]
        motor = re.search(rf'<motor name="{act}" joint="(\w+)"', text)
        assert motor is not None, f"arm3.xml has no motor {act}"
        joint = motor.group(1)
        text = re.sub(rf'(<joint name="{joint}"[^/]*)/>', rf'\1 armature="{GEARED_ARMATURE}"/>', text)
    return text


def declared_xml(damping: float = DECLARED_DAMPING, text: str | None = None) -> str:
    """The declared model: arm3.xml (or `text`) with every joint's damping set to the declared guess."""
    text = ARM.read_text() if text is None else text
    return re.sub(r'(<joint name="j\d")( damping="[0-9.]+")', rf'\1 damping="{damping}"', text)


def spec_dict(effect: str | None, target: str | None = None, model_file: str = "arm3_declared.xml") -> dict:
    """The spec that goes with the declared model: joint damping free (except where the effect is damping)."""
    damped = list(JOINTS)
    if effect is not None and FREE_FIELD in EFFECTS[effect].fields:
        damped.remove(target or example(effect)[0])
    return {
        "model": model_file,
        "substeps": 5,
        "signals": {
            "qpos": {"column": "observation.state", "index": [0, 1, 2]},
            "qvel": {"column": "observation.state", "index": [3, 4, 5]},
            "ctrl": {"column": "action", "index": [0, 1, 2]},
            "inputs": {"column": INPUT_COLUMN, "index": [0]},
        },
        "params": [{"name": "damping", "field": "dof_damping", "elements": damped, "bounds": [0.0, 3.0]}],
        "effects": "all",
        "holdout": 0.3,
        "horizon": 0.2,
    }


def declared_files(out: str | Path, effect: str | None, target: str | None = None) -> Path:
    """Write the declared model and its spec into `out`; returns the spec path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    xml = declared_xml(text=arm_xml(effect, target))
    if effect is not None and FREE_FIELD in EFFECTS[effect].fields:  # not declared free: keeps its true value
        joint = target or example(effect)[0]
        found = re.search(rf'<joint name="{joint}" damping="([0-9.]+)"', ARM.read_text())
        assert found is not None, f"arm3.xml declares no damping of joint {joint}"
        true = found.group(1)
        xml = re.sub(rf'(<joint name="{joint}") damping="[0-9.]+"', rf'\1 damping="{true}"', xml)
    (out / "arm3_declared.xml").write_text(xml)
    path = out / "spec.yaml"
    path.write_text(yaml.safe_dump(spec_dict(effect, target), sort_keys=False, default_flow_style=None))
    return path


def write_case(out: str | Path, effect: str | None, **kw) -> Path:
    """Write logs (LeRobot v3), declared model, spec and truth for one hidden effect into `out`."""
    out = Path(out)
    fps = kw.get("fps", 100.0)
    episodes, truth = simulate_arm(effect, **kw)
    ds = from_arrays(
        episodes,
        fps=fps,
        task="track a multisine reference",
        robot_type="arm3",
        names={
            "observation.state": [f"{j}.pos" for j in JOINTS] + [f"{j}.vel" for j in JOINTS],
            "action": [f"{j}.torque" for j in JOINTS],
            INPUT_COLUMN: ["load"],
        },
        meta=[{"generator": "bench.calibrate.generate", "truth": truth.to_json()}] * len(episodes),
    )
    declared_files(out, effect, kw.get("target"))
    write_dataset(out / "logs", ds, overwrite=True)
    (out / "truth.json").write_text(json.dumps(truth.to_json(), indent=2) + "\n")
    return out

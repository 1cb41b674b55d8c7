"""Backlash as position play: a motor behind a dead zone in position, built into the MJCF model.

A drive with play is two bodies, not one: the motor (its rotor inertia) and the link, coupled only
when their positions differ by half the play. MuJoCo has no such joint, so the model is rebuilt
(`mujoco.MjSpec`) with, for each actuator with play,

- a *rotor* body on the world with one joint of the drive's kind (hinge or slide) carrying the
  drive's reflected inertia (the link joint's armature, moved off the link);
- the actuator re-targeted at the rotor joint;
- a fixed tendon `rotor - link` whose length limit [-play/2, +play/2] is the dead zone: inside it
  no force passes, at either end a stiff limit constraint transmits the drive force.

New elements are appended, so every body, joint, dof and actuator index of the declared model is
unchanged and the declared parameters and other effects are written where they were; keyframes get
each rotor at its link's position (at rest), sites, tendons and equality constraints are untouched. The log
measures either side (`Side`): the link (an output encoder) or the motor (an encoder on the motor
shaft, as on most geared drives); the other side's position is not logged and starts at the edge
of the play the logged command pushes towards (`coordinates`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from bench.replay.simulate import Coordinates

SIDES = ("link", "motor")
PLAY_TIMECONST = 0.02  # s, time constant of the contact at either end of the play (MuJoCo default for limits)
ROTOR_SHARE = 0.01  # rotor inertia as a share of the dof's inertia when the declared joint has no armature


@dataclass(frozen=True)
class Play:
    """Where the play of one actuator lives in the rebuilt model."""

    actuator: int
    side: str  # which position the log measures: "link" or "motor"
    link_dof: int  # == the link joint's qpos address (hinge and slide joints)
    rotor_dof: int  # == the rotor joint's qpos address
    tendon: int


@dataclass(frozen=True)
class PlayModel:
    """A declared model rebuilt with play on some actuators."""

    model: mujoco.MjModel
    plays: tuple[Play, ...]

    def play(self, actuator: int) -> Play:
        return next(p for p in self.plays if p.actuator == actuator)


def build(source: Path | str, plays: tuple[tuple[int, str], ...], like: mujoco.MjModel) -> PlayModel:
    """The MJCF (a file, or XML text) rebuilt with play on each (actuator index, measured side).

    `like` is the model being calibrated, compiled from the same MJCF: its timestep is kept.
    """
    if isinstance(source, Path):
        spec, base = mujoco.MjSpec.from_file(str(source)), mujoco.MjModel.from_xml_path(str(source))
    else:
        spec, base = mujoco.MjSpec.from_string(source), mujoco.MjModel.from_xml_string(source)
    if (base.nbody, base.njnt, base.nu) != (like.nbody, like.njnt, like.nu):
        raise ValueError("the MJCF does not compile to the model being calibrated")
    for act, _ in plays:
        a = spec.actuators[act]
        link = a.target
        j = mujoco.mj_name2id(base, mujoco.mjtObj.mjOBJ_JOINT, link)
        body = spec.worldbody.add_body(name=f"{a.name or act}_rotor")
        body.mass, body.inertia, body.explicitinertial = 1e-9, [1e-9, 1e-9, 1e-9], True
        body.add_joint(name=f"{a.name or act}_rotor", type=mujoco.mjtJoint(base.jnt_type[j]), axis=[0.0, 0.0, 1.0])
        tendon = spec.add_tendon(name=f"{a.name or act}_play", limited=True, range=[-1.0, 1.0])  # set_play sets it
        tendon.solref_limit = [PLAY_TIMECONST, 1.0]
        tendon.wrap_joint(f"{a.name or act}_rotor", 1.0)
        tendon.wrap_joint(link, -1.0)
        a.target = f"{a.name or act}_rotor"
    # keyframes list every coordinate: each rotor starts where its link is in that keyframe, at rest
    link_qpos = [int(base.jnt_qposadr[int(base.actuator_trnid[a, 0])]) for a, _ in plays]
    for key in spec.keys:
        qpos = np.asarray(key.qpos, dtype=np.float64)
        if qpos.size == base.nq:
            key.qpos = np.concatenate([qpos, qpos[link_qpos]])
        qvel = np.asarray(key.qvel, dtype=np.float64)
        if qvel.size == base.nv:
            key.qvel = np.concatenate([qvel, np.zeros(len(plays))])
    model = spec.compile()
    model.opt.timestep = like.opt.timestep
    out = []
    for i, (act, side) in enumerate(plays):
        j = int(like.actuator_trnid[act, 0])
        rotor = like.njnt + i
        out.append(Play(act, side, int(like.jnt_dofadr[j]), int(model.jnt_dofadr[rotor]), like.ntendon + i))
    return PlayModel(model, tuple(out))


def set_play(model: mujoco.MjModel, p: Play, width: float, inertia: float) -> None:
    """Open the dead zone to `width` and move the drive's inertia from the link joint to the rotor."""
    model.tendon_range[p.tendon] = (-0.5 * width, 0.5 * width)
    rotor = model.dof_armature[p.link_dof] if model.dof_armature[p.link_dof] > 0 else ROTOR_SHARE * inertia
    model.dof_armature[p.rotor_dof] = rotor
    model.dof_armature[p.link_dof] = 0.0


def coordinates(model: mujoco.MjModel, plays: list[tuple[Play, float]], nq: int, warmup: int) -> Coordinates:
    """Logged coordinates in the rebuilt model, and where the unlogged side of each play starts.

    A first guess puts it at the edge of the play the command pushes towards (the motor leads the
    link by +play/2 while it pushes forwards, lags by play/2 while it pulls; both sides at the logged
    velocity); `warmup` frames simulated before each segment then find it (`Coordinates.warmup`).
    """
    qpos_adr = np.arange(nq)
    hidden, follows = [], []
    for p, _ in plays:
        if p.side == "motor":
            qpos_adr[p.link_dof] = p.rotor_dof
        hidden.append(p.link_dof if p.side == "motor" else p.rotor_dof)
        follows.append(p.link_dof)
    sign = np.sign(model.actuator_gear[:, 0] * model.actuator_gainprm[:, 0])

    def init(frames: np.ndarray, qpos: np.ndarray, qvel: np.ndarray, ctrl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(qpos)
        full_q, full_v = np.zeros((n, model.nq)), np.zeros((n, model.nv))
        full_q[:, :nq], full_v[:, :nq] = qpos, qvel
        for p, width in plays:
            lead = 0.5 * width * np.sign(ctrl[:, p.actuator] * sign[p.actuator])  # rotor - link
            logged = qpos[:, p.link_dof]
            if p.side == "link":
                full_q[:, p.rotor_dof] = logged + lead
            else:
                full_q[:, p.rotor_dof] = logged
                full_q[:, p.link_dof] = logged - lead
            full_v[:, p.rotor_dof] = qvel[:, p.link_dof]
        return full_q, full_v

    return Coordinates(qpos_adr, qpos_adr.copy(), init, np.array(hidden), np.array(follows), warmup)

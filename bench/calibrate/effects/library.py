"""The library: every effect family's row (`EFFECTS`), with its bounds scaled to the system and its
realisation in MuJoCo, and the pairs of families that together are exactly a third (`MERGES`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from bench.calibrate.effects.row import Builder, Effect, Scales, Target

if TYPE_CHECKING:
    import mujoco

# --- bounds and realisations ---------------------------------------------------------------------


def _f(s: Scales, t: Target) -> float:
    return float(s.force[t.dof])


def _apply_coulomb(b: Builder, t: Target, x: np.ndarray, s: Scales) -> None:
    b.model.dof_frictionloss[t.dof] += x[0]


def _apply_asymmetric(b: Builder, t: Target, x: np.ndarray, s: Scales) -> None:
    # friction -F+ when moving forward, +F- backward = symmetric (F+ + F-)/2 plus a constant offset;
    # at rest the friction loss holds any force in [-F-, F+], exactly as the asymmetric law says.
    b.model.dof_frictionloss[t.dof] += 0.5 * (x[0] + x[1])
    b.add_qfrc(t.dof, -0.5 * (x[0] - x[1]))


def _apply_stribeck(b: Builder, t: Target, x: np.ndarray, s: Scales) -> None:
    b.model.dof_frictionloss[t.dof] += x[0] + x[1]
    b.add_stribeck(t.dof, x[1], x[2])


def _apply_viscous(b: Builder, t: Target, x: np.ndarray, s: Scales) -> None:
    b.model.dof_damping[t.dof] += x[0]


def _apply_armature(b: Builder, t: Target, x: np.ndarray, s: Scales) -> None:
    b.model.dof_armature[t.dof] += x[0]
    b.mark_setconst()


def _apply_spring(b: Builder, t: Target, x: np.ndarray, s: Scales) -> None:
    # -k (q - q_ref) = -k (q - q_model) + k (q_ref - q_model): a spring towards the model's reference
    # pose plus a constant preload p; linear in (k, p), so its signature is exact; q_ref = q_model + p / k
    b.model.jnt_stiffness[t.index] += x[0]
    b.add_qfrc(t.dof, x[1])


def _report_spring(x: np.ndarray, s: Scales, t: Target) -> dict[str, float]:
    k, p = float(x[0]), float(x[1])
    return {"stiffness": k, "reference": float(s.spring_ref[t.dof]) + p / k if k > 0 else float("nan")}


def _intervals_spring(x: np.ndarray, cov: np.ndarray, s: Scales, t: Target) -> dict[str, list | None]:
    k, p = float(x[0]), float(x[1])
    sd_k = float(np.sqrt(max(cov[0, 0], 0.0)))
    out: dict[str, list | None] = {"stiffness": [k - 1.96 * sd_k, k + 1.96 * sd_k], "reference": None}
    if k > 0:  # delta method: d(p/k) = [-p/k^2, 1/k]
        g = np.array([-p / k**2, 1.0 / k])
        sd = float(np.sqrt(max(g @ cov @ g, 0.0)))
        r = float(s.spring_ref[t.dof]) + p / k
        out["reference"] = [r - 1.96 * sd, r + 1.96 * sd]
    return out


def _apply_payload(b: Builder, t: Target, x: np.ndarray, s: Scales) -> None:
    # a point mass at the body's centre of mass: mass grows, inertia about the COM does not
    b.model.body_mass[t.index] += x[0]
    b.mark_setconst()


def _apply_gain(b: Builder, t: Target, x: np.ndarray, s: Scales) -> None:
    b.model.actuator_gainprm[t.index, 0] *= 1.0 + x[0]


def _apply_bias(b: Builder, t: Target, x: np.ndarray, s: Scales) -> None:
    b.add_qfrc(t.dof, x[0])


def _apply_input(b: Builder, t: Target, x: np.ndarray, s: Scales) -> None:
    b.add_input(t.input, t.dof, x[0])


def _apply_play(b: Builder, t: Target, x: np.ndarray, s: Scales) -> None:
    b.set_play(t.index, float(x[0]), float(s.inertia[t.dof]))


def _apply_delay(b: Builder, t: Target, x: np.ndarray, s: Scales) -> None:
    b.ctrl_op("delay", t.index, x[0])


def _apply_deadband(b: Builder, t: Target, x: np.ndarray, s: Scales) -> None:
    b.ctrl_op("deadband", t.index, x[0] / s.ctrl_gain[t.index])


def saturation_limit(share: float, s: Scales, act: int) -> float:
    """Command limit that clips `share` of the logged commands (a quantile of |command|; share 0 = max)."""
    u = s.ctrl_sorted[act]
    return float(np.interp(1.0 - share, np.linspace(0.0, 1.0, len(u)), u))


def _apply_saturation(b: Builder, t: Target, x: np.ndarray, s: Scales) -> None:
    b.ctrl_op("saturation", t.index, saturation_limit(float(x[0]), s, t.index))


def _report_saturation(x: np.ndarray, s: Scales, t: Target) -> dict[str, float]:
    return {
        "limit": saturation_limit(float(x[0]), s, t.index) * float(s.ctrl_gain[t.index]),
        "clipped_share": float(x[0]),
    }


def _input_gain_max(s: Scales, t: Target) -> float:
    return _f(s, t) / max(float(s.input_max[t.input]), 1e-12)


PLAY_SCAN = (0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.55)


def _plant_command(kind: str, param: str) -> Callable[[Builder, Target, dict[str, float], mujoco.MjModel], None]:
    """Plant a command transform (`kind`: saturation, deadband) whose parameter `param` is a drive force: in
    command units, divided by the actuator's gear."""

    def plant(b: Builder, t: Target, p: dict[str, float], model: mujoco.MjModel) -> None:
        b.ctrl_op(kind, t.index, p[param] / float(model.actuator_gear[t.index, 0]))

    return plant


def _plant_spring(b: Builder, t: Target, p: dict[str, float], model: mujoco.MjModel) -> None:
    # the preload that puts the rest position at `reference`
    k = p["stiffness"]
    _apply_spring(b, t, np.array([k, k * (p["reference"] - float(model.qpos_spring[t.dof]))]), None)  # type: ignore[arg-type]


FRICTION = ("a friction", None)


def _backlash(side: str, doc: str) -> Effect:
    """Backlash as position play of up to 0.2 of the joint's half range, as the log measures it on `side`.

    The two sides are one family each (`backlash_link`, `backlash_motor`) of one group: a target
    takes at most one of them."""
    return Effect(
        f"backlash_{side}",
        "actuator",
        ("play",),
        ("rad|m",),
        lambda s, t: [(0.0, 0.2 * float(s.half_range[t.dof]))],
        _apply_play,
        doc,
        threshold=True,
        group="play",
        play_side=side,
        fd_step=0.02,
        scan=PLAY_SCAN,
        limits={"play": ("a play width", None)},
        example=("m2", {"play": 0.05}),
    )


EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in [
        Effect(
            "coulomb_friction",
            "joint",
            ("friction",),
            ("N·m|N",),
            lambda s, t: [(0.0, 0.5 * _f(s, t))],
            _apply_coulomb,
            "dry friction of constant magnitude opposing motion (MuJoCo friction loss)",
            fields=("dof_frictionloss",),
            limits={"friction": FRICTION},
            example=("j2", {"friction": 0.6}),
        ),
        Effect(
            "asymmetric_friction",
            "joint",
            ("friction_pos", "friction_neg"),
            ("N·m|N", "N·m|N"),
            lambda s, t: [(0.0, 0.5 * _f(s, t))] * 2,
            _apply_asymmetric,
            "dry friction whose magnitude depends on the direction of motion",
            fields=("dof_frictionloss",),
            extends={"coulomb_friction": lambda x, b: np.array([x[0], x[0]])},
            contrast=(1.0, -1.0),
            limits={"friction_pos": FRICTION, "friction_neg": FRICTION},
            example=("j2", {"friction_pos": 0.9, "friction_neg": 0.3}),
        ),
        Effect(
            "stribeck_friction",
            "joint",
            ("friction", "static_excess", "stribeck_velocity"),
            ("N·m|N", "N·m|N", "rad/s|m/s"),
            lambda s, t: [
                (0.0, 0.5 * _f(s, t)),
                (0.0, 0.5 * _f(s, t)),
                (0.01 * float(s.vel[t.dof]), 1.0 * float(s.vel[t.dof])),
            ],
            _apply_stribeck,
            "dry friction that is higher at rest and falls to its kinetic level above the Stribeck velocity",
            fields=("dof_frictionloss",),
            shape=(0.15,),
            extends={"coulomb_friction": lambda x, b: np.array([x[0], 0.0, b[2][0] + 0.15 * (b[2][1] - b[2][0])])},
            contrast=(0.0, 1.0, 0.0),
            limits={
                "friction": FRICTION,
                "static_excess": ("a static friction excess", None),
                "stribeck_velocity": ("a Stribeck velocity", None),
            },
            example=("j2", {"friction": 0.3, "static_excess": 0.5, "stribeck_velocity": 0.3}),
        ),
        Effect(
            "viscous_damping",
            "joint",
            ("damping",),
            ("N·m·s/rad|N·s/m",),
            lambda s, t: [(0.0, _f(s, t) / max(float(s.vel[t.dof]), 1e-9))],
            _apply_viscous,
            "force proportional to velocity (MuJoCo dof damping)",
            fields=("dof_damping",),
            limits={"damping": ("a damping", None)},
            example=("j2", {"damping": 1.2}),
        ),
        Effect(
            "armature",
            "joint",
            ("armature",),
            ("kg·m²|kg",),
            lambda s, t: [(0.0, 2.0 * float(s.inertia[t.dof]))],
            _apply_armature,
            "reflected rotor inertia added to the joint (MuJoCo armature)",
            fields=("dof_armature",),
            limits={"armature": ("an armature", None)},
            example=("j2", {"armature": 0.15}),
        ),
        Effect(
            "actuator_delay",
            "actuator",
            ("delay",),
            ("s",),
            lambda s, t: [(0.0, max(0.1, 10 * s.dt))],
            _apply_delay,
            "transport delay between the logged command and the force applied",
            limits={"delay": ("a delay", None)},
            example=("m2", {"delay": 0.015}),  # 20 ms and more make this PD loop unstable
        ),
        Effect(
            "torque_saturation",
            "actuator",
            ("clipped_share",),
            ("1",),
            lambda s, t: [(0.0, 0.9)],
            _apply_saturation,
            "drive force clipped at a limit (parameter: the share of logged commands above it; 0 = no clipping)",
            report=_report_saturation,
            threshold=True,
            limits={"clipped_share": ("a share of commands", 1.0)},
            example=("m2", {"limit": 5.0}),
            plant=_plant_command("saturation", "limit"),
        ),
        Effect(
            "deadband",
            "actuator",
            ("deadband",),
            ("N·m|N",),
            lambda s, t: [(0.0, 0.25 * _f(s, t))],
            _apply_deadband,
            "dead band on the drive force: small commands are lost (stiction in the drive, an amplifier's dead zone)",
            threshold=True,
            limits={"deadband": ("a dead band", None)},
            example=("m2", {"deadband": 0.6}),
            plant=_plant_command("deadband", "deadband"),
        ),
        _backlash(
            "link",
            "position play between motor and link (total width), measured on the link side: the rotor "
            "crosses the gap unseen, then the link is driven",
        ),
        _backlash(
            "motor",
            "position play between motor and link (total width), measured on the motor side: the motor "
            "crosses the gap fast and free, the link lags",
        ),
        Effect(
            "payload_mass",
            "body",
            ("mass",),
            ("kg",),
            lambda s, t: [(0.0, max(s.mass, 1e-3))],
            _apply_payload,
            "extra point mass at the body's centre of mass",
            fields=("body_mass",),
            limits={"mass": ("a mass", None)},
            example=("link3", {"mass": 0.6}),
        ),
        Effect(
            "joint_spring",
            "joint",
            ("stiffness", "preload"),
            ("N·m/rad|N/m", "N·m|N"),
            lambda s, t: [(0.0, _f(s, t) / max(float(s.half_range[t.dof]), 1e-6)), (-0.5 * _f(s, t), 0.5 * _f(s, t))],
            _apply_spring,
            "spring with its own rest position (cables, hoses, gravity compensators); reported as stiffness and "
            "reference (rest position)",
            fields=("jnt_stiffness",),
            report=_report_spring,
            intervals=_intervals_spring,
            gate=(0,),
            standalone=True,
            extends={"bias": lambda x, b: np.array([0.0, x[0]])},
            contrast=(1.0, 0.0),
            limits={"stiffness": ("a stiffness", None)},
            example=("j2", {"stiffness": 4.0, "reference": 0.4}),
            plant=_plant_spring,
        ),
        Effect(
            "actuator_gain",
            "actuator",
            ("gain_error",),
            ("1",),
            lambda s, t: [(-0.5, 0.5)],
            _apply_gain,
            "relative error of the drive gain (force = (1 + e) x nominal)",
            fields=("actuator_gainprm",),
            example=("m2", {"gain_error": -0.25}),
        ),
        Effect(
            "bias",
            "joint",
            ("force",),
            ("N·m|N",),
            lambda s, t: [(-0.5 * _f(s, t), 0.5 * _f(s, t))],
            _apply_bias,
            "constant generalised force (offset of the drive or of the force measurement)",
            example=("j2", {"force": 0.8}),
        ),
        Effect(
            "input_channel",
            "joint",
            ("gain",),
            ("(N·m|N) per input unit",),
            lambda s, t: [(-_input_gain_max(s, t), _input_gain_max(s, t))],
            _apply_input,
            "a known extra logged signal acting on the joint with an unknown gain",
            example=("j2", {"gain": 1.5}),
            reads_input=True,
        ),
    ]
}

# two families on one target that together are exactly a third: (a, b) -> (merged, lift of a's and b's params)
MERGES: dict[tuple[str, str], tuple[str, Callable[[np.ndarray, np.ndarray], np.ndarray]]] = {
    # friction F plus a constant force b: -(F - b) forwards, +(F + b) backwards: F+ = F - b, F- = F + b
    ("coulomb_friction", "bias"): ("asymmetric_friction", lambda f, b: np.array([f[0] - b[0], f[0] + b[0]])),
}

"""Spec of a real arm's calibration by inverse dynamics (`method: idim`): model, joints, signals, what is fitted.

    method: idim                                  # the measured joint torque is the signal
    model: {suite: held_out_robots, robot: Panda} # the suite's own scene for that robot, or an MJCF path
    joints: [joint1, ..., joint7]                 # model joints in the log's column order (a unique suffix will do)
    signals:
      qpos: {column: observation.state, index: [0, ..., 6]}
      qvel: {column: observation.velocity, index: [0, ..., 6]}   # optional: derived from qpos when absent
      torque: {column: observation.effort, index: [0, ..., 6]}
    torque: measured      # measured (torque sensors) | command (desired torque) | current (motor current)

The rest has defaults (docs/calibration.md, "Real arms"). Every problem is a one-line `SpecError`
naming the field; names are checked against the model in `bench.calibrate.arm.loop`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from bench.calibrate.feedback import gains
from bench.calibrate.spec import HOLDOUT_AT, TraceSpec, parse_holdout, parse_trace
from bench.core.errors import SpecError, valid_choices
from bench.core.provenance import portable
from bench.replay.spec import SignalSpec, check_keys, number, parse_signal, read_spec_file

ARM_KEYS = (
    "method",
    "model",
    "joints",
    "signals",
    "torque",
    "rate",
    "filter_hz",
    "friction",
    "armature",
    "inertia",
    "payload",
    "effects",
    "holdout",
    "holdout_at",
    "period",
    "horizon",
    "horizons",
    "loop_gain",
    "estimate",
    "didim",
    "payload_region",
    "bootstrap",
    "controller",
    "gains",
    "trace",
)
SIGNALS = ("qpos", "qvel", "torque")
TORQUE_KINDS = ("measured", "command", "current")
FRICTION = ("coulomb", "viscous", "offset")
ARM_EFFECTS = ("payload", "actuator_gain", "stribeck_friction", "asymmetric_friction", "joint_spring")
ESTIMATES = ("auto", "idim", "didim")
PAYLOAD_RADIUS = 0.15  # m: by default a payload's centre of mass lies within this distance of its frame's origin


@dataclass(frozen=True)
class ArmSpec:
    """A parsed arm spec (paths resolved against the spec file)."""

    model: Path | None  # an MJCF file, or None with `suite`
    suite: str | None
    robot: str | None
    joints: tuple[str, ...]
    signals: dict[str, SignalSpec]
    torque: str = "measured"
    rate: float = 200.0  # Hz at which inverse dynamics is evaluated, after filtering
    filter_hz: float = 20.0  # zero-phase Butterworth cut-off on positions, velocities and torques
    friction: tuple[str, ...] = FRICTION
    armature: bool = False  # default: true for command and current signals (the rotor is behind a link-side sensor)
    inertia: tuple[str, ...] | None = None  # None: every link moved by the joints; () none
    payload: str | None = None  # body or site of the flange / tool frame (default: the last link's last fixed body)
    effects: tuple[str, ...] = ARM_EFFECTS
    holdout: float = 0.3  # share of the log held out
    holdout_window: tuple[float, float] | None = None  # or these seconds of a one-episode log
    holdout_at: str = "least_repeated"  # where the share sits (bench.calibrate.novelty)
    period: float | None = None  # seconds: the excitation's period, when known (else detected)
    horizons: tuple[float, ...] = (0.05, 0.2, 1.0)  # seconds of the forward check's k-step horizons
    loop_gain: float = 20.0  # stiffness of the forward check's virtual loop, in torque spreads per position spread
    estimate: str = "auto"  # which estimate runs carry: auto (the one the held-out simulation supports) | idim | didim
    didim: int = 3  # refinement iterations of the forward (DIDIM) estimate; 0: none
    payload_region: tuple[tuple[float, float, float], float] = ((0.0, 0.0, 0.0), PAYLOAD_RADIUS)  # centre, radius
    bootstrap: int = 200
    controller: tuple[tuple[float, ...], tuple[float, ...]] | None = None  # (kp, kd) per joint: the log's loop
    gains: tuple[float, ...] | None = None  # torque per unit of a `current` signal (torque constant x gear)
    trace: TraceSpec = field(default_factory=TraceSpec)
    source: Path | None = None

    def to_json(self) -> dict[str, object]:
        """JSON-able form, embedded in calibration.json."""
        return {
            "method": "idim",
            "model": str(self.model) if self.model else {"suite": self.suite, "robot": self.robot},
            "joints": list(self.joints),
            "signals": {k: {"column": s.column, "index": list(s.index)} for k, s in self.signals.items()},
            "torque": self.torque,
            "rate": self.rate,
            "filter_hz": self.filter_hz,
            "friction": list(self.friction),
            "armature": self.armature,
            "inertia": "all" if self.inertia is None else list(self.inertia),
            "payload": self.payload,
            "effects": list(self.effects),
            "holdout": list(self.holdout_window) if self.holdout_window else self.holdout,
            "holdout_at": "window" if self.holdout_window else self.holdout_at,
            "period": self.period,
            "horizons": list(self.horizons),
            "loop_gain": self.loop_gain,
            "estimate": self.estimate,
            "didim": self.didim,
            "payload_region": {"center": list(self.payload_region[0]), "radius": self.payload_region[1]},
            "bootstrap": self.bootstrap,
            "controller": None
            if self.controller is None
            else {"kp": list(self.controller[0]), "kd": list(self.controller[1])},
            "gains": list(self.gains) if self.gains else None,
            "trace": dict(self.trace.__dict__),
            "source": portable(self.source),  # relative to the checkout when inside it
        }


def is_arm_spec(raw: object) -> bool:
    """A spec mapping that asks for inverse-dynamics identification."""
    return isinstance(raw, dict) and raw.get("method") == "idim"


def load_arm_spec(path: str | Path) -> ArmSpec:
    """Read and parse an arm spec file."""
    raw, p = read_spec_file(path)
    return parse_arm_spec(raw, base_dir=p.parent, source=p)


def _names(value: object, where: str, valid: tuple[str, ...] | None = None) -> tuple[str, ...]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) and v for v in value):
        raise SpecError(f"spec field {where!r} must be a list of names; got {value!r}")
    if valid is not None:
        for v in value:
            if v not in valid:
                raise SpecError(f"spec field {where!r}: unknown {v!r}; {valid_choices(v, valid)}")
    if len(set(value)) != len(value):
        raise SpecError(f"spec field {where!r} names {next(v for v in value if value.count(v) > 1)!r} twice")
    return tuple(value)


def _choice_list(raw: object, where: str, valid: tuple[str, ...]) -> tuple[str, ...]:
    if raw == "all":
        return valid
    if raw in ("none", None) or raw == []:
        return ()
    return _names(raw, where, valid)


def _model(raw: object, base_dir: Path) -> tuple[Path | None, str | None, str | None]:
    if isinstance(raw, dict):
        check_keys(raw, ("suite", "robot"), "model")
        suite, robot = raw.get("suite"), raw.get("robot")
        if not isinstance(suite, str) or not suite or not isinstance(robot, str) or not robot:
            raise SpecError("spec field 'model' must be an MJCF path or {suite: NAME, robot: NAME}")
        return None, suite, robot
    if not isinstance(raw, str) or not raw:
        raise SpecError(f"spec field 'model' must be an MJCF path or {{suite: NAME, robot: NAME}}; got {raw!r}")
    path = (base_dir / raw).resolve()
    if not path.is_file():
        raise SpecError(f"spec field 'model': MJCF file {str(path)!r} does not exist")
    return path, None, None


def _controller(raw: object, n: int) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    if raw is None:
        return None
    kp, kd = gains(raw)
    if len(kp) != n:
        raise SpecError(f"spec field 'controller.kp' must list one gain per joint ({n}); got {len(kp)}")
    return kp, kd


def _horizons(raw: Mapping[str, object]) -> tuple[float, ...]:
    if "horizon" in raw and "horizons" in raw:
        raise SpecError("spec fields 'horizon' and 'horizons' both given; 'horizons' lists every one")
    if "horizon" in raw:
        return (number(raw["horizon"], "horizon", lo=1e-3, hi=3600.0),)
    v = raw.get("horizons", [0.05, 0.2, 1.0])
    if not isinstance(v, (list, tuple)) or not v or len(v) > 6:
        raise SpecError(f"spec field 'horizons' must list 1 to 6 durations in seconds; got {v!r}")
    return tuple(sorted(number(x, "horizons", lo=1e-3, hi=3600.0) for x in v))


def _region(raw: object) -> tuple[tuple[float, float, float], float]:
    if raw is None:
        return (0.0, 0.0, 0.0), PAYLOAD_RADIUS
    raw = check_keys(raw, ("center", "radius"), "payload_region")
    c = raw.get("center", [0.0, 0.0, 0.0])
    if not isinstance(c, (list, tuple)) or len(c) != 3:
        raise SpecError(f"spec field 'payload_region.center' must be [x, y, z] in metres (payload frame); got {c!r}")
    r = raw.get("radius", PAYLOAD_RADIUS)
    if not isinstance(r, (int, float)) or isinstance(r, bool) or r <= 0:
        raise SpecError(
            f"spec field 'payload_region.radius' must be a positive distance in metres; got {r!r} (the region is empty)"
        )
    return (float(c[0]), float(c[1]), float(c[2])), number(r, "payload_region.radius", lo=1e-6, hi=100.0)


def parse_arm_spec(raw: object, base_dir: str | Path = ".", source: Path | None = None) -> ArmSpec:
    """Check a raw arm spec mapping and build an ArmSpec (one SpecError naming the field otherwise)."""
    raw = check_keys(raw, ARM_KEYS, "")
    if raw.get("method") != "idim":
        raise SpecError(f"spec field 'method' must be idim for an arm spec; got {raw.get('method')!r}")
    model, suite, robot = _model(raw.get("model"), Path(base_dir))
    joints = _names(raw.get("joints"), "joints")
    sig_raw = check_keys(raw.get("signals"), SIGNALS, "signals")
    for required in ("qpos", "torque"):
        if required not in sig_raw:
            raise SpecError(f"spec field 'signals.{required}' is required (column and index of the logged {required})")
    signals = {k: parse_signal(v, f"signals.{k}") for k, v in sig_raw.items()}
    for k, s in signals.items():
        if len(s.index) != len(joints):
            raise SpecError(
                f"spec field 'signals.{k}.index' names {len(s.index)} columns; 'joints' names {len(joints)} "
                "(one column per joint, in the same order)"
            )
    kind = raw.get("torque", "measured")
    if kind not in TORQUE_KINDS:
        raise SpecError(f"spec field 'torque': {kind!r}; {valid_choices(str(kind), TORQUE_KINDS)}")
    gains = None
    if kind == "current":
        g = raw.get("gains")
        if not isinstance(g, (list, tuple)) or len(g) != len(joints):
            raise SpecError(
                f"spec field 'gains' must list, per joint, the torque per unit of current (torque constant x gear "
                f"ratio) for torque: current ({len(joints)} numbers); got {g!r}"
            )
        gains = tuple(number(x, "gains", lo=1e-9) for x in g)
    elif raw.get("gains") is not None:
        raise SpecError("spec field 'gains' is only for torque: current (the log's currents to torque)")
    inertia_raw = raw.get("inertia", "all")
    inertia = None if inertia_raw == "all" else () if inertia_raw in ("none", None) else _names(inertia_raw, "inertia")
    armature = raw.get("armature", kind != "measured")
    if not isinstance(armature, bool):
        raise SpecError(f"spec field 'armature' must be true or false; got {armature!r}")
    payload = raw.get("payload")
    if payload is not None and (not isinstance(payload, str) or not payload):
        raise SpecError(f"spec field 'payload' must name a body or site of the model; got {payload!r}")
    rate = number(raw.get("rate", 200.0), "rate", lo=1.0, hi=10_000.0)
    filter_hz = number(raw.get("filter_hz", 20.0), "filter_hz", lo=0.1, hi=5_000.0)
    if filter_hz >= rate / 2:
        raise SpecError(
            f"spec field 'filter_hz' ({filter_hz:g}) must be below half of 'rate' ({rate:g} Hz): the signals are "
            "decimated to 'rate' after filtering"
        )
    share, window = parse_holdout(raw.get("holdout", 0.3))
    holdout_at = raw.get("holdout_at", "least_repeated")
    if holdout_at not in HOLDOUT_AT:
        raise SpecError(f"spec field 'holdout_at': {holdout_at!r}; {valid_choices(str(holdout_at), HOLDOUT_AT)}")
    estimate = raw.get("estimate", "auto")
    if estimate not in ESTIMATES:
        raise SpecError(f"spec field 'estimate': {estimate!r}; {valid_choices(str(estimate), ESTIMATES)}")
    return ArmSpec(
        model=model,
        suite=suite,
        robot=robot,
        joints=joints,
        signals=signals,
        torque=kind,
        rate=rate,
        filter_hz=filter_hz,
        friction=_choice_list(raw.get("friction", "all"), "friction", FRICTION),
        armature=armature,
        inertia=inertia,
        payload=payload,
        effects=_choice_list(raw.get("effects", "all"), "effects", ARM_EFFECTS),
        holdout=share,
        holdout_window=window,
        holdout_at=holdout_at,
        period=None if raw.get("period") is None else number(raw["period"], "period", lo=1e-3, hi=1e6),
        horizons=_horizons(raw),
        loop_gain=number(raw.get("loop_gain", 20.0), "loop_gain", lo=0.1, hi=1e4),
        estimate=estimate,
        didim=number(raw.get("didim", 3), "didim", lo=0, hi=50, integer=True),
        payload_region=_region(raw.get("payload_region")),
        bootstrap=number(raw.get("bootstrap", 200), "bootstrap", lo=0, hi=10_000, integer=True),
        controller=_controller(raw.get("controller"), len(joints)),
        gains=gains,
        trace=parse_trace(raw.get("trace")),
        source=source,
    )

"""Real2Sim from Python: what `bench calibrate` does (a spec's model or a real arm fitted to logs, a suite's robot
in its scene, a synthetic case, an excitation design, the effect library), and the parts experiments build on:
write the report, identify the model.

A calibration is carried into runs with `RunConfig(calibration=...)` (docs/calibration.md).
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from bench.calibrate.apply import model_hash
from bench.calibrate.arm.blocks import torque_error
from bench.calibrate.arm.data import load_arm_log
from bench.calibrate.arm.design import design_spec, limits_of, run_design, samples_of_log, write_design
from bench.calibrate.arm.loop import ArmCalibration, calibrate_arm, score_reference, summary_line
from bench.calibrate.arm.model import build
from bench.calibrate.arm.report import write_arm_report
from bench.calibrate.arm.spec import ARM_EFFECTS, ArmSpec, is_arm_spec, load_arm_spec, parse_arm_spec
from bench.calibrate.effects import EFFECTS, Effect
from bench.calibrate.generate import write_case
from bench.calibrate.gradient import METHODS, GradientFitter
from bench.calibrate.report import write_report
from bench.calibrate.servo import (
    ServoCalibration,
    ServoSpec,
    calibrate_servo,
    is_servo_spec,
    parse_servo_spec,
    read_runs,
    write_servo_report,
)
from bench.calibrate.servo import summary as servo_summary
from bench.calibrate.servo.arm import (
    ArmServoCalibration,
    calibrate_arm_servos,
    is_servo_arm_spec,
    parse_servo_arm_spec,
    write_arm_servo_report,
)
from bench.calibrate.servo.arm import summary as arm_servo_summary
from bench.calibrate.spec import EffectRequest, load_spec
from bench.calibrate.suite_robot import calibrate_suite, torque_joints
from bench.calibrate.trace import calibrate_episodes
from bench.core import outputs
from bench.core.config import Range, ranged
from bench.core.errors import ConfigError, DataError, did_you_mean
from bench.logs import read_dataset
from bench.replay.spec import load_model, read_spec_file
from bench.sims.mjx import check_model
from bench.sims.mjx import device as mjx_device
from bench.sims.mjx import require as require_mjx

__all__ = [
    "ArmCalibration",
    "ArmServoCalibration",
    "arm_servo_summary",
    "calibrate_arm_servos",
    "CalibrateConfig",
    "Calibrated",
    "DesignConfig",
    "Designed",
    "GenerateConfig",
    "ServoCalibration",
    "SuiteCalibrateConfig",
    "calibrate",
    "calibrate_arm",
    "calibrate_robot",
    "calibrate_servo",
    "calibrate_suite",
    "design_excitation",
    "effects",
    "generate_case",
    "load_arm_log",
    "load_arm_spec",
    "model_hash",
    "score_reference",
    "servo_summary",
    "summary_line",
    "torque_error",
    "torque_joints",
    "write_arm_report",
    "write_report",
]

MAX_THREADS = 256  # rollout threads: far above any core count here, far below what hangs a machine
MAX_EPISODES = 10_000  # generated episodes
MAX_FRAMES = 5_000_000  # generated frames in all (a few hundred MB of logs)


@dataclass(frozen=True)
class CalibrateConfig:
    """Keys of `bench calibrate spec=...`: a spec's model fitted to logs."""

    spec: Optional[str] = None  # calibration spec, YAML or JSON (docs/calibration.md) (required)
    logs: Optional[str] = None  # LeRobot v3 dataset folder (`bench logs import` converts CSV / MAT / RLDS) (required)
    out: Optional[str] = None  # folder for calibration.json, report.md and plots (required)
    seed: int = ranged(0, 0)  # which episodes are held out (time split when there is one episode)
    effects: Any = None  # override the spec's effect list: all, none or [name,...]
    threads: Optional[int] = ranged(None, 1, MAX_THREADS)  # rollout threads (default: the spec's, 1)
    quiet: bool = False  # no progress lines on stderr
    residual: bool = True  # also fit a learned residual (a model of the force the calibrated physics misses); held-out errors with and without it
    method: str = "least_squares"  # how each fit runs: least_squares (finite differences, CPU MuJoCo) | gradient (MJX, the mjx extra; docs/mjx.md)
    overwrite: bool = False  # replace an existing out folder that bench wrote


@dataclass(frozen=True)
class SuiteCalibrateConfig:
    """Keys of `bench calibrate suite=...`: a suite's robot fitted in its scene to `bench run record=` logs."""

    suite: Optional[str] = None  # suite whose robot is calibrated (required)
    robot: Optional[str] = None  # the robot of the suite (required)
    logs: Optional[str] = None  # `bench run suite=NAME ... record=DIR` logs of that robot (required)
    out: Optional[str] = None  # folder for calibration.json (with its `apply` section), report.md and plots (required)
    condition: Optional[str] = None  # keep only the episodes recorded under this condition (default: all)
    seed: int = ranged(0, 0)  # which episodes are held out
    threads: int = ranged(1, 1, MAX_THREADS)  # rollout threads
    quiet: bool = False  # no progress lines on stderr
    residual: bool = True  # also fit a learned residual (a model of the force the calibrated physics misses); held-out errors with and without it
    overwrite: bool = False  # replace an existing out folder that bench wrote


@dataclass(frozen=True)
class GenerateConfig:
    """Keys of `bench calibrate generate`: a synthetic case with one hidden effect."""

    effect: Optional[str] = None  # the hidden effect (`bench calibrate effects`), or none (required)
    out: Optional[str] = None  # folder for logs/, arm3_declared.xml, spec.yaml and truth.json (required)
    episodes: int = ranged(8, 2, MAX_EPISODES)  # episodes to simulate
    duration: float = ranged(6.0, 0, 3600.0, lo_open=True)  # seconds per episode
    fps: float = ranged(100.0, 0, 10_000.0, lo_open=True)  # frames per second
    seed: int = ranged(0, 0)  # seed of the references and the hidden parameters
    target: Optional[str] = None  # joint or body the effect acts on (default: the effect's own)
    disturbance: Optional[str] = None  # cogging: a force no effect of the library describes (for the learned residual)
    overwrite: bool = False  # replace an existing out folder that bench wrote


def _limits(hi: float) -> Any:
    """A list of positive limits that also takes one bare value (`velocity=2` is `velocity=[2]`: every joint)."""
    return dataclasses.field(default=None, metadata={"range": Range(0, hi, lo_open=True), "bare": True})


@dataclass(frozen=True)
class DesignConfig:
    """Keys of `bench calibrate design`: an excitation that makes an arm spec's parameters identifiable."""

    spec: Optional[str] = None  # arm spec (method: idim) whose parameters the excitation must identify (required)
    out: Optional[str] = None  # folder for design.json and trajectory.csv (required)
    logs: Optional[str] = None  # a log of the arm (LeRobot v3): its excitation is the "before", checked for gaps
    period: float = ranged(10.0, 1.0, 120.0)  # seconds of one period of the trajectory (it repeats)
    harmonics: int = ranged(5, 2, 20)  # Fourier harmonics per joint (the highest at harmonics/period Hz)
    seed: int = ranged(0, 0)  # seed of the random starts and of the search (the same seed, the same design)
    margin: float = ranged(0.05, 0.0, 0.5)  # share of each joint's range kept clear at either end
    velocity: Optional[list[float]] = _limits(1e3)  # velocity limit per joint, or one for all, rad/s (required)
    torque: Optional[list[float]] = _limits(1e6)  # torque limit per joint or one for all, N·m (default: the actuators')
    overwrite: bool = False  # replace an existing out folder that bench wrote
    quiet: bool = False  # no progress lines on stderr


@dataclass(frozen=True)
class Calibrated:
    """What a calibration wrote (OUT/calibration.json, report.md, plots) and what it found."""

    path: Path  # OUT/calibration.json
    calibration: Any  # an ArmCalibration (an arm spec, `method: idim`), else the fit and trace of a spec or a suite
    extra: dict[str, Any] | None = None  # what its report adds: the gradient fitter's stats, a suite's `apply` section

    @property
    def warnings(self) -> list[str]:
        found: list[str] = self.calibration.warnings
        return found


@dataclass(frozen=True)
class Designed:
    """An excitation design (`bench calibrate design`): OUT/design.json and OUT/trajectory.csv written."""

    out: Path
    design: Any  # bench.calibrate.arm.design's result: condition numbers before and after, identified directions
    limits: Any  # the limits it kept to, and where each came from


def _require(cfg: Any, *keys: str, command: str = "bench calibrate") -> list[str]:
    """The values of the required `keys` of `cfg` (ConfigError naming the first one not given)."""
    for key in keys:
        if getattr(cfg, key) is None:
            raise ConfigError(f"missing key {key!r}; usage: {command} {' '.join(k + '=...' for k in keys)}")
    return [getattr(cfg, key) for key in keys]


def _effect_names(value: Any, valid: Sequence[str], of: str = "") -> tuple[str, ...]:
    """The effects key's list (or one name), each checked against `valid` (`of`: what they are effects of)."""
    names = value if isinstance(value, list) else [value]
    for n in names:
        if n not in valid:
            raise ConfigError(
                f"key 'effects': unknown effect {n!r}{of}; valid: all, none, {', '.join(valid)}."
                f"{did_you_mean(str(n), valid)}"
            )
    return tuple(str(n) for n in names)


def _effects(value: Any) -> Any:
    if value is None:
        return "spec"
    if value == "all":
        return None
    if value == "none":
        return ()
    return tuple(EffectRequest(n) for n in _effect_names(value, list(EFFECTS)))


def _load_logs(path: Path) -> tuple[list[dict[str, Any]], float]:
    if not path.exists():
        raise DataError(f"logs folder {str(path)!r} does not exist")
    ds = read_dataset(path)
    return [ep.data for ep in ds.episodes], float(ds.fps)


def _arm(cfg: CalibrateConfig, spec: ArmSpec, spec_file: str, logs: str, out_dir: str) -> Calibrated:
    """A real arm by inverse dynamics (`method: idim`): logs -> OUT/calibration.json, report.md, torque.png."""
    inputs = {"spec": spec_file, "logs": logs, **({"model": str(spec.model)} if spec.model else {})}
    out = _out(out_dir, cfg.overwrite, inputs)
    if cfg.effects is not None:
        chosen = _arm_effects(cfg.effects)
        spec = dataclasses.replace(spec, effects=chosen)
    episodes, fps = _load_logs(Path(logs).expanduser())
    cal = calibrate_arm(spec, episodes, fps, seed=cfg.seed, threads=cfg.threads or 1, log=_log(cfg.quiet))
    outputs.replace_dir(out, lambda tmp: write_arm_report(cal, tmp))
    return Calibrated(out / "calibration.json", cal)


def _servo(cfg: CalibrateConfig, spec: ServoSpec, spec_file: str, logs: str, out_dir: str) -> Calibrated:
    """A position servo from its own logs (`method: servo`): OUT/calibration.json and report.md."""
    if cfg.method == "gradient" or cfg.effects is not None:
        raise ConfigError(
            "a servo spec (method: servo) takes its effects from the spec; leave method= and effects= out"
        )
    out = _out(out_dir, cfg.overwrite, {"spec": spec_file, "logs": logs})
    runs = read_runs(Path(logs).expanduser(), spec.columns, units=spec.units, load_scale=spec.load_scale, fps=spec.rate)
    cal = calibrate_servo(spec, runs, log=_log(cfg.quiet))
    outputs.replace_dir(out, lambda tmp: write_servo_report(cal, tmp))
    return Calibrated(out / "calibration.json", cal)


def _servo_arm(cfg: CalibrateConfig, raw: dict[str, Any], spec_path: Path, logs: str, out_dir: str) -> Calibrated:
    """An arm's servos from its LeRobot dataset (`method: servo_arm`): OUT/calibration.json (with `apply` and
    `draws`) and report.md; nothing written on bad input."""
    if cfg.method == "gradient" or cfg.effects is not None or cfg.threads is not None:
        raise ConfigError(
            "a servo_arm spec fits each servo's stiffness, damping, Coulomb friction and armature in one rollout "
            "per parameter kind; leave method=, effects= and threads= out"
        )
    spec = parse_servo_arm_spec(raw, spec_path)
    out = _out(out_dir, cfg.overwrite, {"spec": str(spec_path), "logs": logs, "ranges": spec.ranges_path})
    cal = calibrate_arm_servos(spec, logs, seed=cfg.seed, log=_log(cfg.quiet))
    outputs.replace_dir(out, lambda tmp: write_arm_servo_report(cal, tmp))
    return Calibrated(out / "calibration.json", cal)


def _arm_effects(value: Any) -> tuple[str, ...]:
    if value == "all":
        return ARM_EFFECTS
    if value == "none":
        return ()
    return _effect_names(value, ARM_EFFECTS, " for an arm spec")


def calibrate(cfg: CalibrateConfig) -> Calibrated:
    """`bench calibrate spec=SPEC logs=DIR out=DIR`: the spec's model fitted to the logs, the residual traced to
    missing effects, held-out errors before and after (an arm spec, `method: idim`: the arm by inverse dynamics);
    OUT/calibration.json, report.md and plots. Progress lines go to stderr unless `cfg.quiet`."""
    spec_file, logs, out_dir = _require(cfg, "spec", "logs", "out")
    if cfg.method not in METHODS:
        raise ConfigError(
            f"key 'method': {cfg.method!r} is not a fitting method; valid: {', '.join(METHODS)}."
            f"{did_you_mean(str(cfg.method), METHODS)}"
        )
    raw, spec_path = read_spec_file(Path(spec_file).expanduser())
    if is_arm_spec(raw):
        if cfg.method == "gradient":
            raise ConfigError(
                "key 'method': gradient fits forward (simulation) specs; an arm spec (method: idim) is linear "
                "least squares on the torque, solved exactly: leave method= out"
            )
        return _arm(cfg, parse_arm_spec(raw, spec_path.parent, spec_path), spec_file, logs, out_dir)
    if is_servo_spec(raw):
        return _servo(cfg, parse_servo_spec(raw, spec_path), spec_file, logs, out_dir)
    if is_servo_arm_spec(raw):
        return _servo_arm(cfg, raw, spec_path, logs, out_dir)
    spec = load_spec(spec_path)
    fitter = _gradient_fitter(spec, cfg.quiet) if cfg.method == "gradient" else None
    out = _out(out_dir, cfg.overwrite, {"spec": spec_file, "model": str(spec.model), "logs": logs})
    episodes, fps = _load_logs(Path(logs).expanduser())
    cal = calibrate_episodes(
        spec,
        episodes,
        fps,
        seed=cfg.seed,
        effects=_effects(cfg.effects),
        threads=spec.threads if cfg.threads is None else cfg.threads,
        log=_log(cfg.quiet),
        residual=cfg.residual,
        **({"fitter": fitter} if fitter is not None else {}),
    )
    extra = None
    if fitter is not None:
        extra = {"method": {"name": "gradient", "device": mjx_device(), **fitter.stats.to_json()}}
    return Calibrated(_write(out, cal, extra), cal, extra)


def _gradient_fitter(spec: Any, quiet: bool) -> GradientFitter:
    """The MJX fitter, after checking (before any work) that JAX is installed and MJX can simulate the model."""
    require_mjx()
    check_model(load_model(spec.model), where=spec.model.name)
    return GradientFitter(log=_log(quiet))


def _log(quiet: bool) -> Callable[[str], None]:
    """Progress lines on stderr (none when quiet)."""
    return (lambda msg: None) if quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))


def _out(value: str, overwrite: bool, inputs: dict[str, Any]) -> Path:
    """OUT checked against `bench.core.outputs`' rule (never an input or inside one; overwrite=true for bench's own)."""
    return outputs.check("out", value, inputs, overwrite=overwrite)


def _write(out: Path, cal: Any, extra: dict[str, Any] | None = None) -> Path:
    """The calibration report, built aside and swapped in whole (`bench.core.outputs.replace_dir`)."""
    outputs.replace_dir(out, lambda tmp: write_report(cal, tmp, extra))
    return out / "calibration.json"


def calibrate_robot(cfg: SuiteCalibrateConfig) -> Calibrated:
    """`bench calibrate suite=NAME robot=R logs=DIR out=DIR`: a suite's robot fitted in its scene to `bench run
    record=` logs; OUT/calibration.json carries the `apply` section `RunConfig(calibration=OUT)` runs with."""
    suite, robot, logs, out_dir = _require(cfg, "suite", "robot", "logs", "out")
    out = _out(out_dir, cfg.overwrite, {"logs": logs})
    cal, extra = calibrate_suite(
        suite,
        robot,
        Path(logs),
        seed=cfg.seed,
        threads=cfg.threads,
        log=_log(cfg.quiet),
        residual=cfg.residual,
        condition=cfg.condition,
    )
    return Calibrated(_write(out, cal, extra), cal, extra)


def generate_case(cfg: GenerateConfig) -> Path:
    """`bench calibrate generate`: a synthetic case with one hidden effect (OUT/logs, the declared model, its spec,
    truth.json); returns OUT."""
    name, out_dir = _require(cfg, "effect", "out", command="bench calibrate generate")
    effect = None if name in ("none", "null") else name
    out = _out(out_dir, cfg.overwrite, {})
    frames = cfg.episodes * cfg.duration * cfg.fps
    if frames > MAX_FRAMES:
        raise ConfigError(
            f"episodes x duration x fps = {frames:.3g} frames; at most {MAX_FRAMES:,} are generated "
            "(lower episodes=, duration= or fps=)"
        )
    params = {k: getattr(cfg, k) for k in ("episodes", "duration", "fps", "seed", "target", "disturbance")}
    outputs.replace_dir(out, lambda tmp: write_case(tmp, effect, **params))
    return out


def design_excitation(cfg: DesignConfig) -> Designed:
    """`bench calibrate design`: an excitation for an arm spec; OUT/design.json and OUT/trajectory.csv (nothing
    written on bad input). Progress lines go to stderr unless `cfg.quiet`."""
    spec_file, out_dir = _require(cfg, "spec", "out", command="bench calibrate design")
    spec = design_spec(spec_file, cfg.harmonics, cfg.period)
    inputs = {"spec": spec_file, "logs": cfg.logs, **({"model": str(spec.model)} if spec.model else {})}
    out = _out(out_dir, cfg.overwrite, inputs)
    am = build(spec)
    lim = limits_of(am, cfg.margin, cfg.velocity, cfg.torque)
    log_samples = None
    if cfg.logs is not None:
        episodes, fps = _load_logs(Path(cfg.logs).expanduser())
        log_samples = (*samples_of_log(spec, am, episodes, fps), cfg.logs)
    d = run_design(
        spec,
        am,
        lim,
        period=cfg.period,
        harmonics=cfg.harmonics,
        seed=cfg.seed,
        log_samples=log_samples,
        progress=_log(cfg.quiet),
    )
    outputs.replace_dir(out, lambda tmp: write_design(d, tmp, spec, am, cfg.seed, inputs))
    return Designed(out, d, lim)


def effects() -> dict[str, Effect]:
    """`bench calibrate effects`: the effect library, name -> its row (kind, parameters, what it models)."""
    return dict(EFFECTS)

"""`bench calibrate`: fit a model to logs and trace the residual; generate test data; list the effects."""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from bench.calibrate.arm.design import design_spec, limits_of, run_design, samples_of_log, write_design
from bench.calibrate.arm.loop import calibrate_arm, summary_line
from bench.calibrate.arm.model import build
from bench.calibrate.arm.report import write_arm_report
from bench.calibrate.arm.spec import ARM_EFFECTS, ArmSpec, is_arm_spec, parse_arm_spec
from bench.calibrate.effects import EFFECTS
from bench.calibrate.generate import write_case
from bench.calibrate.gradient import METHODS, GradientFitter
from bench.calibrate.report import write_report
from bench.calibrate.spec import EffectRequest, load_spec
from bench.calibrate.suite_robot import calibrate_suite
from bench.calibrate.trace import calibrate_episodes
from bench.core import config, outputs
from bench.core.config import Range, ranged
from bench.core.errors import ConfigError, DataError, did_you_mean
from bench.logs import read_dataset
from bench.replay.spec import load_model, read_spec_file
from bench.sims.mjx import check_model
from bench.sims.mjx import device as mjx_device
from bench.sims.mjx import require as require_mjx

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


DESIGN_USAGE = (
    "usage: bench calibrate design spec=SPEC out=DIR [logs=DIR] [period=10] [harmonics=5] [seed=0] [margin=0.05]\n"
    "                              [velocity=[...]] [torque=[...]] [overwrite=false] [quiet=false]"
)
DESIGN_ABOUT = (
    "design proposes what to record for an arm spec (method: idim): a periodic Fourier trajectory per joint\n"
    "(Swevers et al. 1997, Gaz et al. 2019) that starts and ends at rest, stays within the joint ranges less the\n"
    "margin, the velocity limits and the torque limits (the declared model's torque with its friction), and\n"
    "minimises the condition number of the regressor the calibration fits (parameters in their plausible\n"
    "sizes, over the directions a motion identifies at all). It prints the condition number before (the log's\n"
    "excitation with logs=, else a random trajectory) and after, warns when the log leaves parameters\n"
    "unidentified that the design identifies, and writes OUT/design.json (coefficients, limits, condition\n"
    "numbers, what each identifies) and OUT/trajectory.csv (t, q, dq, ddq per joint over one period at 1 kHz)."
)


GENERATE_USAGE = (
    "usage: bench calibrate generate effect=NAME|none out=DIR [episodes=8] [duration=6] [fps=100] [seed=0]\n"
    "                                [target=NAME] [disturbance=cogging]"
)
USAGE = (
    "usage: bench calibrate spec=SPEC logs=DIR out=DIR [seed=0] [effects=all|[name,...]] [threads=1] [quiet=false]\n"
    "                       [residual=true] [method=least_squares|gradient]\n"
    "       bench calibrate suite=NAME robot=NAME logs=DIR out=DIR [condition=NAME] [seed=0] [threads=1] [quiet=false]\n"
    "                       [residual=true]\n"
    f"       {GENERATE_USAGE.removeprefix('usage: ')}\n"
    f"       {DESIGN_USAGE.removeprefix('usage: ')}\n"
    "       bench calibrate effects"
)
GENERATE_ABOUT = (
    "generate writes a synthetic case: a 3-joint arm under PD tracking with ONE hidden effect\n"
    "(or none), as LeRobot logs (OUT/logs) plus the declared model, its spec and truth.json;\n"
    "disturbance=cogging adds a force no effect of the library describes (for the learned residual). Then:\n"
    "  bench calibrate spec=OUT/spec.yaml logs=OUT/logs out=OUT/result"
)


def help_text() -> str:
    """`bench calibrate --help`: the spec keys, the suite keys, generate and effects."""
    return config.command_help(
        USAGE,
        "Real2Sim: fit the spec's declared parameters to the logs (bounded least squares on truncated\n"
        "horizons re-initialised from logged states), trace what is still wrong to a missing effect of the\n"
        "library, add it, refit, and report held-out errors before and after.",
        CalibrateConfig,
        notes="A spec with `method: idim` calibrates a real arm from its own torque log by inverse dynamics\n"
        "(links' inertia, friction, offsets; payload and drive-gain effects; a forward check), e.g. the real Panda:\n"
        'bench/calibrate/models/panda_gaz.yaml (docs/calibration.md, "Real arms"); its calibration.json carries\n'
        "`apply` (bench run ... calibration=OUT) and `draws` (perturb.AXIS=from(OUT)).\n\n"
        "suite= calibrates a suite's own robot in its scene from `bench run ... record=DIR` logs (MuJoCo\n"
        "state before each frame, the command of every physics step): a damping and an armature scale over\n"
        "the robot's motor-driven joints, plus Coulomb friction, payloads and gain errors the search finds.\n"
        "calibration.json then carries an `apply` section: `bench run suite=NAME ... calibration=OUT` runs\n"
        "that robot's cells with the calibrated model (a file for another suite, robot or model is refused).\n\n"
        f"suite keys:\n{config.key_help(SuiteCalibrateConfig)}\n\n"
        f"{GENERATE_ABOUT}\n\ngenerate keys (bench calibrate generate --help):\n{config.key_help(GenerateConfig)}\n\n"
        f"{DESIGN_ABOUT}\n\ndesign keys (bench calibrate design --help):\n{config.key_help(DesignConfig)}\n\n"
        "effects lists the effect library (bench calibrate effects).",
        examples=[
            "bench calibrate generate effect=coulomb_friction out=/tmp/case",
            "bench calibrate spec=/tmp/case/spec.yaml logs=/tmp/case/logs out=/tmp/case/result",
            "bench logs import DATA_EMPS.mat out=logs/emps state=[qm] action=[vir]",
            "bench calibrate spec=bench/calibrate/models/emps.yaml logs=logs/emps out=runs/emps",
        ],
    )


def generate_help() -> str:
    """`bench calibrate generate --help`."""
    return config.command_help(
        GENERATE_USAGE,
        GENERATE_ABOUT,
        GenerateConfig,
        examples=["bench calibrate generate effect=coulomb_friction out=/tmp/case"],
    )


def design_help() -> str:
    """`bench calibrate design --help`."""
    return config.command_help(
        DESIGN_USAGE,
        DESIGN_ABOUT,
        DesignConfig,
        notes="Velocity limits are required (a MuJoCo model holds none); torque limits default to the actuators'\n"
        "forcerange (or ctrlrange x gain x gear); slides take m/s and N. The Franka Panda's published limits:\n"
        "  velocity=[2.175,2.175,2.175,2.175,2.61,2.61,2.61] torque=[87,87,87,87,12,12,12]\n"
        "Record whole periods of trajectory.csv and give the calibration spec `period:` (docs/calibration.md,\n"
        '"Real arms").',
        examples=[
            "bench calibrate design spec=bench/calibrate/models/panda_gaz.yaml logs=logs/panda_gaz out=runs/panda_design "
            "velocity=[2.175,2.175,2.175,2.175,2.61,2.61,2.61] torque=[87,87,87,87,12,12,12]",
        ],
    )


def effects_help() -> str:
    """`bench calibrate effects --help`."""
    return config.command_help(
        "usage: bench calibrate effects",
        "Lists the effect library: each effect's name, kind, parameters and what it models. It takes no keys.",
    )


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


def _effects(value: Any):
    if value is None:
        return "spec"
    if value == "all":
        return None
    if value == "none":
        return ()
    return tuple(EffectRequest(n) for n in _effect_names(value, list(EFFECTS)))


def _load_logs(path: Path) -> tuple[list[dict], float]:
    if not path.exists():
        raise DataError(f"logs folder {str(path)!r} does not exist")
    ds = read_dataset(path)
    return [ep.data for ep in ds.episodes], float(ds.fps)


def cmd_arm(cfg: CalibrateConfig, spec: ArmSpec, spec_file: str, logs: str, out_dir: str) -> int:
    """A real arm by inverse dynamics (`method: idim`): logs -> OUT/calibration.json, report.md, torque.png."""
    inputs = {"spec": spec_file, "logs": logs, **({"model": str(spec.model)} if spec.model else {})}
    out = _out(out_dir, cfg.overwrite, inputs)
    if cfg.effects is not None:
        chosen = _arm_effects(cfg.effects)
        spec = dataclasses.replace(spec, effects=chosen)
    episodes, fps = _load_logs(Path(logs).expanduser())
    cal = calibrate_arm(spec, episodes, fps, seed=cfg.seed, threads=cfg.threads or 1, log=_log(cfg.quiet))
    for w in cal.warnings:
        print(f"warning: {w}", file=sys.stderr)
    outputs.replace_dir(out, lambda tmp: write_arm_report(cal, tmp))
    path = out / "calibration.json"
    print(f"wrote {path} and {path.parent / 'report.md'}")
    if cal.am.suite is not None:
        s = cal.am.suite
        print(f"run with it: bench run suite={s['name']} robots=[{s['robot']}] calibration={path}")
    print(summary_line(cal))
    return 0


def _arm_effects(value: Any) -> tuple[str, ...]:
    if value == "all":
        return ARM_EFFECTS
    if value == "none":
        return ()
    return _effect_names(value, ARM_EFFECTS, " for an arm spec")


def cmd_run(cfg: CalibrateConfig) -> int:
    """Calibrate: spec + logs -> OUT/calibration.json, OUT/report.md, plots."""
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
        return cmd_arm(cfg, parse_arm_spec(raw, spec_path.parent, spec_path), spec_file, logs, out_dir)
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
    for w in cal.warnings:
        print(f"warning: {w}", file=sys.stderr)
    extra = None
    if fitter is not None:
        extra = {"method": {"name": "gradient", "device": mjx_device(), **fitter.stats.to_json()}}
        st = fitter.stats
        print(
            f"gradient fits: {st.fits} ({st.fallbacks} by least squares), {st.evaluations} value-and-gradient "
            f"evaluations, {st.wall_s:.1f} s of which {st.compile_s:.1f} s compiling ({mjx_device()})"
        )
    path = _write(out, cal, extra)
    _summary(cal, path)
    return 0


def _gradient_fitter(spec: Any, quiet: bool) -> GradientFitter:
    """The MJX fitter, after checking (before any work) that JAX is installed and MJX can simulate the model."""
    require_mjx()
    check_model(load_model(spec.model), where=spec.model.name)
    return GradientFitter(log=_log(quiet))


def _log(quiet: bool):
    """Progress lines on stderr (none when quiet)."""
    return (lambda msg: None) if quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))


def _out(value: str, overwrite: bool, inputs: dict[str, Any]) -> Path:
    """OUT checked against `bench.core.outputs`' rule (never an input or inside one; overwrite=true for bench's own)."""
    return outputs.check("out", value, inputs, overwrite=overwrite)


def _write(out: Path, cal: Any, extra: dict | None = None) -> Path:
    """The calibration report, built aside and swapped in whole (`bench.core.outputs.replace_dir`)."""
    outputs.replace_dir(out, lambda tmp: write_report(cal, tmp, extra))
    return out / "calibration.json"


def _summary(cal, path: Path) -> None:
    e = cal.errors
    added = ", ".join(f"{a['name']}@{a['target']}" for a in cal.added) or "none"
    print(f"effects added: {added}")
    print(
        f"held-out free-run NRMSE: nominal {e['nominal']['free_run_nrmse']:.4g} -> declared "
        f"{e['declared']['free_run_nrmse']:.4g} -> final {e['final']['free_run_nrmse']:.4g} "
        f"(RMSE {e['declared']['free_run_rmse']:.4g} -> {e['final']['free_run_rmse']:.4g})"
    )
    if cal.learned:
        h = cal.learned["heldout"]
        print(
            "learned residual, apart from the physics (held-out k-step NRMSE): "
            f"{h['physics']['k_step_nrmse']:.4g} -> {h['physics_plus_residual']['k_step_nrmse']:.4g}"
        )
    flags = [w for w in cal.warnings if "bound" in w or "rose" in w]
    tail = f"; {len(flags)} to check: " + "; ".join(flags) if flags else ""
    print(f"wrote {path} and {path.parent / 'report.md'} ({cal.wall['total']:.1f} s){tail}")


def cmd_suite(cfg: SuiteCalibrateConfig) -> int:
    """Calibrate a suite's robot in its scene: logs of `bench run record=` -> OUT/calibration.json with `apply`."""
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
    for w in cal.warnings:
        print(f"warning: {w}", file=sys.stderr)
    path = _write(out, cal, extra)
    _summary(cal, path)
    print(
        f"{len(extra['apply']['edits'])} model edit(s) for {robot}; run with them: bench run "
        f"suite={suite} robots=[{robot}] calibration={path}"
    )
    return 0


def cmd_generate(cfg: GenerateConfig) -> int:
    """Write a synthetic case with one hidden effect."""
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
    print(f"wrote {out}: logs/, arm3_declared.xml, spec.yaml, truth.json (hidden: {effect or 'nothing'})")
    return 0


def cmd_design(cfg: DesignConfig) -> int:
    """An excitation for an arm spec: OUT/design.json and OUT/trajectory.csv (nothing written on bad input)."""
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
    b, a = d.before, d.after
    print(
        f"condition number ({d.parameters} parameters, {d.rank} directions a motion identifies): "
        f"{b['condition']:.4g} ({b['of']}) -> {a['condition']:.4g} (the design)"
    )
    print(
        f"identified directions: {d.parameters - b['ident'].unidentified} -> {d.parameters - a['ident'].unidentified} "
        f"of the {d.rank} a motion can identify; limits: velocity from {lim.source['velocity']}, torque from "
        f"{lim.source['torque']}"
    )
    for w in d.warnings:
        print(f"warning: {w}", file=sys.stderr)
    print(
        f"wrote {out / 'design.json'} and {out / 'trajectory.csv'} ({cfg.period:g} s period at 1 kHz, starting and "
        f"ending at rest: move to its first row first; record whole periods, spec `period: {cfg.period:g}`; "
        f"{d.evaluations} trajectories evaluated, {d.wall:.1f} s)"
    )
    return 0


def cmd_effects(argv: list[str]) -> int:
    """List the effect library (`bench calibrate effects`, no arguments)."""
    if argv:
        raise ConfigError(f"unexpected argument {argv[0]!r}; bench calibrate effects takes none")
    width = max(len(n) for n in EFFECTS)
    for name, eff in EFFECTS.items():
        print(f"{name.ljust(width)}  {eff.kind:8s}  {', '.join(eff.params)}: {eff.doc}")
    return 0


# subcommand -> (handler of the arguments after it, its --help); other arguments calibrate (spec= or suite=)
SUBCOMMANDS: dict[str, tuple[Callable[[list[str]], int], Callable[[], str]]] = {
    "generate": (
        lambda argv: cmd_generate(config.build_from_argv(GenerateConfig, argv, "bench calibrate generate")),
        generate_help,
    ),
    "effects": (cmd_effects, effects_help),
    "design": (
        lambda argv: cmd_design(config.build_from_argv(DesignConfig, argv, "bench calibrate design")),
        design_help,
    ),
}


def main(argv: list[str]) -> int:
    """Entry point of `bench calibrate ...`: spec=... or suite=... calibrates; generate and effects are subcommands."""
    positional, overrides = config.split_args(argv)
    wants_help = any(a in ("-h", "--help") for a in positional)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(help_text(), end="")
        return 0
    if positional and positional[0] in SUBCOMMANDS:
        handler, help_of = SUBCOMMANDS[positional[0]]
        if wants_help:
            print(help_of(), end="")
            return 0
        return handler(positional[1:] + overrides)
    if wants_help:
        print(help_text(), end="")
        return 0
    if positional:
        raise ConfigError(
            f"unexpected argument {positional[0]!r}; subcommands: {', '.join(SUBCOMMANDS)} "
            f"(or spec=... logs=... out=..., or suite=... robot=... logs=... out=...)"
        )
    if any(config.top_key(o) == "suite" for o in overrides):
        return cmd_suite(config.build(SuiteCalibrateConfig, overrides))
    return cmd_run(config.build(CalibrateConfig, overrides))

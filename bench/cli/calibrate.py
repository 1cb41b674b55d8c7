"""`bench calibrate`: fit a model to logs and trace the residual; generate test data; list the effects (the command
lines and printed summaries over `bench.api.calibration`)."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench.api import calibration as cal
from bench.core import config
from bench.core.errors import ConfigError

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
        cal.CalibrateConfig,
        notes="A spec with `method: idim` calibrates a real arm from its own torque log by inverse dynamics\n"
        "(links' inertia, friction, offsets; payload and drive-gain effects; a forward check), e.g. the real Panda:\n"
        'bench/calibrate/models/panda_gaz.yaml (docs/calibration.md, "Real arms"); its calibration.json carries\n'
        "`apply` (bench run ... calibration=OUT) and `draws` (perturb.AXIS=from(OUT)).\n\n"
        "A spec with `method: servo_arm` calibrates an arm's servos (arm: so101 | koch: stiffness / kp, damping,\n"
        "Coulomb friction per joint, and a transport delay searched up to the spec's max_delay) from its LeRobot\n"
        "dataset (action = goal positions, observation.state = positions, units rad | deg | normalized with\n"
        "lerobot's calibration ranges; the Koch: rad | deg from its model's zero) with the arm's own dynamics from\n"
        "its suite's model, holding out whole episodes; calibration.json carries `apply` (bench run suite=so101\n"
        "calibration=OUT, or suite=koch), `draws` (perturb.gain=from(OUT))\n"
        'and `delay` (a delay found: calibration= runs the commands late) (docs/calibration.md, "Arms from LeRobot\n'
        'datasets").\n\n'
        "suite= calibrates a suite's own robot in its scene from `bench run ... record=DIR` logs (MuJoCo\n"
        "state before each frame, the command of every physics step): a damping and an armature scale over\n"
        "the robot's motor-driven joints, plus Coulomb friction, payloads and gain errors the search finds.\n"
        "calibration.json then carries an `apply` section: `bench run suite=NAME ... calibration=OUT` runs\n"
        "that robot's cells with the calibrated model (a file for another suite, robot or model is refused).\n\n"
        f"suite keys:\n{config.key_help(cal.SuiteCalibrateConfig)}\n\n"
        f"{GENERATE_ABOUT}\n\ngenerate keys (bench calibrate generate --help):\n{config.key_help(cal.GenerateConfig)}\n\n"
        f"{DESIGN_ABOUT}\n\ndesign keys (bench calibrate design --help):\n{config.key_help(cal.DesignConfig)}\n\n"
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
        cal.GenerateConfig,
        examples=["bench calibrate generate effect=coulomb_friction out=/tmp/case"],
    )


def design_help() -> str:
    """`bench calibrate design --help`."""
    return config.command_help(
        DESIGN_USAGE,
        DESIGN_ABOUT,
        cal.DesignConfig,
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


def _warn(done: cal.Calibrated) -> None:
    for w in done.warnings:
        print(f"warning: {w}", file=sys.stderr)


def cmd_run(cfg: cal.CalibrateConfig) -> int:
    """Calibrate: spec + logs -> OUT/calibration.json, OUT/report.md, plots."""
    done = cal.calibrate(cfg)
    _warn(done)
    if isinstance(done.calibration, cal.ServoCalibration):  # a position servo from its own logs (`method: servo`)
        print("\n".join(cal.servo_summary(done.calibration)))
        print(f"wrote {done.path} and {done.path.parent / 'report.md'} ({done.calibration.wall['total']:.1f} s)")
        return 0
    if isinstance(done.calibration, cal.ArmServoCalibration):  # an arm's servos from a LeRobot dataset
        print("\n".join(cal.arm_servo_summary(done.calibration)))
        arm = done.calibration.arm
        print(f"wrote {done.path} and {done.path.parent / 'report.md'}")
        print(f"run with it: bench run suite={arm.suite} calibration={done.path}")
        return 0
    if isinstance(done.calibration, cal.ArmCalibration):  # a real arm by inverse dynamics (`method: idim`)
        path = done.path
        print(f"wrote {path} and {path.parent / 'report.md'}")
        if done.calibration.am.suite is not None:
            s = done.calibration.am.suite
            print(f"run with it: bench run suite={s['name']} robots=[{s['robot']}] calibration={path}")
        print(cal.summary_line(done.calibration))
        return 0
    if done.extra is not None:
        st = done.extra["method"]
        print(
            f"gradient fits: {st['fits']} ({st['fallbacks']} by least squares), {st['evaluations']} value-and-gradient "
            f"evaluations, {st['wall_s']:.1f} s of which {st['compile_s']:.1f} s compiling ({st['device']})"
        )
    _summary(done.calibration, done.path)
    return 0


def _summary(cal: Any, path: Path) -> None:
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


def cmd_suite(cfg: cal.SuiteCalibrateConfig) -> int:
    """Calibrate a suite's robot in its scene: logs of `bench run record=` -> OUT/calibration.json with `apply`."""
    done = cal.calibrate_robot(cfg)
    _warn(done)
    _summary(done.calibration, done.path)
    assert done.extra is not None, "a suite calibration has its `apply` section"
    print(
        f"{len(done.extra['apply']['edits'])} model edit(s) for {cfg.robot}; run with them: bench run "
        f"suite={cfg.suite} robots=[{cfg.robot}] calibration={done.path}"
    )
    return 0


def cmd_generate(cfg: cal.GenerateConfig) -> int:
    """Write a synthetic case with one hidden effect."""
    out = cal.generate_case(cfg)
    effect = None if cfg.effect in ("none", "null") else cfg.effect
    print(f"wrote {out}: logs/, arm3_declared.xml, spec.yaml, truth.json (hidden: {effect or 'nothing'})")
    return 0


def cmd_design(cfg: cal.DesignConfig) -> int:
    """An excitation for an arm spec: OUT/design.json and OUT/trajectory.csv (nothing written on bad input)."""
    done = cal.design_excitation(cfg)
    d, lim, out = done.design, done.limits, done.out
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
    library = cal.effects()
    width = max(len(n) for n in library)
    for name, eff in library.items():
        print(f"{name.ljust(width)}  {eff.kind:8s}  {', '.join(eff.params)}: {eff.doc}")
    return 0


# subcommand -> (handler of the arguments after it, its --help); other arguments calibrate (spec= or suite=)
SUBCOMMANDS: dict[str, tuple[Callable[[list[str]], int], Callable[[], str]]] = {
    "generate": (
        lambda argv: cmd_generate(config.build_from_argv(cal.GenerateConfig, argv, "bench calibrate generate")),
        generate_help,
    ),
    "effects": (cmd_effects, effects_help),
    "design": (
        lambda argv: cmd_design(config.build_from_argv(cal.DesignConfig, argv, "bench calibrate design")),
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
        return cmd_suite(config.build(cal.SuiteCalibrateConfig, overrides))
    return cmd_run(config.build(cal.CalibrateConfig, overrides))

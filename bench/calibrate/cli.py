"""`bench calibrate`: fit a model to logs and trace the residual; generate test data; list the effects."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from bench.errors import ConfigError, DataError, did_you_mean

USAGE = """usage: bench calibrate spec=SPEC logs=DIR out=DIR [seed=0] [effects=all|[name,...]] [threads=1] [quiet=false]
                       [residual=true]
       bench calibrate suite=NAME robot=NAME logs=DIR out=DIR [condition=NAME] [seed=0] [threads=1] [quiet=false]
                       [residual=true]
       bench calibrate generate effect=NAME|none out=DIR [episodes=8] [duration=6] [fps=100] [seed=0]
                                [target=NAME] [disturbance=cogging]
       bench calibrate effects

Real2Sim: fit the spec's declared parameters to the logs (bounded least squares on truncated
horizons re-initialised from logged states), trace what is still wrong to a missing effect of the
library, add it, refit, and report held-out errors before and after.

  spec      calibration spec, YAML or JSON (docs/calibration.md)
  logs      LeRobot v3 dataset folder (`bench logs import` converts CSV / MAT / RLDS)
  out       folder for calibration.json, report.md and plots
  seed      which episodes are held out (time split when there is one episode)
  effects   override the spec's effect list: all, none or [name,...]
  threads   rollout threads (default: the spec's, 1)
  residual  also fit a learned residual (a small model of the force the calibrated physics still
            misses) and report held-out errors with and without it, apart from the physics (default true)

suite= calibrates a suite's own robot in its scene from `bench run ... record=DIR` logs (MuJoCo
state before each frame, the command of every physics step): a damping and an armature scale over
the robot's motor-driven joints, plus Coulomb friction, payloads and gain errors the search finds.
calibration.json then carries an `apply` section: `bench run suite=NAME ... calibration=OUT` runs
that robot's cells with the calibrated model (a file for another suite, robot or model is refused).

generate writes a synthetic case: a 3-joint arm under PD tracking with ONE hidden effect
(or none), as LeRobot logs (OUT/logs) plus the declared model, its spec and truth.json;
disturbance=cogging adds a force no effect of the library describes (for the learned residual). Then:
  bench calibrate spec=OUT/spec.yaml logs=OUT/logs out=OUT/result

examples:
  bench calibrate generate effect=coulomb_friction out=/tmp/case
  bench calibrate spec=/tmp/case/spec.yaml logs=/tmp/case/logs out=/tmp/case/result
  bench logs import DATA_EMPS.mat out=logs/emps state=[qm] action=[vir]
  bench calibrate spec=bench/calibrate/models/emps.yaml logs=logs/emps out=runs/emps
"""

RUN_KEYS = ("spec", "logs", "out", "seed", "effects", "threads", "quiet", "residual", "overwrite")
SUITE_KEYS = ("suite", "robot", "logs", "out", "seed", "threads", "quiet", "residual", "condition", "overwrite")
GEN_KEYS = ("effect", "out", "episodes", "duration", "fps", "seed", "target", "disturbance", "overwrite")


def _check(kv: dict, valid: tuple[str, ...], required: tuple[str, ...]) -> None:
    for key in kv:
        if key not in valid:
            raise ConfigError(f"unknown key {key!r}; valid keys: {', '.join(valid)}.{did_you_mean(key, valid)}")
    for key in required:
        if kv.get(key) in (None, ""):
            raise ConfigError(f"missing key {key!r}; usage: bench calibrate {' '.join(k + '=...' for k in required)}")


MAX_THREADS = 256  # rollout threads: far above any core count here, far below what hangs a machine
MAX_EPISODES = 10_000  # generated episodes
MAX_FRAMES = 5_000_000  # generated frames in all (a few hundred MB of logs)


def _int(kv: dict, key: str, default: int, lo: int = 0, hi: int | None = None) -> int:
    value = kv.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or value < lo or (hi is not None and value > hi):
        valid = f"an integer in [{lo}, {hi}]" if hi is not None else f"an integer >= {lo}"
        raise ConfigError(f"key {key!r} must be {valid}; got {value!r}")
    return value


def _float(kv: dict, key: str, default: float, hi: float) -> float:
    value = kv.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value <= hi:
        raise ConfigError(f"key {key!r} must be a positive number <= {hi:g}; got {value!r}")
    return float(value)


def _effects(value: Any):
    from bench.calibrate.effects import EFFECTS
    from bench.calibrate.spec import EffectRequest

    if value is None:
        return "spec"
    if value == "all":
        return None
    if value == "none":
        return ()
    names = value if isinstance(value, list) else [value]
    for n in names:
        if n not in EFFECTS:
            raise ConfigError(
                f"key 'effects': unknown effect {n!r}; valid: all, none, {', '.join(EFFECTS)}."
                f"{did_you_mean(str(n), EFFECTS)}"
            )
    return tuple(EffectRequest(str(n)) for n in names)


def _load_logs(path: Path) -> tuple[list[dict], float]:
    from bench.logs import read_dataset

    if not path.exists():
        raise DataError(f"logs folder {str(path)!r} does not exist")
    ds = read_dataset(path)
    return [ep.data for ep in ds.episodes], float(ds.fps)


def cmd_run(kv: dict) -> int:
    """Calibrate: spec + logs -> OUT/calibration.json, OUT/report.md, plots."""
    from bench.calibrate.spec import load_spec
    from bench.calibrate.trace import run

    _check(kv, RUN_KEYS, ("spec", "logs", "out"))
    spec = load_spec(Path(str(kv["spec"])).expanduser())
    out = _out(kv, {"spec": str(kv["spec"]), "model": str(spec.model), "logs": str(kv["logs"])})
    episodes, fps = _load_logs(Path(str(kv["logs"])).expanduser())
    quiet = _flag(kv, "quiet")
    log = (lambda msg: None) if quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
    threads = _int(kv, "threads", spec.threads, lo=1, hi=MAX_THREADS)
    residual = _residual(kv)
    cal = run(
        spec,
        episodes,
        fps,
        seed=_int(kv, "seed", 0),
        effects=_effects(kv.get("effects")),
        threads=threads,
        log=log,
        residual=residual,
    )
    for w in cal.warnings:
        print(f"warning: {w}", file=sys.stderr)
    path = _write(out, cal)
    _summary(cal, path)
    return 0


def _out(kv: dict, inputs: dict[str, Any]) -> Path:
    """OUT checked against `bench.outputs`' rule (never an input or inside one; overwrite=true for bench's own)."""
    from bench import outputs

    overwrite = kv.get("overwrite", False)
    if not isinstance(overwrite, bool):
        raise ConfigError(f"key 'overwrite' must be true or false; got {overwrite!r}")
    return outputs.check("out", str(kv["out"]), inputs, overwrite=overwrite)


def _write(out: Path, cal: Any, extra: dict | None = None) -> Path:
    """The calibration report, built aside and swapped in whole (`bench.outputs.replace_dir`)."""
    from bench import outputs
    from bench.calibrate.report import write_report

    outputs.replace_dir(out, lambda tmp: write_report(cal, tmp, extra))
    return out / "calibration.json"


def _flag(kv: dict, key: str) -> bool:
    value = kv.get(key, False)
    if not isinstance(value, bool):
        raise ConfigError(f"key {key!r} must be true or false; got {value!r}")
    return value


def _residual(kv: dict) -> bool:
    residual = kv.get("residual", True)
    if not isinstance(residual, bool):
        raise ConfigError(f"key 'residual' must be true or false; got {residual!r}")
    return residual


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
    print(f"wrote {path} and {path.parent / 'report.md'} ({cal.wall['total']:.1f} s)")


def cmd_suite(kv: dict) -> int:
    """Calibrate a suite's robot in its scene: logs of `bench run record=` -> OUT/calibration.json with `apply`."""
    from bench.calibrate.suite import calibrate_suite

    _check(kv, SUITE_KEYS, ("suite", "robot", "logs", "out"))
    out = _out(kv, {"logs": str(kv["logs"])})
    residual, threads, seed = _residual(kv), _int(kv, "threads", 1, lo=1, hi=MAX_THREADS), _int(kv, "seed", 0)
    log = (lambda msg: None) if _flag(kv, "quiet") else (lambda msg: print(msg, file=sys.stderr, flush=True))
    cal, extra = calibrate_suite(
        str(kv["suite"]),
        str(kv["robot"]),
        Path(str(kv["logs"])),
        seed=seed,
        threads=threads,
        log=log,
        residual=residual,
        condition=None if kv.get("condition") is None else str(kv["condition"]),
    )
    for w in cal.warnings:
        print(f"warning: {w}", file=sys.stderr)
    path = _write(out, cal, extra)
    _summary(cal, path)
    print(
        f"{len(extra['apply']['edits'])} model edit(s) for {kv['robot']}; run with them: bench run "
        f"suite={kv['suite']} robots=[{kv['robot']}] calibration={path}"
    )
    return 0


def cmd_generate(kv: dict) -> int:
    """Write a synthetic case with one hidden effect."""
    from bench import outputs
    from bench.calibrate.generate import write_case

    _check(kv, GEN_KEYS, ("effect", "out"))
    effect = None if kv["effect"] in ("none", "null") else str(kv["effect"])
    out = _out(kv, {})
    episodes = _int(kv, "episodes", 8, lo=2, hi=MAX_EPISODES)
    duration, fps = _float(kv, "duration", 6.0, 3600.0), _float(kv, "fps", 100.0, 10_000.0)
    params = dict(
        episodes=episodes,
        duration=duration,
        fps=fps,
        seed=_int(kv, "seed", 0),
        target=kv.get("target"),
        disturbance=kv.get("disturbance"),
    )
    frames = episodes * duration * fps
    if frames > MAX_FRAMES:
        raise ConfigError(
            f"episodes x duration x fps = {frames:.3g} frames; at most {MAX_FRAMES:,} are generated "
            "(lower episodes=, duration= or fps=)"
        )
    outputs.replace_dir(out, lambda tmp: write_case(tmp, effect, **params))
    print(f"wrote {out}: logs/, arm3_declared.xml, spec.yaml, truth.json (hidden: {effect or 'nothing'})")
    return 0


def cmd_effects() -> int:
    """List the effect library."""
    from bench.calibrate.effects import EFFECTS

    width = max(len(n) for n in EFFECTS)
    for name, eff in EFFECTS.items():
        print(f"{name.ljust(width)}  {eff.kind:8s}  {', '.join(eff.params)}: {eff.doc}")
    return 0


def main(argv: list[str]) -> int:
    """Entry point of `bench calibrate ...`."""
    from bench.config import parse_kv

    if not argv or argv[0] in ("-h", "--help", "help"):
        print(USAGE)
        return 0
    positional, kv = parse_kv(argv)
    if positional[:1] == ["generate"]:
        return cmd_generate(kv)
    if positional[:1] == ["effects"]:
        return cmd_effects()
    if positional:
        raise ConfigError(
            f"unexpected argument {positional[0]!r}; subcommands: generate, effects "
            f"(or spec=... logs=... out=..., or suite=... robot=... logs=... out=...)"
        )
    return cmd_suite(kv) if "suite" in kv else cmd_run(kv)

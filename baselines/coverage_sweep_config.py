"""The coverage sweep's keys (`SweepConfig`), their `--help`, and the checks made before anything runs.

`baselines.coverage_sweep` runs the experiment; the conditions it names (DR widths, the surrogate's
perturbed simulator) are formed here with bench's own `perturb.*` grammar.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from bench.api import ConfigError, did_you_mean


@dataclass(frozen=True)
class SweepConfig:
    """Keys of the coverage sweep (`python -m baselines.coverage_sweep --help`)."""

    suite: str = "held_out_robots"  # suite with a scripted expert and a seen/unseen robot split
    order: list[str] = field(default_factory=lambda: ["Panda", "Sawyer", "IIWA"])  # seen robots, added one at a time
    total_episodes: int = 36  # demonstrations per training set (budget=fixed), split evenly over robots
    budget: str = "fixed"  # fixed: total_episodes over the set's robots; per_robot: total_episodes each
    dr_axis: str = "gain"  # domain-randomisation axis ('' skips the DR part)
    dr_widths: list[float] = field(default_factory=lambda: [0.1, 0.3])  # DR widths w besides 0: uniform(1-w, 1+w)
    surrogate_target: str = "Panda"  # in-domain robot of the surrogate-data experiment
    surrogate_in_domain: int = 12  # fixed in-domain demonstrations (target robot, nominal)
    surrogate_episodes: int = 24  # mismatched demonstrations added to them
    surrogate_perturb: str = "latency=4"  # strongly perturbed simulator on the target robot: AXIS=LEVEL
    surrogate_eval_episodes: int = 30  # evaluation episodes on the target robot per surrogate model
    eval_episodes: int = 10  # evaluation episodes per cell (all robots) per sweep model
    demo_seed: int = 0  # seed of the demonstration runs (the extra run uses demo_seed+1)
    eval_seed: int = 1  # seed of every evaluation run (same initial states for every model)
    seeds: list[int] = field(
        default_factory=lambda: [0, 1, 2]
    )  # BC training seeds per training set (spread enters every interval)
    workers: int = 2  # worker processes of each bench run
    horizon: int = 0  # control steps per episode, demonstrations and evaluations (0 = suite default)
    parts: list[str] = field(default_factory=lambda: ["robots", "dr", "surrogate"])  # experiments to run
    bc: dict[str, Any] = field(default_factory=dict)  # baselines.bc Args overrides, e.g. bc.epochs=50
    workdir: str = "runs/coverage"  # demonstrations, checkpoints, evaluation runs (reused when present)
    out: str = "results/coverage"  # sweep.json and sweep.png go here
    n_boot: int = 2000  # bootstrap resamples
    confidence: float = 0.95  # two-sided interval level


PARTS = ("robots", "dr", "surrogate")


BUDGETS = ("fixed", "per_robot")


def sweep_help() -> str:
    from bench.api.scripts import command_help

    return command_help(
        "usage: python -m baselines.coverage_sweep [key=value ...]",
        "Does wider training coverage buy held-out success? Records scripted demonstrations\n"
        "(bench run ... record=), trains baselines.bc on nested training sets — 1, 2, 3 seen robots at a\n"
        "fixed demonstration budget (robots); domain randomisation of one axis at widths 0, ±w (dr) —\n"
        "evaluates each checkpoint on every cell with policy=checkpoint (same seeds for all),\n"
        "and reports held-out (unseen) success, in-distribution success on the training robots and the\n"
        "transfer gap against coverage, with intervals, the WLS slope with a paired bootstrap interval,\n"
        "and a plot. surrogate: a fixed in-domain set (target robot) alone, plus other robots' data, plus\n"
        "data from a strongly perturbed simulator; success on the target robot, paired differences.\n"
        "Everything under workdir is reused on a rerun (runs resume; datasets and checkpoints are kept\n"
        "when their inputs match), so an interrupted sweep continues where it stopped.",
        SweepConfig,
        [
            "python -m baselines.coverage_sweep out=results/coverage workdir=/tmp/coverage",
            "python -m baselines.coverage_sweep parts=[robots] total_episodes=24 eval_episodes=5 workers=2",
            "python -m baselines.coverage_sweep dr_axis=friction dr_widths=[0.5] bc.epochs=60",
        ],
    )


def check_sweep(cfg: SweepConfig, suite) -> None:
    for p in cfg.parts:
        if p not in PARTS:
            raise ConfigError(f"parts: {p!r} is not a part; valid: {', '.join(PARTS)}.{did_you_mean(p, PARTS)}")
    if cfg.budget not in BUDGETS:
        raise ConfigError(f"budget={cfg.budget!r}: valid: {', '.join(BUDGETS)}")
    robots = suite.manifest.get("robots", {})
    seen, unseen = robots.get("seen", []), robots.get("unseen", [])
    if not seen or not unseen:
        raise ConfigError(f"suite {suite.name!r} has no seen/unseen robot split; the sweep needs one")
    if not cfg.order:
        raise ConfigError("order: give the seen robots to add one at a time, e.g. order=[Panda,Sawyer,IIWA]")
    if not cfg.seeds or len(set(cfg.seeds)) != len(cfg.seeds):
        raise ConfigError(f"seeds={cfg.seeds}: give one or more distinct training seeds, e.g. seeds=[0,1,2]")
    for r in cfg.order + [cfg.surrogate_target]:
        if r not in seen:
            raise ConfigError(
                f"order/surrogate_target: {r!r} is not a seen robot of {suite.name!r}; valid: "
                f"{', '.join(seen)}.{did_you_mean(r, seen)}"
            )
    if len(set(cfg.order)) != len(cfg.order):
        raise ConfigError(f"order={cfg.order}: repeats a robot")
    for key in (
        "total_episodes",
        "eval_episodes",
        "surrogate_in_domain",
        "surrogate_episodes",
        "surrogate_eval_episodes",
        "workers",
    ):
        if getattr(cfg, key) < 1:
            raise ConfigError(f"{key}={getattr(cfg, key)}: must be >= 1")
    if cfg.budget == "fixed" and cfg.total_episodes < len(cfg.order):
        raise ConfigError(f"total_episodes={cfg.total_episodes}: must be >= len(order)={len(cfg.order)} (budget=fixed)")
    if "dr" in cfg.parts and cfg.dr_axis:
        from bench.api.sims import AXES

        if cfg.dr_axis not in AXES:
            raise ConfigError(f"dr_axis={cfg.dr_axis!r}: valid: {', '.join(AXES)}.{did_you_mean(cfg.dr_axis, AXES)}")
        if AXES[cfg.dr_axis].kind != "model":
            raise ConfigError(
                f"dr_axis={cfg.dr_axis!r}: DR widths are scales of nominal; valid: model axes "
                f"({', '.join(a for a, v in AXES.items() if v.kind == 'model')})"
            )
        for w in cfg.dr_widths:
            if not 0 < w < 1:
                raise ConfigError(f"dr_widths: {w} must be in (0, 1): the range is uniform(1-w, 1+w)")
    if "surrogate" in cfg.parts:
        surrogate_condition(cfg.surrogate_perturb)
    if not 0.5 <= cfg.confidence < 1:
        raise ConfigError(f"confidence={cfg.confidence}: must be in [0.5, 1)")
    if cfg.n_boot < 100:
        raise ConfigError(f"n_boot={cfg.n_boot}: must be >= 100")
    from baselines.bc import Args

    valid = [f.name for f in dataclasses.fields(Args)]
    for k in cfg.bc:
        if k not in valid or k in ("data", "out", "robots", "conditions", "max_episodes"):
            raise ConfigError(
                f"bc.{k}: not a training argument the sweep passes on; valid: "
                f"{', '.join(v for v in valid if v not in ('data', 'out', 'robots', 'conditions', 'max_episodes'))}"
                f".{did_you_mean(k, valid)}"
            )


def surrogate_condition(text: str):
    """The Condition of `surrogate_perturb` ("AXIS=LEVEL"), checked with bench.sims.perturb.reset's grammar."""
    from bench.api.sims import conditions_from_config

    if "=" not in text:
        raise ConfigError(f"surrogate_perturb={text!r}: write AXIS=LEVEL, e.g. latency=4 or gain=0.6")
    axis, level = text.split("=", 1)
    try:
        value: Any = float(level)
    except ValueError:
        value = level
    conds = conditions_from_config({axis.strip(): [value]})
    if len(conds) != 2 or conds[1].level is None or isinstance(conds[1].level, list):
        raise ConfigError(f"surrogate_perturb={text!r}: give one level, e.g. latency=4")
    return conds[1]


def dr_condition_names(cfg: SweepConfig) -> list[tuple[float, str, str]]:
    """(width, condition name, perturb grammar) per DR width, names as bench.sims.perturb.reset forms them."""
    from bench.api.sims import conditions_from_config

    out = []
    for w in cfg.dr_widths:
        text = f"uniform({1 - w:g},{1 + w:g})"
        name = conditions_from_config({cfg.dr_axis: [text]})[1].name
        out.append((float(w), name, text))
    return out


def per_robot(cfg: SweepConfig, k: int) -> int:
    return cfg.total_episodes // k if cfg.budget == "fixed" else cfg.total_episodes

"""Behaviour cloning: an MLP trained with torch on CPU from LeRobot v3 demonstrations.

One readable file in the CleanRL manner: the arguments are the `Args` dataclass (one
docstring per field), seeding is explicit (random, numpy, torch), the run name encodes
dataset, algorithm and seed, and the result is a checkpoint `bench run policy=checkpoint`
loads (`baselines.checkpoint`: safetensors weights + JSON spec, never a pickle).

    python -m baselines.bc data=[demos/seen] out=runs/bc/policy.safetensors seed=0
    bench run suite=held_out_robots policy=checkpoint checkpoint=runs/bc/policy.safetensors

What it learns: `observation.state` -> `action`, both normalised by their training mean
and std (dimensions that never vary get mean 0, std 1, so the network learns a
constant); an action dimension that never varies is reproduced exactly (its spec std is 1e-9,
so the network's output for it does not reach the command). The gripper command is binary in the demonstrations (+1 close, -1 open), so
by default (`gripper=sign`) its output is a logit trained with a logistic loss; the
checkpoint stores `gripper_sharpness` as that dimension's action std, so at inference
the command is `clip(sharpness * logit, -1, 1)`: +-1 except in a thin band around
p = 0.5 (|logit| < 1/sharpness). The policy is memoryless (one observation in, one
action out), the format `policy=checkpoint` runs.

Determinism: one torch thread, `torch.use_deterministic_algorithms(True)`, and every
draw (initialisation, shuffling, input noise) from generators seeded by `seed`: the same
data and arguments give bit-identical weights, hence the same checkpoint sha256 (the
training wall time is returned, not stored in the checkpoint, for that reason).
"""

from __future__ import annotations

import ast
import inspect
import os
import random
import re
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from bench.api import ConfigError, DataError
from bench.api.data import portable


@dataclass(frozen=True)
class TrainIO:
    """What every trainer in `baselines/` reads and writes (`bc.py`, `bc_image.py`): data in, one checkpoint out."""

    data: list[str] = field(default_factory=list)
    """LeRobot v3 dataset folder(s) to train on, e.g. [demos/seen] (`bench run ... record=DIR`)"""
    out: Optional[str] = None
    """checkpoint to write (.safetensors; the .json spec goes beside it); default runs/TRAINER/RUN_NAME/policy.safetensors"""
    overwrite: bool = False
    """replace an existing checkpoint at `out` (only one bench wrote; never an input)"""
    seed: int = 0
    """seeds random, numpy and torch: initial weights, minibatch order, input noise or augmentation"""


@dataclass(frozen=True)
class Args(TrainIO):
    robots: Optional[list[str]] = None
    """keep only episodes whose meta `robot` is listed (None = every robot)"""
    conditions: Optional[list[str]] = None
    """keep only episodes whose meta `condition` is listed, e.g. [nominal] (None = all)"""
    max_episodes: int = 0
    """at most this many episodes per (robot, condition): the first ones, datasets in the order given (0 = all)"""
    successful_only: bool = True
    """drop demonstrations whose episode never succeeded (meta `success_once`)"""
    hidden: list[int] = field(default_factory=lambda: [256, 256])
    """MLP hidden layer widths"""
    activation: str = "relu"
    """hidden activation: relu, tanh, gelu or elu"""
    epochs: int = 30
    """passes over the training frames"""
    batch_size: int = 256
    """frames per minibatch"""
    lr: float = 1e-3
    """Adam learning rate (cosine-annealed to 0 over the run)"""
    weight_decay: float = 1e-5
    """AdamW weight decay"""
    obs_noise: float = 0.0
    """std of Gaussian noise added to the normalised observations during training (0 = none)"""
    gripper: str = "sign"
    """gripper dimension: sign (logistic loss, output saturates to +-1) or regress (MSE like the rest)"""
    gripper_sharpness: float = 20.0
    """gripper=sign: command = clip(sharpness * logit, -1, 1)"""
    threads: int = 1
    """torch CPU threads (1 keeps training bit-reproducible and leaves cores to the simulators)"""


GRIPPER_MODES = ("sign", "regress")


def run_name(args: Args) -> str:
    """`DATASET__bc__sSEED`, the dataset part joined from the data folders' names."""
    data = "+".join(Path(p).name for p in args.data) or "nodata"
    return f"{data}__bc__s{args.seed}"


def recorded_data(paths: Sequence[str]) -> list[str]:
    """The data folders as a checkpoint records them: relative to the checkout when inside it (`portable`), else
    by the folder's name alone, so a checkpoint names no folder of the machine that trained it (a scratch folder's
    absolute path would also change its sha256 from one machine to the next)."""
    out = []
    for given in paths:
        where = Path(given).resolve()
        rel = portable(where)
        out.append(where.name if rel is None or Path(rel).is_absolute() else rel)
    return out


def seed_everything(seed: int, threads: int = 1) -> None:
    """Seed random, numpy and torch and make torch deterministic on `threads` CPU threads."""
    import torch

    random.seed(seed)
    np.random.seed(seed)  # noqa: NPY002 - for third-party code only; our own draws use seeded generators
    torch.manual_seed(seed)
    torch.set_num_threads(int(threads))
    torch.use_deterministic_algorithms(True)


# -- data ------------------------------------------------------------------------------------
def obs_layout(names: Sequence[str]) -> list[list[Any]]:
    """[name, width] pairs from a dataset's flat element names (inverse of `bench.execution.recording`).

    The recorder writes a width-w field `f` as `f_0 .. f_{w-1}` and a width-1 field as `f`,
    so a run `f_0, f_1, ...` of length >= 2 is one field; anything else is a width-1 field.
    """
    out: list[list[Any]] = []
    i = 0
    names = list(names)
    while i < len(names):
        m = re.fullmatch(r"(.+)_0", names[i])
        if m:
            prefix, w = m.group(1), 1
            while i + w < len(names) and names[i + w] == f"{prefix}_{w}":
                w += 1
            if w >= 2:
                out.append([prefix, w])
                i += w
                continue
        out.append([names[i], 1])
        i += 1
    return out


@dataclass
class Demos:
    """Training frames gathered from one or more datasets."""

    obs: np.ndarray  # (N, D) float32
    action: np.ndarray  # (N, A) float32
    episode: np.ndarray  # (N,) int64: index into `episodes`
    episodes: list[dict]  # per episode: source, index, robot, condition, params, frames
    obs_names: list[list[Any]]  # [name, width] pairs
    action_names: list[str]

    def __add__(self, other: Demos) -> Demos:
        if self.obs_names != other.obs_names or self.action_names != other.action_names:
            raise DataError("cannot combine demonstrations with different observation/action layouts")
        return Demos(
            np.concatenate([self.obs, other.obs]),
            np.concatenate([self.action, other.action]),
            np.concatenate([self.episode, other.episode + len(self.episodes)]),
            self.episodes + other.episodes,
            self.obs_names,
            self.action_names,
        )


def load_demos(
    paths: Sequence[str | os.PathLike],
    robots: Sequence[str] | None = None,
    conditions: Sequence[str] | None = None,
    max_episodes: int = 0,
    successful_only: bool = True,
) -> Demos:
    """Frames of the selected episodes of LeRobot v3 datasets (`observation.state`, `action`).

    Args:
        paths: dataset folders.
        robots, conditions: keep episodes whose meta `robot` / `condition` is listed (None = all).
        max_episodes: at most this many per (robot, condition), the first ones in the order of
            `paths` and then of their episodes (0 = all).
        successful_only: drop episodes whose meta says `success_once` is false.

    Raises:
        DataError: a dataset without the two features, layouts that differ, or nothing selected.
    """
    from bench.api.datasets import read_dataset

    if not paths:
        raise ConfigError("data: give at least one dataset folder, e.g. data=[demos/seen]")
    obs, act, epi = [], [], []
    episodes: list[dict[str, Any]] = []
    obs_names = action_names = None
    seen_robots: set[str] = set()
    counts: dict[tuple, int] = {}
    for path in paths:
        if not Path(path).is_dir():
            raise ConfigError(f"data: {str(path)!r} is not a dataset folder")
        ds = read_dataset(path)
        for feat in ("observation.state", "action"):
            if feat not in ds.features:
                raise DataError(f"{path}: feature {feat!r} is missing; BC needs observation.state and action")
        o_names = obs_layout(
            ds.features["observation.state"].get("names")
            or [f"obs_{i}" for i in range(ds.feature_shape("observation.state")[0])]
        )
        a_names = list(ds.features["action"].get("names") or [f"a{i}" for i in range(ds.feature_shape("action")[0])])
        if obs_names is None:
            obs_names, action_names = o_names, a_names
        elif (o_names, a_names) != (obs_names, action_names):
            raise DataError(f"{path}: observation/action names differ from {paths[0]}'s")
        for ep in ds.episodes:
            meta = ep.meta or {}
            robot, cond = meta.get("robot"), meta.get("condition", "nominal")
            seen_robots.add(str(robot))
            if robots is not None and robot not in robots:
                continue
            if conditions is not None and cond not in conditions:
                continue
            if successful_only and meta.get("success_once") is False:
                continue
            key = (robot, cond)
            if max_episodes and counts.get(key, 0) >= max_episodes:
                continue
            counts[key] = counts.get(key, 0) + 1
            o, a = ep.data["observation.state"], ep.data["action"]
            obs.append(np.asarray(o, np.float32))
            act.append(np.asarray(a, np.float32))
            epi.append(np.full(len(o), len(episodes), np.int64))
            episodes.append(
                {
                    "source": str(path),
                    "index": ep.index,
                    "task": meta.get("task"),
                    "robot": robot,
                    "env": meta.get("env"),
                    "condition": cond,
                    "params": meta.get("params") or {},
                    "frames": len(o),
                }
            )
    if not episodes:
        what = f"robots={list(robots)}" if robots is not None else "the filters"
        raise DataError(
            f"data: no episode selected by {what} (conditions={conditions}, successful_only="
            f"{successful_only}); robots in the data: {', '.join(sorted(seen_robots))}"
        )
    return Demos(np.concatenate(obs), np.concatenate(act), np.concatenate(epi), episodes, obs_names, action_names)  # type: ignore[arg-type]


def _moments(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and std per column; columns that (almost) never vary get mean 0, std 1."""
    mean, std = x.mean(axis=0).astype(np.float64), x.std(axis=0).astype(np.float64)
    flat = std < 1e-6
    mean[flat], std[flat] = 0.0, 1.0
    return mean, std


# -- training --------------------------------------------------------------------------------
def _check(args: Args) -> None:
    if args.gripper not in GRIPPER_MODES:
        raise ConfigError(f"gripper={args.gripper!r}: valid: {', '.join(GRIPPER_MODES)}")
    import math

    for key, hi in (("epochs", 100_000), ("batch_size", 1_000_000), ("threads", 256)):
        if not 1 <= getattr(args, key) <= hi:
            raise ConfigError(f"{key}={getattr(args, key)}: must be an integer in [1, {hi:,}]")
    for key, lo_open in (("lr", True), ("gripper_sharpness", True), ("weight_decay", False), ("obs_noise", False)):
        v = getattr(args, key)
        if not math.isfinite(v) or (v <= 0 if lo_open else v < 0) or v > 1e6:
            raise ConfigError(f"{key}={v}: must be a finite number {'>' if lo_open else '>='} 0 and <= 1e6")
    if args.seed < 0:
        raise ConfigError(f"seed={args.seed}: must be >= 0")
    hidden = getattr(args, "hidden", None)
    if hidden is not None and any(not 1 <= int(h) <= 65_536 for h in hidden):
        raise ConfigError(f"hidden={list(hidden)}: layer widths must be integers in [1, 65536]")
    if args.max_episodes < 0:
        raise ConfigError(f"max_episodes={args.max_episodes}: must be >= 0 (0 = all)")


def fit(demos: Demos, args: Args) -> tuple[Any, dict[str, Any], dict[str, Any]]:
    """Train the MLP on `demos`; return (model, checkpoint spec, training info).

    The info holds the wall time, frame/episode counts and final losses; the spec holds
    what inference needs plus reproducible metadata (no wall time, so same seed -> same file).
    """
    import torch
    import torch.nn.functional as F

    from baselines.architectures import build

    _check(args)
    seed_everything(args.seed, args.threads)
    t0 = time.perf_counter()
    obs_mean, obs_std = _moments(demos.obs)
    act_mean, act_std = _moments(demos.action)
    # an action dimension the demonstrations never vary (the Lift expert's rotations) is reproduced
    # exactly: its spec std is ~0 so the network output does not reach the command, and it has no loss
    const = [i for i in range(demos.action.shape[1]) if np.ptp(demos.action[:, i]) < 1e-6]
    grip = [i for i, n in enumerate(demos.action_names) if "gripper" in n.lower()] if args.gripper == "sign" else []
    for i in grip:
        values = np.unique(np.sign(demos.action[:, i]))
        if not set(values.tolist()) <= {-1.0, 1.0}:
            raise DataError(f"gripper=sign: action {demos.action_names[i]!r} has zeros; use gripper=regress")
        act_mean[i], act_std[i] = 0.0, float(args.gripper_sharpness)
    cont = [i for i in range(demos.action.shape[1]) if i not in grip and i not in const]
    x = torch.from_numpy(((demos.obs - obs_mean) / obs_std).astype(np.float32))
    y = torch.from_numpy(((demos.action - act_mean) / act_std).astype(np.float32))
    y_grip = torch.from_numpy((demos.action[:, grip] > 0).astype(np.float32))
    kwargs = {"hidden": [int(h) for h in args.hidden], "activation": args.activation}
    model = build("mlp", x.shape[1], y.shape[1], kwargs)
    gen = torch.Generator().manual_seed(args.seed)
    opt = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=args.weight_decay)
    n = len(x)
    steps_per_epoch = max(1, -(-n // args.batch_size))
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=args.epochs * steps_per_epoch)
    history = []
    for epoch in range(args.epochs):
        perm = torch.randperm(n, generator=gen)
        total = total_c = total_g = 0.0
        for s in range(steps_per_epoch):
            idx = perm[s * args.batch_size : (s + 1) * args.batch_size]
            xb = x[idx]
            if args.obs_noise > 0:
                xb = xb + args.obs_noise * torch.randn(xb.shape, generator=gen)
            out = model(xb)
            loss_c = F.mse_loss(out[:, cont], y[idx][:, cont]) if cont else out.sum() * 0
            loss_g = F.binary_cross_entropy_with_logits(out[:, grip], y_grip[idx]) if grip else out.sum() * 0
            loss = loss_c + loss_g
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            total += loss.item() * len(idx)
            total_c += loss_c.item() * len(idx)
            total_g += loss_g.item() * len(idx)
        history.append({"epoch": epoch, "loss": total / n, "mse": total_c / n, "gripper_bce": total_g / n})
    spec_act_mean, spec_act_std = act_mean.copy(), act_std.copy()
    for i in const:
        spec_act_mean[i], spec_act_std[i] = float(demos.action[0, i]), 1e-9
    model.eval()
    with torch.inference_mode():
        out = model(x)
        grip_acc = float(((out[:, grip] > 0).float() == y_grip).float().mean()) if grip else None
    robots = sorted({str(e["robot"]) for e in demos.episodes})
    conditions = sorted({str(e["condition"]) for e in demos.episodes})
    spec = {
        "architecture": "mlp",
        "kwargs": kwargs,
        "obs_names": demos.obs_names,
        "action_names": demos.action_names,
        "normalization": {
            "obs": {"mean": obs_mean, "std": obs_std},
            "action": {"mean": spec_act_mean, "std": spec_act_std},
        },
        "clip_actions": True,
        "meta": {
            "algorithm": "bc",
            "run_name": run_name(args),
            "seed": args.seed,
            # where it is saved is not what it is; where its data lay, only as a portable name (`recorded_data`)
            "args": {k: recorded_data(v) if k == "data" else v for k, v in asdict(args).items() if k != "out"},
            "episodes": len(demos.episodes),
            "frames": n,
            "robots": robots,
            "conditions": conditions,
            "gripper_dims": [demos.action_names[i] for i in grip],
            "constant_dims": [demos.action_names[i] for i in const],
        },
    }
    info = {
        "run_name": run_name(args),
        "train_wall_s": round(time.perf_counter() - t0, 3),
        "frames": n,
        "episodes": len(demos.episodes),
        "robots": robots,
        "conditions": conditions,
        "final": history[-1],
        "gripper_accuracy": grip_acc,
        "history": history,
    }
    return model, spec, info


def train(args: Args, demos: Demos | None = None) -> tuple[Path, dict[str, Any]]:
    """Load the demonstrations (unless given), fit, save the checkpoint; return (path, info)."""
    from baselines.checkpoint import save_checkpoint
    from bench.api.data import outputs

    _check(args)
    out = Path(args.out) if args.out else Path("runs") / "bc" / run_name(args) / "policy.safetensors"
    for target in (out, out.with_suffix(".json")):  # the weights and the spec beside them
        outputs.check("out", target, {"data": list(args.data)}, kind="file", overwrite=args.overwrite)
    if demos is None:
        demos = load_demos(args.data, args.robots, args.conditions, args.max_episodes, args.successful_only)
    model, spec, info = fit(demos, args)
    path = save_checkpoint(out, model, spec)
    outputs.remember(path, path.with_suffix(".json"))
    info["checkpoint"] = str(path)
    return path, info


# -- command line ----------------------------------------------------------------------------
def field_docs(args_class: type) -> dict[str, str]:
    """Field name -> the docstring under it in `args_class` and its dataclass bases (CleanRL's one-line-per-field style)."""
    docs: dict[str, str] = {}
    for cls in reversed(args_class.__mro__):
        if cls is object or "__dataclass_fields__" not in vars(cls):
            continue
        body = ast.parse(inspect.getsource(cls)).body[0].body  # type: ignore[attr-defined]
        for a, b in zip(body, body[1:]):
            if (
                isinstance(a, ast.AnnAssign)
                and isinstance(b, ast.Expr)
                and isinstance(getattr(b, "value", None), ast.Constant)
            ):
                docs[a.target.id] = str(b.value.value)  # type: ignore[union-attr]
    return docs


def key_rows(args_class: type) -> str:
    """The `keys:` block of a trainer's --help: one line per field, its docstring and its default."""
    docs = field_docs(args_class)
    defaults = asdict(args_class())
    return "\n".join(f"  {k:<18} {docs.get(k, '')} (default: {defaults[k]})" for k in defaults)


def help_text() -> str:
    rows = key_rows(Args)
    return (
        "usage: python -m baselines.bc data=[DIR,...] [key=value ...]\n\n"
        "Behaviour cloning: trains an MLP (obs -> action, normalised) on LeRobot v3 demonstrations\n"
        "and writes a checkpoint for `bench run policy=checkpoint checkpoint=PATH`.\n\n"
        f"keys:\n{rows}\n\n"
        "example:\n"
        "  bench run suite=held_out_robots splits=[seen] policy=scripted episodes=40 record=demos/seen\n"
        "  python -m baselines.bc data=[demos/seen] out=runs/bc/policy.safetensors\n"
        "  bench run suite=held_out_robots policy=checkpoint checkpoint=runs/bc/policy.safetensors\n"
    )


def main(argv: list[str]) -> int:
    """CLI: parse key=value into `Args`, train, print where the checkpoint went."""
    from bench.api.scripts import build_from_argv

    if argv and argv[0] in ("-h", "--help"):
        print(help_text())
        return 0
    args: Args = build_from_argv(Args, argv, "python -m baselines.bc")
    path, info = train(args)
    print(
        f"{info['run_name']}: {info['episodes']} episodes, {info['frames']} frames, robots {info['robots']}; "
        f"loss {info['final']['loss']:.4f}, gripper accuracy {info['gripper_accuracy']}, "
        f"{info['train_wall_s']:.1f} s -> {path}"
    )
    return 0


if __name__ == "__main__":
    from bench.api.scripts import guarded  # bad input: one line, exit 2; never a traceback

    raise SystemExit(guarded(lambda: main(sys.argv[1:])))

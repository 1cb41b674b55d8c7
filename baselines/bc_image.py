"""Image-based behaviour cloning: a small CNN on the camera images plus proprioception, trained with torch on CPU.

One readable file in the CleanRL manner (the state-based sibling is `baselines/bc.py`): the
arguments are `Args` (one docstring per field), seeding is explicit, and the result is a
checkpoint (safetensors weights + JSON spec, never a pickle) that `policy=bc_image` runs.

    bench run suite=held_out_robots policy=scripted splits=[seen] obs=state+rgb image_size=64 \\
        episodes=20 horizon=130 seed=100 record=demos_img
    python -m baselines.bc_image data=[demos_img] out=runs/bc_image/policy.safetensors
    bench run suite=held_out_robots obs=state+rgb image_size=64 policy=bc_image \\
        checkpoint=runs/bc_image/policy.safetensors

What it sees: every camera of the dataset (`observation.images.<camera>`, e.g. the front
`agentview` and the wrist `robot0_eye_in_hand`) and the robot's own state only, picked by name
from `observation.state` (`proprio`: end-effector position, its orientation relative to reset,
gripper opening) -- not the object's pose, which must come from the pixels. Each camera has its
own conv trunk (4 conv layers, stride 2, ReLU, global average pooling of the last map plus a
spatial soft-argmax of its channels); the features and the normalised proprioception go through
an MLP to the 7-D action. Training adds random shifts of the images (+-`shift` pixels, the
DrQ augmentation); the gripper command is a logit with a logistic loss as in `bc.py`.

Determinism: `torch.use_deterministic_algorithms(True)`, `threads` CPU threads, every draw from
generators seeded by `seed`.
"""

from __future__ import annotations

import json
import os
import random
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from baselines.bc import TrainIO, key_rows, obs_layout
from bench.api import BenchError, ConfigError, DataError
from bench.protocols import RGB, STATE, PolicyContext, PolicyIdentity, PolicyPlugin
from bench.protocols.env import obs_slices

CAMERA_PREFIX = "observation.images."


@dataclass(frozen=True)
class Args(TrainIO):
    """`TrainIO` (data: datasets with camera features, from `bench run obs=state+rgb record=DIR`) and:"""

    cameras: Optional[list[str]] = None
    """cameras to use (names after observation.images.); None = every camera of the dataset"""
    proprio: list[str] = field(default_factory=lambda: ["eef_pos", "eef_quat_rel", "gripper_opening"])
    """fields of observation.state the policy sees besides the images (the robot's own state)"""
    successful_only: bool = True
    """drop demonstrations whose episode never succeeded (meta `success_once`)"""
    channels: list[int] = field(default_factory=lambda: [32, 32, 64, 64])
    """conv trunk widths (one stride-2 3x3 conv each)"""
    hidden: int = 256
    """MLP hidden width (two layers)"""
    epochs: int = 20
    """passes over the training frames"""
    batch_size: int = 64
    """frames per minibatch"""
    lr: float = 1e-3
    """Adam learning rate (cosine-annealed to 0 over the run)"""
    weight_decay: float = 1e-4
    """AdamW weight decay"""
    shift: int = 4
    """random image shift in pixels during training (replicate-padded crop); 0 = none"""
    gripper_sharpness: float = 20.0
    """command = clip(sharpness * logit, -1, 1) for the gripper dimension (the last action)"""
    threads: int = 2
    """torch CPU threads"""


# -- data ------------------------------------------------------------------------------------
def load(args: Args) -> dict[str, Any]:
    """Frames of the selected episodes: images per camera (N, H, W, 3) uint8, proprio (N, P), action (N, A)."""
    from bench.api.datasets import read_dataset

    if not args.data:
        raise ConfigError("data: give at least one dataset folder with camera features, e.g. data=[demos_img]")
    images: dict[str, list[np.ndarray]] = {}
    proprio, action, episodes = [], [], 0
    spec: dict[str, Any] = {}
    for path in args.data:
        if not Path(path).is_dir():
            raise ConfigError(f"data: {str(path)!r} is not a dataset folder")
        ds = read_dataset(path)
        cams = [k[len(CAMERA_PREFIX) :] for k in ds.features if k.startswith(CAMERA_PREFIX)]
        if args.cameras is not None:
            missing = [c for c in args.cameras if c not in cams]
            if missing:
                raise ConfigError(f"cameras: {missing[0]!r} is not a camera of {path}; valid: {', '.join(cams)}")
            cams = list(args.cameras)
        if not cams:
            raise DataError(f"{path}: no camera feature ({CAMERA_PREFIX}<camera>); record with obs=state+rgb")
        for feat in ("observation.state", "action"):
            if feat not in ds.features:
                raise DataError(f"{path}: feature {feat!r} is missing")
        slices = obs_slices(
            [(str(n), int(w)) for n, w in obs_layout(ds.features["observation.state"].get("names") or [])]
        )
        unknown = [f for f in args.proprio if f not in slices]
        if unknown:
            raise ConfigError(
                f"proprio: {unknown[0]!r} is not a field of {path}'s observation.state; valid: {', '.join(slices)}"
            )
        mine = {
            "cameras": cams,
            "image_shape": [ds.feature_shape(CAMERA_PREFIX + c) for c in cams],
            "state_fields": [[n, s.stop - s.start] for n, s in slices.items()],
            "action_names": list(ds.features["action"].get("names") or []),
        }
        if spec and mine != spec:
            raise DataError(f"{path}: cameras, image sizes or observation layout differ from {args.data[0]}'s")
        spec = mine
        idx = np.concatenate([np.arange(slices[f].start, slices[f].stop) for f in args.proprio])
        for ep in ds.episodes:
            if args.successful_only and (ep.meta or {}).get("success_once") is False:
                continue
            episodes += 1
            for c in cams:
                images.setdefault(c, []).append(ep.data[CAMERA_PREFIX + c])
            proprio.append(np.asarray(ep.data["observation.state"], np.float32)[:, idx])
            action.append(np.asarray(ep.data["action"], np.float32))
    if not action:
        raise DataError(f"no episode selected from {args.data} (successful_only={args.successful_only})")
    return {
        "images": {c: np.concatenate(v) for c, v in images.items()},
        "proprio": np.concatenate(proprio),
        "action": np.concatenate(action),
        "episodes": episodes,
        **spec,
    }


# -- model -----------------------------------------------------------------------------------
def build_net(n_cameras: int, channels: Sequence[int], proprio_dim: int, hidden: int, action_dim: int):
    """Per-camera conv trunks (pooled + soft-argmax features) -> MLP with the proprioception -> action."""
    import torch
    from torch import nn

    class Trunk(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            layers: list[nn.Module] = []
            c_in = 3
            for c in channels:
                layers += [nn.Conv2d(c_in, c, 3, stride=2, padding=1), nn.ReLU()]
                c_in = c
            self.conv = nn.Sequential(*layers)
            self.out = 3 * c_in  # mean activation + expected (x, y) per channel

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            f = self.conv(x)
            b, c, h, w = f.shape
            soft = torch.softmax(f.reshape(b, c, h * w), dim=-1).reshape(b, c, h, w)
            ys = torch.linspace(-1.0, 1.0, h, device=x.device)
            xs = torch.linspace(-1.0, 1.0, w, device=x.device)
            ex = (soft.sum(dim=2) * xs).sum(dim=-1)
            ey = (soft.sum(dim=3) * ys).sum(dim=-1)
            return torch.cat([f.mean(dim=(2, 3)), ex, ey], dim=1)

    class Net(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.trunks = nn.ModuleList([Trunk() for _ in range(n_cameras)])
            width = sum(t.out for t in self.trunks) + proprio_dim
            self.head = nn.Sequential(
                nn.Linear(width, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, action_dim)
            )

        def forward(self, images: list[torch.Tensor], proprio: torch.Tensor) -> torch.Tensor:
            feats = [t(x) for t, x in zip(self.trunks, images)]
            return self.head(torch.cat(feats + [proprio], dim=1))

    return Net()


def _to_tensor(batch: np.ndarray):
    """(B, H, W, 3) uint8 -> (B, 3, H, W) float in [0, 1]."""
    import torch

    return torch.from_numpy(np.ascontiguousarray(batch)).permute(0, 3, 1, 2).float().div_(255.0)


def _shift(x, pad: int, gen):
    """Random translation of each image by up to +-pad pixels (replicate padding, then a random crop)."""
    import torch
    import torch.nn.functional as F

    if pad <= 0:
        return x
    b, _, h, w = x.shape
    padded = F.pad(x, (pad, pad, pad, pad), mode="replicate").permute(0, 2, 3, 1)  # (B, H+2p, W+2p, 3)
    rows = torch.arange(h)[None, :] + torch.randint(0, 2 * pad + 1, (b, 1), generator=gen)
    cols = torch.arange(w)[None, :] + torch.randint(0, 2 * pad + 1, (b, 1), generator=gen)
    out = padded[torch.arange(b)[:, None, None], rows[:, :, None], cols[:, None, :]]  # (B, H, W, 3)
    return out.permute(0, 3, 1, 2)


def train(args: Args) -> dict[str, Any]:
    """Train on `args.data`, write the checkpoint; returns paths, sizes and the training cost."""
    import torch
    import torch.nn.functional as F
    from safetensors.torch import save_file

    from bench.api.data import outputs

    out_path = Path(
        args.out
        or f"runs/bc_image/{'+'.join(Path(d).name for d in args.data)}__bc_image__s{args.seed}/policy.safetensors"
    )
    for target in (out_path, out_path.with_suffix(".json")):  # checked before any training
        outputs.check("out", target, {"data": list(args.data)}, kind="file", overwrite=args.overwrite)
    t_start = time.perf_counter()
    random.seed(args.seed)
    np.random.seed(args.seed)  # noqa: NPY002 - third-party code only; our draws use seeded generators
    torch.manual_seed(args.seed)
    torch.set_num_threads(int(args.threads))
    torch.use_deterministic_algorithms(True)
    data = load(args)
    cams = data["cameras"]
    n = len(data["action"])
    p_mean, p_std = data["proprio"].mean(0), data["proprio"].std(0) + 1e-6
    act = data["action"]
    a_mean, a_std = act.mean(0), act.std(0) + 1e-6
    a_mean[-1], a_std[-1] = 0.0, 1.0 / args.gripper_sharpness  # gripper: a logit, command = clip(sharpness * logit)
    net = build_net(len(cams), args.channels, data["proprio"].shape[1], args.hidden, act.shape[1])
    opt = torch.optim.AdamW(net.parameters(), lr=args.lr, weight_decay=args.weight_decay)
    steps = args.epochs * max(1, n // args.batch_size)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=steps)
    gen = torch.Generator().manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    proprio_n = torch.from_numpy((data["proprio"] - p_mean) / p_std).float()
    target = torch.from_numpy((act - a_mean) / a_std).float()
    grip = torch.from_numpy((act[:, -1] > 0).astype(np.float32))
    losses = []
    for _epoch in range(args.epochs):
        order = rng.permutation(n)
        total = 0.0
        for b in range(0, n - args.batch_size + 1, args.batch_size):
            idx = order[b : b + args.batch_size]
            imgs = [_shift(_to_tensor(data["images"][c][idx]), args.shift, gen) for c in cams]
            out = net(imgs, proprio_n[idx])
            loss = F.mse_loss(out[:, :-1], target[idx, :-1]) + F.binary_cross_entropy_with_logits(out[:, -1], grip[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss.detach()) * len(idx)
        losses.append(total / max(1, (n // args.batch_size) * args.batch_size))
        print(
            f"epoch {_epoch + 1}/{args.epochs}: loss {losses[-1]:.4f} ({time.perf_counter() - t_start:.0f} s)",
            file=sys.stderr,
            flush=True,
        )
    out_path.parent.mkdir(parents=True, exist_ok=True)
    save_file({k: v.contiguous() for k, v in net.state_dict().items()}, str(out_path))
    spec = {
        "format": "bench.bc_image/1",
        "cameras": cams,
        "image_shape": data["image_shape"],
        "state_fields": data["state_fields"],
        "proprio": list(args.proprio),
        "action_names": data["action_names"],
        "proprio_mean": p_mean.tolist(),
        "proprio_std": p_std.tolist(),
        "action_mean": a_mean.tolist(),
        "action_std": a_std.tolist(),
        "channels": list(args.channels),
        "hidden": args.hidden,
        "train": {
            **{k: v for k, v in asdict(args).items() if k not in ("out",)},
            "frames": n,
            "episodes": data["episodes"],
            "final_loss": round(losses[-1], 6),
        },
    }
    out_path.with_suffix(".json").write_text(json.dumps(spec, indent=1))
    outputs.remember(out_path, out_path.with_suffix(".json"))
    return {
        "checkpoint": str(out_path),
        "frames": n,
        "episodes": data["episodes"],
        "losses": losses,
        "train_seconds": time.perf_counter() - t_start,
        "parameters": sum(p.numel() for p in net.parameters()),
    }


# -- policy ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Options:
    """Keys of policy=bc_image."""

    checkpoint: Optional[str] = None  # a bc_image checkpoint (.safetensors with its .json spec beside it)


def _load_spec(checkpoint: Optional[str]) -> dict[str, Any]:
    if not checkpoint:
        raise ConfigError(
            "checkpoint: policy=bc_image needs checkpoint=PATH.safetensors (python -m baselines.bc_image)"
        )
    path = Path(checkpoint)
    spec_path = path.with_suffix(".json")
    if not path.is_file() or not spec_path.is_file():
        raise ConfigError(f"checkpoint: {checkpoint!r} or its spec {spec_path.name} does not exist")
    try:
        spec = json.loads(spec_path.read_text())
    except json.JSONDecodeError as exc:
        raise DataError(f"{spec_path}: not valid JSON ({exc})") from None
    if spec.get("format") != "bench.bc_image/1":
        raise DataError(f"{spec_path}: format {spec.get('format')!r}; expected bench.bc_image/1")
    return spec


class ImageBCPolicy:
    """The trained network acting on `rgb.<camera>` images and the proprioceptive fields of `state`."""

    def __init__(self, net, spec: dict[str, Any], state_fields: Sequence[tuple[str, int]], low, high):
        import torch

        self.torch, self.net, self.spec = torch, net.eval(), spec
        offsets, start = {}, 0
        for name, width in state_fields:
            offsets[name] = slice(start, start + int(width))
            start += int(width)
        self.idx = np.concatenate([np.arange(offsets[f].start, offsets[f].stop) for f in spec["proprio"]])
        self.p_mean, self.p_std = np.asarray(spec["proprio_mean"]), np.asarray(spec["proprio_std"])
        self.a_mean, self.a_std = np.asarray(spec["action_mean"]), np.asarray(spec["action_std"])
        self.low, self.high = np.asarray(low, np.float64), np.asarray(high, np.float64)

    def reset(self, seed: int) -> None:
        pass

    def act(self, obs: dict[str, Any]) -> np.ndarray:
        torch = self.torch
        with torch.no_grad():
            imgs = [_to_tensor(np.asarray(obs[f"{RGB}{c}"])[None]) for c in self.spec["cameras"]]
            p = (np.asarray(obs[STATE], np.float64)[self.idx] - self.p_mean) / self.p_std
            out = self.net(imgs, torch.from_numpy(p[None]).float())[0].numpy().astype(np.float64)
        return np.clip(out * self.a_std + self.a_mean, self.low, self.high).astype(np.float32)


class ImageBCPlugin(PolicyPlugin):
    """`policy=bc_image`: a `baselines.bc_image` checkpoint on the suite's camera images and proprioception."""

    Options = Options

    def obs_keys(self, options: Any) -> tuple[str, ...]:
        spec = _load_spec(options.checkpoint)
        return (STATE, *(f"{RGB}{c}" for c in spec["cameras"]))

    def identity(self, options: Any) -> PolicyIdentity:
        from bench.api.data import sha256_file

        return PolicyIdentity(str(options.checkpoint), sha256_file(Path(options.checkpoint)))

    def preflight(self, options: Any, suite: Any, cells: Sequence[Any], horizon: int) -> None:
        spec = _load_spec(options.checkpoint)
        for cell in cells[:1]:
            obs = suite.obs_spec(cell)
            for c, shape in zip(spec["cameras"], spec["image_shape"]):
                have = obs.get(f"{RGB}{c}")
                if have is None or list(have.shape) != list(shape):
                    raise ConfigError(
                        f"checkpoint: trained on rgb.{c} {shape}; suite {suite.name} gives "
                        f"{list(have.shape) if have is not None else 'no such camera'} (set obs=state+rgb, "
                        f"cameras=[{','.join(spec['cameras'])}], image_size={shape[0]})"
                    )
            fields = [list(f) for f in obs[STATE].fields]
            if fields != spec["state_fields"]:
                raise ConfigError(
                    f"checkpoint: trained on state fields {spec['state_fields']}; the suite gives {fields}"
                )

    def make(self, cell: Any, env: Any, ctx: PolicyContext) -> ImageBCPolicy:
        import torch
        from safetensors.torch import load_file

        spec = _load_spec(ctx.options.checkpoint)
        torch.set_num_threads(1)
        net = build_net(
            len(spec["cameras"]), spec["channels"], len(spec["proprio_mean"]), spec["hidden"], len(spec["action_mean"])
        )
        net.load_state_dict(load_file(str(ctx.options.checkpoint)))
        return ImageBCPolicy(net, spec, env.obs_spec[STATE].fields, env.action_spec.low, env.action_spec.high)


def main(argv: list[str]) -> int:
    from bench.api.scripts import build_from_argv

    if any(a in ("-h", "--help") for a in argv):
        print(
            f"usage: python -m baselines.bc_image data=[DIR,...] [key=value ...]\n\n{__doc__}\nkeys:\n{key_rows(Args)}"
        )
        return 0
    try:
        args: Args = build_from_argv(Args, argv, "python -m baselines.bc_image")
        result = train(args)
    except BenchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(
        f"trained on {result['frames']} frames ({result['episodes']} episodes), {result['parameters']} parameters, "
        f"{result['train_seconds']:.0f} s on {os.cpu_count()} cores ({args.threads} torch threads); "
        f"loss {result['losses'][0]:.3f} -> {result['losses'][-1]:.3f}; checkpoint {result['checkpoint']}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

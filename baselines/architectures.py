"""Torch policy architectures by name: the registry a checkpoint's spec points into.

A checkpoint stores only weights (safetensors) plus a JSON spec naming an
architecture here and its keyword arguments; loading rebuilds the module from
this registry and loads the weights into it, so no code is ever unpickled.
Every builder takes `(obs_dim, action_dim, **kwargs)` and returns an
`nn.Module` mapping a normalised observation batch (B, obs_dim) to a normalised
action batch (B, action_dim).

Add an architecture by writing a builder and listing it in `ARCHITECTURES`;
names are part of the checkpoint format, so never rename or change one in place
(add `mlp2` instead).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

from bench.api import SpecError, did_you_mean

ACTIVATIONS = ("relu", "tanh", "gelu", "elu")
OUT_ACTIVATIONS = ("none", "tanh")


def mlp(
    obs_dim: int,
    action_dim: int,
    hidden: list[int] | tuple[int, ...] = (256, 256),
    activation: str = "relu",
    out_activation: str = "none",
    layer_norm: bool = False,
):
    """Multi-layer perceptron: Linear -> [LayerNorm] -> activation per hidden layer, then Linear.

    Args:
        obs_dim: input width (the flat observation).
        action_dim: output width (the flat action).
        hidden: widths of the hidden layers, e.g. [256, 256]; [] gives a linear policy.
        activation: one of relu, tanh, gelu, elu.
        out_activation: "none" or "tanh" (squashes the normalised action into [-1, 1]).
        layer_norm: add a LayerNorm after each hidden Linear.
    """
    import torch.nn as nn

    if activation not in ACTIVATIONS:
        raise SpecError(
            f"mlp: activation={activation!r} is not valid; valid: {', '.join(ACTIVATIONS)}"
            f"{did_you_mean(activation, ACTIVATIONS)}"
        )
    if out_activation not in OUT_ACTIVATIONS:
        raise SpecError(f"mlp: out_activation={out_activation!r} is not valid; valid: {', '.join(OUT_ACTIVATIONS)}")
    if not isinstance(hidden, (list, tuple)) or not all(isinstance(h, int) and h > 0 for h in hidden):
        raise SpecError(f"mlp: hidden={hidden!r} must be a list of positive integers, e.g. [256, 256]")
    act = {"relu": nn.ReLU, "tanh": nn.Tanh, "gelu": nn.GELU, "elu": nn.ELU}[activation]
    layers: list[nn.Module] = []
    width = int(obs_dim)
    for h in hidden:
        layers.append(nn.Linear(width, int(h)))
        if layer_norm:
            layers.append(nn.LayerNorm(int(h)))
        layers.append(act())
        width = int(h)
    layers.append(nn.Linear(width, int(action_dim)))
    if out_activation == "tanh":
        layers.append(nn.Tanh())
    return nn.Sequential(*layers)


ARCHITECTURES: dict[str, Callable[..., Any]] = {"mlp": mlp}


def build(name: str, obs_dim: int, action_dim: int, kwargs: dict[str, Any] | None = None):
    """Build the registered architecture `name`; unknown names or keyword arguments are a SpecError."""
    if name not in ARCHITECTURES:
        valid = sorted(ARCHITECTURES)
        raise SpecError(
            f"architecture={name!r} is not registered; valid: {', '.join(valid)}.{did_you_mean(name, valid)}"
        )
    builder = ARCHITECTURES[name]
    kwargs = dict(kwargs or {})
    params = [p for p in inspect.signature(builder).parameters if p not in ("obs_dim", "action_dim")]
    for key in kwargs:
        if key not in params:
            raise SpecError(
                f"architecture {name!r}: unknown argument {key!r}; valid: {', '.join(params)}."
                f"{did_you_mean(key, params)}"
            )
    try:
        return builder(int(obs_dim), int(action_dim), **kwargs)
    except SpecError:
        raise
    except (TypeError, ValueError) as exc:
        raise SpecError(f"architecture {name!r} with {kwargs}: {exc}") from None

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


def rowwise(model, x):
    """`model(x)` for a batch (B, D) whose row i is bit for bit what the same call gives `x[i:i+1]` alone.

    A batched matrix product sums in an order that depends on the batch size (the packaged BC's actions move by up
    to 1e-2 between a batch of 1 and of 32 once de-normalised), and a vectorised elementwise kernel rounds a value
    by where it falls in memory, either of which would make a vectorised run's records differ from an unbatched
    one's. So each `nn.Linear` of a `nn.Sequential` is a batch of one-row products (`baddbmm`, which runs the same
    product per row whatever the batch), ReLU and Identity (no rounding) take the batch at once, and other layers
    (tanh, GELU, ELU, LayerNorm) one row at a time, as does a model that is not a `nn.Sequential`. `act` is this
    with B = 1. Checked over widths and layers in tests/test_vector.py.
    """
    import torch  # torch: loaded only when a policy answers (the registry itself imports none)

    if not isinstance(model, torch.nn.Sequential):
        return torch.cat([model(x[i : i + 1]) for i in range(len(x))])
    h, n = x[:, None, :], len(x)
    for m in model:
        if isinstance(m, torch.nn.Linear):
            weight = m.weight.t().expand(n, -1, -1)
            h = torch.bmm(h, weight) if m.bias is None else torch.baddbmm(m.bias.expand(n, 1, -1), h, weight)
        elif isinstance(m, (torch.nn.ReLU, torch.nn.Identity)):  # no rounding: exact whatever the layout
            h = m(h)
        else:  # a vectorised kernel rounds a row by where it falls in memory: one row at a time
            h = torch.cat([m(h[i : i + 1]) for i in range(n)])
    return h[:, 0]

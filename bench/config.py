"""Command-line overrides in Hydra's grammar onto typed, frozen configs.

`key=value` sets a field, `a.b=value` a nested one, `key=[x,y]` a list. Values are
parsed as YAML scalars/flow lists by OmegaConf. The result is a frozen dataclass:
nothing downstream can mutate it. An unknown key or a value of the wrong type is
a one-line `ConfigError` (exit 2) that names the key and suggests the closest one.
"""
from __future__ import annotations

import dataclasses
import re
from typing import Any, Iterable, TypeVar

from bench.errors import ConfigError, did_you_mean

T = TypeVar("T")


def split_args(argv: Iterable[str]) -> tuple[list[str], list[str]]:
    """Split argv into positional arguments and `key=value` overrides (in order)."""
    positional, overrides = [], []
    for arg in argv:
        if "=" in arg and not arg.startswith("="):
            overrides.append(arg)
        else:
            positional.append(arg)
    return positional, overrides


def build_from_argv(cls: type, argv: Iterable[str], command: str):
    """`key=value` arguments of a command that takes no positional ones -> a frozen `cls` (ConfigError if not)."""
    positional, overrides = split_args(argv)
    if positional:
        raise ConfigError(f"unexpected argument {positional[0]!r}; {command} takes key=value only "
                          f"(see {command} --help)")
    return build(cls, overrides)


def top_key(override: str) -> str:
    """`perturb.friction=[1,2]` -> `perturb`: the key a `key=value` override sets (or sets inside)."""
    return override.split("=", 1)[0].split(".", 1)[0]


def partition(overrides: Iterable[str], owners: dict[str, list[str]], context: str) -> dict[str, list[str]]:
    """Route each `key=value` override to the one owner (runner, suite, policy ...) that declares its key.

    A key no owner declares is a ConfigError listing every owner's keys; a key two owners
    declare is a plugin conflict (ConfigError naming both).
    """
    out: dict[str, list[str]] = {name: [] for name in owners}
    claimed: dict[str, str] = {}
    for name, keys in owners.items():
        for k in keys:
            if k in claimed:
                raise ConfigError(f"key {k!r} is declared by both {claimed[k]} and {name}; the plugins conflict")
            claimed[k] = name
    for item in overrides:
        if "=" not in item or not item.split("=", 1)[0]:
            raise ConfigError(f"argument {item!r} is not key=value ({context})")
        key = top_key(item)
        if key not in claimed:
            listing = "; ".join(f"{name}: {', '.join(keys) or '(none)'}" for name, keys in owners.items())
            raise ConfigError(f"unknown key {key!r} ({context}); valid keys — {listing}.{did_you_mean(key, claimed)}")
        out[claimed[key]].append(item)
    return out


def parse_kv(argv: Iterable[str]) -> tuple[list[str], dict[str, Any]]:
    """Positional arguments and a nested dict of the `key=value` overrides (untyped).

    For commands whose keys are checked by hand; typed commands use `build`.
    """
    from omegaconf import OmegaConf

    positional, overrides = split_args(argv)
    try:
        kv = OmegaConf.to_container(OmegaConf.from_dotlist(overrides), resolve=True)
    except Exception as exc:  # omegaconf grammar errors
        raise ConfigError(f"cannot parse overrides {overrides}: {str(exc).splitlines()[0]}") from None
    return positional, kv  # type: ignore[return-value]


def _fields(schema: type) -> list[str]:
    return [f.name for f in dataclasses.fields(schema)]


def build(schema: type[T], overrides: Iterable[str], *, base: dict | None = None) -> T:
    """Merge `key=value` overrides onto the dataclass `schema` and return a frozen instance.

    Args:
        schema: a (frozen) dataclass whose fields have defaults and type hints.
        overrides: strings like `episodes=10`, `robots=[UR5e,IIWA]`, `perturb.friction=[0.5,1]`.
        base: optional values applied before the overrides (e.g. a stored config).
    """
    from omegaconf import OmegaConf
    from omegaconf.errors import ConfigKeyError, OmegaConfBaseException, ValidationError

    from omegaconf.errors import MissingMandatoryValue

    overrides = list(overrides)
    for item in overrides:
        key = item.split("=", 1)[0]
        if "=" not in item or not key:
            raise ConfigError(f"argument {item!r} is not key=value; valid keys: {', '.join(_fields(schema))}")
    keys = [item.split("=", 1)[0] for item in overrides]
    twice = next((k for i, k in enumerate(keys) if k in keys[:i]), None)
    if twice is not None:
        given = [item for item in overrides if item.split("=", 1)[0] == twice]
        raise ConfigError(f"key {twice!r} is given twice ({' and '.join(given)}); give it once")
    for key in keys:  # `a.b=[1,2] a.b.c=x`: OmegaConf fails with a bare ValueError
        child = next((k for k in keys if k.startswith(key + ".")), None)
        if child:
            raise ConfigError(f"{key} is set to a value and also given the sub-key {child}; "
                              f"give every part as a sub-key instead (e.g. {key}.levels=[...] {child}=...)")
    try:
        cfg = OmegaConf.structured(schema)
        if base:
            cfg = OmegaConf.merge(cfg, base)
        cfg = OmegaConf.merge(cfg, OmegaConf.from_dotlist(overrides))
        return OmegaConf.to_object(cfg)  # type: ignore[return-value]
    except MissingMandatoryValue as exc:
        key = str(getattr(exc, "full_key", None) or getattr(exc, "key", "?"))
        raise ConfigError(f"{key}: required, and not given ({key}=...)") from None
    except ConfigKeyError as exc:
        key = str(getattr(exc, "full_key", None) or getattr(exc, "key", "?"))
        top = key.split(".")[0]
        valid = _fields(schema)
        hint = did_you_mean(top, valid) if top not in valid else ""
        raise ConfigError(f"unknown key {key!r}; valid keys: {', '.join(valid)}.{hint}") from None
    except ValidationError as exc:
        key = str(getattr(exc, "full_key", None) or getattr(exc, "key", "?"))
        msg = str(exc).splitlines()[0]
        raise ConfigError(f"bad value for {key!r}: {msg}") from None
    except OmegaConfBaseException as exc:
        raise ConfigError(f"cannot parse overrides: {str(exc).splitlines()[0]}") from None


def key_help(schema: type) -> str:
    """One line per field of `schema`: its name and the comment beside it in the source.

    Commands build their `--help` key list from their config dataclass with this, so the
    help cannot drift from the keys that are actually accepted.
    """
    import inspect

    defaults: dict[str, Any] = {}
    required = set()
    for f in dataclasses.fields(schema):
        if f.default is not dataclasses.MISSING:
            defaults[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
            defaults[f.name] = f.default_factory()  # type: ignore[misc]
        else:
            required.add(f.name)
    rows = []
    for line in inspect.getsource(schema).splitlines():
        line = line.strip()
        m = re.match(r"^(\w+)\s*:[^#]*#\s*(.*)$", line)
        if m and m.group(1) in required:
            rows.append((m.group(1) + " (required)", m.group(2)))
        elif m and m.group(1) in defaults:
            d = defaults[m.group(1)]
            shown = "" if d is None or d == {} else f"={str(d).lower() if isinstance(d, bool) else d}"
            rows.append((m.group(1) + shown, m.group(2)))
    width = max((len(k) for k, _ in rows), default=0) + 2
    return "\n".join(f"  {k:<{width}}{doc}" for k, doc in rows)


def command_help(usage: str, about: str, schema: type | None = None, examples: Iterable[str] = (),
                 notes: str = "") -> str:
    """The `--help` text of a command: usage, what it does, its keys (from `schema`, see `key_help`),
    optional notes and examples. Every command builds its help here, so the key list cannot drift
    from the keys it accepts."""
    parts = [usage.rstrip(), about.strip("\n")]
    if schema is not None:
        parts.append("keys:\n" + key_help(schema))
    if notes:
        parts.append(notes.strip("\n"))
    examples = list(examples)
    if examples:
        parts.append("examples:\n" + "\n".join(f"  {e}" for e in examples))
    return "\n\n".join(parts) + "\n"

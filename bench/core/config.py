"""Command-line overrides in Hydra's grammar onto typed, frozen configs.

`key=value` sets a field, `a.b=value` a nested one, `key=[x,y]` a list. Values are
parsed as YAML scalars/flow lists by OmegaConf. The result is a frozen dataclass:
nothing downstream can mutate it. An unknown key or a value of the wrong type is
a one-line `ConfigError` (exit 2) that names the key and suggests the closest one.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import re
import typing
from collections.abc import Iterable, Mapping
from typing import TypeVar

from bench.core.errors import ConfigError, did_you_mean

T = TypeVar("T")

# limits shared by every command (a typo must not start an absurd job; the message names the limit)
MAX_INT = 2**63 - 1  # any integer key: what numpy and JSON readers hold
MAX_N_BOOT = 1_000_000  # bootstrap resamples
MAX_SEED = 2**63 - 1
MAX_EPISODES = 100_000
MAX_HORIZON = 100_000
MAX_WORKERS = 1024
MAX_TIMEOUT_S = 7 * 24 * 3600.0
MAX_RUN_ID = 128
CONTROL_CHARS = re.compile(r"[\x00-\x1f\x7f]")
_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z0-9_]+)*")


@dataclasses.dataclass(frozen=True)
class Range:
    """The valid values of a numeric key: lo <= v <= hi (or < where open); `None` = unbounded."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def contains(self, v: float) -> bool:
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return False
        return not (self.hi is not None and (v >= self.hi if self.hi_open else v > self.hi))

    def describe(self) -> str:
        lo = "-inf" if self.lo is None else _num_text(self.lo)
        hi = "inf" if self.hi is None else _num_text(self.hi)
        return f"{'(' if self.lo_open or self.lo is None else '['}{lo}, {hi}{')' if self.hi_open or self.hi is None else ']'}"


def _num_text(x: float) -> str:
    """1000000 (not 1e+06) for whole numbers a reader types, %g otherwise."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e16 else f"{x:g}"


def check_stored(schema: type, values: object, where: str) -> None:
    """The ranged keys of `schema` in a stored config (run.json's `config`): numbers of the right kind inside
    their range, so a hand-edited file cannot ask for 10**12 bootstrap resamples (ConfigError naming file and key)."""
    if not isinstance(values, dict):
        return
    for f in dataclasses.fields(schema):
        rng = f.metadata.get("range")
        if rng is None or f.name not in values:
            continue
        v = values[f.name]
        whole = f.type in ("int", int)
        if (
            isinstance(v, bool)
            or not isinstance(v, (int, float))
            or (whole and isinstance(v, float) and not v.is_integer())
        ):
            raise ConfigError(
                f"{where}: config.{f.name}={v!r} is not {'a whole' if whole else 'a'} number; valid: {rng.describe()}"
            )
        check_number(f"{where}: config.{f.name}", v, rng)


def ranged(
    default: T, lo: float | None = None, hi: float | None = None, *, lo_open: bool = False, hi_open: bool = False
) -> T:
    """A dataclass field with a default and a valid range that `build` checks (the message names the range).

    `n_boot: int = ranged(2000, 1, MAX_N_BOOT)  # bootstrap replicates`
    """
    return dataclasses.field(default=default, metadata={"range": Range(lo, hi, lo_open, hi_open)})


def one_or_more(default: T | None = None) -> T | None:
    """A list field that also takes one bare value, which `build` reads as a list of one (`state=q` is `state=[q]`).

    `state: Optional[list[str]] = one_or_more()  # columns of observation.state`
    """
    return dataclasses.field(default=default, metadata={"bare": True})


def check_number(key: str, value: object, rng: Range | None = None) -> None:
    """One numeric value of `key`: finite, inside the int64 range, inside `rng` (ConfigError naming the key)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(
            f"{key}={value}: not a finite number" + (f"; valid: {rng.describe()}" if rng is not None else "")
        )
    if isinstance(value, int) and abs(value) > MAX_INT:
        raise ConfigError(
            f"{key}={value}: out of range; integers are at most 2**63-1"
            + (f" (valid: {rng.describe()})" if rng is not None else "")
        )
    if rng is not None and not rng.contains(value):
        raise ConfigError(
            f"{key}={value if isinstance(value, int) else format(value, 'g')}: must be in {rng.describe()}"
        )


def check_values(key: str, value: object, rng: Range | None = None, depth: int = 0) -> None:
    """Every number inside `value` (lists, dicts) finite and in range; strings free of control characters."""
    if depth > 20:
        raise ConfigError(f"{key}: nested too deeply")
    if isinstance(value, str):
        if CONTROL_CHARS.search(value):
            raise ConfigError(f"{key}={value!r}: contains a control character; give printable text")
    elif isinstance(value, dict):
        for k, v in value.items():
            check_values(f"{key}.{k}", v, rng, depth + 1)
    elif isinstance(value, (list, tuple)):
        for v in value:
            check_values(key, v, rng, depth + 1)
    else:
        check_number(key, value, rng)


def _is_selection(f: dataclasses.Field[object]) -> bool:
    """An `Optional[list[...]] = None` key: None means "all", so an empty list is a mistake, not "none"."""
    if f.default is not None:
        return False
    tp = f.type if not isinstance(f.type, str) else f.type.replace(" ", "")
    if isinstance(tp, str):
        return tp.startswith(("Optional[list[", "Optional[List[")) or (tp.startswith("list[") and tp.endswith("|None"))
    args = typing.get_args(tp)
    return any(typing.get_origin(a) is list for a in args)


def validate(obj: object, prefix: str = "") -> None:
    """Check a built config (a dataclass instance): numbers finite and inside their field's range, no control
    characters, no empty selection list (`robots=[]`). ConfigError naming the key on the first problem."""
    if not dataclasses.is_dataclass(obj) or isinstance(obj, type):
        raise TypeError(f"validate: a {type(obj).__name__} is not a dataclass instance")
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        key = prefix + f.name
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            validate(v, key + ".")
            continue
        if isinstance(v, (list, tuple)) and not v and _is_selection(f):
            raise ConfigError(f"{key}=[] selects nothing; leave {key} out for all, or list at least one")
        check_values(key, v, f.metadata.get("range"))


def split_args(argv: Iterable[str]) -> tuple[list[str], list[str]]:
    """Split argv into positional arguments and `key=value` overrides (in order)."""
    positional, overrides = [], []
    for arg in argv:
        if "=" in arg and not arg.startswith("="):
            overrides.append(arg)
        else:
            positional.append(arg)
    return positional, overrides


def build_from_argv(cls: type[T], argv: Iterable[str], command: str) -> T:
    """`key=value` arguments of a command that takes no positional ones -> a frozen `cls` (ConfigError if not)."""
    positional, overrides = split_args(argv)
    if positional:
        raise ConfigError(
            f"unexpected argument {positional[0]!r}; {command} takes key=value only (see {command} --help)"
        )
    return build(cls, overrides)


# the sub-key a bare list value means, where it is not `levels` (`perturb.combine=[a,b]` is `perturb.combine.axes=`)
LIST_SUBKEY = {"combine": "axes"}


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
        if not _KEY.fullmatch(item.split("=", 1)[0]):
            raise ConfigError(
                f"key {item.split('=', 1)[0][:60]!r} is not a key name (letters, digits, _ and dotted "
                f"parts) ({context})"
            )
        key = top_key(item)
        if key not in claimed:
            listing = "; ".join(f"{name}: {', '.join(keys) or '(none)'}" for name, keys in owners.items())
            raise ConfigError(f"unknown key {key!r} ({context}); valid keys — {listing}.{did_you_mean(key, claimed)}")
        out[claimed[key]].append(item)
    return out


def _first_line(exc: BaseException) -> str:
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    return lines[0] if lines else type(exc).__name__


def check_overrides(overrides: list[str], schema: type | None) -> None:
    """Each `key=value` on its own: a key, a value, text that parses (YAML list syntax, quotes),
    nothing given twice. The error names the key (`robots=[Panda` -> robots: ...)."""
    from omegaconf import OmegaConf  # omegaconf: loaded only when key=value arguments are parsed

    valid = f"; valid keys: {', '.join(_fields(schema))}" if schema is not None else ""
    keys = []
    for item in overrides:
        key, _, value = item.partition("=")
        if "=" not in item or not key:
            raise ConfigError(f"argument {item!r} is not key=value{valid}")
        if not _KEY.fullmatch(key):
            raise ConfigError(f"key {key[:60]!r} is not a key name (letters, digits, _ and dotted parts){valid}")
        if CONTROL_CHARS.search(item):
            raise ConfigError(f"{key}={value!r}: contains a control character; give printable text")
        if not value.strip():
            raise ConfigError(f"{key}= has no value; give one or leave {key} out")
        try:
            OmegaConf.to_container(OmegaConf.from_dotlist([item]), resolve=False)
        except Exception as exc:  # YAML / grammar errors of this one value
            raise ConfigError(
                f"{key}={value}: cannot parse the value ({_first_line(exc)}); lists are "
                "written [a,b], text with , [ ] { } or : in quotes"
            ) from None
        keys.append(key)
    twice = next((k for i, k in enumerate(keys) if k in keys[:i]), None)
    if twice is not None:
        given = [item for item in overrides if item.split("=", 1)[0] == twice]
        raise ConfigError(f"key {twice!r} is given twice ({' and '.join(given)}); give it once")


def _bare_as_list(schema: type, overrides: list[str]) -> list[str]:
    """`key=v` -> `key=[v]` for the `one_or_more` fields of `schema` given one bare (scalar) value."""
    bare = {f.name for f in dataclasses.fields(schema) if f.metadata.get("bare")}
    out = []
    for item in overrides:
        key, _, value = item.partition("=")
        scalar = not value.lstrip().startswith(("[", "{"))  # a list is kept, a mapping refused by the type
        out.append(f"{key}=[{value}]" if key in bare and scalar else item)
    return out


def _fields(schema: type) -> list[str]:
    return [f.name for f in dataclasses.fields(schema)]


def build(schema: type[T], overrides: Iterable[str], *, base: Mapping[str, object] | None = None) -> T:
    """Merge `key=value` overrides onto the dataclass `schema` and return a frozen instance.

    Args:
        schema: a (frozen) dataclass whose fields have defaults and type hints.
        overrides: strings like `episodes=10`, `robots=[UR5e,IIWA]`, `perturb.friction=[0.5,1]`.
        base: optional values applied before the overrides (e.g. a stored config).
    """
    from omegaconf import OmegaConf  # omegaconf: loaded only when key=value arguments are parsed
    from omegaconf.errors import (  # omegaconf: loaded only when key=value arguments are parsed
        ConfigKeyError,
        MissingMandatoryValue,
        OmegaConfBaseException,
        ValidationError,
    )

    given = list(overrides)
    check_overrides(given, schema)
    overrides = _bare_as_list(schema, given)
    keys = [item.split("=", 1)[0] for item in overrides]
    for key in keys:  # `a.b=[1,2] a.b.c=x`: OmegaConf fails with a bare ValueError
        child = next((k for k in keys if k.startswith(key + ".")), None)
        if child:
            listed = LIST_SUBKEY.get(key.rsplit(".", 1)[-1], "levels")  # the sub-key a bare list stands for
            raise ConfigError(
                f"{key} is set to a value and also given the sub-key {child}; "
                f"give every part as a sub-key instead (e.g. {key}.{listed}=[...] {child}=...)"
            )
    try:
        cfg = OmegaConf.structured(schema)
        if base:
            cfg = OmegaConf.merge(cfg, base)
        cfg = OmegaConf.merge(cfg, OmegaConf.from_dotlist(overrides))
        out = OmegaConf.to_object(cfg)
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
        raise ConfigError(f"cannot parse overrides: {_first_line(exc)}") from None
    except (ValueError, TypeError) as exc:  # a value OmegaConf's own converters refuse
        raise ConfigError(f"bad value in {' '.join(given) or 'the options'}: {_first_line(exc)}") from None
    if not isinstance(out, schema):  # OmegaConf builds the structured config's own class
        raise TypeError(f"build: OmegaConf returned a {type(out).__name__}, not a {schema.__name__}")
    validate(out)
    return out


def _field_lines(source: str) -> list[str]:
    """The source's lines, a field wrapped over several lines (`x: int = ranged(\n ...\n)  # doc`) joined into one:
    its code, then its comments (`  # ...`)."""
    out: list[tuple[str, list[str]]] = []
    depth = 0
    for raw in source.splitlines():
        code, hash_, comment = raw.strip().partition("#")
        if depth > 0:
            out[-1] = (f"{out[-1][0]} {code.strip()}", out[-1][1])
        else:
            out.append((code.strip(), []))
        if hash_ and comment.strip():
            out[-1][1].append(comment.strip())
        depth += code.count("(") + code.count("[") - code.count(")") - code.count("]")
        depth = max(depth, 0)
    return [f"{code}  # {' '.join(comments)}" if comments else code for code, comments in out]


def key_help(schema: type, keys: Iterable[str] | None = None) -> str:
    """One line per key of `schema`: its name, its default, and the comment beside it in the source of the class
    that declares it (inherited fields included).

    Commands build their `--help` key list from their config dataclass with this, so the help cannot drift from
    the keys that are actually accepted. `keys`: the keys to list, from their owner (e.g.
    `bench.protocols.option_keys`, which `bench list` prints too); default every field, in declaration order.
    """
    docs = field_docs(schema)
    fields = {f.name: f for f in dataclasses.fields(schema)}
    rows = []
    for name in fields if keys is None else keys:
        f = fields[name]
        if f.default is not dataclasses.MISSING:
            d = f.default
        elif f.default_factory is not dataclasses.MISSING:
            d = f.default_factory()
        else:
            rows.append((f.name + " (required)", docs.get(f.name, "")))
            continue
        shown = "" if d is None or d == {} else f"={str(d).lower() if isinstance(d, bool) else d}"
        rows.append((f.name + shown, docs.get(f.name, "")))
    width = max((len(k) for k, _ in rows), default=0) + 2
    return "\n".join(f"  {k:<{width}}{doc}".rstrip() for k, doc in rows)


def field_docs(schema: type) -> dict[str, str]:
    """Field name -> the comment beside it, read from the source of `schema` and of the dataclasses it extends
    (a subclass's comment wins); a class whose source cannot be read (made at run time) gives none."""
    docs: dict[str, str] = {}
    for cls in reversed(schema.__mro__):
        if not dataclasses.is_dataclass(cls):
            continue
        names = {f.name for f in dataclasses.fields(cls)}
        try:
            source = inspect.getsource(cls)
        except (OSError, TypeError):
            continue
        for line in _field_lines(source):
            m = re.match(r"^(\w+)\s*:[^#]*#\s*(.*)$", line)
            if m and m.group(1) in names:
                docs[m.group(1)] = m.group(2)
    return docs


def command_help(
    usage: str, about: str, schema: type | None = None, examples: Iterable[str] = (), notes: str = ""
) -> str:
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

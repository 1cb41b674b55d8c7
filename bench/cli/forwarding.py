"""The key split of commands that run `bench run` underneath (`bench regress`, `bench compare`): each
`key=value` is the command's own (a field of its config), a forbidden run key (the command sets it), or a
`bench run` key (the runner's or the suite's), forwarded verbatim; anything else is refused with one line."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields

from bench.api import RUNNER_KEYS, RunConfig
from bench.api.plugins import option_keys, suite_options_type
from bench.core import config as config_mod
from bench.core.errors import ConfigError, did_you_mean


def split_keys(
    argv: list[str], own_type: type, forbidden: Mapping[str, str | None], command: str
) -> tuple[list[str], list[str], dict[str, str]]:
    """(the command's own overrides, the forwarded `bench run` overrides, those by top key).

    `forbidden` maps a run key the command sets itself to the key to use instead (None: no hint)."""
    positional, overrides = config_mod.split_args(argv)
    if positional:
        raise ConfigError(
            f"unexpected argument {positional[0]!r}; bench {command} takes key=value only (see bench {command} --help)"
        )
    own_names = {f.name for f in fields(own_type)}
    suite = config_mod.build(RunConfig, [o for o in overrides if config_mod.top_key(o) == "suite"]).suite
    run_names = set(RUNNER_KEYS) | set(option_keys(suite_options_type(suite)))
    own: list[str] = []
    forwarded: list[str] = []
    by_key: dict[str, str] = {}
    for item in overrides:
        key = item.split("=", 1)[0]
        top = key.split(".")[0]
        if top in own_names:
            own.append(item)
        elif top in forbidden:
            hint = f"; use {forbidden[top]}" if forbidden[top] else ""
            raise ConfigError(f"key {top!r} is not valid for bench {command}{hint}")
        elif top in run_names:
            forwarded.append(item)
            by_key[top] = item
        else:
            valid = sorted(own_names | (run_names - set(forbidden) - {"out", "run_id"}))
            raise ConfigError(f"unknown key {key!r}; valid keys: {', '.join(valid)}.{did_you_mean(top, valid)}")
    return own, forwarded, by_key

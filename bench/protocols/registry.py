"""Suites and policies by name (entry points) or by import path (`package.module:attr`).

The built-ins register through our own pyproject (groups `bench.suites`, `bench.policies`)
exactly as third-party packages do, so there is one mechanism. Entry points are strings
imported only when used; a miss lists what exists and suggests the closest name. Two
distributions registering one name, or a suite whose `name` differs from its entry-point
name, is an error, not a silent skip. A reference with a colon (`my_pkg.suites:MySuite`)
imports the module directly, from the current folder too, so an out-of-tree plugin runs
without packaging.
"""

from __future__ import annotations

import functools
import importlib
import os
import sys
from importlib.metadata import EntryPoint, entry_points
from types import ModuleType
from typing import Any

from bench.core.errors import RegistryError, did_you_mean
from bench.protocols import FactoryPlugin, PolicyPlugin, Suite

SUITES = "bench.suites"
POLICIES = "bench.policies"


@functools.cache
def _installed(group: str) -> tuple[EntryPoint, ...]:
    """The group's entry points, read once per process: scanning every installed distribution's metadata
    takes ~2 ms, and a policy server resolves its client's suite at every episode reset."""
    return tuple(entry_points(group=group))


def group_entry_points(group: str) -> dict[str, EntryPoint]:
    found: dict[str, EntryPoint] = {}
    for ep in _installed(group):
        if ep.name in found and found[ep.name].value != ep.value:
            raise RegistryError(
                f"{group}: name {ep.name!r} is registered twice ({found[ep.name].value} and {ep.value}); "
                "uninstall one of the packages"
            )
        found[ep.name] = ep
    return found


def names(group: str) -> list[str]:
    """Registered names in an entry-point group, sorted."""
    return sorted(group_entry_points(group))


def import_module(module_name: str, kind: str) -> ModuleType:
    """Import `module_name`, searching the current folder too (as `python -m` does).

    So `suite=tests.toy_suite:ToySuite` works from the checkout; worker processes inherit the
    search path. A failure is a one-line RegistryError naming `kind` (the key that asked).
    """
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if os.getcwd() not in sys.path:  # the plugin, or a module it imports, may live in the current folder
            sys.path.insert(0, os.getcwd())
            return import_module(module_name, kind)
        raise RegistryError(f"{kind}: cannot import {module_name!r} ({type(exc).__name__}: {exc})") from None
    except Exception as exc:  # a broken plugin must say which one, not vanish
        raise RegistryError(f"{kind}: importing {module_name!r} failed: {type(exc).__name__}: {exc}") from exc


def import_ref(ref: str, kind: str) -> Any:
    """The attribute `attr` of `package.module` for a reference `package.module:attr`.

    Untyped: a plugin's object, whatever its module holds; `suite_class` and `load_policy` check what they use."""
    module_name, _, attr = ref.partition(":")
    if not module_name or not attr:
        raise RegistryError(f"{kind}={ref!r}: write package.module:attr, e.g. {kind}=my_pkg.plugins:Thing")
    module = import_module(module_name, f"{kind}={ref!r}")
    try:
        return getattr(module, attr)
    except AttributeError:
        valid = [n for n in dir(module) if not n.startswith("_")]
        raise RegistryError(
            f"{kind}={ref!r}: module {module_name!r} has no {attr!r}.{did_you_mean(attr, valid)}"
        ) from None


def _load(group: str, name: str, kind: str) -> Any:
    if ":" in name:
        return import_ref(name, kind)
    eps = group_entry_points(group)
    if name not in eps:
        valid = sorted(eps)
        raise RegistryError(
            f"{kind}={name!r} is not registered; valid: {', '.join(valid) or '(none: is the package installed?)'}"
            f" (or {kind}=package.module:attr).{did_you_mean(name, valid)}"
        )
    try:
        return eps[name].load()
    except Exception as exc:  # a broken plugin must say which one, not vanish
        raise RegistryError(f"{kind}={name!r}: loading {eps[name].value} failed: {type(exc).__name__}: {exc}") from exc


def suite_class(ref: str) -> type[Suite]:
    """The suite class registered under `ref`, or imported from `package.module:Class`."""
    cls = _load(SUITES, ref, "suite")
    if not isinstance(cls, type):
        raise RegistryError(f"suite={ref!r}: {cls!r} is not a class")
    declared = getattr(cls, "name", None)
    if ":" not in ref and declared != ref:
        raise RegistryError(
            f"suite={ref!r}: the entry point loads {cls.__module__}.{cls.__name__}, whose name is "
            f"{declared!r}; an entry-point name must equal its Suite.name"
        )
    return cls


def make_suite(ref: str, options: Any = None) -> Suite:  # options: the suite's own Options instance
    """The suite `ref` built with `options` (an instance of its Options; None = the defaults)."""
    return suite_class(ref)(options)


def load_policy(ref: str) -> PolicyPlugin:
    """The policy plugin registered under `ref` (or `package.module:attr`).

    A `PolicyPlugin` subclass is instantiated; any other callable is taken as a factory
    `f(cell, env, ctx) -> Policy` (`FactoryPlugin`).
    """
    obj = _load(POLICIES, ref, "policy")
    if isinstance(obj, type) and issubclass(obj, PolicyPlugin):
        return obj()
    if isinstance(obj, PolicyPlugin):
        return obj
    if callable(obj):
        return FactoryPlugin(obj)
    raise RegistryError(f"policy={ref!r}: {obj!r} is neither a PolicyPlugin nor a factory function")

"""Suites and policies by name, through entry points (groups `bench.suites`, `bench.policies`).

The built-ins register through our own pyproject exactly as third-party packages do,
so there is one mechanism. Entry points are strings ("pkg.module:attr") imported only
when a suite or policy is made; a miss lists what exists and suggests the closest name.
Two distributions registering the same name is an error, not a silent skip.
"""
from __future__ import annotations

import time
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from bench.errors import RegistryError, did_you_mean

SUITES = "bench.suites"
POLICIES = "bench.policies"


def _group(group: str) -> dict[str, EntryPoint]:
    found: dict[str, EntryPoint] = {}
    for ep in entry_points(group=group):
        if ep.name in found and found[ep.name].value != ep.value:
            raise RegistryError(
                f"{group}: name {ep.name!r} is registered twice ({found[ep.name].value} and {ep.value}); "
                "uninstall one of the packages"
            )
        found[ep.name] = ep
    return found


def names(group: str) -> list[str]:
    """Registered names in an entry-point group, sorted."""
    return sorted(_group(group))


def _load(group: str, name: str, kind: str) -> Any:
    eps = _group(group)
    if name not in eps:
        valid = sorted(eps)
        raise RegistryError(
            f"{kind}={name!r} is not registered; valid: {', '.join(valid) or '(none: is the package installed?)'}."
            f"{did_you_mean(name, valid)}"
        )
    try:
        return eps[name].load()
    except Exception as exc:  # a broken plugin must say which one, not vanish
        raise RegistryError(f"{kind}={name!r}: loading {eps[name].value} failed: {type(exc).__name__}: {exc}") from exc


def make_suite(name: str):
    """Instantiate the suite registered under `name`."""
    return _load(SUITES, name, "suite")()


def policy_factory(name: str):
    """The factory `make(cell, env, cfg) -> policy` registered under `name`."""
    return _load(POLICIES, name, "policy")


def main_list(argv: list[str]) -> int:
    """`bench list`: registered suites with their manifests, and policies."""
    if argv and argv[0] in ("-h", "--help"):
        print("usage: bench list\n\nPrints the registered suites (entry points `bench.suites`) with their seen/unseen\n"
              "split manifest, and the registered policies (`bench.policies`).")
        return 0
    t0 = time.perf_counter()
    print("suites:")
    for name in names(SUITES):
        suite = make_suite(name)
        print(f"  {name} (v{suite.version}, reference policy: {suite.reference_policy}) — {suite.summary_line()}")
        for axis, split in suite.manifest.items():
            for side in ("seen", "unseen"):
                vals = split.get(side, [])
                if vals:
                    print(f"      {axis:<7} {side:<6} {', '.join(map(str, vals))}")
    print("policies:")
    for name, ep in sorted(_group(POLICIES).items()):
        print(f"  {name:<11} {ep.value}")
    print(f"({(time.perf_counter() - t0) * 1000:.0f} ms)")
    return 0

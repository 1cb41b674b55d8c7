"""`bench list`: the registered suites (with their seen/unseen manifests) and policies."""

from __future__ import annotations

import time

from bench.api import RegistryError
from bench.api.plugins import list_plugins
from bench.core.config import command_help


def main_list(argv: list[str]) -> int:
    """`bench list`: registered suites with their manifests and keys, and policies."""
    if argv and argv[0] not in ("-h", "--help"):
        raise RegistryError(f"bench list takes no arguments; got {argv[0]!r} (bench list --help)")
    if argv:
        print(
            command_help(
                "usage: bench list",
                "Prints the registered suites (entry points `bench.suites`) with their seen/unseen split\n"
                "manifest and their own keys, and the registered policies (`bench.policies`).\n"
                "Out-of-tree plugins need no registration: suite=package.module:Class, "
                "policy=package.module:attr.",
            ),
            end="",
        )
        return 0

    t0 = time.perf_counter()
    found = list_plugins()
    print("suites:")
    for s in found.suites:
        if s.error is not None:
            print(f"  {s.name}: unavailable — {s.error}")
            continue
        policies = (
            f"default policy: {s.default_policy}"
            if s.default_policy == s.reference_policy
            else f"default policy: {s.default_policy}, reference policy: {s.reference_policy}"
        )
        print(
            f"  {s.name} (v{s.version}, {policies}) — {s.summary}"
            + (f" [keys: {', '.join(s.keys)}]" if s.keys else "")
            + (f"\n      unavailable: {s.unavailable}" if s.unavailable else "")
        )
        for axis, split in s.manifest.items():
            for side in ("seen", "unseen"):
                vals = split.get(side, [])
                if vals:
                    print(f"      {axis:<7} {side:<6} {', '.join(map(str, vals))}")
    print("policies:")
    for name, value in found.policies:
        print(f"  {name:<11} {value}")
    print(f"({(time.perf_counter() - t0) * 1000:.0f} ms)")
    return 0

"""`bench list`: the registered suites (with their seen/unseen manifests) and policies."""

from __future__ import annotations

import time

from bench.core.config import command_help
from bench.core.errors import RegistryError
from bench.protocols import option_keys
from bench.protocols.registry import POLICIES, SUITES, group_entry_points, names, suite_class
from bench.protocols.suite import summary_line


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
    print("suites:")
    for name in names(SUITES):
        try:
            cls = suite_class(name)
        except RegistryError as exc:
            print(f"  {name}: unavailable — {exc}")
            continue
        keys = option_keys(cls.Options)
        unavailable = getattr(cls, "unavailable", None)  # SuiteBase's hook; other suites may lack it
        why = unavailable() if unavailable is not None else None
        default = getattr(cls, "default_policy", "") or cls.reference_policy  # what `bench run` runs without policy=
        policies = (
            f"default policy: {default}"
            if default == cls.reference_policy
            else f"default policy: {default}, reference policy: {cls.reference_policy}"
        )
        print(
            f"  {name} (v{cls.version}, {policies}) — {summary_line(cls)}"
            + (f" [keys: {', '.join(keys)}]" if keys else "")
            + (f"\n      unavailable: {why}" if why else "")
        )
        for axis, split in cls.manifest.items():
            for side in ("seen", "unseen"):
                vals = split.get(side, [])
                if vals:
                    print(f"      {axis:<7} {side:<6} {', '.join(map(str, vals))}")
    print("policies:")
    for name, ep in sorted(group_entry_points(POLICIES).items()):
        print(f"  {name:<11} {ep.value}")
    print(f"({(time.perf_counter() - t0) * 1000:.0f} ms)")
    return 0

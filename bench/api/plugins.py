"""The registered plugins and their keys: what `bench list` prints, what `bench run --help` lists, and the
Options types the commands that take a suite's or a policy's own keys (`check`, `serve`, `actions`,
`regress`) type those keys with.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from bench.core.errors import RegistryError
from bench.protocols import option_keys, registry
from bench.protocols.registry import POLICIES, SUITES
from bench.protocols.suite import policy_ref, summary_line
from bench.sims.perturb.axes import axes_help

__all__ = [
    "PluginKeys",
    "Plugins",
    "SuiteEntry",
    "axes_help",
    "list_plugins",
    "option_keys",
    "plugin_keys",
    "policy_for",
    "policy_options_type",
    "suite_options_type",
]


@dataclass(frozen=True)
class SuiteEntry:
    """A registered suite as `bench list` shows it, or why it cannot be loaded (`error`)."""

    name: str
    error: str | None = None  # the RegistryError of a suite that cannot be loaded (the rest is then empty)
    version: str = ""
    default_policy: str = ""  # what `bench run` runs without policy=
    reference_policy: str = ""  # the suite's expert
    summary: str = ""  # the first line of its docstring
    keys: list[str] = field(default_factory=list)  # its own key=value keys
    unavailable: str | None = None  # why it cannot run here (a missing simulator), from `unavailable()`
    manifest: Mapping[str, Mapping[str, Sequence[str]]] = field(default_factory=dict)  # axis -> seen/unseen


@dataclass(frozen=True)
class Plugins:
    """What is registered: the suites (entry points `bench.suites`) and the policies (`bench.policies`)."""

    suites: list[SuiteEntry]
    policies: list[tuple[str, str]]  # (name, package.module:attr), sorted by name


@dataclass(frozen=True)
class PluginKeys:
    """The own keys of one plugin of a run: `owner` is "suite NAME" or "policy NAME"."""

    owner: str
    schema: type  # its Options dataclass
    keys: list[str]


def list_plugins() -> Plugins:
    """`bench list`: the registered suites (manifest, keys, default policy, availability) and policies."""
    suites = []
    for name in registry.names(SUITES):
        try:
            cls = registry.suite_class(name)
        except RegistryError as exc:
            suites.append(SuiteEntry(name, error=str(exc)))
            continue
        unavailable = getattr(cls, "unavailable", None)  # SuiteBase's hook; other suites may lack it
        suites.append(
            SuiteEntry(
                name,
                version=cls.version,
                default_policy=getattr(cls, "default_policy", "") or cls.reference_policy,
                reference_policy=cls.reference_policy,
                summary=summary_line(cls),
                keys=option_keys(cls.Options),
                unavailable=unavailable() if unavailable is not None else None,
                manifest=cls.manifest,
            )
        )
    policies = [(name, ep.value) for name, ep in sorted(registry.group_entry_points(POLICIES).items())]
    return Plugins(suites, policies)


def suite_options_type(ref: str) -> type:
    """The Options dataclass of suite `ref` (registered name or package.module:Class): its own keys."""
    return registry.suite_class(ref).Options


def policy_options_type(ref: str) -> type:
    """The Options dataclass of policy `ref` (registered name or package.module:attr): its own keys."""
    options: type = registry.load_policy(ref).Options
    return options


def policy_for(suite: str, policy: str | None = None) -> str:
    """The policy `bench run suite=SUITE` runs: `policy`, else the suite's default policy."""
    return policy_ref(registry.suite_class(suite), policy)


def plugin_keys(suite: str, policy: str | None = None) -> list[PluginKeys]:
    """The own keys of `bench run suite=SUITE policy=POLICY`'s suite and policy (POLICY None: the suite's default)."""
    suite_cls = registry.suite_class(suite)
    ref = policy_ref(suite_cls, policy)
    plugin = registry.load_policy(ref)
    return [
        PluginKeys(f"suite {suite}", suite_cls.Options, option_keys(suite_cls.Options)),
        PluginKeys(f"policy {ref}", plugin.Options, option_keys(plugin.Options)),
    ]

"""Registry: entry points, lazy imports, misses with suggestions."""

import subprocess
import sys

import pytest

from bench.core.errors import RegistryError
from bench.protocols import registry


def test_builtins_registered_through_entry_points():
    assert "held_out_robots" in registry.names(registry.SUITES)
    assert {"random", "scripted"} <= set(registry.names(registry.POLICIES))


@pytest.mark.parametrize("name", registry.names(registry.SUITES))
def test_every_suite_declares_identity(name):
    cls = registry.suite_class(name)  # entry-point name == Suite.name is checked here
    assert cls.name == name and cls.version
    for axis, split in cls.manifest.items():
        assert not set(split.get("seen", [])) & set(split.get("unseen", [])), axis


def test_suite_miss_lists_valid_names():
    with pytest.raises(
        RegistryError,
        match=r"suite='held_out_robts' is not registered; valid: .*held_out_robots.*"
        r"Did you mean 'held_out_robots'\?",
    ):
        registry.make_suite("held_out_robts")


def test_policy_miss():
    with pytest.raises(RegistryError, match="policy='nope' is not registered"):
        registry.load_policy("nope")
    with pytest.raises(RegistryError, match=r"policy='bench.nope:x': cannot import 'bench.nope'"):
        registry.load_policy("bench.nope:x")
    with pytest.raises(RegistryError, match=r"policy='tests.toy_suite:nope': module 'tests.toy_suite' has no 'nope'"):
        registry.load_policy("tests.toy_suite:nope")


def test_list_imports_no_simulator():
    code = (
        "import sys; from bench.cli import main; main(['list']); "
        "heavy = [m for m in ('robosuite', 'metaworld', 'mujoco', 'torch', 'sapien', 'mani_skill') if m in sys.modules]; "
        "print('HEAVY', heavy)"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "held_out_robots" in res.stdout and "seen" in res.stdout
    assert "HEAVY []" in res.stdout

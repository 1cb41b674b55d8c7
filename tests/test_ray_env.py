"""What Ray workers are given (ray_env=code|pip|installed) and how their versions are compared.

No cluster here: these build the runtime env and compare version reports (the cluster tests,
tests/test_ray_executor.py, run them for real)."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.core import provenance
from bench.core.errors import ConfigError
from bench.execution import ray_env

REPO = Path(__file__).resolve().parents[1]


def test_code_ships_the_project_its_entry_points_and_an_out_of_tree_plugin():
    env = ray_env.runtime_env("code", "tests.toy_suite:ToySuite", "scripted")
    paths = [Path(p) for p in env["py_modules"]]
    names = [p.name for p in paths]
    assert {"bench", "suites", "baselines", "tests"} <= set(names)
    assert any(n.startswith("bench_harness") and n.endswith((".dist-info", ".egg-info")) for n in names)
    assert all(p.exists() for p in paths) and (REPO / "bench") in paths
    assert env["excludes"] == ["__pycache__", "*.pyc"] and "pip" not in env


def test_an_installed_plugin_package_is_not_shipped():
    env = ray_env.runtime_env("code", "held_out_robots", "numpy.random:default_rng")
    assert "numpy" not in [Path(p).name for p in env["py_modules"]]  # under site-packages: the nodes have it


def test_pip_pins_the_drivers_versions_of_the_project_requirements():
    pytest.importorskip("packaging", reason="packaging (a dependency of ray) reads the requirement strings")
    env = ray_env.runtime_env("pip", "held_out_robots", "scripted")
    pins = env["pip"]["packages"]
    mine = provenance.package_versions()
    for name in ("numpy", "mujoco", "robosuite", "scipy"):
        assert f"{name}=={mine[name]}" in pins
    assert any(p.startswith("rich") for p in pins)  # unpinned requirements keep their specifier
    assert not any(p.startswith("bench-harness") for p in pins) and env["py_modules"]


def test_installed_ships_nothing_and_extra_fields_merge(monkeypatch):
    for name in ray_env.PASS_ENV:  # other tests' imports set some of them (e.g. ManiSkill's prompt switch)
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("MUJOCO_GL", "egl")
    env = ray_env.runtime_env(
        "installed", "held_out_robots", "scripted", {"env_vars": {"OMP_NUM_THREADS": "1"}, "container": {"image": "x"}}
    )
    assert env == {"env_vars": {"MUJOCO_GL": "egl", "OMP_NUM_THREADS": "1"}, "container": {"image": "x"}}
    with pytest.raises(ConfigError, match="ray_env='conda': valid: code, pip, installed"):
        ray_env.runtime_env("conda", "held_out_robots", "scripted")


def test_version_mismatch_names_the_first_difference_in_one_line():
    me = {"python": "3.11", "packages": {"mujoco": "3.3.0", "numpy": "1.26.4"}}
    assert ray_env.version_mismatch(me, me, "node a") is None
    other = {"python": "3.11", "packages": {"mujoco": "3.3.2", "numpy": "1.26.4"}}
    assert ray_env.version_mismatch(me, other, "pid 7 on node a") == (
        "the cluster has mujoco 3.3.2 (pid 7 on node a), this driver 3.3.0; install the same versions on every "
        "node (ray_env=pip installs this driver's, docs/ray.md)"
    )
    missing = {"python": "3.11", "packages": {"numpy": "1.26.4"}}
    assert "the cluster has mujoco (not installed)" in ray_env.version_mismatch(me, missing, "n")
    assert ray_env.version_mismatch(me, {**me, "python": "3.10"}, "n").startswith(
        "the cluster runs Python 3.10 (n), this driver Python 3.11"
    )


@pytest.mark.parametrize("address", ["auto", "local", "10.0.0.5:6379", "head.cluster:6379", "[::1]:6379"])
def test_addresses_that_are_accepted(address):
    ray_env.check_address(address)


@pytest.mark.parametrize("address", ["10.0.0.5", "head:port", "head:70000", ":6379", "ray://head:10001"])
def test_addresses_that_are_refused(address):
    with pytest.raises(ConfigError, match=f"ray_address='{address}': give auto, local or HOST:PORT"):
        ray_env.check_address(address)

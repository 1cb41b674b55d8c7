"""What a Ray cluster needs to run a plan like this machine does: connection, runtime env, version check.

- `connect` joins the cluster at `ray_address` (`auto`, `HOST:PORT`, or `local` for a private
  one-machine cluster) and turns every way that fails into one line: Ray missing (the install
  command), nothing listening at the address (checked with a plain TCP connect first, since
  `ray.init` retries for minutes), Ray's own version check.
- `runtime_env` is what every actor gets, by `ray_env=`: `code` ships this checkout's
  packages (bench, suites, baselines, their entry points, and an out-of-tree suite or policy
  package) through the cluster's object store; `pip` also pip-installs the driver's versions
  of the project's requirements into a per-job virtualenv on each node; `installed` ships
  nothing (the nodes run an image or a shared environment that has the project).
- `version_mismatch` compares an actor's Python and package versions with the driver's
  (`bench.core.provenance.package_versions`): records carry the driver's versions, so a worker
  that differs would mislabel them.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import socket
import subprocess
import sys
from collections.abc import Mapping
from importlib.metadata import PackageNotFoundError, distribution, entry_points, requires
from pathlib import Path
from types import ModuleType
from typing import TypedDict

from packaging.requirements import Requirement

from bench.core import provenance
from bench.core.errors import ConfigError, ExecutorError

INSTALL = "pip install 'bench-harness[ray]' (in a checkout: pip install -e '.[ray]')"
RAY_ENVS = ("code", "pip", "installed")
PROJECT_PACKAGES = ("bench", "suites", "baselines")
DIST = "bench-harness"
# driver environment variables that change what a worker computes or renders; passed to every actor
PASS_ENV = ("MUJOCO_GL", "PYOPENGL_PLATFORM", "MUJOCO_EGL_DEVICE_ID", "MS_SKIP_ASSET_DOWNLOAD_PROMPT")
PROBE_TIMEOUT_S = 5.0  # TCP connect to the head
GCS_PROBE_S = 20.0  # the head's GCS answering (so a wrong address costs at most ~25 s, not minutes)


def import_ray() -> ModuleType:
    """The `ray` module, or a one-line error with the install command."""
    try:
        import ray  # the ray extra: loaded only for executor=ray
    except ImportError:
        raise ExecutorError(f"executor=ray needs Ray, which is not installed here: {INSTALL}") from None
    return ray


def ray_installed() -> bool:
    return importlib.util.find_spec("ray") is not None


def check_address(address: str) -> None:
    """Refuse a malformed `ray_address` (before anything is written)."""
    if address in ("auto", "local"):
        return
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536 or "/" in address:
        raise ConfigError(
            f"ray_address={address!r}: give auto, local or HOST:PORT (e.g. 10.0.0.5:6379, "
            "the head's `ray start --head --port=6379`)"
        )


def _bootstrap(ray: ModuleType, address: str) -> str:
    """host:port Ray will dial for `address` (auto: RAY_ADDRESS or the cluster `ray start` made here)."""
    from ray._private import services  # the same resolution ray.init does

    try:
        found = services.canonicalize_bootstrap_address(address)
    except ConnectionError:
        found = None
    if not found:
        raise ExecutorError(
            "ray_address=auto: no Ray cluster is running on this machine (none started with "
            "`ray start --head`, no RAY_ADDRESS); give ray_address=HOST:PORT or ray_address=local"
        )
    return str(found)


def _probe(address: str, given: str) -> None:
    host, _, port = address.rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=PROBE_TIMEOUT_S):
            pass
    except OSError as exc:
        raise ExecutorError(
            f"ray_address={given}: no Ray cluster answers at {address} "
            f"({exc.strerror or type(exc).__name__}); start one with `ray start --head "
            f"--port={port}` there, or give another address"
        ) from None


_GCS_PROBE = """
import sys
from ray._raylet import GcsClient
GcsClient(address=sys.argv[1]).internal_kv_get(b"bench-probe", None)
"""


def _probe_gcs(address: str, given: str) -> None:
    """Ask the GCS at `address` for its cluster id in a child process that can be stopped.

    Something other than Ray listening there would keep `ray.init` retrying for minutes.
    """
    try:
        res = subprocess.run(
            [sys.executable, "-c", _GCS_PROBE, address], capture_output=True, text=True, timeout=GCS_PROBE_S
        )
    except subprocess.TimeoutExpired:
        raise ExecutorError(
            f"ray_address={given}: something listens at {address} but no Ray GCS answered within "
            f"{GCS_PROBE_S:g} s; give the head's --port (default 6379)"
        ) from None
    if res.returncode != 0:
        lines = [ln.strip() for ln in res.stderr.splitlines() if ln.strip() and not ln.startswith((" ", "["))]
        raise ExecutorError(
            f"ray_address={given}: the Ray cluster at {address} refused this driver: "
            f"{lines[-1] if lines else 'exit code ' + str(res.returncode)}"
        )


def connect(address: str, env: Mapping[str, object] | None = None, num_cpus: int | None = None) -> bool:
    """Join the cluster at `address` with the job's runtime `env`; True when this call connected.

    A process that already called `ray.init` keeps its connection and its runtime env (False):
    `ray.shutdown` is then not ours to call.
    """
    ray = import_ray()
    if ray.is_initialized():
        return False
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    quiet: dict[str, object] = {"logging_level": logging.ERROR, "log_to_driver": False, "runtime_env": env or None}
    try:
        if address == "local":
            ray.init(address="local", num_cpus=num_cpus, _node_ip_address="127.0.0.1", include_dashboard=False, **quiet)
        else:
            target = _bootstrap(ray, address)
            _probe(target, address)
            _probe_gcs(target, address)
            ray.init(address=target, **quiet)
    except ExecutorError:
        raise
    except Exception as exc:  # Ray's own checks (its version, Python's) come as several lines: keep the first
        first = next((line.strip() for line in str(exc).splitlines() if line.strip()), type(exc).__name__)
        raise ExecutorError(f"ray_address={address}: connecting failed: {first}") from None
    return True


def _module_of(ref: str, group: str) -> str:
    """The module a suite/policy reference loads (`pkg.mod:attr`, or a registered name's entry point)."""
    if ":" in ref:
        return ref.partition(":")[0]
    found = entry_points(group=group, name=ref)
    return next(iter(found)).value.partition(":")[0] if found else ""


def _installed(path: Path) -> bool:
    return any(part in ("site-packages", "dist-packages") for part in path.parts)


def code_paths(suite_ref: str, policy_ref: str) -> list[str]:
    """Folders (or files) to ship: the project's packages and their metadata, plus a plugin's own package.

    A suite or policy whose top-level package is installed (under site-packages) must be
    installed on the cluster too; one imported from a checkout or the current folder is shipped.
    """
    paths: list[str] = []
    names = list(PROJECT_PACKAGES)
    for ref, group in ((suite_ref, "bench.suites"), (policy_ref, "bench.policies")):
        top = _module_of(ref, group).split(".")[0]
        if top and top not in names:
            names.append(top)
    for name in names:
        spec = importlib.util.find_spec(name)
        if spec is None:
            continue
        if spec.submodule_search_locations:
            path = Path(list(spec.submodule_search_locations)[0])
        elif spec.origin:
            path = Path(spec.origin)
        else:
            continue
        if name in PROJECT_PACKAGES or not _installed(path):
            paths.append(str(path))
    try:  # the project's metadata (.dist-info or .egg-info): entry points and version, as on the driver
        meta = getattr(distribution(DIST), "_path", None)  # PathDistribution's folder
        if meta is not None and Path(meta).is_dir():
            paths.append(str(meta))
    except PackageNotFoundError:
        pass
    return paths


def pins() -> list[str]:
    """The project's requirements with this driver's installed versions pinned (for ray_env=pip)."""
    mine = provenance.package_versions()
    out: dict[str, str] = {}
    for text in requires(DIST) or []:
        req = Requirement(text)
        if req.marker is not None and "extra" in str(req.marker):
            continue
        out[req.name.lower()] = str(req)
    for name, version in mine.items():
        if name != DIST:
            out[name.lower()] = f"{name}=={version}"
    return sorted(out.values())


def runtime_env(
    mode: str, suite_ref: str, policy_ref: str, extra: Mapping[str, object] | None = None
) -> dict[str, object]:
    """The runtime env each actor starts in (see the module docstring for the modes)."""
    if mode not in RAY_ENVS:
        raise ConfigError(f"ray_env={mode!r}: valid: {', '.join(RAY_ENVS)}")
    env: dict[str, object] = {}
    if mode in ("code", "pip"):
        env["py_modules"] = code_paths(suite_ref, policy_ref)
        env["excludes"] = ["__pycache__", "*.pyc"]
    if mode == "pip":
        env["pip"] = {"packages": pins(), "pip_check": False}
    env_vars = {k: os.environ[k] for k in PASS_ENV if k in os.environ}
    if env_vars:
        env["env_vars"] = env_vars
    for key, value in (extra or {}).items():
        current = env.get(key)
        if isinstance(value, dict) and isinstance(current, dict):
            env[key] = {**current, **value}
        elif isinstance(value, list) and isinstance(current, list):
            env[key] = [*current, *value]
        else:
            env[key] = value
    return env


class NodeReport(TypedDict):
    """What a process runs (`report`): Python major.minor and the result-changing package versions."""

    python: str
    packages: dict[str, str]


def report() -> NodeReport:
    """What this process runs: Python major.minor and the result-changing package versions."""
    return {"python": f"{sys.version_info[0]}.{sys.version_info[1]}", "packages": provenance.package_versions()}


def version_mismatch(driver: NodeReport, worker: NodeReport, where: str) -> str | None:
    """One line naming the first difference between a worker's `report()` and the driver's, or None."""
    if driver["python"] != worker["python"]:
        return (
            f"the cluster runs Python {worker['python']} ({where}), this driver Python {driver['python']}; "
            "use the same Python on every node"
        )
    mine, theirs = driver["packages"], worker["packages"]
    for name in sorted(set(mine) | set(theirs)):
        if mine.get(name) != theirs.get(name):
            return (
                f"the cluster has {name} {theirs.get(name) or '(not installed)'} ({where}), this driver "
                f"{mine.get(name) or '(not installed)'}; install the same versions on every node "
                "(ray_env=pip installs this driver's, docs/ray.md)"
            )
    return None

"""Real Ray clusters for tests and benchmarks, confined to the loopback address.

Ray does not stay on 127.0.0.1 by itself: it resolves `127.0.0.1` and `localhost` (also in
`--node-ip-address=127.0.0.1` and `ray.init(_node_ip_address=...)`) to the machine's
interface address and its GCS listens on every interface (measured with ray 2.60 on these
machines). So every Ray process a test starts runs inside a throwaway Linux namespace
(`unshare`: user, network, PID, mount) whose only network device is `lo`: Ray then finds
no other address, and nothing in it can reach or be reached from outside. Ray's session
files go to a tmpfs mounted over /tmp/ray in that namespace, token authentication is off
(`RAY_AUTH_MODE=disabled`: nothing but loopback exists there) so no token is written to
~/.ray, and when the namespace's first process ends the kernel kills every process left in
it: a cluster cannot outlive its test, even when the test fails or times out.

`run(argv)` runs a command in such a namespace; inside it, `Cluster` starts a head and
extra nodes (`ray start --block`, 1 CPU each by default) and kills a node's whole process
tree (raylet and its workers: what a machine failure looks like to the driver).
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
NAMESPACE = ["unshare", "--user", "--map-root-user", "--net", "--pid", "--fork", "--mount-proc", "--kill-child"]
# inside: loopback up, Ray's session files on a private tmpfs, then the command
PRELUDE = 'ip link set lo up && mkdir -p /tmp/ray && mount -t tmpfs bench-ray /tmp/ray && exec "$@"'
ENV = {"RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0", "MUJOCO_GL": "disable"}


def unavailable() -> str | None:
    """Why a loopback-only namespace cannot be made here (None when it can)."""
    if sys.platform != "linux":
        return "needs Linux namespaces (unshare)"
    for tool in ("unshare", "ip"):
        if shutil.which(tool) is None:
            return f"needs the `{tool}` command to confine Ray to a loopback-only network namespace"
    try:
        res = subprocess.run(
            [*NAMESPACE, "sh", "-c", PRELUDE, "sh", "true"], capture_output=True, text=True, timeout=30
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"cannot create a loopback-only namespace: {exc}"
    if res.returncode != 0:
        return f"cannot create a loopback-only namespace (unprivileged user namespaces off?): {res.stderr.strip()}"
    return None


def run(argv: list[str], timeout: float, cwd: Path = REPO) -> subprocess.CompletedProcess:
    """Run `argv` in a fresh loopback-only namespace; everything it started is killed when it ends."""
    env = {**os.environ, **ENV}
    return subprocess.run(
        [*NAMESPACE, "sh", "-c", PRELUDE, "sh", *argv],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


# -- inside the namespace ----------------------------------------------------------------------
def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def descendants(pid: int) -> list[int]:
    """`pid` and every process below it (from /proc: parent links)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(children.get(p, []))
    return out


def kill_tree(pid: int) -> list[int]:
    """SIGKILL a process and all its descendants (by pid); returns the pids signalled."""
    pids = descendants(pid)
    for p in pids:
        try:
            os.kill(p, signal.SIGKILL)
        except ProcessLookupError:
            pass
    deadline = time.time() + 10
    while time.time() < deadline and any(Path(f"/proc/{p}").exists() and _alive(p) for p in pids):
        time.sleep(0.1)
    return pids


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


class Cluster:
    """A head and optional extra nodes on 127.0.0.1 (use inside `run`'s namespace)."""

    def __init__(self, head_cpus: int = 1, log_dir: Path | None = None):
        self.port = free_port()
        self.address = f"127.0.0.1:{self.port}"
        self.log_dir = log_dir
        self.nodes: list[subprocess.Popen] = []
        self._start(["--head", f"--port={self.port}", "--include-dashboard=false"], head_cpus)
        self.wait_nodes(1)

    def _start(self, args: list[str], cpus: int) -> subprocess.Popen:
        log = open(self.log_dir / f"node{len(self.nodes)}.log", "w") if self.log_dir else subprocess.DEVNULL
        ray = str(Path(sys.executable).with_name("ray"))
        argv = [
            ray,
            "start",
            *args,
            f"--num-cpus={cpus}",
            "--node-ip-address=127.0.0.1",
            "--disable-usage-stats",
            "--object-store-memory=200000000",
            "--block",
        ]
        proc = subprocess.Popen(
            argv, stdout=log, stderr=subprocess.STDOUT, start_new_session=True, env={**os.environ, **ENV}
        )
        self.nodes.append(proc)
        return proc

    def add_node(self, cpus: int = 1) -> subprocess.Popen:
        proc = self._start([f"--address={self.address}"], cpus)
        self.wait_nodes(len(self.nodes))
        return proc

    def alive_nodes(self) -> int:
        """Nodes the GCS counts as alive (`ray status`: one `node_...` line per active node)."""
        ray = str(Path(sys.executable).with_name("ray"))
        res = subprocess.run(
            [ray, "status", f"--address={self.address}"],
            capture_output=True,
            text=True,
            timeout=60,
            env={**os.environ, **ENV},
        )
        active = res.stdout.split("Active:", 1)[-1].split("Pending:", 1)[0] if "Active:" in res.stdout else ""
        return sum(1 for line in active.splitlines() if line.strip().startswith("1 node_"))

    def wait_nodes(self, n: int, timeout: float = 120) -> None:
        deadline = time.time() + timeout
        while time.time() < deadline:
            for proc in self.nodes:
                if proc.poll() is not None:
                    raise RuntimeError(f"a ray node exited with code {proc.returncode} (logs: {self.log_dir})")
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=1):
                    pass
                if self.alive_nodes() >= n:
                    return
            except OSError:
                pass
            time.sleep(1)
        raise RuntimeError(f"the Ray cluster did not reach {n} node(s) in {timeout:g} s (logs: {self.log_dir})")

    def kill_node(self, proc: subprocess.Popen) -> list[int]:
        """A machine failure: the node's `ray start`, raylet, object store and every worker on it, SIGKILLed."""
        return kill_tree(proc.pid)

    def stop(self) -> None:
        for proc in reversed(self.nodes):
            kill_tree(proc.pid)

    def __enter__(self) -> Cluster:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

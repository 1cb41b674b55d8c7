"""Hostile inputs: a workspace of valid inputs, a corpus of bad ones, and the checks every bad input must pass.

For each case the command runs in process (`bench.cli.main`, or a `python -m` module's `main`) and
must: exit 2, print exactly one line on stderr that matches the case's pattern (it names the field),
print no traceback, and leave every file of the workspace as it was: nothing changed, nothing removed,
nothing created (a bad input writes nothing). Two kinds of case expect another exit code: a run, score
or gate that measured nothing exits 3 with a last stderr line `nothing measured: ...` matching the
pattern (it may write its records where the case allows), and an input that looks odd but must work
(episodes shorter than k) exits 0. Misbehaving policy servers (`server_port`) run on 127.0.0.1. The workspace is built once (a LeRobot dataset, a toy
run, a leaderboard, outcome tables, CSV / MAT / RLDS logs, an MJCF with its spec, a checkpoint); each
case writes its own bad files into a folder of its own before the snapshot is taken.

`python tests/hostile.py` runs the corpus and prints, per family of the issues (data loss,
tracebacks, silent acceptances, unbounded work, files left behind, unreadable output; capability
missing, nothing measured, slow servers, short episodes, physically impossible bounds), how many
inputs were tried and how many failed; the test module (tests/test_hostile_inputs.py) asserts each.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import re
import resource
import shutil
import signal
import sys
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
TOY = "suite=tests.toy_suite:ToySuite"
FAMILIES = (
    "data loss",
    "traceback",
    "silent acceptance",
    "unbounded work",
    "left behind",
    "unreadable output",
    # issue 28: runs that look fine but measured nothing, and what they come from
    "capability missing",
    "nothing measured",
    "slow servers",
    "short episodes",
    "physically impossible bounds",
)

ARM_XML = """<mujoco model="arm1">
  <option timestep="0.01"/>
  <worldbody>
    <body name="link1">
      <joint name="j1" type="hinge" axis="0 0 1" damping="0.5"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03" mass="1"/>
    </body>
  </worldbody>
  <actuator><motor name="m1" joint="j1" gear="1"/></actuator>
</mujoco>
"""

SPEC_YAML = """model: arm.xml
substeps: 10
signals:
  qpos: {column: observation.state, index: [0]}
  qvel: {column: observation.state, index: [1]}
  ctrl: {column: action, index: [0]}
params:
  - {name: damping, field: dof_damping, elements: [j1], bounds: [0.01, 5]}
effects: none
holdout: 0.5
"""


# ----------------------------------------------------------------------------- the workspace


def _arm_logs(path: Path, episodes: int = 2, frames: int = 40) -> None:
    """A dataset of the 1-joint arm under random torques, simulated with MuJoCo (qpos, qvel; torque)."""
    import mujoco

    from bench.logs import from_arrays, write_dataset

    model = mujoco.MjModel.from_xml_string(ARM_XML)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    eps = []
    for _ in range(episodes):
        mujoco.mj_resetData(model, data)
        u = rng.uniform(-1, 1, size=(frames, 1))
        x = np.zeros((frames, 2))
        for t in range(frames):
            x[t] = data.qpos[0], data.qvel[0]
            data.ctrl[:] = u[t]
            for _ in range(10):
                mujoco.mj_step(model, data)
        eps.append({"observation.state": x.astype(np.float32), "action": u.astype(np.float32)})
    write_dataset(path, from_arrays(eps, fps=10, names={"observation.state": ["q", "qd"], "action": ["tau"]}))


def _rlds(path: Path) -> bool:
    """A copy of the shared TFDS-written RLDS fixture (False when ../shared is absent)."""
    src = SHARED / "data" / "formats" / "rlds_toy" / "toy_rlds"
    if not src.is_dir():
        return False
    shutil.copytree(src, path)
    for p in path.rglob("*"):
        p.chmod(0o755 if p.is_dir() else 0o644)
    return True


def _checkpoint(path: Path) -> None:
    """A tiny MLP checkpoint for the toy suite (obs pos, goal; action push)."""
    import torch

    from baselines.architectures import build
    from baselines.checkpoint import save_checkpoint

    torch.manual_seed(0)
    net = build("mlp", 2, 1, {"hidden": [4]})
    save_checkpoint(
        path,
        net,
        {
            "architecture": "mlp",
            "kwargs": {"hidden": [4]},
            "obs_names": [["pos", 1], ["goal", 1]],
            "action_names": ["push"],
        },
    )


def build_workspace(root: Path) -> Path:
    """The valid inputs every case starts from, under `root` (created)."""
    from bench import api
    from bench.board.leaderboard import merge, read_input
    from bench.core.io import write_atomic

    root.mkdir(parents=True, exist_ok=True)
    cwd = os.getcwd()
    os.chdir(REPO)  # tests.toy_suite is imported from the checkout
    try:
        api.run(api.config_from_argv([TOY, "episodes=2", "workers=1", f"out={root}", "run_id=run", "n_boot=200"]))
    finally:
        os.chdir(cwd)
    write_atomic(root / "lb.json", merge([read_input(str(root / "run"))]))
    _arm_logs(root / "ds")
    (root / "arm.xml").write_text(ARM_XML)
    (root / "spec.yaml").write_text(SPEC_YAML)
    rows = [{"policy": p, "trials": 20, "successes": s} for p, s in (("a", 5), ("b", 10), ("c", 15))]
    (root / "sim.json").write_text(json.dumps(rows))
    (root / "real.json").write_text(json.dumps([dict(r, successes=r["successes"] - 2) for r in rows]))
    t = np.arange(50) / 100.0
    (root / "data.csv").write_text("t,q,u\n" + "".join(f"{a:.3f},{np.sin(a):.5f},{np.cos(a):.5f}\n" for a in t))
    import scipy.io

    scipy.io.savemat(
        root / "data.mat", {"t": t[:, None], "q": np.sin(t)[:, None], "u": np.cos(t)[:, None], "k": np.array([[2.0]])}
    )
    _rlds(root / "rlds")
    _checkpoint(root / "ckpt" / "policy.safetensors")
    _capabilities(root)
    (root / "cases").mkdir()
    return root


def _capabilities(root: Path) -> None:
    """Markers of what this machine lacks (a capability-missing case `needs` its marker: it runs only here)."""
    import importlib.util

    if importlib.util.find_spec("mani_skill") is not None:
        from bench.sims.maniskill import physx_gpu_library
        from bench.sims.sapien_novulkan import render_device_available

        if not render_device_available():
            (root / "no-vulkan").write_text("SAPIEN finds no Vulkan device here\n")
        import torch

        if not torch.cuda.is_available() or physx_gpu_library() is not None:
            (root / "no-physx-gpu").write_text("no CUDA device, or no PhysX GPU library\n")


# ----------------------------------------------------------------------------- slow policy servers

_SERVERS: dict[str, int] = {}
_KEEP: list = []  # the servers' sockets, open while the corpus runs
SERVERS = ("hang", "stall", "stall_openpi")


def server_port(name: str) -> int:
    """The port of a misbehaving policy server on 127.0.0.1, started once per process (daemon threads).

    hang: accepts TCP connections (the kernel's backlog) and never answers the websocket handshake.
    stall: a bench server (bench's protocol in its metadata) that never answers a request.
    stall_openpi: the same, as an openpi server (no bench metadata: no request before the episodes' warm-up).
    """
    if name not in _SERVERS:
        import socket
        import threading

        from bench.remote import wire
        from bench.remote.serving import WebsocketServer

        if name == "hang":
            sock = socket.create_server(("127.0.0.1", 0), backlog=64)
            _KEEP.append(sock)
            _SERVERS[name] = sock.getsockname()[1]
        else:

            class Stall:
                def handle(self, request):
                    threading.Event().wait()  # never answers

                def close(self) -> None:
                    pass

            meta = {"bench": {"protocol": wire.PROTOCOL}} if name == "stall" else {"policy": "stalls"}
            ws = WebsocketServer(Stall, meta, "127.0.0.1", 0)
            _KEEP.append(ws)
            _SERVERS[name] = ws.start()
    return _SERVERS[name]


# ----------------------------------------------------------------------------- running one input


@dataclass
class Result:
    code: int | None
    out: str
    err: str
    exc: str | None  # the traceback of an exception that escaped the command, if any
    seconds: float


class _Timeout(BaseException):
    pass


def _alarm(signum, frame):
    raise _Timeout()


def run_main(
    main: Callable[[list[str]], int], argv: list[str], cwd: Path, timeout: float = 60.0, memory_gb: float | None = None
) -> Result:
    """`main(argv)` in process with stdout/stderr captured, in `cwd`, under a time (and memory) limit."""
    import time

    out, err = io.StringIO(), io.StringIO()
    old_cwd = os.getcwd()
    old_handler = signal.signal(signal.SIGALRM, _alarm)
    old_limit = resource.getrlimit(resource.RLIMIT_AS)
    if memory_gb:
        resource.setrlimit(resource.RLIMIT_AS, (int(memory_gb * 2**30), old_limit[1]))
    signal.setitimer(signal.ITIMER_REAL, timeout)
    t0 = time.perf_counter()
    code, exc = None, None
    try:
        os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(list(argv))
    except _Timeout:
        exc = f"timed out after {timeout:g} s"
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    except BaseException:  # noqa: B036 - a hostile input must never get here
        exc = traceback.format_exc()
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old_handler)
        if memory_gb:
            resource.setrlimit(resource.RLIMIT_AS, old_limit)
        os.chdir(old_cwd)
    return Result(code, out.getvalue(), err.getvalue(), exc, time.perf_counter() - t0)


def cli_main(argv: list[str]) -> int:
    from bench.cli import main

    return main(argv)


def module_main(module: str) -> Callable[[list[str]], int]:
    def main(argv: list[str]) -> int:
        import importlib

        from bench.cli import guarded

        return guarded(lambda: importlib.import_module(module).main(argv))

    return main


# ----------------------------------------------------------------------------- snapshots


def snapshot(root: Path) -> dict[str, tuple]:
    """Every entry under `root`: files by (size, sha256 of the content), folders and links by kind."""
    out: dict[str, tuple] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames:
            p = Path(dirpath) / name
            out[str(p.relative_to(root))] = ("link",) if p.is_symlink() else ("dir",)
        for name in filenames:
            p = Path(dirpath) / name
            rel = str(p.relative_to(root))
            if p.is_symlink():
                out[rel] = ("link", os.readlink(p))
                continue
            try:
                data = p.read_bytes()
            except OSError:
                out[rel] = ("unreadable",)
                continue
            out[rel] = ("file", len(data), hashlib.sha256(data).hexdigest())
    return out


def changes(before: dict[str, tuple], after: dict[str, tuple]) -> list[str]:
    """What differs: `+path` created, `-path` removed, `~path` changed."""
    out = [f"+{p}" for p in sorted(set(after) - set(before))]
    out += [f"-{p}" for p in sorted(set(before) - set(after))]
    out += [f"~{p}" for p in sorted(set(before) & set(after)) if before[p] != after[p]]
    return out


# ----------------------------------------------------------------------------- cases


@dataclass
class Case:
    """One bad input: what to run, how to set it up, and the line it must get."""

    family: str
    name: str
    argv: list[str]  # `{ws}` is the workspace, `{case}` the case's own folder
    match: str  # regex the single stderr line must match
    setup: Callable[[Path, Path], None] | None = None  # (workspace, case dir): writes the bad files
    main: str = "bench"  # "bench" or a module with main(argv), e.g. "baselines.bc"
    cwd: str = "{case}"
    code: int = 2
    needs: tuple[str, ...] = ()  # workspace entries the case needs (skipped without them)
    memory_gb: float | None = 4.0  # address-space limit while it runs (a hostile input must not eat the machine)
    timeout: float = 60.0
    allowed: tuple[str, ...] = field(default=())  # paths (relative to the workspace) the command may create

    def expand(self, text: str, ws: Path, case: Path) -> str:
        for name in SERVERS:  # {port:hang}: the port of a misbehaving server (`server_port`)
            if f"{{port:{name}}}" in text:
                text = text.replace(f"{{port:{name}}}", str(server_port(name)))
        return text.replace("{ws}", str(ws)).replace("{case}", str(case))


def check(case: Case, ws: Path) -> tuple[list[str], Result | None]:
    """Run one case; return (problems found, result). No problems means the input was handled right."""
    case_dir = ws / "cases" / case.name
    if any(not (ws / n).exists() for n in case.needs):
        return [], None
    if case_dir.exists():
        shutil.rmtree(case_dir)
    case_dir.mkdir(parents=True)
    if case.setup:
        case.setup(ws, case_dir)
    before = snapshot(ws)
    argv = [case.expand(a, ws, case_dir) for a in case.argv]
    main = cli_main if case.main == "bench" else module_main(case.main)
    res = run_main(
        main, argv, Path(case.expand(case.cwd, ws, case_dir)), timeout=case.timeout, memory_gb=case.memory_gb
    )
    after = snapshot(ws)
    problems = []
    if res.exc is not None:
        problems.append("traceback: " + res.exc.strip().splitlines()[-1][:300])
    elif res.code != case.code:
        problems.append(f"exit {res.code}, expected {case.code}")
    lines = [ln for ln in res.err.splitlines() if ln.strip()]
    if res.exc is None and case.code == 2:
        if len(lines) != 1:
            problems.append(f"{len(lines)} lines on stderr: {res.err.strip()[:300]!r}")
        elif not re.search(case.match, lines[0]):
            problems.append(f"stderr does not match {case.match!r}: {lines[0][:300]}")
    elif res.exc is None and case.code == 3:  # nothing measured: the run's output, then the one line saying so
        if not lines or not lines[-1].startswith("nothing measured: ") or not re.search(case.match, lines[-1]):
            problems.append(f"last stderr line is not 'nothing measured: ...{case.match}': {lines[-1:]!r}")
    if "Traceback (most recent call last)" in res.err + res.out:
        problems.append("a traceback was printed")
    allowed = {case.expand(a, ws, case_dir) for a in case.allowed}
    diff = [c for c in changes(before, after) if not any(str(ws / c[1:]).startswith(a) for a in allowed)]
    if diff:
        problems.append(f"files changed: {', '.join(diff[:6])}" + (" ..." if len(diff) > 6 else ""))
    return problems, res


def write(rel: str, content: str | bytes) -> Callable[[Path, Path], None]:
    """A setup that writes `content` to the case folder's `rel`."""

    def setup(ws: Path, case: Path) -> None:
        p = case / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            p.write_bytes(content)
        else:
            p.write_text(content)

    return setup


def copy(src: str, dst: str, edit: Callable[[Path], None] | None = None) -> Callable[[Path, Path], None]:
    """A setup that copies workspace `src` to the case folder's `dst`, then applies `edit` to the copy."""

    def setup(ws: Path, case: Path) -> None:
        s, d = ws / src, case / dst
        if s.is_dir():
            shutil.copytree(s, d)
        else:
            d.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(s, d)
        if edit:
            edit(d)

    return setup


def edit_json(rel: str, fn: Callable[[dict], object]) -> Callable[[Path], None]:
    """An edit that rewrites the JSON file `rel` (inside the copy) with `fn(doc)` (the new document,
    or None when `fn` changed the document in place)."""

    def edit(root: Path) -> None:
        p = root / rel if rel else root
        doc = json.loads(p.read_text())
        new = fn(doc)
        p.write_text(json.dumps(doc if new is None else new, allow_nan=True))

    return edit


def summarize(results: list[tuple[Case, list[str]]]) -> str:
    """Per family: tried, handled, failed (with the failures listed)."""
    lines = [f"{'family':<30} {'tried':>6} {'ok':>6} {'failed':>7}"]
    for fam in FAMILIES:
        rows = [(c, p) for c, p in results if c.family == fam]
        bad = [(c, p) for c, p in rows if p]
        lines.append(f"{fam:<30} {len(rows):>6} {len(rows) - len(bad):>6} {len(bad):>7}")
    lines.append(
        f"{'total':<30} {len(results):>6} {sum(1 for _, p in results if not p):>6} {sum(1 for _, p in results if p):>7}"
    )
    for c, p in results:
        if p:
            lines.append(f"  FAIL [{c.family}] {c.name}: {'; '.join(p)}")
    return "\n".join(lines)


if __name__ == "__main__":  # python tests/hostile.py [WORKDIR]: run the corpus, print the counts
    import tempfile

    sys.path.insert(0, str(REPO))
    sys.path.insert(0, str(REPO / "tests"))
    from hostile_corpus import CASES

    work = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="hostile-"))
    ws = work / "ws"
    if not (ws / "cases").is_dir():
        build_workspace(ws)
    only = os.environ.get("HOSTILE_ONLY")
    results = []
    for case in CASES:
        if only and not re.search(only, case.name):
            continue
        try:
            problems, res = check(case, ws)
        except Exception as exc:  # a broken case, not a finding
            print(f"SETUP {case.name}: {type(exc).__name__}: {exc}", flush=True)
            continue
        if res is None:
            continue
        results.append((case, problems))
        print(
            ("FAIL " if problems else "ok   ")
            + f"{case.name} ({res.seconds:.1f}s)"
            + (": " + "; ".join(problems) if problems else ""),
            flush=True,
        )
    print(summarize(results))

"""policy=remote and bench serve on the toy suite, both directions against openpi-client, and bad servers.

Servers listen on 127.0.0.1 only. The "bad" servers are real websocket servers built on openpi-client's
serializer that answer wrongly on purpose (wrong shape, NaN, non-msgpack, text, too late, dying).
"""

from __future__ import annotations

import contextlib
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from bench import api
from bench.cli import main
from bench.records import comparable
from bench.remote.server import PolicyServer, ServeConfig

pytest.importorskip("openpi_client", reason="openpi-client is in the test extra")
from openpi_client import msgpack_numpy as openpi_msgpack  # noqa: E402
from openpi_client.websocket_client_policy import WebsocketClientPolicy  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
TOY = "tests.toy_suite:ToySuite"


@contextlib.contextmanager
def bench_server(policy: str = "scripted", log: list | None = None, **keys):
    """`bench serve` in a thread of this process (the same code the command runs); yields the port."""
    from bench.core import config
    from bench.protocols import registry

    own = {k: v for k, v in keys.items() if k in ServeConfig.__annotations__}
    cfg = ServeConfig(policy=policy, suite=TOY, port=0, **own)
    plugin = registry.load_policy(policy)
    popts = config.build(plugin.Options, [f"{k}={v}" for k, v in keys.items() if k not in own])
    server = PolicyServer(cfg, None, popts, log.append if log is not None else None)
    ws, port = server.start()
    try:
        yield port
    finally:
        ws.shutdown()
        server.close()


class FaultServer:
    """An openpi-style server (websockets.sync + openpi-client's msgpack_numpy) with a scripted answer."""

    def __init__(self, answer, metadata=None):
        from websockets.sync.server import serve

        self.answer, self.requests = answer, []
        self.metadata = metadata if metadata is not None else {"policy": "openpi-style"}
        self.server = serve(self._handle, "127.0.0.1", 0, compression=None, max_size=None)
        self.port = self.server.socket.getsockname()[1]
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def _handle(self, ws):
        packer = openpi_msgpack.Packer()
        ws.send(packer.pack(self.metadata))
        while True:
            try:
                obs = openpi_msgpack.unpackb(ws.recv())
            except Exception:
                return
            self.requests.append(obs)
            out = self.answer(obs)
            if out is None:
                return  # drop the connection
            ws.send(out if isinstance(out, (str, bytes)) else packer.pack(out))

    def close(self):
        self.server.shutdown()


def greedy(obs, key="state"):
    pos, goal = obs[key]
    return {"actions": np.repeat(np.array([[np.clip(10 * (goal - pos), -1, 1)]], np.float32), 3, axis=0)}


def run_cfg(tmp_path, run_id, policy, **kw):
    keys = ("host", "port", "timeout_s", "replan_every", "obs_map", "overlap", "checkpoint")  # the policy's own
    policy_options = {k: kw.pop(k) for k in keys if k in kw}
    return api.RunConfig(
        suite=TOY,
        policy=policy,
        episodes=kw.pop("episodes", 3),
        workers=1,
        out=str(tmp_path),
        run_id=run_id,
        policy_options=policy_options,
        **kw,
    )


def same(a, b):
    strip = lambda r: {k: v for k, v in comparable(r).items() if k not in ("policy", "extras")}  # noqa: E731
    key = lambda r: r.job_id  # noqa: E731
    return [strip(r) for r in sorted(a, key=key)] == [strip(r) for r in sorted(b, key=key)]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# -- policy=remote against bench serve -------------------------------------------------------------
@pytest.mark.parametrize(
    "policy, replan",
    [("scripted", 0), ("tests.toy_suite:chunk_policy", 0), ("tests.toy_suite:chunk_policy", 2), ("random", 0)],
)
def test_remote_records_equal_in_process(tmp_path, policy, replan):
    local = api.run(run_cfg(tmp_path, "local", policy))
    with bench_server(policy) as port:
        remote = api.run(run_cfg(tmp_path, "remote", "remote", port=port, replan_every=replan))
    assert all(r.error is None for r in remote.records) and len(remote.records) == 9
    if replan == 0:
        assert same(local.records, remote.records)
    stats = [r.extras["policy"] for r in remote.records]
    chunk = 4 if "chunk" in policy else 1
    per = chunk if replan == 0 else min(replan, chunk)
    assert all(s["requests"] == -(-r.length // per) for s, r in zip(stats, remote.records))
    assert all(0 < s["rtt_ms"]["p50"] < 1000 and s["fps"] == 10.0 and "server_ms" in s for s in stats)
    meta = (tmp_path / "remote" / "run.json").read_text()
    assert '"port": ' in meta and '"name": "remote"' in meta


def test_overlapped_requests_record_the_observation_the_server_saw(tmp_path):
    """overlap=true: the next chunk is asked for with the observation of the step before it starts."""
    with bench_server("tests.toy_suite:chunk_policy") as port:
        over = api.run(run_cfg(tmp_path, "over", "remote", port=port, replan_every=2, overlap=True))
        plain = api.run(run_cfg(tmp_path, "plain", "remote", port=port, replan_every=2))
    assert all(r.error is None for r in over.records + plain.records) and len(over.records) == 9
    for r in over.records:
        stats = r.extras["policy"]
        # chunk 1 from step 0's observation (rows 0-1 at steps 0-1), then one request at every other step
        # from the observation of the step before the chunk starts (rows 1-2 of each answer executed)
        assert stats["overlap"] is True and stats["obs_steps"] == [0] + list(range(1, r.length - 1, 2)), stats
        assert stats["requests"] == len(stats["obs_steps"])
    for r in plain.records:
        assert r.extras["policy"]["overlap"] is False and r.extras["policy"]["obs_steps"] == list(range(0, r.length, 2))
    # the toy task is solved either way (one step older observations barely matter to it)
    assert sum(r.success_once for r in over.records) == sum(r.success_once for r in plain.records)


def test_overlap_refuses_a_chunk_it_cannot_overlap(tmp_path):
    with bench_server("tests.toy_suite:chunk_policy") as port:
        res = api.run(run_cfg(tmp_path, "short", "remote", port=port, replan_every=4, overlap=True, episodes=1))
    assert all("give a replan_every below the chunk length" in (r.error or "") for r in res.records)


def test_checkpoint_identity_travels(tmp_path):
    """A served checkpoint's sha256 reaches the remote run's records, as it would in process."""
    import torch

    from baselines.architectures import build
    from baselines.checkpoint import save_checkpoint

    spec = {
        "architecture": "mlp",
        "kwargs": {"hidden": [8]},
        "obs_names": [["pos", 1], ["goal", 1]],
        "action_names": ["push"],
    }
    torch.manual_seed(0)
    model = build("mlp", 2, 1, {"hidden": [8]})
    path = tmp_path / "toy.safetensors"
    save_checkpoint(path, model, spec)
    local = api.run(run_cfg(tmp_path, "local", "checkpoint", checkpoint=str(path), episodes=2))
    with bench_server("checkpoint", checkpoint=str(path)) as port:
        remote = api.run(run_cfg(tmp_path, "remote", "remote", port=port, episodes=2))
    assert same(local.records, remote.records)
    assert {r.checkpoint_sha256 for r in remote.records} == {local.records[0].checkpoint_sha256} != {None}


def test_obs_map_and_task_reach_the_server(tmp_path):
    server = FaultServer(lambda obs: greedy(obs, "observation/state"))
    try:
        res = api.run(
            run_cfg(
                tmp_path,
                "m",
                "remote",
                port=server.port,
                episodes=1,
                robots=["a"],
                obs_map=["observation/state:state", "prompt:task", "goal_only:state.goal"],
            )
        )
    finally:
        server.close()
    assert all(r.error is None for r in res.records) and any(r.success_once for r in res.records)
    warm, first = server.requests[0], server.requests[1]  # the warm-up inference: zeros of the same entries
    assert sorted(warm) == sorted(first) and not warm["observation/state"].any()
    assert sorted(first) == ["goal_only", "observation/state", "prompt"] and first["prompt"] == "reach"
    assert first["goal_only"].tolist() == [0.5] and first["observation/state"].dtype == np.float32


def test_bench_server_renames_openpi_style_keys():
    with bench_server(obs_map=["observation/state:state", "prompt:task"]) as port:
        client = WebsocketClientPolicy("127.0.0.1", port)
        out = client.infer({"observation/state": np.array([0.0, 0.5], np.float32), "prompt": "reach"})
        client._ws.close()
    assert out["actions"].tolist() == [[1.0]]


# -- openpi's client against bench serve -----------------------------------------------------------
def test_openpi_client_against_bench_serve_command():
    """The real `bench serve` command in its own process; openpi-client's WebsocketClientPolicy queries it."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "bench", "serve", "policy=scripted", f"suite={TOY}", "cell=reach/c/line", "port=0"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline()
        if "bench serve: policy scripted on ws://127.0.0.1:" not in line:
            proc.kill()
            pytest.fail(f"bench serve did not start: {line!r} {proc.communicate()[1][-2000:]}")
        port = int(line.split("ws://127.0.0.1:")[1].split(" ")[0])
        client = WebsocketClientPolicy("127.0.0.1", port)
        meta = client.get_server_metadata()
        assert meta["bench"]["protocol"] == "bench.remote/1" and meta["bench"]["cell"] == "reach/c/line"
        out = client.infer({"state": np.array([0.0, 0.5], np.float32)})
        assert out["actions"].shape == (1, 1) and out["actions"].dtype == np.float32 and out["actions"][0, 0] == 1.0
        assert out["server_timing"]["infer_ms"] >= 0
        out = client.infer({"state": np.array([0.48, 0.5], np.float64)})  # float64 is cast to the declared float32
        assert out["actions"][0, 0] == pytest.approx(0.2)
        with pytest.raises(RuntimeError, match=r"error: the observation lacks \['state'\]"):
            client.infer({"observation/state": np.zeros(2, np.float32)})
        with pytest.raises(RuntimeError, match=r"error: obs\['state'\] has shape \[3\]; this cell's state is \[2\]"):
            client.infer({"state": np.zeros(3, np.float32)})
        with pytest.raises(RuntimeError, match=r"obs\['state'\] has dtype <U1"):
            client.infer({"state": np.array(["a", "b"])})
        assert client.infer({"state": np.array([0.5, 0.5], np.float32)})["actions"][0, 0] == 0.0  # still serving
        client._ws.close()
        import urllib.request

        with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=5) as r:
            assert r.status == 200
    finally:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0 and "bench serve: stopped" in out
    assert "refused request" in err and "Traceback" not in err


def test_malformed_requests_are_refused_without_dying():
    from websockets.sync.client import connect

    log: list[str] = []
    with bench_server(log=log) as port:
        with connect(f"ws://127.0.0.1:{port}", compression=None, proxy=None) as ws:
            ws.recv()  # metadata
            for bad in (
                b"\xc1garbage",
                "a text frame",
                openpi_msgpack.packb([1, 2]),
                openpi_msgpack.packb(
                    {"state": {b"__ndarray__": True, b"data": b"\0" * 8, b"dtype": "|O", b"shape": [1]}}
                ),
                openpi_msgpack.packb({"__bench__": {"op": "launch"}}),
                openpi_msgpack.packb(
                    {
                        "__bench__": {
                            "op": "reset",
                            "seed": 1,
                            "suite": "toy",
                            "suite_class": "os:system",
                            "cell": "reach/a/line",
                            "run_seed": 0,
                            "horizon": 5,
                        }
                    }
                ),
            ):
                ws.send(bad)
                answer = ws.recv(timeout=10)
                assert isinstance(answer, str) and answer.startswith("error: "), answer
            ws.send(openpi_msgpack.packb({"state": np.array([0.0, 0.5], np.float32)}))
            assert openpi_msgpack.unpackb(ws.recv(timeout=10))["actions"][0, 0] == 1.0
    refused = [line for line in log if "refused request" in line]
    assert len(refused) == 6 and "suite 'toy' (os:system) is not served here" in refused[-1]


# -- policy=remote against a server built on openpi-client's serializer -------------------------------
def test_remote_against_an_openpi_style_server(tmp_path):
    server = FaultServer(greedy)
    try:
        res = api.run(run_cfg(tmp_path, "o", "remote", port=server.port, replan_every=1))
    finally:
        server.close()
    local = api.run(run_cfg(tmp_path, "l", "scripted"))
    assert same(local.records, res.records)  # the greedy answer repeated: one row per request, as in process
    assert all("__bench__" not in req for req in server.requests)  # no control messages to a non-bench server
    assert sorted(server.requests[0]) == ["state", "task"]


@pytest.mark.parametrize(
    "answer, reason",
    [
        (
            lambda obs: {"actions": np.zeros((3, 2), np.float32)},
            "answered actions of shape [3, 2]; this env needs (1,) or a chunk (T, 1)",
        ),
        (lambda obs: {"actions": np.array([[np.nan]], np.float32)}, "answered a non-finite action (NaN or inf)"),
        (lambda obs: {"action": np.zeros((1, 1))}, "has no 'actions' entry"),
        (lambda obs: {"actions": "left"}, "answered actions of type str"),
        (lambda obs: b"\xc1 not msgpack", "the server's answer is not msgpack"),
        (lambda obs: "Traceback: boom", "refused the request: Traceback: boom"),
        (lambda obs: None, "closed the connection"),
    ],
)
def test_bad_answers_fail_the_episode_with_the_reason(tmp_path, answer, reason):
    server = FaultServer(answer)
    try:
        res = api.run(run_cfg(tmp_path, "bad", "remote", port=server.port, timeout_s=2.0, episodes=2))
    finally:
        server.close()
    assert len(res.records) == 6 and all(r.error and reason in r.error for r in res.records), res.records[0].error
    # a server that closes instead of answering fails the warm-up, when the policy is made
    prefix = "building env/policy failed: RemoteError: " if reason == "closed the connection" else "RemoteError: "
    assert res.records[0].error.startswith(prefix)
    assert res.summary["counts"]["errors"] == 6


def test_a_slow_server_times_out_per_episode_never_hangs(tmp_path):
    def slow(obs):
        time.sleep(0.6)
        return greedy(obs)

    server = FaultServer(slow)
    t0 = time.monotonic()
    try:
        res = api.run(run_cfg(tmp_path, "slow", "remote", port=server.port, timeout_s=0.3, episodes=1))
    finally:
        server.close()
    assert all("did not answer within timeout_s=0.3 s" in r.error for r in res.records)
    assert time.monotonic() - t0 < 15


def test_episodes_fail_while_the_server_is_down_and_succeed_when_it_is_back(tmp_path):
    port = free_port()
    cfg = ServeConfig(suite=TOY, port=port)
    state: dict = {"n": 0, "ws": None}

    def start():
        state["ws"], _ = PolicyServer(cfg, None, None).start()

    def on_record(record):
        state["n"] += 1
        if state["n"] == 2:
            state["ws"].shutdown()  # the server dies after the second episode ...
        if state["n"] == 4:
            start()  # ... and is back two episodes later

    start()
    try:
        res = api.run(run_cfg(tmp_path, "down", "remote", port=port, timeout_s=0.5, episodes=3), on_record=on_record)
    finally:
        state["ws"].shutdown()
    errors = [r.error for r in sorted(res.records, key=lambda r: r.finished_at)]
    assert errors[:2] == [None, None] and all(e and f"no policy server at 127.0.0.1:{port}" in e for e in errors[2:4])
    assert errors[4:] == [None] * 5


# -- bad input at the command line ------------------------------------------------------------------
def test_nothing_listening_is_one_line_naming_host_port(tmp_path, capsys):
    port = free_port()
    t0 = time.monotonic()
    rc = main(["run", f"suite={TOY}", "policy=remote", f"port={port}", "warmup_s=0.5", f"out={tmp_path}", "run_id=x"])
    err = capsys.readouterr().err
    assert rc == 2 and time.monotonic() - t0 < 5
    assert err.count("\n") == 1 and f"no policy server at 127.0.0.1:{port}: connection refused" in err
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["port=0"], "port=0: must be in [1, 65535]"),
        (["timeout_s=0"], "timeout_s=0.0: must be > 0"),
        (["replan_every=-1"], "replan_every=-1: must be >= 0"),
        (["overlap=true"], "overlap=true: give replan_every >= 1"),
        (["obs_map=[observation/state]"], "entry 'observation/state' is not WIRE_KEY:SOURCE"),
        (
            ["obs_map=[img:rgb.front]"],
            "policy 'remote' needs observation keys ['rgb.front']; suite 'toy' cell "
            "reach/a/line provides state(2) float32",
        ),
        (
            ["obs_map=[g:state.gaol]"],
            "obs_map: g:state.gaol: the state of suite 'toy' cell reach/a/line has no field 'gaol'",
        ),
        (["host=a b"], "host='a b': give a host name or IP address"),
    ],
)
def test_bad_remote_keys(tmp_path, capsys, args, message):
    with bench_server() as port:
        rc = main(
            ["run", f"suite={TOY}", "policy=remote", f"port={port}", *args, f"out={tmp_path}", "run_id=x"]
            if "port" not in args[0]
            else ["run", f"suite={TOY}", "policy=remote", *args, f"out={tmp_path}"]
        )
    err = capsys.readouterr().err
    assert rc == 2 and message in err and err.count("\n") == 1, err


def test_server_refuses_a_suite_it_does_not_serve(tmp_path, capsys):
    """The bench server checks, before the run, that it can serve the run's suite and cells."""
    ws, port = PolicyServer(ServeConfig(port=0), None, None).start()
    try:
        rc = main(["run", f"suite={TOY}", "policy=remote", f"port={port}", f"out={tmp_path}", "run_id=x"])
    finally:
        ws.shutdown()
    err = capsys.readouterr().err
    assert rc == 2 and "suite 'toy' (tests.toy_suite:ToySuite) is not served here" in err, err
    assert "restart it with suite=tests.toy_suite:ToySuite" in err and not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["policy=nope"], "policy='nope' is not registered"),
        (["port=70000"], "port=70000: must be in [0, 65535]"),
        (["cell=reach/z/line"], "cell='reach/z/line' is not a cell of suite"),
        (["obs_map=[s:state.pos]"], "a server can only rename whole entries"),
        (["checkpoint=x.safetensors"], "unknown key 'checkpoint'"),
        (["policy=checkpoint", "checkpoint=/nonexistent.safetensors"], "no such file"),
        (["batch=0"], "batch=0: must be in [1, 1024]"),
        (["batch=2", "batch_wait_ms=-1"], "batch_wait_ms=-1.0: must be in [0, 1000]"),
        (["prepare=-1"], "prepare=-1: must be in [0, 1024]"),
    ],
)
def test_bench_serve_bad_input(capsys, args, message):
    port = [] if any(a.startswith("port=") for a in args) else ["port=0"]
    assert main(["serve", f"suite={TOY}", *port, *args]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err


def test_bench_serve_port_in_use(capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert main(["serve", f"suite={TOY}", f"port={port}"]) == 2
    assert f"host=127.0.0.1 port={port}: cannot listen there" in capsys.readouterr().err


def test_serve_listens_on_loopback_by_default():
    assert ServeConfig().host == "127.0.0.1"
    from bench.remote.client import RemoteOptions

    assert RemoteOptions().host == "127.0.0.1"


# -- policy on logs -----------------------------------------------------------------------------------
def test_bench_actions_accepts_a_remote_policy(tmp_path):
    """`bench actions` with policy=remote gives the in-process scripted policy's numbers, plus latency."""
    from bench.api.policy_on_logs import ActionsConfig, evaluate
    from bench.remote.client import RemoteOptions

    api.run(
        api.RunConfig(
            suite=TOY,
            policy="scripted",
            episodes=2,
            workers=1,
            out=str(tmp_path),
            run_id="rec",
            record=str(tmp_path / "demos"),
        )
    )
    ref = evaluate(ActionsConfig(logs=str(tmp_path / "demos"), policy="scripted", suite=TOY))
    with bench_server() as port:
        got = evaluate(
            ActionsConfig(logs=str(tmp_path / "demos"), policy="remote", suite=TOY), RemoteOptions(port=port)
        )
    assert got["per_dim"] == ref["per_dim"] and got["frames"] == ref["frames"] > 0
    assert got["policy_latency"]["requests"] == got["frames"]


# -- latency: records, summary (composed with perturb.latency), report ------------------------------------
def test_latency_in_summary_composes_with_perturb_latency_and_is_reported(tmp_path):
    with bench_server() as port:
        res = api.run(run_cfg(tmp_path, "lat", "remote", port=port, episodes=2, perturb={"latency": [2, 5]}))
        local = api.run(run_cfg(tmp_path, "loc", "scripted", episodes=2, perturb={"latency": [2, 5]}))
    assert same(local.records, res.records)  # the measured latency never changes a rollout
    block = res.summary["policy_latency"]
    assert block["requests"] == sum(r.extras["policy"]["requests"] for r in res.records) and block["fps"] == 10.0
    conds = {c["condition"]: c for c in block["conditions"]}
    assert list(conds)[0] == "nominal" and conds["nominal"]["injected_steps"] == 0
    five = next(c for name, c in conds.items() if "5" in name)
    assert five["injected_steps"] == 5
    assert five["effective_steps"]["p50"] == pytest.approx(5 + five["rtt_steps"]["p50"], abs=1e-3)
    assert five["rtt_steps"]["p50"] == pytest.approx(five["rtt_ms"]["p50"] * 10 / 1000, abs=1e-3)
    assert main(["report", str(tmp_path / "lat"), f"out={tmp_path / 'rep'}"]) == 0
    page = (tmp_path / "rep" / "index.html").read_text()
    assert "Policy latency (remote policy)" in page and (tmp_path / "rep" / "latency.png").stat().st_size > 5000
    assert "effective steps (injected + measured)" in page
    assert main(["report", str(tmp_path / "loc"), f"out={tmp_path / 'rep2'}"]) == 0  # in process: no section
    assert "Policy latency" not in (tmp_path / "rep2" / "index.html").read_text()


def test_camera_images_travel_to_bench_serve_and_to_openpi_style_servers(tmp_path, monkeypatch):
    """held_out_robots with two rendered cameras: records equal in process through bench serve (which checks the
    images against the cell's spec), and an openpi-style server gets the very pixels under LIBERO-style names."""
    monkeypatch.setenv("MUJOCO_GL", "egl")
    cams = {"obs": "state+rgb", "image_size": 32}
    cfg = dict(
        suite="held_out_robots",
        robots=["Panda"],
        episodes=1,
        horizon=3,
        workers=1,
        out=str(tmp_path),
        suite_options=cams,
    )
    plan = api.plan(api.RunConfig(policy="scripted", run_id="local", **cfg))
    worker = api.worker(plan)
    local = [worker.run(job) for job in plan.jobs]
    env, _ = worker.built(plan.jobs[0])
    first = env.reset(plan.jobs[0].seed)
    worker.close()
    with bench_server() as port:  # the client names held_out_robots and its camera options
        remote = api.run(api.RunConfig(policy="remote", run_id="remote", policy_options={"port": port}, **cfg))
    assert all(r.error is None for r in remote.records) and same(local, remote.records)
    server = FaultServer(lambda obs: {"actions": np.zeros((10, 7), np.float32)})
    libero = [
        "observation/image:rgb.agentview",
        "observation/wrist_image:rgb.robot0_eye_in_hand",
        "observation/state:state.eef_pos+state.eef_quat_rel+state.gripper_opening",
        "prompt:task",
    ]
    try:
        res = api.run(
            api.RunConfig(
                policy="remote",
                run_id="libero",
                **cfg,
                policy_options={"port": server.port, "obs_map": libero, "replan_every": 5},
            )
        )
    finally:
        server.close()
    # the warm-up inference (zeros of the same entries), then one request: 3 steps < 5 rows per chunk
    assert all(r.error is None for r in res.records) and len(server.requests) == 2
    warm, req = server.requests
    assert {k: np.shape(v) for k, v in warm.items()} == {k: np.shape(v) for k, v in req.items()}
    assert not warm["observation/image"].any() and warm["prompt"] == "Lift"
    assert req["observation/image"].dtype == np.uint8 and req["observation/image"].shape == (32, 32, 3)
    assert np.array_equal(req["observation/image"], first["rgb.agentview"])
    assert np.array_equal(req["observation/wrist_image"], first["rgb.robot0_eye_in_hand"])
    assert np.array_equal(req["observation/state"], first["state"][:8]) and req["prompt"] == "Lift"


def test_envs_prepared_ahead_are_handed_over_once():
    """bench serve builds the envs of announced cells in the background; a reset takes them, or builds its own."""
    from bench.remote.server import Prepared

    made, closed = [], []

    class Env:
        def __init__(self, key):
            self.key = key
            made.append(key)

        def close(self):
            closed.append(self.key)

    gate, started = threading.Event(), threading.Event()

    def slow(key):
        started.set()
        gate.wait(5)
        return Env(key)

    p = Prepared(limit=2)
    p.add("a", lambda: slow("a"))
    p.add("b", lambda: Env("b"))
    p.add("c", lambda: Env("c"))  # over the limit: not built ahead
    assert started.wait(5)
    assert p.take("b") is None  # queued behind "a", not started: the caller builds it itself, now
    gate.set()
    env = p.take("a")  # under way: waits for it
    assert env is not None and env.key == "a" and p.take("a") is None
    p.add("d", lambda: Env("d"))
    for _ in range(100):
        if "d" in made:
            break
        time.sleep(0.05)
    p.close()  # "d" was never taken: closed with the server
    assert made == ["a", "d"] and closed == ["d"]


def _toy_checkpoint(path, chunk=3, width=64):
    import torch

    from baselines.architectures import build
    from baselines.checkpoint import save_checkpoint

    torch.manual_seed(0)
    model = build("mlp", 2, chunk, {"hidden": [width, width]})
    spec = {"architecture": "mlp", "kwargs": {"hidden": [width, width]}, "obs_names": [["pos", 1], ["goal", 1]]}
    return save_checkpoint(path, model, {**spec, "action_names": ["push"], "chunk": chunk})


def test_batching_server_answers_concurrent_workers_in_batches(tmp_path):
    """batch=4: four connections' requests share forward passes, and get the answers they get alone."""
    from bench.remote.connection import Connection

    ckpt = _toy_checkpoint(tmp_path / "p.safetensors")
    rng = np.random.default_rng(0)
    observations = [rng.uniform(-1, 1, (20, 2)).astype(np.float32) for _ in range(4)]
    reset = {
        "__bench__": {
            "op": "reset",
            "seed": 0,
            "cell": "reach/a/line",
            "suite": "toy",
            "suite_class": "tests.toy_suite:ToySuite",
            "suite_options": {},
            "run_seed": 0,
            "horizon": 30,
        }
    }

    def ask(port, k, out):
        conn = Connection("127.0.0.1", port, 30.0)
        conn.connect()
        conn.request(reset)
        out[k] = [conn.request({"state": o}) for o in observations[k]]
        conn.close()

    answers = {}
    for batch in (1, 4):
        with bench_server("checkpoint", checkpoint=str(ckpt), batch=batch, batch_wait_ms=50.0) as port:
            got: dict = {}
            threads = [threading.Thread(target=ask, args=(port, k, got)) for k in range(4)]
            for t in threads:
                t.start()
            for t in threads:
                t.join(60)
            answers[batch] = got
    sizes = [a["server_timing"].get("batch", 1) for k in range(4) for a in answers[4][k]]
    assert max(sizes) > 1  # requests did share forward passes
    for k in range(4):
        for a, b in zip(answers[1][k], answers[4][k]):
            assert a["actions"].shape == (3, 1)
            np.testing.assert_allclose(a["actions"], b["actions"], rtol=1e-5, atol=1e-6)

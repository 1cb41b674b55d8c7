"""executor=ray on real Ray clusters (head + nodes on 127.0.0.1 in a loopback-only namespace,
tests/ray_sandbox.py; the runs themselves in tests/ray_scenarios.py): the records of a local
run, timeouts and errors alike, one line for each bad input, and nothing lost or duplicated
when a worker process, a node or the driver is killed mid-run (the last two are slow)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests import ray_sandbox

REPO = Path(__file__).resolve().parents[1]
ray_missing = pytest.mark.skipif(
    __import__("importlib").util.find_spec("ray") is None, reason="Ray is not installed (pip install -e '.[ray]')"
)


def scenario(name: str, out: Path, timeout: float) -> dict:
    why = ray_sandbox.unavailable()
    if why:
        pytest.skip(why)
    res = ray_sandbox.run([sys.executable, "-m", "tests.ray_scenarios", name, str(out)], timeout=timeout)
    assert res.returncode == 0, res.stderr[-4000:]
    return {**json.loads((out / "facts.json").read_text()), "out": str(out)}


@pytest.fixture(scope="module")
def basics(tmp_path_factory):
    return scenario("basics", tmp_path_factory.mktemp("ray_basics"), timeout=600)


def bench_lines(stderr: str) -> list[str]:
    """stderr without the warnings Ray's C++ core prints in a namespace that has no external route."""
    return [ln for ln in stderr.splitlines() if ln.strip() and "network_util.cc" not in ln]


def same(records: list[dict]) -> list[dict]:
    """Records as two runs with the same seed must agree on them (timing, pid, run id, retries aside)."""
    drop = {"wall_s", "finished_at", "worker_pid", "run_id"}
    out = []
    for r in records:
        d = {k: v for k, v in r.items() if k not in drop}
        extras = {k: v for k, v in d.pop("extras", {}).items() if k != "retries"}
        if extras:
            d["extras"] = extras
        out.append(d)
    return sorted(out, key=lambda d: d["job_id"])


@ray_missing
def test_ray_gives_the_records_and_summary_of_a_local_run(basics):
    assert basics["ray"]["rc"] == 0, basics["ray"]["stderr"]
    ray, local = basics["records_ray"], basics["records_local"]
    assert len(ray) == 12 and same(ray) == same(local)
    assert len({r["worker_pid"] for r in ray}) == 2  # two long-lived actors, each reusing its env
    s_ray, s_local = basics["summary_ray"], basics["summary_local"]
    for key in ("cells", "splits", "gaps", "counts", "metric"):
        assert s_ray[key] == s_local[key], key
    assert s_ray["provenance"]["executor"]["kind"] == "ray" and s_ray["config"]["executor"] == "ray"


@ray_missing
def test_timeouts_and_episode_errors_are_recorded_as_locally(basics):
    hang = [r for r in basics["records_hang"] if r["robot"] == "c"]
    assert len(hang) == 2 and all(r["error"].startswith("timeout after 0.5 s at step 2") for r in hang)
    boom = [r for r in basics["records_raise"] if r["robot"] == "c"]
    assert len(boom) == 2 and all(r["error"].startswith("RuntimeError: toy env exploded (toy_suite.py:") for r in boom)
    assert all(r["error"] is None for r in basics["records_raise"] if r["robot"] != "c")
    assert basics["summary_raise"]["counts"]["errors"] == 2


@ray_missing
@pytest.mark.parametrize(
    "case, message",
    [
        (
            "closed_port",
            "error: ray_address=127.0.0.1:{port}: no Ray cluster answers at 127.0.0.1:{port} "
            "(Connection refused); start one with `ray start --head --port={port}` there",
        ),
        ("auto_none", "error: ray_address=auto: no Ray cluster is running on this machine"),
        (
            "not_ray",
            "error: ray_address=127.0.0.1:{port}: something listens at 127.0.0.1:{port} but no Ray GCS "
            "answered within 20 s",
        ),
    ],
)
def test_no_cluster_is_one_line_within_30_s(basics, case, message):
    fact = basics[case]
    lines = bench_lines(fact["stderr"])
    port = lines[0].split("127.0.0.1:")[1].split(":")[0] if case != "auto_none" else ""
    assert fact["rc"] == 2 and len(lines) == 1 and lines[0].startswith(message.format(port=port)), lines
    assert fact["seconds"] < 30


@ray_missing
def test_a_worker_that_cannot_import_the_suite_says_so_once(basics):
    fact = basics["plugin_installed"]  # the plugin is on the driver's PYTHONPATH only, and ray_env=installed
    lines = bench_lines(fact["stderr"])
    assert fact["rc"] == 2 and len(lines) == 1, lines
    assert "cannot load the run: suite='toyplug:ToySuite': cannot import 'toyplug' (ModuleNotFoundError" in lines[0]
    assert len(basics["records_plug_code"]) == 3  # ray_env=code ships the plugin's module to the workers


@ray_missing
def test_a_cluster_with_other_package_versions_is_refused_before_anything_is_written(basics):
    fact = basics["mismatch"]
    assert fact["error"].startswith("executor=ray: the cluster has mujoco 0.0.1 (pid ")
    assert "this driver 3.3" in fact["error"] and "\n" not in fact["error"] and fact["written"] == []


@ray_missing
def test_record_writes_the_same_dataset_as_a_local_run(basics):
    pq = pytest.importorskip("pyarrow.parquet")
    assert basics["rec_ray"]["rc"] == 0, basics["rec_ray"]["stderr"]
    out = Path(basics["out"])
    ray_files = sorted(p.relative_to(out / "ds_ray") for p in (out / "ds_ray").rglob("*.parquet"))
    local_files = sorted(p.relative_to(out / "ds_local") for p in (out / "ds_local").rglob("*.parquet"))
    assert ray_files == local_files and any(str(f).startswith("data") for f in ray_files)
    for f in ray_files:
        assert pq.read_table(out / "ds_ray" / f).equals(pq.read_table(out / "ds_local" / f)), f


@ray_missing
def test_gpu_requests_are_checked_against_the_cluster(basics):
    fact = basics["no_gpu"]
    lines = bench_lines(fact["stderr"])
    assert fact["rc"] == 2 and len(lines) == 1, lines
    assert lines[0].startswith("error: the Ray cluster at 127.0.0.1:") and lines[0].endswith(
        "has 2 CPUs and 0 GPUs; one actor needs actor_cpus=1 actor_gpus=1"
    )


@ray_missing
def test_a_private_cluster_for_one_run(basics):
    assert basics["private"]["rc"] == 0, basics["private"]["stderr"]
    assert len(basics["records_private"]) == 3 and basics["summary_private"]["provenance"]["executor"]["nodes"] == 1
    # the moment the run has exited, no Ray daemon or worker of its private cluster is left in its session
    assert basics["private"]["left"] == [], basics["private"]["left"]


def test_executor_ray_without_ray_installed_gives_the_install_command(tmp_path):
    code = (
        "import sys; sys.modules['ray'] = None\n"  # what an environment without the extra looks like
        "from bench.cli import main\n"
        f"sys.exit(main(['run', 'suite=tests.toy_suite:ToySuite', 'executor=ray', 'out={tmp_path}']))"
    )
    res = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and res.stderr.strip().splitlines() == [
        "error: executor=ray needs Ray, which is not installed here: pip install 'bench-harness[ray]' "
        "(in a checkout: pip install -e '.[ray]')"
    ]
    assert not any(tmp_path.iterdir())


@pytest.mark.slow
@ray_missing
def test_killed_worker_process_and_killed_node_lose_no_episode(tmp_path):
    facts = scenario("faults", tmp_path, timeout=900)
    local = same(facts["records_local"])
    for run_id in ("worker_kill", "node_kill"):
        assert facts[run_id]["rc"] == 0, facts[run_id]["stderr"]
        recs = facts[f"records_{run_id}"]
        assert len(recs) == 24 and len({r["job_id"] for r in recs}) == 24, run_id  # none lost, none twice
        assert same(recs) == local, run_id
        retried = [r for r in recs if "retries" in r.get("extras", {})]
        assert retried, f"{run_id}: no episode was in flight on the killed worker"
        assert all(r["extras"]["retries"][0].startswith("Ray actor pid ") for r in retried)
    assert facts["node_kill"]["node2_ran"], "the killed node had run episodes of this run"
    assert "requeued" in facts["node_kill"]["stderr"]


@pytest.mark.slow
@ray_missing
def test_a_killed_driver_resumes_like_a_local_run(tmp_path):
    facts = scenario("driver_kill", tmp_path, timeout=900)
    assert 6 <= facts["after_kill"] < 30
    assert facts["resume"]["rc"] == 0, facts["resume"]["stderr"]
    assert f"{facts['after_kill']} of 30 episodes already recorded" in " ".join(facts["resume"]["stderr"].split())
    assert len({r["job_id"] for r in facts["records_k"]}) == len(facts["records_k"]) == 30
    assert same(facts["records_k"]) == same(facts["records_whole"])

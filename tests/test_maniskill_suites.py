"""The ManiSkill suites end to end on CPU: declared tables against the built envs, the runner, experts.

Real ManiSkill/SAPIEN/PhysX on CPU (no Vulkan needed); skipped as a whole without the extra, except
the tests of what a user without the extra sees. The reference-policy success rates over every
seen cell are `slow`; image observations need a Vulkan device (`vulkan`).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.core.errors import ConfigError
from tests.fixtures import each_env

REPO = Path(__file__).resolve().parents[1]
HAS_MS = True
try:
    import mani_skill  # noqa: F401
except ImportError:
    HAS_MS = False
needs_ms = pytest.mark.skipif(not HAS_MS, reason="the maniskill extra is not installed (pip install -e '.[maniskill]')")


def suite(name: str, **options):
    from bench import api

    return api.load_suite(name, **options)


# -- without the extra -------------------------------------------------------------------------
def test_without_the_extra_list_says_what_is_missing_and_check_skips(monkeypatch, capsys):
    from bench.cli import listing
    from bench.cli.check import main as check_main
    from bench.protocols import registry
    from bench.sims import maniskill as sim_maniskill

    monkeypatch.setattr(
        sim_maniskill, "missing_extra", lambda: "needs mani-skill and sapien: pip install -e '.[maniskill]'"
    )
    assert listing.main_list([]) == 0
    out = capsys.readouterr().out
    assert "maniskill_tasks (v1" in out and "tasks   unseen PegInsertionSide" in out
    assert out.count("unavailable: needs mani-skill and sapien: pip install -e '.[maniskill]'") == 2
    with pytest.raises(ConfigError, match=r"ManiSkill suites needs mani-skill and sapien"):
        suite("maniskill_tasks")
    monkeypatch.setattr(registry, "names", lambda group: ["maniskill_held_out_robots", "maniskill_tasks"])
    assert check_main(["states=false", "contract=false"]) == 0  # checking every suite skips them
    out = capsys.readouterr().out
    assert "maniskill_tasks: skipped (unavailable: needs mani-skill and sapien" in out
    assert "maniskill_held_out_robots: skipped (unavailable:" in out


# -- declared tables vs the built envs ---------------------------------------------------------
@needs_ms
@pytest.mark.parametrize("name", ["maniskill_tasks", "maniskill_held_out_robots"])
def test_declared_obs_spec_equals_the_built_env_for_every_cell(name):
    from suites.maniskill_common import TASKS

    s = suite(name)
    for cell, env in each_env(s):
        assert dict(env.obs_spec) == dict(s.obs_spec(cell)), cell.key
        for obj in TASKS[cell.task].objects:  # perturb.mass's default targets exist
            assert obj in env.base.scene.actors, (cell.key, obj, list(env.base.scene.actors))


@needs_ms
def test_control_mode_and_camera_tables_match_maniskill():
    from bench.sims.maniskill import ManiSkillEnv, cameras_of
    from suites.maniskill_common import CONTROL_MODES

    for robot, modes in CONTROL_MODES.items():
        env = ManiSkillEnv("PickCube-v1", robot, 10)
        try:
            assert tuple(env.base.agent.supported_control_modes) == modes, robot
            declared = [c.uid for c in _as_list(env.base._default_sensor_configs)]
            declared += [c.uid for c in _as_list(env.base.agent._sensor_configs)]
            assert tuple(declared) == cameras_of(robot), robot
        finally:
            env.close()


def _as_list(x):
    if x is None:
        return []
    if isinstance(x, dict):
        return list(x.values())
    return list(x) if isinstance(x, (list, tuple)) else [x]


@needs_ms
@pytest.mark.parametrize(
    "name,task,robot", [("maniskill_tasks", "PushCube", "panda"), ("maniskill_held_out_robots", "PickCube", "so100")]
)
def test_bench_check_contract(name, task, robot):
    from bench.execution.check import check_contract, check_suite

    s = suite(name)
    assert check_suite(s) == []
    cell = next(c for c in s.all_cells() if c.task == task and c.robot == robot)
    assert check_contract(s, cell, s.default_horizon) == []


# -- bad keys ------------------------------------------------------------------------------------
@needs_ms
def test_bad_options_are_one_line():
    with pytest.raises(ConfigError, match=r"obs='depth': valid: state, rgb, state\+rgb"):
        suite("maniskill_tasks", obs="depth")
    with pytest.raises(ConfigError, match=r"image_size=8: must be in \[16, 1024\]"):
        suite("maniskill_tasks", obs="rgb", image_size=8)
    with pytest.raises(
        ConfigError,
        match=r"control_mode='pd_joint_position': panda supports pd_joint_delta_pos, "
        r"pd_joint_pos.* Did you mean 'pd_joint_pos'\?",
    ):
        suite("maniskill_tasks", control_mode="pd_joint_position")
    with pytest.raises(ConfigError, match=r"cameras=\['base_camera'\]: cameras need obs=rgb"):
        suite("maniskill_held_out_robots", cameras=["base_camera"])
    with pytest.raises(ConfigError, match=r"reset='hard': valid: rebuild, soft"):
        suite("maniskill_held_out_robots", reset="hard")
    from suites.maniskill_common import cell_cameras  # the declared spec's check (building the suite needs Vulkan)

    with pytest.raises(
        ConfigError,
        match=r"cameras: 'hand_camera' is not a camera of a table-top task with fetch; "
        r"valid: base_camera, fetch_head, fetch_hand",
    ):
        cell_cameras("fetch", "rgb", ["hand_camera"])


@needs_ms
def test_cameras_without_a_vulkan_device_are_refused_when_the_run_is_planned(tmp_path):
    """obs=rgb on a machine without Vulkan: one line naming the fix, exit 2, nothing written, no episode."""
    from bench.sims.sapien_novulkan import render_device_available

    if render_device_available():
        pytest.skip("this machine has a Vulkan device: ManiSkill renders cameras here")
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "bench",
            "run",
            "suite=maniskill_tasks",
            "tasks=[PickCube]",
            "obs=rgb",
            "policy=random",
            "episodes=2",
            "workers=1",
            f"out={tmp_path}",
            "run_id=rgb",
        ],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=300,
    )
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert out.returncode == 2 and len(lines) == 1, out.stderr
    assert re.search(
        r"^error: obs=rgb: ManiSkill cameras need a Vulkan device .*fetch_lavapipe\.sh.*obs=state", lines[0]
    )
    assert not (tmp_path / "rgb").exists()


@needs_ms
def test_the_gpu_backend_names_the_physx_library_it_lacks():
    """sim_backend=physx_cuda needs a CUDA device and SAPIEN's PhysX GPU library (downloaded at first use)."""
    import torch

    from bench.sims.maniskill import physx_gpu_library

    missing = physx_gpu_library()
    if missing is not None:
        assert re.search(r"\.sapien/physx/[^/]+/libPhysXGpu_64\.so$", missing)
    want = "no CUDA device" if not torch.cuda.is_available() else "PhysX GPU library .* is missing"
    if torch.cuda.is_available() and missing is None:
        pytest.skip("this machine has CUDA and the PhysX GPU library: physx_cuda can run")
    with pytest.raises(ConfigError, match=rf"sim_backend=physx_cuda: .*{want}.*use sim_backend=physx_cpu"):
        suite("maniskill_tasks", sim_backend="physx_cuda")


@needs_ms
def test_cli_bad_control_mode_exits_2_with_one_line(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "bench", "run", "suite=maniskill_tasks", "control_mode=pd_ee_posee", f"out={tmp_path}"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=300,
    )
    assert out.returncode == 2
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: control_mode='pd_ee_posee': panda supports")
    assert "Did you mean 'pd_ee_pose'?" in lines[0] and not any(tmp_path.iterdir())


# -- through the runner ------------------------------------------------------------------------
def _run(tmp_path, name, **kw):
    from bench import api

    options = kw.pop("suite_options", {})
    cfg = api.RunConfig(suite=name, out=str(tmp_path), workers=1, suite_options=options, **kw)
    return api.run(cfg)


@needs_ms
def test_maniskill_tasks_expert_through_the_runner(tmp_path):
    res = _run(tmp_path, "maniskill_tasks", tasks=["PickCube", "PokeCube"], episodes=2, run_id="a")
    recs = res.records
    assert len(recs) == 4 and all(r.error is None for r in recs), [r.error for r in recs]
    assert all(r.success_once for r in recs)
    assert {r.backend for r in recs} == {"mani_skill-3.0.1/sapien-3.0.3/physx_cpu"}
    again = _run(tmp_path, "maniskill_tasks", tasks=["PickCube", "PokeCube"], episodes=2, run_id="b").records
    key = lambda r: r.job_id  # noqa: E731
    for x, y in zip(sorted(recs, key=key), sorted(again, key=key)):  # deterministic expert and resets
        assert (x.success_once, x.length, x.steps_to_success, x.init_state_hash) == (
            y.success_once,
            y.length,
            y.steps_to_success,
            y.init_state_hash,
        )
        assert x.return_ == pytest.approx(y.return_, abs=1e-9)


@needs_ms
def test_held_out_robots_perturbations_recorded_and_paired(tmp_path):
    res = _run(
        tmp_path,
        "maniskill_held_out_robots",
        robots=["panda"],
        tasks=["PickCube"],
        episodes=2,
        perturb={"friction": [0.5], "gravity": [0.5], "action_noise": [0.1]},
        run_id="p",
    )
    recs = res.records
    assert len(recs) == 8 and all(r.error is None for r in recs), [r.error for r in recs]
    by_cond: dict[str, list] = {}
    for r in recs:
        by_cond.setdefault(r.condition, []).append(r)
    assert set(by_cond) == {"nominal", "friction=0.5", "gravity=0.5", "action_noise=0.1"}
    assert {r.params.get("gravity") for r in by_cond["gravity=0.5"]} == {0.5}
    hashes = {c: sorted(r.init_state_hash for r in rs) for c, rs in by_cond.items()}
    assert len({tuple(h) for h in hashes.values()}) == 1  # the same starts under every condition
    assert all(r.success_once for r in by_cond["nominal"])


@needs_ms
def test_expert_needs_pd_joint_pos(tmp_path):
    res = _run(
        tmp_path,
        "maniskill_tasks",
        tasks=["PushCube"],
        episodes=1,
        run_id="c",
        suite_options={"control_mode": "pd_ee_delta_pos"},
    )
    (rec,) = res.records
    assert "the motion-planning expert for PushCube commands pd_joint_pos" in rec.error


@needs_ms
def test_random_policy_and_interface_axes_on_every_robot(tmp_path):
    res = _run(
        tmp_path,
        "maniskill_held_out_robots",
        policy="random",
        tasks=["PickCube"],
        episodes=1,
        horizon=20,
        perturb={"latency": [1]},
        run_id="r",
    )
    assert len(res.records) == 8 and all(r.error is None for r in res.records), [r.error for r in res.records]
    assert {r.robot for r in res.records} == {"panda", "panda_wristcam", "fetch", "so100"}


# -- the reference policies on their seen cells (the >= 0.9 claim) -------------------------------
# seen cells whose reference falls short, with the floor measured (run seed 0, 20 episodes: 16/20)
KNOWN_SHORT = {"LiftPegUpright/panda": 0.7}  # ManiSkill's own solution: a screw plan fails or the peg tips back


@needs_ms
@pytest.mark.slow
@pytest.mark.parametrize("name", ["maniskill_tasks", "maniskill_held_out_robots"])
def test_reference_policy_at_least_90_percent_on_seen_cells(tmp_path, name):
    res = _run(tmp_path, name, splits=["seen"], episodes=10, run_id="ref")
    rates: dict[str, list[bool]] = {}
    for r in res.records:
        assert r.error is None, r.error
        rates.setdefault(r.task + "/" + r.robot, []).append(r.success_once)
    low = {k: float(np.mean(v)) for k, v in rates.items() if np.mean(v) < KNOWN_SHORT.get(k, 0.9)}
    assert not low, low


# -- images (a Vulkan device) ------------------------------------------------------------------
_RGB = r"""
import json, sys, numpy as np
from bench import api
s = api.load_suite("maniskill_held_out_robots", obs="state+rgb", image_size=64)
cell = next(c for c in s.all_cells() if c.robot == "panda_wristcam" and c.task == "PickCube")
env = s.make_env(cell, 10)
out = {}
for k in (0, 1):
    obs = env.reset(5)
    obs, *_ = env.step(np.array([0.5, 0, 0, -1], np.float32))
    out[k] = {key: [list(v.shape), str(v.dtype), int(v.sum())] for key, v in obs.items() if key.startswith("rgb.")}
print(json.dumps({"spec": sorted(s.obs_spec(cell)), "obs": out, "render": env.render}))
"""


@needs_ms
@pytest.mark.vulkan
def test_rgb_observations_on_cpu(vulkan_icd):
    env = {**os.environ, "VK_ICD_FILENAMES": vulkan_icd}
    out = subprocess.run([sys.executable, "-c", _RGB], capture_output=True, text=True, cwd=REPO, env=env, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["render"] == "vulkan"
    assert got["spec"] == ["rgb.base_camera", "rgb.hand_camera", "state", "task"]
    first, second = got["obs"]["0"], got["obs"]["1"]
    assert first == second  # same seed and action -> the same images
    for key, (shape, dtype, total) in first.items():
        assert shape == [64, 64, 3] and dtype == "uint8" and total > 0, key


@needs_ms
def test_motion_plan_expert_thread_ends_when_the_episode_is_cut_short():
    """An episode ended mid-plan (horizon, timeout, error) unwinds the solution's thread at the next reset or
    when the policy is dropped; nothing is left blocked."""
    import gc
    import threading

    s = suite("maniskill_tasks")
    cell = next(c for c in s.all_cells() if c.task == "PushCube")
    env = s.make_env(cell, 250)
    pol = s.make_expert(cell, env)
    obs = env.reset(0)
    pol.reset(0)
    for _ in range(5):
        obs, *_ = env.step(pol.act(obs))
    thread = pol._thread
    assert thread is not None and thread.is_alive()
    pol.reset(1)
    thread.join(timeout=10)
    assert not thread.is_alive()
    env.reset(1)
    for _ in range(5):
        obs, *_ = env.step(pol.act(obs))
    thread = pol._thread
    del pol
    gc.collect()
    thread.join(timeout=10)
    assert not thread.is_alive() and not any(t.name.startswith("mp-") and t.is_alive() for t in threading.enumerate())
    env.close()

"""ManiSkill3 on CPU: the adapter, the no-Vulkan stand-ins, PhysX perturbation axes, bad input.

Runs real ManiSkill/SAPIEN/PhysX (the `maniskill` extra); skipped as a whole when it is absent.
Without a Vulkan device (these machines) the stand-ins of `bench.sims.sapien_novulkan` are installed
in this process by the first env built; tests that need real Vulkan materials run in a
subprocess with `VK_ICD_FILENAMES` (marked `vulkan`, skipped when no device is set up).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mani_skill", reason="the maniskill extra is not installed (pip install -e '.[maniskill]')")

from bench.core.errors import ConfigError  # noqa: E402
from bench.protocols import STATE, TASK, check_obs  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def make(task="PickCube-v1", robot="panda", horizon=60, **kw):
    from bench.sims.maniskill import ManiSkillEnv, NativeInterface

    mode = kw.pop("control_mode", "pd_joint_pos")
    return ManiSkillEnv(task, robot, horizon, interface=NativeInterface(mode), object_names=("cube",), **kw)


def actions(env, n=60, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(env.action_spec.low, env.action_spec.high, size=(n, env.action_spec.dim)).astype(np.float32)


def trajectory(env, seed, acts):
    env.reset(seed)
    out = []
    for a in acts:
        env.step(a)
        out.append(env.base.get_state()[0].numpy().copy())
    return np.array(out)


@pytest.fixture(scope="module")
def pick():
    env = make()
    yield env
    env.close()


# -- the contract ------------------------------------------------------------------------------
def test_reset_step_success_and_spec(pick):
    obs = pick.reset(3)
    assert check_obs(pick.obs_spec, obs) is None
    assert pick.obs_spec[STATE].shape == (42,) and dict(pick.obs_spec[STATE].fields)["tcp_pose"] == 7
    assert pick.action_spec.names[-1] == "gripper" and pick.action_spec.dim == 8
    obs, reward, terminated, truncated, info = pick.step(np.zeros(8, np.float32))
    assert check_obs(pick.obs_spec, obs) is None
    assert isinstance(reward, float) and terminated is False and truncated is False
    assert isinstance(pick.success(), bool) and info["success"] is pick.success()
    assert pick.fps == 20.0 and pick.backend.startswith("mani_skill-3.0.1/sapien-3.0.3/physx_cpu")
    assert pick.mujoco is None and pick.inputs is None and pick.model_axes is not None


def test_truncated_at_horizon():
    env = make(horizon=3)
    env.reset(0)
    flags = [env.step(np.zeros(8, np.float32))[3] for _ in range(3)]
    env.close()
    assert flags == [False, False, True]


def test_seed_fixes_the_initial_state(pick):
    pick.reset(1)
    a = pick.init_state().copy()
    pick.reset(2)
    b = pick.init_state().copy()
    pick.reset(1)
    assert np.array_equal(a, pick.init_state()) and not np.array_equal(a, b)


def test_rebuild_reset_same_trajectory_whatever_ran_before(pick):
    """The default reset rebuilds the scene: same seed + actions -> same trajectory after other episodes."""
    acts = actions(pick, 60)
    first = trajectory(pick, 7, acts)
    trajectory(pick, 3, actions(pick, 60, seed=1))
    again = trajectory(pick, 7, acts)
    assert np.array_equal(first, again)


def test_soft_reset_restores_the_initial_state_but_not_the_contact_history():
    """What reset=soft gives up (the reason rebuild is the default): measured, not assumed."""
    env = make(reset="soft")
    acts = actions(env, 60)
    first = trajectory(env, 7, acts)
    env.reset(7)
    init_again = env.init_state().copy()
    again = trajectory(env, 7, acts)
    env.close()
    fresh = make(reset="soft")
    fresh.reset(7)
    assert np.array_equal(fresh.init_state(), init_again)  # the initial state is exact ...
    assert np.array_equal(trajectory(fresh, 7, acts), first)  # ... and a fresh scene repeats the first run
    fresh.close()
    assert not np.array_equal(first, again)  # ... but the hand hitting the table resolves differently later


def test_task_instruction_in_obs():
    env = make(instruction="pick up the cube")
    obs = env.reset(0)
    assert obs[TASK] == "pick up the cube" and env.obs_spec[TASK].dtype == "str"
    assert check_obs(env.obs_spec, obs) is None
    env.close()


# -- the stand-ins -----------------------------------------------------------------------------
def test_stand_ins_installed_without_vulkan(pick):
    from bench.sims import sapien_novulkan as nv

    if nv._state["mode"] == "vulkan":
        pytest.skip("this process has a Vulkan device: the stand-ins are not needed")
    import sapien.render

    assert pick.render == "stand-ins" and sapien.render.RenderMaterial is nv.InertRenderMaterial
    mat = sapien.render.RenderMaterial(base_color=[1, 0, 0, 1])
    mat.set_base_color([0, 1, 0, 1])
    assert mat.get_base_color() == [0, 1, 0, 1]
    nv.install()  # idempotent


def test_stand_ins_refuse_unchecked_versions(monkeypatch):
    from bench.sims import sapien_novulkan as nv

    monkeypatch.setattr(nv, "_state", {"mode": None})
    monkeypatch.setattr(nv, "installed_versions", lambda: {"mani-skill": "3.0.2", "sapien": "3.0.3"})
    with pytest.raises(
        ConfigError,
        match=r"checked against mani-skill==3\.0\.1, sapien==3\.0\.3, found mani-skill "
        r"3\.0\.2, sapien 3\.0\.3",
    ):
        nv.install()


def test_cameras_without_vulkan_one_line(pick):
    from bench.sims import sapien_novulkan as nv

    if nv._state["mode"] == "vulkan":
        pytest.skip("this process has a Vulkan device")
    with pytest.raises(ConfigError, match=r"obs=rgb: ManiSkill cameras need a Vulkan device .*fetch_lavapipe\.sh"):
        make(obs="rgb")


_PROBE = r"""
import json, sys, numpy as np
import bench.sims.sapien_novulkan as nv
if sys.argv[1] == "stand-ins":
    nv.install()
from bench.sims.maniskill import ManiSkillEnv, NativeInterface
env = ManiSkillEnv("PickCube-v1", "panda", 60, interface=NativeInterface("pd_joint_pos"))
acts = np.random.default_rng(0).uniform(env.action_spec.low, env.action_spec.high, size=(60, 8)).astype(np.float32)
env.reset(11)
states = []
for a in acts:
    env.step(a)
    states.append(env.base.get_state()[0].numpy().tolist())
print(json.dumps({"render": env.render, "states": states}))
"""


def _probe(mode: str, vulkan: str | None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "VK_ICD_FILENAMES"}
    if vulkan:
        env["VK_ICD_FILENAMES"] = vulkan
    out = subprocess.run(
        [sys.executable, "-c", _PROBE, mode], capture_output=True, text=True, cwd=REPO, env=env, timeout=300
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_stand_ins_same_trajectory_across_processes():
    """Without Vulkan: two processes, each with the stand-ins, give the same trajectory to the bit."""
    a, b = _probe("auto", None), _probe("auto", None)
    assert a["states"] == b["states"]


@pytest.mark.vulkan
def test_stand_ins_never_change_physics(vulkan_icd):
    """With a Vulkan device both can run: real SAPIEN materials vs the stand-ins, same trajectory to the bit."""
    real = _probe("auto", vulkan_icd)
    inert = _probe("stand-ins", vulkan_icd)
    no_device = _probe("auto", None)
    assert real["render"] == "vulkan" and inert["render"] == "stand-ins" and no_device["render"] == "stand-ins"
    assert real["states"] == inert["states"] == no_device["states"]


# -- bad input -----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kw, match",
    [
        ({"robot": "xarm6_robotiq"}, r"PickCube-v1 with robot xarm6_robotiq: needs an asset download \(xarm6\)"),
        (
            {"task": "TurnFaucet-v1"},
            r"TurnFaucet-v1 with robot panda: needs an asset download \(partnet_mobility_faucet \(\d+ of \d+ parts\)\)",
        ),
        ({"task": "PickCube"}, r"task 'PickCube' is not a ManiSkill task\. Did you mean 'PickCube-v1'\?"),
        ({"robot": "pandas"}, r"robot 'pandas' is not a ManiSkill robot\. Did you mean 'panda'"),
        (
            {"control_mode": "pd_ee_velocity"},
            r"control_mode='pd_ee_velocity': panda supports pd_joint_delta_pos, pd_joint_pos, pd_ee_delta_pos",
        ),
    ],
    ids=["robot-assets", "task-assets", "unknown-task", "unknown-robot", "unknown-control-mode"],
)
def test_refused_in_one_line_and_never_prompts(kw, match):
    """An unknown task, robot or control mode, or one whose assets are not on disk: one line, no download prompt."""
    with pytest.raises(ConfigError, match=match):
        make(**kw)
    assert os.environ["MS_SKIP_ASSET_DOWNLOAD_PROMPT"] == "1"


def test_empty_folder_of_a_failed_download_counts_as_missing(monkeypatch, tmp_path):
    from mani_skill.utils import assets

    from bench.sims.maniskill import missing_assets

    src = assets.DATA_SOURCES["ycb"]
    monkeypatch.setattr(src, "output_dir", tmp_path)
    (tmp_path / src.target_path).mkdir(parents=True)  # what an interrupted download leaves
    assert assets.is_data_source_downloaded("ycb")  # ManiSkill's own check is fooled
    assert missing_assets("PickSingleYCB-v1", "panda") == ["ycb"]


def test_gpu_backend_refused_without_cuda():
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a CUDA device")
    with pytest.raises(ConfigError, match=r"sim_backend=physx_cuda: this machine has no CUDA device"):
        make(sim_backend="physx_cuda")


# -- PhysX perturbation axes ---------------------------------------------------------------------
def _slide(env, seed=0):
    """Distance the cube slides in 10 control steps after a 1 m/s push along x (the robot holds still)."""
    env.reset(seed)
    hold = np.append(env.base.agent.robot.get_qpos()[0].numpy()[:7], 1.0).astype(np.float32)
    cube = env.base.cube
    x0 = float(cube.pose.p[0, 0])
    cube._bodies[0].set_linear_velocity([1.0, 0.0, 0.0])
    for _ in range(10):
        env.step(hold)
    return float(cube.pose.p[0, 0]) - x0


def test_friction_axis_changes_sliding_and_restores_exactly():
    env = make(reset="soft")
    axes = env.model_axes
    nominal = _slide(env)
    axes.apply("friction", 0.5, {})
    slippery = _slide(env)
    axes.restore()
    again = _slide(env)
    env.close()
    assert slippery > 1.5 * nominal > 0  # Coulomb: half the friction, about twice the distance
    assert again == pytest.approx(nominal, abs=1e-6)


def test_mass_damping_gain_edit_physx_and_restore():
    env = make()
    axes, base = env.model_axes, env.base
    cube = base.cube._bodies[0]
    joint = base.agent.robot.active_joints[0]._objs[0]
    m0, k0, d0 = cube.mass, joint.stiffness, joint.damping
    axes.apply("mass", 3.0, {})
    axes.apply("gain", 0.5, {})
    axes.apply("damping", 2.0, {"joints": ["panda_joint1"]})
    env.reset(0)  # rebuild: the edits are re-applied to the new scene
    cube = env.base.cube._bodies[0]
    joint = env.base.agent.robot.active_joints[0]._objs[0]
    assert cube.mass == pytest.approx(3 * m0) and joint.stiffness == pytest.approx(0.5 * k0)
    assert joint.damping == pytest.approx(2 * d0)
    assert env.base.agent.robot.active_joints[1]._objs[0].damping == pytest.approx(d0)  # not targeted
    axes.restore()
    env.reset(0)
    assert env.base.cube._bodies[0].mass == pytest.approx(m0)
    assert env.base.agent.robot.active_joints[0]._objs[0].damping == pytest.approx(d0)
    env.close()


def test_gravity_rebuilds_scene_same_initial_state_and_back():
    env = make(reset="soft")
    acts = actions(env, 30)
    nominal = trajectory(env, 5, acts)
    init = env.init_state().copy()
    env.model_axes.apply("gravity", 0.5, {})
    env.reset(5)
    assert np.array_equal(env.init_state(), init)  # paired by seed: the same start under both conditions
    assert env.base.scene.px.config.gravity[2] == pytest.approx(-4.905)
    env.model_axes.restore()
    back = trajectory(env, 5, acts)  # rebuilt at nominal gravity: a fresh scene, the same run
    env.close()
    assert np.array_equal(back, nominal)


def test_named_targets_and_unsupported_axes_are_one_line():
    env = make()
    axes = env.model_axes
    with pytest.raises(
        ConfigError,
        match=r"perturb\.mass\.bodies: 'cubee' is not a body of PickCube-v1 with panda; "
        r"valid: .*Did you mean 'cube'\?",
    ):
        axes.apply("mass", 2.0, {"bodies": ["cubee"]})
    with pytest.raises(ConfigError, match=r"perturb\.damping\.joints: 'joint1' is not a joint"):
        axes.apply("damping", 2.0, {"joints": ["joint1"]})
    with pytest.raises(
        ConfigError,
        match=r"perturb\.armature: not available on ManiSkill/PhysX; model axes there: "
        r"damping, friction, gain, gravity, link_mass, mass",
    ):
        axes.apply("armature", 2.0, {})
    with pytest.raises(ConfigError, match=r"perturb\.friction\.geoms: friction takes no geoms"):
        axes.apply("friction", 2.0, {"geoms": ["x"]})
    env.close()


def test_friction_on_named_bodies_leaves_shared_materials_of_others_alone():
    env = make(reset="soft")
    table = env.base.scene.actors["table-workspace"]._bodies[0].collision_shapes[0]
    before = table.physical_material.static_friction
    env.model_axes.apply("friction", 0.1, {"bodies": ["cube"]})
    cube = env.base.scene.actors["cube"]._bodies[0].collision_shapes[0]
    assert cube.physical_material.static_friction == pytest.approx(0.1 * before)
    assert table.physical_material.static_friction == pytest.approx(before)  # it shared the cube's material
    env.model_axes.restore()
    assert cube.physical_material.static_friction == pytest.approx(before)
    env.close()


def test_perturb_module_dispatches_to_model_axes():
    """bench.sims.perturb.reset.apply (the runner's entry) reaches the PhysX axes and records the value."""
    from bench.sims import perturb
    from bench.sims.perturb import axes

    env = make()
    conds = axes.conditions_from_config({"mass": [2.0], "latency": [2]})
    stepper, params = perturb.apply(env, conds[1], np.random.default_rng(0))
    assert stepper is env and params == {"mass": 2.0}
    stepper.reset(0)
    assert env.base.cube._bodies[0].mass == pytest.approx(2 * 0.064, rel=1e-4)
    stepper, params = perturb.apply(env, conds[2], np.random.default_rng(0))
    assert params == {"latency": 2} and stepper is not env
    stepper.reset(0)
    assert env.base.cube._bodies[0].mass == pytest.approx(0.064, rel=1e-4)  # restored for the next condition
    env.close()


# -- the GPU path's batched env, on the CPU backend (one env) -------------------------------------
def test_vec_env_per_env_seed_matches_the_one_env_adapter():
    """ManiSkillVecEnv resets env i alone with its own seed: the start is the one-env adapter's for that seed."""
    from bench.sims.maniskill import NativeInterface
    from bench.sims.maniskill_vec import ManiSkillVecEnv

    vec = ManiSkillVecEnv("PickCube-v1", "panda", 1, interface=NativeInterface("pd_joint_pos"), sim_backend="physx_cpu")
    one = make(reset="soft")
    (obs,) = vec.reset([21])
    ref = one.reset(21)
    assert np.array_equal(vec.init_states()[0], one.init_state())
    assert np.array_equal(obs[STATE], ref[STATE])
    acts = actions(one, 5)
    for a in acts:
        (obs,), reward, success = vec.step(a[None])
        ref, r, *_ = one.step(a)
        assert np.array_equal(obs[STATE], ref[STATE]) and reward[0] == pytest.approx(r) and success[0] == one.success()
    with pytest.raises(ConfigError, match=r"num_envs=4: ManiSkill's physx_cpu backend holds one env"):
        ManiSkillVecEnv("PickCube-v1", "panda", 4, sim_backend="physx_cpu")
    vec.close()
    one.close()

"""suite koch: the Koch v1.1 reach scene (ManiSkill's URDF in MuJoCo), its split, its scripted expert, the model
axes, its servos calibrated from a LeRobot dataset recorded with hidden servo parameters, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench.calibrate.servo.arm import calibrate_arm_servos, parse_servo_arm_spec
from bench.calibrate.servo.arm.model import describe
from bench.cli import main
from bench.protocols import STATE, EnvAdapter, check_obs
from benchmarks.bench_so101_calibration import HIDDEN_KOCH, record  # the benchmark's hidden servos and recorder
from suites import koch

pytestmark = pytest.mark.skipif(koch.assets_dir() is None, reason="ManiSkill's Koch assets are not installed (.[koch])")


def _cell(scene: str = "nominal"):
    suite = koch.Koch()
    return suite, next(c for c in suite.all_cells() if c.env == scene)


def test_split_follows_the_declared_region():
    for name in koch.SEEN_SCENES:
        assert koch.in_seen_region(koch.scene_params(name)), name
    for name in koch.UNSEEN_SCENES:
        assert not koch.in_seen_region(koch.scene_params(name)), name
    splits = {c.env: c.split for c in koch.Koch().all_cells()}
    assert splits["nominal"] == "seen" and splits["far"] == "unseen" and len(splits) == 8


def test_model_is_the_urdf_with_lerobot_joint_names_and_declared_servos():
    suite, cell = _cell()
    env = suite.make_env(cell, 5)
    try:
        assert isinstance(env, EnvAdapter) and env.fps == 30.0
        m = env.mujoco.model
        assert env.action_spec.names == koch.ACTION_NAMES
        assert m.jnt_range[m.joint("shoulder_lift").id].tolist() == pytest.approx([0.0, 2.2])  # radians, as the URDF
        elbow = m.actuator("elbow_flex").id
        assert m.actuator_gainprm[elbow, 0] == pytest.approx(1500 * koch.TORQUE_PER_KP)  # lerobot's elbow P gain
        assert m.actuator_biasprm[elbow, 1] == pytest.approx(-1500 * koch.TORQUE_PER_KP)
        assert m.actuator_forcerange[elbow].tolist() == pytest.approx([-0.52, 0.52])  # XL330 stall at 5 V
        a, b, a2 = env.reset(1), env.reset(2), env.reset(1)
        assert check_obs(suite.obs_spec(cell), a) is None
        assert np.array_equal(a[STATE], a2[STATE]) and not np.array_equal(a[STATE], b[STATE])
        for _ in range(30):  # the servos hold the rest pose
            obs, *_ = env.step(np.array(koch.REST, np.float32))
        assert np.abs(obs[STATE][:6] - np.array(koch.REST)).max() < 0.1
    finally:
        env.close()


def test_scripted_expert_reaches_seen_and_unseen_targets():
    suite = koch.Koch()
    for scene in ("nominal", "far", "above"):
        cell = next(c for c in suite.all_cells() if c.env == scene)
        env = suite.make_env(cell, koch.HORIZON)
        expert = suite.make_expert(cell, env)
        for seed in range(2):
            obs = env.reset(seed)
            expert.reset(seed)
            won = False
            for _ in range(koch.HORIZON):
                obs, _, _, _, info = env.step(expert.act(obs))
                won |= bool(info["is_success"])
            assert won, (scene, seed)
        env.close()


def test_run_end_to_end_with_model_axes(tmp_path, capsys):
    argv = ["run", "suite=koch", "envs=[nominal]", "episodes=2", "workers=1"]
    argv += ["perturb.gain=[0.3]", "perturb.damping=[3]", "perturb.frictionloss=[2]"]
    assert main([*argv, f"out={tmp_path}", "run_id=r"]) == 0
    text = (tmp_path / "r" / "summary.json").read_text()
    for condition in ("gain=0.3", "damping=3", "frictionloss=2"):
        assert condition in text


def test_servos_calibrated_from_a_recording_with_hidden_servos(tmp_path):
    """Known truth: hidden P gains, damping and friction per joint, recorded by `bench run suite=koch
    calibration=HIDDEN record=DIR policy=baselines.koch_scripted:excitation`, then calibrated from the dataset."""
    logs, hidden = record(tmp_path, episodes=8, seed=0, name="koch")
    spec = parse_servo_arm_spec({"method": "servo_arm", "arm": "koch", "units": "rad"}, tmp_path / "spec.yaml")
    cal = calibrate_arm_servos(spec, logs, seed=0)
    assert np.allclose(cal.servos.stiffness, hidden.stiffness, rtol=0.05)
    assert np.allclose(cal.servos.damping, hidden.damping, rtol=0.15)
    lo, hi = (b[:18] for b in cal.interval())  # stiffness, damping, Coulomb (kind-major); the armature is held
    truth = np.concatenate([hidden.stiffness, hidden.damping, hidden.coulomb])
    assert np.mean((lo <= truth) & (truth <= hi)) >= 16 / 18
    fr = cal.errors["free_run"]
    assert fr["fitted"]["rmse"] < 0.5 * fr["declared"]["rmse"]  # held-out episodes predicted better
    kp = describe(cal.arm, cal.servos, spec.torque_per_kp)  # firmware gains in the Koch's units (Position P Gain)
    assert kp["elbow_flex"]["kp"] == pytest.approx(HIDDEN_KOCH["elbow_flex"]["kp"], rel=0.05)
    assert json.loads((tmp_path / "hidden" / "calibration.json").read_text())["apply"]


@pytest.mark.parametrize(
    ("arg", "says"),
    [("envs=[nominl]", "Did you mean 'nominal'"), ("cameras=[frnt]", "Did you mean 'front'")],
)
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, arg, says):
    assert main(["run", "suite=koch", arg, f"out={tmp_path}", "run_id=bad"]) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1
    assert not (tmp_path / "bad").exists()


def test_latency_first_frames_hold_the_start_not_joint_zero():
    """A delayed servo keeps its last goal: `perturb.latency`'s first frames repeat the env's hold action (the start
    pose's goals); joint zero would stretch the folded Koch out."""
    from bench.sims.perturb.interface import PerturbedInterface

    suite, cell = _cell()
    env = PerturbedInterface(suite.make_env(cell, 10), np.random.default_rng(0), latency=3)
    try:
        start = env.reset(0)[STATE][:6]
        assert np.allclose(start, koch.REST, atol=1e-6)
        far = np.array([0.5, 1.0, 1.0, 0.5, 0.5, 1.0], np.float32)
        for _ in range(3):  # the queue's frames: the start held, the far goal not yet acting
            obs, *_ = env.step(far)
        assert np.abs(obs[STATE][:6] - start).max() < 0.05
        for _ in range(20):
            obs, *_ = env.step(far)
        assert np.abs(obs[STATE][:6] - far).max() < 0.3  # then the commands act
    finally:
        env.close()

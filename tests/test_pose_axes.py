"""Pose axes (`init_qpos`, `object_pose`, `object_yaw`): the episode starts from a moved arm or object layout.

Checked on the real simulators: the initial state differs from the nominal one by exactly the offset drawn
(and recorded), the first observation is a fresh observation of the edited state (images re-rendered), the
controllers follow the edited joints (robosuite's OSC holds the new pose, Meta-World's mocap is carried
with the hand), draws are deterministic per seed, and bad input is one line, exit 2, nothing written."""

from __future__ import annotations

import math
import re

import mujoco
import numpy as np
import pytest

from bench import api
from bench.cli import main
from bench.core.errors import ConfigError
from bench.protocols import STATE, ActionSpec, Feature, MujocoHandle
from bench.protocols.env import AdapterBase, state_hash
from bench.protocols.suite import condition_rng
from bench.sims import perturb
from bench.sims.perturb import axes

pytest.importorskip("robosuite")

SEED = 11
LIFT = ["suite=held_out_robots", "robots=[Panda]", "policy=scripted", "workers=1"]


def _cond(**perturbs):
    return axes.conditions_from_config(perturbs)[1]


def _start(env, cond, seed: int = SEED):
    """(nominal qpos, first observation, params, stepper) of an episode of `cond` after a nominal one."""
    env.reset(seed)
    nominal = env.mujoco.data.qpos.copy()
    stepper, params = perturb.apply(env, cond, condition_rng(seed, cond))
    return nominal, stepper.reset(seed), params, stepper


@pytest.fixture(scope="module")
def lift():
    from suites.lift import make_env  # robosuite: imported only when this fixture builds an env

    env = make_env("Lift", "Panda", 20)
    yield env
    env.close()


@pytest.fixture(scope="module")
def sawyer():
    from bench.sims.metaworld import MetaWorldEnv  # Meta-World: imported only when this fixture builds an env

    env = MetaWorldEnv("pick-place-v3", 20)
    yield env
    env.close()


def _arm_qpos(env) -> np.ndarray:
    m = env.mujoco.model
    return np.array([m.joint(j).qposadr[0] for j in env.mujoco.arm_joints])


def test_rows_are_listed_in_help():
    text = axes.axes_help()
    for name in ("init_qpos", "object_pose", "object_yaw"):
        assert re.search(rf"^  {name} ", text, re.M), name


def test_init_qpos_moves_only_the_arm_by_the_level_and_records_it(lift):
    nominal, obs, params, _ = _start(lift, _cond(init_qpos=[0.2]))
    qpos = lift.mujoco.data.qpos
    arm = _arm_qpos(lift)
    diff = qpos - nominal
    assert np.linalg.norm(diff[arm]) == pytest.approx(0.2, abs=1e-12)
    np.testing.assert_array_equal(np.delete(diff, arm), 0.0)  # the gripper and the cube did not move
    assert params["init_qpos"] == 0.2 and params["init_qpos.joints"] == list(lift.mujoco.arm_joints)
    np.testing.assert_allclose(params["init_qpos.offset"], diff[arm], atol=1e-12)
    # the observation is a fresh one of the edited state, and the recorded initial state is the edited one
    fresh = lift.observer.observe(lift.raw._get_observations(force_update=True))
    np.testing.assert_array_equal(obs[STATE], fresh[STATE])
    assert np.allclose(obs[STATE][3:7], [0, 0, 0, 1])  # orientation relative to the (edited) start
    np.testing.assert_array_equal(lift.init_state()[: qpos.size], qpos)


def test_one_named_joint_moves_by_plus_level(lift):
    cond = _cond(init_qpos={"levels": [0.05], "joints": ["robot0_joint2"]})
    nominal, _, params, _ = _start(lift, cond)
    diff = lift.mujoco.data.qpos - nominal
    j = lift.mujoco.model.joint("robot0_joint2").qposadr[0]
    assert diff[j] == pytest.approx(0.05, abs=1e-12)
    np.testing.assert_array_equal(np.delete(diff, j), 0.0)
    assert params["init_qpos.offset"] == [pytest.approx(0.05)]


def test_the_arm_does_not_snap_back(lift):
    _, _, _, stepper = _start(lift, _cond(init_qpos=[0.3]))
    arm = _arm_qpos(lift)
    edited = lift.mujoco.data.qpos[arm].copy()
    for _ in range(5):
        stepper.step(np.zeros(lift.action_spec.dim, np.float32))
    # the OSC re-initialised at the edited joints holds them (measured ~1e-9 rad; its old goal pulled ~0.01 rad)
    assert np.abs(lift.mujoco.data.qpos[arm] - edited).max() < 1e-4


def test_object_pose_and_yaw_move_the_cube(lift):
    adr = lift.mujoco.model.body("cube_main").jntadr[0]
    q = lift.mujoco.model.jnt_qposadr[adr]
    nominal, obs, params, _ = _start(lift, _cond(object_pose=[0.04]))
    now = lift.mujoco.data.qpos
    shift = now[q : q + 3] - nominal[q : q + 3]
    assert np.linalg.norm(shift[:2]) == pytest.approx(0.04, abs=1e-12) and shift[2] == 0
    np.testing.assert_allclose(params["object_pose.offset"], shift[:2], atol=1e-12)
    np.testing.assert_allclose(obs[STATE][8:11], now[q : q + 3], atol=1e-6)  # the observation's object_pos
    nominal, _, params, _ = _start(lift, _cond(object_yaw=[0.5]))
    now = lift.mujoco.data.qpos
    np.testing.assert_array_equal(now[q : q + 3], nominal[q : q + 3])
    half = params["object_yaw.applied"] / 2
    turned = np.empty(4)
    mujoco.mju_mulQuat(turned, np.array([math.cos(half), 0, 0, math.sin(half)]), nominal[q + 3 : q + 7])
    np.testing.assert_allclose(now[q + 3 : q + 7], turned, atol=1e-12)
    assert abs(params["object_yaw.applied"]) == 0.5


def test_episodes_are_deterministic_per_seed(lift):
    cond = _cond(init_qpos=uniform_range(0.05, 0.3))
    runs = []
    for seed in (3, 3, 4):
        _, obs, params, _ = _start(lift, cond, seed)
        runs.append((obs[STATE].copy(), params, state_hash(lift.init_state())))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    assert runs[0][1:] == runs[1][1:]
    assert runs[0][1] != runs[2][1] and runs[0][2] != runs[2][2]
    _start(lift, _cond(object_pose=[0.02]), 3)
    nominal_hash = state_hash(lift.init_state())
    lift.reset(3)
    assert state_hash(lift.init_state()) != nominal_hash  # the edit is in the recorded initial state


def uniform_range(low: float, high: float) -> str:
    return f"uniform({low},{high})"


def test_metaworld_hand_follows_the_edited_arm(sawyer):
    data = sawyer.mujoco.data
    sawyer.reset(SEED)
    hand_nominal = data.body("hand").xpos.copy()
    nominal, obs, params, stepper = _start(sawyer, _cond(init_qpos=[0.05]))
    arm = _arm_qpos(sawyer)
    diff = data.qpos - nominal
    assert np.linalg.norm(diff[arm]) == pytest.approx(0.05, abs=1e-12)
    np.testing.assert_array_equal(np.delete(diff, arm), 0.0)
    # Meta-World's reset observation of this state: the current frame twice, the goal hidden
    env = sawyer._env
    frame = env._get_curr_obs_combined_no_goal()
    np.testing.assert_array_equal(obs[STATE], np.hstack([frame, frame, np.zeros(3)]).astype(np.float32))
    np.testing.assert_allclose(sawyer.init_state()[-6:-3], data.mocap_pos[0])  # recorded with the moved mocap
    hand = data.body("hand").xpos.copy()
    assert np.linalg.norm(hand - hand_nominal) > 0.01
    for _ in range(5):
        stepper.step(np.zeros(4, np.float32))
    # the weld holds the hand near its edited place (a nominal start drifts ~4 mm over 10 steps as well)
    assert np.linalg.norm(data.body("hand").xpos - hand) < 0.006


def test_camera_images_are_rendered_from_the_edited_state():
    p = api.plan(api.config_from_argv([*LIFT, "obs=state+rgb", "image_size=24", "cameras=[agentview]"]))
    env = p.suite.make_env(p.cells[0], 5)
    try:
        plain = env.reset(SEED)["rgb.agentview"]
        _, obs, _, _ = _start(env, _cond(object_pose=[0.08]))
        again = env.mujoco.cameras.render()["rgb.agentview"]
        np.testing.assert_array_equal(obs["rgb.agentview"], again)
        assert not np.array_equal(obs["rgb.agentview"], plain)
    finally:
        env.close()


def test_gym_mujoco_observation_is_of_the_edited_state():
    from bench.sims.gym import GymEnv  # gymnasium: imported only by the test that builds one

    env = GymEnv("HalfCheetah-v5", 5)
    try:
        nominal, obs, params, _ = _start(env, _cond(init_qpos=[0.2]))
        assert params["init_qpos.joints"] == ["bthigh", "bshin", "bfoot", "fthigh", "fshin", "ffoot"]
        assert np.linalg.norm(env.mujoco.data.qpos - nominal) == pytest.approx(0.2, abs=1e-12)
        np.testing.assert_array_equal(obs[STATE], env._flat_obs(env._env.unwrapped._get_obs()))
    finally:
        env.close()


class _NoEditEnv(AdapterBase):
    """A MuJoCo adapter without `edit_start` (the default refuses)."""

    backend = "stub"
    obs_spec = {STATE: Feature.state([("q", 1)])}
    action_spec = ActionSpec.box(["a"], -1, 1)

    def __init__(self) -> None:
        model = mujoco.MjModel.from_xml_string(
            '<mujoco><worldbody><body><joint name="j" range="-1 1"/><geom size=".1"/></body></worldbody></mujoco>'
        )
        self.mujoco = MujocoHandle(model, mujoco.MjData(model), arm_joints=("j",))

    def reset(self, seed):
        return {STATE: np.zeros(1, np.float32)}

    def step(self, action):
        return self.reset(0), 0.0, False, False, {}

    def success(self):
        return False


def test_an_adapter_without_edit_start_is_refused():
    with pytest.raises(
        ConfigError, match=r"^perturb.init_qpos: stub-env \(stub\) cannot start an episode from an edited state"
    ):
        perturb.validate(_NoEditEnv(), [_cond(init_qpos=[0.1])], "stub-env")


@pytest.mark.parametrize(
    "argv, pattern",
    [
        (
            [*LIFT, "perturb.init_qpos=[0.1,1.0]"],
            r"^error: perturb.init_qpos: a level of 1 rad can take joint 'robot0_joint4' of Lift/Panda/\S+ out of its "
            r"range \[-3.072, -0.0698\] \(it starts at -2.6\d*\); largest valid level: 0.45\d*$",
        ),
        (
            [*LIFT, "perturb.init_qpos=uniform(0.1,0.9)"],
            r"largest valid level: 0.45",
        ),
        (
            [*LIFT, "perturb.init_qpos.levels=[0.1]", "perturb.init_qpos.joints=[robot0_joint9]"],
            r"perturb.init_qpos.joints: 'robot0_joint9' is not a joint of .*Did you mean 'robot0_joint\d'\?",
        ),
        (
            [*LIFT, "perturb.object_pose.levels=[0.01]", "perturb.object_pose.bodies=[cube_mian]"],
            r"perturb.object_pose.bodies: 'cube_mian' is not a body of .*Did you mean 'cube_main'\?",
        ),
        (
            [*LIFT, "perturb.object_yaw.levels=[0.1]", "perturb.object_yaw.bodies=[table]"],
            r"perturb.object_yaw.bodies: 'table' of .* has no free joint.*bodies with one: cube_main",
        ),
        (
            ["suite=gym", "env_id=HalfCheetah-v5", "perturb.object_pose=[0.01]"],
            r"perturb.object_pose: .* declares no manipulated object; name the bodies with perturb.object_pose.bodies",
        ),
        (
            ["suite=gym", "env_id=CartPole-v1", "perturb.init_qpos=[0.1]"],
            r"perturb.init_qpos: .* \(gymnasium-\S+\) has no MuJoCo state to edit; pose axes work on",
        ),
        ([*LIFT, "perturb.init_qpos=[-0.1]"], r"perturb.init_qpos: -0.1 is invalid"),
    ],
    ids=[
        "joint-range",
        "range-high-end",
        "unknown-joint",
        "unknown-body",
        "body-not-free",
        "no-object",
        "no-mujoco",
        "negative",
    ],
)
def test_bad_input_is_one_line_exit_2_nothing_written(tmp_path, capsys, argv, pattern):
    out = tmp_path / "runs"
    code = main(["run", *argv, "episodes=1", f"out={out}"])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert re.search(pattern, err.strip()), err
    assert not out.exists()

"""Perturbation library: CLI grammar, model axes on real MuJoCo models, interface wrapper, errors."""

import json

import mujoco
import numpy as np
import pytest

from bench.core.errors import ConfigError
from bench.protocols import STATE, ActionSpec, Feature, MujocoHandle
from bench.protocols.suite import NOMINAL, Condition, condition_rng
from bench.sims import perturb
from bench.sims.perturb import axes

pytest.importorskip("gymnasium")

# A raw MJCF: a hinged arm driven by a position servo and a motor, and a free box on a plane.
MJCF = """
<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1" friction="1 0.005 0.0001"/>
    <body name="link1" pos="0 0 1">
      <joint name="hinge1" type="hinge" axis="0 1 0" damping="0.5" armature="0.1" frictionloss="0.2"/>
      <geom name="link1_geom" type="capsule" fromto="0 0 0 0.5 0 0" size="0.04" mass="1"/>
      <body name="link2" pos="0.5 0 0">
        <joint name="hinge2" type="hinge" axis="0 1 0" damping="0.3" armature="0.05"/>
        <geom name="link2_geom" type="capsule" fromto="0 0 0 0.4 0 0" size="0.03" mass="0.5"/>
      </body>
    </body>
    <body name="box" pos="1 1 0.05">
      <freejoint name="box_free"/>
      <geom name="box_geom" type="box" size="0.05 0.05 0.05" mass="0.2" friction="0.8 0.005 0.0001"/>
    </body>
  </worldbody>
  <actuator>
    <position name="servo1" joint="hinge1" kp="50"/>
    <motor name="motor2" joint="hinge2" gear="1" ctrlrange="-5 5"/>
  </actuator>
</mujoco>
"""


class MjcfEnv:
    """A raw MJCF behind the EnvAdapter contract (`model`/`data` kept as attributes for the tests)."""

    backend = f"mujoco-{mujoco.__version__}"
    inputs = None
    model_axes = None
    fps = 0.0

    def __init__(self, xml: str = MJCF):
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        self.mujoco = MujocoHandle(self.model, self.data, ("box",))
        self.action_spec = ActionSpec.box(["servo1", "motor2"], [-1.0, -5.0], [1.0, 5.0])
        self.obs_spec = {STATE: Feature.state([("qpos", self.model.nq)])}
        self.horizon = 100

    def reset(self, seed: int):
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[0] = np.random.default_rng(seed).uniform(-0.1, 0.1)
        mujoco.mj_forward(self.model, self.data)
        return {STATE: self.data.qpos.astype(np.float32).copy()}

    def step(self, action):
        self.data.ctrl[:] = action
        mujoco.mj_step(self.model, self.data)
        return {STATE: self.data.qpos.astype(np.float32).copy()}, 0.0, False, False, {}

    def success(self):
        return False

    def init_state(self):
        return np.concatenate([self.data.qpos, self.data.qvel])

    def close(self):
        pass


def cond(name: str, value) -> Condition:
    conds = axes.conditions_from_config({name: value})
    assert conds[0].name == "nominal"
    return conds[1]


def apply(env, c, seed=0):
    stepper, params = perturb.apply(env, c, condition_rng(seed, c))
    stepper.reset(seed)
    return stepper, params


# -- grammar ----------------------------------------------------------------------------------
def test_grid_and_range_conditions_are_named_and_nominal_first():
    conds = axes.conditions_from_config(
        {
            "friction": [0.25, 0.5, 1.0, 2.0],
            "mass": "uniform(0.8,1.2)",
            "latency": 4,
            "damping": {"levels": [0.5], "loguniform": [0.5, 2], "joints": ["hinge1"]},
        }
    )
    assert [c.name for c in conds] == [
        "nominal",
        "friction=0.25",
        "friction=0.5",
        "friction=1",
        "friction=2",
        "mass~U(0.8,1.2)",
        "latency=4",
        "damping=0.5",
        "damping~logU(0.5,2)",
    ]
    assert conds[5].level == [0.8, 1.2] and conds[5].spec["kind"] == "uniform"
    assert conds[7].spec["targets"] == {"joints": ["hinge1"]}
    assert axes.conditions_from_config({}) == [NOMINAL]


def test_cli_grammar_through_the_run_config():
    from bench.api import RunConfig
    from bench.core import config

    cfg = config.build(
        RunConfig,
        [
            "perturb.friction=[0.5,2]",
            "perturb.gravity=uniform(0.9,1.1)",
            "perturb.mass.levels=[2]",
            "perturb.mass.bodies=[box]",
            "perturb.link_mass.uniform=[0.5,1.5]",
        ],
    )
    names = [c.name for c in axes.conditions_from_config(cfg.perturb)]
    assert names == ["nominal", "friction=0.5", "friction=2", "gravity~U(0.9,1.1)", "mass=2", "link_mass~U(0.5,1.5)"]


@pytest.mark.parametrize(
    "perturb_cfg, match",
    [
        ({"fricton": [0.5]}, r"perturb.fricton: unknown perturbation axis; valid: .*Did you mean 'friction'\?"),
        ({"friction": [-0.5]}, r"perturb.friction: -0.5 is invalid; friction levels \(scale of nominal\) must be >= 0"),
        ({"mass": [0]}, r"perturb.mass: 0 is invalid; .* must be > 0"),
        ({"latency": [1.5]}, r"perturb.latency: 1.5 is not a whole number"),
        ({"action_hold": [0]}, r"must be >= 1"),
        ({"friction": "uniform(1.2,0.8)"}, r"low > high"),
        ({"friction": "uniform(0.8)"}, r"cannot parse|not a number"),
        ({"friction": "abc"}, r"'abc' is not a number"),
        ({"mass": {"levels": [2], "bodys": ["box"]}}, r"perturb.mass.bodys: unknown key; .*Did you mean 'bodies'\?"),
        ({"friction": {"joints": ["hinge1"], "levels": [2]}}, r"perturb.friction.joints: unknown key"),
        (
            {"mass": {"bodies": ["box"]}},
            r"give levels=\[...\], a range \(uniform/loguniform=\[low,high\]\) or curve=uniform\(low,high\)",
        ),
    ],
    ids=[
        "unknown-axis",
        "negative-scale",
        "zero-mass",
        "fractional-latency",
        "hold-zero",
        "range-reversed",
        "range-one-bound",
        "not-a-number",
        "bad-target-key",
        "target-key-of-other-axis",
        "targets-without-levels",
    ],
)
def test_bad_perturbations_are_one_line_config_errors(perturb_cfg, match):
    with pytest.raises(ConfigError, match=match) as exc:
        axes.conditions_from_config(perturb_cfg)
    assert "\n" not in str(exc.value)


# -- names against the model ---------------------------------------------------------------------
def test_validate_names_against_the_model():
    env = MjcfEnv()
    perturb.validate(env, axes.conditions_from_config({"mass": {"levels": [2], "bodies": ["box"]}}))
    with pytest.raises(
        ConfigError, match=r"perturb.mass.bodies: 'bx' is not a body of the env; valid: .*Did you mean 'box'\?"
    ):
        perturb.validate(env, axes.conditions_from_config({"mass": {"levels": [2], "bodies": ["bx"]}}))
    with pytest.raises(ConfigError, match=r"perturb.damping.joints: 'hinge3' is not a joint"):
        perturb.validate(env, axes.conditions_from_config({"damping": {"levels": [2], "joints": ["hinge3"]}}))
    with pytest.raises(ConfigError, match=r"perturb.gain.actuators: 'servo' is not an actuator.*Did you mean"):
        perturb.validate(env, axes.conditions_from_config({"gain": {"levels": [2], "actuators": ["servo"]}}))
    # hinge2 has frictionloss 0: scaling it would change nothing
    with pytest.raises(ConfigError, match=r"nominal frictionloss of every targeted element .* is 0"):
        perturb.validate(env, axes.conditions_from_config({"frictionloss": {"levels": [2], "joints": ["hinge2"]}}))


def test_mass_without_declared_object_asks_for_bodies():
    env = MjcfEnv()
    env.mujoco.object_bodies = ()
    with pytest.raises(ConfigError, match=r"declares no manipulated object .*perturb.mass.bodies=\[...\]"):
        perturb.validate(env, axes.conditions_from_config({"mass": [2]}))


# -- model axes ----------------------------------------------------------------------------------
def _ids(m, kind, *names):
    return [getattr(m, kind)(n).id for n in names]


@pytest.mark.parametrize(
    "axis, field, picks",
    [
        ("friction", "geom_friction", lambda m: list(range(m.ngeom))),
        ("mass", "body_mass", lambda m: _ids(m, "body", "box")),
        ("link_mass", "body_mass", lambda m: _ids(m, "body", "link1", "link2")),
        ("damping", "dof_damping", lambda m: [0, 1]),
        ("armature", "dof_armature", lambda m: [0, 1]),
        ("frictionloss", "dof_frictionloss", lambda m: [0, 1]),
    ],
)
def test_model_axis_scales_its_targets_and_never_drifts(axis, field, picks):
    env = MjcfEnv()
    m = env.model
    nominal = getattr(m, field).copy()
    idx = picks(m)
    for _ in range(3):  # applied again and again on a reused env: relative to nominal, never compounding
        apply(env, cond(axis, [0.5]))
        np.testing.assert_allclose(getattr(m, field)[idx], nominal[idx] * 0.5)
        others = np.setdiff1d(np.arange(len(nominal)), idx)
        np.testing.assert_array_equal(getattr(m, field)[others], nominal[others])
    apply(env, NOMINAL)
    np.testing.assert_array_equal(getattr(m, field), nominal)


def test_mass_and_armature_show_in_the_mass_matrix():
    env = MjcfEnv()
    m, d = env.model, env.data

    def full_m():
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, M, d.qM)
        return M

    apply(env, NOMINAL)
    M0 = full_m()
    apply(env, cond("link_mass", [2.0]))
    M1 = full_m()
    # hinge dofs are 0, 1: link inertia doubled (armature unchanged) -> M[0,0] - arm doubles
    np.testing.assert_allclose(M1[0, 0] - 0.1, 2 * (M0[0, 0] - 0.1), rtol=1e-6)
    apply(env, cond("armature", [3.0]))
    np.testing.assert_allclose(full_m()[0, 0], M0[0, 0] + 0.2, rtol=1e-6)
    apply(env, cond("mass", [4.0]))
    box_dof = m.body("box").dofadr[0]
    np.testing.assert_allclose(full_m()[box_dof, box_dof], 4 * 0.2, rtol=1e-6)
    assert m.body_subtreemass[m.body("box").id] == pytest.approx(0.8)  # derived constants refreshed
    apply(env, NOMINAL)
    np.testing.assert_allclose(full_m(), M0)
    assert m.body_subtreemass[m.body("box").id] == pytest.approx(0.2)


def test_position_servo_gain_scales_stiffness_not_setpoint():
    env = MjcfEnv()
    m = env.model
    apply(env, cond("gain", {"levels": [0.5], "actuators": ["servo1"]}))
    assert m.actuator_gainprm[0, 0] == pytest.approx(25) and m.actuator_biasprm[0, 1] == pytest.approx(-25)
    assert m.actuator_gainprm[1, 0] == pytest.approx(1)  # the motor was not targeted
    apply(env, cond("gain", [0.5]))
    assert m.actuator_gainprm[1, 0] == pytest.approx(0.5) and m.actuator_biasprm[1, 1] == 0


def test_gravity_and_friction_change_the_motion():
    env = MjcfEnv()
    m, d = env.model, env.data

    z_adr = m.jnt_qposadr[m.joint("box_free").id] + 2

    def box_z_after(c, steps=100):
        apply(env, c)
        d.qpos[z_adr] = 0.5  # lift the box: free fall
        for _ in range(steps):
            mujoco.mj_step(m, d)
        return d.qpos[z_adr]

    z_nom, z_half = box_z_after(NOMINAL), box_z_after(cond("gravity", [0.5]))
    assert z_half > z_nom + 0.05
    assert m.opt.gravity[2] == pytest.approx(-4.905)
    apply(env, NOMINAL)
    assert m.opt.gravity[2] == pytest.approx(-9.81)

    def box_slide(c):  # push the box sideways with an initial velocity; low friction slides further
        apply(env, c)
        d.qvel[m.jnt_dofadr[m.joint("box_free").id]] = 1.0
        x_adr = m.jnt_qposadr[m.joint("box_free").id]
        x0 = d.qpos[x_adr]
        for _ in range(200):
            mujoco.mj_step(m, d)
        return d.qpos[x_adr] - x0

    assert box_slide(cond("friction", [0.1])) > box_slide(NOMINAL) + 0.05


def test_range_draws_from_the_episode_rng_and_records_the_value():
    env = MjcfEnv()
    c = cond("friction", "loguniform(0.5,2)")
    values = []
    for seed in range(20):
        _, params = apply(env, c, seed)
        assert set(params) == {"friction"} and 0.5 <= params["friction"] <= 2
        assert env.model.geom_friction[0, 0] == pytest.approx(params["friction"])  # floor nominal 1.0
        values.append(params["friction"])
    assert len(set(values)) == 20
    assert apply(env, c, 3)[1] == apply(env, c, 3)[1]  # same episode seed -> same draw
    lat = cond("latency", "uniform(0,3)")
    drawn = {apply(env, lat, s)[1]["latency"] for s in range(30)}
    assert drawn == {0, 1, 2, 3}
    json.dumps(apply(env, c, 1)[1], allow_nan=False)


# -- interface axes on a real Gymnasium MuJoCo env --------------------------------------------------
@pytest.fixture(scope="module")
def cheetah():
    from bench.sims.gym import GymEnv

    env = GymEnv("HalfCheetah-v5", 50)
    yield env
    env.close()


def _commands(n, dim, seed=0):
    return np.random.default_rng(seed).uniform(-1, 1, size=(n, dim)).astype(np.float32)


def test_latency_delays_the_executed_action(cheetah):
    stepper, params = apply(cheetah, cond("latency", [3]))
    assert params == {"latency": 3}
    cmds = _commands(10, 6)
    for t, a in enumerate(cmds):
        stepper.step(a)
        expected = np.zeros(6) if t < 3 else cmds[t - 3]
        np.testing.assert_allclose(cheetah.mujoco.data.ctrl, expected, atol=1e-6)


def test_action_hold_lowers_the_control_rate(cheetah):
    stepper, _ = apply(cheetah, cond("action_hold", [4]))
    cmds = _commands(12, 6)
    for t, a in enumerate(cmds):
        stepper.step(a)
        np.testing.assert_allclose(cheetah.mujoco.data.ctrl, cmds[(t // 4) * 4], atol=1e-6)


def test_action_and_observation_noise(cheetah):
    cmds = np.zeros((200, 6), np.float32)
    stepper, _ = apply(cheetah, cond("action_noise", [0.1]))
    executed = []
    for a in cmds:
        stepper.step(a)
        executed.append(cheetah.mujoco.data.ctrl.copy())
    assert np.std(executed) == pytest.approx(0.1, rel=0.15)  # half-range is 1 on HalfCheetah

    clean_env = apply(cheetah, NOMINAL)[0]
    clean = [clean_env.reset(5)[STATE]] + [clean_env.step(a)[0][STATE] for a in cmds[:20]]
    noisy_env, _ = perturb.apply(cheetah, cond("obs_noise", [0.05]), np.random.default_rng(0))
    noisy = [noisy_env.reset(5)[STATE]] + [noisy_env.step(a)[0][STATE] for a in cmds[:20]]
    diff = np.array(noisy) - np.array(clean)  # noise on what the policy sees, the dynamics are untouched
    assert np.std(diff) == pytest.approx(0.05, rel=0.2)
    np.testing.assert_allclose(cheetah.init_state(), clean_env.init_state())


def test_model_axis_needs_a_mujoco_model():
    from bench.sims.gym import GymEnv

    env = GymEnv("CartPole-v1", 20)
    with pytest.raises(
        ConfigError,
        match=r"perturb.friction: the env \(gymnasium-.*\) cannot apply it; model axes "
        r"there: none; interface axes work everywhere",
    ):
        perturb.validate(env, axes.conditions_from_config({"friction": [0.5]}))
    stepper, params = apply(env, cond("latency", [1]))  # interface axes work on any env
    assert params == {"latency": 1} and stepper.step(np.array([1.0]))[0][STATE].shape == (4,)


def test_robosuite_object_mass_survives_soft_reset_and_names_are_checked():
    import importlib.util

    if importlib.util.find_spec("robosuite") is None:  # not importorskip: the adapter quiets robosuite's import
        pytest.skip("robosuite is not installed")
    from suites.lift import make_env

    env = make_env("Lift", "Panda", 20)
    try:
        assert env.mujoco.object_bodies == ("cube_main",)
        model = env.mujoco.model
        cube = model.body("cube_main").id
        m0 = model.body_mass[cube]
        apply(env, cond("mass", [3.0]))  # apply, then robosuite's soft reset
        assert model.body_mass[cube] == pytest.approx(3 * m0)
        apply(env, NOMINAL)
        assert model.body_mass[cube] == pytest.approx(m0)
        # the check `bench run` makes before writing anything (exit 2 path: tests/test_gym_suite.py)
        with pytest.raises(
            ConfigError,
            match=r"perturb.mass.bodies: 'cube' is not a body of Lift/Panda/default; "
            r"valid: .*Did you mean 'cube_main'\?",
        ):
            perturb.validate(
                env,
                axes.conditions_from_config({"mass": {"levels": [2], "bodies": ["cube"]}}),
                where="Lift/Panda/default",
            )
    finally:
        env.close()


def test_nominal_after_perturbations_replays_a_fresh_env_exactly():
    fresh, used = MjcfEnv(), MjcfEnv()
    for axis, value in [
        ("link_mass", [3.0]),
        ("armature", [0.2]),
        ("mass", "uniform(2,3)"),
        ("gain", [0.3]),
        ("friction", [0.1]),
        ("gravity", [0.2]),
    ]:
        apply(used, cond(axis, value))
    actions = np.random.default_rng(1).uniform(-1, 1, size=(300, 2))

    def states(env):
        perturb.apply(env, NOMINAL, np.random.default_rng(0))
        env.reset(4)
        out = []
        for a in actions:
            env.step(a)
            out.append(np.concatenate([env.data.qpos, env.data.qvel]))
        return np.array(out)

    np.testing.assert_array_equal(states(used), states(fresh))
    for field in ("body_subtreemass", "dof_invweight0", "body_invweight0", "actuator_acc0"):
        np.testing.assert_allclose(getattr(used.model, field), getattr(fresh.model, field), rtol=1e-12)

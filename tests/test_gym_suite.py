"""suite=gym: any Gymnasium env id as a one-cell suite, with perturbations; bad input exits 2 writing nothing."""

import json

import numpy as np
import pytest

from bench.cli import main
from bench.core.errors import ConfigError
from bench.core.schema import validate
from bench.records import comparable, read_records

pytest.importorskip("gymnasium")


def run(tmp_path, run_id, *extra, env_id="InvertedPendulum-v5"):
    return main(
        [
            "run",
            "suite=gym",
            f"env_id={env_id}",
            "episodes=3",
            "workers=1",
            "horizon=40",
            f"out={tmp_path}",
            f"run_id={run_id}",
            *extra,
        ]
    )


def test_suite_needs_a_registered_env_id():
    from suites.gym_suite import GymOptions, GymSuite

    with pytest.raises(ConfigError, match=r"env_id: suite=gym needs a Gymnasium env id"):
        GymSuite()
    with pytest.raises(
        ConfigError, match=r"env_id='HalfCheeta-v5': not a registered Gymnasium env .*Did you mean 'HalfCheetah-v5'\?"
    ):
        GymSuite(GymOptions("HalfCheeta-v5"))
    suite = GymSuite(GymOptions("HalfCheetah-v5"))
    assert suite.default_horizon == 1000 and suite.default_metric == "return"
    (cell,) = suite.all_cells()
    assert (cell.task, cell.split) == ("HalfCheetah-v5", "seen")
    assert suite.describe()["env_id"] == "HalfCheetah-v5"


def test_env_id_module_prefix_imports_the_registering_module(tmp_path, monkeypatch):
    """`env_id=module:Env-v0` imports the module that registers the env, as gymnasium.make accepts."""
    from suites.gym_suite import GymOptions, GymSuite

    (tmp_path / "my_envs_mod.py").write_text(
        "import gymnasium\n"
        "gymnasium.register(id='MyPendulum-v0', entry_point='gymnasium.envs.classic_control:PendulumEnv', "
        "max_episode_steps=77)\n"
    )
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    suite = GymSuite(GymOptions("my_envs_mod:MyPendulum-v0"))
    assert suite.default_horizon == 77
    assert run(tmp_path / "runs", "mod", env_id="my_envs_mod:MyPendulum-v0") == 0
    recs = read_records(tmp_path / "runs" / "mod" / "episodes.jsonl")
    assert len(recs) == 3 and all(r.error is None and r.task == "my_envs_mod:MyPendulum-v0" for r in recs)


def test_box_env_contract_and_seeded_reset():
    from bench.sims.gym import GymEnv

    env = GymEnv("HalfCheetah-v5", 20)
    assert env.obs_spec["state"].fields == (("obs", 17),) and env.action_spec.dim == 6 and env.mujoco is not None
    assert env.backend.startswith("gymnasium-") and "/mujoco-" in env.backend
    actions = np.random.default_rng(0).uniform(-1, 1, size=(20, 6))

    def trajectory(seed):
        obs = [env.reset(seed)["state"]]
        init = env.init_state().copy()
        for a in actions:
            o, r, terminated, truncated, info = env.step(a)
            obs.append(o["state"])
            assert env.success() is False
        assert truncated and not terminated  # truncated at the horizon
        return init, np.array(obs)

    (i1, t1), (i2, t2), (i3, _) = trajectory(7), trajectory(7), trajectory(8)
    np.testing.assert_array_equal(t1, t2)
    np.testing.assert_array_equal(i1, i2)
    assert not np.allclose(i1, i3)
    env.close()


def test_discrete_actions_are_rounded_within_bounds():
    from baselines.random_policy import RandomPolicy
    from bench.sims.gym import GymEnv

    env = GymEnv("CartPole-v1", 50)
    assert env.mujoco is None and env.action_spec.names == ("action",)
    assert (env.action_spec.low[0], env.action_spec.high[0]) == (-0.5, 1.5)
    assert env._action(np.array([0.49])) == 0 and env._action(np.array([0.51])) == 1
    assert env._action(np.array([9.0])) == 1
    policy = RandomPolicy(env.action_spec.low, env.action_spec.high)
    policy.reset(0)
    picks = [env._action(policy.act(None)) for _ in range(400)]
    assert 0.4 < np.mean(picks) < 0.6


def test_run_with_perturbations_records_params_and_sensitivity(tmp_path):
    assert (
        run(
            tmp_path,
            "a",
            "perturb.friction=[0.5,2.0]",
            "perturb.gravity=uniform(0.5,1.5)",
            "perturb.action_noise=[0.3]",
        )
        == 0
    )
    recs = read_records(tmp_path / "a" / "episodes.jsonl")
    assert len(recs) == 15 and all(r.error is None for r in recs)
    by_cond = {}
    for r in recs:
        by_cond.setdefault(r.condition, []).append(r)
    assert sorted(by_cond) == ["action_noise=0.3", "friction=0.5", "friction=2", "gravity~U(0.5,1.5)", "nominal"]
    grav = [r.params["gravity"] for r in by_cond["gravity~U(0.5,1.5)"]]
    assert len(set(grav)) == 3 and all(0.5 <= g <= 1.5 for g in grav)
    assert all(r.params == {"friction": 0.5} for r in by_cond["friction=0.5"])
    # same episode index -> same initial state under every condition (pairing by seed)
    for ep in range(3):
        assert len({r.init_state_hash for r in recs if r.episode == ep}) == 1
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert validate(summary) == "bench.summary/1"
    assert summary["suite"]["env_id"] == "InvertedPendulum-v5"
    conds = [e["condition"] for e in summary["sensitivity"]]
    assert conds == ["nominal", "action_noise=0.3", "friction=0.5", "friction=2", "gravity~U(0.5,1.5)"]
    noise = summary["sensitivity"][1]["drop_vs_nominal"]["return"]
    assert noise["n_pairs"] == 3 and noise["value"] is not None


def test_same_seed_with_domain_randomisation_gives_identical_records(tmp_path):
    args = ["perturb.link_mass=uniform(0.5,2)", "perturb.latency=uniform(0,3)", "perturb.obs_noise=[0.05]"]
    assert run(tmp_path, "a", *args) == 0
    assert run(tmp_path, "b", *args) == 0
    a, b = (sorted(read_records(tmp_path / rid / "episodes.jsonl"), key=lambda r: r.job_id) for rid in "ab")
    assert [comparable(r) for r in a] == [comparable(r) for r in b]
    assert len({r.params["link_mass"] for r in a if r.axis == "link_mass"}) == 3
    assert run(tmp_path, "c", "seed=1", *args) == 0
    c = read_records(tmp_path / "c" / "episodes.jsonl")
    assert {r.params.get("link_mass") for r in c if r.axis == "link_mass"}.isdisjoint(
        {r.params["link_mass"] for r in a if r.axis == "link_mass"}
    )


@pytest.mark.parametrize(
    "extra, match",
    [
        (["perturb.fricton=[0.5]"], r"perturb.fricton: unknown perturbation axis; .*Did you mean 'friction'\?"),
        (
            ["perturb.friction=[-1]"],
            r"perturb.friction: -1 is invalid; friction levels \(scale of nominal\) must be >= 0",
        ),
        (
            ["perturb.mass.levels=[2]", "perturb.mass.bodies=[pole2]"],
            r"perturb.mass.bodies: 'pole2' is not a body of InvertedPendulum-v5/default/default; valid: world, cart, pole.*Did you mean 'pole'\?",
        ),
        (["perturb.mass=[2]"], r"perturb.mass: InvertedPendulum-v5/default/default declares no manipulated object"),
        (["perturb.damping=[2]", "CartPole-v1"], r"perturb.damping: .* cannot apply it; model axes there: none"),
        (
            ["perturb.friction=[0.5]", "perturb.friction.bodies=[pole]"],
            r"perturb.friction is set to a value and also given the sub-key perturb.friction.bodies; .*perturb.friction.levels=",
        ),
    ],
    ids=[
        "unknown-axis",
        "negative-scale",
        "unknown-body",
        "mass-without-object",
        "model-axis-on-non-mujoco",
        "levels-and-subkeys-mixed",
    ],
)
def test_bad_perturbation_exits_2_and_writes_nothing(tmp_path, capsys, extra, match):
    env_id = extra[-1] if extra[-1] == "CartPole-v1" else "InvertedPendulum-v5"
    assert run(tmp_path, "bad", *[e for e in extra if e != env_id], env_id=env_id) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err
    import re

    assert re.search(match, err), err
    assert not (tmp_path / "bad").exists()

"""held_out_envs on real Meta-World: manifests, cells, seeding that pins the initial state, the expert."""

import subprocess
import sys
import warnings

import numpy as np
import pytest

from bench.api import RunConfig
from bench.core.errors import ConfigError
from bench.protocols.env import state_hash
from bench.protocols.suite import select_cells
from suites.held_out_envs import ML10, ML45, HeldOutEnvs, HeldOutEnvsML45

pytest.importorskip("metaworld")

from bench.sims.metaworld import OBS_NAMES, MetaWorldEnv, metaworld_manifest  # noqa: E402

SUITES = [HeldOutEnvs, HeldOutEnvsML45]


@pytest.mark.parametrize("suite_cls", SUITES, ids=lambda c: c.name)
def test_manifest_disjoint_and_cells_match(suite_cls):
    suite = suite_cls()
    split = suite.manifest["tasks"]
    assert set(split["seen"]).isdisjoint(split["unseen"])
    assert len(split["unseen"]) == 5 and len(split["seen"]) in (10, 45)
    cells = suite.all_cells()
    assert len(cells) == len(split["seen"]) + len(split["unseen"])
    assert {c.task for c in cells if c.split == "seen"} == set(split["seen"])
    assert {c.task for c in cells if c.split == "unseen"} == set(split["unseen"])
    assert {(c.robot, c.env) for c in cells} == {("Sawyer", suite.benchmark)}


@pytest.mark.parametrize("benchmark,declared", [("ML10", ML10), ("ML45", ML45)], ids=["ML10", "ML45"])
def test_declared_manifest_is_metaworlds_own(benchmark, declared):
    assert metaworld_manifest(benchmark) == {"tasks": declared}


@pytest.mark.parametrize("benchmark", ["ML10", "ML25", "ML45"])
def test_manifest_parsed_from_source_equals_imported_definition(benchmark):
    from metaworld import env_dict

    defined = getattr(env_dict, f"{benchmark}_V3")
    assert metaworld_manifest(benchmark) == {"tasks": {"seen": list(defined["train"]), "unseen": list(defined["test"])}}


def test_metaworld_manifest_is_fast_and_imports_no_metaworld():
    code = (
        "import sys, time; from bench.sims.metaworld import metaworld_manifest; t = time.perf_counter(); "
        "metaworld_manifest('ML45'); print('metaworld' in sys.modules, time.perf_counter() - t < 0.5)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "True"]


def test_metaworld_ml25_overlap_is_reported_as_defined():
    split = metaworld_manifest("ml25")["tasks"]
    assert set(split["seen"]) & set(split["unseen"]) == {"basketball-v3"}


def test_metaworld_manifest_rejects_unknown_benchmark():
    with pytest.raises(ConfigError, match=r"benchmark='ML11'.*valid: ML10, ML25, ML45.*Did you mean"):
        metaworld_manifest("ML11")


def test_cell_selection_by_split_and_task():
    suite = HeldOutEnvs()
    cells = select_cells(suite, RunConfig(splits=["unseen"]))
    assert [c.task for c in cells] == ML10["unseen"]
    cells = select_cells(suite, RunConfig(tasks=["drawer-open-v3", "reach-v3"]))
    assert {(c.task, c.split) for c in cells} == {("drawer-open-v3", "unseen"), ("reach-v3", "seen")}
    with pytest.raises(ConfigError, match="tasks: 'drawer-open' is not in suite.*Did you mean 'drawer-open-v3'"):
        select_cells(suite, RunConfig(tasks=["drawer-open"]))


def test_horizon_over_500_rejected():
    from bench import api

    assert HeldOutEnvs.max_horizon == 500
    with pytest.raises(ConfigError, match="horizon=600: suite 'held_out_envs' episodes last at most 500 steps"):
        api.plan(RunConfig(suite="held_out_envs", horizon=600, tasks=["reach-v3"]))


def test_listing_does_not_import_metaworld():
    code = "import sys, bench.protocols.registry as r; r.make_suite('held_out_envs'); print('metaworld' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.fixture(scope="module")
def drawer_open():
    env = MetaWorldEnv("drawer-open-v3")
    yield env
    env.close()


def test_seed_pins_initial_state(drawer_open):
    env = drawer_open
    obs_a = env.reset(7)["state"]
    hash_a = state_hash(env.init_state())
    for _ in range(30):  # move things, then come back with the same seed
        env.step(np.array([1.0, -1.0, 0.5, 1.0]))
    obs_b = env.reset(7)["state"]
    assert state_hash(env.init_state()) == hash_a
    np.testing.assert_array_equal(obs_a, obs_b)
    env.reset(8)
    assert state_hash(env.init_state()) != hash_a
    global_state = np.random.get_state()[1].copy()
    env.reset(9)
    np.testing.assert_array_equal(np.random.get_state()[1], global_state)  # global RNG untouched


def test_goal_hidden_and_layout(drawer_open):
    obs = drawer_open.reset(0)["state"]
    assert obs.shape == (sum(w for _, w in OBS_NAMES),) == (39,) and obs.dtype == np.float32
    assert np.all(obs[-3:] == 0.0)
    assert np.linalg.norm(drawer_open.true_goal()) > 0.1  # the goal exists, it is only hidden


def test_expert_solves_a_test_task_quietly(drawer_open):
    env = drawer_open
    expert = HeldOutEnvs().make_expert(None, env)
    obs = env.reset(3)
    expert.reset(3)
    successes, done, steps = [], False, 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the policy's "Constant(s) may be too high" must not reach the user
        while not done:
            action = expert.act(obs)
            assert action.shape == (4,) and np.all(np.abs(action) <= 1.0)
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
            successes.append(env.success())
            steps += 1
    assert steps == 500 and any(successes)
    assert np.all(obs["state"][-3:] == 0.0)  # the expert's goal never leaks into the observation


def test_short_horizon_ends_episode():
    env = MetaWorldEnv("reach-v3", horizon=5)
    env.reset(0)
    dones = [env.step(np.zeros(4))[3] for _ in range(5)]  # truncated at the horizon
    assert dones == [False] * 4 + [True]
    with pytest.raises(RuntimeError, match="reset first"):
        env.step(np.zeros(4))
    env.close()

"""held_out_scenes: declared scene split, cells, and one real robosuite scene with its table where declared."""

import numpy as np
import pytest

from bench.api import RunConfig
from bench.core.errors import ConfigError
from bench.protocols.env import state_hash
from bench.protocols.suite import select_cells
from suites.held_out_scenes import (
    NOMINAL,
    SEEN_SCENES,
    UNSEEN_SCENES,
    HeldOutScenes,
    env_kwargs,
    region_relation,
    scene_params,
)


def test_manifest_disjoint_and_cells_carry_parameters():
    suite = HeldOutScenes()
    split = suite.manifest["envs"]
    assert set(split["seen"]).isdisjoint(split["unseen"])
    cells = suite.all_cells()
    assert [c.env for c in cells] == split["seen"] + split["unseen"]
    assert {(c.task, c.robot) for c in cells} == {("Lift", "Panda")}
    for c in cells:
        assert c.options == scene_params(c.env)
        assert set(c.options) == set(NOMINAL)
    assert len({str(sorted(c.options.items())) for c in cells}) == len(cells)  # no two scenes alike


@pytest.mark.parametrize("name", list(SEEN_SCENES), ids=str)
def test_seen_scene_inside_seen_region(name):
    assert region_relation(scene_params(name)) == "inside"


@pytest.mark.parametrize("name", list(UNSEEN_SCENES), ids=str)
def test_unseen_scene_outside_seen_region(name):
    assert region_relation(scene_params(name)) == "outside"


def test_straddling_spawn_region_is_flagged():
    params = dict(NOMINAL, spawn_x=[0.04, 0.10])
    assert region_relation(params) == "straddles"


def test_env_selection():
    suite = HeldOutScenes()
    cells = select_cells(suite, RunConfig(envs=["nominal", "spawn_far"]))
    assert [(c.env, c.split) for c in cells] == [("nominal", "seen"), ("spawn_far", "unseen")]
    with pytest.raises(ConfigError, match="envs: 'spawn_fra' is not in suite.*Did you mean 'spawn_far'"):
        select_cells(suite, RunConfig(envs=["spawn_fra"]))


def test_env_kwargs_of_a_scene():
    kw = env_kwargs(scene_params("table_up_12cm"))
    assert kw["table_offset"] == (0.0, 0.0, 0.92)
    assert kw["table_full_size"] == (0.8, 0.8, 0.05)
    assert kw["placement_x_range"] == (-0.03, 0.03)


@pytest.fixture(scope="module")
def scene_env():
    """Build a scene's env once per module: scene_env(name) -> RobosuiteEnv (horizon 20)."""
    pytest.importorskip("robosuite")
    suite, built = HeldOutScenes(), {}

    def get(name):
        if name not in built:
            cell = next(c for c in suite.all_cells() if c.env == name)
            built[name] = suite.make_env(cell, 20)
        return built[name]

    yield get
    for env in built.values():
        env.close()


def test_raised_table_scene_builds_where_declared(scene_env):
    env = scene_env("table_up_12cm")
    m = env.mujoco.model
    assert env.mujoco.data.site_xpos[m.site("table_top").id][2] == pytest.approx(0.92)
    table = m.geom("table_collision").id
    assert m.geom_priority[table] == 1 and m.geom_friction[table][0] == pytest.approx(1.0)
    obs = env.reset(0)
    for _ in range(10):  # let the cube settle on the table
        obs, *_ = env.step(np.zeros(7))
    cube_z = obs["state"][8 + 2]  # object_pos z (see suites/lift.py OBS_FIELDS)
    assert cube_z == pytest.approx(0.92 + 0.021, abs=0.004)  # resting on the raised table (half-size 2-2.2 cm)
    assert not env.success()  # success is measured from this table's height, not robosuite's 0.8 m


def test_spawn_region_is_where_declared(scene_env):
    env = scene_env("spawn_side")
    ys = [env.reset(s)["state"][9] for s in range(5)]  # object_pos y
    assert all(-0.13 - 1e-6 <= y <= -0.07 + 1e-6 for y in ys), ys
    assert len(set(np.round(ys, 6))) == 5  # seeds give different placements


def test_scene_is_part_of_the_initial_state(scene_env):
    """Nominal and the slippery table start from the same joint state; the hashes must still differ."""
    nominal, slippery = scene_env("nominal"), scene_env("table_slippery")
    assert slippery.mujoco.model.geom_friction[slippery.mujoco.model.geom("table_collision").id][0] == pytest.approx(
        0.2
    )
    nominal.reset(4)
    slippery.reset(4)
    n_state, s_state = nominal.init_state(), slippery.init_state()
    nq = nominal.mujoco.model.nq + nominal.mujoco.model.nv
    np.testing.assert_allclose(n_state[:nq], s_state[:nq])  # same placement, same robot pose
    assert state_hash(n_state) != state_hash(s_state)
    nominal.reset(4)
    assert state_hash(nominal.init_state()) == state_hash(n_state)

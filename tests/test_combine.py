"""Combined perturbation axes (`perturb.combine`): the grammar (factorial, seeded fraction, all-at-once), the parts
applied together in one episode with their own draws, the interaction scoring, schemas, report and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bench.board.leaderboard import merge
from bench.board.report.page import interactions_section
from bench.cli import main
from bench.core.errors import ConfigError
from bench.core.schema import validate
from bench.protocols import STATE, ActionSpec, Feature, MujocoHandle
from bench.protocols.suite import NOMINAL, condition_rng
from bench.scoring.interactions import interactions, sentence
from bench.scoring.summary import build
from bench.sims import perturb
from bench.sims.perturb import axes
from bench.sims.perturb.combine import Combination
from tests.fixtures import provenance, record

mujoco = pytest.importorskip("mujoco")

MJCF = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1" friction="1 0.005 0.0001"/>
    <body name="link1" pos="0 0 1">
      <joint name="hinge1" type="hinge" axis="0 1 0" damping="0.5"/>
      <geom name="link1_geom" type="capsule" fromto="0 0 0 0.5 0 0" size="0.04" mass="1"/>
    </body>
    <body name="box" pos="1 1 0.05">
      <freejoint name="box_free"/>
      <geom name="box_geom" type="box" size="0.05 0.05 0.05" mass="0.2"/>
    </body>
  </worldbody>
  <actuator><motor name="motor1" joint="hinge1" ctrlrange="-1 1"/></actuator>
</mujoco>
"""


class MjcfEnv:
    """A raw MJCF behind the EnvAdapter contract: a hinged link and a free box."""

    backend = "mujoco"
    inputs = None
    model_axes = None
    fps = 0.0
    horizon = 50

    def __init__(self) -> None:
        self.model = mujoco.MjModel.from_xml_string(MJCF)
        self.data = mujoco.MjData(self.model)
        self.mujoco = MujocoHandle(self.model, self.data, ("box",))
        self.action_spec = ActionSpec.box(["motor1"], [-1.0], [1.0])
        self.obs_spec = {STATE: Feature.state([("qpos", self.model.nq)])}

    def reset(self, seed: int) -> dict:
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[0] = np.random.default_rng(seed).uniform(-0.1, 0.1)
        mujoco.mj_forward(self.model, self.data)
        return {STATE: self.data.qpos.astype(np.float32).copy()}

    def step(self, action):
        self.data.ctrl[:] = action
        mujoco.mj_step(self.model, self.data)
        return {STATE: self.data.qpos.astype(np.float32).copy()}, 0.0, False, False, {}


def conditions(perturb_cfg: dict, seed: int = 0):
    return axes.conditions_from_config(perturb_cfg, seed)


def apply(env, cond, seed: int):
    """What the rollout does: the condition's generator from the episode seed, then reset through the stepper."""
    stepper, params = perturb.apply(env, cond, condition_rng(seed, cond), seed=seed)
    return stepper, params, stepper.reset(seed)


# -- grammar ---------------------------------------------------------------------------------------
def test_factorial_after_the_single_axis_conditions_and_the_all_at_once_one():
    singles = {"friction": [0.25, 2], "mass": [3]}
    conds = conditions({**singles, "combine": ["friction", "mass"]})
    assert [c.name for c in conds[: len(conds) - 2]] == [c.name for c in conditions(singles)]  # unchanged, first
    combos = conds[-2:]
    assert [c.name for c in combos] == ["friction=0.25&mass=3", "friction=2&mass=3"]
    assert all(isinstance(c, Combination) and c.axis == "friction&mass" for c in combos)
    assert combos[0].level == {"friction": 0.25, "mass": 3.0}
    assert [p.name for p in combos[0].parts] == ["friction=0.25", "mass=3"]
    assert [c.all_at_once for c in combos] == [True, False]  # |log 0.25| > |log 2|: farthest from nominal


def test_all_at_once_is_farthest_from_nominal_per_axis_unit():
    conds = conditions({"latency": [8, 2], "gravity": [1.5, 0.2], "combine": ["latency", "gravity"]})
    (worst,) = [c for c in conds if isinstance(c, Combination) and c.all_at_once]
    assert worst.name == "latency=8&gravity=0.2"  # 8 steps from 0; |log 0.2| > |log 1.5|


def test_fraction_is_a_seeded_subset_that_keeps_the_all_at_once_combination():
    cfg = {"friction": [0.5, 2], "mass": [2, 3, 5], "latency": [1, 4], "combine": ["friction", "mass", "latency"]}
    full = [c for c in conditions(cfg) if isinstance(c, Combination)]
    assert len(full) == 2 * 3 * 2
    half = {**cfg, "combine": {"axes": ["friction", "mass", "latency"], "fraction": 0.5}}
    picks = {s: [c.name for c in conditions(half, s) if isinstance(c, Combination)] for s in range(6)}
    assert all(len(p) == 6 for p in picks.values())
    assert picks[3] == [c.name for c in conditions(half, 3) if isinstance(c, Combination)]  # same seed, same subset
    assert len({tuple(p) for p in picks.values()}) > 1  # another seed, another subset
    worst = next(c.name for c in full if c.all_at_once)
    assert all(worst in p for p in picks.values())
    assert all(p == [c.name for c in full if c.name in p] for p in picks.values())  # in factorial order
    tiny = {**half, "combine": {"axes": ["friction", "mass", "latency"], "fraction": 0.01}}
    assert [c.name for c in conditions(tiny) if isinstance(c, Combination)] == [worst]


@pytest.mark.parametrize(
    "cfg, match",
    [
        (
            {"mass": [2], "combine": ["fricton", "mass"]},
            r"'fricton' is not a perturbation axis; .*Did you mean 'friction'",
        ),
        ({"mass": [2], "combine": ["friction", "mass"]}, r"friction has no levels in this run; give them with"),
        ({"mass": [2], "combine": ["mass", "mass"]}, r"1 distinct axis given \(mass\); combining needs at least 2"),
        ({"mass": [2], "friction": [2], "combine": {"axes": ["mass", "friction"], "fraction": 0}}, r"fraction: 0 is"),
        ({"mass": [2], "friction": [2], "combine": {"axes": ["mass", "friction"], "fraction": 1.5}}, r"\(0, 1\]"),
        ({"mass": [2], "friction": [2], "combine": {"axis": ["mass"]}}, r"combine.axis: unknown key.*'axes'"),
        (
            {"mass": [2], "instruction": ["nonsense"], "combine": ["mass", "instruction"]},
            r"instruction is measured one variant at a time",
        ),
    ],
    ids=["unknown-axis", "no-levels", "one-axis", "fraction-0", "fraction-above-1", "bad-key", "instruction"],
)
def test_bad_combine_is_a_one_line_config_error(cfg, match):
    with pytest.raises(ConfigError, match=match) as exc:
        conditions(cfg)
    assert "\n" not in str(exc.value)


# -- applied together ------------------------------------------------------------------------------
def test_parts_are_applied_together_in_one_episode_and_scales_compose():
    env = MjcfEnv()
    m = env.model
    friction0, mass0 = m.geom_friction.copy(), m.body_mass.copy()
    box = m.body("box").id
    (combo,) = [c for c in conditions({"friction": [0.5], "mass": [4], "combine": ["friction", "mass"]})[3:]]
    for _ in range(2):  # on a reused env, relative to nominal every time
        _, params, _ = apply(env, combo, seed=7)
        np.testing.assert_allclose(m.geom_friction, friction0 * 0.5)
        assert m.body_mass[box] == pytest.approx(mass0[box] * 4)
        assert m.body_subtreemass[box] == pytest.approx(mass0[box] * 4)  # derived constants refreshed
        assert params == {"friction": 0.5, "mass": 4.0}
    apply(env, NOMINAL, seed=7)
    np.testing.assert_array_equal(m.geom_friction, friction0)
    assert m.body_subtreemass[box] == pytest.approx(mass0[box])
    cfg = {"mass": [2], "link_mass": {"levels": [3], "bodies": ["box"]}, "combine": ["mass", "link_mass"]}
    apply(env, conditions(cfg)[-1], seed=7)
    assert m.body_mass[box] == pytest.approx(mass0[box] * 6)  # two scales of one body multiply


def test_each_part_draws_what_it_draws_alone():
    cfg = {"friction": "loguniform(0.5,2)", "latency": "uniform(0,4)", "obs_noise": [0.1]}
    conds = conditions({**cfg, "combine": ["friction", "latency", "obs_noise"]})
    single = {c.axis: c for c in conds[1:4]}
    combo = conds[-1]
    env = MjcfEnv()
    for seed in (1, 2, 3, 4):
        _, params, obs = apply(env, combo, seed)
        for axis in ("friction", "latency"):
            assert params[axis] == apply(env, single[axis], seed)[1][axis]
        alone = apply(env, single["obs_noise"], seed)[2]  # the noise the observation got: the part's own generator
        np.testing.assert_array_equal(obs[STATE], alone[STATE])
    with pytest.raises(ValueError, match="needs the episode seed"):
        perturb.apply(env, combo, condition_rng(7, combo))


# -- scoring ---------------------------------------------------------------------------------------
def rec(condition, episode, success, robot="Panda", axis=None, level=None, error=None):
    return record(
        condition=condition,
        episode=episode,
        robot=robot,
        axis=axis,
        level=level,
        params={},
        seed=1000 + episode,
        success_once=bool(success),
        success_at_end=bool(success),
        error=error,
    )


def run_records(n=8, combo_fails=6, robot="Panda"):
    """Nominal always succeeds; friction alone fails episodes 0-1, mass alone 2-3, together 0..combo_fails-1."""
    out = []
    for e in range(n):
        out += [
            rec("nominal", e, 1, robot),
            rec("friction=0.5", e, e >= 2, robot, "friction", 0.5),
            rec("friction=0.8", e, 1, robot, "friction", 0.8),
            rec("mass=3", e, not 2 <= e < 4, robot, "mass", 3.0),
            rec("friction=0.5&mass=3", e, e >= combo_fails, robot, "friction&mass", {"friction": 0.5, "mass": 3.0}),
            rec("friction=0.8&mass=3", e, e >= 2, robot, "friction&mass", {"friction": 0.8, "mass": 3.0}),
        ]
    return out


def test_interaction_is_the_combined_drop_minus_the_sum_of_single_drops():
    entries = interactions(run_records(), np.random.default_rng(0), n_boot=500)
    assert [e["condition"] for e in entries] == ["friction=0.5&mass=3", "friction=0.8&mass=3"]
    worst, other = entries
    assert worst["all_at_once"] and not other["all_at_once"]
    assert worst["n"] == 8
    assert worst["drop"]["value"] == pytest.approx(6 / 8)
    assert [s["value"] for s in worst["single_drops"]] == pytest.approx([2 / 8, 2 / 8])
    assert worst["sum_of_single_drops"]["value"] == pytest.approx(4 / 8)
    inter = worst["interaction"]
    assert inter["value"] == pytest.approx(2 / 8)
    # the wider of a paired bootstrap over seeds (per seed the interaction is +1 on episodes 4-5, 0 elsewhere:
    # about [0, 0.5]) and MOVER over the drops' own intervals, which is wider at 8 pairs
    d, (dl, du) = worst["drop"]["value"], worst["drop"]["ci"]
    (s1, (l1, u1)), (s2, (l2, u2)) = [(x["value"], x["ci"]) for x in worst["single_drops"]]
    below, above = np.hypot(s1 - l1, s2 - l2), np.hypot(u1 - s1, u2 - s2)
    assert worst["sum_of_single_drops"]["ci"] == pytest.approx([0.5 - below, 0.5 + above], abs=1e-6)
    mover = [0.25 - np.hypot(d - dl, above), 0.25 + np.hypot(du - d, below)]
    assert mover[0] < 0 and mover[1] > 0.625
    assert inter["ci"] == pytest.approx(mover, abs=1e-6)
    # friction=0.8 alone drops nothing, mass=3 drops 2/8 (seeds 2-3), together 2/8 but on seeds 0-1: the mean
    # interaction is 0 while every seed's is +1, -1 or 0
    assert other["interaction"]["value"] == pytest.approx(0.0)
    assert other["interaction"]["ci"][0] < 0 < other["interaction"]["ci"][1]
    sure = interactions(run_records(combo_fails=4), np.random.default_rng(0), n_boot=500)[0]
    assert sure["interaction"]["value"] == 0.0  # 0 on every seed: a bootstrap alone would say [0, 0]
    assert sure["interaction"]["ci"][0] < -0.3 and sure["interaction"]["ci"][1] > 0.3
    assert sure["reading"] == "not distinguishable from the sum of single drops"


def test_interaction_reading_and_sentence():
    recs = []
    for e in range(40):  # each alone drops nothing, together everything: compounding
        recs += [
            rec("nominal", e, 1),
            rec("friction=0.5", e, 1, axis="friction", level=0.5),
            rec("mass=3", e, 1, axis="mass", level=3.0),
            rec("friction=0.5&mass=3", e, 0, axis="friction&mass", level={"friction": 0.5, "mass": 3.0}),
        ]
    (entry,) = interactions(recs, np.random.default_rng(0), n_boot=300)
    assert entry["reading"] == "more than the sum of single drops"
    line = sentence(entry)
    assert line.startswith("friction=0.5 with mass=3 (all at once): drop +1.00 [")
    assert "; sum of single drops +0.00 [" in line and "; interaction +1.00 [+0." in line  # not [+1.00, +1.00]
    assert line.endswith("(more than the sum of single drops; success_once, 40 pairs)")


def test_pairs_leave_out_errors_and_a_missing_part_is_null_with_a_reason():
    recs = run_records()
    recs = [
        rec(r.condition, r.episode, r.success_once, axis=r.axis, level=r.level, error="boom")
        if r.condition == "mass=3" and r.episode == 0
        else r
        for r in recs
    ]
    entry = interactions(recs, np.random.default_rng(0), n_boot=200)[0]
    assert entry["n"] == 7 and entry["drop"]["value"] == pytest.approx(5 / 7)
    no_part = [r for r in run_records() if r.condition != "mass=3"]
    entry = interactions(no_part, np.random.default_rng(0), n_boot=200)[0]
    assert entry["interaction"] == {"value": None, "ci": None, "reason": "no record of mass=3 in this run"}
    assert "no interaction (no record of mass=3 in this run)" in sentence(entry)


def _summary(records):
    meta = {
        "run_id": "r",
        "suite": {"name": "toy", "version": "1", "manifest": {}},
        "policy": {"name": "p", "checkpoint": None, "checkpoint_sha256": None},
        "config": {"seed": 0, "n_boot": 200, "confidence": 0.95, "metric": "success_once"},
        "expected_episodes": len(records),
        "provenance": provenance(backend=["b"], episode_seeds=[1], finished_at="2026-01-01T00:00:00+00:00"),
    }
    return build(records, run_meta=meta).to_json()


def test_summary_leaderboard_and_report_carry_the_interactions():
    recs = run_records() + run_records(robot="UR5e")
    summary = _summary(recs)
    assert validate(summary) == "bench.summary/1"
    assert [e["condition"] for e in summary["interactions"]] == ["friction=0.5&mass=3", "friction=0.8&mass=3"]
    assert summary["interactions"][0]["n"] == 16
    assert "curves" not in summary
    broken = json.loads(json.dumps(summary))
    del broken["interactions"][0]["interaction"]["ci"]
    with pytest.raises(Exception, match=r"interactions\[0\]"):
        validate(broken)
    board = merge([("r/summary.json", summary)])
    assert validate(board) == "bench.leaderboard/1"
    (entry,) = board["entries"]
    assert entry["interactions"][0]["interaction"]["value"] == pytest.approx(0.25)
    assert entry["interactions"][0]["all_at_once"] is True
    html = interactions_section(summary["interactions"])
    assert "Combined perturbations" in html and "friction=0.5 with mass=3 <b>(all at once)</b>" in html


# -- the command line ------------------------------------------------------------------------------
TOY = ["run", "suite=tests.toy_suite:ToySuite", "workers=1", "episodes=3"]


@pytest.mark.parametrize(
    "keys, match",
    [
        (["perturb.latency=[2]", "perturb.combine=[fricton,latency]"], "Did you mean 'friction'?"),
        (["perturb.latency=[2]", "perturb.combine=[latency,action_noise]"], "action_noise has no levels in this run"),
        (["perturb.latency=[2]", "perturb.combine=[latency]"], "combining needs at least 2"),
        (
            ["perturb.latency=[2]", "perturb.obs_noise=[1]", "perturb.combine.axes=[latency,obs_noise]"]
            + ["perturb.combine.fraction=2"],
            "perturb.combine.fraction: 2 is invalid",
        ),
        (["perturb.latency=[2]", "perturb.light=[0.5]", "perturb.combine=[latency,light]"], "has no camera rig"),
        (["perturb.latency=[2]", "perturb.friction=[0.5]", "perturb.combine=[friction,latency]"], "cannot apply it"),
        (
            ["perturb.latency=[2]", "perturb.obs_noise=[1]", "perturb.combine=[latency,obs_noise]"]
            + ["perturb.combine.fraction=0.5"],
            "(e.g. perturb.combine.axes=[...] perturb.combine.fraction=...)",
        ),
    ],
    ids=[
        "unknown-axis",
        "no-levels",
        "one-axis",
        "fraction",
        "visual-without-cameras",
        "model-without-model",
        "list-and-sub-key",
    ],
)
def test_bad_combine_on_the_command_line_exits_2_and_writes_nothing(tmp_path: Path, capsys, keys, match):
    out = tmp_path / "runs"
    assert main([*TOY, *keys, f"out={out}"]) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_a_combined_run_keeps_the_single_axis_records_and_prints_the_interaction(tmp_path: Path, capsys):
    keys = ["perturb.latency=[2,6]", "perturb.action_noise=[1.5]"]
    assert main([*TOY, *keys, f"out={tmp_path}", "run_id=plain"]) == 0
    assert main([*TOY, *keys, "perturb.combine=[latency,action_noise]", f"out={tmp_path}", "run_id=comb"]) == 0
    printed = capsys.readouterr().out
    assert "latency=6 with action_noise=1.5 (all at once): drop " in printed and "; interaction " in printed

    def records(run: str) -> dict[str, dict]:
        volatile = ("run_id", "finished_at", "worker_pid", "wall_s")
        lines = (tmp_path / run / "episodes.jsonl").read_text().splitlines()
        rows = [{k: v for k, v in json.loads(x).items() if k not in volatile} for x in lines]
        return {r["job_id"]: r for r in rows}

    plain, combined = records("plain"), records("comb")
    assert {k: combined[k] for k in plain} == plain  # nominal and single-axis records unchanged
    extra = [r for k, r in combined.items() if k not in plain]
    assert len(extra) == 2 * 3 * 3  # 2 combinations x 3 cells x 3 episodes
    assert {json.dumps(r["params"], sort_keys=True) for r in extra} == {
        '{"action_noise": 1.5, "latency": 2}',
        '{"action_noise": 1.5, "latency": 6}',
    }


def test_a_pose_axis_combines_with_a_model_axis():
    """init_qpos (a `start` hook: the state the reset leaves is edited) and damping (a model scale) in one episode,
    each as it is alone: the same offset, the same damping."""
    from bench.sims.gym import GymEnv  # gymnasium: imported only by the test that builds one

    conds = {c.name: c for c in conditions({"init_qpos": [0.2], "damping": [3], "combine": ["init_qpos", "damping"]})}
    combo = conds["init_qpos=0.2&damping=3"]
    assert isinstance(combo, Combination)
    env = GymEnv("HalfCheetah-v5", 5)
    try:
        _, params, _ = apply(env, combo, 11)
        damping = env.mujoco.model.dof_damping.copy()
        _, alone, _ = apply(env, conds["init_qpos=0.2"], 11)
        assert params["init_qpos.offset"] == alone["init_qpos.offset"]
        assert np.linalg.norm(params["init_qpos.offset"]) == pytest.approx(0.2, abs=1e-9)
        apply(env, conds["damping=3"], 11)
        np.testing.assert_array_equal(damping, env.mujoco.model.dof_damping)
        apply(env, NOMINAL, 11)
        assert not np.array_equal(damping, env.mujoco.model.dof_damping)  # restored between episodes
    finally:
        env.close()

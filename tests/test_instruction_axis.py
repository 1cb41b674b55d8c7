"""perturb.instruction: variants drawn from the shipped data, what the policy sees, the action difference, refusals."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import re
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.core.errors import ConfigError
from bench.execution.rollout import RunContext, run_episode
from bench.protocols import STATE, TASK, ActionSpec, Feature
from bench.protocols.env import AdapterBase
from bench.protocols.suite import Cell, Job
from bench.sims.perturb import language
from bench.sims.perturb.axes import conditions_from_config

DATA = sorted((Path(__file__).parents[1] / "suites" / "instructions").glob("*.json"))
TRUE = "pick up the cube and place it on the plate"
TOY_DATA = {
    "source": "toy",
    "sha256": "0",
    "synonyms": {"cube": ["block"], "plate": ["dish"]},
    "distractors": ["while humming a tune"],
    "tasks": {
        "toy": {"instruction": TRUE, "paraphrase": ["put the cube on the plate", "move the cube onto the plate"]}
    },
}


@pytest.mark.parametrize("path", DATA, ids=lambda p: p.stem)
@pytest.mark.parametrize("variant", language.VARIANTS)
def test_variants_deterministic_per_seed_and_from_the_shipped_data(path, variant):
    data = language.load(path)
    for task, entry in data["tasks"].items():
        true = entry["instruction"]
        texts = [language.variant_text(variant, task, data, np.random.default_rng([s, 1])) for s in range(6)]
        again = [language.variant_text(variant, task, data, np.random.default_rng([s, 1])) for s in range(6)]
        assert texts == again, (task, variant)
        for text in texts:
            if variant == "empty":
                assert text == ""
            else:
                assert text and text != true, (task, variant, text)
            if variant == "paraphrase":
                assert text in entry["paraphrase"]
            if variant == "distractor":
                assert text.rstrip(".").endswith(tuple(data["distractors"]))
            if variant == "nonsense":
                assert set(text.split()) <= set(language.NONSENSE)
                assert not set(text.split()) & set(re.findall(r"[a-z]+", true.lower()))


def test_shipped_instructions_are_the_suites_own():
    from suites import aloha, held_out_envs, maniskill_common, pusht  # the suites' tables (ManiSkill's: its extra)

    def tasks(name):
        return json.loads((Path(aloha.__file__).with_name("instructions") / f"{name}.json").read_text())["tasks"]

    assert {t: e["instruction"] for t, e in tasks("aloha").items()} == {
        t: s.instruction for t, s in aloha.TASKS.items()
    }
    assert tasks("pusht") == {pusht.TASK_ID: tasks("pusht")[pusht.TASK_ID]}
    assert tasks("pusht")[pusht.TASK_ID]["instruction"] == pusht.INSTRUCTION
    assert {t: e["instruction"] for t, e in tasks("maniskill").items()} == {
        t: s.instruction for t, s in maniskill_common.TASKS.items()
    }
    every = set(held_out_envs.ML10["seen"] + held_out_envs.ML10["unseen"] + held_out_envs.ML45["seen"])
    assert every | set(held_out_envs.ML45["unseen"]) <= set(tasks("metaworld"))
    assert held_out_envs.instruction("drawer-open-v3") == "open the drawer"


def test_grammar_one_condition_per_word_and_numbers_refused():
    conds = conditions_from_config({"instruction": ["paraphrase", "empty", "nonsense", "empty"]})
    assert [c.name for c in conds] == ["nominal", "instruction=paraphrase", "instruction=empty", "instruction=nonsense"]
    assert [c.level for c in conds[1:]] == ["paraphrase", "empty", "nonsense"]
    for bad in ([0.5], "uniform(0,1)", {"curve": "uniform(0,1)"}, ["paraphrse"]):
        with pytest.raises(ConfigError, match="perturb.instruction"):
            conditions_from_config({"instruction": bad})


# -- the rollout: what the policy sees and the action difference ------------------------------------------
class WordsEnv(AdapterBase):
    """A one-number env whose observation carries an instruction."""

    backend, horizon, fps = "words-1", 12, 10.0
    obs_spec = {STATE: Feature.state([("x", 1)]), TASK: Feature.text()}
    action_spec = ActionSpec.box(["a"], -1.0, 1.0)

    def reset(self, seed):
        self.x = 0.0
        return {STATE: np.zeros(1, np.float32), TASK: TRUE}

    def step(self, action):
        self.x += float(action[0])
        return {STATE: np.array([self.x], np.float32), TASK: TRUE}, 0.0, False, False, {}

    def success(self):
        return False

    def init_state(self):
        return np.zeros(1)


class ChunkingReader:
    """Stateful and chunking: answers a chunk of 3 rows, 0.5 when it reads the true instruction, else -0.5; counts
    its calls (its state, reset per episode)."""

    def __init__(self):
        self.seen: list[str] = []

    def reset(self, seed):
        self.calls = 0

    def act(self, obs):
        self.seen.append(obs[TASK])
        self.calls += 1
        sign = 0.5 if obs[TASK] == TRUE else -0.5
        return np.full((3, 1), sign, np.float32)


def _episode(variant, shadow=True):
    cond = next(c for c in conditions_from_config({"instruction": [variant]}) if c.axis == "instruction")
    cond = dataclasses.replace(cond, spec={**cond.spec, "instructions": TOY_DATA})
    job = Job(Cell("words", "toy", "r", "e", "seen"), cond, 0, 7)
    ctx = RunContext("run", "1", "reader", None, {}, horizon=8, timeout_s=0)
    policy, twin = ChunkingReader(), ChunkingReader()
    record, ok = run_episode(job, WordsEnv(), policy, ctx, shadow=twin if shadow else None)
    assert ok, record.error
    return record, policy, twin


@pytest.mark.parametrize("variant", ["paraphrase", "nonsense", "empty"])
def test_the_policy_sees_the_variant_and_the_shadow_the_true_text(variant):
    record, policy, twin = _episode(variant)
    words = record.extras["instruction"]
    assert words["variant"] == variant and words["true"] == TRUE
    assert set(policy.seen) == {words["text"]} and set(twin.seen) == {TRUE}
    assert len(policy.seen) == len(twin.seen) == policy.calls == twin.calls == 3  # 8 steps in chunks of 3: 0, 3, 6
    assert record.params == {"instruction": variant}
    # every variant differs here, so every executed step differs by 1 (a half-range of [-1, 1])
    assert words["action_diff"] == pytest.approx(1.0) and words["steps_differ"] == 1.0 and words["steps"] == 8
    if variant == "paraphrase":
        assert words["text"] in TOY_DATA["tasks"]["toy"]["paraphrase"]
    assert _episode(variant)[0].extras["instruction"]["text"] == words["text"]  # the seed decides the text


def test_nominal_episodes_have_no_instruction_record():
    job = Job(Cell("words", "toy", "r", "e", "seen"), conditions_from_config({})[0], 0, 7)
    ctx = RunContext("run", "1", "reader", None, {}, horizon=4, timeout_s=0)
    record, _ = run_episode(job, WordsEnv(), ChunkingReader(), ctx)
    assert "instruction" not in record.extras


# -- Meta-World: the language-reading expert, and records unchanged by the instruction in the observation -------
needs_metaworld = pytest.mark.skipif(importlib.util.find_spec("metaworld") is None, reason="Meta-World not installed")


def _mw_episode(variant, task="drawer-open-v3", horizon=40):
    from baselines.metaworld_language import LanguageExpertPlugin, LanguageOptions  # needs Meta-World (skipped)
    from bench.protocols import PolicyContext
    from suites.held_out_envs import HeldOutEnvs

    suite = HeldOutEnvs()
    cell = next(c for c in suite.all_cells() if c.task == task)
    plugin = LanguageExpertPlugin()
    conds = language.prepare(
        conditions_from_config({"instruction": [variant]}), suite, [cell], plugin.obs_keys(None), "metaworld_language"
    )
    env = suite.make_env(cell, horizon)
    ctx = PolicyContext(LanguageOptions(experts="suite"), suite, 0, horizon)
    policy, twin = plugin.make(cell, env, ctx), plugin.make(cell, env, ctx)
    run = RunContext("run", "1", "metaworld_language", None, {}, horizon=horizon, timeout_s=0)
    record, ok = run_episode(Job(cell, conds[1], 0, 11), env, policy, run, shadow=twin)
    env.close()
    assert ok, record.error
    return record.extras["instruction"]


@needs_metaworld
def test_language_expert_paraphrase_differs_by_zero_nonsense_by_more():
    para = _mw_episode("paraphrase")
    assert para["text"] != para["true"] == "open the drawer"
    assert para["action_diff"] == 0.0 and para["steps_differ"] == 0.0
    for control in ("nonsense", "empty"):
        assert _mw_episode(control)["action_diff"] > 0.1


@needs_metaworld
def test_metaworld_observation_gains_the_instruction_and_nothing_else_changes():
    from baselines.metaworld_expert import make_expert  # needs Meta-World (skipped without it)
    from bench.api.sims import MetaWorldEnv

    runs = []
    for instruction in (None, "open the drawer"):
        env = MetaWorldEnv("drawer-open-v3", 30, instruction)
        expert = make_expert(env)
        obs = env.reset(5)
        states, rewards = [obs[STATE]], []
        assert (TASK in obs) == (instruction is not None) and (TASK in env.obs_spec) == (instruction is not None)
        for _ in range(30):
            obs, reward, *_ = env.step(expert.act(obs))
            states.append(obs[STATE])
            rewards.append(reward)
        runs.append((np.array(states), rewards, env.success(), env.init_state()))
        env.close()
    (s0, r0, ok0, i0), (s1, r1, ok1, i1) = runs
    assert np.array_equal(s0, s1) and r0 == r1 and ok0 == ok1 and np.array_equal(i0, i1)


# -- refusals through the command line: one line, exit 2, nothing written --------------------------------
@pytest.mark.parametrize(
    "argv, pattern",
    [
        (["suite=held_out_envs", "policy=scripted", "perturb.instruction=[nonsense]"], "policy 'scripted' reads none"),
        (["suite=held_out_robots", "perturb.instruction=[nonsense]"], "gives the policy no instruction"),
        (["suite=held_out_envs", "policy=metaworld_language", "perturb.instruction=[0.5]"], "categorical"),
        (["suite=held_out_envs", "policy=metaworld_language", "perturb.instruction.curve=uniform(0,1)"], "levels"),
    ],
    ids=["policy-reads-no-instruction", "suite-without-instruction", "number", "curve"],
)
def test_refusals_exit_2_nothing_written(tmp_path, capsys, argv, pattern):
    out = tmp_path / "runs"
    code = main(["run", *argv, "episodes=1", f"out={out}"])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert re.search(pattern, err), err
    assert not out.exists()

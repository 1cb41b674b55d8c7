"""`bench run vector=N` (bench.execution.vector): N envs of one cell and condition in lockstep, their policy asked
once per step; records equal to vector=1's, early ends masked, batched and split policies, bad input."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from bench import api
from bench.cli import main
from bench.execution.rollout import RunContext, run_episode
from bench.execution.scheduling import JobQueue
from bench.execution.vector import run_vector
from bench.protocols import STATE, ActionSpec, Feature, batchable
from bench.protocols.suite import Cell, Condition, Job, expand_jobs
from bench.records import comparable, read_records
from tests.toy_suite import GreedyExpert

TOY = "suite=tests.toy_suite:ToySuite"
CELL = Cell("toy", "reach", "a", "line", "seen")


def ctx(horizon: int = 12, timeout: float = 0) -> RunContext:
    return RunContext("r", "1", "p", None, {}, horizon, timeout)


class EndingEnv:
    """x' = x + a; ends (terminated) once x passes 1, after a number of steps that depends on the seed; counts steps."""

    backend, fps, mujoco, inputs, model_axes = "ending-1", 10.0, None, None, None
    obs_spec = {STATE: Feature.state([("x", 1)])}
    action_spec = ActionSpec.box(["a"], -1.0, 1.0)

    def __init__(self, fail_at: int | None = None):
        self.x, self.steps_taken, self.fail_at, self.t = 0.0, 0, fail_at, 0

    def reset(self, seed: int) -> dict:
        self.x, self.t = float(np.random.default_rng(seed).uniform(-2, 0.5)), 0
        return {STATE: np.array([self.x], np.float32)}

    def step(self, action):
        self.steps_taken += 1
        self.t += 1
        if self.fail_at is not None and self.t >= self.fail_at:
            raise RuntimeError("ending env broke")
        self.x += 0.3 * float(action[0])
        return {STATE: np.array([self.x], np.float32)}, -abs(1 - self.x), self.x > 1, False, {}

    def success(self) -> bool:
        return self.x > 1

    def init_state(self) -> np.ndarray:
        return np.array([self.x])

    def close(self) -> None:
        pass


class Push:
    """Pushes right, harder the further left; answers chunks of `chunk` rows."""

    def __init__(self, chunk: int = 1):
        self.chunk, self.calls = chunk, 0

    def reset(self, seed: int) -> None:
        pass

    def act(self, obs: dict) -> np.ndarray:
        self.calls += 1
        x = float(obs[STATE][0])
        return np.full((self.chunk, 1), np.clip(1.5 - x, -1, 1), np.float32)


class BatchPush(Push):
    """Push, declaring batches: `act_batch` answers (N, T, A), or a wrong count with `wrong=True`."""

    batch_key = "push"

    def __init__(self, chunk: int = 1, wrong: bool = False, log: list | None = None):
        super().__init__(chunk)
        self.wrong, self.log = wrong, log if log is not None else []

    def act_batch(self, observations: list[dict]) -> np.ndarray:
        self.log.append(len(observations))
        answers = np.stack([Push.act(self, o) for o in observations])
        return answers[1:] if self.wrong else answers


class SplitPush(Push):
    """Push with `send`/`receive`, logging the order of the calls."""

    def __init__(self, log: list):
        super().__init__()
        self.log, self.sent = log, None

    def send(self, obs: dict) -> None:
        self.log.append("send")
        self.sent = obs

    def receive(self) -> np.ndarray:
        self.log.append("receive")
        return self.act(self.sent)


def jobs(n: int, seed: int = 3) -> list[Job]:
    return expand_jobs([CELL], [Condition()], n, seed)


def alone(js: list[Job], make_policy, c: RunContext) -> list[dict]:
    return [comparable(run_episode(j, EndingEnv(), make_policy(), c)[0]) for j in js]


@pytest.mark.parametrize("chunk", [1, 3])
@pytest.mark.parametrize("kind", ["plain", "batch", "split"])
def test_lockstep_records_equal_one_env_and_ended_episodes_are_masked(kind, chunk):
    js, c = jobs(6), ctx()
    log: list = []
    make = {
        "plain": lambda: Push(chunk),
        "batch": lambda: BatchPush(chunk, log=log),
        "split": lambda: SplitPush(log) if chunk == 1 else Push(chunk),
    }[kind]
    envs = [EndingEnv() for _ in js]
    policies = [make() for _ in js]
    results = run_vector(js, envs, policies, c)
    want = alone(js, make, c)
    assert [comparable(r) for r, _ in results] == want
    lengths = [r.length for r, _ in results]
    assert len(set(lengths)) > 1 and min(lengths) < c.horizon  # some ended early, at different steps
    assert [e.steps_taken for e in envs] == lengths  # an ended episode is never stepped again
    if kind == "batch":  # one call per step for every env wanting an answer
        assert sum(log) == sum(p.calls for p in policies) and len(log) < sum(log)
        assert log[0] == len(js)
    if kind == "split" and chunk == 1:  # every env's request goes out before any answer is read
        first = log[: 2 * len(js)]
        assert first == ["send"] * len(js) + ["receive"] * len(js)


def test_a_failing_env_ends_only_its_episode():
    js, c = jobs(4), ctx()
    envs = [EndingEnv(fail_at=2 if i == 1 else None) for i in range(len(js))]
    results = run_vector(js, envs, [Push() for _ in js], c)
    records = [r for r, _ in results]
    assert [ok for _, ok in results] == [r.error is None for r in records]
    assert records[1].error.startswith("RuntimeError: ending env broke") and records[1].length == 1
    assert all(r.error is None for i, r in enumerate(records) if i != 1)
    assert comparable(records[1]) == comparable(run_episode(js[1], EndingEnv(fail_at=2), Push(), c)[0])


def test_a_wrong_batch_shape_is_recorded_for_those_episodes():
    js, c = jobs(3), ctx()
    results = run_vector(js, [EndingEnv() for _ in js], [BatchPush(wrong=True) for _ in js], c)
    for record, usable in results:
        assert not usable and record.length == 0
        assert "act_batch returned an array of shape (2, 1, 1) for 3 observations" in record.error


def test_checkpoint_batches_are_bit_for_bit_its_single_answers():
    torch = pytest.importorskip("torch")
    from baselines.architectures import build, rowwise
    from baselines.checkpoint import PACKAGED_BC, load_policy

    torch.set_num_threads(1)
    policy = load_policy(PACKAGED_BC)
    assert batchable(policy)
    rng = np.random.default_rng(0)
    obs = [{STATE: rng.normal(size=18).astype(np.float32)} for _ in range(33)]
    assert all(np.array_equal(a, policy.act(o)) for a, o in zip(policy.act_batch(obs), obs))
    torch.manual_seed(0)
    for kwargs in (
        {"hidden": [50, 33], "activation": "elu"},
        {"hidden": [64], "activation": "gelu", "layer_norm": True, "out_activation": "tanh"},
        {"hidden": [7, 100], "activation": "tanh"},
    ):
        model = build("mlp", 11, 5, kwargs)
        x = torch.randn(40, 11)
        with torch.inference_mode():
            one = torch.cat([rowwise(model, x[i : i + 1]) for i in range(40)])
            assert torch.equal(rowwise(model, x), one), kwargs


def test_take_group_gives_one_cell_and_condition():
    conds = [Condition(), Condition("f2", "friction", 2.0)]
    cells = [CELL, Cell("toy", "reach", "b", "line", "seen")]
    q = JobQueue(expand_jobs(cells, conds, 5, 0))
    groups = []
    while group := q.take_group((), 4):
        groups.append([(j.cell.robot, j.condition.name, j.episode) for j in group])
    assert sorted(len(g) for g in groups) == [1] * 4 + [4] * 4  # 5 episodes per cell and condition: 4 + 1
    assert all(len({(r, c) for r, c, _ in g}) == 1 for g in groups)
    assert len({job for g in groups for job in g}) == 20


def run_records(out: Path, run_id: str) -> list[dict]:
    return [comparable(r) for r in sorted(read_records(out / run_id / "episodes.jsonl"), key=lambda r: r.job_id)]


def test_bench_run_vector_records_equal_vector_1(tmp_path):
    common = [TOY, "episodes=5", "fault=raise", "perturb.action_noise=uniform(0,0.3)", f"out={tmp_path}"]
    assert main(["run", *common, "workers=1", "run_id=one"]) == 3  # robot c fails every episode: exit 3
    assert main(["run", *common, "workers=1", "vector=4", "run_id=four"]) == 3
    assert main(["run", *common, "workers=2", "vector=5", "run_id=two"]) == 3
    one = run_records(tmp_path, "one")
    assert any(r["error"] for r in one) and len(one) == 30
    assert run_records(tmp_path, "four") == one
    assert run_records(tmp_path, "two") == one
    assert json.loads((tmp_path / "four" / "run.json").read_text())["config"]["vector"] == 4
    assert "vector" not in json.loads((tmp_path / "one" / "run.json").read_text())["config"]


@pytest.mark.parametrize(
    "args, message",
    [
        (["vector=0"], "vector=0: must be in [1, 65536]"),
        (["vector=5"], "vector=5: more envs than a cell has episodes (episodes=4 per cell and condition)"),
    ],
)
def test_bad_vector_is_one_line_and_writes_nothing(tmp_path, capsys, args, message):
    code = main(["run", TOY, "episodes=4", f"out={tmp_path}", "run_id=x", *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and message in err[0]
    assert not os.listdir(tmp_path)


def test_resume_may_change_vector(tmp_path):
    cfg = api.RunConfig(suite="tests.toy_suite:ToySuite", episodes=4, workers=1, out=str(tmp_path), run_id="r")
    api.run(cfg, only=lambda j: j.episode < 2)
    again = api.run(api.RunConfig(**{**cfg.__dict__, "vector": 2}))
    assert (again.resumed, again.ran) == (6, 6)
    reference = api.run(api.RunConfig(**{**cfg.__dict__, "run_id": "ref"}))
    assert [comparable(r) for r in sorted(again.records, key=lambda r: r.job_id)] == [
        comparable(r) for r in sorted(reference.records, key=lambda r: r.job_id)
    ]


def test_greedy_expert_has_no_batch():
    assert not batchable(GreedyExpert())


def test_held_out_robots_with_the_packaged_bc_records_equal_vector_1(tmp_path):
    pytest.importorskip("robosuite")
    pytest.importorskip("torch")
    common = [
        "suite=held_out_robots",
        "policy=bc",
        "robots=[Panda]",
        "episodes=3",
        "horizon=10",
        "workers=1",
        "perturb.friction=uniform(0.5,1.5)",
        f"out={tmp_path}",
    ]
    assert main(["run", *common, "run_id=one"]) == 0
    assert main(["run", *common, "vector=3", "run_id=three"]) == 0
    one = run_records(tmp_path, "one")
    assert len(one) == 6 and all(r["error"] is None for r in one)
    assert run_records(tmp_path, "three") == one

"""`bench run vector=N` bad input refused before anything is written (one line, exit 2): vector=0, a vector over
a cell's episodes, and a batched policy whose `act_batch` answers a wrong shape (`bench.execution.vector.probe`)."""

from __future__ import annotations

import numpy as np
import pytest

from bench.cli import main

TOY = "suite=tests.toy_suite:ToySuite"


class WrongBatch:
    """Declares batches; `act_batch` answers one action fewer than it was asked for (its `act` is right)."""

    batch_key = "wrong-batch"

    def reset(self, seed: int | None = None) -> None:
        return None

    def act(self, obs: dict) -> np.ndarray:
        return np.zeros(1, np.float32)

    def act_batch(self, observations: list[dict]) -> np.ndarray:
        return np.zeros((len(observations) - 1, 1), np.float32)


def wrong_batch_policy(cell, env, ctx) -> WrongBatch:
    return WrongBatch()


def right_batch_policy(cell, env, ctx):
    from tests.test_vector import BatchPush  # the well-behaved batched policy of the vector tests

    return BatchPush()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["vector=0"], "vector=0: must be in [1, 65536]"),
        (["vector=3"], "vector=3: more envs than a cell has episodes (episodes=2 per cell"),
        (
            ["vector=2", "policy=tests.test_vector_bad_input:wrong_batch_policy"],
            "vector=2: the batched policy WrongBatch on reach/a/line: policy act_batch returned",
        ),
    ],
    ids=["zero", "over-episodes", "wrong-batch-shape"],
)
def test_bad_vector_input_is_one_line_and_writes_nothing(tmp_path, capsys, extra, message):
    argv = ["run", TOY, "episodes=2", "horizon=3", "workers=1", f"out={tmp_path}", "run_id=bad", *extra]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "bad").exists()


def test_wrong_batch_shape_message_names_the_shape(tmp_path, capsys):
    argv = ["run", TOY, "episodes=2", "horizon=3", "workers=1", "vector=2", f"out={tmp_path}", "run_id=bad"]
    assert main([*argv, "policy=tests.test_vector_bad_input:wrong_batch_policy"]) == 2
    assert "act_batch returned an array of shape (1, 1) for 2 observations" in capsys.readouterr().err


def test_a_right_batch_shape_passes_the_probe_and_runs(tmp_path):
    argv = ["run", TOY, "episodes=2", "horizon=3", "workers=1", "vector=2", f"out={tmp_path}", "run_id=ok"]
    assert main([*argv, "policy=tests.test_vector_bad_input:right_batch_policy"]) == 0
    assert (tmp_path / "ok" / "episodes.jsonl").exists()

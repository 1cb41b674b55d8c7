"""The MJX Lift suite (suites/mjx_lift.py): N worlds per call, one record per world, bad input refused.

Needs the mjx extra; skipped without it. Small on purpose: JAX compiles each world count once (40 s on this CPU,
then cached on disk), so the runs here use 1 and 2 worlds and a 60-step horizon.
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.cli import main
from bench.core.errors import ConfigError
from bench.records import read_records

pytest.importorskip("mujoco.mjx")
pytest.importorskip("robosuite")


def _run(tmp_path, *extra: str) -> int:
    return main(["run", "suite=mjx_lift", "episodes=2", "horizon=60", "seed=3", f"out={tmp_path}", *extra])


@pytest.mark.slow
def test_vector_run_gives_one_record_per_world_like_vector_1(tmp_path):
    assert _run(tmp_path, "workers=1", "vector=2", "run_id=two") == 0
    assert _run(tmp_path, "workers=1", "vector=1", "run_id=one") == 0
    two = sorted(read_records(tmp_path / "two" / "episodes.jsonl"), key=lambda r: r.episode)
    one = sorted(read_records(tmp_path / "one" / "episodes.jsonl"), key=lambda r: r.episode)
    assert [r.episode for r in two] == [0, 1]
    assert len({r.init_state_hash for r in two}) == 2  # each world its own cube from its episode seed
    assert all(r.success_once and r.error is None for r in two)  # the batched expert lifts the cube
    assert [r.init_state_hash for r in one] == [r.init_state_hash for r in two]
    # a world stepped alone and in a batch of 2: the same outcome (float32 batches may differ in the last bits)
    assert [(r.success_once, r.steps_to_success) for r in one] == [(r.success_once, r.steps_to_success) for r in two]
    assert all(r.backend.startswith("mjx-") for r in two)


def test_axis_mjx_cannot_express_is_refused_before_the_run(tmp_path, capsys):
    assert _run(tmp_path, "perturb.damping=[0.5]", "run_id=bad") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "perturb.damping" in err and "friction, mass" in err
    assert not (tmp_path / "bad").exists()


def test_world_count_beyond_memory_is_refused_in_one_line():
    from bench.sims import mjx_lift  # the MJX scene: only with the extra (importorskip above)

    mjx_lift.check_worlds(1024, available=2**34)  # 16 GiB holds 1,024 worlds
    with pytest.raises(ConfigError) as e:
        mjx_lift.check_worlds(10**6, available=2**34)
    assert "worlds=1000000" in str(e.value) and "\n" not in str(e.value)


def test_batched_expert_is_stateless_and_batched():
    from baselines.mjx_lift_expert import BatchLiftExpert  # beside the suite: only once the extra is there
    from bench.sims.mjx_lift import OBS_FIELDS  # imports MuJoCo's MJX helpers: only with the extra

    expert = BatchLiftExpert(OBS_FIELDS)
    obs = np.zeros(18, np.float32)
    obs[0:3], obs[7], obs[8:11] = (0.0, 0.0, 0.83), 0.4, (0.0, 0.0, 0.82)  # closed on the cube: lift
    far = obs.copy()
    far[8:11] = (0.1, 0.0, 0.82)  # away from the cube, open: hover
    far[7] = 1.0
    batch = expert.act_batch([{"state": obs}, {"state": far}])
    assert batch.shape == (2, 7)
    assert batch[0, 2] > 0 and batch[0, 6] == 1.0 and batch[1, 6] == -1.0
    assert np.array_equal(expert.act({"state": far}), batch[1])


def test_observation_is_held_out_robots_lift_observation():
    """bench.sims sits below the suites, so the MJX scene names the Lift observation itself: it must stay the one
    suites/lift.py defines (a policy trained on held_out_robots reads both)."""
    from bench.sims.mjx_lift import OBS_FIELDS
    from suites.lift import OBS_FIELDS as LIFT

    assert list(OBS_FIELDS) == [tuple(f) for f in LIFT]

"""A lerobot policy evaluated by bench over the remote-policy protocol, end to end (slow; lerobot's side venv).

bench records Lift demonstrations on Panda; lerobot's own dataset tool and training script (in the side venv
built by `.ci/lerobot-venv.sh`, BENCH_LEROBOT_PYTHON) train a tiny ACT on them; `baselines/lerobot_adapter.py`
serves it; `bench run suite=held_out_robots policy=remote` and `bench actions policy=remote` evaluate it. Budget:
4 recorded episodes of 60 steps, 60 training steps of an 80k-parameter model, 1 evaluation episode.
"""

from __future__ import annotations

import pytest

from bench.cli import main
from bench.records import read_records
from tests.lerobot_side import served, train

OBS_MAP = (
    "obs_map=[observation.state:state,"
    "observation.environment_state:state.object_pos+state.object_quat+state.gripper_to_object]"
)


@pytest.mark.slow
def test_lerobot_act_trained_on_bench_data_runs_through_policy_remote(lerobot_python, tmp_path, capsys):
    record = ["run", "suite=held_out_robots", "policy=scripted", "robots=[Panda]", "episodes=4", "horizon=60"]
    policy_dir, out = train(lerobot_python, tmp_path, record, [], steps=60, batch=8)
    assert "observation.environment_state = object_pos_0" in out
    err_log = tmp_path / "adapter.err"
    with served(lerobot_python, policy_dir, err_log) as (proc, port):
        capsys.readouterr()
        assert (
            main(
                [
                    "run",
                    "suite=held_out_robots",
                    "policy=remote",
                    f"port={port}",
                    "timeout_s=60",
                    "robots=[Panda]",
                    "episodes=1",
                    "horizon=40",
                    "replan_every=4",
                    "workers=1",
                    OBS_MAP,
                    f"out={tmp_path}",
                    "run_id=remote",
                ]
            )
            == 0
        )
        records = read_records(tmp_path / "remote" / "episodes.jsonl")
        assert len(records) == 1 and records[0].error is None and records[0].length == 40
        stats = records[0].extras["policy"]
        assert stats["requests"] == 10 and stats["rtt_ms"]["p50"] > 0 and stats["server_ms"]["p50"] > 0
        assert records[0].checkpoint_sha256 and len(records[0].checkpoint_sha256) == 64  # the served weights
        # policy on logs with the same served policy (its first action of each chunk vs the logged one)
        assert (
            main(
                [
                    "actions",
                    f"logs={tmp_path / 'demos'}",
                    "policy=remote",
                    f"port={port}",
                    "timeout_s=60",
                    OBS_MAP,
                    f"out={tmp_path / 'actions.json'}",
                ]
            )
            == 0
        )
        assert "round trips: 240" in capsys.readouterr().out
    log = err_log.read_text()
    assert proc.returncode == 0 and "disconnected after" in log and "Traceback" not in log, log[-2000:]

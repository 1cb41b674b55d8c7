"""`bench sweep`: tiny linear checkpoints on the toy suite (common seeds, steps from meta or file names, the best
set and the selection, leaderboard entries, resume, CI exit codes), its bad input, and the packaged BC
checkpoint's architecture against them."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from baselines.architectures import build as build_model
from baselines.checkpoint import save_checkpoint
from bench.api.sweep import SweepConfig, sweep, training_step
from bench.cli import main
from bench.core.config import build
from bench.core.errors import ConfigError
from bench.scoring.sweep import Point, select

REPO = Path(__file__).resolve().parents[1]
PACKAGED = REPO / "baselines" / "checkpoints" / "bc_lift_seen40.safetensors"
TOY = ["suite=tests.toy_suite:ToySuite", "episodes=8", "horizon=8", "workers=1"]


def _linear(path: Path, gain: float, hidden: list[int] | None = None, meta: dict | None = None) -> Path:
    """a = gain * (goal - pos): a small gain is slow (fails in 8 steps), a large one saturates (the expert)."""
    torch.manual_seed(0)
    model = build_model("mlp", 2, 1, {"hidden": hidden or []})
    if not hidden:
        with torch.no_grad():
            model[0].weight[:] = torch.tensor([[-gain, gain]])
            model[0].bias.zero_()
    spec = {
        "architecture": "mlp",
        "kwargs": {"hidden": hidden or []},
        "obs_names": [["pos", 1], ["goal", 1]],
        "action_names": ["push"],
        **({"meta": meta} if meta else {}),
    }
    return save_checkpoint(path, model, spec)


@pytest.fixture
def ckpts(tmp_path: Path) -> Path:
    folder = tmp_path / "train"
    for step, gain in ((1000, 0.05), (2000, 20.0), (3000, 25.0)):
        _linear(folder / f"policy_step{step}.safetensors", gain)
    return folder


def test_sweep_selects_among_equals_and_writes_entries(tmp_path, ckpts, capsys):
    out = tmp_path / "sw"
    assert main(["sweep", f"checkpoints={ckpts}", *TOY, f"out={out}"]) == 0
    doc = json.loads((out / "sweep.json").read_text())
    rows = {r["name"]: r for r in doc["checkpoints"]}
    assert [r["step"] for r in doc["checkpoints"]] == [1000, 2000, 3000] and doc["step_source"] == "file name"
    # the two saturating checkpoints play the same episodes identically: both in the best set, the later selected
    assert doc["best_set"] == ["policy_step2000", "policy_step3000"] and doc["selected"] == "policy_step3000"
    assert rows["policy_step1000"]["beaten_by"]["checkpoint"] in doc["best_set"]
    board = json.loads((out / "leaderboard.json").read_text())
    assert len(board["entries"]) == 3 and len({e["policy"]["checkpoint_sha256"] for e in board["entries"]}) == 3
    assert (out / "sweep.png").stat().st_size > 0
    printed = capsys.readouterr().out
    assert "policy_step3000" in printed and "cannot be told apart" in printed
    # common seeds: every checkpoint played the same episodes
    seeds = [
        sorted(json.loads(x)["seed"] for x in (Path(r["run_dir"]) / "episodes.jsonl").read_text().splitlines())
        for r in doc["checkpoints"]
    ]
    assert seeds[0] == seeds[1] == seeds[2]
    # CI: a bar the best cannot clear exits 1; rerunning resumes the recorded episodes
    assert main(["sweep", f"checkpoints={ckpts}", *TOY, f"out={out}", "min_success=0.99"]) == 1
    assert "FAIL" in capsys.readouterr().out


def test_steps_from_meta_then_file_name_then_order(tmp_path):
    a = _linear(tmp_path / "a_step_7.safetensors", 1.0, meta={"global_step": 42})
    assert training_step(a, json.loads(a.with_suffix(".json").read_text())) == (42.0, "meta.global_step")
    assert training_step(Path("ckpt-epoch3-iter500.pt"), None) == (500.0, "file name")
    assert training_step(Path("model_12.pt"), None) == (12.0, "file name")
    assert training_step(Path("final.pt"), None) == (None, "order")


def test_selection_keeps_the_true_best_at_alpha():
    rng = np.random.default_rng(0)
    misses, reps = 0, 200
    for _ in range(reps):  # five checkpoints, the best 0.7, two at 0.65, two far behind; 60 common episodes
        u = rng.random(60)
        rates = (0.4, 0.65, 0.7, 0.65, 0.3)
        pts = [Point(f"c{i}", i, {("x", "n", s): float(u[s] < r) for s in range(60)}) for i, r in enumerate(rates)]
        misses += "c2" not in select(pts, 0.05)["best_set"]
    assert misses / reps <= 0.05


def test_bad_input_one_line_exit_2_nothing_written(tmp_path, ckpts, capsys):
    out = tmp_path / "sw"
    assert main(["sweep", "checkpoints=[]", *TOY, f"out={out}"]) == 2
    assert "checkpoint list is empty" in capsys.readouterr().err
    other = tmp_path / "other"
    shutil.copytree(ckpts, other)
    _linear(other / "policy_step4000.safetensors", 1.0, hidden=[4])
    assert main(["sweep", f"checkpoints={other}", *TOY, f"out={out}"]) == 2
    err = capsys.readouterr().err
    assert "checkpoints of different architectures in one sweep" in err and len(err.strip().splitlines()) == 1
    mixed = f"checkpoints=[{ckpts / 'policy_step1000.safetensors'},{PACKAGED}]"
    assert main(["sweep", mixed, *TOY, f"out={out}"]) == 2
    assert "different architectures" in capsys.readouterr().err
    assert main(["sweep", f"checkpoints={ckpts}", *TOY, "run_id=x", f"out={out}"]) == 2
    assert "sets run_id=" in capsys.readouterr().err
    assert not out.exists()
    with pytest.raises(ConfigError, match="alpha"):
        build(SweepConfig, ["alpha=0.7"])


def test_packaged_checkpoint_sweeps_on_its_suite(tmp_path):
    """The committed BC checkpoint and a copy of it (another step) on one robot, 1 episode, a short horizon."""
    folder = tmp_path / "bc"
    folder.mkdir()
    for step in (10, 20):
        shutil.copy(PACKAGED, folder / f"bc_step{step}.safetensors")
        shutil.copy(PACKAGED.with_suffix(".json"), folder / f"bc_step{step}.json")
    res = sweep(
        SweepConfig(checkpoints=[str(folder)], out=str(tmp_path / "sw")),
        ["suite=held_out_robots", "robots=[Panda]", "episodes=1", "horizon=20", "workers=1"],
    )
    assert res.exit_code == 0 and [r["step"] for r in res.doc["checkpoints"]] == [10, 20]
    assert res.doc["best_set"] == ["bc_step10", "bc_step20"]  # the same weights: never told apart

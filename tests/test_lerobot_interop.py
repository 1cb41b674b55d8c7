"""lerobot itself loads what bench writes: every frame, every feature, every task string, the metadata, and
one episode on its own.

lerobot cannot live in bench's environment (it brings pandas, and its torch pin pulls a CUDA build), so it
runs in a side virtual environment built by `.ci/lerobot-venv.sh`; point BENCH_LEROBOT_PYTHON at its
python. `tests/lerobot_load.py` runs there and dumps what lerobot read; the comparison happens here.
"""
from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.logs import from_arrays, read_dataset, write_dataset
from bench.logs import lerobot
from bench.logs.dataset import is_image

REPO = Path(__file__).resolve().parents[1]
LOADER = REPO / "tests" / "lerobot_load.py"
SHARED = REPO.parent / "shared" / "data"


@pytest.fixture(scope="module")
def lerobot_python() -> str:
    py = os.environ.get("BENCH_LEROBOT_PYTHON", "")
    if not py:
        pytest.skip("BENCH_LEROBOT_PYTHON is not set: lerobot lives in a side venv (it brings pandas and a CUDA "
                    "torch); build it with `bash .ci/lerobot-venv.sh` and set BENCH_LEROBOT_PYTHON=.lerobot-venv/bin/python")
    if not Path(py).exists():
        pytest.fail(f"BENCH_LEROBOT_PYTHON={py} does not exist")
    return py


def _lerobot_read(py: str, root: Path, tmp: Path, episode: int | None = None) -> tuple[dict, dict]:
    out = tmp / f"lerobot_{root.name}"
    argv = [py, str(LOADER), str(root), str(out)] + ([] if episode is None else [str(episode)])
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    with np.load(str(out) + ".npz") as z:
        arrays = {k: z[k] for k in z.files}
    return arrays, json.loads(Path(str(out) + ".json").read_text())


def _assert_lerobot_reads_as_bench(py: str, root: Path, tmp: Path, episode: int | None = None) -> dict:
    """lerobot's view of `root` equals bench's reader's view, frame by frame; returns lerobot's metadata."""
    ds = read_dataset(root)
    arrays, doc = _lerobot_read(py, root, tmp, episode)
    n = ds.num_frames
    assert doc["lerobot_len"] == doc["total_frames"] == n
    assert doc["num_episodes"] == doc["total_episodes"] == len(ds.episodes)
    assert doc["fps"] == ds.fps and doc["robot_type"] == ds.robot_type
    assert doc["tasks_table"] == ds.tasks and doc["total_tasks"] == len(ds.tasks)  # strings, not integers
    assert doc["episode_lengths"] == [len(ep) for ep in ds.episodes]
    assert doc["frame_tasks"] == [ds.tasks[t] for ep in ds.episodes for t in ep.data["task_index"]]
    assert set(arrays) == set(ds.features), (sorted(arrays), sorted(ds.features))
    for name, feature in ds.features.items():
        got = arrays[name]
        if name == "episode_index":
            want = np.concatenate([np.full(len(ep), ep.index) for ep in ds.episodes])
        else:
            want = np.concatenate([ep.data[name] for ep in ds.episodes])
        if is_image(feature):  # lerobot: float32 C x H x W in [0, 1]; bench: uint8 H x W x C
            assert got.dtype == np.float32 and got.shape == (n, want.shape[3], want.shape[1], want.shape[2]), name
            np.testing.assert_array_equal(np.rint(got * 255).astype(np.uint8).transpose(0, 2, 3, 1), want, err_msg=name)
            continue
        want = want.reshape(n, *[s for s in feature["shape"] if s != 1] or [])  # lerobot squeezes (T, 1) to (T,)
        got = got.reshape(want.shape)
        if want.dtype == np.bool_:
            got = got.astype(np.bool_)
        assert got.dtype == want.dtype, (name, got.dtype, want.dtype)
        np.testing.assert_array_equal(got, want, err_msg=name)
    if episode is not None:
        ep = next(e for e in ds.episodes if e.index == episode)
        assert doc["episode_subset"]["episode_index"] == [episode]
        assert doc["episode_subset"]["index"] == [int(i) for i in ep.data["index"]]
    return doc


def _synthetic():
    rng = np.random.default_rng(7)
    eps = []
    for e in range(4):
        t = 5 + 4 * e
        eps.append({
            "observation.state": rng.standard_normal((t, 14)),
            "action": rng.standard_normal((t, 14)),
            "next.reward": rng.standard_normal(t),
            "next.done": np.arange(t) == t - 1,
            "observation.images.cam": rng.integers(0, 256, (t, 12, 10, 3), dtype=np.uint8),
        })
    return from_arrays(eps, fps=30, task=["fold towel", "open drawer", "fold towel", "stack cups"],
                       names={"action": [f"j{i}" for i in range(14)]}, robot_type="aloha",
                       meta=[{"success": e % 2 == 0} for e in range(4)])


def test_lerobot_loads_written_dataset(lerobot_python, tmp_path):
    root = write_dataset(tmp_path / "synthetic", _synthetic())
    _assert_lerobot_reads_as_bench(lerobot_python, root, tmp_path, episode=2)


def test_lerobot_loads_dataset_split_over_files(lerobot_python, tmp_path, monkeypatch):
    monkeypatch.setattr(lerobot, "DATA_FILES_SIZE_IN_MB", 0)  # one data file per episode
    root = write_dataset(tmp_path / "split", _synthetic())
    assert len(list((root / "data" / "chunk-000").iterdir())) == 4
    _assert_lerobot_reads_as_bench(lerobot_python, root, tmp_path, episode=3)


def test_lerobot_loads_csv_import(lerobot_python, tmp_path):
    src = tmp_path / "log.csv"
    src.write_text("time,q1,q2,u\n" + "".join(f"{i * 0.01:.2f},{i},{i * i},{-i}\n" for i in range(25)))
    root = tmp_path / "csv"
    assert main(["logs", "import", str(src), f"out={root}", "time=time", "state=[q1,q2]", "action=u", "task=wave"]) == 0
    _assert_lerobot_reads_as_bench(lerobot_python, root, tmp_path)


def test_lerobot_loads_rlds_import(lerobot_python, tmp_path):
    src = SHARED / "formats" / "rlds_toy" / "toy_rlds"
    if not src.is_dir():
        pytest.skip(f"RLDS reference not found at {src} (the shared folder lives outside the repo)")
    root = tmp_path / "rlds"
    assert main(["logs", "import", str(src), f"out={root}", "fps=5"]) == 0
    _assert_lerobot_reads_as_bench(lerobot_python, root, tmp_path, episode=1)


def test_lerobot_loads_bench_run_recording(lerobot_python, tmp_path):
    """`bench run record=` (robosuite rollouts, nominal and perturbed, success per episode)."""
    root = tmp_path / "rec"
    assert main(["run", "policy=scripted", "robots=[Panda]", "episodes=1", "horizon=15", "workers=1", "run_id=r",
                 f"out={tmp_path / 'runs'}", f"record={root}", "perturb.link_mass=[3]"]) == 0
    doc = _assert_lerobot_reads_as_bench(lerobot_python, root, tmp_path, episode=1)
    assert doc["total_episodes"] == 2

"""lerobot itself loads what bench writes: every frame, every feature, every task string, the metadata, and
one episode on its own; camera streams as PNG images and as video (MP4, H.264 or AV1). And bench reads what
lerobot itself wrote with video.

lerobot cannot live in bench's environment (it brings pandas, and its torch pin pulls a CUDA build), so it
runs in a side virtual environment built by `.ci/lerobot-venv.sh`; point BENCH_LEROBOT_PYTHON at its
python. `tests/lerobot_load.py` runs there and dumps what lerobot read, `tests/lerobot_write.py` writes a
dataset with lerobot's own recording API; the comparisons happen here.

Video tolerances, stated: lerobot (torchcodec on the system's FFmpeg) and bench (PyAV's FFmpeg) decode the
same file to frames that differ by at most 1 level of 255 (measured: identical); decoded frames differ from
the frames written by the codec's loss, held to `video_frames.MAE` per frame and to the right order.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from video_frames import assert_close_frames, frames

from bench.cli import main
from bench.logs import from_arrays, lerobot, read_dataset, read_episode, write_dataset
from bench.logs.dataset import is_image
from bench.logs.lerobot import write as lerobot_write
from tests.fixtures import recorded

REPO = Path(__file__).resolve().parents[1]
LOADER = REPO / "tests" / "lerobot_load.py"
WRITER = REPO / "tests" / "lerobot_write.py"
SHARED = REPO.parent / "shared" / "data"


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
            pixels = np.rint(got * 255).astype(np.uint8).transpose(0, 2, 3, 1)
            if feature["dtype"] == "video":  # two FFmpeg builds decode the same stream: colour conversion may round
                diff = np.abs(pixels.astype(np.int16) - want)
                assert diff.max() <= 1, (name, int(diff.max()))
            else:
                np.testing.assert_array_equal(pixels, want, err_msg=name)
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
        eps.append(
            {
                "observation.state": rng.standard_normal((t, 14)),
                "action": rng.standard_normal((t, 14)),
                "next.reward": rng.standard_normal(t),
                "next.done": np.arange(t) == t - 1,
                "observation.images.cam": rng.integers(0, 256, (t, 12, 10, 3), dtype=np.uint8),
            }
        )
    return from_arrays(
        eps,
        fps=30,
        task=["fold towel", "open drawer", "fold towel", "stack cups"],
        names={"action": [f"j{i}" for i in range(14)]},
        robot_type="aloha",
        meta=[{"success": e % 2 == 0} for e in range(4)],
    )


def _video_episodes(codec_sizes: dict[str, tuple[int, int]]) -> tuple[list[dict], dict[str, np.ndarray]]:
    """Four episodes with smooth moving camera scenes (all frames distinct), state, action and reward."""
    rng = np.random.default_rng(3)
    eps, start = [], 0
    written: dict[str, list] = {k: [] for k in codec_sizes}
    for e in range(4):
        t = 6 + 3 * e
        ep = {
            "observation.state": rng.standard_normal((t, 4)),
            "action": rng.standard_normal((t, 2)),
            "next.reward": rng.standard_normal(t),
        }
        for c, (key, (h, w)) in enumerate(codec_sizes.items()):
            ep[key] = frames(t, h, w, camera=c, start=start)
            written[key].append(ep[key])
        eps.append(ep)
        start += t
    return eps, {k: np.concatenate(v) for k, v in written.items()}


@pytest.mark.parametrize("codec", ["h264", "av1"])
def test_lerobot_loads_written_video_dataset(lerobot_python, tmp_path, codec):
    """Video features beside a PNG camera; with H.264 one camera has an odd size (stored as yuv444p)."""
    cams = {"observation.images.front": (96, 128), "observation.images.side": (45, 61) if codec == "h264" else (46, 62)}
    eps, written = _video_episodes(cams)
    for ep in eps:
        ep["observation.images.png"] = ep["observation.images.side"][:, :12, :10]
    ds = from_arrays(eps, fps=15, task=["pick", "place", "pick", "place"], robot_type="toy", video=list(cams))
    root = write_dataset(tmp_path / codec, ds, video_codec=codec)
    doc = _assert_lerobot_reads_as_bench(lerobot_python, root, tmp_path, episode=2)
    for key in cams:
        assert doc["features"][key]["dtype"] == "video"
        got = np.concatenate([ep.data[key] for ep in read_dataset(root).episodes])
        assert_close_frames(got, written[key], codec, key)


def test_lerobot_loads_video_split_over_files(lerobot_python, tmp_path, monkeypatch):
    monkeypatch.setattr(lerobot_write, "VIDEO_FILES_SIZE_IN_MB", 0)  # one mp4 file per episode
    cams = {"observation.images.front": (64, 64)}
    eps, written = _video_episodes(cams)
    root = write_dataset(tmp_path / "split", from_arrays(eps, fps=10, video=True))
    assert len(list((root / "videos" / "observation.images.front" / "chunk-000").iterdir())) == 4
    _assert_lerobot_reads_as_bench(lerobot_python, root, tmp_path, episode=3)
    got = np.concatenate([ep.data["observation.images.front"] for ep in read_dataset(root).episodes])
    assert_close_frames(got, written["observation.images.front"], "h264")


@pytest.mark.parametrize("vcodec", [None, "h264"], ids=["lerobot-default-av1", "h264"])
def test_bench_reads_lerobot_video_dataset(lerobot_python, tmp_path, vcodec):
    """A dataset lerobot itself recorded (add_frame / save_episode, its encoder): bench reads every frame."""
    root, given = tmp_path / "by_lerobot", tmp_path / "given.npz"
    proc = subprocess.run(
        [lerobot_python, str(WRITER), str(root), str(given)] + ([vcodec] if vcodec else []),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    codec = vcodec or "av1"
    with np.load(given) as z:
        want = {k: z[k] for k in z.files}
    ds = read_dataset(root)
    assert [len(ep) for ep in ds.episodes] == [7, 12, 9] and ds.fps == 10
    for key in ("observation.state", "action"):
        np.testing.assert_array_equal(np.concatenate([ep.data[key] for ep in ds.episodes]), want[key], err_msg=key)
    for key in ("observation.images.front", "observation.images.wrist"):
        assert ds.features[key]["dtype"] == "video"
        got = np.concatenate([ep.data[key] for ep in ds.episodes])
        assert_close_frames(got, want[key], codec, key)
        one = read_episode(root, 1)  # a seek into the middle of the file
        np.testing.assert_array_equal(one.data[key], ds.episodes[1].data[key])
    _assert_lerobot_reads_as_bench(lerobot_python, root, tmp_path, episode=1)  # lerobot's decoding = bench's
    summary = lerobot.info(root)["features"]["observation.images.front"]
    assert summary["video"] == {"codec": codec, "pix_fmt": "yuv420p", "fps": 10, "files": 1}


def test_lerobot_loads_written_dataset(lerobot_python, tmp_path):
    root = write_dataset(tmp_path / "synthetic", _synthetic())
    _assert_lerobot_reads_as_bench(lerobot_python, root, tmp_path, episode=2)


def test_lerobot_loads_dataset_split_over_files(lerobot_python, tmp_path, monkeypatch):
    monkeypatch.setattr(lerobot_write, "DATA_FILES_SIZE_IN_MB", 0)  # one data file per episode
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
    keys = ["policy=scripted", "robots=[Panda]", "episodes=1", "horizon=15", "workers=1"]
    root = recorded(tmp_path, *keys, "perturb.link_mass=[3]")
    doc = _assert_lerobot_reads_as_bench(lerobot_python, root, tmp_path, episode=1)
    assert doc["total_episodes"] == 2


def test_lerobot_loads_bench_run_recording_with_cameras(lerobot_python, tmp_path):
    """`bench run obs=state+rgb record=`: both cameras become video features lerobot decodes like bench."""
    keys = ["robots=[Panda]", "episodes=2", "horizon=12", "workers=1", "obs=state+rgb", "image_size=48"]
    root = recorded(tmp_path, *keys, into="rec_cam")
    doc = _assert_lerobot_reads_as_bench(lerobot_python, root, tmp_path, episode=1)
    assert {k for k, v in doc["features"].items() if v["dtype"] == "video"} == {
        "observation.images.agentview",
        "observation.images.robot0_eye_in_hand",
    }

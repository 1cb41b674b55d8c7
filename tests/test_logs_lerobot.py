"""LeRobot v3.0 read/write: the shared references read exactly, round trips are identical, and
what we write has the schema and metadata of what lerobot writes."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from video_frames import assert_close_frames, frames

from bench.core.errors import BenchError, DataError
from bench.logs import (
    Episode,
    LogDataset,
    from_arrays,
    info,
    lerobot,
    read_dataset,
    read_episode,
    write_dataset,
)
from bench.logs.lerobot import write as lerobot_write

REPO = Path(__file__).resolve().parents[1]
FORMATS = Path(__file__).resolve().parents[2] / "shared" / "data" / "formats"
DATA = "data/chunk-000/file-000.parquet"
EPISODES = "meta/episodes/chunk-000/file-000.parquet"


@pytest.fixture
def formats() -> Path:
    if not (FORMATS / "lerobot_v3_state").is_dir():
        pytest.skip(f"reference datasets not found at {FORMATS} (the shared folder lives outside the repo)")
    return FORMATS


def _parquet_rows(root: Path) -> list[dict]:
    return pq.read_table(root / DATA).to_pylist()


def _sample(n_episodes: int = 3, images: bool = True) -> LogDataset:
    rng = np.random.default_rng(1)
    eps = []
    for e in range(n_episodes):
        t = 4 + 3 * e
        ep = {
            "observation.state": rng.standard_normal((t, 3)),
            "action": rng.standard_normal((t, 2)),
            "next.reward": rng.standard_normal(t),  # 1-D -> (T, 1) scalar feature
            "next.done": np.arange(t) == t - 1,  # bool
        }
        if images:
            ep["observation.images.cam"] = rng.integers(0, 256, (t, 6, 5, 3), dtype=np.uint8)
        eps.append(ep)
    return from_arrays(
        eps,
        fps=20,
        task=["reach", "push", "reach"][:n_episodes],
        names={"action": ["x", "y"]},
        robot_type="toy",
        meta=[{"success": e % 2 == 0, "seed": e} for e in range(n_episodes)],
    )


def _assert_same(a: LogDataset, b: LogDataset) -> None:
    assert a.fps == b.fps and a.tasks == b.tasks and a.robot_type == b.robot_type
    assert a.features == b.features
    assert len(a.episodes) == len(b.episodes)
    for x, y in zip(a.episodes, b.episodes):
        assert x.index == y.index and x.tasks == y.tasks and x.meta == y.meta
        assert list(x.data) == list(y.data)
        for k in x.data:
            assert x.data[k].dtype == y.data[k].dtype, k
            assert x.data[k].shape == y.data[k].shape, k
            np.testing.assert_array_equal(x.data[k], y.data[k], err_msg=k)


# ----------------------------------------------------------------------------- references


def test_state_reference_reads_exactly(formats):
    root = formats / "lerobot_v3_state"
    ds = read_dataset(root)
    assert (ds.fps, ds.robot_type, ds.tasks) == (10.0, "so100", ["pick cube", "place cube"])
    assert [len(ep) for ep in ds.episodes] == [5, 7]
    assert [ep.tasks for ep in ds.episodes] == [["pick cube"], ["place cube"]]
    assert ds.features["observation.state"]["names"] == [f"j{i}" for i in range(6)]
    # README: default_rng(0) standard normals, state then action, frame by frame.
    rng = np.random.default_rng(0)
    for ep in ds.episodes:
        for f in range(len(ep)):
            np.testing.assert_array_equal(ep.data["observation.state"][f], rng.standard_normal(6).astype(np.float32))
            np.testing.assert_array_equal(ep.data["action"][f], rng.standard_normal(6).astype(np.float32))
    rows = _parquet_rows(root)
    flat = [ep for ep in ds.episodes for _ in range(len(ep))]
    frames = [f for ep in ds.episodes for f in range(len(ep))]
    for row, ep, f in zip(rows, flat, frames):
        assert row["episode_index"] == ep.index
        np.testing.assert_array_equal(ep.data["observation.state"][f], np.float32(row["observation.state"]))
        np.testing.assert_array_equal(ep.data["action"][f], np.float32(row["action"]))
        for key in ("frame_index", "index", "task_index"):
            assert ep.data[key][f] == row[key]
        assert ep.data["timestamp"][f] == np.float32(row["timestamp"])
    assert ds.episodes[1].data["timestamp"].dtype == np.float32
    assert ds.episodes[1].data["index"].tolist() == list(range(5, 12))


def test_image_reference_reads_exactly(formats):
    from PIL import Image

    root = formats / "lerobot_v3_image"
    ds = read_dataset(root)
    assert ds.features["observation.images.cam"]["dtype"] == "image"
    rows = _parquet_rows(root)
    frames = [(ep, f) for ep in ds.episodes for f in range(len(ep))]
    assert len(rows) == len(frames) == 12
    for row, (ep, f) in zip(rows, frames):
        img = ep.data["observation.images.cam"][f]
        assert img.dtype == np.uint8 and img.shape == (8, 8, 3)
        np.testing.assert_array_equal(img, np.asarray(Image.open(io.BytesIO(row["observation.images.cam"]["bytes"]))))
        np.testing.assert_array_equal(ep.data["observation.state"][f], np.float32(row["observation.state"]))
        np.testing.assert_array_equal(ep.data["action"][f], np.float32(row["action"]))


@pytest.mark.parametrize("name", ["lerobot_v3_state", "lerobot_v3_image"])
def test_read_episode_matches_full_read(formats, name):
    ds = read_dataset(formats / name)
    for ep in ds.episodes:
        one = read_episode(formats / name, ep.index)
        assert one.index == ep.index and one.tasks == ep.tasks
        for k in ep.data:
            np.testing.assert_array_equal(one.data[k], ep.data[k])
    with pytest.raises(DataError, match="'episode_index' 2 is not in 0..1"):
        read_episode(formats / name, 2)


def test_info_reads_metadata_only(formats):
    summary = info(formats / "lerobot_v3_image")
    assert summary["episodes"] == 2 and summary["frames"] == 12 and summary["fps"] == 10
    assert summary["features"]["observation.images.cam"]["shape"] == [8, 8, 3]
    assert summary["tasks"] == ["pick cube", "place cube"]
    assert summary["lengths"] == {"min": 5, "max": 7, "mean": 6.0}


# ----------------------------------------------------------------------------- round trips


def test_round_trip_identical(tmp_path):
    ds = _sample()
    out = write_dataset(tmp_path / "ds", ds)
    back = read_dataset(out)
    _assert_same(ds, back)
    assert back.features["next.reward"]["shape"] == [1] and back.episodes[0].data["next.reward"].shape == (4, 1)
    assert back.episodes[2].data["next.done"].dtype == np.bool_
    for ep in ds.episodes:
        one = read_episode(out, ep.index)
        for k in ep.data:
            np.testing.assert_array_equal(one.data[k], ep.data[k])
    # scalar features are plain columns, as lerobot stores shape-[1] features
    schema = pq.read_schema(out / DATA)
    assert str(schema.field("next.reward").type) == "float" and str(schema.field("next.done").type) == "bool"


def test_reference_round_trip(formats, tmp_path):
    for name in ("lerobot_v3_state", "lerobot_v3_image"):
        ds = read_dataset(formats / name)
        _assert_same(ds, read_dataset(write_dataset(tmp_path / name, ds)))


def test_one_row_group_per_episode_and_episode_table(tmp_path):
    out = write_dataset(tmp_path / "ds", _sample(images=False))
    md = pq.read_metadata(out / DATA)
    assert [md.row_group(i).num_rows for i in range(md.num_row_groups)] == [4, 7, 10]
    eps = pq.read_table(out / EPISODES).to_pylist()
    assert [e["episode_index"] for e in eps] == [0, 1, 2]
    assert [(e["dataset_from_index"], e["dataset_to_index"], e["length"]) for e in eps] == [
        (0, 4, 4),
        (4, 11, 7),
        (11, 21, 10),
    ]
    assert [e["tasks"] for e in eps] == [["reach"], ["push"], ["reach"]]
    assert json.loads(eps[0]["bench/meta"]) == {"success": True, "seed": 0}
    assert eps[1]["stats/action/count"] == [7]


def test_read_episode_reads_only_its_row_group(tmp_path, monkeypatch):
    out = write_dataset(tmp_path / "ds", _sample(images=False))
    info(out)  # metadata (tasks, episode table) is read whole once and cached
    calls = []
    original = pq.ParquetFile.read_row_groups

    def spy(self, row_groups, *args, **kwargs):
        calls.append(list(row_groups))
        return original(self, row_groups, *args, **kwargs)

    monkeypatch.setattr(pq.ParquetFile, "read_row_groups", spy)
    monkeypatch.setattr(pq.ParquetFile, "read", lambda *a, **k: pytest.fail("read_episode read a whole file"))
    ep = read_episode(out, 1)
    assert calls == [[1]] and len(ep) == 7


def test_many_data_files(tmp_path, monkeypatch):
    monkeypatch.setattr(lerobot_write, "DATA_FILES_SIZE_IN_MB", 0)  # a new file for every episode
    ds = _sample()
    out = write_dataset(tmp_path / "ds", ds)
    assert sorted(p.name for p in (out / "data" / "chunk-000").iterdir()) == [f"file-{i:03d}.parquet" for i in range(3)]
    _assert_same(ds, read_dataset(out))
    np.testing.assert_array_equal(read_episode(out, 2).data["action"], ds.episodes[2].data["action"])


# ----------------------------------------------------------------------------- compatibility with lerobot


def test_written_schema_matches_reference(formats, tmp_path):
    ref = formats / "lerobot_v3_image"
    # Built from scratch with the reference's shapes (not read from it): same columns, types, metadata.
    rng = np.random.default_rng(0)
    eps = [
        {
            "observation.state": rng.standard_normal((t, 6)),
            "action": rng.standard_normal((t, 6)),
            "observation.images.cam": rng.integers(0, 256, (t, 8, 8, 3), dtype=np.uint8),
        }
        for t in (5, 7)
    ]
    names = {"observation.state": [f"j{i}" for i in range(6)], "action": [f"j{i}" for i in range(6)]}
    ds = from_arrays(eps, fps=10, task=["pick cube", "place cube"], names=names, robot_type="so100")
    out = write_dataset(tmp_path / "ds", ds)
    for rel in (DATA, EPISODES, "meta/tasks.parquet"):
        want, got = pq.read_schema(ref / rel), pq.read_schema(out / rel)
        assert got.names == want.names, rel
        assert got.remove_metadata().equals(want.remove_metadata()), rel
    hf = lambda p: json.loads(pq.read_schema(p / DATA).metadata[b"huggingface"])["info"]  # noqa: E731
    assert hf(out) == hf(ref)
    pandas_meta = lambda p: json.loads(pq.read_schema(p / "meta/tasks.parquet").metadata[b"pandas"])  # noqa: E731
    want, got = pandas_meta(ref), pandas_meta(out)
    for key in ("index_columns", "column_indexes", "columns"):
        assert got[key] == want[key], key
    assert (
        pq.read_table(out / "meta/tasks.parquet").to_pylist() == pq.read_table(ref / "meta/tasks.parquet").to_pylist()
    )
    info_ref, info_out = (
        json.loads((ref / "meta/info.json").read_text()),
        json.loads((out / "meta/info.json").read_text()),
    )
    assert list(info_out) == list(info_ref)
    assert info_out == info_ref  # same totals, paths, splits and features
    stats_ref, stats_out = (
        json.loads((ref / "meta/stats.json").read_text()),
        json.loads((out / "meta/stats.json").read_text()),
    )
    assert set(stats_out) == set(stats_ref)
    for name in stats_ref:
        assert set(stats_out[name]) == set(stats_ref[name])
        for stat in stats_ref[name]:
            assert np.shape(stats_out[name][stat]) == np.shape(stats_ref[name][stat]), (name, stat)
    ep_ref, ep_out = pq.read_table(ref / EPISODES).to_pylist(), pq.read_table(out / EPISODES).to_pylist()
    for a, b in zip(ep_ref, ep_out):
        for key in lerobot.EPISODE_COLUMNS:
            assert a[key] == b[key], key


def test_reference_stats_reproduced(formats, tmp_path):
    ref = formats / "lerobot_v3_state"
    out = write_dataset(tmp_path / "ds", read_dataset(ref))
    stats_ref, stats_out = (
        json.loads((ref / "meta/stats.json").read_text()),
        json.loads((out / "meta/stats.json").read_text()),
    )
    for name in stats_ref:
        for stat in ("min", "max", "mean", "std", "count"):  # lerobot's quantiles are histogram estimates
            np.testing.assert_allclose(
                stats_out[name][stat], stats_ref[name][stat], rtol=1e-6, atol=1e-7, err_msg=f"{name}/{stat}"
            )


def test_no_pandas_needed():
    code = (
        "import sys, tempfile, numpy as np\n"
        "class NoPandas:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] == 'pandas':\n"
        "            raise ImportError('pandas is blocked in this test')\n"
        "sys.meta_path.insert(0, NoPandas())\n"
        "from bench.logs import from_arrays, write_dataset, read_dataset, read_episode\n"
        "import bench.scoring.agreement\n"
        "d = tempfile.mkdtemp()\n"
        "write_dataset(d + '/x', from_arrays([{'action': np.zeros((3, 2))}], fps=10))\n"
        "read_dataset(d + '/x'); read_episode(d + '/x', 0)\n"
        "assert 'pandas' not in sys.modules\n"
    )
    subprocess.run(
        [sys.executable, "-c", code], check=True, cwd=REPO, env={"PYTHONPATH": str(REPO), "PATH": ""}, timeout=60
    )


# ----------------------------------------------------------------------------- atomic writes


def test_refuses_to_overwrite(tmp_path):
    target = tmp_path / "ds"
    write_dataset(target, _sample(images=False))
    before = sorted(p.relative_to(target) for p in target.rglob("*"))
    other = from_arrays([{"action": np.ones((2, 1))}], fps=5)
    with pytest.raises(BenchError, match="exists and is not empty; pass overwrite=true"):
        write_dataset(target, other)
    assert sorted(p.relative_to(target) for p in target.rglob("*")) == before
    assert len(read_dataset(target).episodes) == 3
    write_dataset(target, other, overwrite=True)
    assert len(read_dataset(target).episodes) == 1
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]  # no temporary or backup folders left


def test_empty_folder_is_fine(tmp_path):
    (tmp_path / "ds").mkdir()
    write_dataset(tmp_path / "ds", _sample(images=False))
    assert info(tmp_path / "ds")["episodes"] == 3


def test_failed_write_keeps_old_dataset(tmp_path, monkeypatch):
    target = tmp_path / "ds"
    write_dataset(target, _sample(images=False))

    def boom(tmp, ds, *codec):
        (tmp / "meta" / "info.json").write_text("{}")
        raise OSError("disk full")

    monkeypatch.setattr(lerobot_write, "_write_into", boom)
    with pytest.raises(OSError, match="disk full"):
        write_dataset(target, _sample(images=False), overwrite=True)
    assert len(read_dataset(target).episodes) == 3
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]


def test_episode_len_and_defaults():
    ds = from_arrays([{"observation.state": np.zeros((5, 2))}], fps=4)
    ep = ds.episodes[0]
    assert isinstance(ep, Episode) and len(ep) == 5 and ds.num_frames == 5
    assert list(ds.features)[-5:] == ["timestamp", "frame_index", "episode_index", "index", "task_index"]
    np.testing.assert_array_equal(ep.data["timestamp"], np.float32([0, 0.25, 0.5, 0.75, 1.0]))
    assert ep.data["observation.state"].dtype == np.float32


@pytest.mark.parametrize("row_group_size", [3, 1000], ids=["episodes-span-groups", "one-group"])
def test_read_episode_any_row_groups(tmp_path, row_group_size):
    """Files written by other tools need not have one row group per episode."""
    ds = _sample(images=False)
    out = write_dataset(tmp_path / "ds", ds)
    table = pq.read_table(out / DATA)
    pq.write_table(table, out / DATA, row_group_size=row_group_size)
    for ep in ds.episodes:
        one = read_episode(out, ep.index)
        for k in ep.data:
            np.testing.assert_array_equal(one.data[k], ep.data[k])


# ----------------------------------------------------------------------------- video features


def _video_dataset(n_episodes: int = 3, size: tuple[int, int] = (64, 96)) -> tuple[LogDataset, np.ndarray]:
    rng = np.random.default_rng(5)
    eps, start = [], 0
    for e in range(n_episodes):
        t = 5 + 2 * e
        eps.append(
            {
                "observation.state": rng.standard_normal((t, 3)),
                "action": rng.standard_normal((t, 2)),
                "observation.images.front": frames(t, *size, start=start),
                "observation.images.png": rng.integers(0, 256, (t, 6, 5, 3), dtype=np.uint8),
            }
        )
        start += t
    ds = from_arrays(
        eps, fps=20, task="reach", video=["observation.images.front"], meta=[{"seed": e} for e in range(n_episodes)]
    )
    return ds, np.concatenate([ep["observation.images.front"] for ep in eps])


def test_video_roundtrip_layout_and_metadata(tmp_path):
    """Video frames live in one mp4 per feature, indexed by the episodes table as lerobot lays it out."""
    ds, written = _video_dataset()
    out = write_dataset(tmp_path / "ds", ds)
    assert (out / "videos/observation.images.front/chunk-000/file-000.mp4").is_file()
    doc = json.loads((out / "meta/info.json").read_text())
    assert doc["video_path"] == lerobot.VIDEO_PATH
    feat = doc["features"]["observation.images.front"]
    assert (
        feat["dtype"] == "video" and feat["shape"] == [64, 96, 3] and feat["names"] == ["height", "width", "channels"]
    )
    assert feat["info"] == {
        "video.height": 64,
        "video.width": 96,
        "video.codec": "h264",
        "video.pix_fmt": "yuv420p",
        "video.is_depth_map": False,
        "video.fps": 20,
        "video.channels": 3,
        "has_audio": False,
    }
    assert "observation.images.front" not in pq.read_schema(out / DATA).names  # no parquet column
    eps = pq.read_table(out / EPISODES)
    assert eps.column("videos/observation.images.front/from_timestamp").to_pylist() == [0.0, 0.25, 0.6]
    assert eps.column("videos/observation.images.front/to_timestamp").to_pylist() == [0.25, 0.6, 1.05]
    stats = json.loads((out / "meta/stats.json").read_text())["observation.images.front"]
    assert np.asarray(stats["mean"]).shape == (3, 1, 1) and stats["count"] == [21]
    back = read_dataset(out)
    assert back.features == ds.features
    for a, b in zip(ds.episodes, back.episodes):
        assert a.meta == b.meta
        for k in a.data:
            if k != "observation.images.front":
                np.testing.assert_array_equal(a.data[k], b.data[k], err_msg=k)
    got = np.concatenate([ep.data["observation.images.front"] for ep in back.episodes])
    assert_close_frames(got, written, "h264")
    one = read_episode(out, 2)  # seeks to the episode's first frame in the shared file
    np.testing.assert_array_equal(
        one.data["observation.images.front"], back.episodes[2].data["observation.images.front"]
    )
    assert "observation.images.front" not in read_dataset(out, videos=False).features
    assert "observation.images.front" not in read_episode(out, 1, videos=False).data
    assert info(out)["features"]["observation.images.front"]["video"] == {
        "codec": "h264",
        "pix_fmt": "yuv420p",
        "fps": 20,
        "files": 1,
    }


def test_video_files_roll_over_and_av1(tmp_path, monkeypatch):
    monkeypatch.setattr(lerobot_write, "VIDEO_FILES_SIZE_IN_MB", 0)  # a new file after every episode
    ds, written = _video_dataset()
    out = write_dataset(tmp_path / "ds", ds, video_codec="av1")
    files = sorted((out / "videos/observation.images.front/chunk-000").iterdir())
    assert [f.name for f in files] == ["file-000.mp4", "file-001.mp4", "file-002.mp4"]
    eps = pq.read_table(out / EPISODES)
    assert eps.column("videos/observation.images.front/file_index").to_pylist() == [0, 1, 2]
    assert eps.column("videos/observation.images.front/from_timestamp").to_pylist() == [0.0, 0.0, 0.0]
    got = np.concatenate([ep.data["observation.images.front"] for ep in read_dataset(out).episodes])
    assert_close_frames(got, written, "av1")
    assert info(out)["features"]["observation.images.front"]["video"]["files"] == 3


def test_video_bad_input_is_refused_before_writing(tmp_path):
    ds, _ = _video_dataset(2)
    target = tmp_path / "out"
    with pytest.raises(DataError, match="video_codec is 'vp9'; valid: h264, av1"):
        write_dataset(target, ds, video_codec="vp9")
    ds.fps = 12.5
    with pytest.raises(DataError, match="field 'fps' is 12.5; video features need a whole number"):
        write_dataset(target, ds)
    ds.fps = 20.0
    ds.episodes[1].data["timestamp"] = ds.episodes[1].data["timestamp"] * 1.5
    with pytest.raises(
        DataError, match=r"column 'timestamp' is 0.075000 at frame 1 of episode 1 .* frame/fps = 0.050000"
    ):
        write_dataset(target, ds)
    odd = from_arrays([{"cam": frames(3, 45, 61)}], fps=10, video=True)
    with pytest.raises(DataError, match="feature 'cam': video frames are 45x61: AV1"):
        write_dataset(target, odd, video_codec="av1")
    with pytest.raises(DataError, match="feature 'depth' has 1 channels; a video feature needs 3"):
        from_arrays([{"depth": np.zeros((3, 8, 8, 1), np.uint8)}], fps=10, video=["depth"])
    with pytest.raises(DataError, match="video given for unknown feature 'cam2'"):
        from_arrays([{"cam": frames(3, 8, 8)}], fps=10, video=["cam2"])
    with pytest.raises(DataError, match="feature 'x' is float32 \\[2\\], not \\(T, H, W, 3\\) uint8"):
        from_arrays([{"x": np.zeros((3, 2))}], fps=10, video=["x"])
    assert not target.exists() and list(tmp_path.iterdir()) == []


def test_video_damage_is_a_one_line_error(tmp_path):
    ds, _ = _video_dataset(2)
    out = write_dataset(tmp_path / "ds", ds)
    mp4 = out / "videos/observation.images.front/chunk-000/file-000.mp4"
    data = mp4.read_bytes()
    mp4.write_bytes(data[: len(data) // 3])  # truncated: the index at the end is gone
    with pytest.raises(
        DataError, match="video feature 'observation.images.front' of episode\\(s\\) 0, 1: .*file-000.mp4"
    ):
        read_dataset(out)
    mp4.unlink()
    with pytest.raises(DataError, match=r"file-000.mp4: file is missing \(video of feature 'observation.images.front'"):
        read_episode(out, 1)
    assert len(read_dataset(out, videos=False).episodes) == 2  # the numeric features are still readable
    table = pq.read_table(out / EPISODES)
    pq.write_table(table.drop_columns(["videos/observation.images.front/from_timestamp"]), out / EPISODES)
    with pytest.raises(DataError, match="column 'videos/observation.images.front/from_timestamp' is missing"):
        read_dataset(out)
    doc = json.loads((out / "meta/info.json").read_text())
    doc["video_path"] = None
    (out / "meta/info.json").write_text(json.dumps(doc))
    with pytest.raises(DataError, match="field 'video_path' is None but features observation.images.front are videos"):
        info(out)


def test_logs_info_shows_video_features(tmp_path, capsys):
    from bench.cli import main

    ds, _ = _video_dataset(2)
    out = write_dataset(tmp_path / "ds", ds, video_codec="av1")
    assert main(["logs", "info", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    row = next(line for line in lines if "observation.images.front" in line)
    assert row.split() == [
        "observation.images.front",
        "video",
        "[64,",
        "96,",
        "3]",
        "av1",
        "yuv420p,",
        "20",
        "fps,",
        "1",
        "mp4",
        "file",
    ]
    assert any(line.split()[:2] == ["observation.images.png", "image"] for line in lines)

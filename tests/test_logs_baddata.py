"""Bad data gives one-line DataErrors naming the file and the field (and exit 2 at the CLI).

Each case starts from a good dataset written in tmp_path and breaks one thing.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from bench.cli import main as bench_main
from bench.core.errors import DataError
from bench.logs import from_arrays, read_dataset, read_episode, write_dataset

DATA = "data/chunk-000/file-000.parquet"
EPISODES = "meta/episodes/chunk-000/file-000.parquet"
LEN = 20  # frames per episode; 4 episodes


@pytest.fixture
def good(tmp_path: Path) -> Path:
    rng = np.random.default_rng(0)
    eps = [
        {"observation.state": rng.standard_normal((LEN, 3)), "action": rng.standard_normal((LEN, 2))} for _ in range(4)
    ]
    return write_dataset(tmp_path / "good", from_arrays(eps, fps=10))


def _rewrite(path: Path, edit: Callable[[pa.Table], pa.Table]) -> None:
    table = pq.read_table(path)
    pq.write_table(edit(table), path)


def _set_column(table: pa.Table, name: str, values) -> pa.Table:
    i = table.column_names.index(name)
    return table.set_column(i, table.schema.field(i), pa.array(values, table.schema.field(i).type))


def _raises(root: Path, pattern: str, episode: int | None = None) -> str:
    with pytest.raises(DataError, match=pattern) as err:
        read_dataset(root)
    message = str(err.value)
    assert "\n" not in message
    if episode is not None:
        with pytest.raises(DataError, match=pattern):
            read_episode(root, episode)
    return message


@pytest.mark.parametrize("rel", ["meta/info.json", "meta/tasks.parquet", EPISODES, DATA])
def test_missing_file(good, rel):
    (good / rel).unlink()
    message = _raises(good, "file is missing")
    assert message.startswith(str(good / rel))


def test_wrong_shape_declared(good):
    info = json.loads((good / "meta/info.json").read_text())
    info["features"]["observation.state"]["shape"] = [4]
    (good / "meta/info.json").write_text(json.dumps(info))
    _raises(
        good, rf"{DATA}: column 'observation.state' has 3 values per frame but meta/info.json declares shape \[4\]", 1
    )


def test_wrong_shape_in_data(good):
    def edit(table):
        rows = table.column("action").to_pylist()
        rows[30] = rows[30] + [0.0]  # episode 1, frame 10: 3 values instead of 2
        i = table.column_names.index("action")
        return table.set_column(i, "action", pa.array(rows, pa.list_(pa.float32())))

    _rewrite(good / DATA, edit)
    _raises(good, rf"{DATA}: column 'action' has 3 values per frame but meta/info.json declares shape \[2\]")


def test_nan_value(good):
    def edit(table):
        rows = table.column("observation.state").to_pylist()
        rows[2 * LEN + 5][1] = float("nan")
        i = table.column_names.index("observation.state")
        return table.set_column(i, table.schema.field(i), pa.array(rows, table.schema.field(i).type))

    _rewrite(good / DATA, edit)
    _raises(good, rf"{DATA}: column 'observation.state' has NaN or inf in episode 2 at frame 5", 2)
    read_episode(good, 1)  # the other episodes stay readable one by one


def test_non_monotonic_timestamp(good):
    def edit(table):
        ts = table.column("timestamp").to_numpy().copy()
        ts[3 * LEN + 17] = ts[3 * LEN + 16]
        return _set_column(table, "timestamp", ts)

    _rewrite(good / DATA, edit)
    _raises(good, rf"{DATA}: column 'timestamp' is not increasing in episode 3 at frame 17", 3)


def test_gap_in_episode_indices(good):
    _rewrite(good / EPISODES, lambda t: t.filter(pa.array([i != 2 for i in range(t.num_rows)])))
    _raises(good, rf"{EPISODES}: column 'episode_index' has a gap or repeat: expected episode 2, found 3")


def test_episode_index_disagrees_with_meta(good):
    def edit(table):
        ep = table.column("episode_index").to_numpy().copy()
        ep[LEN + 4] = 2
        return _set_column(table, "episode_index", ep)

    _rewrite(good / DATA, edit)
    _raises(good, rf"{DATA}: column 'episode_index' is 2 at frame 4 of episode 1", 1)


@pytest.mark.parametrize("rel", [DATA, EPISODES, "meta/tasks.parquet"])
def test_truncated_parquet(good, rel):
    blob = (good / rel).read_bytes()
    (good / rel).write_bytes(blob[: len(blob) // 2])
    message = _raises(good, "truncated")
    assert message.startswith(str(good / rel))


def test_undeclared_column(good):
    _rewrite(good / DATA, lambda t: t.append_column("extra", pa.array(np.zeros(t.num_rows))))
    _raises(good, rf"{DATA}: column 'extra' is not declared in meta/info.json features", 0)


def test_declared_column_missing(good):
    _rewrite(good / DATA, lambda t: t.drop_columns(["action"]))
    _raises(good, rf"{DATA}: column 'action' declared in meta/info.json is missing", 0)


def test_task_index_out_of_range(good):
    _rewrite(good / DATA, lambda t: _set_column(t, "task_index", np.full(t.num_rows, 3)))
    _raises(good, rf"{DATA}: column 'task_index' is 3 in episode 0 at frame 0 but meta/tasks.parquet has 1 tasks", 0)


@pytest.mark.parametrize(
    "edit, pattern",
    [
        (lambda i: i.pop("fps"), "field 'fps' is missing"),
        (lambda i: i.update(codebase_version="v2.1"), "field 'codebase_version' is 'v2.1'"),
        (lambda i: i.update(total_episodes=5), "field 'total_episodes' is 5 but"),
        (lambda i: i["features"].pop("timestamp"), "lacks the default feature 'timestamp'"),
        (
            lambda i: i["features"]["action"].update(shape=[0]),
            r"field 'features.action.shape' is \[0\]; valid: a non-empty list of integers",
        ),
    ],
    ids=["no-fps", "old-version", "total-episodes", "no-timestamp", "bad-shape"],
)
def test_bad_info(good, edit, pattern):
    info = json.loads((good / "meta/info.json").read_text())
    edit(info)
    (good / "meta/info.json").write_text(json.dumps(info))
    message = _raises(good, pattern)
    assert message.startswith(str(good / "meta/info.json"))


def test_info_not_json(good):
    (good / "meta/info.json").write_text("{not json")
    _raises(good, "meta/info.json: not valid JSON")


def test_cli_prints_one_line_and_exits_2(good, capsys):
    (good / "meta/tasks.parquet").unlink()
    assert bench_main(["logs", "info", str(good)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and "meta/tasks.parquet: file is missing" in err


# ----------------------------------------------------------------------------- the writer refuses bad data


def test_writer_refuses_nan(tmp_path):
    state = np.zeros((5, 2))
    state[3, 1] = np.nan
    with pytest.raises(DataError, match="column 'observation.state' has NaN or inf in episode 0 at frame 3"):
        write_dataset(tmp_path / "x", from_arrays([{"observation.state": state}], fps=10))
    assert not (tmp_path / "x").exists()


def test_writer_refuses_bad_timestamps(tmp_path):
    ds = from_arrays([{"action": np.zeros((4, 1)), "timestamp": np.array([0.0, 0.1, 0.1, 0.3])}], fps=10)
    with pytest.raises(DataError, match="column 'timestamp' is not increasing in episode 0 at frame 2"):
        write_dataset(tmp_path / "x", ds)


def test_writer_refuses_wrong_shape(tmp_path):
    ds = from_arrays([{"action": np.zeros((4, 2))}, {"action": np.zeros((3, 2))}], fps=10)
    ds.episodes[1].data["action"] = np.zeros((3, 5), dtype=np.float32)
    with pytest.raises(DataError, match=r"feature 'action' in episode 1 has shape \(3, 5\), expected \(3, 2\)"):
        write_dataset(tmp_path / "x", ds)


def test_writer_refuses_episode_index_gap(tmp_path):
    ds = from_arrays([{"action": np.zeros((4, 2))}, {"action": np.zeros((3, 2))}], fps=10)
    ds.episodes[1].index = 2
    with pytest.raises(DataError, match="episode at position 1 has index 2"):
        write_dataset(tmp_path / "x", ds)


def test_from_arrays_refuses_inconsistent_episodes():
    with pytest.raises(DataError, match=r"from_arrays: episode 1: feature 'action' has dtype float32 shape \[3\]"):
        from_arrays([{"action": np.zeros((4, 2))}, {"action": np.zeros((4, 3))}], fps=10)
    with pytest.raises(DataError, match="feature 'action' has 3 frames but 'observation.state' has 4"):
        from_arrays([{"observation.state": np.zeros((4, 2)), "action": np.zeros((3, 2))}], fps=10)

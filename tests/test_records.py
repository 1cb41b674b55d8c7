"""Records: append-only, torn tail repaired, dedupe, comparable view."""

import json

import pytest

from bench.core.errors import DataError
from bench.records import RecordWriter, comparable, dedupe, read_records
from tests.fixtures import record


def _rec(i, **kw):
    base = dict(seed=100 + i, init_state_hash="abc", success_once=True, return_=1.5, steps_to_success=3)
    base.update(policy="scripted", backend="x", wall_s=0.1, finished_at=1.0, worker_pid=1)
    return record(episode=i, **{**base, **kw})


def test_roundtrip_and_torn_tail(tmp_path):
    path = tmp_path / "episodes.jsonl"
    with RecordWriter(path) as w:
        w.write(_rec(0))
        w.write(_rec(1))
    with open(path, "a") as fh:  # what kill -9 mid-write leaves behind
        fh.write('{"run_id": "r", "job_')
    recs = read_records(path)
    assert [r.episode for r in recs] == [0, 1]
    with RecordWriter(path) as w:  # reopening repairs the tail before appending
        w.write(_rec(2))
    assert [r.episode for r in read_records(path)] == [0, 1, 2]
    assert all(json.loads(line) for line in path.read_text().splitlines())


def test_corrupt_middle_line_is_an_error(tmp_path):
    path = tmp_path / "episodes.jsonl"
    path.write_text(_rec(0).to_json() + "\nnot json\n" + _rec(1).to_json() + "\n")
    with pytest.raises(DataError, match="line 2 is not an episode record"):
        read_records(path)


def test_dedupe_and_comparable():
    a, b = _rec(0, wall_s=1.0, run_id="x"), _rec(0, wall_s=2.0, run_id="y")
    assert len(dedupe([a, b])) == 1
    assert comparable(a) == comparable(b)
    assert comparable(a) != comparable(_rec(0, success_once=False))


def test_atomic_writes_get_the_usual_permissions(tmp_path):
    """mkstemp creates 0600 files; results written atomically are as readable as open() would make them."""
    import os

    from bench.core.io import write_atomic

    umask = os.umask(0o022)
    os.umask(umask)
    write_atomic(tmp_path / "x.json", {"a": 1})
    assert (tmp_path / "x.json").stat().st_mode & 0o777 == 0o666 & ~umask

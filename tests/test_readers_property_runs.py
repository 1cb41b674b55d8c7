"""Property tests over bench's file readers: mutated valid files and random bytes.

Each test starts from a valid document, mutates it (type swaps, deleted keys, NaN/inf, huge and
negative numbers; for bytes: truncation, random bytes, non-UTF-8) and calls the reader. The
reader must either accept it or raise a `BenchError`; any other exception is a bug. CLI-level
properties also check exit 2 and exactly one line on stderr.

Examples per test are fixed (`derandomize=True`) so CI is deterministic; the total is about
1,300 generated inputs (see EXAMPLES below).
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.core.errors import BenchError
from bench.core.schema import load_json, validate
from bench.logs.lerobot.validate import check_info
from bench.records import EpisodeRecord, read_records
from bench.scoring.summary import check_run_meta
from tests.fixtures import record

SETTINGS = dict(deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
EXAMPLES = {
    "records": 300,
    "run_meta": 200,
    "info": 300,
    "json_bytes": 200,
    "summary_like": 150,
    "cli": 100,
    "spec_bytes": 100,
}

# one valid record as episodes.jsonl holds it (tests.fixtures.record, then the writer's own JSON)
RECORD = json.loads(
    record(
        seed=100,
        init_state_hash="abc",
        success_once=True,
        steps_to_success=3,
        return_=1.5,
        policy="scripted",
        backend="x",
        wall_s=0.1,
        finished_at=1.0,
        worker_pid=1,
    ).to_json()
)
RUN_META = {
    "run_id": "r",
    "suite": {"name": "s", "version": "1"},
    "policy": {"name": "p"},
    "config": {"n_boot": 2000, "confidence": 0.95, "seed": 0, "metric": "success_once"},
    "provenance": {},
    "expected_episodes": 3,
}
INFO = {
    "codebase_version": "v3.0",
    "robot_type": "arm",
    "total_episodes": 2,
    "total_frames": 20,
    "total_tasks": 1,
    "fps": 10,
    "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
    "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
    "features": {
        "observation.state": {"dtype": "float32", "shape": [2], "names": None},
        "action": {"dtype": "float32", "shape": [2], "names": ["a", "b"]},
    },
}
LEADERBOARD = {"schema": "bench.leaderboard/1", "suites": [], "ranking": "x", "entries": []}

# values swapped in: wrong types, non-finite, huge and negative numbers
NASTY = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.sampled_from([math.nan, math.inf, -math.inf, 1e300, -1e300, -1, 0, 10**19]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
    st.lists(st.integers(), max_size=3),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
)


def _paths(doc, prefix=()):
    """Every (path to a value) in a JSON document."""
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _paths(v, (*prefix, i))


@st.composite
def mutated(draw, base):
    """`base` with 1-3 edits: a value replaced by a nasty one, or a key deleted."""
    doc = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in _paths(doc) if p]
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        if isinstance(parent, dict) and draw(st.booleans()):
            del parent[path[-1]]
        else:
            parent[path[-1]] = draw(NASTY)
    return doc


def _dump(doc) -> str:
    return json.dumps(doc, allow_nan=True)


@settings(max_examples=EXAMPLES["records"], **SETTINGS)
@given(doc=mutated(RECORD))
def test_episode_records_reader_refuses_or_accepts(tmp_path_factory, doc):
    path = tmp_path_factory.mktemp("rec") / "episodes.jsonl"
    path.write_text(_dump(RECORD) + "\n" + _dump(doc) + "\n" + _dump(RECORD) + "\n")
    try:
        recs = read_records(path)
    except BenchError as exc:
        assert "episodes.jsonl" in str(exc) and "\n" not in str(exc)
        return
    # accepted: every field has the type the scorer relies on
    for r in recs:
        assert isinstance(r, EpisodeRecord) and isinstance(r.success_once, bool) and r.seed >= 0 and r.length >= 0
        assert r.return_ is None or math.isfinite(r.return_)


@settings(max_examples=EXAMPLES["run_meta"], **SETTINGS)
@given(doc=mutated(RUN_META))
def test_run_json_checker_refuses_or_accepts(doc):
    try:
        check_run_meta(doc, "run.json")
    except BenchError as exc:
        assert str(exc).startswith("run.json") and "\n" not in str(exc)
        return
    cfg = doc["config"]
    assert 0 < cfg.get("confidence", 0.95) < 1 and cfg.get("seed", 0) >= 0 and cfg.get("n_boot", 2000) >= 1


@settings(max_examples=EXAMPLES["info"], **SETTINGS)
@given(doc=mutated(INFO))
def test_lerobot_info_checker_refuses_or_accepts(doc):
    try:
        check_info(
            doc,
            Path("ds/meta/info.json"),
            ("codebase_version", "fps", "features", "total_episodes", "total_frames", "data_path"),
        )
    except BenchError as exc:
        assert "info.json" in str(exc) and "\n" not in str(exc)
        return
    assert not isinstance(doc["fps"], bool) and 0 < doc["fps"] <= 10_000
    for feat in doc["features"].values():
        assert all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in feat["shape"])


def _byte_mutations(valid: bytes):
    return st.one_of(
        st.integers(0, len(valid)).map(lambda n: valid[:n]),  # truncation
        st.binary(max_size=64),  # random bytes
        st.tuples(st.integers(0, len(valid)), st.binary(min_size=1, max_size=4)).map(
            lambda t: valid[: t[0]] + t[1] + valid[t[0] :]
        ),  # inserted bytes
        st.sampled_from(
            [
                b"\xff\xfe",
                b"\x80" + valid,
                valid.replace(b'"', b"\xc3", 1),
                b"[" * 5000,
                b'{"schema": 1' + b"0" * 5000 + b"}",
            ]
        ),  # non-UTF-8, deep, huge ints
    )


@settings(max_examples=EXAMPLES["json_bytes"], **SETTINGS)
@given(data=_byte_mutations(json.dumps(LEADERBOARD).encode()))
def test_json_bytes_refused_in_one_line(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("j") / "x.json"
    path.write_bytes(data)
    try:
        validate(load_json(path, expect=dict), str(path))
    except BenchError as exc:
        assert "x.json" in str(exc) and "\n" not in str(exc)


@settings(max_examples=EXAMPLES["summary_like"], **SETTINGS)
@given(
    doc=mutated(
        {
            "schema": "bench.leaderboard/1",
            "suites": [{"name": "s", "version": "1", "manifest": {}}],
            "ranking": "x",
            "entries": [],
        }
    )
)
def test_leaderboard_validate_refuses_or_accepts(doc):
    try:
        validate(doc, "lb.json")
    except BenchError as exc:
        assert str(exc).startswith("lb.json") and "\n" not in str(exc)


@settings(max_examples=EXAMPLES["cli"], **SETTINGS)
@given(doc=mutated(RECORD))
def test_cli_score_exits_2_with_one_line(tmp_path_factory, capsys, doc):
    run = tmp_path_factory.mktemp("run")
    (run / "run.json").write_text(json.dumps(RUN_META))
    (run / "episodes.jsonl").write_text(_dump(doc) + "\n" + _dump(RECORD) + "\n")
    from bench.cli import main

    before = sorted(p.name for p in run.iterdir())
    code = main(["score", str(run)])
    err = capsys.readouterr().err
    assert code in (0, 2), err
    if code == 2:
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
        assert sorted(p.name for p in run.iterdir()) == before


SPEC = (
    b"model: arm.xml\nsubsteps: 4\nsignals:\n  qpos: {column: observation.state, index: [0]}\n"
    b"  ctrl: {column: action, index: [0]}\n"
)


@settings(max_examples=EXAMPLES["spec_bytes"], **SETTINGS)
@given(data=_byte_mutations(SPEC))
def test_spec_file_bytes_refused_in_one_line(tmp_path_factory, data):
    from bench.replay.spec import load_signal_map

    folder = tmp_path_factory.mktemp("spec")
    (folder / "arm.xml").write_text("<mujoco/>")
    path = folder / "spec.yaml"
    path.write_bytes(data)
    try:
        load_signal_map(path)
    except BenchError as exc:
        assert "\n" not in str(exc)


def test_examples_budget():
    """The suite's share of the issue's >= 2,000 generated inputs in CI."""
    assert sum(EXAMPLES.values()) >= 1200


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(pytest.main([__file__, "-q"]))

"""Property tests: mutated result files reach the JSON reader and schema validator.

Every mutation (type swaps, deletions, NaN/inf, huge numbers, truncation, random or
non-UTF-8 bytes) must end in a `BenchError` with a one-line message, or be accepted;
any other exception is a bug in the reader.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.core.errors import BenchError
from bench.core.schema import load_json, validate

REPO = Path(__file__).resolve().parents[1]
SUMMARY = REPO / "results" / "bc_image" / "bc_image-visual" / "summary.json"

SWAPS = st.sampled_from(
    [None, True, -1, 0, 10**30, 1e308, math.nan, math.inf, -math.inf, "", "x" * 300, [], [1, "a"], {}, {"k": None}]
)


def _paths(doc, prefix=()):
    """Every (path) to a value inside `doc`, depth-first."""
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _paths(v, prefix + (i,))


def _mutate(doc, path, value, delete):
    if not path:
        return value
    parent = doc
    for p in path[:-1]:
        parent = parent[p]
    if delete and isinstance(parent, dict):
        del parent[path[-1]]
    else:
        parent[path[-1]] = value
    return doc


def _check(fn):
    try:
        fn()
    except BenchError as exc:
        assert "\n" not in str(exc), str(exc)


@pytest.fixture(scope="module")
def summary_text():
    if not SUMMARY.exists():
        pytest.skip(f"{SUMMARY} absent")
    return SUMMARY.read_text()


@settings(
    max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(data=st.data(), value=SWAPS, delete=st.booleans())
def test_summary_json_mutations(summary_text, tmp_path_factory, data, value, delete):
    doc = json.loads(summary_text)
    paths = list(_paths(doc))
    path = data.draw(st.sampled_from(paths))
    doc = _mutate(doc, path, value, delete)
    f = tmp_path_factory.mktemp("s") / "summary.json"
    f.write_text(json.dumps(doc, allow_nan=True))
    _check(lambda: validate(load_json(f), str(f)))


@settings(
    max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(data=st.data(), junk=st.binary(max_size=64))
def test_summary_bytes_mutations(summary_text, tmp_path_factory, data, junk):
    raw = summary_text.encode()
    cut = data.draw(st.integers(0, len(raw)))
    kind = data.draw(st.sampled_from(["truncate", "insert", "latin1"]))
    if kind == "truncate":
        raw = raw[:cut]
    elif kind == "insert":
        raw = raw[:cut] + junk + raw[cut:]
    else:
        raw = raw[:cut] + b"\xff\xfe" + raw[cut:]
    f = tmp_path_factory.mktemp("b") / "summary.json"
    f.write_bytes(raw)
    _check(lambda: validate(load_json(f), str(f)))


@settings(
    max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(data=st.data(), value=SWAPS, delete=st.booleans())
def test_leaderboard_read_input_mutations(summary_text, tmp_path_factory, data, value, delete):
    from bench.board.leaderboard import entry_from_summary, read_input

    doc = json.loads(summary_text)
    path = data.draw(st.sampled_from(list(_paths(doc))))
    doc = _mutate(doc, path, value, delete)
    run = tmp_path_factory.mktemp("r")
    (run / "summary.json").write_text(json.dumps(doc, allow_nan=True))

    def go():
        source, got = read_input(str(run))
        if got.get("schema") == "bench.summary/1":
            entry_from_summary(got, source)

    _check(go)


@settings(
    max_examples=200, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(data=st.data(), value=SWAPS, delete=st.booleans())
def test_lerobot_info_mutations(shared_dir, tmp_path_factory, data, value, delete):
    import shutil

    from bench.logs import lerobot

    src = shared_dir / "data" / "formats" / "lerobot_v3_state"
    if not src.is_dir():
        pytest.skip(f"{src} absent")
    root = tmp_path_factory.mktemp("ds") / "ds"
    shutil.copytree(src, root)
    doc = json.loads((root / "meta" / "info.json").read_text())
    path = data.draw(st.sampled_from(list(_paths(doc))))
    doc = _mutate(doc, path, value, delete)
    (root / "meta" / "info.json").write_text(json.dumps(doc, allow_nan=True))
    _check(lambda: lerobot.info(root))

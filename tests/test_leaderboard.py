"""Leaderboard merge/show: one entry per policy x checkpoint x suite version, ranking by the lower bound,
refusals (other suite version or manifest, corrupt or foreign JSON) that leave the existing file untouched."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from bench import cli
from bench.board.leaderboard import merge, read_input
from bench.core.errors import DataError
from bench.core.schema import validate
from bench.records import EpisodeRecord
from bench.scoring.summary import build
from tests.fixtures import provenance, record

MANIFEST = {"robots": {"seen": ["A", "B"], "unseen": ["C", "D"]}}


def _records(run_id: str, rates: dict[str, float], episodes: int = 10) -> list[EpisodeRecord]:
    out = []
    for robot, p in rates.items():
        split = "seen" if robot in MANIFEST["robots"]["seen"] else "unseen"
        for e in range(episodes):
            ok = e < round(p * episodes)
            out.append(record(ok, run_id=run_id, suite="toy", robot=robot, split=split, episode=e, seed=e, length=5))
    return out


def summary(
    run_id: str,
    policy: str,
    rates: dict[str, float],
    *,
    sha: str | None = None,
    version: str = "1",
    manifest: dict | None = None,
    finished: str = "2026-01-01T00:00:00+00:00",
) -> dict:
    meta = {
        "run_id": run_id,
        "suite": {"name": "toy", "version": version, "manifest": copy.deepcopy(manifest or MANIFEST)},
        "policy": {"name": policy, "checkpoint": "c.safetensors" if sha else None, "checkpoint_sha256": sha},
        "config": {"seed": 0, "n_boot": 500, "confidence": 0.95, "metric": "success_once"},
        "expected_episodes": 10 * len(rates),
        "provenance": provenance(backend=["b"], episode_seeds=list(range(10)), finished_at=finished),
    }
    s = build(_records(run_id, rates), run_meta=meta).to_json()
    validate(s)
    return s


ALL = {"A": 1.0, "B": 0.9, "C": 0.6, "D": 0.5}


def write(path: Path, doc) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc) if not isinstance(doc, str) else doc)
    return path


def test_merge_ranks_by_lower_bound_within_a_group(tmp_path: Path):
    good = summary("good", "expert", ALL)
    poor = summary("poor", "random", {"A": 0.2, "B": 0.1, "C": 0.0, "D": 0.1})
    mid = summary("mid", "bc", {"A": 0.9, "B": 0.9, "C": 0.3, "D": 0.2}, sha="a" * 64)
    board = merge([("good", good), ("poor", poor), ("mid", mid)])
    validate(board)
    ranked = [(e["rank"], e["policy"]["name"]) for e in board["entries"]]
    assert ranked == [(1, "expert"), (2, "bc"), (3, "random")]
    assert all(e["score"]["split"] == "unseen" for e in board["entries"])
    lows = [e["score"]["ci"][0] for e in board["entries"]]
    assert lows == sorted(lows, reverse=True)


def test_one_entry_per_policy_checkpoint_suite_version(tmp_path: Path):
    small = summary("r1", "bc", {"A": 1.0, "C": 0.5}, sha="b" * 64)
    small["counts"]["episodes"] = 5  # fewer scored episodes than r2
    big = summary("r2", "bc", ALL, sha="b" * 64)
    other_ckpt = summary("r3", "bc", ALL, sha="c" * 64)
    board = merge([("r1", small), ("r2", big), ("r3", other_ckpt)])
    assert sorted(e["run_id"] for e in board["entries"]) == ["r2", "r3"]
    assert next(e for e in board["entries"] if e["run_id"] == "r2")["superseded"] == ["r1"]
    # merging the merged board with its inputs again changes nothing
    again = merge([("board", board), ("r1", small)])
    assert [(e["run_id"], e["rank"]) for e in again["entries"]] == [(e["run_id"], e["rank"]) for e in board["entries"]]


def test_runs_with_a_cell_selection_are_not_ranked_against_full_runs():
    full = summary("full", "expert", ALL)
    part = summary("part", "expert", {"A": 1.0})
    part["config"]["robots"] = ["A"]
    board = merge([("full", full), ("part", part)])
    assert {e["group"] for e in board["entries"]} == {"toy v1 · success_once", 'toy v1 · success_once · robots=["A"]'}
    assert all(e["rank"] == 1 for e in board["entries"])


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda s: s["suite"].update(version="2"), "refusing to rank across suite versions"),
        (
            lambda s: s["suite"]["manifest"]["robots"].update(seen=["A"], unseen=["B", "C", "D"]),
            "refusing to rank across split manifests",
        ),
    ],
    ids=["suite-version", "split-manifest"],
)
def test_merge_refuses_incomparable_suites(change, match):
    a, b = summary("a", "expert", ALL), summary("b", "random", ALL)
    change(b)
    with pytest.raises(DataError, match=match):
        merge([("a", a), ("b", b)])


@pytest.fixture
def existing(tmp_path: Path) -> Path:
    runs = [write(tmp_path / "runs" / n / "summary.json", summary(n, n, ALL)) for n in ("x", "y")]
    out = tmp_path / "leaderboard.json"
    assert cli.main(["leaderboard", "merge", *(str(r.parent) for r in runs), f"out={out}"]) == 0
    return out


@pytest.mark.parametrize(
    "bad, match",
    [
        ('{"schema": "bench.summary/1", ', "not valid JSON"),
        (json.dumps({"name": "someone else's file"}), "not a bench result (no 'schema' field)"),
        (json.dumps({"schema": "other.tool/3"}), "unknown schema 'other.tool/3'"),
        (json.dumps({"schema": "bench.summary/1", "run_id": "x"}), "is a required property"),
        (json.dumps({"schema": "bench.summary/1", "value": float("nan")}), "NaN"),
    ],
    ids=["corrupt", "foreign", "unknown-schema", "incomplete-summary", "nan"],
)
def test_bad_input_exits_2_and_leaves_the_leaderboard_untouched(existing: Path, tmp_path: Path, capsys, bad, match):
    before = existing.read_bytes()
    bad_file = write(tmp_path / "bad.json", bad)
    good = write(tmp_path / "runs" / "z" / "summary.json", summary("z", "z", ALL))
    code = cli.main(["leaderboard", "merge", str(good), str(bad_file), f"out={existing}"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("error:") and len(err.splitlines()) == 1 and match in err, err
    assert existing.read_bytes() == before
    assert not [p for p in existing.parent.iterdir() if p.name.startswith(".leaderboard")]  # no temp file left


def test_other_version_via_cli_exits_2_untouched(existing: Path, tmp_path: Path, capsys):
    before = existing.read_bytes()
    v2 = summary("v2", "new", ALL, version="2")
    code = cli.main(["leaderboard", "merge", str(existing), str(write(tmp_path / "v2.json", v2)), f"out={existing}"])
    assert code == 2 and "refusing to rank across suite versions" in capsys.readouterr().err
    assert existing.read_bytes() == before


def test_verdict_or_leaderboard_kinds(tmp_path: Path, existing: Path):
    verdict = {"schema": "bench.regress/1"}
    with pytest.raises(DataError):
        read_input(str(write(tmp_path / "v.json", verdict)))
    src, doc = read_input(str(existing))
    assert doc["schema"] == "bench.leaderboard/1"


def test_show_ranks_and_refuses_non_leaderboards(existing: Path, tmp_path: Path, capsys):
    board = json.loads(existing.read_text())
    entries = copy.deepcopy(board["entries"])
    assert cli.main(["leaderboard", "show", str(existing)]) == 0
    out = capsys.readouterr().out
    assert "ranked by the lower bound" in out and all(e["run_id"] in out for e in entries)
    s = write(tmp_path / "s.json", summary("s", "s", ALL))
    assert cli.main(["leaderboard", "show", str(s)]) == 2
    assert "is not a leaderboard" in capsys.readouterr().err
    assert cli.main(["leaderboard", "validate", str(existing)]) == 0


def test_merge_needs_out_and_inputs(tmp_path: Path, capsys):
    assert cli.main(["leaderboard", "merge", "x"]) == 2
    assert "out=FILE is required" in capsys.readouterr().err
    assert cli.main(["leaderboard", "merge", f"out={tmp_path / 'l.json'}"]) == 2
    assert cli.main(["leaderboard", "merge", "x", "outt=y"]) == 2
    assert "unknown key 'outt'" in capsys.readouterr().err
    assert not (tmp_path / "l.json").exists()


def test_runs_of_different_suite_specs_are_not_ranked_together_unless_told_to():
    from bench.protocols.suite import SuiteSpec

    a, b = summary("a", "expert", ALL), summary("b", "random", ALL)
    a["provenance"]["packages"] = {"mujoco": "3.3.0", "numpy": "1.26.4"}
    b["provenance"]["packages"] = {"mujoco": "3.3.1", "numpy": "1.26.0"}  # numpy is not a simulator
    with pytest.raises(
        DataError, match=r"b: suite toy: simulator mujoco 3\.3\.0 vs 3\.3\.1 \(in a\): refusing to rank"
    ):
        merge([("a", a), ("b", b)])
    assert len(merge([("a", a), ("b", b)], allow_spec_change=True)["entries"]) == 2
    b["provenance"]["packages"]["mujoco"] = "3.3.0"
    merge([("a", a), ("b", b)])  # numpy's version does not change what the suite simulates
    sa = SuiteSpec.of(a["suite"], a["provenance"]["packages"])
    assert sa.digest == SuiteSpec.of(json.loads(json.dumps(a["suite"])), a["provenance"]["packages"]).digest
    assert sa.to_json()["simulators"] == {"mujoco": "3.3.0"} and sa.digest.startswith("toy-v1@")

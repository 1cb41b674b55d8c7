"""Committed reference results: every summary validates and re-scores identically from its own records,
and results/leaderboard.json is exactly the merge of the committed runs."""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

import pytest

from bench.board.leaderboard import merge, read_input
from bench.core.provenance import safetensors_metadata
from bench.core.schema import load_json, validate
from bench.records import EPISODES, read_records
from bench.scoring.summary import build

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "results"
RUNS = sorted(p for p in (RESULTS / "runs").glob("*") if p.is_dir()) if (RESULTS / "runs").is_dir() else []


def test_results_folder_has_runs_and_a_leaderboard():
    assert RUNS, f"no committed reference runs under {RESULTS / 'runs'}"
    assert (RESULTS / "leaderboard.json").is_file()


@pytest.mark.parametrize("run", RUNS, ids=[p.name for p in RUNS])
def test_summary_validates_and_rescores_identically(run: Path):
    for name in (EPISODES, "run.json", "summary.json"):
        assert (run / name).is_file(), f"{run.name}: {name} missing"
    summary = load_json(run / "summary.json")
    assert validate(summary, str(run)) == "bench.summary/1"
    meta = load_json(run / "run.json")
    records = read_records(run / EPISODES)
    assert len(records) == summary["counts"]["episodes"]
    assert {r.run_id for r in records} == {summary["run_id"]} == {run.name}
    rescored = json.loads(json.dumps(build(records, run_meta=meta).to_json()))
    assert rescored == summary


@pytest.mark.parametrize("run", RUNS, ids=[p.name for p in RUNS])
def test_records_carry_the_checkpoint_hash_of_the_run(run: Path):
    meta = load_json(run / "run.json")
    shas = {r.checkpoint_sha256 for r in read_records(run / EPISODES)}
    assert shas == {meta["policy"]["checkpoint_sha256"]}


def test_leaderboard_is_the_merge_of_the_committed_runs(monkeypatch):
    board = load_json(RESULTS / "leaderboard.json")
    assert validate(board) == "bench.leaderboard/1"
    monkeypatch.chdir(REPO)  # sources are recorded relative to the repository root
    inputs = [read_input(str(Path("results/runs") / r.name)) for r in RUNS]
    assert json.loads(json.dumps(merge(inputs))) == board, (
        "results/leaderboard.json is stale: bench leaderboard merge results/runs/* out=results/leaderboard.json overwrite=true"
    )


def _absolute_paths(node, where: str = ""):
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _absolute_paths(v, f"{where}.{k}" if where else str(k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _absolute_paths(v, f"{where}[{i}]")
    elif isinstance(node, str) and (node.startswith(("/", "~")) or node[1:3] in (":\\", ":/")):
        yield f"{where}={node}"


def _json_or_text(text: str):
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


# a machine's folder in running text; an argument of a command the reader types (`work=/tmp/x`) is their choice
MACHINE_FOLDER = re.compile(r"(?<![\w.=~-])/(?:tmp|work|home|root|Users)/\S*")


def test_committed_results_hold_no_absolute_path():
    """Results and their provenance name files relative to the checkout, never a folder of the machine that made
    them: JSON documents and records, the metadata in every safetensors header (a checkpoint's spec records its
    training data: baselines.bc writes it portable), and any other text file (bench.core.provenance.portable)."""
    found = []
    for path in sorted(p for p in RESULTS.rglob("*") if p.is_file()):
        rel = path.relative_to(RESULTS).as_posix()
        if path.suffix in (".json", ".jsonl"):
            text = path.read_text()
            lines = [text] if path.suffix == ".json" else [ln for ln in text.splitlines() if ln.strip()]
            found += [f"{rel}: {hit}" for line in lines for hit in _absolute_paths(json.loads(line))]
        elif path.suffix == ".safetensors":
            meta = safetensors_metadata(path) or {}
            found += [
                f"{rel} (header): {hit}" for hit in _absolute_paths({k: _json_or_text(v) for k, v in meta.items()})
            ]
        elif path.suffix not in (".png", ".mp4", ".parquet"):
            found += [f"{rel}: {m.group(0)}" for m in MACHINE_FOLDER.finditer(path.read_text())]
    assert not found, found[:10]


def test_aloha_act_entry_has_its_gap_and_per_axis_drops():
    """The small ACT on ALOHA transfer-cube (results/aloha_act): seen/unseen gap and each axis' drop, with intervals."""
    board = load_json(RESULTS / "leaderboard.json")
    entry = next(e for e in board["entries"] if e["run_id"] == "aloha-act-s100")
    assert entry["suite"]["name"] == "aloha" and entry["policy"]["checkpoint"] == "results/aloha_act/pretrained_model"
    gap = next(g for g in entry["gaps"] if g["kind"] == "seen-unseen" and g["metric"] == "success_once")
    assert gap["value"] is not None and len(gap["ci"]) == 2
    drops = {d["axis"]: d for d in entry["drops"]}
    assert set(drops) == {"friction", "mass", "gain", "frictionloss", "latency"}
    assert all(d["drop"]["n_pairs"] == 70 and len(d["drop"]["ci"]) == 2 for d in drops.values())
    weights = RESULTS / "aloha_act" / "pretrained_model" / "model.safetensors"
    assert hashlib.sha256(weights.read_bytes()).hexdigest() == entry["policy"]["checkpoint_sha256"]

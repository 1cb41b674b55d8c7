"""summary.json and run.json are written from typed dataclasses and read back into them, byte for byte."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.core.errors import DataError
from bench.scoring.typed import CellRow, RunMeta, Summary

RESULTS = Path(__file__).resolve().parents[1] / "results"
SUMMARIES = sorted(RESULTS.rglob("summary.json"))
RUNS = sorted(RESULTS.rglob("run.json"))


@pytest.mark.parametrize("path", SUMMARIES, ids=[str(p.relative_to(RESULTS)) for p in SUMMARIES])
def test_every_committed_summary_reads_into_the_types_and_back_identically(path):
    text = path.read_text()
    doc = json.loads(text)
    typed = Summary.from_json(doc, str(path))
    assert json.dumps(typed.to_json()) == json.dumps(doc)
    assert all(isinstance(c, CellRow) for c in typed.cells) and typed.counts.episodes >= 0


@pytest.mark.parametrize("path", RUNS, ids=[str(p.relative_to(RESULTS)) for p in RUNS])
def test_every_committed_run_json_reads_into_run_meta_and_back(path):
    doc = json.loads(path.read_text())
    assert json.dumps(RunMeta.from_json(doc, str(path)).to_json()) == json.dumps(doc)


def test_a_field_of_the_wrong_type_is_one_line_naming_it():
    doc = json.loads(SUMMARIES[0].read_text())
    doc["cells"][0]["n"] = "ten"
    with pytest.raises(DataError, match=r"summary\.cells\[0\]: field 'n' is 'ten'"):
        Summary.from_json(doc)
    doc["cells"][0]["n"] = 10
    del doc["counts"]["complete"]
    with pytest.raises(DataError, match=r"summary\.counts: field 'complete' is missing"):
        Summary.from_json(doc)

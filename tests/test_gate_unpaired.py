"""The regression gate on unpaired runs (`bench regress paired=false`): its statistics, and the CLI end to end."""

from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from bench.board.gate import sequential
from bench.board.gate import unpaired as gate
from bench.scoring import exact

A = ("Lift", "Panda", "default", "nominal", "seen")
B = ("Lift", "IIWA", "default", "nominal", "seen")
C = ("Lift", "UR5e", "default", "nominal", "unseen")


def test_one_cell_is_its_exact_test_and_many_cells_get_holm_over_the_paired_gates_weights():
    one = gate.evaluate({A: gate.Batches(9, 10, 2, 12)}, 0.05, 0.05, 0.5, 12)
    (t,) = one["tests"]
    assert t["id"] == "pooled" and t["test"] == gate.TEST_NAME
    assert t["p"] == pytest.approx(exact.chan(9, 10, 2, 12, 0.05, "greater"), rel=1e-5)
    assert one["decision"] == "regression" and t["lcb"] > 0.05
    cells = {A: gate.Batches(20, 20, 4, 20), B: gate.Batches(18, 20, 18, 20), C: gate.Batches(15, 20, 16, 20)}
    look = gate.evaluate(cells, 0.05, 0.05, 0.5, 20)
    by = {t["id"]: t for t in look["tests"]}
    assert set(by) == {"pooled", "split:seen", "split:unseen", *(sequential.cell_id(k) for k in cells)}
    want = sequential.holm(
        {h: by[h]["p"] for h in by},
        {h: 0.05 * w for h, w in sequential.base_weights(sorted(cells), False, 0.5).items()},
    )
    assert {h for h, (rej, _) in want.items() if rej} == set(look["regressed"])
    assert sequential.cell_id(A) in look["regressed"] and sequential.cell_id(B) not in look["regressed"]
    assert by[sequential.cell_id(B)]["p"] == pytest.approx(exact.chan(18, 20, 18, 20, 0.05, "greater"), rel=1e-5)
    assert by["pooled"]["test"] == gate.POOLED_NAME


def test_equal_large_batches_certify_no_regression_and_small_ones_stay_inconclusive():
    big = gate.evaluate({A: gate.Batches(150, 200, 152, 200), B: gate.Batches(160, 200, 161, 200)}, 0.1, 0.05, 0.5, 200)
    assert big["decision"] == "no_regression" and big["certify"]["p"] < 0.05 and not big["regressed"]
    small = gate.evaluate({A: gate.Batches(4, 5, 4, 5)}, 0.1, 0.05, 0.5, 5)
    assert small["decision"] == "continue" and sequential.decide([small], False) == ("inconclusive", 0)


def test_stratified_score_of_one_cell_is_farrington_manning_and_its_bounds_invert_it():
    from scipy.stats import norm

    b = gate.Batches(14, 20, 9, 22)
    assert gate.stratified_z([b], 0.1) == pytest.approx(float(exact.margin_z(14, 20, 9, 22, 0.1)))
    lcb = gate.bound([b], 0.95, "lower")
    assert gate.stratified_z([b], lcb) == pytest.approx(norm.ppf(0.95), abs=1e-6) and lcb < b.drop


def test_stratified_pooled_test_keeps_its_size_near_alpha_on_the_boundary():
    """Four cells at drop = margin (rates 0.8 -> 0.7), 30 episodes a side: the pooled test's exact size, enumerated
    cell by cell is too large (31^8 tables), so 4,000 draws from a seeded generator; it stays near alpha."""
    import numpy as np

    rng = np.random.default_rng(38)
    hits = 0
    for _ in range(4000):
        groups = [gate.Batches(int(rng.binomial(30, 0.8)), 30, int(rng.binomial(30, 0.7)), 30) for _ in range(4)]
        hits += gate.p_value(groups, 0.1, "greater") < 0.05
    assert hits / 4000 < 0.05 + 3 * (0.05 * 0.95 / 4000) ** 0.5


# -- CLI ----------------------------------------------------------------------------------------
def _bench(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench", *args], capture_output=True, text=True, cwd=cwd, timeout=600)


def _run(tmp_path: Path, run_id: str, *args: str) -> Path:
    res = _bench(
        "run", *args, "robots=[Panda]", "horizon=70", "workers=1", f"run_id={run_id}", f"out={tmp_path}", cwd=tmp_path
    )
    assert res.returncode == 0, res.stderr[-2000:]
    return tmp_path / run_id


def test_unpaired_gate_on_runs_with_other_seeds(tmp_path: Path):
    """Real rollouts: the expert (seed 1) vs random (seed 2): the paired gate refuses, paired=false finds the drop."""
    base = _run(tmp_path, "base", "policy=scripted", "episodes=6", "seed=1")
    cand = _run(tmp_path, "cand", "policy=random", "episodes=6", "seed=2")
    refused = _bench("regress", f"candidate={cand}", f"baseline={base}", f"runs={tmp_path / 'p'}", cwd=tmp_path)
    assert refused.returncode == 2 and "paired=false compares the two runs unpaired" in refused.stderr
    assert not (tmp_path / "p").exists()
    res = _bench(
        "regress", f"candidate={cand}", f"baseline={base}", "paired=false", f"out={tmp_path / 'v.json'}", cwd=tmp_path
    )
    assert res.returncode == 1, res.stderr[-2000:]
    v = json.loads((tmp_path / "v.json").read_text())
    assert v["pairing"] == "unpaired" and v["test"] == "chan_exact_unconditional" and v["verdict"] == "regression"
    assert v["seeds"] == {"candidate": 2, "baseline": 1}
    (cell,) = v["cells"]
    assert (cell["episodes_baseline"], cell["episodes_candidate"], cell["baseline"], cell["candidate"]) == (6, 6, 1, 0)
    assert v["p_values"]["pooled"] == pytest.approx(exact.chan(6, 6, 0, 6, v["margin"], "greater"), rel=1e-5)
    root = ET.parse(tmp_path / "v.junit.xml").getroot()
    cases = {(c.get("classname"), c.get("name")): c for c in root.iter("testcase")}
    assert cases[("bench-regress.cells", "Lift/Panda/default (seen)")].find("failure") is not None
    assert "regression (exit 1)" in (tmp_path / "v.md").read_text()
    # the same run against itself: nothing to flag; too few episodes to certify -> inconclusive, exit 0
    same = _bench(
        "regress", f"candidate={base}", f"baseline={base}", "paired=false", f"out={tmp_path / 's.json'}", cwd=tmp_path
    )
    assert same.returncode == 0 and json.loads((tmp_path / "s.json").read_text())["verdict"] == "inconclusive"


@pytest.mark.parametrize(
    "args,match",
    [
        (["candidate=random"], "candidate='random': paired=false compares two recorded run directories"),
        (["episodes=4"], "episodes=: paired=false compares two recorded runs as they are"),
        (["margin=1.5"], "margin=1.5: must be in [0, 1)"),
    ],
)
def test_unpaired_bad_input_is_one_line_exit_2_nothing_written(tmp_path: Path, args, match):
    from tests.fixtures import record

    run = tmp_path / "r"
    run.mkdir()
    (run / "episodes.jsonl").write_text(record(True).to_json() + "\n")
    (run / "run.json").write_text(
        json.dumps({"run_id": "r", "suite": {"name": "s", "version": "1"}, "policy": {}, "config": {}})
    )
    cand = [a for a in args if a.startswith("candidate=")] or [f"candidate={run}"]
    rest = [a for a in args if not a.startswith("candidate=")]
    res = _bench(
        "regress", *cand, f"baseline={run}", "paired=false", *rest, f"out={tmp_path / 'o' / 'v.json'}", cwd=tmp_path
    )
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1 and match in lines[0], res.stderr
    assert not (tmp_path / "o").exists()

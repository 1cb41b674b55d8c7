"""`bench compare`: the group-sequential design's errors (exact and simulated), recorded runs compared look by look,
unpaired runs, and the bad input refused on one line with exit 2 before anything is written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bench.board.compare import design as sd
from bench.board.compare import looks as sl
from bench.board.gate.sequential import pairs_of
from bench.cli import main
from bench.protocols.suite import episode_seed
from bench.records import RecordWriter
from bench.scoring import exact
from tests.fixtures import record

ROBOTS = ["Panda", "UR5e"]


def write_run(path: Path, rates: dict[str, list[bool]], seed: int = 0, policy: str = "p") -> Path:
    """A recorded run directory: per robot, the 0/1 outcomes of its episodes (seeds as `bench run` draws them)."""
    path.mkdir(parents=True)
    with RecordWriter(path / "episodes.jsonl") as w:
        for robot, outcomes in rates.items():
            for i, ok in enumerate(outcomes):
                w.write(
                    record(ok, robot=robot, episode=i, seed=episode_seed(seed, i), init_state_hash=None, policy=policy)
                )
    n = max(len(v) for v in rates.values())
    meta = {
        "run_id": path.name,
        "suite": {"name": "held_out_robots", "version": "1"},
        "policy": {"name": policy},
        "config": {"seed": seed, "episodes": n, "metric": "success_once", "n_boot": 2000, "confidence": 0.95},
        "provenance": {},
        "expected_episodes": n * len(rates),
    }
    (path / "run.json").write_text(json.dumps(meta))
    return path


# -- the design --------------------------------------------------------------------------------------
def test_boundaries_are_lan_demets_obrien_fleming():
    """Five equally spaced looks, one-sided 0.025: Jennison & Turnbull's table (4.877, 3.357, 2.680, 2.290, 2.031)."""
    got = sd.one_sided_bounds((0.2, 0.4, 0.6, 0.8, 1.0), 0.025)
    assert np.allclose(got, [4.877, 3.357, 2.680, 2.290, 2.031], atol=0.004)
    assert sd.one_sided_bounds((1.0,), 0.025)[0] == pytest.approx(1.959964, abs=1e-6)


@pytest.mark.parametrize("cells,batch", [(1, 5), (7, 5), (7, 2)])
def test_exact_errors_of_the_sized_design(cells, batch):
    """Exactly (the law of the counts carried over the looks): P(naming a policy | d = 0) <= alpha at every discordance,
    P(A | d = delta) >= 1 - beta at the plan, P(equivalent | d = delta) <= beta, and fewer pairs than the fixed design."""
    cap, power = sd.size_cap(0.05, 0.2, 0.2, cells, batch)
    assert cap is not None and power >= 0.8
    d = sd.Design(0.05, 0.2, 0.2, tuple(sd.looks_schedule(cap, batch)))
    fixed, _ = sd.fixed_pairs(0.05, 0.2, 0.2)
    for p in (0.02, 0.1, 0.25, 0.5):  # p10 = p01 = p: discordance 2p
        op = sd.operating(d, p, p, cells)
        assert op.a_better + op.b_better <= 0.05, (p, op)
    alt = sd.operating(d, *sd.planned_pairs(0.2), cells)
    assert alt.a_better >= 0.8 and alt.equivalent <= 0.2 and alt.expected_pairs < fixed
    assert sd.operating(d, 0.25, 0.25, cells).expected_pairs < fixed


def test_simulated_comparisons_hold_their_errors():
    """400 comparisons per scenario through `looks.evaluate_look` (the function `bench compare` calls), 7 cells:
    type-I <= alpha and power at delta >= 1 - beta, up to the simulation's own error (3 standard errors)."""
    cells, batch = 7, 5
    cap, _ = sd.size_cap(0.05, 0.2, 0.2, cells, batch)
    assert cap is not None
    d = sd.Design(0.05, 0.2, 0.2, tuple(sd.looks_schedule(cap, batch)))
    keys = [("Lift", f"r{j}", "default", "nominal", "seen") for j in range(cells)]
    rng = np.random.default_rng(0)
    table = {}
    for label, ra, rb, rho in (("null", 0.5, 0.5, 0.0), ("null rho", 0.8, 0.8, 0.5), ("delta", 0.6, 0.4, 0.0)):
        got = {"a_better": 0, "b_better": 0, "equivalent": 0, "inconclusive": 0}
        used = []
        for _ in range(400):
            u = rng.random((cells, cap))
            v = np.where(rng.random((cells, cap)) < rho, u, rng.random((cells, cap)))
            a, b = u < ra, v < rb
            looks = []
            for k, n in enumerate(d.schedule):
                counts = {key: pairs_of(a[j, :n], b[j, :n]) for j, key in enumerate(keys)}
                looks.append(sl.evaluate_look(counts, d, k, cells, bounds=False))
                if looks[-1]["answer"] != "continue":
                    break
            got[sl.verdict_of(looks)] += 1
            used.append(looks[-1]["pairs"])
        table[label] = {k: v / 400 for k, v in got.items()} | {"pairs": float(np.mean(used))}
    se = 3 * np.sqrt(0.05 * 0.95 / 400)
    assert table["null"]["a_better"] + table["null"]["b_better"] <= 0.05 + se
    assert table["null rho"]["a_better"] + table["null rho"]["b_better"] <= 0.05 + se
    assert table["delta"]["a_better"] >= 0.8 - 3 * np.sqrt(0.8 * 0.2 / 400)
    fixed, _ = sd.fixed_pairs(0.05, 0.2, 0.2)
    assert table["delta"]["pairs"] < fixed and table["null"]["pairs"] < fixed


# -- recorded runs through the CLI ------------------------------------------------------------------------
def test_two_recorded_runs_are_compared_look_by_look(tmp_path: Path, capsys):
    rng = np.random.default_rng(1)
    a = write_run(tmp_path / "a", {r: list(rng.random(40) < 0.9) for r in ROBOTS}, policy="new")
    b = write_run(tmp_path / "b", {r: list(rng.random(40) < 0.3) for r in ROBOTS}, policy="old")
    before = (a / "episodes.jsonl").read_bytes()
    out = tmp_path / "c.json"
    assert main(["compare", f"a={a}", f"b={b}", "batch=5", f"out={out}", f"runs={tmp_path}"]) == 0
    doc = json.loads(out.read_text())
    assert doc["schema"] == "bench.compare/1" and doc["answer"] == "a_better" and doc["stopped_early"]
    assert doc["pairs_used"] < doc["pairs_cap"] == 80 and len(doc["looks"]) < 8
    ids = [t["id"] for t in doc["tests"]]
    assert ids[0] == "pooled" and {"cell:Lift/Panda/default", "cell:Lift/UR5e/default"} <= set(ids)
    pooled = doc["tests"][0]
    assert pooled["lo"] > 0 and pooled["alpha"] == 0.05 and doc["tests"][1]["alpha"] == 0.025
    assert (a / "episodes.jsonl").read_bytes() == before and "A BETTER" in capsys.readouterr().err


def test_unpaired_runs_use_boschloo(tmp_path: Path):
    a = write_run(tmp_path / "a", {"Panda": [True] * 14 + [False] * 6}, seed=0)
    b = write_run(tmp_path / "b", {"Panda": [True] * 6 + [False] * 14}, seed=1)
    out = tmp_path / "u.json"
    assert main(["compare", f"a={a}", f"b={b}", "paired=false", f"out={out}"]) == 0
    doc = json.loads(out.read_text())
    t = doc["tests"][0]
    assert t["boschloo_p"] == pytest.approx(exact.boschloo(14, 20, 6, 20), rel=1e-5)
    assert t["fisher_p"] >= t["boschloo_p"] and doc["answer"] == (
        "a_better" if t["boschloo_p"] < 0.05 else "inconclusive"
    )


@pytest.mark.parametrize(
    "args,match",
    [
        (["alpha=0.5"], "alpha=0.5: must be in (0, 0.5)"),
        (["alpha=0"], "alpha=0.0: must be in (0, 0.5)"),
        (["beta=0.7"], "beta=0.7: must be in (0, 0.5)"),
        (["delta=0"], "delta=0.0: must be in (0, 1)"),
        (["delta=-0.1"], "delta=-0.1: must be in (0, 1)"),
        (["b={a}"], "are the same policy"),
        (["b={other_cells}"], "other suite cells"),
        (["b={other_seeds}"], "seed differs between A and B (0 vs 7)"),
    ],
)
def test_bad_input_is_one_line_exit_2_nothing_written(tmp_path: Path, capsys, args, match):
    a = write_run(tmp_path / "a", {"Panda": [True] * 4})
    runs = {
        "a": a,
        "other_cells": write_run(tmp_path / "oc", {"UR5e": [True] * 4}),
        "other_seeds": write_run(tmp_path / "os", {"Panda": [False] * 4}, seed=7),
    }
    before = sorted(p for p in tmp_path.rglob("*"))
    argv = ["compare", f"a={a}", "b=" + str(write_run(tmp_path / "b", {"Panda": [False] * 4}))]
    for x in args:
        key, value = x.split("=", 1)
        argv = [v for v in argv if not v.startswith(key + "=")] + [f"{key}={value.format(**runs)}"]
    before = sorted(p for p in tmp_path.rglob("*"))
    assert main([*argv, f"runs={tmp_path / 'out'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and len(err.splitlines()) == 1, err
    assert sorted(p for p in tmp_path.rglob("*")) == before  # nothing written


def test_help_names_the_keys_and_the_answers(capsys):
    assert main(["compare", "--help"]) == 0
    text = capsys.readouterr().out
    for word in ("alpha", "beta", "delta", "batch", "paired", "A better", "equivalent", "inconclusive"):
        assert word in text


# -- the shipped JSON Schema (bench.compare/1) ----------------------------------------------------------
def test_compare_outputs_validate_against_the_shipped_schema(tmp_path: Path, capsys):
    """A real paired and a real unpaired comparison validate (as `bench leaderboard validate` checks files); the
    schema refuses what a comparison never holds."""
    from bench.core.errors import DataError
    from bench.core.schema import validate

    rng = np.random.default_rng(2)
    a = write_run(tmp_path / "a", {r: list(rng.random(30) < 0.8) for r in ROBOTS}, policy="new")
    b = write_run(tmp_path / "b", {r: list(rng.random(30) < 0.4) for r in ROBOTS}, policy="old")
    c = write_run(tmp_path / "c", {r: list(rng.random(30) < 0.4) for r in ROBOTS}, seed=3, policy="other")
    paired, unpaired = tmp_path / "p.json", tmp_path / "u.json"
    assert main(["compare", f"a={a}", f"b={b}", "batch=5", f"out={paired}", f"runs={tmp_path}"]) == 0
    assert main(["compare", f"a={a}", f"b={c}", "paired=false", f"out={unpaired}"]) == 0
    docs = [json.loads(paired.read_text()), json.loads(unpaired.read_text())]
    assert [validate(d, "doc") for d in docs] == ["bench.compare/1"] * 2
    assert docs[0]["looks"] and not docs[1]["looks"] and "boschloo_p" in docs[1]["tests"][0]
    assert main(["leaderboard", "validate", str(paired), str(unpaired)]) == 0
    capsys.readouterr()
    broken = [
        {**docs[0], "answer": "maybe"},
        {**docs[0], "alpha": 0.5},
        {**docs[1], "tests": [{**docs[1]["tests"][0], "boschloo_p": 1.5}]},
        {**docs[1], "looks": docs[0]["looks"]},  # an unpaired comparison has one look and no paired looks
        {k: v for k, v in docs[0].items() if k != "pairs_used"},  # a paired one says how many pairs it used
    ]
    for doc in broken:
        with pytest.raises(DataError, match="schema bench.compare/1"):
            validate(doc, "doc")
